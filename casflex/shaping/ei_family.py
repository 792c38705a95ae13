"""Extra-insensitive (EI) family in normalised time: exact solve and a fast fitted form.

The EI, two-hump and three-hump EI shapers of a mode of natural frequency ``ω`` depend on
``ω`` only through the time scale: with ``τ = ω t`` their impulse times and amplitudes are
functions of the damping ratio ``ζ`` and the hump height ``vtol`` alone. This module gives
them in that normalised form (:func:`ei_family_normalised`); :func:`casflex.shaping.ei`,
:func:`~casflex.shaping.ei_two_hump` and :func:`~casflex.shaping.ei_three_hump` scale the
times by ``1/ω``.

* Undamped (``ζ = 0``): the classic closed forms.
* Damped, exact (``method="solve"``): the defining conditions (amplitudes summing to 1;
  V = vtol with dV/dν = 0 at each hump; both components of the residual vector zero at
  each zero) are solved with :func:`scipy.optimize.fsolve` by continuation in ζ from the
  undamped form (tens of ms).
* Damped, fitted (``method="fit"``, the default where it applies): a 2-D Chebyshev series
  in ``ζ`` and ``vtol`` of every impulse time and amplitude over each kind's box
  (:data:`EI_FIT_BOXES`: EI ζ <= 0.2 and 0.01 <= vtol <= 0.2; two-hump EI ζ <= 0.1 and
  0.01 <= vtol <= 0.2; three-hump EI ζ <= 0.12 and 0.01 <= vtol <= 0.1), fitted offline to
  the exact solve on a tensor grid of Chebyshev nodes (``tools/gen_ei_fit.py`` writes
  ``ei_fit_table.npz``). The boxes end where the exact solve stops being one smooth branch:
  three-hump EI has no solution beyond ζ ≈ 0.13 at vtol = 0.2 (a fold) and bends sharply
  towards ζ = 0.2 at vtol = 0.1. Evaluating the fit takes microseconds; it agrees with
  the exact solve to 1e-10 and meets the defining conditions to 1e-9
  (tests/shaping/test_ei_family_fit.py draws random (ζ, vtol) in each box and checks them
  with its own V). Outside the boxes the exact solve is used.
"""

from __future__ import annotations

import math

import numpy as np

from casflex.errors import ProblemFileError, SolverError
from casflex.shaping.ei_fit_table import FIT_BOXES, FIT_TABLE

__all__ = ["EI_KINDS", "EI_FIT_BOXES", "ei_family_normalised"]

#: The kinds of the family: EI, two-hump EI, three-hump EI.
EI_KINDS = ("ei", "ei2", "ei3")

#: kind -> (zeta_max, vtol_min, vtol_max): where the fitted form exists (0 <= ζ <= zeta_max,
#: vtol_min <= vtol <= vtol_max).
EI_FIT_BOXES = {kind: box[:3] for kind, box in FIT_BOXES.items()}

# --- undamped closed forms (time in units of 1/omega, i.e. tau = omega * t) -------------
def _ei_undamped(vtol):
    a = np.array([(1.0 + vtol) / 4.0, (1.0 - vtol) / 2.0, (1.0 + vtol) / 4.0])
    return np.arange(3) * math.pi, a


def _ei2_undamped(vtol):
    x = (vtol**2 * (math.sqrt(1.0 - vtol**2) + 1.0)) ** (1.0 / 3.0)
    # vtol² underflows for vtol < 1e-162; a1 -> 1/8 as vtol -> 0 (reached in double already)
    a1 = (3.0 * x**2 + 2.0 * x + 3.0 * vtol**2) / (16.0 * x) if x > 0.0 else 0.125
    a2 = 0.5 - a1
    return np.arange(4) * math.pi, np.array([a1, a2, a2, a1])


def _ei3_undamped(vtol):
    a1 = (1.0 + 3.0 * vtol + 2.0 * math.sqrt(2.0 * vtol * (vtol + 1.0))) / 16.0
    a2 = (1.0 - vtol) / 4.0
    a3 = 1.0 - 2.0 * (a1 + a2)
    return np.arange(5) * math.pi, np.array([a1, a2, a3, a2, a1])


#: kind -> (undamped closed form, feature at the design frequency)
_HUMP_KINDS = {
    "ei": (_ei_undamped, "hump"),
    "ei2": (_ei2_undamped, "zero"),
    "ei3": (_ei3_undamped, "hump"),
}


