"""Input shaping: residual vibration, closed-form shapers and specified-insensitivity shapers.

This module implements §6.1 of the reference dissertation:

* the percentage residual vibration (PRV) of an under-damped second-order mode excited by
  a sequence of impulses (eq. 187–189). It is returned as a *fraction* (``0`` = no residual
  vibration, ``1`` = as much as a single unit impulse), never multiplied by 100;
* closed-form shapers: ZV (eq. 190–191), ZVD, extra-insensitive (EI) and its two- and
  three-hump variants;
* specified-insensitivity (SI) shapers (§6.1.3): minimum-duration positive shapers whose
  PRV stays below a tolerance on one or more frequency ranges, designed as nonlinear programs
  solved by Ipopt through CasADi (or by SciPy's SLSQP for comparison), with the
  prune-and-merge loop of the dissertation and a dense-grid verification that adds the worst
  frequencies to the sample set until every range provably (on a dense grid refined at its
  local maxima) holds;
* shaper problem files (TOML) and :func:`apply_shaper` to shape sampled joint references.

Units are SI: times in s, frequencies in rad/s (unless a name ends in ``_hz``), damping
ratios dimensionless.
"""

from __future__ import annotations

import math
import time
import tomllib
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy import optimize

from casflex.errors import ModelError, ProblemFileError, SolverError
from casflex.moves import Move

__all__ = [
    "Shaper",
    "convolve",
    "residual_vibration",
    "residual_vibration_casadi",
    "sensitivity_curve",
    "zv",
    "zvd",
    "ei",
    "ei_two_hump",
    "ei_three_hump",
    "apply_shaper",
    "FrequencyRange",
    "SISample",
    "NLPSolution",
    "SIShaperResult",
    "solve_si_nlp",
    "si_shaper",
    "si_shaper_slsqp",
    "initial_si_guess",
    "load_shaper_problem",
    "ranges_from_mapping",
    "modal_displacements",
    "modal_contributions",
    "tolerances_from_contributions",
    "frequencies_along",
    "frequency_ranges_along",
    "MoveShaperResult",
    "shaper_for_move",
    "shaped_reference",
    "residual_amplitude",
]

#: Relative tolerance used to decide that two impulse times coincide when convolving.
_MERGE_RTOL = 1e-10


