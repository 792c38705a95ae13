"""Gain schedules over more than one shape joint (issue 21): the 4-joint spatial arm's
elbow q3 and wrist q4, axes inside the joint limits or a move's box.

Independent checks: the scheduled gain against a direct LQR (:func:`fast_gain`, python-
control's Riccati solver) at the grid points and at random configurations between them,
with the second-order convergence of linear interpolation as the error budget; the fast
loop ``A_f − B_f K(q)`` Hurwitz at those configurations by numpy's eigenvalues; the mass
matrix condition against the exact (pointwise) model.
"""

import numpy as np
import pytest

from casflex import control
from casflex.moves import Move
from casflex.robot import load

ROBOT = "problems/arm4_spatial_actuated.toml"
Q_FROZEN = np.array([0.0, 0.3, 1.0, 0.2])  # the modes are frozen here (pointwise model)
EPS = 1.0 / 55.0  # s: about 1/ω_min of this arm (ω_1 ≈ 54-57 rad/s)


@pytest.fixture(scope="module")
def robot():
    return load(ROBOT)


@pytest.fixture(scope="module")
def frozen_model(robot):
    """Mode integrals frozen at Q_FROZEN: exact there, and M(q, 0) still turns with q2-q4
    through the rigid kinematics, so the boundary layer depends on three joints."""
    from casflex.model import FlexibleModel, PointwiseProvider

    return FlexibleModel(robot, PointwiseProvider(robot, Q_FROZEN, count=3), gravity=None,
                         delta_order=0)


def test_schedule_axes_stay_inside_limits_and_box(robot):
    step = 2 * np.pi / 30
    a1, a2, a3, a4 = control.schedule_axes(robot, (0, 1, 2, 3), 30)
    assert a1.size == 30 and a1[0] == -np.pi  # q1 has no limits: the full turn
    for axis, (lo, hi) in zip((a2, a3, a4), robot.joint_limits[1:], strict=True):
        assert axis[0] == lo and axis[-1] == hi  # the limits themselves
        assert np.all(np.diff(axis) <= step * (1 + 1e-12)) and np.all(np.diff(axis) > 0)
    low, high = np.array([-1.0, -0.5, 0.5, -0.8]), np.array([0.0, 0.3, 1.5, 0.8])
    b2, b3 = control.schedule_axes(robot, (1, 2), 30, box=(low, high))
    assert b2[0] == pytest.approx(low[1] - step) and b2[-1] == pytest.approx(high[1] + step)
    assert b3[0] == pytest.approx(low[2] - step) and b3[-1] == pytest.approx(high[2] + step)
    # near a limit the box is clipped to it
    (c4,) = control.schedule_axes(robot, (3,), 30, box=(low, [0, 0, 0, 2.09]))
    assert c4[-1] == robot.joint_limits[3][1]


def _random_inside(rng, axes, count):
    """Configurations strictly inside the box of the axes, away from the grid points."""
    lo = np.array([a[0] for a in axes])
    hi = np.array([a[-1] for a in axes])
    return lo + (hi - lo) * rng.uniform(0.05, 0.95, (count, len(axes)))


@pytest.mark.slow
def test_two_joint_schedule_matches_direct_lqr(frozen_model):
    model = frozen_model
    # a box around Q_FROZEN where the frozen model is still a physical one (M(q, 0)
    # positive definite, checked below): farther along q3 the frozen mode integrals no
    # longer match the arm's kinematics
    lo, hi = np.array([1.0, -0.6]), np.array([1.2, 0.6])
    errors = {}
    for halvings in (0, 1):
        counts = (np.array([4, 8]) * 2**halvings) + 1  # steps 0.05 and 0.15 rad, halved
        axes = [np.linspace(a, b, c) for a, b, c in zip(lo, hi, counts, strict=True)]
        sched = control.gain_schedule(model, epsilon=EPS, joints=(2, 3), grid=axes,
                                      q=Q_FROZEN, method="linear")
        assert sched.filled == 0 and sched.gains.shape[:2] == tuple(counts)
        # at the grid points: the same LQR, to round-off (unequal axis sizes: a transposed
        # grid or swapped joints would fail here)
        for i, j in ((0, 0), (1, counts[1] - 2), (counts[0] - 1, 2)):
            q = Q_FROZEN.copy()
            q[2], q[3] = axes[0][i], axes[1][j]
            K, _, _ = control.fast_gain(model, q, epsilon=EPS)
            np.testing.assert_allclose(sched.function(q).full(), K, rtol=1e-9,
                                       atol=1e-9 * np.abs(K).max())
        # between them: linear interpolation of a smooth gain, error O(h^2)
        worst = 0.0
        for q34 in _random_inside(np.random.default_rng(7), axes, 10):
            q = Q_FROZEN.copy()
            q[2:] = q34
            assert control.mass_matrix_condition(model, Move(q, q, 0.01))["holds"]
            K, _, _ = control.fast_gain(model, q, epsilon=EPS)
            Ks = sched.function(q).full()
            worst = max(worst, float(np.abs(Ks - K).max() / np.abs(K).max()))
            A, B = (x.full() for x in control.boundary_layer(model, EPS)(q))
            assert np.max(np.linalg.eigvals(A - B @ Ks).real) < 0  # fast loop Hurwitz
        errors[halvings] = worst
    # halving the step divides the error by ~4 (second order); 3 leaves room for the
    # higher-order terms at these steps
    assert errors[1] < errors[0] / 3, errors


