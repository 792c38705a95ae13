"""The study key ``model.kinematics = "exact"`` (issue 19): accepted by the design job and
handed to the model; the job simulates the exact model's rows by RK4 (``poly`` needs them
polynomial in δ). A whole design run on the exact model costs minutes: its cost is
measured in benchmarks/README_fidelity.md, not here."""

from __future__ import annotations

import pytest

from casflex import design


def test_exact_kinematics_reach_build_model(model_study, tmp_path, build_kwargs):
    path = model_study(replace=(("delta_order = 0",
                                 'delta_order = 1\nkinematics = "exact"'),))
    assert design.load_study(path).model["kinematics"] == "exact"
    with pytest.raises(RuntimeError, match="stop"):
        design.run_design(path, tmp_path / "out")
    assert build_kwargs["kinematics"] == "exact" and build_kwargs["delta_order"] == 1
