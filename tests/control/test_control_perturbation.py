"""casflex.control.perturbation: boundary layer, fast LQR gains, gain schedules and their
disk cache.

Independent check: the LQR gain against scipy's Riccati solver.
"""

import numpy as np
import pytest
import scipy.linalg

from casflex import control
from casflex.moves import Move

Q_HORIZONTAL = np.array([0.0, 0.0, -np.pi / 2])
Q_ONE = np.array([0.0, 1.0, -np.pi / 2])
Q_VERTICAL = np.array([0.0, np.pi / 2, -np.pi / 2])


def test_lqr_gain_solves_riccati(elbow_model):
    eps = 1 / 6.4
    K, S, E = control.fast_gain(elbow_model, Q_HORIZONTAL, Q=1.0, R=10.0, epsilon=eps)
    A, B = (x.full() for x in control.boundary_layer(elbow_model, eps)(Q_HORIZONTAL))
    Q, R = np.eye(6), 10 * np.eye(3)
    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    np.testing.assert_allclose(S, P, rtol=1e-6, atol=1e-9 * np.abs(P).max())
    np.testing.assert_allclose(K, np.linalg.solve(R, B.T @ P), rtol=1e-6,
                               atol=1e-9 * np.abs(K).max())
    res = A.T @ S + S @ A - S @ B @ np.linalg.solve(R, B.T @ S) + Q
    assert np.abs(res).max() < 1e-8 * np.abs(S).max()
    assert np.all(np.linalg.eigvals(A - B @ K).real < 0)


@pytest.mark.needs_cc
def test_gain_schedule_interpolates_grid_and_codegens(elbow_model, tmp_path):
    from casflex import codegen

    ax = -np.pi + 2 * np.pi * np.arange(12) / 12
    s = control.gain_schedule(elbow_model, epsilon=1 / 6.4, joints=(1,), grid=[ax],
                              q=Q_HORIZONTAL)
    K0, _, _ = control.fast_gain(elbow_model, [0.0, ax[5], -np.pi / 2], epsilon=1 / 6.4)
    np.testing.assert_allclose(s.function([0.0, ax[5], -np.pi / 2]).full(), K0, rtol=1e-8,
                               atol=1e-10)
    # q2 = ±pi/2 (vertical, modes 1 and 3 inaccessible) were filled from neighbours
    assert s.filled >= 1
    ctrl = control.composite_controller(elbow_model, gain=s)
    bundle = codegen.generate([ctrl], tmp_path, name="composite_test")
    lib = codegen.build(bundle, flags=("-O1",))
    c = codegen.load(lib, "composite")
    args = (Q_ONE, [0.1, 0, 0], [0, 0, 0], np.r_[Q_ONE + 0.01, 0.01, -0.02, 0.005, 0.1,
                                                  0, 0, 0, 0.1, 0])
    np.testing.assert_allclose(c(*args).full(), ctrl(*args).full(), rtol=1e-10, atol=1e-14)


def test_fast_loop_leaves_modes_1_and_3_undamped_at_vertical(elbow_model):
    """Fig. 121-123 at the level of the linearised closed loop (gains from q2 = 0)."""
    model = elbow_model
    eps = 1 / 6.4
    K, _, _ = control.fast_gain(model, Q_HORIZONTAL, epsilon=eps)
    ctrl = control.composite_controller(model, gain=K, epsilon=eps)
    slowest = {}
    for name, q in (("horizontal", Q_HORIZONTAL), ("one", Q_ONE), ("vertical", Q_VERTICAL)):
        cl = control.closed_loop(model, ctrl, Move(q, q, 1.0))
        f = lambda x, cl=cl: cl(5.0, x).full().ravel()  # noqa: E731
        x0 = np.r_[q, np.zeros(9)]
        J = np.column_stack([(f(x0 + e) - f(x0 - e)) / 2e-6 for e in np.eye(12) * 1e-6])
        ev = np.linalg.eigvals(J)
        osc = ev[np.abs(ev.imag) > 1.0]
        slowest[name] = np.sort(-osc.real)
    assert slowest["horizontal"][0] > 0.05 and slowest["one"][0] > 0.02
    # the damping of the slowest oscillation drops from q2 = 0 to q2 = 1 rad
    assert slowest["one"][0] < slowest["horizontal"][0]
    # vertical: two oscillatory pairs (modes 1 and 3) are not damped at all
    assert np.sum(slowest["vertical"] < 1e-6) == 4
    assert np.all(control.composite_stability(
        model, Move(Q_VERTICAL, Q_VERTICAL, 1.0), gain=K, epsilon=eps)["real"] > -1e-6)


