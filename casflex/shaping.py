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

from casflex.errors import ProblemFileError, SolverError

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
    summed: ``y(t) = Σ A_i x(t - t_i)``. Before the reference starts each signal holds its
    first sample and after it ends its last sample, so position, velocity and acceleration
    shaped with the same impulses stay mutually consistent (the derivative of the shaped
    position is the shaped velocity). Values between samples are linearly interpolated.

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

    def shape(x, name):
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
                out[:, j] += a * np.interp(shifted, t, cols[:, j])
        return out.reshape((t_new.size,) + x.shape[1:])

    return t_new, shape(q, "q"), shape(qd, "qd"), shape(qdd, "qdd")


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
    again until every range holds within ``verify_tol``.

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
