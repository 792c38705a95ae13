"""Accelerometers on a model with ``kinematics="exact"`` (issue 19).

A sensor at arc length ``s`` of a flexible link rides the exact rod: the model's rod walk
through its nodes continued to ``s`` (:func:`casflex.model.strain_kinematics.rod_point`),
the sensing element's offset turned with the section. Checked here against references
that do not share that code: the truncated model's sensor to first order in δ (position,
its δ-Jacobian, the acceleration signals and their Jacobians at δ = 0), the analytic
circular arc of a mode of constant curvature (position and frame), and the second time
derivative of the sensor's position by finite differences along a trajectory (lean and
full sensor graphs, tabulated shapes following the elbow).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.modal.integrals import rate_samples
from casflex.model import ConstantProvider, FlexibleModel, PointwiseProvider, node_interpolation
from casflex.sensors import (
    Accelerometer,
    SensorSet,
    kinematic_measurement,
    point_position_function,
)

RNG = np.random.default_rng(1991)
Q = np.array([0.1, 0.3, -0.8])  # in- and out-of-plane modes
OFFSET = (0.01, -0.02, 0.005)  # m, a sensing element off the neutral axis

# on both links, between the rod's nodes (0.37, 0.63 m) and at a link's end (1.0 m)
SENSORS = SensorSet([
    Accelerometer(2, 0.37, name="mid1", offset=OFFSET),
    Accelerometer(2, 1.0, name="end1"),
    Accelerometer(3, 0.63, name="mid2", offset=OFFSET),
    Accelerometer(3, 1.0, name="tip", frame="inertial"),
])


@pytest.fixture(scope="module")
def pointwise(arm):
    """Both kinematics on the same two modes frozen at ``Q``, gravity on."""
    provider = PointwiseProvider(arm, Q, count=2, points=SENSORS.points)
    return (FlexibleModel(arm, provider), FlexibleModel(arm, provider, kinematics="exact"))


# ------------------------------------------------------------------ first order


def test_first_order_equals_the_truncated_sensor(pointwise):
    """The exact rod is the truncated link-local deflection to first order in δ, so the
    positions at δ = 0 and their δ-Jacobians agree, and so do the signals (specific force
    in the sensor frame, gravity on) and their Jacobians in ``(δ, δ̇, δ̈)`` at δ = 0 for
    any joint motion. Both are built from the same tabulated values; the walk reproduces
    ``s e_z + w(s)`` and ``I + [ϑ(s)]×`` up to rounding (1e-10 of each quantity's size)."""
    plain, exact = pointwise
    m = plain.m
    z = np.zeros(m)
    jac = []
    for model in (plain, exact):
        p = ca.vertcat(*point_position_function(model, SENSORS).call(
            [ca.DM(Q), model.delta]))
        h = kinematic_measurement(model, SENSORS)
        x, u, a = ca.SX.sym("x", 2 * m), ca.SX.sym("u", 3 * model.n), ca.SX.sym("a", m)
        y = h(x, u, a)
        jac.append(ca.Function("j", [model.delta, x, u, a],
                               [p, ca.jacobian(p, model.delta), y,
                                ca.jacobian(y, ca.vertcat(x, a))]))
    for _ in range(2):
        u = np.r_[RNG.uniform(-1, 1, 3), RNG.normal(0, 1, 3), RNG.normal(0, 3, 3)]
        args = (z, np.zeros(2 * m), u, z)
        for a, b in zip(jac[0](*args), jac[1](*args), strict=True):
            a, b = a.full(), b.full()
            assert np.abs(a).max() > 1e-3  # not a vacuous comparison
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-10 * np.abs(a).max())
    # and beyond first order they differ: the point of the option
    d = np.full(m, 0.3)
    p0, p1 = (point_position_function(mod, SENSORS)(Q, d)[2].full() for mod in pointwise)
    assert np.abs(p1 - p0).max() > 1e-4


# ------------------------------------------------------------------ the arc


@pytest.fixture(scope="module")
def one_mode(arm):
    """The quantities of one mode at ``Q`` (the arc's fields replace its shapes)."""
    return PointwiseProvider(arm, Q, count=1).quantities


def _arc_model(arm, base, bend, points):
    """An exact model whose one mode bends link 1 with constant curvature ``κ = bend/L``
    about its local x (``ϑ = κ s e_x``, ``w = −½ κ s² e_y``, the arc's first order), link 2
    undeformed; the tabulated values at the sensor ``points`` from the same field."""
    link = arm.links[2]
    k = bend / link.length
    values = {key: np.array(v, copy=True) for key, v in base.items()}
    for key in ("sample_u", "sample_theta"):
        values[key][:] = 0.0
    for p, s in enumerate(rate_samples(link)[0]):
        values["sample_theta"][0, p, 0] = [k * s, 0.0, 0.0]
        values["sample_u"][0, p, 0] = [0.0, -0.5 * k * s**2, 0.0]
    for key, size in (("point_u", 3), ("point_theta", 3), ("point_curvature", 2)):
        values[key] = np.zeros((len(points), 1, size))
    for i, (row, s) in enumerate(points):
        if row == 2:
            values["point_theta"][i, 0] = [k * s, 0.0, 0.0]
            values["point_u"][i, 0] = [0.0, -0.5 * k * s**2, 0.0]
    return FlexibleModel(arm, ConstantProvider(values), kinematics="exact"), k


