"""Accelerometers by the recursive pass (``kinematic_measurement(recursive=True)``).

The reference is the other method in the module: CasADi's time derivatives of the whole
sensor pose (``recursive=False``, itself checked against second differences of the
sensor positions in test_sensors.py and test_sensor_exact_kinematics.py). The recursion
carries the point through the pose's factors with the product rule and takes the rigid
leading factors as body-frame rates, so it is the same signal to rounding: each signal
is a sum of ~10³ operations on numbers of order 1–10² (m/s², with q̈ and δ̈ of order 1),
so the two differ by ~1e-14 of the largest signal; 1e-12 bounds that with room and is
far below any modelling term (the second-order kinematic terms are ~1e-4 of the signal
at δ ~ 1e-2). The Jacobians with respect to ``(x, δ̈)`` (what the estimator uses) are
compared to the same bound.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.model import FlexibleModel, PointwiseProvider
from casflex.sensors import Accelerometer, SensorSet, StrainPair, kinematic_measurement

OFFSET = (0.01, -0.02, 0.005)  # m, a sensing element off the neutral axis
# both links, both frames, gravity on and off, an offset, the rigid part removed, a strain
# pair among them; link 1's beam lies along the DH a, link 2's along d
SENSORS = SensorSet([
    Accelerometer(2, 0.37, name="mid1", offset=OFFSET),
    Accelerometer(2, 1.0, name="end1", frame="inertial"),
    Accelerometer(3, 0.63, name="mid2", offset=OFFSET, rigid=False),
    Accelerometer(3, 1.0, name="tip", gravity=False),
    StrainPair(2, 0.2, (3.5e-3, 2.5e-3), name="sg"),
])
TOL = 1e-12  # of the largest signal (module docstring)


def _operations(h):
    skip = {ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_ASSIGN, ca.OP_PARAMETER}
    return sum(1 for k in range(h.n_instructions()) if h.instruction_id(k) not in skip)


def _with_jacobian(h, jacobian):
    """``(x, u, dddelta) -> (y, ∂y/∂[x; dddelta])`` (reverse mode, as the estimator)."""
    x, u, a = (ca.SX.sym(n, h.size1_in(i)) for i, n in enumerate(("x", "u", "a")))
    y = h(x, u, a)
    J = ca.jtimes(y, ca.vertcat(x, a), ca.SX.eye(y.numel()), True).T if jacobian else y
    return ca.Function("hj", [x, u, a], [y, J], {"cse": True})


def _compare(model, sensors, rng, trials=4, jacobian=True, **options):
    """The recursive and the whole-pose measurement at random states: signals and
    Jacobians within TOL; returns the two graphs' operation counts."""
    graph = _with_jacobian(kinematic_measurement(model, sensors, **options), jacobian)
    rec = _with_jacobian(kinematic_measurement(model, sensors, recursive=True, **options),
                         jacobian)
    m, n = model.m, model.n
    for _ in range(trials):
        args = [np.r_[2e-2 * rng.normal(size=m), 0.3 * rng.normal(size=m)],
                np.r_[rng.uniform(-np.pi, np.pi, n), rng.normal(size=2 * n)],
                rng.normal(size=m)]
        (y0, J0), (y1, J1) = ([np.asarray(v) for v in f(*args)] for f in (graph, rec))
        assert np.abs(y1 - y0).max() <= TOL * np.abs(y0).max()
        assert np.abs(J1 - J0).max() <= TOL * np.abs(J0).max()
    return _operations(graph), _operations(rec)


@pytest.fixture(scope="module")
def provider(arm):
    """Two modes frozen at one shape-joint angle, at the points of SENSORS (a TMM solve,
    ~2 s: shared by the tests below)."""
    return PointwiseProvider(arm, [0.1, 0.3, -0.8], count=2, points=SENSORS.points)


def test_recursive_equals_pose_derivatives(arm, provider):
    """Gravity on, the first-order link-local deflection (the default kinematics). The
    recursive graph must be the smaller one (else it fell back to the whole-pose form and
    compared it with itself)."""
    model = FlexibleModel(arm, provider)
    ops_graph, ops_rec = _compare(model, SENSORS, np.random.default_rng(17))
    assert ops_rec < 0.8 * ops_graph, (ops_rec, ops_graph)


@pytest.mark.slow
def test_recursive_on_the_exact_rod(arm, provider):
    """``kinematics="exact"``: the sensors ride the exact rod (``rod_point``) and link 1's
    end is its rod's end frame. The signals only (the rod walks make the Jacobian graphs
    ~10⁶ operations, a minute to build); the rod dominates both graphs, so no size
    claim."""
    sensors = SensorSet([Accelerometer(3, 0.63, name="mid2", offset=OFFSET),
                         Accelerometer(3, 1.0, name="tip", frame="inertial", rigid=False)],
                        points=SENSORS.points)
    model = FlexibleModel(arm, provider, kinematics="exact")
    _compare(model, sensors, np.random.default_rng(19), jacobian=False)


@pytest.mark.slow
def test_recursive_lean_table_model(arm_model):
    """Three modes tabulated over the elbow (15° grid, the sensor points of
    test_sensors.py's table model): the estimator's lean measurement, its table entries
    and their first and second rates along the elbow filled from one local spline (~4 s
    with the table's build: slow; the fast suite's EKF tests run this path)."""
    points = [(2, 0.6), (3, 1.0)]
    model, _ = arm_model(3, points=points, gravity=None)
    sensors = SensorSet([Accelerometer(2, 0.6, name="a1"),
                         Accelerometer(3, 1.0, name="a2", offset=(0.0, 0.01, 0.02)),
                         Accelerometer(3, 1.0, name="a3", frame="inertial", rigid=False)],
                        points=points)
    ops_graph, ops_rec = _compare(model, sensors, np.random.default_rng(5), lean=True,
                                  lookup="local")
    assert ops_rec < 0.8 * ops_graph, (ops_rec, ops_graph)
