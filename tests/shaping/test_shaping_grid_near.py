"""Digital shapers from the neighbourhood of the analogue one (grid_near) against the
whole-grid LP optimum (grid_optimum) and this module's own residual-vibration check."""

import numpy as np
import pytest

from casflex.shaping import FrequencyRange, grid_near, grid_optimum, si_shaper

CASES = [  # (omega_min, omega_max) rad/s, vtol, grid step s
    ((9.0, 11.0), 0.05, 1e-2),
    ((20.0, 30.0), 0.05, 2e-3),
    ((50.0, 70.0), 0.10, 1e-3),
]


def own_vibration(times, amplitudes, omega):
    """Undamped residual vibration |Σ A_k exp(iωt_k)| written here, not casflex's."""
    return np.abs(np.exp(1j * np.outer(omega, times)) @ amplitudes)


@pytest.mark.parametrize(("band", "vtol", "step"), CASES)
def test_grid_near_is_within_a_sample_of_the_grid_optimum(band, vtol, step):
    analogue = si_shaper([FrequencyRange(*band, 0.0, vtol)]).shaper
    omega = np.linspace(*band, 61)
    near = grid_near(analogue, omega, np.zeros_like(omega), np.full_like(omega, vtol),
                     step=step)
    best = grid_optimum(omega, np.zeros_like(omega), np.full_like(omega, vtol), step=step,
                        horizon=analogue.duration)
    t = np.asarray(near.shaper.times)
    np.testing.assert_allclose(t / step, np.round(t / step), atol=1e-9)
    # the neighbourhood is part of the whole grid, so never shorter than its optimum, and
    # costs at most one sample over it
    assert best.duration - 1e-12 <= near.duration <= best.duration + step + 1e-12
    # the LP meets the samples to a relative 1e-5 (its cutting-plane stop)
    assert own_vibration(t, near.shaper.amplitudes, omega).max() <= vtol * (1 + 1e-5)
