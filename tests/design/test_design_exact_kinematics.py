"""The study key ``model.kinematics = "exact"`` (issue 19): accepted by the design job and
handed to the model; the job simulates the exact model's rows by RK4 (``poly`` needs them
polynomial in δ). Its C does not compile in reasonable time (measured: ``cc -O1`` of the
closed-loop step > 8 min at 3.8 GB), so the study must switch ``codegen.compile`` off. A
whole design run on the exact model costs ~30 min: measured in
benchmarks/README_fidelity.md, not here."""

from __future__ import annotations

import pytest

from casflex import design
from casflex.errors import ProblemFileError

EXACT = ("delta_order = 0", 'delta_order = 1\nkinematics = "exact"')
NO_C = ("compile = true", "compile = false")


def test_exact_kinematics_reach_build_model(model_study, tmp_path, build_kwargs):
    path = model_study(replace=(EXACT, NO_C))
    assert design.load_study(path).model["kinematics"] == "exact"
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["kinematics"] == "exact" and build_kwargs["delta_order"] == 1


def test_exact_kinematics_refuse_compiling_before_heavy_work(model_study, tmp_path,
                                                            build_kwargs):
    with pytest.raises(ProblemFileError) as info:
        design.run_design(model_study(replace=(EXACT,)), tmp_path / "out")
    assert "codegen.compile" in str(info.value) and "codegen.compile = false" in str(info.value)
    assert not build_kwargs
