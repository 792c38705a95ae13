"""A design job whose sampled loop with the EKF diverges reports it (issue 21): the
report, summary.json and the CLI say where and in which quantity, instead of failing.

The study: the bare Table 8 arm (no motor inertias) under the composite law at a 2 ms
sample time. Its residual joint inertia is tiny (~2e-5 kg m², problems/studies/
arm2link_move1.toml), so the fast gains put the joint poles far beyond what a 500 Hz
loop can hold: the sampled loop diverges (measured 2026-12-02).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from casflex.cli import main

ROOT = Path(__file__).resolve().parents[2]
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"


def _study(tmp_path):
    pdir = tmp_path / "problems"
    (pdir / "studies").mkdir(parents=True)
    (pdir / "sensors").mkdir()
    for name in ("arm2link.toml", "moves.toml", "sensors/arm2link_accel.toml"):
        shutil.copy(ROOT / "problems" / name, pdir / name)
    text = STUDY.read_text()
    for old, new in (('robot = "../arm2link_actuated.toml"', 'robot = "../arm2link.toml"'),
                     ("modes = 3 ", "modes = 1 "), ("grid_step = 3.0", "grid_step = 30.0"),
                     ("dt = 0.001", "dt = 0.002"), ("settle = 3.0", "settle = 0.5"),
                     ("compile = true", "compile = false")):
        assert old in text
        text = text.replace(old, new)
    path = pdir / "studies" / "study.toml"
    path.write_text(text)
    return path


@pytest.mark.slow
def test_diverging_loop_is_reported_not_raised(tmp_path, capsys):
    out = tmp_path / "out"
    status = main(["design", str(_study(tmp_path)), "--out", str(out), "--cache-dir",
                   str(tmp_path / "cache"), "--processes", "1", "--json"])
    captured = capsys.readouterr()
    assert status == 0  # the job ran to its end: the verdict is in the report
    s = json.loads(captured.out)
    assert s["status"] == "closed loop diverged"
    assert s["stable"] is False and s["closed_loop_finite"] is False
    d = s["closed_loop_divergence"]
    t_end = s["shaper_duration"] + 2.0 + 0.5  # the shaped move and the settling time
    assert d["time"] is not None and 0.0 <= d["time"] <= t_end
    assert re.fullmatch(r"(q|delta|dq|ddelta)\[\d+\]|tip_deflection", d["quantity"])
    assert f"diverged at t = {d['time']:.6g} s" in d["message"]
    # no number is made up for a loop that has none
    assert s["tracking"]["worst_joint"] is None and s["tracking_error_max"] is None
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["closed_loop_divergence"] == d
    report = (out / "report.md").read_text()
    assert f"closed loop with the EKF diverged at t = {d['time']:.4g} s ({d['quantity']})" \
        in report
    assert f"the closed loop with the EKF DIVERGED at t = {d['time']:.4g} s" in captured.err
