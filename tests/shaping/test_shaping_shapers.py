"""Tests of casflex.shaping.shapers: closed-form shapers, residual vibration, apply_shaper.

References are independent of the implementation: closed-form band edges of the classic
shapers, a direct simulation of a damped second-order system driven by the impulses, and
numerical differentiation.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from casflex.errors import ProblemFileError
from casflex.shaping import (
    Shaper,
    apply_shaper,
    convolve,
    ei,
    ei_three_hump,
    ei_two_hump,
    residual_vibration,
    residual_vibration_casadi,
    sensitivity_curve,
    zv,
    zvd,
)

HZ = 2.0 * math.pi


def band_around(shaper, omega0, zeta, vtol, lo=0.3, hi=1.7, n=200001):
    """Numerically measured band [ω_lo, ω_hi]/ω0 around ω0 where V <= vtol."""
    nu = np.linspace(lo, hi, n)
    v = residual_vibration(shaper, nu * omega0, zeta)
    ok = v <= vtol + 1e-9
    i0 = int(np.argmin(np.abs(nu - 1.0)))
    assert ok[i0]
    i, j = i0, i0
    while i > 0 and ok[i - 1]:
        i -= 1
    while j < n - 1 and ok[j + 1]:
        j += 1
    return nu[i], nu[j]



# ------------------------------------------------------------------ closed-form shapers
@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.2])
def test_zv_zero_vibration_and_half_damped_period(zeta):
    w0 = 2.0 * HZ
    s = zv(w0, zeta)
    assert residual_vibration(s, w0, zeta) < 1e-12
    assert s.duration == pytest.approx(math.pi / (w0 * math.sqrt(1 - zeta**2)), rel=1e-12)
    assert s.amplitudes.sum() == pytest.approx(1.0)


def test_zvd_band_about_14_percent():
    w0 = 5.0
    lo, hi = band_around(zvd(w0), w0, 0.0, 0.05)
    # cos²(πν/2) <= 0.05  ->  ν in [0.8565, 1.1435]
    assert lo == pytest.approx(1 - 0.1435, abs=2e-3)
    assert hi == pytest.approx(1 + 0.1435, abs=2e-3)


def test_ei_undamped_vtol_at_design_frequency_and_20_percent_band():
    w0 = 3.0 * HZ
    s = ei(w0, 0.0, 0.05)
    assert residual_vibration(s, w0) == pytest.approx(0.05, abs=1e-12)
    assert s.duration == pytest.approx(2 * math.pi / w0, rel=1e-12)
    lo, hi = band_around(s, w0, 0.0, 0.05)
    assert hi - lo == pytest.approx(0.3992, abs=2e-3)
    assert lo == pytest.approx(0.80, abs=3e-3)
    assert hi == pytest.approx(1.20, abs=3e-3)


@pytest.mark.parametrize("zeta", [0.05, 0.15])
def test_ei_damped_hump_at_design_frequency(zeta):
    w0 = 10.0
    s = ei(w0, zeta, 0.05)
    assert np.all(s.amplitudes > 0)
    assert residual_vibration(s, w0, zeta) == pytest.approx(0.05, abs=1e-8)
    # ω0 is a local maximum of V; damping widens the band beyond the undamped ±20 %
    near = residual_vibration(s, w0 * np.array([0.99, 1.01]), zeta)
    assert np.all(near < 0.05)
    lo, hi = band_around(s, w0, zeta, 0.05)
    assert 0.39 < hi - lo < 0.6
    # two exact zeros inside the band
    w, v = sensitivity_curve(s, lo * w0, hi * w0, zeta, 20001)
    assert np.min(v[w < w0]) < 1e-3 and np.min(v[w > w0]) < 1e-3


@pytest.mark.parametrize("zeta", [0.0, 0.1])
def test_multi_hump_shapers_wider_than_ei(zeta):
    w0 = 4.0
    b_ei = band_around(ei(w0, zeta, 0.05), w0, zeta, 0.05)
    s2 = ei_two_hump(w0, zeta, 0.05)
    s3 = ei_three_hump(w0, zeta, 0.05)
    b2 = band_around(s2, w0, zeta, 0.05, 0.2, 1.8)
    b3 = band_around(s3, w0, zeta, 0.05, 0.2, 1.8)
    w_ei, w2, w3 = b_ei[1] - b_ei[0], b2[1] - b2[0], b3[1] - b3[0]
    assert w_ei < w2 < w3
    assert residual_vibration(s2, w0, zeta) < 1e-8  # two-hump: zero at ω0
    assert residual_vibration(s3, w0, zeta) == pytest.approx(0.05, abs=1e-8)
    if zeta == 0.0:
        assert len(s2) == 4 and s2.duration == pytest.approx(1.5 * 2 * math.pi / w0)
        assert len(s3) == 5 and s3.duration == pytest.approx(2.0 * 2 * math.pi / w0)


# ------------------------------------------------------------ residual vibration formula
def simulated_residual_ratio(shaper, omega, zeta):
    """Residual amplitude of x'' + 2ζωx' + ω²x = Σ A_i δ(t - t_i), relative to one impulse.

    Integrates between impulses with solve_ivp (each impulse adds A_i to the velocity),
    then measures the amplitude of the free oscillation after the last impulse over two
    periods, compensating the known exponential envelope e^{-ζω(t - tn)}.
    """

    def rhs(_t, y):
        return [y[1], -(omega**2) * y[0] - 2 * zeta * omega * y[1]]

    y = np.zeros(2)
    times, amps = shaper.times, shaper.amplitudes
    for k, (tk, ak) in enumerate(zip(times, amps, strict=True)):
        y = y + np.array([0.0, ak])
        if k + 1 < len(times) and times[k + 1] > tk:
            sol = solve_ivp(rhs, (tk, times[k + 1]), y, rtol=1e-11, atol=1e-13)
            y = sol.y[:, -1]
    tn = times[-1]
    wd = omega * math.sqrt(1 - zeta**2)
    t_end = tn + 2 * (2 * math.pi / wd)
    tt = np.linspace(tn, t_end, 4001)
    sol = solve_ivp(rhs, (tn, t_end), y, t_eval=tt, rtol=1e-11, atol=1e-13)
    shaped = np.max(np.abs(sol.y[0]) * np.exp(zeta * omega * (tt - tn)))
    # eq. 187 normalises by a single unit impulse given when the residual vibration starts
    # (at tn): its free response e^{-ζωτ} sin(ω_d τ)/ω_d has envelope amplitude 1/ω_d at τ = 0
    single = 1.0 / wd
    return shaped / single


@pytest.mark.parametrize(
    "shaper_fn, omega, zeta",
    [
        (lambda: ei(10.0, 0.0, 0.05), 8.7, 0.0),
        (lambda: ei(10.0, 0.1, 0.05), 12.3, 0.1),
        (lambda: zvd(6.0, 0.2), 7.5, 0.05),
        (lambda: Shaper([0.0, 0.13, 0.4, 0.41], [0.3, 0.2, 0.1, 0.4]), 17.0, 0.3),
        (lambda: convolve(zv(5.0), ei(14.0, 0.0, 0.1)), 3.0, 0.02),
    ],
)
def test_formula_matches_simulated_second_order_system(shaper_fn, omega, zeta):
    s = shaper_fn()
    v_formula = residual_vibration(s, omega, zeta)
    v_sim = simulated_residual_ratio(s, omega, zeta)
    assert v_formula == pytest.approx(v_sim, rel=2e-4, abs=1e-6)


def test_residual_vibration_vectorized_and_casadi():
    s = Shaper([0.0, 0.1, 0.25], [0.3, 0.5, 0.2])
    w = np.array([3.0, 10.0, 25.0])
    v = residual_vibration(s, w, 0.07)
    assert v.shape == (3,)
    for sym in (ca.SX, ca.MX):
        t = sym.sym("t", 3)
        a = sym.sym("a", 3)
        f = ca.Function("f", [t, a], [residual_vibration_casadi(t, a, w, 0.07)])
        got = np.array(f(s.times, s.amplitudes)).ravel()
        np.testing.assert_allclose(got, v, rtol=1e-12)
    v2 = residual_vibration_casadi(s.times, s.amplitudes, w, 0.07, squared=True)
    np.testing.assert_allclose(np.array(v2).ravel(), v**2, rtol=1e-12)


def test_shaper_convolution_merges_and_validates():
    a = Shaper([0.0, 1.0], [0.5, 0.5])
    c = convolve(a, a, a)
    np.testing.assert_allclose(c.times, [0, 1, 2, 3])
    np.testing.assert_allclose(c.amplitudes, [1 / 8, 3 / 8, 3 / 8, 1 / 8])
    assert c.duration == pytest.approx(3.0)
    with pytest.raises(ProblemFileError, match="amplitudes"):
        Shaper([0.0, 1.0], [0.5, 0.6])


# ------------------------------------------------------------------------- apply_shaper
def test_apply_shaper_keeps_derivatives_consistent():
    dt = 1e-3
    t = np.arange(0.0, 1.0 + dt / 2, dt)
    tau = t / t[-1]
    # minimum-jerk rest-to-rest motion of 1 rad, and its derivatives
    q = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    qd = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / t[-1]
    qdd = (60 * tau - 180 * tau**2 + 120 * tau**3) / t[-1] ** 2
    shaper = ei(2 * HZ, 0.0, 0.05)
    q2 = np.column_stack([q, -0.5 * q])
    qd2 = np.column_stack([qd, -0.5 * qd])
    qdd2 = np.column_stack([qdd, -0.5 * qdd])
    tn, qs, qds, qdds = apply_shaper(shaper, t, q2, qd2, qdd2)
    assert tn[-1] >= t[-1] + shaper.duration - 1e-12
    assert qs.shape == (tn.size, 2)
    np.testing.assert_allclose(qs[-1], [1.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(qs[0], [0.0, 0.0], atol=1e-12)
    scale = np.max(np.abs(qds))
    np.testing.assert_allclose(np.gradient(qs, tn, axis=0), qds, atol=2e-3 * scale)
    np.testing.assert_allclose(np.gradient(qds, tn, axis=0), qdds, atol=2e-2 * np.max(qdds))
    # 1-D input and the shaped signal is the weighted sum of shifted copies
    tn1, q1, qd1, qdd1 = apply_shaper(shaper, t, q)
    assert qd1 is None and qdd1 is None and q1.shape == tn1.shape
    k = 200
    expect = sum(
        a * np.interp(tn1[k] - ti, t, q)
        for a, ti in zip(shaper.amplitudes, shaper.times, strict=True)
    )
    assert q1[k] == pytest.approx(expect)
