"""The structured pieces of the EKF step against independent references: the RK4
transition matrix in closed form against CasADi's differentiation through
``rk4_step``, and the standard form of the scalar covariance update against the Joseph
form and the batch update."""

import dataclasses

import casadi as ca
import numpy as np
import pytest

from casflex.estimation import ekf_step_function, run_ekf, tabulate_plant
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.robot import load
from casflex.sensors import Accelerometer, SensorSet, kinematic_measurement
from casflex.simulate.integrators import rk4_step

DT = 1e-3
Q = 5e-6


@pytest.fixture(scope="module")
def small():
    robot = load("problems/arm2link.toml")
    ss = SensorSet([Accelerometer(3, 1.0, name="tip"), Accelerometer(2, 1.0, name="elbow")])
    model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0.3, 0.6], 2, ss.points),
                          gravity=None)
    return tabulate_plant(model, cache_dir=False, check=False), ss


@pytest.mark.parametrize("order, jacobians", [(1, "exact"), (2, "first_order"),
                                              (2, "linearized")])
def test_transition_equals_rk4_jacobian(small, order, jacobians):
    """With every channel masked the step only predicts: ``P_next = Φ P Φᵀ + Q dt`` with
    ``Φ`` the Jacobian of one RK4 step of the plant's first-order part. The reference
    ``Φ`` is CasADi's differentiation through :func:`rk4_step` at the plant's numeric
    coefficients; the step forms it by Horner's rule on the blocks of ``A``: the two
    differ by rounding only (1e-12 relative: ~10 operations per entry on numbers of
    |Φ| ≤ 1.1 and |P| ~ 1)."""
    plant, ss = small
    if order == 1:
        plant = dataclasses.replace(plant, order=1)
    m = plant.m
    step = ekf_step_function(plant, ss, Q, 1e-4, DT, jacobians=jacobians)
    rng = np.random.default_rng(3)
    u = np.r_[rng.uniform(-1, 1, 3), rng.normal(size=6)]
    A0 = rng.normal(size=(2 * m, 2 * m))
    P = A0 @ A0.T + np.eye(2 * m)
    x = rng.normal(size=2 * m) * 1e-3
    _, P_next, x_post = step(x, P, u, np.zeros(6), np.zeros(6))
    assert np.array_equal(np.asarray(x_post).ravel(), x)  # no update: all masked
    r0, Jd, Jv = (np.asarray(ca.evalf(c)) for c in plant.coefficients(u[:3], u[3:6], u[6:]))
    xs = ca.SX.sym("x", 2 * m)
    Phi = ca.Function("phi", [xs], [ca.jacobian(rk4_step(
        lambda z: ca.vertcat(z[m:], r0 + Jd @ z[:m] + Jv @ z[m:]), xs, DT), xs)])
    Phi = np.asarray(Phi(x))
    ref = Phi @ P @ Phi.T + Q * DT * np.eye(2 * m)
    assert np.abs(np.asarray(P_next) - ref).max() <= 1e-12 * np.abs(ref).max()


def test_standard_form_equals_joseph(small):
    """The scalar updates in standard form ``P − k bᵀ`` against the Joseph form and the
    batch update (Cholesky of S, Joseph form) over 300 steps with a dropout of one
    channel: equal to rounding (1e-10 relative: the rounding of ~10⁴ operations per step
    fed back through the filter, measured 1e-14), and exactly symmetric."""
    plant, ss = small
    rng = np.random.default_rng(4)
    N = 300
    t = np.arange(N) * DT
    u = np.zeros((N, 9))
    u[:, 1] = 0.3 + 0.4 * np.sin(3 * t)
    u[:, 2] = 0.6 - 0.5 * np.sin(2 * t)
    u[:, 4] = 1.2 * np.cos(3 * t)
    u[:, 5] = -1.0 * np.cos(2 * t)
    u[:, 7] = -3.6 * np.sin(3 * t)
    u[:, 8] = 2.0 * np.sin(2 * t)
    y = rng.normal(scale=0.05, size=(N, 6))
    y[100:140, 2] = np.nan  # one channel lost
    P0 = 1e-6 * np.eye(4)
    runs = {form: run_ekf(ekf_step_function(plant, ss, Q, 1e-4, DT, **opts), u, y,
                          np.zeros(4), P0)
            for form, opts in (("standard", {"joseph": False}), ("joseph", {"joseph": True}),
                               ("batch", {"update": "batch"}))}
    std = runs["standard"]
    for other in ("joseph", "batch"):
        ref = runs[other]
        assert np.abs(std.x - ref.x).max() <= 1e-10 * np.abs(ref.x).max(), other
        assert np.abs(std.P - ref.P).max() <= 1e-10 * np.abs(ref.P).max(), other
    assert np.all(std.P == np.swapaxes(std.P, 1, 2))  # exactly symmetric


