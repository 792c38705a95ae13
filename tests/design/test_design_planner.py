"""The design job's planner step on the one-link arm: the plan at the shaped move's limits,
verified by simulation; a planner that finds no plan is reported, not fatal."""

from __future__ import annotations

import time

import numpy as np
import pytest

from casflex.design import plan_next_to_shaped, planner_summary
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move, ShapedMove
from casflex.robot import load
from casflex.shaping import zv
from casflex.simulate import simulate_prescribed

SETTINGS = {"objective": "time", "duration": None, "weight": 0.0, "robust": 0.0,
            "end": "shaped", "intervals": 30, "transcription": "collocation",
            "max_iter": 300, "verify_dt": 1e-4}


@pytest.fixture(scope="module")
def case():
    robot = load("problems/onelink.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    omega = float(np.sqrt(model.functions()["stiffness"]([0.0]).full()[0, 0]))
    move = Move([0.0], [0.5], 1.0, settle=1.0, name="half")
    # a ZV shaper 30 % off the mode (a poor model): the shaped move leaves a residual of
    # ~0.15 mm, far above the plan's discretisation error (~1 um here)
    shaped = ShapedMove(move, zv(0.7 * omega))
    run = simulate_prescribed(model, shaped, dt=1e-3)
    return model, move, shaped, run


def test_plan_at_the_shaped_limits(case):
    model, move, shaped, run = case
    c = plan_next_to_shaped(model, move, shaped, run, SETTINGS, dt=1e-3)
    s = planner_summary(c, "shaped")
    assert s["success"] and s["move"] == "half"
    # the limits are the shaped move's peaks with the joints on it (simulated here at 1 ms)
    assert s["limits"]["torque"][0] == pytest.approx(np.abs(run.tau).max(), rel=1e-9)
    assert s["limits"]["velocity"][0] == pytest.approx(np.abs(run.dq).max(), rel=1e-9)
    assert s["end_bound"] == pytest.approx(run.residual_tip_deflection, rel=1e-12)
    assert s["duration"] < shaped.duration
    # verified at 0.1 ms with the joints on the plan: the bound within the 1 % budget of
    # tests/planning/test_plan_onelink.py
    assert s["residual_tip_deflection"] <= 1.01 * s["end_bound"]


def test_no_plan_is_reported(case):
    model, move, shaped, run = case
    c = plan_next_to_shaped(model, move, shaped, run, dict(SETTINGS, max_iter=1), dt=1e-3)
    assert c.plan is None
    s = planner_summary(c, "shaped")
    assert s["success"] is False and "Maximum" in s["error"]
    assert s["shaped"]["duration"] == shaped.duration


def test_point_derivatives_compiled_in_the_cache_give_casadi_s_plan(case, tmp_path,
                                                                     monkeypatch):
    # the study's default with collocation ("points", compiled once into the job's cache)
    # against CasADi's own derivatives: the same NLP, so the same plan to Ipopt's tolerance
    monkeypatch.setenv("CASFLEX_BACKGROUND_BUILDS", "1")  # a user's default (conftest: off)
    model, move, shaped, run = case
    ref = plan_next_to_shaped(model, move, shaped, run, dict(SETTINGS, derivatives="casadi"),
                              dt=1e-3, cache_dir=tmp_path)
    assert not (tmp_path / "jit").exists()  # nothing compiled for CasADi's derivatives
    c = plan_next_to_shaped(model, move, shaped, run, dict(SETTINGS, derivatives="points"),
                            dt=1e-3, cache_dir=tmp_path)
    assert c.plan.stats["derivatives"] == "points"
    jit = tmp_path / "jit"
    assert list(jit.glob("plan_points-*"))  # the point function's quick builds
    assert c.plan.duration == pytest.approx(ref.plan.duration, rel=1e-6)
    assert ref.plan.duration < shaped.duration
    # the optimised builds come from the background (point_compiler); once they are in
    # the cache a second job builds nothing and finds the same plan
    end = time.monotonic() + 120.0
    while list(jit.glob(".gen-*")) and time.monotonic() < end:
        time.sleep(0.1)
    libraries = sorted(jit.glob("plan_points-*"))
    assert len(libraries) == 4  # values and derivatives, each quick and optimised
    again = plan_next_to_shaped(model, move, shaped, run, dict(SETTINGS, derivatives="points"),
                                dt=1e-3, cache_dir=tmp_path)
    assert sorted(jit.glob("plan_points-*")) == libraries
    assert again.plan.duration == pytest.approx(c.plan.duration, rel=1e-9)
