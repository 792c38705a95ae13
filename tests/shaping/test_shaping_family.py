"""The shaper family: defining conditions, damped forms included, checked with a residual
vibration written here (not casflex's), and the published durations and bands."""

from __future__ import annotations

import math

import numpy as np
import pytest

from casflex.errors import ProblemFileError
from casflex.shaping import (
    UM_ZV_PEAK_FACTOR,
    UM_ZVD_PEAK_FACTOR,
    convolve,
    ei,
    ei_three_hump,
    ei_two_hump,
    mzv,
    sna_zv,
    um_ei,
    um_zv,
    um_zvd,
    zv,
    zvd,
)

HZ = 2.0 * math.pi


def residual(shaper, omega, zeta):
    """|Σ A_i exp((ζω + iω_d) t_i)| exp(-ζω t_n): eq. 187, written independently."""
    omega = np.atleast_1d(np.asarray(omega, float))[:, None]
    t = shaper.times[None, :]
    s = zeta * omega + 1j * omega * math.sqrt(1.0 - zeta**2)
    return np.abs(np.exp(s * t) @ shaper.amplitudes) * np.exp(-zeta * omega[:, 0] * t[0, -1])


def band(shaper, vtol=0.05):
    """Contiguous band around ν = 1 where V <= vtol, as relative frequency offsets."""
    nu = np.linspace(0.2, 1.8, 160001)
    v = residual(shaper, nu * HZ, 0.0)
    i0 = int(np.argmin(np.abs(nu - 1.0)))
    lo = hi = i0
    while lo > 0 and v[lo - 1] <= vtol:
        lo -= 1
    while hi < nu.size - 1 and v[hi + 1] <= vtol:
        hi += 1
    return nu[lo] - 1.0, nu[hi] - 1.0


@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.1, 0.3])
@pytest.mark.parametrize("shaper", [zv, zvd, mzv, um_zv])
def test_zero_vibration_at_the_design_frequency(shaper, zeta):
    s = shaper(7.0, zeta)
    assert abs(s.amplitudes.sum() - 1.0) < 1e-12
    assert residual(s, 7.0, zeta)[0] < 1e-12


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.2])
def test_zvd_and_mzv_have_a_flat_or_shallow_zero(zeta):
    w = 7.0
    eps = 1e-4
    # ZVD: dV/dω = 0 at ω as well (V ~ (Δω)² there)
    s = zvd(w, zeta)
    assert residual(s, w * (1.0 + eps), zeta)[0] < 1e-6
    # MZV: a simple zero (V ~ Δω), less than ZV's slope
    slope_mzv = residual(mzv(w, zeta), w * (1.0 + eps), zeta)[0] / eps
    slope_zv = residual(zv(w, zeta), w * (1.0 + eps), zeta)[0] / eps
    assert slope_mzv < slope_zv


def test_um_zv_is_unity_magnitude_and_its_peak_input_limit():
    for zeta in (0.0, 0.05, 0.2):
        s = um_zv(10.0, zeta)
        assert s.amplitudes.tolist() == [1.0, -1.0, 1.0]
        partial = np.cumsum(s.amplitudes)
        assert partial.min() >= 0.0 and partial.max() <= 1.0  # a step stays within [0, 1]
        assert np.abs(s.amplitudes).sum() == UM_ZV_PEAK_FACTOR
    assert um_zv(10.0).duration == pytest.approx(2.0 * math.pi / 10.0 / 3.0, rel=1e-12)
    with pytest.raises(ProblemFileError, match="zeta"):
        um_zv(10.0, 0.6)


@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_ei_family_conditions(zeta):
    w = 5.0
    for fun, humps in ((ei, 1), (ei_two_hump, 2), (ei_three_hump, 3)):
        s = fun(w, zeta, 0.05)
        grid = np.linspace(0.3 * w, 1.7 * w, 200001)
        v = residual(s, grid, zeta)
        inner = (v[1:-1] >= v[:-2]) & (v[1:-1] >= v[2:]) & (v[1:-1] < 0.5)
        peaks = v[1:-1][inner]
        assert len(peaks) == humps
        np.testing.assert_allclose(peaks, 0.05, atol=1e-6)  # grid resolution of the peak


