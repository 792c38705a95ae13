"""The fitted damped EI family meets its defining conditions and equals the exact solve.

The reference is this module's own residual-vibration evaluation (eq. 187 in normalised
frequency ν = ω/ω0 and time τ = ω0 t, with its analytic ν-derivative) and its own search
for the humps and zeros of V: nothing of casflex's V code is used.
"""

import math

import numpy as np
import pytest
from scipy import optimize

from casflex.errors import ProblemFileError
from casflex.shaping import ei, ei_three_hump, ei_two_hump
from casflex.shaping.ei_family import EI_FIT_BOXES, ei_family_normalised

# (humps between the outermost zeros, zeros) of each kind in 0 < ν < 2, ν = 1 included
FEATURES = {"ei": (1, 2), "ei2": (2, 3), "ei3": (3, 4)}
RNG = np.random.default_rng(20261202)
# random (ζ, vtol) inside each kind's fitted box, its corners' neighbourhood included
CASES = [(kind, float(v), float(z)) for kind, (zmax, vmin, vmax) in sorted(EI_FIT_BOXES.items())
         for z, v in zip(RNG.uniform(0.0, zmax, 6), RNG.uniform(vmin, vmax, 6), strict=True)]


def residual(tau, amp, nu, zeta):
    """Complex residual G(ν) (|G| = V of eq. 187) and dG/dν, written out independently."""
    s = math.sqrt(1.0 - zeta**2)
    rate = zeta * (tau - tau[-1]) + 1j * s * tau
    terms = amp * np.exp(np.multiply.outer(nu, rate))
    return terms.sum(axis=-1), (terms * rate).sum(axis=-1)


def v_and_slope(tau, amp, nu, zeta):
    """V(ν) and dV/dν."""
    g, dg = residual(tau, amp, nu, zeta)
    v = np.abs(g)
    return v, (np.conj(g) * dg).real / np.maximum(v, 1e-300)


def features(tau, amp, zeta):
    """Refined zeros of V in 0.05 < ν < 1.95 and the humps between the outermost two."""
    nu = np.linspace(0.05, 1.95, 38001)
    v, _ = v_and_slope(tau, amp, nu, zeta)
    i = np.arange(1, nu.size - 1)
    # on this grid (step 5e-5) V is below 1e-3 next to a zero and far above it elsewhere
    minima = i[(v[i] <= v[i - 1]) & (v[i] <= v[i + 1]) & (v[i] < 1e-3)]
    maxima = i[(v[i] >= v[i - 1]) & (v[i] >= v[i + 1])]
    maxima = maxima[(maxima > minima.min()) & (maxima < minima.max())] if minima.size else []

    def slope(x):
        return float(v_and_slope(tau, amp, x, zeta)[1])

    humps = [optimize.brentq(slope, nu[k - 1], nu[k + 1], xtol=1e-15) for k in maxima]
    zeros = []
    for k in minima:
        # Gauss-Newton on the complex G: quadratic convergence to a zero of both parts
        x = nu[k]
        for _ in range(8):
            g, dg = residual(tau, amp, x, zeta)
            x -= (np.conj(dg) * g).real / abs(dg) ** 2
        zeros.append(float(x))
    return humps, zeros


@pytest.mark.parametrize("kind, vtol, zeta", CASES)
def test_fit_meets_the_defining_conditions_and_equals_the_solve(kind, vtol, zeta):
    tau, amp = ei_family_normalised(kind, zeta, vtol, method="fit")
    tau_x, amp_x = ei_family_normalised(kind, zeta, vtol, method="solve")
    # the generator checked the fit to 1e-10 between its nodes (tools/gen_ei_fit.py)
    np.testing.assert_allclose(tau, tau_x, rtol=0.0, atol=1e-10)
    np.testing.assert_allclose(amp, amp_x, rtol=0.0, atol=1e-10)
    assert abs(amp.sum() - 1.0) < 1e-14 and np.all(amp > 0.0) and np.all(np.diff(tau) > 0)
    humps, zeros = features(tau, amp, zeta)
    assert (len(humps), len(zeros)) == FEATURES[kind]
    # the design frequency is a hump (EI, three-hump) or a zero (two-hump)
    at_one = humps if kind != "ei2" else zeros
    assert min(abs(x - 1.0) for x in at_one) < 1e-6
    v1, s1 = v_and_slope(tau, amp, 1.0, zeta)
    if kind == "ei2":
        assert v1 < 1e-9
    else:
        assert abs(v1 - vtol) < 1e-9 and abs(s1) < 1e-9
    for x in humps:  # V = vtol where its slope vanishes (conditions to 1e-9)
        assert abs(v_and_slope(tau, amp, x, zeta)[0] - vtol) < 1e-9
    for x in zeros:
        assert v_and_slope(tau, amp, x, zeta)[0] < 1e-9


def test_the_boxes_are_the_documented_ones():
    # the ranges stated in the docs (where the exact solve stays on one smooth branch)
    assert EI_FIT_BOXES == {"ei": (0.2, 0.01, 0.2), "ei2": (0.1, 0.01, 0.2),
                            "ei3": (0.12, 0.01, 0.1)}


def test_public_shapers_use_the_fit_and_fall_back_to_the_solve():
    w = 2 * math.pi * 3.0
    for fn, kind in ((ei, "ei"), (ei_two_hump, "ei2"), (ei_three_hump, "ei3")):
        s = fn(w, 0.07, 0.05)
        tau, amp = ei_family_normalised(kind, 0.07, 0.05, method="fit")
        np.testing.assert_allclose(s.times * w, tau, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(s.amplitudes, amp, rtol=1e-14, atol=1e-15)
    # outside the box "auto" is the exact solve and "fit" refuses, naming the box
    zmax, vmin, vmax = EI_FIT_BOXES["ei"]
    for zeta, vtol in ((zmax + 0.02, 0.05), (0.07, vmax + 0.05), (0.07, vmin / 2)):
        got = ei_family_normalised("ei", zeta, vtol)
        want = ei_family_normalised("ei", zeta, vtol, method="solve")
        np.testing.assert_array_equal(got[0], want[0])
        with pytest.raises(ProblemFileError, match="fit covers"):
            ei_family_normalised("ei", zeta, vtol, method="fit")
    with pytest.raises(ProblemFileError, match="kind"):
        ei_family_normalised("zv", 0.1, 0.05)


def test_three_hump_exact_solve_is_one_smooth_branch_in_its_box_at_vtol_010():
    """Three-hump EI at vtol 0.10, the top of its box: on 0 <= ζ <= 0.12 neighbouring ζ give
    neighbouring shapers (beyond, towards ζ = 0.2, the solution bends ever faster: its
    step per 0.005 of ζ grows from 0.013 to 0.43, why the box stops at 0.12)."""
    zetas = np.linspace(0.0, 0.12, 25)
    x = np.array([np.concatenate(ei_family_normalised("ei3", float(z), 0.1, "solve"))
                  for z in zetas])
    step = np.abs(np.diff(x, axis=0)).max(axis=1)  # 0.01-0.06 per 0.005 of ζ here
    bend = np.abs(np.diff(x, 2, axis=0)).max(axis=1)
    # on one smooth branch consecutive steps differ by a small fraction of a step (h x''
    # against x': under 0.1 on this interval); a jump of branch (1.5e-2 seen before, as
    # large as a step) makes them differ by a step's size
    assert np.all(bend < 0.25 * np.maximum(step[:-1], step[1:]))
