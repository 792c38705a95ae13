"""The study section ``[planner]``: off unless given, every key validated with the file,
field, value and rule named; the report's "Planned move" section from a summary."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from casflex import design
from casflex.design.report import write_report
from casflex.errors import ProblemFileError

ROOT = Path(__file__).resolve().parents[2]
ONELINK = ROOT / "problems" / "studies" / "onelink_swing.toml"
ARM = ROOT / "problems" / "studies" / "arm2link_move1.toml"


def _study(tmp_path, planner_lines):
    """The onelink study with its [planner] section replaced (paths made absolute)."""
    text = ONELINK.read_text().replace('"../', f'"{ROOT}/problems/')
    head = text[:text.index("[planner]")]
    path = tmp_path / "study.toml"
    path.write_text(head + planner_lines)
    return path


def test_planner_is_off_unless_given():
    assert design.load_study(ARM).planner is None  # the bundled arm2link study
    p = design.load_study(ONELINK).planner
    assert p["objective"] == "time" and p["end"] == "shaped" and p["robust"] == 0.0
    assert p["transcription"] == "collocation" and p["intervals"] is None
    from casflex.planning import ROBUST_STEPS

    assert p["robust_steps"] == ROBUST_STEPS and p["robust_path"] is None


def test_planner_switched_off(tmp_path):
    assert design.load_study(_study(tmp_path, "[planner]\nenabled = false\n")).planner is None


def test_planner_values(tmp_path):
    p = design.load_study(_study(tmp_path, "[planner]\nobjective = 'energy'\nduration = 2.5\n"
                                 "robust = 0.1\nend = 0.002\nintervals = 40\n"
                                 "transcription = 'shooting'\nmodes = 1\n"
                                 "robust_steps = 2\nrobust_path = 'frequency'\n")).planner
    assert (p["objective"], p["duration"], p["robust"], p["end"], p["intervals"],
            p["transcription"], p["modes"], p["robust_steps"], p["robust_path"]) == (
        "energy", 2.5, 0.1, 0.002, 40, "shooting", 1, 2, "frequency")


@pytest.mark.parametrize("lines, derivatives", [
    ("", "points"),  # as casflex plan: compiled point derivatives with collocation
    ("transcription = 'shooting'\n", "casadi"),
    ("derivatives = 'casadi'\n", "casadi"),
    ("derivatives = 'blocks'\n", "blocks"),
])
def test_planner_derivatives(tmp_path, lines, derivatives):
    p = design.load_study(_study(tmp_path, "[planner]\n" + lines)).planner
    assert p["derivatives"] == derivatives


@pytest.mark.parametrize("lines, field, value, rule", [
    ("objective = 'fastest'", "planner.objective", "fastest", "must be one of"),
    ("duration = 2.0", "planner.duration", "2.0", "'time' plan finds its own"),
    ("objective = 'energy'\nduration = -1.0", "planner.duration", "-1.0", "must be"),
    ("objective = 'weighted'", "planner.weight", "0.0", "must be > 0"),
    ("robust = 0.7", "planner.robust", "0.7", "must be"),
    ("robust_steps = 0", "planner.robust_steps", "0", "must be"),
    ("robust_steps = 2.5", "planner.robust_steps", "2.5", "whole number"),
    ("robust_path = 'both'", "planner.robust_path", "both", "must be one of"),
    ("end = 'still'", "planner.end", "still", "must be one of"),
    ("end = 0.0", "planner.end", "0.0", "must be"),
    ("intervals = 2", "planner.intervals", "2", "must be"),
    ("intervals = 10.5", "planner.intervals", "10.5", "whole number"),
    ("transcription = 'pseudospectral'", "planner.transcription", "pseudospectral",
     "must be one of"),
    ("derivatives = 'sparse'", "planner.derivatives", "sparse", "must be one of"),
    ("transcription = 'shooting'\nderivatives = 'points'", "planner.derivatives", "points",
     "needs transcription = 'collocation'"),
    ("modes = 2", "planner.modes", "2", "must be"),  # the study's model has 1 mode
    ("verify_dt = 0.5", "planner.verify_dt", "0.5", "must be"),
    ("enabled = 1", "planner.enabled", "1", "true or false"),
    ("tolerance = 1e-3", "planner.tolerance", "0.001", "unknown key"),
])
def test_bad_planner_keys_name_file_field_value_rule(tmp_path, lines, field, value, rule):
    path = _study(tmp_path, "[planner]\n" + lines + "\n")
    with pytest.raises(ProblemFileError) as err:
        design.load_study(path)
    message = str(err.value)
    assert "\n" not in message
    for part in (path.name, field, value, rule):
        assert part in message, (part, message)


def _summary(planner):
    return {
        "study": "demo", "robot": "onelink", "move": "swing", "modes": 1,
        "controller": "inversion", "frequency_span": [[25.7, 25.7]],
        "frequency_ranges": [[20.6, 30.8]], "contributions": [1.0], "tolerances": [0.05],
        "shaper": {"times": [0.0, 0.12], "amplitudes": [0.5, 0.5]},
        "shaper_duration": 0.12, "residual_unshaped": 0.08, "residual_shaped": 0.002,
        "residual_closed_loop": 0.003, "residual_reduction": 0.975,
        "max_tip_deflection": {"unshaped": 0.1, "shaped": 0.05, "closed_loop": 0.05},
        "estimation_rms_ratio": {"delta": [120.0], "ddelta": [80.0]},
        "stability": {"check": "eq. 226", "stable": True, "worst_margin": 0.5,
                      "unit": "1/s^3", "worst_time": 1.0},
        "closed_loop_finite": True, "tracking_error_max": 0.01, "stable": True,
        "c_compiled": False, "c_functions": ["rt_step"], "c_files": ["a.c"],
        "timings_s": {"model_s": 1.0, "planner_s": 2.0}, "planner": planner}


SHAPED = {"duration": 2.25, "residual_tip_deflection": 2e-5, "torque_peak": [0.0434],
          "velocity_peak": [0.932]}


def test_report_section(tmp_path):
    study = design.load_study(ONELINK)
    planner = {"success": True, "move": "swing", "duration": 1.96, "objective": "time",
               "status": "Solve_Succeeded", "iterations": 23, "intervals": 113,
               "end": "shaped", "end_bound": 2e-5, "verify_dt": 1e-4,
               "residual_tip_deflection": 2.4e-5, "residual_torque_driven": 1.1e-5,
               "residual_ocp": 2e-5, "torque_peak": [0.0435], "velocity_peak": [0.932],
               "shortening": 1 - 1.96 / 2.25, "shaped": SHAPED,
               "robust": [{"error": -0.1, "residual_tip_deflection": 3e-5,
                           "residual_torque_driven": 3e-5,
                           "shaped_residual_tip_deflection": 4e-5}],
               "trajectory_csv": "planned_trajectory.csv",
               "c_table": {"header": "o_plan.h", "source": "o_plan.c"}}
    report, summary = write_report(tmp_path, study, _summary(planner))
    text = report.read_text()
    section = text[text.index("## Planned move"):text.index("## Closed loop")]
    assert "**12.9 %** shorter" in section
    assert "| planned | 1.9600 | 0.024 | 0.011 | 0.0435 | 0.932 |" in section
    assert "| -10 % | 0.03 | 0.04 |" in section
    # 2.4e-5 against a bound of 2e-5: flagged, with the excess
    assert "exceeds the end bound by 20.0 %" in section
    assert "![planned vs shaped](planned.png)" in section
    assert "planned move 2.00 s" in text
    assert '"planner": {' in summary.read_text()


def test_report_section_names_each_scenarios_bound(tmp_path):
    # a robust plan is bounded in every scenario by the shaped move's residual there
    study = design.load_study(ONELINK)
    planner = {"success": True, "move": "swing", "duration": 1.96, "objective": "time",
               "status": "Solve_Succeeded", "iterations": 23, "intervals": 113,
               "end": "shaped", "end_bound": 2e-5, "end_bounds": [2e-5, 4e-5, 1e-5],
               "verify_dt": 1e-4, "residual_tip_deflection": 1.9e-5,
               "residual_torque_driven": 1.1e-5, "residual_ocp": 2e-5,
               "torque_peak": [0.0435], "velocity_peak": [0.932],
               "shortening": 1 - 1.96 / 2.25, "shaped": SHAPED, "robust": [],
               "trajectory_csv": "planned_trajectory.csv",
               "c_table": {"header": "o_plan.h", "source": "o_plan.c"}}
    text = write_report(tmp_path, study, _summary(planner))[0].read_text()
    section = text[text.index("## Planned move"):text.index("## Closed loop")]
    assert ("residual tip deflection ≤ 0.02 / 0.04 / 0.01 mm at the nominal, −, + "
            "frequency error") in section


def test_report_section_without_a_plan(tmp_path):
    study = design.load_study(ONELINK)
    planner = {"success": False, "move": "swing", "error": "torque limit too low",
               "end": "rest", "shaped": SHAPED}
    text = write_report(tmp_path, study, _summary(planner))[0].read_text()
    assert re.search(r"\*\*The planner found no plan\*\*.*torque limit too low", text)
    assert "planned.png" not in text


def test_no_section_without_planner(tmp_path):
    study = design.load_study(ARM)
    assert "## Planned move" not in write_report(tmp_path, study, _summary(None))[0].read_text()
