"""End bounds held by the verified residual (casflex.planning.hold_verified_bounds and
plan_robot_move's bound_corrections).

The OCP bounds the residual it predicts with its own discretisation; the verification
simulates the plan with the simulators at their own step. On a coarse OCP the two differ
by a few per cent, and the plan whose bound is B leaves more than B once simulated. The
correction re-solves with a tighter bound; the judge is the simulation, not the OCP.
"""

from __future__ import annotations

import pytest

from casflex.errors import ModelError, SolverError
from casflex.planning import (
    BOUND_MARGIN,
    hold_verified_bounds,
    tightened_bounds,
    verified_residuals,
)


class _Plan:
    """A stand-in plan: shorter for looser bounds, as a minimum-time plan is."""

    def __init__(self, bounds, iterations=4):
        self.duration = 2.0 - sum(bounds)
        self.stats = {"end_bounds": list(bounds), "iterations": iterations,
                      "status": "Solve_Succeeded", "solve_s": 0.25}


def _verify_with(factors):
    """A verification whose residual is ``factor`` times the plan's bound, per scenario."""
    def verify(plan):
        b = plan.stats["end_bounds"]
        values = [f * x for f, x in zip(factors, b, strict=True)]
        return {"prescribed": values[0], "errors": [{"prescribed": v} for v in values[1:]]}
    return verify


def test_a_plan_within_its_bounds_is_not_solved_again():
    calls = []
    first = _Plan([0.01])
    verify = _verify_with([0.9])
    kept, v, record = hold_verified_bounds(lambda b, g: calls.append(b), verify, first,
                                           verify(first))
    assert kept is first and record == [] and calls == []
    assert "bound_corrections" not in first.stats


def test_only_the_scenarios_past_their_bounds_are_tightened():
    # robust plan: nominal within, -r 10 % over, +r 25 % over (factors 1.1 and 1.25)
    first = _Plan([0.010, 0.020, 0.005])
    verify = _verify_with([0.95, 1.1, 1.25])
    solved = []

    def solve(bounds, guess):
        solved.append((bounds, guess))
        return _Plan(bounds)

    kept, v, record = hold_verified_bounds(solve, verify, first, verify(first))
    assert len(solved) == 1 and solved[0][1] is first  # warm from the last plan
    aim = 1.0 - BOUND_MARGIN
    assert solved[0][0] == pytest.approx([0.010, aim * 0.020 / 1.1, aim * 0.005 / 1.25],
                                         rel=1e-15)
    assert verified_residuals(v) == pytest.approx([0.0095, aim * 0.020, aim * 0.005],
                                                  rel=1e-12)
    assert kept.stats["end_asked"] == [0.010, 0.020, 0.005]
    assert record[0]["verified"] == verified_residuals(v)
    assert kept.duration > first.duration


def test_a_failed_re_solve_keeps_the_first_plan_and_is_recorded():
    first = _Plan([0.01])
    verify = _verify_with([1.2])

    def solve(bounds, guess):
        raise SolverError("plan_move: Ipopt found no plan (Maximum_Iterations_Exceeded)")

    kept, v, record = hold_verified_bounds(solve, verify, first, verify(first))
    assert kept is first and v["prescribed"] == pytest.approx(0.012)
    assert len(record) == 1 and "Maximum_Iterations_Exceeded" in record[0]["failed"]
    assert record[0]["solve_s"] is None and kept.stats["bound_corrections"] == record


def test_when_no_plan_meets_the_bound_the_smallest_excess_is_kept():
    # residuals that do not follow the bound (the simulator's own error dominates): the
    # re-solves make it worse, and the first plan is kept
    first = _Plan([0.01])
    excess = iter([1.3, 1.5, 1.4])

    def verify(plan):
        return {"prescribed": next(excess) * 0.01, "errors": []}

    kept, v, record = hold_verified_bounds(lambda b, g: _Plan(b), verify, first,
                                           verify(first))
    assert len(record) == 2 and kept is first
    assert v["prescribed"] == pytest.approx(0.013)


def test_corrections_must_be_a_count():
    first = _Plan([0.01])
    with pytest.raises(ModelError, match="bound_corrections"):
        hold_verified_bounds(lambda b, g: first, _verify_with([2.0]), first,
                             _verify_with([2.0])(first), corrections=-1)


def test_tightened_bounds_rule():
    # a residual above its bound: the bound scaled to aim BOUND_MARGIN below; at or
    # below it: kept
    assert tightened_bounds([1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [2.0, 1.0, 3.0]) == \
        [0.5 * (1.0 - BOUND_MARGIN), 2.0, 3.0]


def test_one_link_coarse_plan_meets_its_bound_once_simulated():
    # 20 intervals: the OCP's prediction is 3 % below the residual the 0.1 ms simulation
    # of its joint motion finds (the shaped swing's residual is well below the 1 mm bound
    # here, so the simulator's own error at the torque switches is small against it)
    from casflex.moves import load_move
    from casflex.planning import plan_robot_move
    from casflex.robot import load

    robot = load("problems/onelink.toml")
    swing = load_move("problems/moves.toml:onelink_swing")
    kw = {"n_modes": 1, "intervals": 20, "end": 1e-3, "dt": 1e-4}
    as_solved = plan_robot_move(robot, swing, bound_corrections=0, **kw).summary()
    held = plan_robot_move(robot, swing, **kw).summary()
    assert as_solved["end_bound_excess"] > 0.01  # verified above the bound without it
    assert as_solved["bound_corrections"] is None
    assert held["residual_tip_deflection"] <= 1e-3 and held["end_bound_excess"] == 0.0
    # the first solve is the same; the re-solves are counted on top of it
    record = held["bound_corrections"]
    assert 1 <= len(record) <= 2
    assert held["iterations"] == as_solved["iterations"] + sum(r["iterations"]
                                                                for r in record)
    assert [(p["duration"], p["iterations"]) for p in held["passes"]] == \
        [(p["duration"], p["iterations"]) for p in as_solved["passes"]]
    # a tighter bound costs time: the kept plan is the last re-solve, longer than the first
    assert held["duration"] == record[-1]["duration"] > as_solved["duration"]
    assert record[0]["end_bounds"][0] < 1e-3
