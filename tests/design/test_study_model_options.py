"""The study keys ``model.shape_rates`` and ``model.foreshortening`` (issue 19): validated,
and handed to build_model (the design job simulates with ``method="poly"``, which takes
both)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from casflex import design
from casflex.errors import ProblemFileError

ROOT = Path(__file__).resolve().parents[2]
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"


def _study(tmp_path, model_lines):
    pdir = tmp_path / "problems"
    (pdir / "studies").mkdir(parents=True)
    (pdir / "sensors").mkdir()
    for name in ("arm2link.toml", "arm2link_actuated.toml", "moves.toml",
                 "sensors/arm2link_accel.toml"):
        shutil.copy(ROOT / "problems" / name, pdir / name)
    text = STUDY.read_text()
    old = "delta_order = 0"
    assert old in text
    path = pdir / "studies" / "study.toml"
    path.write_text(text.replace(old, model_lines))
    return path


@pytest.fixture()
def captured(monkeypatch):
    """build_model's keywords, the job stopped there."""
    import casflex.model

    seen = {}

    def capture(*args, **kwargs):
        seen.update(kwargs)
        raise RuntimeError("stop")

    monkeypatch.setattr(casflex.model, "build_model", capture)
    return seen


def test_shape_rates_reaches_build_model(tmp_path, captured):
    path = _study(tmp_path, "delta_order = 1\nshape_rates = true")
    assert design.load_study(path).model["shape_rates"] is True
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert captured["shape_rates"] is True and captured["delta_order"] == 1


def test_shape_rates_off_by_default(tmp_path, captured):
    path = _study(tmp_path, "delta_order = 0")
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert captured["shape_rates"] is False


@pytest.mark.parametrize("lines, rule", [
    ("delta_order = 0\nshape_rates = true", "needs model.delta_order = 1"),
    ('delta_order = 1\nshape_rates = "yes"', "must be true or false"),
])
def test_bad_shape_rates_fails_before_heavy_work(tmp_path, captured, lines, rule):
    with pytest.raises(ProblemFileError) as info:
        design.run_design(_study(tmp_path, lines), tmp_path / "out")
    assert "model.shape_rates" in str(info.value) and rule in str(info.value)
    assert not captured


@pytest.mark.parametrize("lines, rates", [
    ("delta_order = 1\nforeshortening = true", False),
    ("delta_order = 1\nshape_rates = true\nforeshortening = true", True)])
def test_foreshortening_reaches_build_model(tmp_path, captured, lines, rates):
    path = _study(tmp_path, lines)
    assert design.load_study(path).model["foreshortening"] is True
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert captured["foreshortening"] is True and captured["shape_rates"] is rates
    assert captured["delta_order"] == 1


def test_foreshortening_off_by_default(tmp_path, captured):
    path = _study(tmp_path, "delta_order = 1")
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert captured["foreshortening"] is False


@pytest.mark.parametrize("lines, rule", [
    ("delta_order = 0\nforeshortening = true", "needs model.delta_order = 1"),
    ("delta_order = 1\nforeshortening = 1", "must be true or false"),
])
def test_bad_foreshortening_fails_before_heavy_work(tmp_path, captured, lines, rule):
    with pytest.raises(ProblemFileError) as info:
        design.run_design(_study(tmp_path, lines), tmp_path / "out")
    assert "model.foreshortening" in str(info.value) and rule in str(info.value)
    assert not captured