def test_multi_mode_convolution():
    s = convolve(zv(10.0, 0.02), ei(31.0, 0.05, 0.05), mzv(57.0, 0.0))
    assert residual(s, 10.0, 0.02)[0] < 1e-12
    assert residual(s, 57.0, 0.0)[0] < 1e-12
    assert residual(s, 31.0, 0.05)[0] <= 0.05 + 1e-9
    assert s.duration == pytest.approx(
        zv(10.0, 0.02).duration + ei(31.0, 0.05, 0.05).duration + mzv(57.0).duration)


# published figures (Singhose; the EI family at 5 %): duration in periods, ≤ 5 % band
PUBLISHED = {
    "ZV": (zv, 0.5, None),
    "ZVD": (zvd, 1.0, None),
    "EI": (lambda w: ei(w, 0.0, 0.05), 1.0, (-0.20, 0.20)),
    "EI2": (lambda w: ei_two_hump(w, 0.0, 0.05), 1.5, (-0.35, 0.35)),
    "EI3": (lambda w: ei_three_hump(w, 0.0, 0.05), 2.0, (-0.45, 0.50)),
}


@pytest.mark.parametrize("name", list(PUBLISHED))
def test_published_durations_and_bands(name):
    fun, periods, published_band = PUBLISHED[name]
    s = fun(HZ)
    assert s.duration == pytest.approx(periods, rel=1e-12)
    if published_band is not None:
        lo, hi = band(s)
        # the published bands are read off plots to about 2-3 % of the frequency
        assert lo == pytest.approx(published_band[0], abs=0.035)
        assert hi == pytest.approx(published_band[1], abs=0.03)


@pytest.mark.parametrize("zeta", [0.0, 0.03, 0.1, 0.3])
@pytest.mark.parametrize("n", [0.0, 0.25, 1.0, 3.0])
def test_sna_zv_zero_vibration_specified_negative_and_peak(zeta, n):
    w = 2.5 * HZ
    s = sna_zv(w, zeta, n)
    assert residual(s, w, zeta)[0] < 1e-12  # |A| <= 1 + 2N, times ~1: round-off level
    assert len(s) == (3 if n else 2)
    assert (s.amplitudes[1] if n else 0.0) == pytest.approx(-n, abs=1e-13)
    assert s.amplitudes.sum() == pytest.approx(1.0, abs=1e-14)
    assert np.abs(s.amplitudes).sum() == pytest.approx(1.0 + 2.0 * n, abs=1e-12)
    assert np.all(np.diff(s.times) > 0.0)
    if zeta == 0.0:
        # the shortest: no three-impulse shaper A1, -N, 1+N-A1 (brute force over A1 and
        # the angles, written here) has V(ω) = 0 with a shorter last time
        theta3 = w * s.duration
        for a1 in np.linspace(0.05, 1.0 + n - 0.05, 41):
            a3 = 1.0 + n - a1
            c3 = (n * n - a1 * a1 - a3 * a3) / (2.0 * a1 * a3)  # |A1 + A3 e^{iθ3}| = N
            if -1.0 <= c3 <= 1.0:
                assert math.acos(c3) >= theta3 - 1e-9
    if n == 1.0 and zeta == 0.0:  # damped UM-ZV keeps +1 outer impulses, SNA-ZV does not
        np.testing.assert_allclose(s.times, um_zv(w, zeta).times, rtol=0, atol=1e-9)


def test_sna_zv_endpoints_and_errors():
    w = 3.0 * HZ
    np.testing.assert_allclose(sna_zv(w, 0.1, 0.0).times, zv(w, 0.1).times, atol=1e-15)
    np.testing.assert_allclose(sna_zv(w, 0.1, 0.0).amplitudes, zv(w, 0.1).amplitudes,
                               atol=1e-15)
    with pytest.raises(ProblemFileError, match="negative"):
        sna_zv(w, 0.0, -0.5)


def residual_and_slope(shaper, omega, zeta):
    """G = Σ A_i exp(s t_i) and dG/dω (s = ζω + iω_d, ζ fixed), written independently."""
    t = shaper.times
    rate = complex(zeta, math.sqrt(1.0 - zeta**2))
    e = shaper.amplitudes * np.exp(rate * omega * t)
    return e.sum(), (e * rate * t).sum()


