"""The plausibility bounds (casflex._validate.BOUNDS) against the handbook values their
reasons name: the real materials and machines at either end must pass, values a decade
beyond them must not. The other tests of the bounds (tests/test_faults.py,
tests/test_bad_input.py) read the limits from BOUNDS itself, so a limit moved by a factor
passes there; these values are written here, from their sources.
"""

from __future__ import annotations

import pytest

from casflex._validate import plausible
from casflex.errors import ModelError

# (quantity, value, what) that must be accepted: handbook values
REAL = [
    ("E", 2.0e5, "a soft silicone elastomer, ~0.2 MPa"),
    ("E", 69e9, "aluminium"),
    ("E", 210e9, "steel"),
    ("E", 1.2e12, "diamond, ~1.05-1.2 TPa"),
    ("G", 79e9, "steel"),
    ("G", 4.8e11, "diamond, ~0.48 TPa"),
    ("rho", 2.0, "silica aerogel, ~2 kg/m^3"),
    ("rho", 2700.0, "aluminium"),
    ("rho", 22590.0, "osmium"),
    ("tip_mass", 2300.0, "the largest industrial robot payload, 2.3 t"),
    ("tip_mass", 0.0, "no payload"),
    ("move_duration", 0.005, "a 5 ms move"),
    ("move_duration", 86400.0, "a day-long move"),
    ("beam_length", 0.002, "a 2 mm flexure"),
    ("noise_acceleration", 250e-6 * 9.80665, "the dissertation's 250 ug accelerometer"),
    ("noise_strain", 3e-7, "the dissertation's strain gauges (R = 9e-14)"),
]

# values a decade beyond the named extremes: refused
OUTSIDE = [("E", 1e4), ("E", 1.5e13), ("rho", 0.1), ("rho", 2.3e5), ("tip_mass", 1e5),
           ("move_duration", 1e-4), ("beam_length", 1e-4)]


@pytest.mark.parametrize("quantity, value, what", REAL)
def test_real_values_are_plausible(quantity, value, what):
    assert plausible(value, quantity, what) == value


@pytest.mark.parametrize("quantity, value", OUTSIDE)
def test_values_a_decade_beyond_are_refused(quantity, value):
    with pytest.raises(ModelError):
        plausible(value, quantity, quantity)
