"""tabulate_plant evaluates the exact rows a chunk of grid points at a time: the same
coefficients, bit for bit, whatever the chunk, and numpy memory bounded by the chunk."""

import tracemalloc

import numpy as np
import pytest

import casflex.estimation.plant as plant_module
from casflex.estimation import tabulate_plant


@pytest.mark.slow
def test_chunks_change_nothing_and_bound_the_memory(arm_model, monkeypatch):
    model, _ = arm_model(1, 30.0, gravity=None)
    # the differences' designs (55 Δ designs per point) are what grew: measured with them
    whole = tabulate_plant(model, cache_dir=False, check=False,
                           derivatives="differences")  # one chunk: every column
    evaluations = whole.info["evaluations"]
    per_point = evaluations // whole.table.values["coef"][..., 0].size
    assert per_point < plant_module.CHUNK_EVALUATIONS  # the whole grid fits one chunk above
    # one grid point per chunk: each coefficient is computed from the same columns with the
    # same arithmetic, so the table is identical, not merely close
    monkeypatch.setattr(plant_module, "CHUNK_EVALUATIONS", per_point)
    tracemalloc.start()
    try:
        chunked = tabulate_plant(model, cache_dir=False, check=False,
                                 derivatives="differences")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(chunked.table.values["coef"], whole.table.values["coef"])
    np.testing.assert_array_equal(chunked.pattern, whole.pattern)
    # the design matrices of all columns at once (q, q̇, q̈ and Δ: 3n + 2m floats each)
    # were what grew without bound; with one grid point per chunk numpy holds a small
    # fraction of them (the 12-point grid: about 1/12 plus the coefficient table)
    all_designs = evaluations * (3 * model.n + 2 * model.m) * 8
    assert peak < all_designs / 3, (peak, all_designs)


@pytest.mark.slow
def test_exact_derivatives_chunks_change_nothing(arm_model, monkeypatch):
    """The exact-derivative path (one evaluation per design) chunked per grid point gives
    the same table bit for bit."""
    model, _ = arm_model(1, 30.0, gravity=None)
    whole = tabulate_plant(model, cache_dir=False, check=False)
    per_point = whole.info["evaluations"] // whole.table.values["coef"][..., 0].size
    monkeypatch.setattr(plant_module, "CHUNK_EVALUATIONS", per_point)
    chunked = tabulate_plant(model, cache_dir=False, check=False)
    np.testing.assert_array_equal(chunked.table.values["coef"], whole.table.values["coef"])
    np.testing.assert_array_equal(chunked.pattern, whole.pattern)