def _g_and_dg(tau, amp, nu, zeta):
    """Complex residual G(ν) and dG/dν of a normalised shaper (τ = ω0 t, ν = ω/ω0)."""
    s = math.sqrt(1.0 - zeta**2)
    tn = tau[-1]
    expo = nu * (zeta * (tau - tn) + 1j * s * tau)
    z = amp * np.exp(expo)
    g = z.sum()
    dg = (z * (zeta * (tau - tn) + 1j * s * tau)).sum()
    return g, dg


def _undamped_features(tau, amp, centre):
    """Locate the zeros and humps of the undamped curve in (0, 2) ν except the centre one."""
    nu = np.linspace(1e-3, 2.0 - 1e-3, 40001)
    v = np.abs(np.exp(1j * np.outer(nu, tau)) @ amp)
    inner = slice(1, -1)
    is_min = (v[inner] <= v[:-2]) & (v[inner] <= v[2:])
    is_max = (v[inner] >= v[:-2]) & (v[inner] >= v[2:])
    idx = np.arange(1, nu.size - 1)
    zeros = [nu[i] for i in idx[is_min] if v[i] < 1e-3 and abs(nu[i] - 1.0) > 1e-3]
    humps = [nu[i] for i in idx[is_max] if abs(nu[i] - 1.0) > 1e-3 and v[i] < 0.999]
    return zeros, humps


def _solve(kind, zeta, vtol):
    """Normalised EI-family shaper; damped forms solved from the defining conditions."""
    from scipy import optimize  # here: importing it costs ~0.5 s
    closed, centre = _HUMP_KINDS[kind]
    tau0, amp0 = closed(vtol)
    if zeta == 0.0:
        return tau0, amp0
    zeros, humps = _undamped_features(tau0, amp0, centre)
    n = tau0.size
    nz = len(zeros)

    def unpack(x):
        amp = x[:n]
        tau = np.concatenate([[0.0], x[n : 2 * n - 1]])
        nu_z = x[2 * n - 1 : 2 * n - 1 + nz]
        nu_h = x[2 * n - 1 + nz :]
        return amp, tau, nu_z, nu_h

    def residuals(x, z):
        amp, tau, nu_z, nu_h = unpack(x)
        res = [amp.sum() - 1.0]
        g, dg = _g_and_dg(tau, amp, 1.0, z)
        if centre == "hump":
            res += [abs(g) ** 2 - vtol**2, 2.0 * (np.conj(g) * dg).real]
        else:
            res += [g.real, g.imag]
        for nu in nu_z:
            g, _ = _g_and_dg(tau, amp, nu, z)
            res += [g.real, g.imag]
        for nu in nu_h:
            g, dg = _g_and_dg(tau, amp, nu, z)
            res += [abs(g) ** 2 - vtol**2, 2.0 * (np.conj(g) * dg).real]
        return np.array(res)

    x = np.concatenate([amp0, tau0[1:], zeros, humps])
    steps = max(1, math.ceil(zeta / 0.02))
    for z in np.linspace(0.0, zeta, steps + 1)[1:]:
        # stretch the times to the damped period as a predictor
        sol, info, ier, msg = optimize.fsolve(residuals, x, args=(z,), full_output=True, xtol=1e-13)
        if ier != 1 or np.max(np.abs(info["fvec"])) > 1e-9:
            ls = optimize.least_squares(residuals, x, args=(z,), xtol=1e-15, ftol=1e-15, gtol=1e-15)
            sol, msg = ls.x, ls.message
            worst = float(np.max(np.abs(ls.fun)))
        else:
            worst = float(np.max(np.abs(info["fvec"])))
        amp, tau, _, _ = unpack(sol)
        if worst > 1e-9 or np.any(amp < -1e-12) or np.any(np.diff(tau) <= 0.0):
            raise SolverError(
                f"damped {kind} shaper: the defining conditions could not be solved at "
                f"zeta={z:.4g} (vtol={vtol:.4g}): {str(msg).strip()}"
            )
        x = sol
    amp, tau, _, _ = unpack(x)
    amp = np.clip(amp, 0.0, None)
    return tau, amp / amp.sum()


