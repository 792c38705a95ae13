"""The violation ceiling of a solve (casflex.planning.ViolationCeiling,
``plan_move(violation_ceiling=...)``) and the restarts' default
(casflex.planning.RESTART_VIOLATION_CEILING)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from casflex.errors import ModelError, SolverError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.planning import (
    RESTART_VIOLATION_CEILING,
    VIOLATION_CEILING_STATUS,
    ViolationCeiling,
    plan_move,
)
from casflex.planning.restarts import solve_with_restarts
from casflex.robot import load

COMMON = {"torque_limit": 0.1, "intervals": 20}


@pytest.fixture(scope="module")
def onelink():
    robot = load("problems/onelink.toml")
    return FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)


@pytest.fixture(scope="module")
def start(onelink):
    """A plan (end bound 2 mm) as an iterate without multipliers: from it the problem with
    a 1 mm end bound starts at a violation of 1e-3, leaves the constraints behind (above
    1 at iterates 6-7) and comes back to its plan (26 iterations)."""
    plan = plan_move(onelink, [0.0], [1.0], **COMMON, end=2e-3)
    return dataclasses.replace(plan, solution=None)


def _trace(onelink, start, **kw):
    seen = []
    plan = plan_move(onelink, [0.0], [1.0], **COMMON, end=1e-3, guess=start, **kw,
                     progress=lambda i, f, v: seen.append(v))
    return plan, seen


def test_below_the_ceiling_the_path_is_unchanged(onelink, start):
    free, seen = _trace(onelink, start)
    assert seen[0] < 0.01 and max(seen) > 0.5  # the excursion the tests rely on
    capped, seen_capped = _trace(onelink, start, violation_ceiling=1.01 * max(seen))
    # a listener, not a constraint: the same iterates and the same plan, bit for bit
    assert seen_capped == seen
    assert capped.duration == free.duration
    np.testing.assert_array_equal(capped.node_tau, free.node_tau)


def test_an_iterate_above_the_ceiling_ends_the_solve(onelink, start):
    _, seen = _trace(onelink, start)
    first = next(i for i, v in enumerate(seen) if v > 0.1)
    with pytest.raises(SolverError, match=VIOLATION_CEILING_STATUS) as err:
        _trace(onelink, start, violation_ceiling=0.1)
    assert (f"the constraint violation rose to {seen[first]:.6g} at iterate {first}, "
            f"above violation_ceiling = 0.1") in str(err.value)
    # it stopped there: the solve's cost is that of the iterates up to the escape, and a
    # retry from the iterate alone is worth it only when the multipliers were used
    assert err.value.solve["iterations"] == first
    assert err.value.solve["used_guess_solution"] is False


def test_the_rule_itself():
    rule = ViolationCeiling(0.5)
    assert [rule.update(1.0, v) for v in (0.1, 0.5, 0.49)] == [False] * 3
    assert rule.exceeded is None
    assert rule.update(1.0, math.nan)  # a NaN iterate has left too
    assert rule.exceeded[0] == 3 and math.isnan(rule.exceeded[1])
    assert rule.update(1.0, 0.0)  # and the escape is kept


@pytest.mark.parametrize("kw, rule", [
    ({"violation_ceiling": 0.0}, "violation_ceiling"),
    ({"violation_ceiling": -1.0}, "violation_ceiling"),
    ({"violation_ceiling": math.inf}, "violation_ceiling"),
    ({"violation_ceiling": 1.0, "solver": "fatrop"}, "iteration callback"),
])
def test_bad_ceilings_are_refused(onelink, kw, rule):
    with pytest.raises(ModelError, match=rule):
        plan_move(onelink, [0.0], [1.0], **COMMON, **kw)


@dataclasses.dataclass
class _Plan:
    duration: float
    solution: dict | None = None
    stats: dict = dataclasses.field(default_factory=dict)


def _recording_solver(calls, fail_with_multipliers=False):
    """A stand-in for plan_move recording each call's (guess has multipliers,
    violation_ceiling); every pass shortens the plan by 10 %, or fails from a plan with
    multipliers if asked to."""
    def solve(guess, restarts, violation_ceiling=None):
        with_multipliers = getattr(guess, "solution", None) is not None
        calls.append((with_multipliers, violation_ceiling))
        if with_multipliers and fail_with_multipliers:
            raise SolverError(f"plan_move: Ipopt found no plan ({VIOLATION_CEILING_STATUS})")
        d = 3.0 if guess == "cold" else 0.9 * guess.duration
        return _Plan(d, {"x": None}, {"objective_value": d, "iterations": 5, "status": "ok",
                                      "solve_s": 1.0, "solve_cpu_s": 1.0})
    return solve


def test_the_restarts_from_multipliers_get_the_default_ceiling():
    calls = []
    solve_with_restarts(_recording_solver(calls), {"guess": "cold"}, restarts=2,
                        restart_rtol=1e-3)
    ceiling = RESTART_VIOLATION_CEILING
    assert calls == [(False, None), (True, ceiling), (True, ceiling)]
    # the retry from the iterate alone gets none: its first steps jump and come back
    calls.clear()
    best = solve_with_restarts(_recording_solver(calls, fail_with_multipliers=True),
                               {"guess": "cold"}, restarts=1, restart_rtol=1e-3)
    assert calls == [(False, None), (True, ceiling), (False, None)]
    assert best.stats["best_pass"] == 2
    # a ceiling given is every attempt's
    calls.clear()
    solve_with_restarts(_recording_solver(calls, fail_with_multipliers=True),
                        {"guess": "cold", "violation_ceiling": 5.0}, restarts=1,
                        restart_rtol=1e-3)
    assert calls == [(False, 5.0), (True, 5.0), (False, 5.0)]


def test_a_restart_given_up_is_tried_from_the_iterate_alone(onelink, monkeypatch):
    # through plan_move, with the restarts' default ceiling below any start's violation
    # (a plan is feasible to Ipopt's tolerance, not exactly): the restart from the plan's
    # iterate and multipliers is given up at its start, the retry from the iterate alone
    # is solved
    import casflex.planning.restarts as restarts

    monkeypatch.setattr(restarts, "RESTART_VIOLATION_CEILING", 1e-300)
    plan = plan_move(onelink, [0.0], [1.0], **COMMON, end=2e-3, restarts=1)
    passes = plan.stats["passes"]
    assert len(passes) == 3
    assert VIOLATION_CEILING_STATUS in passes[1]["status"] and passes[1]["iterations"] == 0
    assert passes[2]["duration"] == pytest.approx(passes[0]["duration"], rel=1e-6)
