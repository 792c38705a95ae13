"""The design report's structure: its sections, the figures it shows exist, and every
number it prints equals the one in summary.json (to the digits printed)."""

from __future__ import annotations

import json
import re
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

from casflex import design
from casflex.design.report import write_report
from casflex.planning import PlannedMove

ROOT = Path(__file__).resolve().parents[2]
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"

SECTIONS = ["Frequencies and modal contributions along the move", "Shaper",
            "Tip deflection", "Closed loop: joint tracking", "Estimation (EKF in the loop)",
            "Stability along the shaped move", "Modal accessibility along the move",
            "C code", "Timings", "References"]
NUMBER = r"(-?\d+(?:\.\d+)?(?:e[-+]?\d+)?)"


def _agrees(text: str, value: float, scale: float = 1.0) -> bool:
    """``text`` (a printed number) is ``value * scale`` rounded to the digits printed: the
    difference is at most half a unit of the last printed digit (plus rounding of the
    product)."""
    printed = Decimal(text)
    half_unit = float(Decimal(1).scaleb(printed.as_tuple().exponent)) / 2
    return abs(float(printed) - value * scale) <= half_unit * (1 + 1e-9) + 1e-12 * abs(value)


def _one(pattern: str, text: str) -> list[str]:
    found = re.findall(pattern, text)
    assert len(found) == 1, f"expected one match of {pattern!r}, got {found}"
    return list(found[0]) if isinstance(found[0], tuple) else [found[0]]


def _table_rows(text: str, header: str) -> list[list[str]]:
    """The cells of the rows of the Markdown table whose header row starts with ``header``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


def check_report(out: Path) -> None:
    """Every rule of the report's structure, against ``out/summary.json``."""
    text = (out / "report.md").read_text()
    s = json.loads((out / "summary.json").read_text())
    headings = re.findall(r"^## (.+)$", text, flags=re.M)
    sections = list(SECTIONS)
    if s.get("planner") is not None:  # a [planner] section: after the tip deflection
        sections.insert(sections.index("Tip deflection") + 1, "Planned move")
    assert headings == sections
    # every figure shown exists, and every figure the job saved is shown
    shown = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert shown and len(shown) == len(set(shown))
    for name in shown:
        assert (out / name).is_file() and (out / name).stat().st_size > 1000, name
    assert set(shown) == set(s["figures"])
    # every dissertation reference in the text is explained in the References section
    body, refs = text.split("## References")
    for ref in set(re.findall(r"(?:eq\. \d+|§[\d.]*\d)", body)):
        assert ref in refs, ref
    # numbers
    m = s["modes"]
    rows = _table_rows(text, "| mode | ω span")
    assert len(rows) == m
    for j, row in enumerate(rows):
        assert _agrees(row[3], s["contributions"][j]) and _agrees(row[4], s["tolerances"][j])
        lo, hi = row[2].split(" – ")
        assert _agrees(lo, s["frequency_ranges"][j][0])
        assert _agrees(hi, s["frequency_ranges"][j][1])
        # one precision for every contribution (no `1` next to `0.65`)
    assert len({len(r[3].split(".")[-1]) for r in rows}) == 1
    assert _agrees(_one(r"duration \*\*" + NUMBER + r" s\*\*", text)[0], s["shaper_duration"])
    assert _agrees(_one(r"Shaping removes \*\*" + NUMBER + r" %\*\*", text)[0],
                   s["residual_reduction"], 100)
    tip = _table_rows(text, "| run | max [mm]")
    for row, key in zip(tip, ("unshaped", "shaped", "closed_loop"), strict=True):
        assert _agrees(row[1], s["max_tip_deflection"][key], 1e3)
        assert _agrees(row[2], s[f"residual_{key}"], 1e3)
    g, tr = s["slow_gains"], s["tracking"]
    kp, kd = _one(r"\*\*Kp = " + NUMBER + r" 1/s², Kd = " + NUMBER + r" 1/s\*\*", text)
    assert _agrees(kp, g["Kp"]) and _agrees(kd, g["Kd"])
    assert _agrees(_one(r"ω_min / ω_c = \*\*" + NUMBER + r"\*\*", text)[0], g["separation"])
    assert _agrees(_one(r"bandwidth ω_c = " + NUMBER + " rad/s, damping", text)[0],
                   g["bandwidth"])
    assert _agrees(_one(r"in the loop: \*\*" + NUMBER + r" rad\*\*", text)[0], tr["max"])
    assert tr["max"] == pytest.approx(s["tracking_error_max"], rel=1e-12)
    assert _one(r"\(q(\d), at t = ", text)[0] == str(tr["worst_joint"])
    ekf = _table_rows(text, "| mode | δ | δ̇ |")
    assert len(ekf) == m
    for j, row in enumerate(ekf):
        for cell, key in zip(row[1:], ("delta", "ddelta"), strict=True):
            value = s["estimation_rms_ratio"][key][j]
            number = re.match(r"\**" + NUMBER, cell).group(1)
            assert _agrees(number, value), (cell, value)
            assert ("⚠" in cell) == (value < 10)  # weak estimates are flagged
    low = s["accessibility_min"]
    mode, value, time = _one(r"lowest index along this move is mode (\d)'s, " + NUMBER
                             + r" √kg·m at t = " + NUMBER + " s", text)
    assert int(mode) == low["mode"] and _agrees(value, low["value"])
    assert _agrees(time, low["time"])
    if s.get("planner") is not None and s["planner"]["success"]:
        _check_planner(text, s["planner"])
    timings = _one(r"## Timings\n\n(.+)\n", text)[0]
    assert "_s " not in timings  # labels, not the summary's keys
    printed = re.findall(NUMBER + " s", timings)
    assert len(printed) == len(s["timings_s"])
    for p, v in zip(printed, s["timings_s"].values(), strict=True):
        assert _agrees(p, v)


