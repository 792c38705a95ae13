"""FlexibleModel(foreshortening=True): the beams' shortening and M_qq to second order in δ.

The option is the geometric (centrifugal) stiffening of the modal model (issue 19): the
first-order model leaves the δ² part of the kinetic energy ``½ q̇ᵀ M_qq q̇`` out, and with
it every term of the δ equations that is linear in δ and quadratic in q̇. Checked here
against the Southwell coefficients of a uniform rotating cantilever (Rayleigh quotient of
the analytic Euler–Bernoulli mode, computed in the test), the skew symmetry of Ṁ − 2C,
the rigid limit and (slow) the conservation of T + V in free motion.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import quad

from casflex.model import FlexibleModel, PointwiseProvider
from casflex.robot import loads

RNG = np.random.default_rng(1987)

# One revolute joint about the vertical z0 turning a horizontal 1 m cantilever (the Table 8
# link): the classic rotating beam with the hub at its root.
ROTOR = """
name = "rotor"
gravity = [0.0, 0.0, -9.81]
damping_ratio = 0.0
[[link]]
name = "hub"
joint = "revolute"
[[link]]
name = "beam"
joint = "fixed"
a = 1.0
[link.section]
shape = "rectangle"
a = 0.005
b = 0.007
[link.material]
E = 69.0e9
G = 26.9e9
rho = 2700.0
"""


def _southwell_first_mode() -> float:
    """Rayleigh quotient ``∫ ½(1 − x²) φ'² dx / ∫ φ² dx`` of the first clamped–free mode
    of a uniform Euler–Bernoulli beam (unit length): the centrifugal tension of a beam
    turning about its root, ``P(x) = ρA Ω² (L² − x²)/2``, over its modal mass."""
    bl = 1.8751040687119611  # first root of 1 + cos β cosh β = 0
    sig = (np.cosh(bl) + np.cos(bl)) / (np.sinh(bl) + np.sin(bl))

    def phi(x):
        return np.cosh(bl * x) - np.cos(bl * x) - sig * (np.sinh(bl * x) - np.sin(bl * x))

    def dphi(x):
        return bl * (np.sinh(bl * x) + np.sin(bl * x)
                     - sig * (np.cosh(bl * x) - np.cos(bl * x)))

    num = quad(lambda x: 0.5 * (1 - x * x) * dphi(x) ** 2, 0, 1, epsabs=1e-13)[0]
    return num / quad(lambda x: phi(x) ** 2, 0, 1, epsabs=1e-13)[0]


def test_southwell_coefficients_of_a_rotating_cantilever():
    """At a constant rate Ω the δ rows have the stiffness ``ω² + K Ω²``: K = 1.1933 (the
    Southwell coefficient of the first mode) bending along the rotation axis, K − 1 =
    0.1933 bending in the plane of rotation (the centrifugal softening of the δ² part of
    Ψ against the stiffening of the shortening). The default model has K = 0 for both."""
    robot = loads(ROTOR)
    K1 = _southwell_first_mode()
    assert abs(K1 - 1.1933) < 1e-4  # the published value (Southwell; Wright et al. 1982)
    provider = PointwiseProvider(robot, [0.0], count=4)
    end_u = np.asarray(provider.quantities["end_u"])[0]  # (m, 3), local beam frame
    omega = np.asarray(provider.quantities["omega"])
    # local y of the beam is the joint axis z0 (beam along a: local (x, y, z) -> DH (y, z, x))
    bending = [j for j in range(4) if np.abs(end_u[j, :2]).max() > 10 * abs(end_u[j, 2])]
    axial_mode = min(bending[:2], key=lambda j: abs(end_u[j, 0]))  # along the axis
    plane_mode = max(bending[:2], key=lambda j: abs(end_u[j, 0]))
    rate = 3.0  # rad/s
    # the first-order model has no δ² part of M_qq: neither stiffening nor softening
    for option, expected in ((True, (K1, K1 - 1.0)), (False, (0.0, 0.0))):
        f = FlexibleModel(robot, provider, gravity=None,
                          foreshortening=option).functions()["dddelta"]
        d = ca.SX.sym("d", 4)
        stiff = -ca.Function("k", [d], [ca.jacobian(
            f([0.0], [rate], [0.0], d, ca.DM.zeros(4)), d)])(np.zeros(4)).full()
        for j, k in zip((axial_mode, plane_mode), expected, strict=True):
            coefficient = (stiff[j, j] - omega[j] ** 2) / rate**2
            # 1e-4: the torsional inertia ρI_p of the sections enters Ψ (≈ 2e-5 here);
            # the 16-point quadrature of the shortening is exact to 1e-12
            assert abs(coefficient - k) < 1e-4, (option, j, coefficient, k)


@pytest.fixture(scope="module")
def models(arm_model):
    plain, _ = arm_model(3, step_deg=15, gravity=None)
    short, _ = arm_model(3, step_deg=15, gravity=None, foreshortening=True)
    both, _ = arm_model(3, step_deg=15, gravity=None, foreshortening=True,
                        shape_rates=True)
    return plain, short, both


def _state(n, m):
    return (RNG.uniform(-np.pi, np.pi, n), RNG.normal(0, 1.0, n),
            RNG.normal(0, 0.01, m), RNG.normal(0, 0.1, m))


def test_rigid_limit_and_orders(models):
    """At δ = 0 nothing changes; M_qq changes by exactly its δ² part (the first-order part
    is the default model's), M_qδ and M_δδ by first-order terms only (the shortening in
    ∂p/∂δ_k, the second-order end transforms in ∂T/∂δ): M is truncated there."""
    plain, short, _ = (m.functions()["mass"] for m in models)
    q = np.array([0.3, -0.4, 0.9])
    np.testing.assert_allclose(short(q, np.zeros(3)).full(), plain(q, np.zeros(3)).full(),
                               rtol=0, atol=1e-12)
    d0 = np.array([0.02, -0.01, 0.015])
    diffs = [short(q, e * d0).full() - plain(q, e * d0).full() for e in (1.0, 0.5)]
    for block, power in (((slice(0, 3), slice(0, 3)), 2), ((slice(0, 3), slice(3, 6)), 1),
                         ((slice(3, 6), slice(3, 6)), 1)):
        a, b = (np.abs(x[block]).max() for x in diffs)
        assert a > 1e-6 and abs(a / b - 2.0**power) < 1e-6 * 2.0**power, (block, a, b)


@pytest.mark.parametrize("which", [1, 2], ids=["foreshortening", "with_shape_rates"])
def test_mdot_minus_2c_is_skew(models, which):
    f = models[which].functions()
    for _ in range(4):
        q, dq, d, dd = _state(3, 3)
        C = f["coriolis"](q, d, dq, dd).full()
        h = 1e-6  # central difference of M along the velocity
        Mdot = (f["mass"](q + h * dq, d + h * dd).full()
                - f["mass"](q - h * dq, d - h * dd).full()) / (2 * h)
        S = Mdot - 2 * C
        assert np.abs(S + S.T).max() < 1e-7 * max(1.0, np.abs(Mdot).max())


def test_needs_first_order(arm):
    from casflex.errors import ModelError

    with pytest.raises(ModelError, match="foreshortening"):
        FlexibleModel(arm, PointwiseProvider(arm, [0.0, 0.0, 0.5], count=2),
                      delta_order=0, foreshortening=True)


@pytest.mark.slow
def test_free_motion_conserves_energy(arm, arm_model):
    """τ = 0, no damping, no gravity, both options, shapes following q3: T + V conserved
    over 5 s (the initial state, motor inertias and q3 range of test_shape_rates; the
    bound is the integrator's). With gravity the arm falls through many turns of q3,
    across the table's wrap at −π, where the slopes of the padded B-spline jump."""
    from casflex.model import TableProvider

    _, table = arm_model(3, step_deg=15, gravity=None, shape_rates=True)
    links = list(arm.links)
    for row in arm.joint_rows:
        links[row] = dataclasses.replace(links[row], motor_inertia=0.01)
    robot = dataclasses.replace(arm, links=tuple(links))
    model = FlexibleModel(robot, TableProvider(table), gravity=None,
                          damping_ratio=0.0, shape_rates=True, foreshortening=True)
    f = model.functions()
    n, m = model.n, model.m
    x = ca.SX.sym("x", 2 * (n + m))
    integ = ca.integrator("F", "cvodes", {"x": x, "ode": f["ode"](x, ca.DM.zeros(n))},
                          0.0, 5.0, {"abstol": 1e-12, "reltol": 1e-12,
                                     "max_num_steps": 200000})
    x0 = np.r_[0.1, -0.3, 0.5, 0.004, -0.003, 0.002, 0.2, 0.3, 0.1, 0.05, 0.0, -0.05]

    def energy(xv):
        return float(f["energy"](xv[:n], xv[n + m:2 * n + m], xv[n:n + m],
                                 xv[2 * n + m:])[2])

    E0 = energy(x0)
    xf = integ(x0=x0)["xf"].full().ravel()
    assert abs(energy(xf) - E0) < 1e-6 * abs(E0)

