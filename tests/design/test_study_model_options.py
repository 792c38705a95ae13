"""The study keys ``model.shape_rates`` and ``model.foreshortening`` (issue 19): validated,
and handed to build_model (the design job simulates with ``method="poly"``, which takes
both)."""

from __future__ import annotations

import pytest

from casflex import design
from casflex.errors import ProblemFileError


def test_shape_rates_reaches_build_model(model_study, tmp_path, build_kwargs):
    path = model_study(replace=(("delta_order = 0", "delta_order = 1\nshape_rates = true"),))
    assert design.load_study(path).model["shape_rates"] is True
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["shape_rates"] is True and build_kwargs["delta_order"] == 1


def test_shape_rates_off_by_default(model_study, tmp_path, build_kwargs):
    path = model_study(replace=(("delta_order = 0", "delta_order = 0"),))
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["shape_rates"] is False


@pytest.mark.parametrize("lines, rule", [
    ("delta_order = 0\nshape_rates = true", "needs model.delta_order = 1"),
    ('delta_order = 1\nshape_rates = "yes"', "must be true or false"),
])
def test_bad_shape_rates_fails_before_heavy_work(model_study, tmp_path, build_kwargs, lines, rule):
    with pytest.raises(ProblemFileError) as info:
        design.run_design(model_study(replace=(("delta_order = 0", lines),)), tmp_path / "out")
    assert "model.shape_rates" in str(info.value) and rule in str(info.value)
    assert not build_kwargs


@pytest.mark.parametrize("lines, rates", [
    ("delta_order = 1\nforeshortening = true", False),
    ("delta_order = 1\nshape_rates = true\nforeshortening = true", True)])
def test_foreshortening_reaches_build_model(model_study, tmp_path, build_kwargs, lines, rates):
    path = model_study(replace=(("delta_order = 0", lines),))
    assert design.load_study(path).model["foreshortening"] is True
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["foreshortening"] is True and build_kwargs["shape_rates"] is rates
    assert build_kwargs["delta_order"] == 1


def test_foreshortening_off_by_default(model_study, tmp_path, build_kwargs):
    path = model_study(replace=(("delta_order = 0", "delta_order = 1"),))
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["foreshortening"] is False


@pytest.mark.parametrize("lines, rule", [
    ("delta_order = 0\nforeshortening = true", "needs model.delta_order = 1"),
    ("delta_order = 1\nforeshortening = 1", "must be true or false"),
])
def test_bad_foreshortening_fails_before_heavy_work(model_study, tmp_path, build_kwargs, lines,
                                                    rule):
    with pytest.raises(ProblemFileError) as info:
        design.run_design(model_study(replace=(("delta_order = 0", lines),)), tmp_path / "out")
    assert "model.foreshortening" in str(info.value) and rule in str(info.value)
    assert not build_kwargs


@pytest.mark.parametrize("lines, rule", [
    ('delta_order = 1\nkinematics = "nonlinear"', "must be one of"),
    ('delta_order = 0\nkinematics = "exact"', "needs model.delta_order = 1"),
])
def test_kinematics_checked_before_heavy_work(model_study, tmp_path, build_kwargs, lines, rule):
    with pytest.raises(ProblemFileError) as info:
        design.run_design(model_study(replace=(("delta_order = 0", lines),)), tmp_path / "out")
    assert "model.kinematics" in str(info.value) and rule in str(info.value)
    assert not build_kwargs


def test_kinematics_truncated_by_default(model_study, tmp_path, build_kwargs):
    path = model_study(replace=(("delta_order = 0", "delta_order = 1"),))
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["kinematics"] == "truncated"
