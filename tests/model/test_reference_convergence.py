"""The ANCF reference of the fidelity tests: converged in elements and time step, and its
committed runs (tests/reference_runs/) current and reproducible.

The reference runs the tests compare against are committed as data keyed by a hash of
the reference's source and the run's parameters (``tests/fidelity_cases.py``,
:func:`reference_key`): a test here fails when a run is missing or stale, and a slow one
recomputes a run from scratch and compares it with the stored one, so that the stored
data cannot go stale or wrong silently.
"""

from __future__ import annotations

import numpy as np
import pytest
from fidelity_cases import (
    CONVERGENCE_MOVE,
    compute_reference_run,
    on_grid,
    reference_run,
    stale_stored_runs,
)


def test_stored_reference_runs_are_current():
    """Every run of STORED_RUNS is stored under its current key, and nothing else is."""
    missing, stale = stale_stored_runs()
    assert not missing and not stale, (
        f"tests/reference_runs/ is out of date (missing {missing}, stale {stale}): "
        "run python tests/fidelity_cases.py and commit tests/reference_runs/")


@pytest.mark.slow
def test_stored_reference_run_reproduces():
    """A run recomputed from scratch equals the stored one (the cheapest full-resolution
    run: 16 elements, 1 ms, 2 s).

    Tolerance 1e-6 of the peak: a different machine or BLAS changes the run by round-off
    only (Newton is iterated to 1e-6 relative with the exact tangent, so the converged
    steps differ at the round-off level); a changed reference or run differs by far more
    than that (the fidelity budgets are 0.5–5 % of the peak).
    """
    stored = reference_run(CONVERGENCE_MOVE, 16, 1e-3)
    fresh = compute_reference_run(CONVERGENCE_MOVE, 16, 1e-3)
    np.testing.assert_array_equal(stored["t"], fresh["t"])
    peak = np.linalg.norm(fresh["d"], axis=1).max()
    assert np.abs(stored["d"] - fresh["d"]).max() <= 1e-6 * peak


def test_reference_converged_in_elements_and_step(ref_cache):
    """16 vs 32 elements per link and 1 ms vs 0.5 ms give the same tip deflection history
    within 0.5 % of its peak (the budget the fidelity targets leave to the reference)."""
    base = reference_run(CONVERGENCE_MOVE, 16, 1e-3, ref_cache)
    fine = reference_run(CONVERGENCE_MOVE, 32, 1e-3, ref_cache)
    short = reference_run(CONVERGENCE_MOVE, 16, 5e-4, ref_cache)
    peak = np.linalg.norm(base["d"], axis=1).max()
    for other in (fine, short):
        gap = np.linalg.norm(on_grid(other, base["t"]) - base["d"], axis=1).max()
        assert gap < 5e-3 * peak