def test_masked_channel_is_left_out(small):
    """A masked channel changes nothing: the sequential update equals, exactly, that of a
    sensor set without the channel (its own H and R: an independent build), whatever the
    masked channel's sample and variance (0 here: the mask gates the gain through
    ``gate / (h b + r + 1 − gate)``, whose denominator stays ≥ 1), over a run of steps
    with the other channels' innovations fed back through x and P."""
    plant, ss = small
    tip, elbow = ss
    fewer = SensorSet([dataclasses.replace(tip, axes="xz"), elbow])  # tip's y left out
    r = np.full(6, 1e-4)
    r[1] = 0.0
    full = ekf_step_function(plant, ss, Q, np.diag(r), DT)
    ref = ekf_step_function(plant, fewer, Q, np.diag(np.delete(r, 1)), DT)
    rng = np.random.default_rng(5)
    x, P = np.zeros(4), 1e-6 * np.eye(4)
    xr, Pr = x, P
    mask = np.ones(6)
    mask[1] = 0.0
    for _ in range(20):
        u = np.r_[0.0, rng.uniform(-1, 1, 2), rng.normal(size=6)]
        y = rng.normal(scale=0.05, size=6)
        y[1] = 1e300  # never used
        x, P, xp = (np.asarray(v) for v in full(x, P, u, y, mask))
        xr, Pr, xpr = (np.asarray(v) for v in ref(xr, Pr, u, np.delete(y, 1), np.ones(5)))
        assert np.array_equal(xp, xpr) and np.array_equal(x, xr) and np.array_equal(P, Pr)
    assert np.abs(xp).max() > 0  # the other channels did update


def _gain_row(step, x, u, j, p=1e-8, r=1.0):
    """Row ``j`` of the step's measurement Jacobian ``H``, read off its update: with only
    channel ``j`` valid, ``P = p I`` and variance ``r`` the update is ``dx = p hᵀ e / s``
    with ``s = p |h|² + r``; the difference of two samples gives ``g = hᵀ / s``, and ``s``
    is the root of ``p |g|² s² − s + r = 0`` that tends to ``r`` (exact, no ``p → 0``)."""
    nx, ny = x.size, step.size1_in("y")
    mask = np.zeros(ny)
    mask[j] = 1.0
    P = p * np.eye(nx)
    xp = [np.asarray(step(x, P, u, np.eye(ny)[j] * e, mask)[2]).ravel() for e in (0.0, 1.0)]
    g = (xp[1] - xp[0]) / p
    a = p * g @ g
    s = 2.0 * r / (1.0 + np.sqrt(1.0 - 4.0 * a * r))
    return s * g


def _measurement_jacobian_fd(plant, sensors, x, u, first_order):
    """``H`` by central differences of the kinematic measurement (the model's own
    interpolants, not the step's lookup) with ``δ̈`` from the plant's coefficients at
    ``u``: ``d/dx h(x, δ̈(x))``, or with ``first_order`` the plant's first-order part in
    the chain rule, ``∂h/∂x + ∂h/∂δ̈ [J_δ J_δ̇]`` at ``δ̈(x)`` (the step's ``H`` then)."""
    n, m = plant.n, plant.m
    h = kinematic_measurement(plant.model, sensors)
    coef = [np.asarray(ca.evalf(c)) for c in plant.coefficients(
        u[:n], u[n:2 * n], u[2 * n:], quadratic=True)]
    r0, Jd, Jv = coef[0].ravel(), coef[1], coef[2]

    def acc(z):
        out = r0 + Jd @ z[:m] + Jv @ z[m:]
        if plant.pairs:
            out = out + coef[3] @ np.asarray(ca.evalf(plant.quadratic_terms(z))).ravel()
        return out

    def y(z, a):
        return np.asarray(h(z, u, a)).ravel()

    step = 1e-6
    a0 = acc(x)
    cols = []
    for k in range(2 * m):
        e = np.eye(2 * m)[k] * step
        if first_order:
            cols.append((y(x + e, a0) - y(x - e, a0)) / (2 * step))
        else:
            cols.append((y(x + e, acc(x + e)) - y(x - e, acc(x - e))) / (2 * step))
    H = np.array(cols).T
    if first_order:
        Ja = np.array([(y(x, a0 + d) - y(x, a0 - d)) / (2 * step)
                       for d in np.eye(m) * step]).T
        H = H + Ja @ np.hstack([Jd, Jv])
    return H


@pytest.mark.parametrize("where", ["pointwise", "table"])
def test_measurement_jacobian_equals_central_differences(small, arm_model, accel_sensors,
                                                         where):
    """The step's ``H`` (read off its update) against central differences of the
    kinematic measurement: at a deflected state and a moving arm, for the pointwise
    model's step (no table: the measurement is differentiated as it is) and the table
    model's default step (the measurement's entries and the plant's table from one
    shared lookup, ``jacobians="first_order"`` on a second-order plant: the bench's).
    1e-7 of the largest entry: measured 1e-12 (pointwise) and 1.5e-10 (table: the
    differences' truncation and rounding, step 1e-6 on δ ~ 1e-3); the chain term
    through δ̈ scaled by 0.9995 is off by 5e-4."""
    if where == "pointwise":
        plant, ss = small
        plant = dataclasses.replace(plant, order=1)
        jacobians = "exact"
    else:
        ss = accel_sensors
        model, _ = arm_model(3, points=ss.points, gravity=None)
        plant = tabulate_plant(model, order=2, cache_dir=False)
        jacobians = "first_order"
    rng = np.random.default_rng(6)
    m, n = plant.m, plant.n
    step = ekf_step_function(plant, ss, Q, 1.0, DT, jacobians=jacobians)
    for _ in range(3):
        x = rng.normal(size=2 * m) * np.r_[np.full(m, 1e-3), np.full(m, 3e-2)]
        u = np.r_[rng.uniform(-1, 1, n), rng.normal(size=2 * n)]
        H = np.array([_gain_row(step, x, u, j) for j in range(ss.n_outputs)])
        ref = _measurement_jacobian_fd(plant, ss, x, u, jacobians == "first_order")
        assert np.abs(H - ref).max() <= 1e-7 * np.abs(ref).max()
