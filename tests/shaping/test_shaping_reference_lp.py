"""SI shapers against an independent reference: impulses on a fine time grid, one LP per
duration (scipy's HiGHS), bisection on the duration (issue 14).

Everything the reference needs is written here and shares no code with casflex: the
residual vibration at the same instant (the vibration left after the last impulse divided
by the unshaped response at that time, |Σ A_k exp((ζω + iω_d) t_k)|), the LP and the
dense evaluation that checks casflex's shapers.

Reference LP. With the times fixed on ``t_k = k h`` the constraint |z_s| <= vtol at a
sample frequency is a disc in the complex plane; the reference replaces the disc by the
regular 24-gon *inscribed* in it (|z| <= vtol guaranteed, at most 0.86 % conservative in
vtol), on about ten samples per oscillation of V(ω). Its optimum is therefore an upper
estimate of the grid optimum (by a fraction of a percent in duration); casflex (free
impulse times, the exact disc) must not be longer than it by more than 1 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog

from casflex.shaping import FrequencyRange, si_shaper

HZ = 2.0 * math.pi
POLYGON = 24
REFERENCE_STEPS = 300  # grid steps up to casflex's duration (0.33 % resolution)


def vibration_left(times, amplitudes, omega, zeta):
    """|Σ A_k exp((ζω + iω_d) t_k)| on an array of ω: vibration at the same instant."""
    omega = np.asarray(omega, float)[:, None]
    s = zeta * omega + 1j * omega * math.sqrt(1.0 - zeta**2)
    return np.abs(np.exp(s * np.asarray(times)[None, :]) @ np.asarray(amplitudes))


def dense_max(times, amplitudes, lo, hi, zeta, n=40001):
    return float(vibration_left(times, amplitudes, np.linspace(lo, hi, n), zeta).max())


def reference_rows(problem, times, horizon):
    """Rows A x <= 1 of the inscribed polygons on every sample of every range."""
    rows = []
    angles = 2.0 * math.pi * np.arange(POLYGON) / POLYGON
    for lo, hi, zeta, vtol in problem:
        n = max(6, math.ceil(10.0 * (hi - lo) * horizon / (2.0 * math.pi)) + 1)
        omega = np.linspace(lo, hi, n)[:, None]
        z = np.exp((zeta * omega + 1j * omega * math.sqrt(1.0 - zeta**2)) * times[None, :])
        for th in angles:
            rows.append((np.cos(th) * z.real + np.sin(th) * z.imag)
                        / (vtol * math.cos(math.pi / POLYGON)))
    return np.vstack(rows)


def reference_duration(problem, duration_hint):
    """Shortest grid shaper (step duration_hint / 300) meeting the inscribed polygons."""
    h = duration_hint / REFERENCE_STEPS
    k_max = 2 * REFERENCE_STEPS
    times = h * np.arange(k_max + 1)
    rows = reference_rows(problem, times, k_max * h)

    def feasible(k):
        res = linprog(np.zeros(k + 1), A_ub=rows[:, : k + 1], b_ub=np.ones(rows.shape[0]),
                      A_eq=np.ones((1, k + 1)), b_eq=[1.0], bounds=(0.0, None),
                      method="highs")
        return res.status == 0

    assert feasible(k_max), "the reference found no grid shaper within twice casflex's"
    lo, hi = 0, k_max
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if feasible(mid):
            hi = mid
        else:
            lo = mid
    return hi * h


def random_problem(rng):
    problem = []
    for _ in range(int(rng.integers(1, 4))):
        centre = HZ * rng.uniform(1.0, 30.0)
        width = rng.uniform(0.05, 0.60)
        problem.append((centre * (1.0 - width / 2.0), centre * (1.0 + width / 2.0),
                        float(rng.uniform(0.0, 0.05)), float(rng.uniform(0.02, 0.20))))
    return problem


RANDOM = [random_problem(np.random.default_rng(1400 + i)) for i in range(30)]
ISSUE_RANGE = (137.13, 162.60)
SWEEP = [0.0, 0.005, 0.01, 0.015, 0.02, 0.025, 0.02814, 0.03, 0.035, 0.04, 0.045, 0.05]
FAST_SWEEP = [0.005, 0.02814]  # the issue's failures


def check_against_reference(problem):
    ranges = [FrequencyRange(*p) for p in problem]
    # must not fail; no time limit: these tests judge the result, the benchmark the speed
    # (the shared test machine can be many times slower than an idle one)
    res = si_shaper(ranges, time_limit=None)
    t, a = res.shaper.times, res.shaper.amplitudes
    assert np.all(a >= 0.0) and abs(a.sum() - 1.0) < 1e-12
    for (lo, hi, zeta, vtol), reported in zip(problem, res.max_prv, strict=True):
        # "verified" means V <= vtol, with no slack, by this module's own evaluation
        assert dense_max(t, a, lo, hi, zeta) <= vtol
        assert reported <= vtol
    ref = reference_duration(problem, res.duration)
    # 1 %: the issue's bound on casflex against the grid optimum
    assert res.duration <= 1.01 * ref, (res.duration, ref)
    return res, ref


@pytest.mark.parametrize("zeta", FAST_SWEEP)
def test_issue_damped_range(zeta):
    res, ref = check_against_reference([(*ISSUE_RANGE, zeta, 0.0567)])
    assert res.duration < 0.04  # not the 2.59 s or 0.079 s of the issue


@pytest.mark.slow
@pytest.mark.parametrize("zeta", [z for z in SWEEP if z not in FAST_SWEEP])
def test_issue_damping_sweep(zeta):
    check_against_reference([(*ISSUE_RANGE, zeta, 0.0567)])


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(RANDOM)))
def test_random_problems(index):
    check_against_reference(RANDOM[index])


def test_reference_finds_the_zv_shaper():
    """The reference itself: one frequency, tiny vtol -> half a period (ZV)."""
    omega = 10.0
    ref = reference_duration([(omega, omega, 0.0, 1e-3)], math.pi / omega)
    assert ref == pytest.approx(math.pi / omega, rel=2.0 / REFERENCE_STEPS)
