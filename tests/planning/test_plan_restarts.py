"""Warm restarts of the planner (casflex.planning.restarts) on the one-link arm."""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.planning import plan_move
from casflex.robot import load

MOVE = Move([0.0], [1.0], 2.0, settle=1.0)
COMMON = {"torque_limit": 0.05, "velocity_limit": 1.0, "intervals": 24}


@pytest.fixture(scope="module")
def onelink():
    robot = load("problems/onelink.toml")
    return FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)


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
