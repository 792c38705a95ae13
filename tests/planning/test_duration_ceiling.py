"""The duration ceiling of a minimum-time solve (casflex.planning.DurationCeiling,
``plan_move(duration_ceiling=...)``) and the defaults of casflex plan and the design job
(a continuation's answer to an escape: tests/planning/test_plan_continuation.py)."""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError, SolverError
from casflex.moves import Move
from casflex.planning import CEILING_STATUS, continuation_ceiling, plan_move
from casflex.robot import load

# from a 1.1 s guess Ipopt's duration rises to 1.371 s at iterate 3 and comes back to
# the 1.281 s plan (13 iterations)
COMMON = {"torque_limit": 0.1, "intervals": 20, "end": 2e-3,
          "guess": Move([0.0], [1.0], 1.1)}


def _trace(onelink, **kw):
    seen = []
    plan = plan_move(onelink, [0.0], [1.0], **COMMON, **kw,
                     progress=lambda i, f, v: seen.append(f))
    return plan, seen


def test_below_the_ceiling_the_path_is_unchanged(onelink):
    free, seen = _trace(onelink)
    assert max(seen) > 1.3 and free.duration < 1.3  # the excursion the test relies on
    capped, seen_capped = _trace(onelink, duration_ceiling=1.05 * max(seen))
    # a listener, not a constraint: the same iterates and the same plan, bit for bit
    assert seen_capped == seen
    assert capped.duration == free.duration
    np.testing.assert_array_equal(capped.node_tau, free.node_tau)


def test_an_iterate_above_the_ceiling_ends_the_solve(onelink):
    _, seen = _trace(onelink)
    first = next(i for i, f in enumerate(seen) if f > 1.3)
    with pytest.raises(SolverError, match=CEILING_STATUS) as err:
        _trace(onelink, duration_ceiling=1.3)
    message = str(err.value)
    assert f"rose to {seen[first]:.6g} s at iterate {first}, above duration_ceiling = 1.3 s" \
        in message
    # it stopped there: the solve's cost is that of the iterates up to the escape
    assert err.value.solve["iterations"] == first


def test_a_start_above_the_ceiling_is_given_up_at_once(onelink):
    with pytest.raises(SolverError, match="at iterate 0"):
        _trace(onelink, duration_ceiling=1.0)


@pytest.mark.parametrize("kw, rule", [
    ({"duration_ceiling": 0.0}, "duration_ceiling"),
    ({"duration_ceiling": -1.0}, "duration_ceiling"),
    ({"duration_ceiling": "2"}, "duration_ceiling"),
    ({"duration_ceiling": 2.0, "objective": "weighted", "weight": 1.0}, "objective='time'"),
    ({"duration_ceiling": 2.0, "solver": "fatrop"}, "iteration callback"),
])
def test_bad_ceilings_are_refused(onelink, kw, rule):
    with pytest.raises(ModelError, match=rule):
        plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20, **kw)


class _Stop(Exception):
    """Raised by :func:`_capture` once it has the arguments."""


def _capture(seen):
    """A stand-in of plan_move that records its keyword arguments in ``seen``."""
    def capture(model, move, **kw):
        seen.update(kw)
        raise _Stop
    return capture


def test_the_default_ceiling_of_plan_robot_move(monkeypatch):
    # plan_robot_move (casflex plan) hands plan_move the shaped move's duration for a
    # robust path
    import casflex.planning.verify as verify

    seen = {}
    monkeypatch.setattr(verify, "plan_move", _capture(seen))
    robot = load("problems/onelink.toml")
    move = Move([0.0], [1.0], 2.0, settle=1.0)
    # the default path with the shaped move's end bounds is the bound path: a path even
    # with one step; the frequency path with one step is the robust problem directly
    for robust, steps, path, expected in ((0.1, 3, None, True), (0.1, 1, None, True),
                                          (0.1, 1, "frequency", False),
                                          (0.0, 3, None, False)):
        seen.clear()
        with pytest.raises(_Stop):
            verify.plan_robot_move(robot, move, 1, robust=robust, robust_steps=steps,
                                   robust_path=path, intervals=20)
        shaped = seen["guess"].duration
        assert seen["duration_ceiling"] == (pytest.approx(shaped) if expected else None)
    assert continuation_ceiling("weighted", 0.1, 3, 2.0) is None


def test_the_design_jobs_robust_planner_has_the_same_ceiling(onelink, monkeypatch):
    import casflex.planning
    from casflex.design.planner import plan_next_to_shaped
    from casflex.moves import ShapedMove
    from casflex.shaping import zv
    from casflex.simulate import simulate_prescribed

    seen = {}
    monkeypatch.setattr(casflex.planning, "plan_move", _capture(seen))
    move = Move([0.0], [0.5], 1.0, settle=0.5)
    shaped = ShapedMove(move, zv(25.7))
    run = simulate_prescribed(onelink, shaped, dt=1e-3)
    settings = {"objective": "time", "duration": None, "weight": 0.0, "robust": 0.1,
                "robust_steps": 3, "end": "rest", "intervals": 12,
                "transcription": "collocation", "max_iter": 200}
    with pytest.raises(_Stop):
        plan_next_to_shaped(onelink, move, shaped, run, settings, dt=1e-3, cache_dir=False)
    assert seen["duration_ceiling"] == pytest.approx(float(shaped.duration))


def test_a_duration_that_is_not_positive_ends_the_solve(onelink, monkeypatch):
    # an iterate at T <= 0 (its lower bound is a constraint, which Ipopt may violate) has
    # left the problem: given up as an escape above the ceiling is. Ipopt is made to
    # show one by a listener that reports the third iterate's objective negated
    import casflex.planning.ocp as ocp

    real = ocp.iteration_callback

    def flipping(lbg, ubg, nx, listeners, soft=None):
        count = {"n": 0}

        def flip(call):
            return lambda f, v: call(-f if count["n"] == 2 else f, v)

        def counter(f, v):
            count["n"] += 1

        return real(lbg, ubg, nx, [flip(c) for c in listeners] + [counter], soft=soft)

    monkeypatch.setattr(ocp, "iteration_callback", flipping)
    with pytest.raises(SolverError, match=r"the duration fell to -[0-9.]+ s at iterate 2, "
                                          r"not a duration"):
        _trace(onelink, duration_ceiling=2.0)
