"""A robot file written by ``casflex calibrate --out`` is a robot file like any other: it
loads, and a design study naming it validates (the design job itself is not run here;
its steps are tested in tests/design)."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from casflex.cli import main
from casflex.design.study import load_study
from casflex.identification import model_frequencies, parse_parameter_path, with_parameters
from casflex.robot import load

ROBOT = "problems/arm2link_actuated.toml"


@pytest.mark.slow  # a fit and a study load (model checks) on two shared cores
def test_calibrated_robot_file_feeds_a_design_study(tmp_path):
    robot = load(ROBOT)
    E = parse_parameter_path("link2.material.E", robot)
    q = np.array([[0.0, 0.0, a] for a in (0.0, 0.8, 1.6, 2.4)])
    # the "measurements": the same arm with link 2's E at 62 GPa (a pipeline test; the
    # accuracy of the fit is tested against the independent FE in test_updating.py)
    f = model_frequencies(with_parameters(robot, [E], [62e9]), q, 3)
    rows = [",".join(repr(float(v)) for v in (*qi, *fi)) for qi, fi in zip(q, f, strict=True)]
    (tmp_path / "meas.csv").write_text("q1,q2,q3,f1,f2,f3\n" + "\n".join(rows) + "\n")
    (tmp_path / "fit.toml").write_text('[[parameter]]\npath = "link2.material.E"\n'
                                       'min = 30e9\nmax = 120e9\n')
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(["calibrate", ROBOT, "--data", str(tmp_path / "meas.csv"), "--fit",
                       str(tmp_path / "fit.toml"), "--out", str(tmp_path / "cal.toml"),
                       "--processes", "1", "--json"])
    assert status == 0, err.getvalue()
    assert json.loads(out.getvalue())["parameters"]["link2.material.E"] == pytest.approx(
        62e9, rel=1e-6)  # exact data from the same model: the root tolerance is what is left
    cal = load(tmp_path / "cal.toml")
    assert cal.links[-1].material.E == pytest.approx(62e9, rel=1e-6)
    assert cal.n_joints == robot.n_joints

    root = Path.cwd() / "problems"
    study_text = (root / "studies" / "arm2link_move1.toml").read_text(encoding="utf-8")
    study_text = study_text.replace('robot = "../arm2link_actuated.toml"', 'robot = "cal.toml"')
    study_text = study_text.replace('"../moves.toml:move1"',
                                    json.dumps(str(root / "moves.toml") + ":move1"))
    study_text = study_text.replace('"../sensors/arm2link_accel.toml"',
                                    json.dumps(str(root / "sensors" / "arm2link_accel.toml")))
    assert 'robot = "cal.toml"' in study_text
    (tmp_path / "study.toml").write_text(study_text)
    study = load_study(tmp_path / "study.toml")
    assert study.robot_path == tmp_path / "cal.toml"
    assert study.robot.links[-1].material.E == pytest.approx(62e9, rel=1e-6)