@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.1, 0.3])
def test_um_zvd_conditions_unity_magnitude_and_peak_input(zeta):
    w = 4.0 * HZ
    s = um_zvd(w, zeta)
    g, dg = residual_and_slope(s, w, zeta)
    # terms of size <= exp(ζ ω t_n) <= 4 and (their times) <= 4 t_n: round-off level
    assert abs(g) < 1e-12 and abs(dg) < 1e-12 * s.duration
    assert s.amplitudes.tolist() == [1.0, -1.0, 1.0, -1.0, 1.0]
    partial = np.cumsum(s.amplitudes)
    assert partial.min() >= 0.0 and partial.max() <= 1.0  # a step stays within [0, 1]
    assert np.abs(s.amplitudes).sum() == UM_ZVD_PEAK_FACTOR == 1.0 + 2.0 * 2.0
    assert np.all(np.diff(s.times) > 0.0)
    # flat zero like ZVD: V ~ (Δω)² next to ω
    assert residual(s, w * (1.0 + 1e-4), zeta)[0] < 1e-6


def test_um_zvd_undamped_duration_and_band():
    """Undamped: symmetric about the middle impulse, 2 b with ωa, ωb from the two
    conditions solved here by bisection on b (a from the second equation)."""
    w = HZ
    s = um_zvd(w)
    b_total = s.duration / 2.0 * w
    # 1 - 2 cos a + 2 cos b = 0 gives a; then a sin a - b sin b must vanish: bisection on b
    def mismatch(b):
        a = math.acos((1.0 + 2.0 * math.cos(b)) / 2.0)
        return a * math.sin(a) - b * math.sin(b)
    lo, hi = 2.0, 2.5
    assert mismatch(lo) * mismatch(hi) < 0.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mismatch(lo) * mismatch(mid) > 0.0 else (lo, mid)
    assert b_total == pytest.approx(lo, abs=1e-12)
    np.testing.assert_allclose(s.times + s.times[::-1], s.duration, rtol=0, atol=1e-12)
    # shorter than ZVD (one period) and no narrower a 5 % band than ZV's
    lo5, hi5 = band(s)
    zlo, zhi = band(zv(HZ))
    assert s.duration < zvd(HZ).duration and hi5 - lo5 > zhi - zlo
    with pytest.raises(ProblemFileError, match="zeta"):
        um_zvd(w, 0.35)


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.2])
@pytest.mark.parametrize("vtol", [0.02, 0.05, 0.1])
def test_um_ei_hump_zeros_unity_magnitude_and_peak_input(zeta, vtol):
    """V (eq. 187, written here) = vtol with zero slope at ω, one zero on each side."""
    w = 3.0 * HZ
    s = um_ei(w, zeta, vtol)
    assert s.amplitudes.tolist() == [1.0, -1.0, 1.0, -1.0, 1.0]
    assert np.abs(s.amplitudes).sum() == UM_ZVD_PEAK_FACTOR
    partial = np.cumsum(s.amplitudes)
    assert partial.min() >= 0.0 and partial.max() <= 1.0
    assert residual(s, w, zeta)[0] == pytest.approx(vtol, abs=1e-12)
    # central difference, h = 1e-5 relative: truncation ~h² V''' and round-off ~1e-16/h,
    # both below 1e-9 per unit of relative frequency
    h = 1e-5
    slope = (residual(s, w * (1 + h), zeta)[0] - residual(s, w * (1 - h), zeta)[0]) / (2 * h)
    assert abs(slope) < 1e-8
    nu = np.linspace(0.5, 1.5, 20001)
    v = residual(s, nu * w, zeta)
    i = np.arange(1, nu.size - 1)
    minima = i[(v[i] <= v[i - 1]) & (v[i] <= v[i + 1]) & (v[i] < 1e-2)]
    for side in (nu[minima] < 1.0, nu[minima] > 1.0):
        k = minima[side][np.argmin(np.abs(nu[minima][side] - 1.0))]
        x = nu[k] * w
        for _ in range(8):  # Gauss-Newton on the complex G: a zero of both parts
            g, dg = residual_and_slope(s, x, zeta)
            x -= (np.conj(dg) * g).real / abs(dg) ** 2
        assert residual(s, x, zeta)[0] < 1e-9