# --------------------------------------------------------------------------------------
# small validation helpers
# --------------------------------------------------------------------------------------
def _finite_float(value, field_name, path=None):
    """Return ``value`` as a finite float or raise :class:`ProblemFileError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ProblemFileError(path, field_name, value, "must be a real number")
    value = float(value)
    if not math.isfinite(value):
        raise ProblemFileError(path, field_name, value, "must be finite (no NaN or inf)")
    return value


def _check_omega(omega, name="omega"):
    omega = _finite_float(omega, name)
    if omega <= 0.0:
        raise ProblemFileError(None, name, omega, "natural frequency must be > 0 rad/s")
    return omega


def _check_zeta(zeta, name="zeta"):
    zeta = _finite_float(zeta, name)
    if not 0.0 <= zeta < 1.0:
        raise ProblemFileError(None, name, zeta, "damping ratio must satisfy 0 <= zeta < 1")
    return zeta


def _check_vtol(vtol, name="vtol"):
    vtol = _finite_float(vtol, name)
    if not 0.0 < vtol <= 1.0:
        raise ProblemFileError(None, name, vtol, "tolerable vibration must satisfy 0 < vtol <= 1")
    return vtol


# --------------------------------------------------------------------------------------
# Shaper
# --------------------------------------------------------------------------------------
def _merge_impulses(times, amplitudes, atol):
    """Sort impulses by time and sum the amplitudes of impulses closer than ``atol``."""
    order = np.argsort(times, kind="stable")
    times = np.asarray(times, dtype=float)[order]
    amplitudes = np.asarray(amplitudes, dtype=float)[order]
    out_t = [times[0]]
    out_a = [amplitudes[0]]
    for t, a in zip(times[1:], amplitudes[1:], strict=True):
        # keep the first time of a merged group (the times only differ by round-off)
        if t - out_t[-1] <= atol:
            out_a[-1] += a
        else:
            out_t.append(t)
            out_a.append(a)
    return np.array(out_t), np.array(out_a)


@dataclass(frozen=True, eq=False)
class Shaper:
    """A sequence of impulses: amplitudes ``amplitudes`` applied at ``times``.

    Parameters
    ----------
    times : array_like, shape (n,)
        Impulse times in s (sorted on construction, must be finite).
    amplitudes : array_like, shape (n,)
        Impulse amplitudes (dimensionless); they must sum to 1 so that the shaped command
        reaches the same final value as the unshaped one.

    Examples
    --------
    >>> s = Shaper([0.0, 0.5], [0.5, 0.5])
    >>> float(s.duration)
    0.5
    >>> len(s.convolve(s))
    3
    """

    times: np.ndarray
    amplitudes: np.ndarray

    def __post_init__(self):
        t = np.array(self.times, dtype=float).reshape(-1)
        a = np.array(self.amplitudes, dtype=float).reshape(-1)
        if t.size == 0:
            raise ProblemFileError(None, "times", [], "a shaper needs at least one impulse")
        if t.shape != a.shape:
            raise ProblemFileError(
                None, "amplitudes", a.tolist(), f"must have as many entries as times ({t.size})"
            )
        if not np.all(np.isfinite(t)):
            raise ProblemFileError(None, "times", t.tolist(), "must be finite")
        if not np.all(np.isfinite(a)):
            raise ProblemFileError(None, "amplitudes", a.tolist(), "must be finite")
        if abs(a.sum() - 1.0) > 1e-6:
            raise ProblemFileError(None, "amplitudes", a.tolist(), "must sum to 1")
        order = np.argsort(t, kind="stable")
        t, a = t[order], a[order]
        t.setflags(write=False)
        a.setflags(write=False)
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "amplitudes", a)

    def __len__(self):
        return int(self.times.size)

    @property
    def duration(self):
        """Time between the first and the last impulse, s."""
        return float(self.times[-1] - self.times[0])

    def convolve(self, other):
        """Return the convolution of this shaper with ``other`` (coincident times merged).

        Parameters
        ----------
        other : Shaper

        Returns
        -------
        Shaper
            Impulses at every sum ``t_i + t_j`` with amplitude ``A_i * B_j``; impulses whose
            times coincide (to a relative 1e-10 of the duration) are merged.

        Examples
        --------
        >>> a = Shaper([0.0, 1.0], [0.5, 0.5])
        >>> a.convolve(a).amplitudes.tolist()
        [0.25, 0.5, 0.25]
        """
        if not isinstance(other, Shaper):
            raise TypeError("can only convolve a Shaper with another Shaper")
        t = (self.times[:, None] + other.times[None, :]).ravel()
        a = (self.amplitudes[:, None] * other.amplitudes[None, :]).ravel()
        scale = max(1.0, float(np.max(np.abs(t))))
        t, a = _merge_impulses(t, a, _MERGE_RTOL * scale)
        return Shaper(t, a / a.sum())


def convolve(*shapers):
    """Convolve any number of shapers into one multi-mode shaper.

    Parameters
    ----------
    *shapers : Shaper
        At least one shaper.

    Returns
    -------
    Shaper
        The convolution; its duration is the sum of the durations.

    Examples
    --------
    >>> s = convolve(zv(2 * 3.14159, 0.0), zv(2 * 3.14159 * 2.5, 0.0))
    >>> round(s.duration, 3)
    0.7
    """
    if not shapers:
        raise ValueError("convolve() needs at least one shaper")
    out = shapers[0]
    for s in shapers[1:]:
        out = out.convolve(s)
    return out


# --------------------------------------------------------------------------------------
# residual vibration
# --------------------------------------------------------------------------------------
def _as_shaper(shaper):
    if isinstance(shaper, Shaper):
        return shaper
    times, amplitudes = shaper
    return Shaper(times, amplitudes)


def residual_vibration(shaper, omega, zeta=0.0):
    """Residual vibration fraction V(ω, ζ) of a shaper (eq. 187–189).

    ``V = exp(-ζ ω t_n) * sqrt(C² + S²)`` with
    ``C = Σ A_i exp(ζ ω t_i) cos(ω sqrt(1-ζ²) t_i)`` and ``S`` the same with ``sin``: the
    amplitude of the residual oscillation of a mode of natural frequency ``ω`` and damping
    ``ζ`` at the last impulse time, relative to the amplitude of the response to a single
    unit impulse at the moment it is applied (the normalisation of eq. 187: with damping,
    the shaped residual is compared with an unshaped one of the same age, not at the same
    absolute time).
    The dissertation calls it the percentage residual vibration (PRV); here it is a fraction
    (0.05 means 5 %).

    Parameters
    ----------
    shaper : Shaper or (times, amplitudes)
        Impulse sequence; times in s.
    omega : float or array_like
        Natural frequency (frequencies), rad/s.
    zeta : float or array_like, optional
        Damping ratio(s), broadcast against ``omega``.

    Returns
    -------
    float or numpy.ndarray
        V, same shape as the broadcast ``omega``/``zeta``.

    Examples
    --------
    >>> s = zv(10.0, 0.0)
    >>> round(float(residual_vibration(s, 10.0, 0.0)), 12)
    0.0
    >>> residual_vibration(s, [5.0, 10.0]).shape
    (2,)
    """
    shaper = _as_shaper(shaper)
    omega_b, zeta_b = np.broadcast_arrays(
        np.asarray(omega, dtype=float), np.asarray(zeta, dtype=float)
    )
    w = omega_b.reshape(-1, 1)
    z = zeta_b.reshape(-1, 1)
    t = shaper.times.reshape(1, -1)
    tn = shaper.times[-1]
    wd = w * np.sqrt(1.0 - z**2)
    decay = np.exp(-z * w * (tn - t))
    c = (shaper.amplitudes * decay * np.cos(wd * t)).sum(axis=1)
    s = (shaper.amplitudes * decay * np.sin(wd * t)).sum(axis=1)
    v = np.hypot(c, s).reshape(omega_b.shape)
    return float(v) if v.ndim == 0 else v


def residual_vibration_casadi(times, amplitudes, omega, zeta=0.0, squared=False):
    """CasADi expression of the residual vibration fraction V(ω, ζ) (eq. 187–189).

    The impulse times must be ordered so that the last entry is the last impulse.

    Parameters
    ----------
    times, amplitudes : casadi.SX, casadi.MX, casadi.DM or array_like, shape (n,)
        Impulse times (s) and amplitudes; symbolic or numeric.
    omega : float or array_like, shape (m,)
        Natural frequency (frequencies), rad/s (numeric).
    zeta : float or array_like, shape (m,), optional
        Damping ratio(s), broadcast against ``omega``.
    squared : bool, optional
        Return V² instead of V (smooth everywhere; preferable as an NLP constraint).

    Returns
    -------
    casadi.SX, casadi.MX or casadi.DM, shape (m, 1)
        V (or V²) at each frequency.

    Examples
    --------
    >>> import casadi as ca
    >>> t = ca.SX.sym("t", 2)
    >>> a = ca.SX.sym("a", 2)
    >>> v = residual_vibration_casadi(t, a, 10.0, 0.0)
    >>> f = ca.Function("f", [t, a], [v])
    >>> round(float(f([0.0, 3.14159265358979 / 10.0], [0.5, 0.5])), 9)
    0.0
    """

    def _col(x):
        if isinstance(x, (ca.SX, ca.MX, ca.DM)):
            return ca.reshape(x, x.numel(), 1)
        if isinstance(x, (list, tuple)) and any(isinstance(e, (ca.SX, ca.MX)) for e in x):
            return ca.vertcat(*x)
        return ca.DM(np.asarray(x, dtype=float).reshape(-1, 1))

    t = _col(times)
    a = _col(amplitudes)
    n = t.numel()
    omega_b, zeta_b = np.broadcast_arrays(
        np.atleast_1d(np.asarray(omega, dtype=float)), np.asarray(zeta, dtype=float)
    )
    w = ca.DM(omega_b.reshape(-1, 1))
    zw = ca.DM((zeta_b * omega_b).reshape(-1, 1))
    wd = ca.DM((omega_b * np.sqrt(1.0 - zeta_b**2)).reshape(-1, 1))
    tn = t[n - 1]
    ones_row = ca.DM.ones(1, n)
    phase = ca.mtimes(wd, t.T)  # (m, n)
    decay = ca.exp(-ca.mtimes(zw, ones_row) * (tn - ca.mtimes(ca.DM.ones(w.numel(), 1), t.T)))
    c = ca.mtimes(decay * ca.cos(phase), a)
    s = ca.mtimes(decay * ca.sin(phase), a)
    v2 = c**2 + s**2
    return v2 if squared else ca.sqrt(v2)


def sensitivity_curve(shaper, omega_min, omega_max, zeta=0.0, n=500):
    """Residual vibration fraction of a shaper over a band of frequencies.

    Parameters
    ----------
    shaper : Shaper
    omega_min, omega_max : float
        Band limits, rad/s.
    zeta : float, optional
        Damping ratio.
    n : int, optional
        Number of evenly spaced frequencies.

    Returns
    -------
    omega : numpy.ndarray, shape (n,)
        Frequencies, rad/s.
    v : numpy.ndarray, shape (n,)
        Residual vibration fraction at each frequency.

    Examples
    --------
    >>> w, v = sensitivity_curve(zv(10.0, 0.0), 5.0, 15.0, 0.0, n=3)
    >>> w.tolist()
    [5.0, 10.0, 15.0]
    >>> bool(v[1] < 1e-12)
    True
    """
    omega = np.linspace(float(omega_min), float(omega_max), int(n))
    return omega, np.atleast_1d(residual_vibration(shaper, omega, zeta))


# --------------------------------------------------------------------------------------
# closed-form shapers
# --------------------------------------------------------------------------------------
def zv(omega, zeta=0.0):
    """Zero-vibration (ZV) shaper (eq. 190–191).

    Two impulses ``1/(1+K)`` and ``K/(1+K)`` at 0 and half a damped period, with
    ``K = exp(-ζπ/sqrt(1-ζ²))``.

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = zv(2 * math.pi * 3.5)
    >>> round(s.duration, 4)
    0.1429
    """
    omega = _check_omega(omega)
    zeta = _check_zeta(zeta)
    root = math.sqrt(1.0 - zeta**2)
    k = math.exp(-zeta * math.pi / root)
    return Shaper([0.0, math.pi / (omega * root)], [1.0 / (1.0 + k), k / (1.0 + k)])


def zvd(omega, zeta=0.0):
    """Zero-vibration-and-derivative (ZVD) shaper: ZV convolved with itself.

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.

    Returns
    -------
    Shaper
        Impulses ``[1, 2K, K²]/(1+K)²`` at 0, half and one damped period.

    Examples
    --------
    >>> zvd(2 * math.pi).amplitudes.tolist()
    [0.25, 0.5, 0.25]
    """
    omega = _check_omega(omega)
    zeta = _check_zeta(zeta)
    root = math.sqrt(1.0 - zeta**2)
    k = math.exp(-zeta * math.pi / root)
    half = math.pi / (omega * root)
    d = (1.0 + k) ** 2
    return Shaper([0.0, half, 2.0 * half], [1.0 / d, 2.0 * k / d, k * k / d])


# --- undamped closed forms (time in units of 1/omega, i.e. tau = omega * t) -------------
def _ei_undamped(vtol):
    a = np.array([(1.0 + vtol) / 4.0, (1.0 - vtol) / 2.0, (1.0 + vtol) / 4.0])
    return np.arange(3) * math.pi, a


def _ei2_undamped(vtol):
    x = (vtol**2 * (math.sqrt(1.0 - vtol**2) + 1.0)) ** (1.0 / 3.0)
    a1 = (3.0 * x**2 + 2.0 * x + 3.0 * vtol**2) / (16.0 * x)
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


def _hump_shaper(kind, omega, zeta, vtol):
    """EI-family shaper; damped forms solved numerically from the defining conditions."""
    closed, centre = _HUMP_KINDS[kind]
    tau0, amp0 = closed(vtol)
    if zeta == 0.0:
        return Shaper(tau0 / omega, amp0)
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
                f"zeta={z:.4g} (omega={omega:.6g} rad/s, vtol={vtol:.4g}): {str(msg).strip()}"
            )
        x = sol
    amp, tau, _, _ = unpack(x)
    amp = np.clip(amp, 0.0, None)
    return Shaper(tau / omega, amp / amp.sum())


def ei(omega, zeta=0.0, vtol=0.05):
    """Extra-insensitive (EI) shaper: three impulses, V(ω) = vtol at the design frequency.

    Undamped (``zeta == 0``) the closed form ``A = [(1+V)/4, (1-V)/2, (1+V)/4]`` at
    ``0, T/2, T`` (``T = 2π/ω``) is returned. With damping the defining conditions are
    solved numerically (:func:`scipy.optimize.fsolve`, continuation in ζ from the undamped
    form): amplitudes sum to 1, ``V(ω) = vtol`` with a local maximum of V at ω
    (``dV/dω = 0``), and V exactly zero at two frequencies below and above ω (both
    components of the residual vector vanish there); the impulse times are free.

    Parameters
    ----------
    omega : float
        Design natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.
    vtol : float, optional
        Tolerable residual vibration fraction, 0 < vtol <= 1.

    Returns
    -------
    Shaper

    Raises
    ------
    SolverError
        If the damped conditions cannot be solved.

    Examples
    --------
    >>> s = ei(2 * math.pi, 0.0, 0.05)
    >>> round(s.duration, 12), round(float(residual_vibration(s, 2 * math.pi)), 12)
    (1.0, 0.05)
    """
    return _hump_shaper("ei", _check_omega(omega), _check_zeta(zeta), _check_vtol(vtol))


def ei_two_hump(omega, zeta=0.0, vtol=0.05):
    """Two-hump extra-insensitive shaper: four impulses over 1.5 damped periods.

    Undamped the classic closed form is used:
    ``X = (V²(sqrt(1-V²)+1))^(1/3)``, ``A1 = A4 = (3X² + 2X + 3V²)/(16X)``,
    ``A2 = A3 = 1/2 - A1`` at ``0, T/2, T, 3T/2``. V is zero at the design frequency with
    two humps of height vtol on either side. With damping the defining conditions (zero at
    ω, humps of height vtol with zero slope at two free frequencies, zeros at two further
    free frequencies, amplitudes summing to 1) are solved numerically with
    :func:`scipy.optimize.fsolve` by continuation in ζ from the undamped form.

    Parameters
    ----------
    omega : float
        Design natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.
    vtol : float, optional
        Hump height (residual vibration fraction), 0 < vtol < 1.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = ei_two_hump(2 * math.pi, 0.0, 0.05)
    >>> len(s), round(s.duration, 12)
    (4, 1.5)
    """
    return _hump_shaper("ei2", _check_omega(omega), _check_zeta(zeta), _check_vtol(vtol))


def ei_three_hump(omega, zeta=0.0, vtol=0.05):
    """Three-hump extra-insensitive shaper: five impulses over two damped periods.

    Undamped the classic closed form is used:
    ``A1 = A5 = (1 + 3V + 2 sqrt(2V(V+1)))/16``, ``A2 = A4 = (1-V)/4``,
    ``A3 = 1 - 2(A1 + A2)`` at ``0, T/2, T, 3T/2, 2T``; V equals vtol at the design
    frequency and at two further humps. With damping the defining conditions (hump of height
    vtol with zero slope at ω and at two free frequencies, four free zeros, amplitudes summing
    to 1) are solved numerically with :func:`scipy.optimize.fsolve` by continuation in ζ.

    Parameters
    ----------
    omega : float
        Design natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.
    vtol : float, optional
        Hump height (residual vibration fraction), 0 < vtol < 1.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = ei_three_hump(2 * math.pi, 0.0, 0.05)
    >>> len(s), round(s.duration, 12)
    (5, 2.0)
    """
    return _hump_shaper("ei3", _check_omega(omega), _check_zeta(zeta), _check_vtol(vtol))


# --------------------------------------------------------------------------------------
# shaping a sampled reference
# --------------------------------------------------------------------------------------
def apply_shaper(shaper, t, q, qd=None, qdd=None):
    """Shape a sampled joint reference by convolving it with an impulse sequence.

    Every signal is shifted by each impulse time, weighted by the impulse amplitude and
    summed: ``y(t) = Σ A_i x(t - t_i)``. Outside its samples the reference is at rest:
    before it starts the position holds its first sample and after it ends its last one,
    while velocity and acceleration are zero there. Position, velocity and acceleration
    shaped with the same impulses therefore stay mutually consistent (the derivative of the
    shaped position is the shaped velocity) even for a reference that starts with a jump
    in acceleration, such as a bang-bang move. Values between samples are linearly
    interpolated.

    Parameters
    ----------
    shaper : Shaper
        Impulse sequence (the first impulse time is taken as the time origin).
    t : array_like, shape (N,)
        Strictly increasing sample times, s.
    q : array_like, shape (N,) or (N, n_joints)
        Reference positions, rad (or m).
    qd, qdd : array_like, optional
        Reference velocities and accelerations, same shape as ``q``.

    Returns
    -------
    t_new : numpy.ndarray, shape (N + K,)
        Time vector extended past ``t[-1]`` by the shaper duration (same step as the last
        step of ``t``).
    q_new, qd_new, qdd_new : numpy.ndarray or None
        Shaped signals on ``t_new`` (``None`` where no input was given).

    Examples
    --------
    >>> t = np.linspace(0.0, 1.0, 11)
    >>> tn, qn, _, _ = apply_shaper(Shaper([0.0, 0.2], [0.5, 0.5]), t, t)
    >>> round(float(tn[-1]), 6), round(float(qn[-1]), 6)
    (1.2, 1.0)
    """
    shaper = _as_shaper(shaper)
    t = np.asarray(t, dtype=float).reshape(-1)
    if t.size < 2:
        raise ProblemFileError(None, "t", t.tolist(), "needs at least two samples")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise ProblemFileError(None, "t", "...", "must be finite and strictly increasing")
    delays = shaper.times - shaper.times[0]
    duration = float(delays[-1])
    step = float(t[-1] - t[-2])
    k = math.ceil(duration / step - 1e-9) if duration > 0.0 else 0
    t_new = np.concatenate([t, t[-1] + step * np.arange(1, k + 1)])

    def shape(x, name, at_rest):
        if x is None:
            return None
        x = np.asarray(x, dtype=float)
        if x.shape[0] != t.size or x.ndim not in (1, 2):
            raise ProblemFileError(
                None, name, x.shape, f"must have shape ({t.size},) or ({t.size}, n_joints)"
            )
        cols = x.reshape(t.size, -1)
        out = np.zeros((t_new.size, cols.shape[1]))
        for a, d in zip(shaper.amplitudes, delays, strict=True):
            shifted = t_new - d
            for j in range(cols.shape[1]):
                if at_rest:  # derivatives: zero outside the samples
                    out[:, j] += a * np.interp(shifted, t, cols[:, j], left=0.0, right=0.0)
                else:
                    out[:, j] += a * np.interp(shifted, t, cols[:, j])
        return out.reshape((t_new.size,) + x.shape[1:])

    return t_new, shape(q, "q", False), shape(qd, "qd", True), shape(qdd, "qdd", True)


# --------------------------------------------------------------------------------------
# frequency ranges and problem files
# --------------------------------------------------------------------------------------
def _validate_range_values(omega_min, omega_max, zeta, vtol, path=None, prefix=""):
    omega_min = _finite_float(omega_min, prefix + "omega_min", path)
    omega_max = _finite_float(omega_max, prefix + "omega_max", path)
    zeta = _finite_float(zeta, prefix + "zeta", path)
    vtol = _finite_float(vtol, prefix + "vtol", path)
    if omega_min <= 0.0:
        raise ProblemFileError(path, prefix + "omega_min", omega_min, "must be > 0")
    if omega_min > omega_max:
        raise ProblemFileError(
            path, prefix + "omega_max", omega_max, f"must be >= omega_min ({omega_min})"
        )
    if not 0.0 <= zeta < 1.0:
        raise ProblemFileError(path, prefix + "zeta", zeta, "damping must satisfy 0 <= zeta < 1")
    if not 0.0 < vtol <= 1.0:
        raise ProblemFileError(path, prefix + "vtol", vtol, "must satisfy 0 < vtol <= 1")
    return omega_min, omega_max, zeta, vtol


@dataclass(frozen=True)
class FrequencyRange:
    """A band of natural frequencies whose residual vibration must stay below ``vtol``.

    Parameters
    ----------
    omega_min, omega_max : float
        Band limits, rad/s (``0 < omega_min <= omega_max``; equal for a single frequency).
    zeta : float
        Damping ratio of the mode in the band, 0 <= zeta < 1.
    vtol : float
        Tolerable residual vibration fraction, 0 < vtol <= 1 (1 = unconstrained).

    Raises
    ------
    ProblemFileError
        Naming the offending field.

    Examples
    --------
    >>> r = FrequencyRange(10.0, 12.0, 0.0, 0.05)
    >>> r.omega_mid
    11.0
    """

    omega_min: float
    omega_max: float
    zeta: float = 0.0
    vtol: float = 0.05

    def __post_init__(self):
        values = _validate_range_values(self.omega_min, self.omega_max, self.zeta, self.vtol)
        for name, v in zip(("omega_min", "omega_max", "zeta", "vtol"), values, strict=True):
            object.__setattr__(self, name, v)

    @property
    def omega_mid(self):
        """Midpoint of the band, rad/s."""
        return 0.5 * (self.omega_min + self.omega_max)


_RANGE_KEYS = {"omega_min", "omega_max", "zeta", "vtol", "unit"}
_RANGE_REQUIRED = ("omega_min", "omega_max", "vtol")
_TOP_KEYS = {"range", "description"}
_UNITS = {"rad/s": 1.0, "hz": 2.0 * math.pi}


def ranges_from_mapping(data, path=None):
    """Build the frequency ranges of a parsed shaper problem (a TOML document as a dict).

    Parameters
    ----------
    data : dict
        ``{"range": [{"omega_min": ..., "omega_max": ..., "vtol": ..., "zeta": ...,
        "unit": "rad/s" | "Hz"}, ...], "description": "..."}``.
    path : str or None, optional
        File name used in error messages.

    Returns
    -------
    list of FrequencyRange
        Frequencies converted to rad/s.

    Raises
    ------
    ProblemFileError
        Unknown or missing key, non-finite value, omega_min > omega_max, vtol outside
        (0, 1], damping outside [0, 1), unknown unit, no ranges.

    Examples
    --------
    >>> r = ranges_from_mapping({"range": [{"omega_min": 1, "omega_max": 2, "vtol": 0.05,
    ...                                      "unit": "Hz"}]})
    >>> round(r[0].omega_max, 4)
    12.5664
    """
    if not isinstance(data, dict):
        raise ProblemFileError(path, "<document>", type(data).__name__, "must be a table")
    for key in data:
        if key not in _TOP_KEYS:
            raise ProblemFileError(
                path, key, data[key], f"unknown key; allowed top-level keys: {sorted(_TOP_KEYS)}"
            )
    if "description" in data and not isinstance(data["description"], str):
        raise ProblemFileError(path, "description", data["description"], "must be a string")
    tables = data.get("range")
    if tables is None:
        raise ProblemFileError(path, "range", None, "missing: at least one [[range]] is needed")
    if not isinstance(tables, list) or not tables:
        raise ProblemFileError(path, "range", tables, "must be a non-empty array of [[range]]")
    out = []
    for i, tab in enumerate(tables):
        prefix = f"range[{i}]."
        if not isinstance(tab, dict):
            raise ProblemFileError(path, f"range[{i}]", tab, "must be a table")
        for key in tab:
            if key not in _RANGE_KEYS:
                raise ProblemFileError(
                    path, prefix + key, tab[key], f"unknown key; allowed: {sorted(_RANGE_KEYS)}"
                )
        for key in _RANGE_REQUIRED:
            if key not in tab:
                raise ProblemFileError(path, prefix + key, None, "missing required key")
        unit = tab.get("unit", "rad/s")
        if not isinstance(unit, str) or unit.strip().lower() not in _UNITS:
            raise ProblemFileError(path, prefix + "unit", unit, "unit must be 'rad/s' or 'Hz'")
        scale = _UNITS[unit.strip().lower()]
        wmin, wmax, zeta, vtol = _validate_range_values(
            tab["omega_min"], tab["omega_max"], tab.get("zeta", 0.0), tab["vtol"], path, prefix
        )
        out.append(FrequencyRange(wmin * scale, wmax * scale, zeta, vtol))
    return out


def load_shaper_problem(path):
    """Read a shaper problem file (TOML with ``[[range]]`` tables).

    See ``problems/shapers/README.md`` for the keys. Frequencies are given in rad/s or, with
    ``unit = "Hz"``, in Hz, and returned in rad/s.

    Parameters
    ----------
    path : str or pathlib.Path
        The TOML file.

    Returns
    -------
    list of FrequencyRange

    Raises
    ------
    ProblemFileError
        Unreadable file, invalid TOML, or any rule of :func:`ranges_from_mapping`.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "p.toml"
    >>> _ = p.write_text('[[range]]\\nomega_min = 3.0\\nomega_max = 4.0\\nunit = "Hz"\\n'
    ...                  'zeta = 0.0\\nvtol = 0.05\\n')
    >>> r = load_shaper_problem(p)
    >>> len(r), round(r[0].omega_min, 4)
    (1, 18.8496)
    """
    return ranges_from_mapping(_read_toml(path), str(path))


def _read_toml(path):
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(path, "<file>", str(path), f"is not valid TOML: {exc}") from exc


def _as_ranges(ranges):
    if isinstance(ranges, FrequencyRange):
        ranges = [ranges]
    out = []
    for i, r in enumerate(ranges):
        if isinstance(r, FrequencyRange):
            out.append(r)
        elif isinstance(r, dict):
            out.append(FrequencyRange(**r))
        else:
            try:
                out.append(FrequencyRange(*r))
            except TypeError as exc:
                raise ProblemFileError(None, f"range[{i}]", r, "not a frequency range") from exc
    if not out:
        raise ProblemFileError(None, "range", [], "at least one frequency range is needed")
    return out


# --------------------------------------------------------------------------------------
# SI shaper NLP
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SISample:
    """Frequencies at which the SI constraints ``V(ω_s, ζ_s) <= vtol_s`` are imposed.

    Parameters
    ----------
    omega, zeta, vtol : numpy.ndarray, shape (m,)
        Sample frequencies (rad/s), damping ratios and tolerances.
    range_index : numpy.ndarray of int, shape (m,)
        Index of the frequency range each sample belongs to.

    Examples
    --------
    >>> s = SISample.from_ranges([FrequencyRange(10.0, 12.0, 0.0, 0.05)], 3)
    >>> s.omega.tolist()
    [10.0, 11.0, 12.0]
    """

    omega: np.ndarray
    zeta: np.ndarray
    vtol: np.ndarray
    range_index: np.ndarray

    def __len__(self):
        return int(np.size(self.omega))

    @classmethod
    def from_ranges(cls, ranges, per_range):
        """Evenly spaced samples (end points included) on every range with vtol < 1.

        Parameters
        ----------
        ranges : list of FrequencyRange
        per_range : int or sequence of int
            Number of samples on each range (one sample on a zero-width range).

        Returns
        -------
        SISample

        Examples
        --------
        >>> SISample.from_ranges([FrequencyRange(1.0, 2.0, 0.0, 0.1)], 2).omega.tolist()
        [1.0, 2.0]
        """
        counts = np.broadcast_to(np.asarray(per_range, dtype=int), (len(ranges),))
        w, z, v, idx = [], [], [], []
        for i, (r, m) in enumerate(zip(ranges, counts, strict=True)):
            if r.vtol >= 1.0:
                continue
            pts = (
                [r.omega_min]
                if r.omega_max == r.omega_min
                else np.linspace(r.omega_min, r.omega_max, max(2, int(m)))
            )
            w.extend(pts)
            z.extend([r.zeta] * len(pts))
            v.extend([r.vtol] * len(pts))
            idx.extend([i] * len(pts))
        return cls(np.array(w, float), np.array(z, float), np.array(v, float), np.array(idx, int))

    def with_points(self, omega, range_index, ranges):
        """Return a copy with extra sample frequencies added to the given ranges.

        Parameters
        ----------
        omega : array_like
            New sample frequencies, rad/s.
        range_index : array_like of int
            Range each new frequency belongs to (its zeta and vtol are used).
        ranges : list of FrequencyRange

        Returns
        -------
        SISample

        Examples
        --------
        >>> r = [FrequencyRange(1.0, 2.0, 0.0, 0.1)]
        >>> len(SISample.from_ranges(r, 2).with_points([1.5], [0], r))
        3
        """
        z = [ranges[i].zeta for i in range_index]
        v = [ranges[i].vtol for i in range_index]
        return SISample(
            np.concatenate([self.omega, np.asarray(omega, float)]),
            np.concatenate([self.zeta, np.asarray(z, float)]),
            np.concatenate([self.vtol, np.asarray(v, float)]),
            np.concatenate([self.range_index, np.asarray(range_index, int)]),
        )


@dataclass(frozen=True, eq=False)
class NLPSolution:
    """Outcome of one SI NLP solve.

    Attributes
    ----------
    shaper : Shaper
        The solution (amplitudes renormalised to sum exactly to 1).
    success : bool
        Whether the solver reported success.
    status : str
        Solver return status (Ipopt ``return_status`` or SLSQP message).
    iterations : int
        Solver iterations.
    solve_time : float
        Wall time of the solver call only, s.
    build_time : float
        Wall time spent building the problem (CasADi graph and solver instance), s.

    Examples
    --------
    >>> r = FrequencyRange(2 * math.pi * 0.81, 2 * math.pi * 1.19, 0.0, 0.05)
    >>> sol = solve_si_nlp(SISample.from_ranges([r], 9), ei(2 * math.pi))
    >>> sol.success, sol.status, len(sol.shaper), float(sol.shaper.amplitudes.sum())
    (True, 'Solve_Succeeded', 3, 1.0)
    """

    shaper: Shaper
    success: bool
    status: str
    iterations: int
    solve_time: float
    build_time: float


#: Relative margin on vtol imposed inside the NLP so that the returned shaper satisfies the
#: tolerance itself, not only to the solver's constraint-violation tolerance.
_VTOL_MARGIN = 1e-7

_DEFAULT_IPOPT = {
    "print_level": 0,
    "sb": "yes",
    "tol": 1e-10,
    "constr_viol_tol": 1e-10,
    "max_iter": 3000,
    "mu_strategy": "adaptive",
}


def _si_functions(n, samples):
    """CasADi objective/constraints of the SI NLP with ``n`` impulses."""
    a = ca.SX.sym("A", n)
    t = ca.SX.sym("t", n)
    x = ca.vertcat(a, t)
    v2 = residual_vibration_casadi(t, a, samples.omega, samples.zeta, squared=True)
    g_sum = ca.sum1(a) - 1.0
    g_order = t[1:] - t[:-1] if n > 1 else ca.SX(0, 1)
    f = t[n - 1]
    lim = (samples.vtol * (1.0 - _VTOL_MARGIN)) ** 2
    return x, f, g_sum, g_order, v2, lim


def _bounds(n):
    lbx = np.concatenate([np.zeros(n), np.zeros(n)])
    ubx = np.concatenate([np.ones(n), np.full(n, np.inf)])
    ubx[n] = 0.0  # t1 = 0
    return lbx, ubx


def _shaper_from_x(x, n):
    a = np.clip(np.asarray(x[:n], float).ravel(), 0.0, None)
    t = np.asarray(x[n:], float).ravel()
    t = np.maximum.accumulate(np.clip(t, 0.0, None))
    if a.sum() <= 0.0:
        a = np.full(n, 1.0 / n)
    return Shaper(t, a / a.sum())


def solve_si_nlp(samples, guess, method="ipopt", options=None):
    """Solve one specified-insensitivity shaper NLP from a given start.

    Minimise the last impulse time ``t_n`` over impulse amplitudes ``A`` and times ``t``
    subject to ``V(ω_s, ζ_s)² <= vtol_s²`` at every sample (eq. 192, squared for
    smoothness, with a relative margin of 1e-7 on vtol), ``A_i >= 0``, ``Σ A_i = 1``,
    ``t_1 = 0`` and ``t_i <= t_{i+1}``. The number of impulses is that of ``guess``.

    Parameters
    ----------
    samples : SISample
        Constraint frequencies.
    guess : Shaper
        Start point (its first impulse is moved to t = 0).
    method : {"ipopt", "slsqp"}, optional
        Ipopt through CasADi ``nlpsol`` (exact Hessian) or :func:`scipy.optimize.minimize`
        with SLSQP using CasADi-generated gradients and Jacobians of the same functions.
    options : dict, optional
        Extra Ipopt options (without the ``ipopt.`` prefix) or SLSQP options.

    Returns
    -------
    NLPSolution

    Examples
    --------
    >>> r = FrequencyRange(2 * math.pi * 0.81, 2 * math.pi * 1.19, 0.0, 0.05)
    >>> sol = solve_si_nlp(SISample.from_ranges([r], 9), ei(2 * math.pi))
    >>> sol.success, round(sol.shaper.duration, 2)
    (True, 0.99)
    """
    guess = _as_shaper(guess)
    n = len(guess)
    x, f, g_sum, g_order, v2, lim = _si_functions(n, samples)
    x0 = np.concatenate([guess.amplitudes, guess.times - guess.times[0]])
    lbx, ubx = _bounds(n)
    x0 = np.clip(x0, lbx, ubx)
    if method == "ipopt":
        t0 = time.perf_counter()
        g = ca.vertcat(g_sum, g_order, v2)
        m = v2.numel()
        lbg = np.concatenate([[0.0], np.zeros(n - 1), np.full(m, -np.inf)])
        ubg = np.concatenate([[0.0], np.full(n - 1, np.inf), lim])
        opts = dict(_DEFAULT_IPOPT)
        opts.update(options or {})
        solver = ca.nlpsol(
            "si_shaper",
            "ipopt",
            {"x": x, "f": f, "g": g},
            {"ipopt": opts, "print_time": False, "error_on_fail": False},
        )
        t1 = time.perf_counter()
        res = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        t2 = time.perf_counter()
        stats = solver.stats()
        return NLPSolution(
            shaper=_shaper_from_x(np.array(res["x"]).ravel(), n),
            success=bool(stats.get("success", False)),
            status=str(stats.get("return_status", "unknown")),
            iterations=int(stats.get("iter_count", -1)),
            solve_time=t2 - t1,
            build_time=t1 - t0,
        )
    if method == "slsqp":
        t0 = time.perf_counter()
        ineq = ca.vertcat(g_order, ca.DM(lim) - v2)
        f_fun = ca.Function("f", [x], [f, ca.gradient(f, x)])
        eq_fun = ca.Function("geq", [x], [g_sum, ca.jacobian(g_sum, x)])
        in_fun = ca.Function("gin", [x], [ineq, ca.jacobian(ineq, x)])

        def fobj(xv):
            val, grad = f_fun(xv)
            return float(val), np.array(grad).ravel()

        constraints = [
            {
                "type": "eq",
                "fun": lambda xv: np.array(eq_fun(xv)[0]).ravel(),
                "jac": lambda xv: np.array(eq_fun(xv)[1]),
            },
            {
                "type": "ineq",
                "fun": lambda xv: np.array(in_fun(xv)[0]).ravel(),
                "jac": lambda xv: np.array(ca.densify(in_fun(xv)[1])),
            },
        ]
        bounds = list(zip(lbx, ubx, strict=True))
        opts = {"maxiter": 1000, "ftol": 1e-12}
        opts.update(options or {})
        t1 = time.perf_counter()
        res = optimize.minimize(
            fobj,
            x0,
            jac=True,
            method="SLSQP",
            bounds=bounds,
            constraints=constraints,
            options=opts,
        )
        t2 = time.perf_counter()
        return NLPSolution(
            shaper=_shaper_from_x(res.x, n),
            success=bool(res.success),
            status=str(res.message),
            iterations=int(res.get("nit", -1)),
            solve_time=t2 - t1,
            build_time=t1 - t0,
        )
    raise ProblemFileError(None, "method", method, "must be 'ipopt' or 'slsqp'")


# --------------------------------------------------------------------------------------
# verification on dense grids
# --------------------------------------------------------------------------------------
def _range_local_maxima(shaper, r, n_refine=6):
    """Max of V over a range (dense grid refined at local maxima); returns (max, peaks).

    ``peaks`` is a list of ``(omega, V)`` of the refined local maxima (end points included).
    """
    if r.omega_max == r.omega_min:
        v = residual_vibration(shaper, r.omega_min, r.zeta)
        return v, [(r.omega_min, v)]
    width = r.omega_max - r.omega_min
    # V oscillates in ω with a period of about 2π / duration: ~40 points per period
    per = 2.0 * math.pi / max(shaper.duration, 1e-9)
    npts = int(min(20000, max(400, 40.0 * width / per)))
    w = np.linspace(r.omega_min, r.omega_max, npts)
    v = residual_vibration(shaper, w, r.zeta)
    peaks_idx = [0, npts - 1]
    interior = np.nonzero((v[1:-1] >= v[:-2]) & (v[1:-1] >= v[2:]))[0] + 1
    peaks_idx.extend(interior.tolist())
    peaks_idx = sorted(set(peaks_idx), key=lambda i: -v[i])[:n_refine]
    peaks = []
    for i in peaks_idx:
        if i in (0, npts - 1):
            peaks.append((w[i], v[i]))
            continue
        res = optimize.minimize_scalar(
            lambda om: -residual_vibration(shaper, om, r.zeta),
            bounds=(w[i - 1], w[i + 1]),
            method="bounded",
            options={"xatol": 1e-10 * max(1.0, w[i])},
        )
        om = float(res.x)
        vv = float(-res.fun)
        peaks.append((om, vv) if vv >= v[i] else (w[i], v[i]))
    vmax = max(p[1] for p in peaks)
    return float(max(vmax, v.max())), peaks


def _verify(shaper, ranges):
    """Per-range verified max V and the peaks violating the tolerance."""
    maxima = []
    violations = []  # (omega, range index)
    for i, r in enumerate(ranges):
        vmax, peaks = _range_local_maxima(shaper, r)
        maxima.append(vmax)
        if r.vtol >= 1.0:
            # imposes nothing (V <= 1 for positive shapers); a peak of V = 1 must not be
            # added as a sample, where V <= 1 - margin would be a needless, degenerate
            # constraint (all impulses in phase)
            continue
        for om, vv in peaks:
            if vv > r.vtol * (1.0 - 0.5 * _VTOL_MARGIN):
                violations.append((om, i))
    return np.array(maxima), violations


# --------------------------------------------------------------------------------------
# SI shaper design loop
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SIShaperResult:
    """Result of :func:`si_shaper`.

    Attributes
    ----------
    shaper : Shaper
        The specified-insensitivity shaper.
    ranges : list of FrequencyRange
        The design ranges (rad/s).
    max_prv : numpy.ndarray, shape (n_ranges,)
        Verified maximum residual vibration fraction on each range (dense grid refined at
        its local maxima).
    iterations : int
        Number of NLP solves.
    statuses : list of str
        Solver return status of every solve.
    solver_iterations : list of int
        Solver iterations of every solve.
    samples : SISample
        Final sample set (the formulation of the last solve).
    final_guess : Shaper
        Start point of the last solve (pruned/merged result of the previous one).
    initial_guess : Shaper
        The start of the first solve (convolved EI shapers).

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> res = si_shaper([FrequencyRange(0.9 * hz, 1.1 * hz, 0.0, 0.05)])
    >>> res.iterations, res.statuses, len(res.shaper)
    (1, ['Solve_Succeeded'], 3)
    >>> res.max_prv.round(4).tolist(), round(res.duration, 3)
    ([0.05], 0.888)
    """

    shaper: Shaper
    ranges: list
    max_prv: np.ndarray
    iterations: int
    statuses: list
    solver_iterations: list = field(default_factory=list)
    samples: SISample | None = None
    final_guess: Shaper | None = None
    initial_guess: Shaper | None = None

    @property
    def duration(self):
        """Duration of the shaper, s."""
        return self.shaper.duration


def _guess_component(r):
    """Shaper of the EI family at the range midpoint for the initial guess.

    The EI shaper is used when it keeps V below vtol over the whole range (always the case
    for ranges narrower than about ±20 % at 5 %); otherwise the two-hump, then the
    three-hump EI shaper, and finally three-hump convolved with EI (so that the NLP has enough
    impulses to be feasible). A damped form that cannot be solved falls back to the undamped
    form at the damped midpoint frequency.
    """
    vtol = min(r.vtol, 0.999)
    w = np.linspace(r.omega_min, r.omega_max, 201)

    def build(fun):
        try:
            return fun(r.omega_mid, r.zeta, vtol)
        except SolverError:
            return fun(r.omega_mid * math.sqrt(1.0 - r.zeta**2), 0.0, vtol)

    candidates = [build(ei), build(ei_two_hump), build(ei_three_hump)]
    for cand in candidates:
        if np.max(residual_vibration(cand, w, r.zeta)) <= r.vtol * (1.0 + 1e-9):
            return cand
    return candidates[-1].convolve(candidates[0])


def initial_si_guess(ranges, n_impulses=None):
    """Start point of the SI design: EI shapers at the range midpoints convolved (§6.1.3).

    Ranges with ``vtol >= 1`` impose nothing and are skipped. With ``n_impulses`` the
    closest impulses are merged (amplitude-weighted time) until at most that many remain.

    Parameters
    ----------
    ranges : list of FrequencyRange
    n_impulses : int, optional
        Maximum number of impulses of the guess.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> g = initial_si_guess([FrequencyRange(3 * hz, 4 * hz, 0.0, 0.05),
    ...                       FrequencyRange(9 * hz, 13 * hz, 0.0, 0.05),
    ...                       FrequencyRange(20 * hz, 24 * hz, 0.0, 0.05)])
    >>> round(g.duration, 3)
    0.422
    """
    ranges = _as_ranges(ranges)
    parts = [_guess_component(r) for r in ranges if r.vtol < 1.0]
    if not parts:
        return Shaper([0.0], [1.0])
    guess = convolve(*parts)
    if n_impulses is not None:
        n_impulses = int(n_impulses)
        if n_impulses < 1:
            raise ProblemFileError(None, "n_impulses", n_impulses, "must be >= 1")
        t = list(guess.times)
        a = list(guess.amplitudes)
        while len(t) > n_impulses:
            j = int(np.argmin(np.diff(t)))
            w = a[j] + a[j + 1]
            tm = (a[j] * t[j] + a[j + 1] * t[j + 1]) / w if w > 0 else 0.5 * (t[j] + t[j + 1])
            t[j : j + 2] = [tm]
            a[j : j + 2] = [w]
        t[0] = 0.0
        guess = Shaper(t, a)
    return guess


def _prune(shaper, eps_amplitude, eps_time):
    """Drop impulses with amplitude < eps_amplitude and merge impulses closer than eps_time."""
    t = shaper.times
    a = shaper.amplitudes
    keep = a >= eps_amplitude
    if not np.any(keep):
        keep[np.argmax(a)] = True
    t, a = t[keep], a[keep]
    # merge coincident: keep the earlier time for the first impulse, amplitude-weighted else
    out_t, out_a = [t[0]], [a[0]]
    for ti, ai in zip(t[1:], a[1:], strict=True):
        if ti - out_t[-1] < eps_time:
            w = out_a[-1] + ai
            if len(out_t) > 1:
                out_t[-1] = (out_a[-1] * out_t[-1] + ai * ti) / w
            out_a[-1] = w
        else:
            out_t.append(ti)
            out_a.append(ai)
    out_a = np.array(out_a)
    out_t = np.array(out_t)
    out_t[0] = 0.0
    return Shaper(out_t, out_a / out_a.sum())


def _initial_samples_per_range(ranges, duration, samples_per_range):
    if samples_per_range is not None:
        return samples_per_range
    counts = []
    for r in ranges:
        width = r.omega_max - r.omega_min
        # about four samples per oscillation of V(ω) (period 2π / duration)
        counts.append(int(min(60, max(5, math.ceil(4.0 * width * duration / (2.0 * math.pi)) + 1))))
    return counts


def _fail(ranges, shaper, status, what):
    vmax, _ = _verify(shaper, ranges)
    excess = vmax - np.array([r.vtol for r in ranges])
    i = int(np.argmax(excess))
    r = ranges[i]
    raise SolverError(
        f"{what} (solver status '{status}'): range {i} "
        f"[{r.omega_min:.6g}, {r.omega_max:.6g}] rad/s, zeta={r.zeta:.4g}, "
        f"vtol={r.vtol:.4g} not met (max V = {vmax[i]:.4g} at the last iterate)"
    )


def si_shaper(
    ranges,
    n_impulses=None,
    *,
    method="ipopt",
    samples_per_range=None,
    eps_amplitude=1e-4,
    eps_time=1e-5,
    verify_tol=1e-6,
    max_solves=40,
    guess=None,
    options=None,
):
    """Design a specified-insensitivity (SI) shaper for one or more frequency ranges.

    The algorithm of §6.1.3: start from EI shapers designed for the range midpoints and
    convolved (:func:`initial_si_guess`), minimise the last impulse time subject to
    ``V <= vtol`` at sample frequencies of every range (:func:`solve_si_nlp`), then drop
    impulses with amplitude below ``eps_amplitude``, merge impulses closer than
    ``eps_time`` and solve again until nothing changes. Because sampling alone is no
    guarantee, after every solve V is evaluated on a dense grid of every range (refined at
    its local maxima); the violating peaks are added to the samples and the problem is solved
    again until every range holds within ``verify_tol``. A solve that fails from the pruned
    previous solution (infeasible for the new samples) is repeated once from the initial
    guess on the same samples before the design gives up. Ranges with ``vtol >= 1`` are
    checked and reported but never add samples.

    Parameters
    ----------
    ranges : sequence of FrequencyRange (or (omega_min, omega_max, zeta, vtol) tuples)
        Frequencies in rad/s. Ranges with ``vtol == 1`` impose nothing.
    n_impulses : int, optional
        Maximum number of impulses of the initial guess (closest impulses of the convolved
        EI guess merged). Default: no limit.
    method : {"ipopt", "slsqp"}, optional
        NLP solver used for every solve.
    samples_per_range : int or sequence of int, optional
        Initial number of samples on each range (default: about four per oscillation of V).
    eps_amplitude : float, optional
        Impulses with smaller amplitude are removed.
    eps_time : float, optional
        Impulses closer than this (s) are merged.
    verify_tol : float, optional
        Allowed excess of the verified max V over vtol.
    max_solves : int, optional
        Maximum number of NLP solves.
    guess : Shaper, optional
        Start point instead of the convolved EI shapers.
    options : dict, optional
        Solver options passed to :func:`solve_si_nlp`.

    Returns
    -------
    SIShaperResult

    Raises
    ------
    SolverError
        If a solve fails (naming the range and tolerance at fault and the solver status) or
        the loop does not settle within ``max_solves`` solves.

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> res = si_shaper([FrequencyRange(0.7 * hz, 1.3 * hz, 0.0, 0.05)])
    >>> bool(res.max_prv[0] <= 0.05 + 1e-6), bool(1.0 < res.duration < 1.5)
    (True, True)
    """
    ranges = _as_ranges(ranges)
    if int(max_solves) < 1:
        raise ProblemFileError(None, "max_solves", max_solves, "must be >= 1")
    active = [r for r in ranges if r.vtol < 1.0]
    if not active:
        trivial = Shaper([0.0], [1.0])
        vmax, _ = _verify(trivial, ranges)
        return SIShaperResult(trivial, ranges, vmax, 0, [], [], None, trivial, trivial)
    start = _as_shaper(guess) if guess is not None else initial_si_guess(ranges, n_impulses)
    counts = _initial_samples_per_range(ranges, max(start.duration, 1e-3), samples_per_range)
    samples = SISample.from_ranges(ranges, counts)
    current = start
    statuses, iters = [], []
    for _ in range(int(max_solves)):
        sol = solve_si_nlp(samples, current, method=method, options=options)
        statuses.append(sol.status)
        iters.append(sol.iterations)
        if not sol.success and current is not start:
            # The pruned previous solution violates the newly added samples; from such an
            # infeasible start Ipopt's restoration phase can end in a point of local
            # infeasibility. Start again from the initial guess on the same samples.
            retry = solve_si_nlp(samples, start, method=method, options=options)
            statuses.append(retry.status)
            iters.append(retry.iterations)
            if retry.success:
                sol = retry
        if not sol.success:
            _fail(ranges, sol.shaper, sol.status, "SI shaper NLP did not converge")
        pruned = _prune(sol.shaper, eps_amplitude, eps_time)
        changed = len(pruned) != len(sol.shaper)
        vmax, violations = _verify(sol.shaper, ranges)
        excess = vmax - np.array([r.vtol for r in ranges])
        if np.any(excess > verify_tol):
            new = [(om, i) for om, i in violations]
            samples = samples.with_points([p[0] for p in new], [p[1] for p in new], ranges)
            current = pruned
            continue
        if changed:
            current = pruned
            continue
        return SIShaperResult(
            shaper=sol.shaper,
            ranges=ranges,
            max_prv=vmax,
            iterations=len(statuses),
            statuses=statuses,
            solver_iterations=iters,
            samples=samples,
            final_guess=current,
            initial_guess=start,
        )
    _fail(ranges, sol.shaper, statuses[-1], f"SI shaper loop did not settle in {max_solves} solves")


def si_shaper_slsqp(ranges, n_impulses=None, **kwargs):
    """:func:`si_shaper` with every NLP solved by SciPy's SLSQP instead of Ipopt.

    Parameters
    ----------
    ranges : sequence of FrequencyRange
        Frequencies in rad/s.
    n_impulses : int, optional
        See :func:`si_shaper`.
    **kwargs
        Other keyword arguments of :func:`si_shaper`.

    Returns
    -------
    SIShaperResult

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> res = si_shaper_slsqp([FrequencyRange(0.81 * hz, 1.19 * hz, 0.0, 0.05)])
    >>> round(res.duration, 2)
    0.99
    """
    return si_shaper(ranges, n_impulses, method="slsqp", **kwargs)


# --------------------------------------------------------------------------------------
# shapers for planned moves of a flexible arm (§6.1.4–6.1.5)
# --------------------------------------------------------------------------------------
def _model_functions(model):
    """``model.functions()`` of a :class:`casflex.dynamics.FlexibleModel` or ModelError."""
    if not hasattr(model, "functions") or not hasattr(model, "m") or not hasattr(model, "n"):
        raise ModelError(
            f"model: expected a casflex.dynamics.FlexibleModel (e.g. from "
            f"casflex.model.build_model); got {type(model).__name__}"
        )
    if int(model.m) < 1:
        raise ModelError("model: has no flexible modes (m = 0); nothing to shape")
    return model.functions()


def _check_samples(n_samples, name="n_samples"):
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)):
        raise ProblemFileError(None, name, n_samples, "must be an integer >= 2")
    if n_samples < 2:
        raise ProblemFileError(None, name, n_samples, "must be an integer >= 2")
    return int(n_samples)


def _sampled_reference(reference, n_joints=None):
    """Validate a sampled reference ``(t, q, dq, ddq)``; return t (N,), q, ddq (N, n)."""
    if not isinstance(reference, (tuple, list)) or len(reference) != 4:
        raise ProblemFileError(
            None,
            "reference",
            type(reference).__name__,
            "must be a casflex.moves.Move or a sampled (t, q, dq, ddq) tuple "
            "(e.g. the output of apply_shaper)",
        )
    t, q, _, ddq = reference
    t = np.asarray(t, dtype=float).reshape(-1)
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise ProblemFileError(
            None,
            "reference.t",
            f"{t.size} samples",
            "needs >= 2 finite, strictly increasing times [s]",
        )
    out = []
    for name, x in (("q", q), ("ddq", ddq)):
        if x is None:
            raise ProblemFileError(None, f"reference.{name}", None, "is required [rad, rad/s²]")
        x = np.asarray(x, dtype=float)
        x = x.reshape(t.size, 1) if x.ndim == 1 and x.size == t.size else x
        if x.ndim != 2 or x.shape[0] != t.size:
            raise ProblemFileError(
                None, f"reference.{name}", x.shape, f"must have shape ({t.size}, n_joints)"
            )
        if not np.all(np.isfinite(x)):
            raise ProblemFileError(None, f"reference.{name}", "...", "must be finite")
        out.append(x)
    q, ddq = out
    if q.shape != ddq.shape:
        raise ProblemFileError(
            None, "reference.ddq", ddq.shape, f"must have the shape of reference.q {q.shape}"
        )
    if n_joints is not None and q.shape[1] != n_joints:
        raise ModelError(
            f"reference: has {q.shape[1]} joint(s) but the model has {n_joints}; "
            "give one column per joint"
        )
    return t, q, ddq


def _check_move_joints(move, n_joints):
    if n_joints is not None and move.n_joints != n_joints:
        raise ModelError(
            f"reference: move '{move.name}' has {move.n_joints} joint(s) but the model has "
            f"{n_joints}"
        )


def _quadrature(reference, n_samples, n_joints=None):
    """Nodes and weights to integrate along the reference: ``t, q, ddq, weights``.

    A :class:`~casflex.moves.Move` is integrated over ``[0, duration]`` with the midpoint
    rule on an even number of intervals, so that no node falls on a switch of the
    bang-bang acceleration (at 0, T/2 and T) and the integral is exact to O(h²) on each
    smooth piece. A sampled reference uses its own samples and the trapezoidal rule.
    """
    if isinstance(reference, Move):
        _check_move_joints(reference, n_joints)
        n = _check_samples(n_samples)
        n += n % 2
        h = reference.duration / n
        t = (np.arange(n) + 0.5) * h
        q, _, ddq = reference.sample(t)
        return t, q, ddq, np.full(n, h)
    t, q, ddq = _sampled_reference(reference, n_joints)
    dt = np.diff(t)
    w = np.zeros(t.size)
    w[:-1] += 0.5 * dt
    w[1:] += 0.5 * dt
    return t, q, ddq, w


def _path(reference, n_samples, n_joints=None):
    """Positions along the reference (end points included): ``t, q``."""
    if isinstance(reference, Move):
        _check_move_joints(reference, n_joints)
        t = np.linspace(0.0, reference.duration, _check_samples(n_samples) + 1)
        return t, reference.sample(t)[0]
    t, q, _ = _sampled_reference(reference, n_joints)
    return t, q


def _point_jacobian(model, functions, point):
    """casadi.Function ``q -> ∂p/∂δ (3, m)`` at δ = 0 for the chosen point."""
    q = ca.SX.sym("q", model.n)
    d = ca.SX.sym("delta", model.m)
    if point is None:
        p = functions["tip"](q, d)
    elif isinstance(point, ca.Function):
        if point.n_in() != 2 or point.numel_out(0) != 3:
            raise ModelError(
                f"point: a casadi.Function must map (q, delta) to a 3-vector [m]; got "
                f"{point.n_in()} input(s) and {point.numel_out(0)} output entries"
            )
        p = point(q, d)
    elif isinstance(point, (int, np.integer)) and not isinstance(point, bool):
        frames = functions["frames"]
        if not 0 <= int(point) < frames.n_out():
            raise ModelError(
                f"point: frame index {point} out of range; the robot has {frames.n_out()} "
                f"DH rows (0-based; {frames.n_out() - 1} is the last frame, the tip)"
            )
        p = frames(q, d)[int(point)][:3, 3]
    else:
        raise ModelError(
            f"point: {point!r} is not None (the tip), a 0-based DH row index (origin of its "
            "frame) or a casadi.Function (q, delta) -> 3-vector"
        )
    jac = ca.substitute(ca.jacobian(p, d), d, ca.SX.zeros(model.m))
    return ca.Function("point_modal_displacement", [q], [jac], ["q"], ["W"])


def modal_displacements(model, q, point=None):
    """Total modal displacement ``w_j(p)`` of a point at a configuration (eq. 197).

    ``w_j(p) = ‖∂p/∂δ_j‖`` at ``δ = 0``: the length of the displacement of point ``p``
    caused by a unit amplitude of the mass-normalised mode ``j``, from the model's
    kinematics (CasADi Jacobian of the point's position with respect to ``δ``).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    q : array_like, shape (n,)
        Configuration, rad.
    point : None, int or casadi.Function, optional
        ``None`` for the tip (``model.functions()["tip"]``), an integer for the origin of
        the frame of that 0-based DH row (``frames``), or a ``casadi.Function`` mapping
        ``(q, delta)`` to a position (3-vector, m).

    Returns
    -------
    numpy.ndarray, shape (m,)
        Modal displacements, m per unit modal amplitude.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=3),
    ...                       gravity=None)
    >>> modal_displacements(model, [0.0, 0.0, 0.0]).round(2).tolist()
    [4.73, 4.56, 4.18]
    """
    functions = _model_functions(model)
    q = np.asarray(q, dtype=float).reshape(-1)
    if q.size != model.n or not np.all(np.isfinite(q)):
        raise ModelError(f"q: expected {model.n} finite joint values [rad]; got {q.tolist()}")
    jac = _point_jacobian(model, functions, point)(q).full()
    return np.linalg.norm(jac, axis=0)


def modal_contributions(model, reference, point=None, n_samples=400, normalize=True):
    """Relative contribution of every mode to the deflection of a point (eq. 196–197).

    ``r_j = ∫ (|M_qδᵀ(q_d(t))| |q̈_d(t)|)_j dt · w_j(p)`` from the start to the end of the
    planned trajectory, with ``|·|`` taken element-wise (eq. 194: the joint accelerations
    drive the modes through ``M_qδ``) and ``w_j(p)`` the total modal displacement of the
    point at the end configuration (eq. 197, :func:`modal_displacements`). Coriolis and
    centrifugal coupling are neglected, as in the dissertation.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
        Its ``mass`` function gives ``M_qδ = M[:n, n:]`` at ``δ = 0``.
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
        The planned joint trajectory: a move (integrated over ``[0, duration]`` with the
        midpoint rule, which never samples the switches of the bang-bang acceleration) or
        sampled arrays (s, rad, rad/s, rad/s²; shape (N,) and (N, n); trapezoidal rule;
        ``dq`` is not used), e.g. the output of :func:`apply_shaper`. The end configuration
        is ``move.qf`` or the last sample.
    point : None, int or casadi.Function, optional
        The point ``p`` (default the tip), see :func:`modal_displacements`.
    n_samples : int, optional
        Quadrature intervals for a move (rounded up to an even number).
    normalize : bool, optional
        Divide by the largest contribution (the dissertation's normalised ``r``; all zeros
        if nothing is excited). With ``False`` the raw values are returned: with the mass
        normalisation ``M_δδ = I`` they are a bound on the speed, m/s, that each mode gives
        the point by the end of the move. Values below 1e-12 of the largest (round-off of
        couplings that vanish, e.g. out-of-plane modes in a planar move) are set to 0.

    Returns
    -------
    numpy.ndarray, shape (m,)
        ``r`` (dimensionless, max 1) or the raw values.

    Examples
    --------
    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=3),
    ...                       gravity=None)
    >>> move3 = load_move("problems/moves.toml:move3")    # q1 only: shapes do not change
    >>> modal_contributions(model, move3).round(2).tolist()
    [1.0, 0.0, 0.38]
    """
    functions = _model_functions(model)
    n, m = int(model.n), int(model.m)
    t, q, ddq, w = _quadrature(reference, n_samples, n)
    mass = functions["mass"].map(t.size)
    big = mass(q.T, np.zeros((m, t.size))).full()  # (n+m, N*(n+m))
    mqd = big.reshape(n + m, t.size, n + m)[:n, :, n:]  # (n, N, m)
    integrand = np.einsum("inj,ni->nj", np.abs(mqd), np.abs(ddq))  # (N, m)
    integral = w @ integrand
    q_end = reference.qf if isinstance(reference, Move) else q[-1]
    r = integral * modal_displacements(model, q_end, point)
    r[r <= 1e-12 * float(np.max(r))] = 0.0  # round-off of couplings that vanish exactly
    if not normalize:
        return r
    peak = float(np.max(r))
    return r / peak if peak > 0.0 else np.zeros_like(r)


def tolerances_from_contributions(r, vtol=0.05):
    """Tolerable residual vibration of every mode from its contribution (eq. 198).

    The mode with the largest contribution ``r_j`` gets ``vtol``; every other mode ``s``
    gets ``Vtol_s = (r_j / r_s) vtol``, clamped to at most 1 (1 imposes nothing: a mode
    that is not excited, ``r_s → 0``, gets 1). If no mode is excited all are 1.

    Note that the dissertation's example in §6.1.4 quotes ``Vtol = [0.05, 0.05, 0.67]``
    for ``r = [4, 2, 0.3]``; the formula gives ``[0.05, 0.10, 0.67]`` (the 0.30 s shaper
    it reports is the one for the latter).

    Parameters
    ----------
    r : array_like, shape (m,)
        Contributions (normalised or raw; only ratios matter), finite and >= 0.
    vtol : float, optional
        Tolerable residual vibration fraction of the dominant mode, 0 < vtol <= 1.

    Returns
    -------
    numpy.ndarray, shape (m,)
        Residual vibration fractions in ``[vtol, 1]``.

    Examples
    --------
    >>> tolerances_from_contributions([4.0, 2.0, 0.3]).round(3).tolist()
    [0.05, 0.1, 0.667]
    >>> tolerances_from_contributions([0.0, 1.0, 0.0]).tolist()
    [1.0, 0.05, 1.0]
    """
    vtol = _check_vtol(vtol)
    try:
        arr = np.asarray(r, dtype=float)
    except (TypeError, ValueError):
        raise ProblemFileError(None, "r", r, "contributions must be numbers") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ProblemFileError(
            None, "r", np.shape(r), "contributions must be a non-empty 1-D array"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise ProblemFileError(None, "r", arr.tolist(), "contributions must be finite and >= 0")
    peak = float(arr.max())
    out = np.ones_like(arr)
    if peak <= 0.0:
        return out
    pos = arr > 0.0
    out[pos] = np.minimum(1.0, vtol * peak / arr[pos])
    return out


def frequencies_along(model_or_table, reference, n_samples=200):
    """Tracked natural frequencies along a planned joint trajectory.

    Parameters
    ----------
    model_or_table : casflex.dynamics.FlexibleModel or casflex.modal.tables.ModalTable
        A model (``ω = sqrt(diag K(q))`` from its ``stiffness`` function) or a modal table
        (its B-spline ``omega`` interpolant over the shape joints).
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
        The trajectory (see :func:`modal_contributions`); a move is sampled at
        ``n_samples + 1`` evenly spaced times over ``[0, duration]``.
    n_samples : int, optional
        Intervals for a move.

    Returns
    -------
    t : numpy.ndarray, shape (N,)
        Times, s.
    omega : numpy.ndarray, shape (N, m)
        Frequencies of the tracked modes, rad/s.

    Examples
    --------
    >>> from casflex.modal.tables import ModalTable
    >>> from casflex.moves import Move
    >>> axis = np.linspace(-1.0, 0.0, 5)
    >>> table = ModalTable(grid=(axis,), shape_joints=(0,), values={},
    ...                    omega=np.column_stack([10 + axis, 30 - 2 * axis]))
    >>> t, w = frequencies_along(table, Move(q0=[0.0], qf=[-1.0], duration=1.0), 4)
    >>> w[[0, -1]].round(6).tolist()
    [[10.0, 30.0], [9.0, 32.0]]
    """
    obj = model_or_table
    if hasattr(obj, "grid") and hasattr(obj, "shape_joints") and hasattr(obj, "omega"):
        joints = tuple(int(k) for k in obj.shape_joints)
        t, q = _path(reference, n_samples)
        if q.shape[1] <= max(joints):
            raise ModelError(
                f"reference: has {q.shape[1]} joint(s) but the table's shape joints are "
                f"{[k + 1 for k in joints]} (1-based)"
            )
        f = obj.function("omega")
        omega = f.map(t.size)(q[:, list(joints)].T).full().T
        return t, omega.reshape(t.size, -1)
    functions = _model_functions(obj)
    t, q = _path(reference, n_samples, int(obj.n))
    k = functions["stiffness"].map(t.size)(q.T).full()  # (m, N*m)
    m = int(obj.m)
    diag = k.reshape(m, t.size, m)[np.arange(m), :, np.arange(m)].T  # (N, m)
    return t, np.sqrt(np.clip(diag, 0.0, None))


def _per_mode(value, m, name, check):
    arr = np.asarray(value, dtype=float) if not isinstance(value, (int, float)) else None
    if arr is None or arr.ndim == 0:
        v = check(value if arr is None else float(arr), name)
        return [v] * m
    arr = arr.reshape(-1)
    if arr.size != m:
        raise ProblemFileError(None, name, arr.tolist(), f"needs one value per mode ({m})")
    return [check(float(v), f"{name}[{i}]") for i, v in enumerate(arr)]


def _check_margin(margin):
    margin = _finite_float(margin, "margin")
    if not 0.0 <= margin < 1.0:
        raise ProblemFileError(
            None, "margin", margin, "relative margin must satisfy 0 <= margin < 1"
        )
    return margin


def frequency_ranges_along(model_or_table, reference, margin=0.20, zeta=None, vtol=0.05,
                           n_samples=200):
    """Frequency ranges the modes sweep during a planned move, widened by a margin.

    Every mode's range is ``[(1 - margin) min ω_j, (1 + margin) max ω_j]`` over the
    trajectory (:func:`frequencies_along`): the ±20 % robustness margin of §6.1.5 by
    default. With ``margin = 0`` a mode whose frequency does not change gives a single
    frequency.

    Parameters
    ----------
    model_or_table : casflex.dynamics.FlexibleModel or casflex.modal.tables.ModalTable
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
    margin : float, optional
        Relative widening on each side, 0 <= margin < 1.
    zeta : float or array_like, optional
        Damping ratio per mode (or one for all); default the model's ``damping_ratio``
        (0 for a table).
    vtol : float or array_like, optional
        Tolerable residual vibration per mode (or one for all), 0 < vtol <= 1.
    n_samples : int, optional
        Samples of a move (see :func:`frequencies_along`).

    Returns
    -------
    list of FrequencyRange
        One per mode, rad/s.

    Examples
    --------
    >>> from casflex.modal.tables import ModalTable
    >>> from casflex.moves import Move
    >>> axis = np.linspace(-1.0, 0.0, 5)
    >>> table = ModalTable(grid=(axis,), shape_joints=(0,), values={},
    ...                    omega=np.column_stack([10 + axis, 30 - 2 * axis]))
    >>> r = frequency_ranges_along(table, Move(q0=[0.0], qf=[-1.0], duration=1.0),
    ...                            vtol=[0.05, 1.0])
    >>> [(round(x.omega_min, 3), round(x.omega_max, 3), x.vtol) for x in r]
    [(7.2, 12.0, 0.05), (24.0, 38.4, 1.0)]
    """
    margin = _check_margin(margin)
    _, omega = frequencies_along(model_or_table, reference, n_samples)
    if zeta is None:
        zeta = float(getattr(model_or_table, "damping_ratio", 0.0) or 0.0)
    return _ranges_from_omega(omega, margin, zeta, vtol)


def _ranges_from_omega(omega, margin, zeta, vtol):
    m = omega.shape[1]
    zetas = _per_mode(zeta, m, "zeta", _check_zeta)
    vtols = _per_mode(vtol, m, "vtol", _check_vtol)
    lo, hi = omega.min(axis=0), omega.max(axis=0)
    if np.any(lo <= 0.0):
        j = int(np.argmin(lo))
        raise ModelError(f"mode {j + 1} has a non-positive frequency ({lo[j]:.4g} rad/s) along "
                         "the trajectory: a rigid-body mode cannot be shaped")
    return [
        FrequencyRange(float(a) * (1.0 - margin), float(b) * (1.0 + margin), z, v)
        for a, b, z, v in zip(lo, hi, zetas, vtols, strict=True)
    ]


@dataclass(frozen=True, eq=False)
class MoveShaperResult:
    """Result of :func:`shaper_for_move`.

    Attributes
    ----------
    shaper : Shaper
        The SI shaper.
    ranges : list of FrequencyRange
        Design ranges (rad/s, margin included) with the tolerances of every mode.
    contributions : numpy.ndarray, shape (m,)
        Normalised modal contributions ``r`` (eq. 196, max 1).
    raw_contributions : numpy.ndarray, shape (m,)
        The same before normalisation, m/s (see :func:`modal_contributions`).
    tolerances : numpy.ndarray, shape (m,)
        ``Vtol`` of every mode (eq. 198).
    omega_min, omega_max : numpy.ndarray, shape (m,)
        Frequency span of every mode along the move without the margin, rad/s.
    margin : float
        Relative margin added to the spans.
    si : SIShaperResult
        The full SI design result (verified maximum PRV per range, solver statuses).

    Examples
    --------
    Two modes of the arm frozen at one configuration, so each range is a single frequency:

    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=2),
    ...                       gravity=None)
    >>> res = shaper_for_move(model, load_move("problems/moves.toml:move3"), margin=0.0,
    ...                       n_samples=50)
    >>> res.contributions.round(3).tolist(), res.tolerances.round(3).tolist()
    ([1.0, 0.0], [0.05, 1.0])
    >>> res.omega_min.round(3).tolist(), round(res.duration, 3)
    ([8.307, 11.97], 0.366)
    """

    shaper: Shaper
    ranges: list
    contributions: np.ndarray
    raw_contributions: np.ndarray
    tolerances: np.ndarray
    omega_min: np.ndarray
    omega_max: np.ndarray
    margin: float
    si: SIShaperResult

    @property
    def duration(self):
        """Shaper duration, s."""
        return self.shaper.duration

    @property
    def max_prv(self):
        """Verified maximum residual vibration fraction on every range."""
        return self.si.max_prv


def shaper_for_move(model, reference, vtol=0.05, margin=0.20, zeta=None, *, point=None,
                    n_samples=400, n_impulses="auto", **si_options):
    """Design the SI shaper of a planned move from its modal contributions (§6.1.4).

    The steps of the dissertation: the contributions ``r`` of every mode to the deflection
    of ``point`` (:func:`modal_contributions`, eq. 196–197), the tolerances
    ``Vtol`` (:func:`tolerances_from_contributions`, eq. 198), the frequency span of every
    mode along the move widened by ``±margin`` (:func:`frequency_ranges_along`), and the
    minimum-duration SI shaper for those ranges (:func:`si_shaper`).

    The dissertation's simulated moves (§6.1.5.1, Table 14) use the frequency spans
    without a margin (``margin=0``), which reproduces its durations; its ±20 % is the
    robustness margin of the testbed experiments and the default here.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
        Planned joint trajectory (s, rad, rad/s, rad/s²).
    vtol : float, optional
        Tolerable residual vibration of the dominant mode, 0 < vtol <= 1.
    margin : float, optional
        Relative widening of every frequency span, 0 <= margin < 1.
    zeta : float or array_like, optional
        Damping ratio per mode; default the model's ``damping_ratio``.
    point : None, int or casadi.Function, optional
        Point whose deflection matters (default the tip), see :func:`modal_displacements`.
    n_samples : int, optional
        Samples along a move for the contributions and the frequencies.
    n_impulses : "auto", int or None, optional
        Impulses of the initial guess (see :func:`si_shaper`). ``"auto"`` first tries
        four per constrained range (the convolved EI guess of wide, overlapping ranges can
        have dozens of impulses, most of which the optimum drops, and an NLP that large is
        slow) and falls back to the full guess if that design fails; ``None`` always uses
        the full guess.
    **si_options
        Further keyword arguments of :func:`si_shaper`.

    Returns
    -------
    MoveShaperResult

    Raises
    ------
    SolverError
        If the SI design fails.

    Examples
    --------
    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=3),
    ...                       gravity=None)
    >>> res = shaper_for_move(model, load_move("problems/moves.toml:move3"), margin=0.0)
    >>> res.tolerances.round(2).tolist(), round(res.duration, 2)
    ([0.05, 1.0, 0.13], 0.39)
    """
    raw = modal_contributions(model, reference, point=point, n_samples=n_samples,
                              normalize=False)
    peak = float(np.max(raw))
    r = raw / peak if peak > 0.0 else np.zeros_like(raw)
    tol = tolerances_from_contributions(r, vtol)
    margin = _check_margin(margin)
    _, omega = frequencies_along(model, reference, n_samples)
    ranges = _ranges_from_omega(omega, margin, model.damping_ratio if zeta is None else zeta,
                                tol)
    active = sum(1 for x in ranges if x.vtol < 1.0)
    if isinstance(n_impulses, str):
        if n_impulses != "auto":
            raise ProblemFileError(None, "n_impulses", n_impulses,
                                   "must be 'auto', None or an integer >= 1")
        limit = 4 * active
        guess_size = len(initial_si_guess(ranges)) if active else 1
        if active and guess_size > limit:
            try:
                si = si_shaper(ranges, limit, **si_options)
            except SolverError:
                si = si_shaper(ranges, None, **si_options)
        else:
            si = si_shaper(ranges, None, **si_options)
    else:
        si = si_shaper(ranges, n_impulses, **si_options)
    return MoveShaperResult(
        shaper=si.shaper,
        ranges=list(ranges),
        contributions=r,
        raw_contributions=raw,
        tolerances=tol,
        omega_min=omega.min(axis=0),
        omega_max=omega.max(axis=0),
        margin=margin,
        si=si,
    )


def shaped_reference(shaper, move, dt=1e-3, t_end=None):
    """Sample a move and shape it: the reference for a shaped simulation.

    The move is sampled every ``dt`` from 0 to ``t_end`` (default ``move.t_end``, the
    move plus its settle time) and convolved with the shaper (:func:`apply_shaper`), which
    extends it by the shaper's duration: the shaped move ends at
    ``move.duration + shaper.duration`` and is followed by the same settle time.

    Parameters
    ----------
    shaper : Shaper
    move : casflex.moves.Move
    dt : float, optional
        Sample step, s.
    t_end : float, optional
        End of the unshaped samples, s.

    Returns
    -------
    tuple (t, q, dq, ddq)
        s, rad, rad/s, rad/s²; arrays of shape (N,) and (N, n).

    Examples
    --------
    >>> from casflex.moves import Move
    >>> t, q, dq, ddq = shaped_reference(zv(10.0), Move(q0=[0.0], qf=[1.0], duration=1.0,
    ...                                                settle=0.5), dt=0.01)
    >>> round(float(t[-1]), 2), round(float(q[-1, 0]), 6)
    (1.82, 1.0)
    """
    shaper = _as_shaper(shaper)
    if not isinstance(move, Move):
        raise ProblemFileError(None, "move", type(move).__name__, "must be a casflex.moves.Move")
    dt = _finite_float(dt, "dt")
    if dt <= 0.0:
        raise ProblemFileError(None, "dt", dt, "sample step must be > 0 s")
    t_end = move.t_end if t_end is None else _finite_float(t_end, "t_end")
    if t_end <= dt:
        raise ProblemFileError(None, "t_end", t_end, f"must exceed the step dt = {dt} s")
    t = np.arange(int(round(t_end / dt)) + 1) * dt
    q, dq, ddq = move.sample(t)
    return apply_shaper(shaper, t, q, dq, ddq)


def residual_amplitude(t, deflection, t_from):
    """Largest deflection (vector norm) from ``t_from`` on: the residual vibration.

    Parameters
    ----------
    t : array_like, shape (N,)
        Times, s.
    deflection : array_like, shape (N,) or (N, 3)
        Deflection of a point (e.g. ``SimulationResult.tip_deflection``), m.
    t_from : float
        Start of the residual phase (end of the — shaped — move), s.

    Returns
    -------
    float
        ``max ‖deflection(t)‖`` for ``t >= t_from``, m.

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0, 201)
    >>> d = np.column_stack([np.exp(-t) * np.sin(20 * t), 0 * t, 0 * t])
    >>> round(residual_amplitude(t, d, 1.0), 3)   # about exp(-1)
    0.361
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    d = np.asarray(deflection, dtype=float)
    d = d.reshape(t.size, -1) if d.size else d
    if d.shape[0] != t.size:
        raise ProblemFileError(None, "deflection", d.shape, f"needs {t.size} rows (one per time)")
    t_from = _finite_float(t_from, "t_from")
    sel = t >= t_from - 1e-12
    if not np.any(sel):
        raise ProblemFileError(None, "t_from", t_from,
                               f"no sample at or after it (last time {t[-1]:.6g} s)")
    return float(np.max(np.linalg.norm(d[sel], axis=1)))