def test_report_of_a_summary(tmp_path):
    """The report of a made-up three-mode summary (figures as the job would save them)."""
    study = design.load_study(STUDY)
    figures = ["frequencies.png", "prv.png", "tip_deflection.png", "estimation.png",
               "accessibility.png", "joint_tracking.png"]
    for name in figures:
        (tmp_path / name).write_bytes(b"\x89PNG" + bytes(2000))
    s = {
        "study": "demo", "robot": "arm", "move": "move1", "modes": 3,
        "controller": "composite", "frequency_span": [[6.6, 8.3], [9.3, 12.0], [22.7, 34.6]],
        "frequency_ranges": [[5.29, 9.97], [7.45, 14.36], [18.2, 41.5]],
        "contributions": [0.65, 1.0, 0.1317], "tolerances": [0.0769, 0.05, 0.38],
        "shaper": {"times": [0.0, 0.6], "amplitudes": [0.5, 0.5]}, "shaper_duration": 0.6,
        "residual_unshaped": 0.111, "residual_shaped": 0.0108,
        "residual_closed_loop": 0.0058, "residual_reduction": 0.903,
        "max_tip_deflection": {"unshaped": 0.15, "shaped": 0.056, "closed_loop": 0.047},
        "estimation_rms_ratio": {"delta": [247.4, 335.2, 104.7], "ddelta": [44.5, 18.3, 5.81]},
        "stability": {"check": "fast loop Hurwitz (§6.2.3.1)", "stable": True,
                      "worst_margin": 0.88, "unit": "1/s", "worst_time": 3.2},
        "closed_loop_finite": True, "tracking_error_max": 0.0449, "stable": True,
        "slow_gains": {"source": "move", "Kp": 21.43, "Kd": 9.26, "bandwidth": 4.63,
                       "damping": 1.0, "fraction": 0.7, "omega_min": 6.614,
                       "separation": 1.4286, "separation_holds": False,
                       "separation_required": 3.0, "move_frequency": 1.95},
        "tracking": {"max": 0.0449, "per_joint": [0.0202, 0.0083, 0.0449], "worst_joint": 3,
                     "worst_time": 2.9, "limit": 0.05, "true_state": 0.0409,
                     "slow_law_true_state": 0.012},
        "accessibility_min": {"value": 0.0226, "mode": 3, "time": 3.21},
        "c_compiled": True, "c_functions": ["rt_step"], "c_files": ["arm.c"],
        "timings_s": {"model_s": 1.234, "shaper_s": 10.0, "closed_loop_s": 30.5},
        "figures": figures,
    }
    write_report(tmp_path, study, s)
    check_report(tmp_path)
    text = (tmp_path / "report.md").read_text()
    assert "**δ̇3" not in text and "Weak estimates: δ̇3**" in text
    assert "comes from the fast (boundary-layer) feedback" in text


def test_report_checker_catches_a_wrong_number(tmp_path):
    """The checker is not vacuous: a report whose shaper duration disagrees fails it."""
    test_report_of_a_summary(tmp_path)
    report = tmp_path / "report.md"
    report.write_text(report.read_text().replace("**0.6000 s**", "**0.6100 s**"))
    with pytest.raises(AssertionError):
        check_report(tmp_path)


