"""The ANCF reference of the fidelity tests is converged in elements and time step.

Its own module so that, with the suite's two workers taking whole files, this long test
(two fine reference runs, minutes) runs beside the fidelity targets instead of after them.
"""

from __future__ import annotations

import numpy as np
import pytest
from fidelity_cases import PlanarMove, on_grid, reference_run

CONVERGENCE_MOVE = PlanarMove("elbow2_1s_short", -0.8, 1.2, 1.0, settle=1.0)


@pytest.mark.slow
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