def _walk_bounds(link, s, k):
    """The rod integrator's two leading errors up to ``s`` for the turn rate ``k`` [rad/m]:
    the midpoint rule, ``Σ h³ k² / 24`` [m], and the Cayley half-turns, ``Σ (k h)³ / 48``
    [rad] (as tests/model/test_exact_kinematics.py), over the nodes' steps to ``s``."""
    nodes = node_interpolation(link)[0]
    h = np.diff(np.r_[nodes[nodes < s], s])
    return (h**3).sum() * k**2 / 24.0, ((k * h) ** 3).sum() / 48.0


@pytest.mark.parametrize("bend", [0.15, 1.5])
def test_sensor_rides_the_circular_arc(arm, one_mode, bend):
    """At δ = 1 the link is the arc: a sensor at ``s`` sits at ``(0, −(1 − cos κs)/κ,
    sin(κs)/κ)`` in the link's base frame, its section turned by ``κs`` about x, and
    the sensing element at the offset turned with it; the frame of a sensor is read from
    extra sensors at the same point, offset by 1 cm along its axes (positions only). Error budget:
    the walk's two leading terms (:func:`_walk_bounds`), with 2 % for the next order
    ((κh)² ≤ 2e-2) and the frame's angle error carried by the offset."""
    link = arm.links[2]
    c = 0.01
    probes = []
    for s in (0.37, 0.63, 1.0):
        probes += [Accelerometer(2, s, name=f"p{s}_{a}", offset=tuple(c * np.eye(4)[i, :3]))
                   for i, a in enumerate("xyzo")]
    sensors = SensorSet(list(SENSORS) + probes)
    model, k = _arc_model(arm, one_mode, bend, sensors.points)
    pos = point_position_function(model, sensors)
    out = {name: v.full().ravel()
           for name, v in zip(pos.name_out(), pos(Q, [1.0]), strict=True)}
    base = next(b for b in model.bodies if b["kind"] == "beam" and b["row"] == 2)["T"]
    T = np.array(ca.evalf(ca.substitute(base, model.q, ca.DM(Q))))
    for sen in sensors:
        if sen.row != 2:
            continue
        a = k * sen.s
        R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        arc = np.array([0.0, -(1.0 - np.cos(a)) / k, np.sin(a) / k])
        ref = T[:3, :3] @ (arc + R @ np.asarray(sen.offset)) + T[:3, 3]
        position, angle = _walk_bounds(link, sen.s, k)
        bound = 1.02 * (position + angle * np.linalg.norm(sen.offset))
        assert np.abs(out[f"p_{sen.name}"] - ref).max() < bound, sen.name
    for s in (0.37, 0.63, 1.0):
        centre = out[f"p_p{s}_o"]
        frame = np.stack([out[f"p_p{s}_{a}"] - centre for a in "xyz"], axis=1) / c
        a = k * s
        R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        _, angle = _walk_bounds(link, s, k)
        assert np.abs(T[:3, :3].T @ frame - R).max() < 1.02 * angle + 1e-12


# ------------------------------------------------------------------ acceleration

# q(t) = Q0 + QA sin(W t), δ(t) = D0 + DA sin(W t): elbow travel ±0.8 rad at 3 rad/s, and
# deflections into the nonlinear range (0.05 √kg m: ~0.1 rad at the links' ends)
Q0, QA = np.array([0.2, -0.3, 0.4]), np.array([0.5, -0.7, 0.8])
D0, DA = np.array([0.03, -0.05, 0.02]), np.array([0.02, 0.03, -0.03])
W = 3.0


def _traj(t):
    s, c = np.sin(W * t), np.cos(W * t)
    return (Q0 + QA * s, QA * W * c, -QA * W**2 * s,
            D0 + DA * s, DA * W * c, -DA * W**2 * s)


@pytest.mark.slow
def test_acceleration_is_second_derivative_of_position(arm_model):
    """The signals of the exact model (inertial frame, gravity on: ``p̈ − g``; tabulated
    shapes following the elbow, 3 modes, 15° table) equal the second time derivative of
    the sensor's position (``point_position_function``) by a Richardson-extrapolated
    central difference along a trajectory, plus ``−g``, for the full and the lean sensor
    graph (the estimator's). Difference error: truncation ~dt⁴|p⁽⁶⁾|/360 and rounding
    ~1e-16 m/dt², both ~1e-10 m/s² (as test_sensor_shape_rates.py); 1e-6 m/s² is far
    above them and far below the nonlinear part of the signal."""
    sensors = SENSORS.with_options(frame="inertial", gravity=True, rigid=True)
    model, _ = arm_model(3, step_deg=15, points=sensors.points, kinematics="exact")
    g = np.asarray(model.gravity, dtype=float)
    pos = point_position_function(model, sensors)
    graphs = [kinematic_measurement(model, sensors, lean=lean) for lean in (False, True)]
    for t0 in (0.1, 0.8):
        q, dq, ddq, d, dd, ddd = _traj(t0)
        fd2 = []
        for dt in (2e-3, 1e-3):
            p = [np.concatenate([o.full().ravel()
                                 for o in pos(*(_traj(t)[i] for i in (0, 3)))])
                 for t in (t0 - dt, t0, t0 + dt)]
            fd2.append((p[0] - 2.0 * p[1] + p[2]) / dt**2)
        fd = (4.0 * fd2[1] - fd2[0]) / 3.0 - np.tile(g, len(sensors))
        for h in graphs:
            y = h(np.r_[d, dd], np.r_[q, dq, ddq], ddd).full().ravel()
            np.testing.assert_allclose(y, fd, rtol=0, atol=1e-6)