def test_dependent_joints_of_the_boundary_layer(table_model):
    """The shoulder (through M_qδ) and the elbow (the shapes) matter; the base does not."""
    model, table = table_model
    bl = control.boundary_layer(model, control.perturbation_parameter(model, table=table))
    joints = control.dependent_joints(lambda qq: [x.full() for x in bl(qq)], model.n,
                                      np.random.default_rng(0))
    assert joints == (1, 2)


def test_cached_gain_schedule(table_model, tmp_path):
    """Loaded from the cache on the second call with the same gains; a changed weight is
    another key; a corrupt file is recomputed; no cache gives the same gains."""
    model, table = table_model
    eps = control.perturbation_parameter(model, table=table)
    axis = -np.pi + 2.0 * np.pi * np.arange(12) / 12
    first = control.cached_gain_schedule(model, 1.0, 10.0, eps, table, axis,
                                         cache_dir=tmp_path)
    assert not first.info.get("from_cache", False)
    assert first.joints == (1, 2)
    files = sorted(tmp_path.glob("gains-*.npz"))
    assert len(files) == 1
    # the same gains as gain_schedule on that grid
    direct = control.gain_schedule(model, Q=1.0, R=10.0, epsilon=eps, table=table,
                                   joints=(1, 2), grid=[axis, axis])
    np.testing.assert_array_equal(first.gains, direct.gains)
    assert first.filled == direct.filled
    # second call: from the cache, identical schedule
    again = control.cached_gain_schedule(model, 1.0, 10.0, eps, table, axis,
                                         cache_dir=tmp_path)
    assert again.info["from_cache"] is True
    np.testing.assert_array_equal(again.gains, first.gains)
    assert again.filled == first.filled and again.joints == first.joints
    assert again.epsilon == first.epsilon
    q = [0.1, 0.3, -1.2]
    np.testing.assert_array_equal(again.function(q).full(), first.function(q).full())
    # a changed weight is another key: computed and stored beside the first
    other = control.cached_gain_schedule(model, 1.0, 20.0, eps, table, axis,
                                         cache_dir=tmp_path)
    assert not other.info.get("from_cache", False)
    assert len(list(tmp_path.glob("gains-*.npz"))) == 2
    assert not np.array_equal(other.gains, first.gains)
    # a corrupt file is recomputed (and rewritten, so the next call loads it)
    files[0].write_bytes(b"not an npz file")
    redone = control.cached_gain_schedule(model, 1.0, 10.0, eps, table, axis,
                                          cache_dir=tmp_path)
    assert not redone.info.get("from_cache", False)
    np.testing.assert_array_equal(redone.gains, first.gains)
    assert control.cached_gain_schedule(model, 1.0, 10.0, eps, table, axis,
                                        cache_dir=tmp_path).info["from_cache"] is True
    # no cache: computed, nothing written
    off = control.cached_gain_schedule(model, 1.0, 10.0, eps, table, axis, cache_dir=False)
    assert not off.info.get("from_cache", False)
    np.testing.assert_array_equal(off.gains, first.gains)
    assert len(list(tmp_path.glob("gains-*.npz"))) == 2


def test_cached_gain_schedule_table_without_key(table_model, tmp_path):
    """A table without its own key (a Chebyshev fit has none) is computed, never cached:
    two different tables must not share a file."""
    import dataclasses

    model, table = table_model
    keyless = dataclasses.replace(table, info={k: v for k, v in table.info.items()
                                               if k != "key"})
    eps = control.perturbation_parameter(model, table=table)
    axis = -np.pi + 2.0 * np.pi * np.arange(12) / 12
    for _ in range(2):
        sched = control.cached_gain_schedule(model, 1.0, 10.0, eps, keyless, axis,
                                             cache_dir=tmp_path)
        assert not sched.info.get("from_cache", False)
    assert not list(tmp_path.glob("gains-*.npz"))
