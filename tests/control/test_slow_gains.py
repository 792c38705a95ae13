"""Slow tracking gains from the move's lowest natural frequency (casflex.control.gains)."""

from __future__ import annotations

import numpy as np
import pytest

from casflex.control import dissertation_gains, slow_gains_for_move
from casflex.errors import CasflexError


@pytest.mark.parametrize("fraction, damping", [(0.3, 1.0), (0.7, 1.0), (0.5, 0.7)])
def test_the_error_loop_has_the_stated_bandwidth(fraction, damping):
    """Independent check: the roots of s² + Kd s + Kp (the joint-error loop ë + Kd ė + Kp e
    = 0) have modulus ω_c = fraction ω_min and damping ζ = −Re/|s|."""
    omega_min = 6.614
    g = slow_gains_for_move(omega_min, 3.2, fraction=fraction, damping=damping)
    roots = np.roots([1.0, g.Kd, g.Kp])
    # rel 1e-6: np.roots of the double root at ζ = 1 is accurate to ~√eps
    assert np.abs(roots) == pytest.approx([fraction * omega_min] * 2, rel=1e-6)
    assert -roots.real / np.abs(roots) == pytest.approx([damping] * 2, rel=1e-6)
    assert g.separation == pytest.approx(1 / fraction) and g.source == "move"
    assert g.move_frequency == pytest.approx(2 * np.pi / 3.2)


def test_dissertation_gains_are_one_and_two():
    g = dissertation_gains(6.614, 3.2)
    assert (g.Kp, g.Kd, g.bandwidth, g.damping) == (1.0, 2.0, 1.0, 1.0)
    assert g.separation == pytest.approx(6.614)


@pytest.mark.parametrize("kwargs", [{"fraction": 0.0}, {"fraction": 1.0}, {"damping": -1}])
def test_bad_arguments_are_refused(kwargs):
    with pytest.raises(CasflexError):
        slow_gains_for_move(6.6, 3.2, **kwargs)