@pytest.mark.slow
def test_schedule_clamps_outside_its_box(frozen_model):
    axes = [np.linspace(1.0, 1.2, 5), np.linspace(-0.6, 0.6, 9)]
    sched = control.gain_schedule(frozen_model, epsilon=EPS, joints=(2, 3), grid=axes,
                                  q=Q_FROZEN, method="linear")
    edge = Q_FROZEN.copy()
    edge[2], edge[3] = axes[0][-1], axes[1][0]
    beyond = edge + np.array([0.0, 0.0, 0.4, -0.3])  # past both ends
    np.testing.assert_array_equal(sched.function(beyond).full(),
                                  sched.function(edge).full())
    np.testing.assert_array_equal(sched.function(edge).full(), sched.gains[-1, 0])


def _lowest_eigenvalue_of_M(model, q):
    """Smallest eigenvalue of the whole M(q, 0) [mixed units], by numpy: its sign is that
    of the residual joint inertia when M_dd is positive definite (Haynsworth inertia)."""
    import casadi as ca

    M0 = ca.Function("M0", [model.q], [ca.substitute(model.M, model.delta,
                                                     ca.SX.zeros(model.m))])
    return float(np.linalg.eigvalsh(M0(q).full())[0])


@pytest.mark.slow
def test_mass_matrix_condition_flags_an_indefinite_interpolated_model(model_cache):
    """The bare arm's 30-degree table, cubic B-splines: between the grid points the
    interpolated mode integrals of the swapping tube pairs make M(q, 0) indefinite (found
    by a scan of the joint box); the exact model at the same configuration is not."""
    from casflex.model import FlexibleModel, PointwiseProvider, build_model

    bare = load("problems/arm4_spatial.toml")
    q = np.array([0.0, 0.0, np.radians(70.0), np.radians(-77.5)])
    held = Move(q, q, 0.1)
    table_model, _ = build_model(bare, 3, step=np.radians(30.0), gravity=None,
                                 delta_order=0, cache_dir=model_cache, processes=2)
    exact = FlexibleModel(bare, PointwiseProvider(bare, q, count=3), gravity=None,
                          delta_order=0)
    bad = control.mass_matrix_condition(table_model, held)
    good = control.mass_matrix_condition(exact, held)
    assert not bad["holds"] and _lowest_eigenvalue_of_M(table_model, q) < 0
    assert good["holds"] and _lowest_eigenvalue_of_M(exact, q) > 0
    # the exact residual joint inertia is small (the tip bodies ride on the first modes):
    # the reason the study uses the actuated arm, whose motor inertias (>= 3.7e-3 kg m^2)
    # dominate it
    assert good["value"] < 3.7e-3
    assert bad["time"] == 0.0 and np.allclose(bad["q"], q)


@pytest.mark.slow
def test_schedule_stability_over_the_cells(frozen_model):
    axes = [np.linspace(1.0, 1.2, 5), np.linspace(-0.6, 0.6, 9)]
    sched = control.gain_schedule(frozen_model, epsilon=EPS, joints=(2, 3), grid=axes,
                                  q=Q_FROZEN, method="linear")
    r = control.schedule_stability(frozen_model, sched, q=Q_FROZEN)
    assert r["points"] == 4 * 8 and r["stable"]
    # the worst cell centre, checked by hand: the interpolated gain there, numpy's
    # eigenvalues of the fast loop
    q = np.asarray(r["worst_q"]["fast_loop_hurwitz_cells"])
    A, B = (x.full() for x in control.boundary_layer(frozen_model, EPS)(q))
    K = sched.function(q).full()
    worst = np.max(np.linalg.eigvals(A - B @ K).real) / EPS
    assert r["conditions"]["fast_loop_hurwitz_cells"]["value"] == pytest.approx(worst,
                                                                                rel=1e-9)
    assert not np.any(np.isclose(q[2], axes[0])) and not np.any(np.isclose(q[3], axes[1]))
    # without the fast gains the modes are undamped (eigenvalues on the imaginary axis)
    zero = control.GainSchedule.from_gains((2, 3), axes, np.zeros_like(sched.gains), EPS,
                                           n_joints=4, method="linear")
    assert not control.schedule_stability(frozen_model, zero, q=Q_FROZEN)["stable"]