def _check_planner(text, p):
    """The "Planned move" section's numbers against ``summary["planner"]``."""
    rows = _table_rows(text, "| | duration [s] | residual, joints on the move")
    assert [r[0] for r in rows] == ["shaped", "planned"]
    for row, d in zip(rows, (p["shaped"], p), strict=True):
        assert _agrees(row[1], d["duration"])
        assert _agrees(row[2], d["residual_tip_deflection"], 1e3)
        for cell, value in zip(row[4].split(", "), d["torque_peak"], strict=True):
            assert _agrees(cell, value)
    assert _agrees(rows[1][3], p["residual_torque_driven"], 1e3)
    assert _agrees(_one(r"\*\*" + NUMBER + r" %\*\* shorter", text)[0], p["shortening"], 100)
    exceeds = p["residual_tip_deflection"] > p["end_bound"] \
        if isinstance(p["end_bound"], float) else False
    assert ("exceeds the end bound" in text) == exceeds


@pytest.mark.slow
def test_report_of_a_small_design_job(tmp_path):
    """A real (small) job: one mode, a 30° grid, 5 ms, the inversion-based law, C not
    compiled; its report passes every structural rule."""
    text = STUDY.read_text()
    for old, new in [('"../', f'"{ROOT}/problems/'), ("modes = 3 ", "modes = 1 "),
                     ("grid_step = 3.0", "grid_step = 30.0"), ("dt = 0.001", "dt = 0.005"),
                     ("settle = 3.0", "settle = 0.5"), ('"composite"', '"inversion"'),
                     ("compile = true", "compile = false")]:
        assert old in text
        text = text.replace(old, new)
    (tmp_path / "small.toml").write_text(text)
    design.run_design(tmp_path / "small.toml", tmp_path / "out", cache_dir=tmp_path / "cache",
                      processes=1)
    check_report(tmp_path / "out")


@pytest.mark.slow
def test_report_of_the_onelink_study_with_its_planned_move(tmp_path):
    """problems/studies/onelink_swing.toml end to end: a robot without a shape joint and a
    [planner] section; the report passes every structural rule, its Planned move section
    included, and the plan's files are there."""
    text = (ROOT / "problems" / "studies" / "onelink_swing.toml").read_text()
    (tmp_path / "study.toml").write_text(text.replace('"../', f'"{ROOT}/problems/'))
    out = tmp_path / "out"
    result = design.run_design(tmp_path / "study.toml", out, cache_dir=tmp_path / "cache",
                               processes=1)
    check_report(out)
    p = result.summary["planner"]
    # Ipopt's own convergence; when the verified residual passed the bound, the plan was
    # solved again warm with a tighter bound (bound_corrections), which may stop on the
    # progress of T; either way the simulated residual is within the bound asked for
    assert p["success"]
    assert p["status"] == "Solve_Succeeded" or (
        p["bound_corrections"] and p["status"] == "Stopped_On_Progress"), p["status"]
    assert p["residual_tip_deflection"] <= p["end_bound"]
    if p["bound_corrections"]:  # the report says which plan its figures are of
        assert "solved again with the bound" in (out / "report.md").read_text()
    # the comparison is with the job's own shaped move
    assert p["shaped"]["duration"] == pytest.approx(2.0 + result.summary["shaper_duration"],
                                                    rel=1e-12)
    assert p["duration"] < p["shaped"]["duration"]
    # the plan keeps the shaped move's torque peak at its nodes (Ipopt's tolerance)
    csv = np.loadtxt(out / "planned_trajectory.csv", delimiter=",", skiprows=1)
    assert (out / "planned_trajectory.csv").read_text().startswith("t,q1,dq1,ddq1,tau1\n")
    assert np.abs(csv[:, 4]).max() <= p["limits"]["torque"][0] * (1 + 1e-6)
    assert csv[-1, 0] == pytest.approx(p["duration"], rel=1e-12)
    assert csv[-1, 1] == pytest.approx(1.0, abs=1e-8) and abs(csv[-1, 2]) < 1e-8
    # the whole plan, read back: the same motion as the CSV's
    saved = PlannedMove.load(out / p["plan_file"])
    assert saved.duration == p["duration"]
    np.testing.assert_array_equal(saved.q[:, 0], csv[:, 1])
    assert f"`{p['plan_file']}`" in (out / "report.md").read_text()
    header = (out / "c" / p["c_table"]["header"]).read_text()
    samples = int(re.search(r"ONELINK_PLAN_N_SAMPLES (\d+)", header).group(1))
    assert samples == int(np.ceil(p["duration"] / 1e-3 - 1e-9)) + 1
