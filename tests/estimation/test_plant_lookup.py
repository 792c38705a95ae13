"""The EKF plant's spline table evaluated locally (FlexiblePlant.lookup = "local", the
default) gives the coefficients of CasADi's B-spline interpolant ("interpolant") to
rounding, and its generated C has no generic de Boor routine for it."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from casflex.estimation import tabulate_plant

# CasADi fits its interpolating B-spline by iterative least squares (grid values missed by
# up to ~3e-14 relative, measured), the local form by a direct solve; each coefficient is
# a sum of ~10 such spline values times Fourier terms and monomials of size ≤ 4 here:
# 1e-12 of the largest coefficient is ~10x that budget.
RTOL = 1e-12


@pytest.mark.slow  # a plant tabulation (~5 s on a quiet machine)
def test_local_plant_table_equals_the_interpolant(arm_model, model_cache):
    model, _ = arm_model(2, step_deg=15, gravity=None)
    plant = tabulate_plant(model, cache_dir=model_cache)
    assert plant.lookup == "local" and plant.shape_joints == (2,)
    local = plant.function()
    interp = dataclasses.replace(plant, lookup="interpolant").function()
    rng = np.random.default_rng(5)
    grid = np.asarray(plant.table.grid[0])
    qs = np.r_[rng.uniform(-4.0, 4.0, 20), grid[::3]]  # wrapped, and on the knots
    for q3 in qs:
        u = np.r_[rng.uniform(-np.pi, np.pi, 2), q3, rng.normal(size=3), rng.normal(size=3)]
        for a, b in zip(local(u), interp(u), strict=True):
            a, b = np.array(a), np.array(b)
            assert np.max(np.abs(a - b)) <= RTOL * max(np.max(np.abs(b)), 1e-300)
    cg = ca.CodeGenerator("plant.c")
    cg.add(local)
    code = cg.dump()
    assert "nd_boor_eval" not in code and "coef_local" in code