def _fit_rows(kind):
    coeffs = FIT_TABLE[kind]
    nz, nv, m = coeffs.shape
    zeta_max, vmin, vmax, power = FIT_BOXES[kind]
    return (zeta_max, vmin, vmax, power, vmin**power, vmax**power - vmin**power,
            np.arange(nz, dtype=float), np.arange(nv, dtype=float),
            np.ascontiguousarray(coeffs.reshape(nz, nv * m)), nv, m)


#: kind -> the fit's box, Chebyshev orders and coefficients laid out for two products
_FIT_ROWS = {kind: _fit_rows(kind) for kind in FIT_TABLE}


def _fitted(kind, zeta, vtol):
    """Times and amplitudes from the Chebyshev fit, or None outside its box."""
    rows = _FIT_ROWS.get(kind)
    if rows is None:
        return None
    zeta_max, vmin, vmax, power, g0, span, kz, kv, coeffs, nv, m = rows
    if not (0.0 <= zeta <= zeta_max and vmin <= vtol <= vmax):
        return None
    # T_k(x) = cos(k arccos x) on [-1, 1]: one vectorised cosine per coordinate
    x = min(1.0, 2.0 * zeta / zeta_max - 1.0)
    y = min(1.0, max(-1.0, 2.0 * (vtol**power - g0) / span - 1.0))
    along_zeta = np.cos(kz * math.acos(x)) @ coeffs
    values = np.cos(kv * math.acos(y)) @ along_zeta.reshape(nv, m)
    n = (m + 1) // 2
    amp = values[:n] / values[:n].sum()  # a copy: values[n - 1] is reused below
    values[n - 1] = 0.0  # the first time, τ_1 = 0, in place of the last amplitude
    return values[n - 1:], amp


def ei_family_normalised(kind: str, zeta: float, vtol: float, method: str = "auto"
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Normalised impulse times ``τ = ω t`` and amplitudes of an EI-family shaper.

    Parameters
    ----------
    kind : {"ei", "ei2", "ei3"}
        EI, two-hump EI or three-hump EI.
    zeta : float
        Damping ratio, 0 <= zeta < 1 (not checked here: the public shapers check it).
    vtol : float
        Hump height (residual vibration fraction), 0 < vtol < 1.
    method : {"auto", "fit", "solve"}, optional
        ``"auto"``: the closed form if undamped, else the Chebyshev fit where it exists
        (``(zeta, vtol)`` in the kind's box of :data:`EI_FIT_BOXES`), else the exact
        solve. ``"fit"`` raises outside the fit's coverage; ``"solve"`` always solves the
        defining conditions (the undamped case too, where it returns the closed form).

    Returns
    -------
    tau : numpy.ndarray
        Impulse times times ω (dimensionless), first 0.
    amplitudes : numpy.ndarray
        Impulse amplitudes, summing to 1.

    Raises
    ------
    ProblemFileError
        Unknown ``kind`` or ``method``, or ``method="fit"`` outside the fit's coverage.
    SolverError
        If the damped conditions cannot be solved.

    Examples
    --------
    >>> tau, amp = ei_family_normalised("ei", 0.0, 0.05)
    >>> [round(float(t / math.pi), 12) for t in tau], amp.tolist()
    ([0.0, 1.0, 2.0], [0.2625, 0.475, 0.2625])
    >>> fit = ei_family_normalised("ei3", 0.1, 0.05, "fit")
    >>> exact = ei_family_normalised("ei3", 0.1, 0.05, "solve")
    >>> bool(np.allclose(fit, exact, rtol=0.0, atol=1e-10))
    True
    """
    if kind not in _HUMP_KINDS:
        raise ProblemFileError(None, "kind", kind, f"must be one of {', '.join(EI_KINDS)}")
    if method not in ("auto", "fit", "solve"):
        raise ProblemFileError(None, "method", method, "must be one of auto, fit, solve")
    if method == "solve" or (zeta == 0.0 and method == "auto"):
        return _solve(kind, zeta, vtol)
    fitted = _fitted(kind, zeta, vtol)
    if fitted is not None:
        return fitted
    if method == "fit":
        zeta_max, vmin, vmax = EI_FIT_BOXES[kind]
        raise ProblemFileError(
            None, "zeta, vtol", (zeta, vtol),
            f"the {kind} fit covers 0 <= zeta <= {zeta_max} and {vmin} <= vtol <= {vmax}")
    return _solve(kind, zeta, vtol)
