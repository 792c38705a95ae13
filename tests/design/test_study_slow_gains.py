"""The study keys of the slow tracking gains (controller.slow_gains and friends)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from casflex.design import load_study
from casflex.errors import ProblemFileError

ROOT = Path(__file__).resolve().parents[2]
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"


def _study(tmp_path, old, new):
    pdir = tmp_path / "problems"
    (pdir / "studies").mkdir(parents=True)
    (pdir / "sensors").mkdir()
    for name in ("arm2link.toml", "arm2link_actuated.toml", "moves.toml",
                 "sensors/arm2link_accel.toml"):
        shutil.copy(ROOT / "problems" / name, pdir / name)
    text = STUDY.read_text()
    assert old in text
    path = pdir / "studies" / "s.toml"
    path.write_text(text.replace(old, new))
    return path


def test_bundled_study_chooses_gains_from_the_move():
    c = load_study(STUDY).controller
    assert c["slow_gains"] == "move" and c["bandwidth_fraction"] == 0.7
    assert c["Kp"] is None and c["Kd"] is None


def test_dissertation_gains_option(tmp_path):
    c = load_study(_study(tmp_path, 'slow_gains = "move"', 'slow_gains = "dissertation"'))
    assert (c.controller["Kp"], c.controller["Kd"]) == (1.0, 2.0)


def test_given_gains(tmp_path):
    c = load_study(_study(tmp_path, 'slow_gains = "move"',
                          'slow_gains = "given"\nKp = 9.0\nKd = 6.0'))
    assert (c.controller["Kp"], c.controller["Kd"]) == (9.0, 6.0)


@pytest.mark.parametrize("new, field, rule", [
    ('slow_gains = "given"', "controller.Kp", "is required"),
    ('slow_gains = "move"\nKp = 4.0', "controller.Kp", "only with slow_gains = 'given'"),
    ('slow_gains = "fast"', "controller.slow_gains", "must be one of"),
])
def test_bad_slow_gain_keys(tmp_path, new, field, rule):
    with pytest.raises(ProblemFileError) as info:
        load_study(_study(tmp_path, 'slow_gains = "move"', new))
    assert field in str(info.value) and rule in str(info.value)


def test_bandwidth_fraction_below_one(tmp_path):
    with pytest.raises(ProblemFileError) as info:
        load_study(_study(tmp_path, "bandwidth_fraction = 0.7", "bandwidth_fraction = 1.2"))
    assert "controller.bandwidth_fraction" in str(info.value)
