"""A second cold start of the planner (casflex.planning.solve_with_fallback).

The rule is tested with a stand-in for ``plan_move`` whose plans are set per start (the
stall it guards against is a draw of Ipopt's path on the design study, minutes long:
benchmarks/README_planning.md, session 26); the wiring through ``plan_move``, the
restarts and the robust continuation on the one-link arm.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from casflex.errors import ModelError, SolverError
from casflex.moves import Move
from casflex.planning import (
    FALLBACK_SHORTENING,
    PlanInterrupted,
    plan_move,
    solve_with_fallback,
)

SHAPED = Move([0.0], [1.0], 3.0, name="shaped")


def _plan(duration, iterations=10, solve_s=1.0):
    return SimpleNamespace(duration=duration, stats={
        "objective_value": duration, "iterations": iterations, "status": "Solve_Succeeded",
        "solve_s": solve_s, "solve_cpu_s": solve_s})


class Planner:
    """``plan_move``'s stand-in: for each guess name, a plan or an exception."""

    def __init__(self, **outcomes):
        self.outcomes, self.calls = outcomes, []

    def __call__(self, **arguments):
        assert arguments["fallback_guess"] is None  # no second fallback inside
        guess = arguments["guess"]
        name = guess if isinstance(guess, str) else guess.name
        self.calls.append(name)
        outcome = self.outcomes[name]
        if isinstance(outcome, BaseException):
            raise outcome
        return outcome


def _solve(planner, **arguments):
    return solve_with_fallback(planner, {"guess": SHAPED, "objective": "time", **arguments},
                               "rigid")


def test_a_plan_shorter_by_the_margin_needs_no_second_start():
    planner = Planner(shaped=_plan((1.0 - FALLBACK_SHORTENING) * 3.0))
    plan = _solve(planner)
    assert planner.calls == ["shaped"] and "starts" not in plan.stats


@pytest.mark.parametrize("first, second, best", [
    (2.8, 2.1, 1),    # a stall near the start: the second start is kept
    (3.2, 2.1, 1),    # a plan longer than its start
    (2.8, 2.9, 0),    # the second is worse: the first is kept
    (2.8, 2.8, 0),    # a tie keeps the first
])
def test_a_plan_near_its_start_is_solved_again_and_the_shorter_kept(first, second, best):
    planner = Planner(shaped=_plan(first, 40, 2.0), rigid=_plan(second, 100, 5.0))
    plan = _solve(planner)
    assert planner.calls == ["shaped", "rigid"]
    assert plan.duration == (first, second)[best] and plan.stats["best_start"] == best
    starts = plan.stats["starts"]
    assert [s["guess"] for s in starts] == ["shaped", "rigid"]
    assert [s["duration"] for s in starts] == [first, second]
    # the work of both starts is counted
    assert plan.stats["iterations_total"] == 140 and plan.stats["solve_s_total"] == 7.0


def test_the_totals_of_a_start_include_its_restarts():
    first = _plan(2.9, 40, 2.0)
    first.stats.update(iterations_total=90, solve_s_total=4.5, solve_cpu_s_total=4.5)
    plan = _solve(Planner(shaped=first, rigid=_plan(2.1, 100, 5.0)))
    assert plan.stats["starts"][0]["iterations"] == 90
    assert plan.stats["iterations_total"] == 190 and plan.stats["solve_s_total"] == 9.5


def test_a_failed_first_start_is_followed_by_the_second():
    error = SolverError("no plan")
    error.solve = {"iterations": 500, "solve_s": 60.0, "solve_cpu_s": 60.0}
    plan = _solve(Planner(shaped=error, rigid=_plan(2.1, 100, 5.0)))
    assert plan.duration == 2.1 and plan.stats["best_start"] == 1
    first = plan.stats["starts"][0]
    assert first["duration"] is None and first["status"].startswith("SolverError")
    assert plan.stats["iterations_total"] == 600


def test_a_failed_second_start_keeps_the_first_plan():
    plan = _solve(Planner(shaped=_plan(2.9), rigid=SolverError("no plan either")))
    assert plan.duration == 2.9 and plan.stats["best_start"] == 0
    assert plan.stats["starts"][1]["duration"] is None


def test_two_failed_starts_raise_the_first_error_with_the_second_noted():
    with pytest.raises(SolverError, match="no plan from shaped") as info:
        _solve(Planner(shaped=SolverError("no plan from shaped"),
                       rigid=SolverError("no plan from rigid")))
    assert any("no plan from rigid" in note for note in info.value.__notes__)


def test_an_interrupted_second_start_keeps_the_shorter_plan():
    first = _plan(2.9)
    worse = PlanInterrupted(_plan(3.1), "interrupted")
    with pytest.raises(PlanInterrupted) as info:
        _solve(Planner(shaped=first, rigid=worse))
    assert info.value.plan is first
    better = PlanInterrupted(_plan(2.5), "interrupted")
    with pytest.raises(PlanInterrupted) as info:
        _solve(Planner(shaped=first, rigid=better))
    assert info.value.plan is better.plan


@pytest.mark.parametrize("arguments", [{"objective": "energy"}, {"guess": "rigid"}])
def test_the_fallback_needs_a_minimum_time_plan_from_a_move(arguments):
    with pytest.raises(ModelError, match="fallback_guess"):
        _solve(Planner(), **arguments)


def test_plan_move_takes_the_fallback_with_its_restarts(onelink):
    # from a move that lasts about the minimum time the plan is barely shorter: the rigid
    # start is solved too, each with its restarts, and both reach the one optimum
    kw = {"torque_limit": 0.1, "intervals": 20, "restarts": 1, "restart_rtol": 0.0}
    plan = plan_move(onelink, [0.0], [1.0], guess=Move([0.0], [1.0], 1.35),
                     fallback_guess="rigid", **kw)
    alone = plan_move(onelink, [0.0], [1.0], guess="rigid", **kw)
    starts = plan.stats["starts"]
    assert [s["guess"] for s in starts] == ["move", "rigid"]
    assert starts[1]["duration"] == alone.duration
    assert starts[1]["iterations"] == alone.stats["iterations_total"]
    assert abs(starts[0]["duration"] - starts[1]["duration"]) < 1e-6
    assert plan.stats["iterations_total"] == sum(s["iterations"] for s in starts)


def test_the_robust_continuation_gives_the_fallback_to_its_nominal_problem(onelink):
    kw = {"torque_limit": 0.1, "intervals": 40, "end": 2e-3, "robust": 0.1}
    plan = plan_move(onelink, [0.0], [1.0], guess=Move([0.0], [1.0], 1.35),
                     fallback_guess="rigid", robust_steps=2, **kw)
    direct = plan_move(onelink, [0.0], [1.0], **kw)
    assert [c["robust"] for c in plan.stats["continuation"]] == [0.0, 0.05, 0.1]
    assert abs(plan.duration - direct.duration) < 1e-6
