"""Table 2 fixtures (problems/fixtures/*.toml) against the dissertation's Tables 3–7.

The TMM columns of Tables 3–7 are the dissertation's own transfer-matrix numbers, computed
with its conventions from (its reading of) Table 2; casflex solves the same beam equations,
so where the fixture geometry is read correctly the two should agree to about the rounding
of Table 2 (observed: Fixture 1 within 2.0 %). The experiment columns are reported and
bounded loosely only (welds, clamping and tip-mass placement are not modeled).
See the header of each fixture file for the interpretation of Table 2.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from casflex.robot import load, loads
from casflex.tmm import natural_frequencies

try:
    from test_tmm import FREQ_RTOL, fe_modes
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests.tmm.test_tmm import FREQ_RTOL, fe_modes

FIXTURES = Path(__file__).resolve().parents[2] / "problems" / "fixtures"

# Tables 3–7 (Hz): experiment and the dissertation's TMM column (ω4 of Table 3 not measured)
TABLES = {
    "fixture1": ([6.22, 14.78, 59.92, math.nan, 87.94], [6.71, 14.44, 64.27, 76.88, 85.76]),
    "fixture1_tipmass": ([2.88, 10.24, 30.80, 52.01, 71.42], [2.72, 11.03, 31.09, 51.63, 77.64]),
    "fixture2": ([6.19, 8.18, 18.74, 19.25, 37.75], [5.96, 8.03, 18.16, 19.28, 37.90]),
    "fixture2_masses": ([5.84, 7.86, 17.47, 18.62, 33.58], [5.50, 7.643, 16.78, 19.09, 33.60]),
    "fixture3": ([2.89, 3.39, 6.63, 13.41, 18.87], [2.66, 3.28, 6.58, 13.34, 18.35]),
}

# Tolerances against the TMM column, from what was observed with the reading documented in
# the files: Fixture 1 agrees within 2.0 % (3 % allowed). With the 0.1323 kg tip mass the
# spread grows to +7.4 % on ω1 (+1.5, +4.8, +1.7, +0.6 % on ω2..ω5): the text says the tip
# masses "were not located precisely at the tip", and Table 2 gives no offset or inertia for
# it, so the mass-sensitive ω1 carries that uncertainty (8 % allowed).
TOLERANCE = {"fixture1": 0.03, "fixture1_tipmass": 0.08}
UNMATCHED = {
    "fixture2": "Table 2's Fixture 2 does not reproduce Table 5: omega_1 = 7.14 Hz vs 5.96 Hz "
                "(TMM) under every reading tried (theta_2 = 0 or pi/6, sections turned, "
                "J = Ip); see problems/fixtures/fixture2.toml",
    "fixture2_masses": "same geometry as fixture2 (Table 6: 6.58 vs 5.50 Hz); see "
                       "problems/fixtures/fixture2.toml",
    "fixture3": "Table 2's Fixture 3 does not reproduce Table 7: 2.08 4.34 7.28 11.03 14.73 Hz "
                "vs 2.66 3.28 6.58 13.34 18.35 Hz under every section orientation tried; see "
                "problems/fixtures/fixture3.toml",
}


def fixture_hz(name, count=5):
    robot = load(FIXTURES / f"{name}.toml")
    return natural_frequencies(robot, [0.0], count=count) / (2 * math.pi)


@pytest.mark.parametrize("name", sorted(TABLES))
def test_fixture_vs_dissertation_tmm(name):
    if name in UNMATCHED:
        pytest.skip(UNMATCHED[name])
    hz = fixture_hz(name)
    tmm = np.array(TABLES[name][1])
    rel = hz / tmm - 1
    print(name, "casflex", hz.round(2), "TMM", tmm, "rel %", (100 * rel).round(1))
    assert np.all(np.abs(rel) < TOLERANCE[name]), rel


@pytest.mark.parametrize("name", ["fixture1", "fixture1_tipmass"])
def test_fixture_vs_experiment_loose(name):
    # report; loose bound: the dissertation's own TMM/FEA differ from these by up to 14 %
    hz = fixture_hz(name)
    exp = np.array(TABLES[name][0])
    rel = hz / exp - 1
    print(name, "casflex", hz.round(2), "experiment", exp, "rel %", (100 * rel).round(1))
    seen = np.isfinite(exp)
    assert np.all(np.abs(rel[seen]) < 0.15), rel


def test_fixture1_thickness_reading():
    # Table 2 prints a = 0.032 / 0.024 m; read literally, Fixture 1 is ten times too stiff
    text = (FIXTURES / "fixture1.toml").read_text()
    literal = text.replace("a = 0.0032 ", "a = 0.032 ").replace("a = 0.0024 ", "a = 0.024 ")
    assert literal != text
    hz = natural_frequencies(loads(literal), [0.0], count=1) / (2 * math.pi)
    assert hz[0] > 5 * TABLES["fixture1"][1][0]
    assert abs(fixture_hz("fixture1", 1)[0] / TABLES["fixture1"][1][0] - 1) < 0.03


@pytest.mark.parametrize("name", sorted(TABLES))
def test_fixture_models_vs_fe(name):
    # whatever the reading, casflex must solve the files correctly: the independent FE
    # (built from the file's numbers) to the error budget of tests/tmm/test_tmm.py
    robot = load(FIXTURES / f"{name}.toml")
    w = natural_frequencies(robot, [0.0], count=5)
    omega_fe, _ = fe_modes(FIXTURES / f"{name}.toml", [0.0], 5)
    np.testing.assert_allclose(w, omega_fe, rtol=FREQ_RTOL)
