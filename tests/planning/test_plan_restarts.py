"""Warm restarts of the planner (casflex.planning.restarts) on the one-link arm."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from casflex.errors import ModelError, SolverError
from casflex.moves import Move
from casflex.planning import plan_move
from casflex.planning.restarts import solve_with_restarts

MOVE = Move([0.0], [1.0], 2.0, settle=1.0)
COMMON = {"torque_limit": 0.05, "velocity_limit": 1.0, "intervals": 24}


@pytest.mark.parametrize("kw", [{"end": 2e-3}, {"end": "rest", "robust": 0.1}])
def test_restarts_never_lengthen_the_plan(onelink, kw):
    a = plan_move(onelink, MOVE, **COMMON, **kw)
    b = plan_move(onelink, MOVE, **COMMON, **kw, restarts=2, restart_rtol=0.0)
    passes = b.stats["passes"]
    assert 2 <= len(passes) <= 3 and b.stats["restarts"] == len(passes) - 1
    # the first pass is the plan without restarts
    assert passes[0]["duration"] == a.duration
    assert passes[0]["iterations"] == a.stats["iterations"]
    # the restarts start from the optimum (its iterate and multipliers): few iterations
    assert all(p["iterations"] < passes[0]["iterations"] for p in passes[1:])
    assert b.duration <= a.duration
    assert b.duration == min(p["duration"] for p in passes)
    assert b.duration == passes[b.stats["best_pass"]]["duration"]
    assert b.stats["iterations_total"] == sum(p["iterations"] for p in passes)
    assert b.stats["solve_s_total"] == pytest.approx(sum(p["solve_s"] for p in passes))


def test_restart_stops_when_the_plan_does_not_improve(onelink):
    # from the converged plan a restart moves T by ~1e-9 relative: below restart_rtol
    b = plan_move(onelink, MOVE, **COMMON, end=2e-3, restarts=5, restart_rtol=1e-3)
    assert b.stats["restarts"] == 1 and len(b.stats["passes"]) == 2


def test_no_restarts_is_the_single_solve(onelink):
    a = plan_move(onelink, MOVE, **COMMON, end=2e-3)
    b = plan_move(onelink, MOVE, **COMMON, end=2e-3, restarts=0)
    assert "passes" not in a.stats and "passes" not in b.stats
    assert b.duration == a.duration
    np.testing.assert_array_equal(b.node_tau, a.node_tau)


@pytest.mark.parametrize("kw, field", [
    ({"restarts": -1}, "restarts"), ({"restarts": 1.5}, "restarts"),
    ({"restarts": True}, "restarts"), ({"restarts": "2"}, "restarts"),
    ({"restart_rtol": -1e-3}, "restart_rtol"), ({"restart_rtol": float("nan")}, "restart_rtol"),
])
def test_bad_restarts_are_refused(onelink, kw, field):
    with pytest.raises(ModelError, match=field):
        plan_move(onelink, MOVE, **COMMON, **kw)


def test_a_restart_solves_the_same_scaled_problem(onelink):
    # the multipliers of a warm start belong to the rows divided by the previous pass's
    # scales: a restart keeps those scales
    a = plan_move(onelink, MOVE, **COMMON, end=2e-3)
    b = plan_move(onelink, MOVE, **COMMON, end=2e-3, guess=a)
    assert b.stats["warm_start_duals"]
    for key in ("x", "tau"):
        np.testing.assert_array_equal(b.solution["scales"][key], a.solution["scales"][key])
    assert b.solution["scales"]["T"] == a.solution["scales"]["T"]
    # from its own optimum in its own scales Ipopt has nothing left to do
    assert b.stats["iterations"] <= 3
    assert b.duration == pytest.approx(a.duration, rel=1e-6)
    # another number of intervals: no multipliers to reuse, scales from the guess
    c = plan_move(onelink, MOVE, **{**COMMON, "intervals": 30}, end=2e-3, guess=a)
    assert not c.stats["warm_start_duals"]
    assert c.solution["scales"]["T"] == pytest.approx(a.duration, rel=1e-12)


@dataclasses.dataclass
class _Plan:
    """A stand-in plan: what solve_with_restarts reads of one."""

    duration: float
    solution: dict | None = None
    stats: dict = dataclasses.field(default_factory=dict)


def _stand_in_solver(calls, cost=None):
    """A stand-in for plan_move: from a plan with multipliers it fails (the error carrying
    ``cost`` as its solve's), from the iterate alone it shortens the plan by 10 %; a cold
    solve gives 3 s. Every guess is appended to ``calls``."""
    def solve(guess, restarts, violation_ceiling=None):
        calls.append(guess)
        if isinstance(guess, _Plan) and guess.solution is not None:
            error = SolverError("plan_move: Ipopt found no plan (Maximum_Iterations_Exceeded)")
            if cost is not None:
                error.solve = cost
            raise error
        d = 3.0 if guess == "cold" else 0.9 * guess.duration
        return _Plan(d, {"x": None}, {"objective_value": d, "iterations": 5, "status": "ok",
                                      "solve_s": 1.0, "solve_cpu_s": 1.0})
    return solve


def test_a_failed_restart_is_tried_again_without_the_multipliers():
    # the control flow of solve_with_restarts with the stand-in solver
    calls = []
    best = solve_with_restarts(_stand_in_solver(calls), {"guess": "cold"}, restarts=1,
                               restart_rtol=1e-3)
    statuses = [p["status"] for p in best.stats["passes"]]
    assert statuses[0] == "ok" and statuses[1].startswith("SolverError") and statuses[2] == "ok"
    assert best.duration == pytest.approx(2.7) and best.stats["best_pass"] == 2
    # the retry had the same iterate, without its multipliers
    assert calls[2].duration == calls[1].duration == 3.0 and calls[2].solution is None
    assert best.stats["iterations_total"] == 10 and best.stats["solve_s_total"] == 2.0


def test_a_failed_pass_counts_in_the_totals():
    # a failed restart of 500 iterations was most of a run's time, but the totals left it
    # out ("4 restart(s): 89 s in all" for a run of 25 minutes): the error carries what
    # its solve cost, and the pass records and totals count it
    cost = {"iterations": 500, "solve_s": 60.0, "solve_cpu_s": 55.0}
    best = solve_with_restarts(_stand_in_solver([], cost), {"guess": "cold"}, restarts=1,
                               restart_rtol=1e-3)
    failed = best.stats["passes"][1]
    assert failed["duration"] is None and failed["iterations"] == 500
    assert best.stats["iterations_total"] == 510
    assert best.stats["solve_s_total"] == 62.0 and best.stats["solve_cpu_s_total"] == 57.0


def test_plan_move_failure_says_what_its_solve_cost(onelink):
    with pytest.raises(SolverError) as info:
        plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20, max_iter=1)
    spent = info.value.solve
    assert spent["iterations"] == 1 and spent["solve_s"] > 0.0 and spent["solve_cpu_s"] > 0.0
