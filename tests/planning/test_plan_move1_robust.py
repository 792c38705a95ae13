"""The issue's robust claim on move 1 of the design study, through ``casflex plan`` from
scratch: the cold nominal plan, then the bound path at ±10 % (benchmarks/README_planning.md,
session 33). One run of this test is one draw of Ipopt's path, which changes with the
machine's rounding: session 32's CI rehearsal took a 2.65 s plan that had left the path at
0.5 of it and failed two problems later; since such plans are refused (PATH_RISE,
PATH_STATUSES) thirteen draws of thirteen reached the 2.1448 s plan, one of them after all
five halvings (CONTINUATION_HALVINGS) on the problem at 0.5."""

from __future__ import annotations

import json

import pytest

from casflex.cli import main


@pytest.mark.slow
def test_move_1_robust_plan_from_scratch_is_shorter_and_leaves_no_more_than_shaped(capsys):
    code = main(["plan", "problems/arm2link_actuated.toml", "--move",
                 "problems/moves.toml:move1", "--robust", "0.1", "--json",
                 "--delta-order", "0", "--step", "3deg"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    shaped = out["shaped"]
    # at least 20 % shorter than the SI-shaped move, with no more residual vibration on
    # the nominal model (verified by simulation at 0.1 ms, the joints on the plan) ...
    assert out["duration"] <= 0.8 * shaped["duration"]
    assert out["residual_tip_deflection"] <= shaped["residual_tip_deflection"]
    # ... and none more at ±10 % frequency error, where the nominal plan leaves 4.3 and
    # 4.6 times the shaped move's residual (benchmarks/data/planning_moves.json)
    assert [r["error"] for r in out["robust"]] == [-0.1, 0.1]
    for r in out["robust"]:
        assert r["residual_tip_deflection"] <= r["shaped_residual_tip_deflection"], r
