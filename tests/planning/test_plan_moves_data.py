"""The stored comparison of planned and SI-shaped moves (benchmarks/data/planning_moves.json,
written by benchmarks/bench_planning_moves.py and read by notebooks/07_planning).

The solves behind it take minutes each, so the suite does not repeat them; it checks that
the file is the one the notebook was written for (SHA-256) and that its records hold
together by rules that do not depend on the planner: the shaped move lasts the move plus
its shaper, the shaper's amplitudes sum to 1, the plans were given the shaped move's peaks
as limits (a fair comparison), their end bounds are the shaped move's residuals (the
nominal one for the nominal plan; for the robust one the shaped residual at each
frequency error, or in a file stored before session 11 the largest of them). Whether the
plans meet the issue's targets is what the file reports, not what this test asserts
(benchmarks/README_planning.md).
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from pathlib import Path

import pytest

from casflex.moves import load_move

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "benchmarks" / "data" / "planning_moves.json"
NOTEBOOK = ROOT / "notebooks" / "07_planning.py"


@pytest.fixture(scope="module")
def stored():
    sha = re.search(r'DATA_SHA256 = "([0-9a-f]{64})"', NOTEBOOK.read_text()).group(1)
    raw = DATA.read_bytes()
    assert hashlib.sha256(raw).hexdigest() == sha, "rerun bench_planning_moves.py"
    return json.loads(raw)


def _moves(stored):
    return [k for k in ("move1", "move2", "move3") if k in stored]


def test_the_stored_file_holds_move_1_and_the_one_link_cases(stored):
    assert "move1" in _moves(stored)
    assert {"nominal", "robust"} <= set(stored["onelink"]["plans"])


def test_shaped_moves_last_the_move_plus_the_shaper(stored):
    for name in _moves(stored):
        rec = stored[name]
        move = load_move(ROOT / f"problems/moves.toml:{name}")
        assert rec["q0"] == move.q0.tolist() and rec["qf"] == move.qf.tolist()
        shaper = rec["shaped"]["shaper"]
        # times and amplitudes are stored to 10 significant digits
        assert math.isclose(sum(shaper["amplitudes"]), 1.0, rel_tol=1e-9)
        assert math.isclose(rec["shaped"]["duration"], move.duration + shaper["times"][-1],
                            rel_tol=1e-9)


def test_plans_were_given_the_shaped_peaks_as_limits(stored):
    for name in _moves(stored):
        rec = stored[name]
        moving = [a != b for a, b in zip(rec["q0"], rec["qf"], strict=True)]
        # the limits come from plan_robot_move's shaped run and the peaks from this file's
        # own run of the same shaped move at the same step: equal to round-off
        for key in [k for k in ("planned", "robust") if k in rec]:
            limits = rec[key]["limits"]
            for j, moves_j in enumerate(moving):
                if moves_j:
                    assert math.isclose(limits["torque"][j],
                                        rec["shaped"]["torque_peak"][j], rel_tol=1e-9)
                    assert math.isclose(limits["velocity"][j],
                                        rec["shaped"]["velocity_peak"][j], rel_tol=1e-9)
                else:  # a held joint: no torque limit (limits.py), 1e-3 of the velocity
                    assert limits["torque"][j] == math.inf
                    assert math.isclose(limits["velocity"][j],
                                        1e-3 * max(limits["velocity"]), rel_tol=1e-12)


def test_end_bounds_are_the_shaped_residuals(stored):
    for name in _moves(stored):
        rec = stored[name]
        shaped = rec["shaped"]
        k = shaped["errors"].index(0.0)
        assert math.isclose(rec["planned"]["end_bound"], shaped["prescribed"][k],
                            rel_tol=1e-9)
        if "robust" in rec:
            assert rec["robust"]["scenarios"] == [0.0, -rec["robust"]["robust"],
                                                  rec["robust"]["robust"]]
            bounds = rec["robust"].get("end_bounds")
            if bounds is None:  # stored before session 11: one bound, the largest
                assert math.isclose(rec["robust"]["end_bound"], max(shaped["prescribed"]),
                                    rel_tol=1e-12)
            else:  # one bound per scenario (0, -r, +r): the shaped residual at that error
                for e, b in zip(rec["robust"]["scenarios"], bounds, strict=True):
                    k = shaped["errors"].index(e)
                    assert math.isclose(b, shaped["prescribed"][k], rel_tol=1e-12)
                assert rec["robust"]["end_bound"] == bounds[0]
