"""Shapers: impulse sequences, their residual vibration and shaping a sampled reference.

§6.1.1–6.1.2 of the reference dissertation, with no knowledge of robots or models:

* :class:`Shaper` (impulse times and amplitudes) and :func:`convolve` (multi-mode
  shapers);
* the percentage residual vibration (PRV) of an under-damped second-order mode excited by
  a sequence of impulses (eq. 187–189), numerically (:func:`residual_vibration`,
  :func:`sensitivity_curve`) and as a CasADi expression
  (:func:`residual_vibration_casadi`). It is returned as a *fraction* (``0`` = no residual
  vibration, ``1`` = as much as a single unit impulse), never multiplied by 100;
* closed-form shapers: ZV (eq. 190–191), ZVD, extra-insensitive (EI) and its two- and
  three-hump variants (damped forms from :mod:`casflex.shaping.ei_family`);
* :func:`apply_shaper` to shape sampled joint references.

:func:`check_omega`, :func:`check_zeta` and :func:`check_vtol` are the argument checks of
natural frequencies, damping ratios and tolerable vibrations shared by the shaping modules.

Units are SI: times in s, frequencies in rad/s, damping ratios dimensionless.
"""

from __future__ import annotations

import heapq
import math
import os
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import number
from casflex.errors import ProblemFileError
from casflex.shaping.ei_family import ei_family_normalised

__all__ = [
    "Shaper",
    "convolve",
    "merge_closest",
    "residual_vibration",
    "DEFINITIONS",
    "residual_vibration_casadi",
    "sensitivity_curve",
    "band_maximum",
    "zv",
    "zvd",
    "ei",
    "ei_two_hump",
    "ei_three_hump",
    "apply_shaper",
]

#: Relative tolerance used to decide that two impulse times coincide when convolving.
_MERGE_RTOL = 1e-10


# --------------------------------------------------------------------------------------
# argument checks shared by the shaping modules
# --------------------------------------------------------------------------------------
def check_omega(omega: float, field: str = "omega") -> float:
    """``omega`` as a natural frequency, rad/s: a finite real number > 0.

    Parameters
    ----------
    omega : float
        The value to check.
    field : str, optional
        Argument name for the error message.

    Returns
    -------
    float

    Raises
    ------
    ProblemFileError
        Naming ``field``, the value and the rule.

    Examples
    --------
    >>> check_omega(10)
    10.0
    >>> check_omega(0.0)
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: <in-memory description>: field 'omega' = 0.0: must be > 0.0
    """
    return number(omega, field, low=0.0, low_open=True, error=ProblemFileError)


def check_zeta(zeta: float, field: str = "zeta",
               path: str | os.PathLike | None = None) -> float:
    """``zeta`` as a damping ratio: a finite real number with ``0 <= zeta < 1``.

    Parameters
    ----------
    zeta : float
        The value to check.
    field : str, optional
        Argument or dotted problem-file field name for the error message.
    path : str or os.PathLike, optional
        Problem file the value comes from.

    Returns
    -------
    float

    Raises
    ------
    ProblemFileError
        Naming ``field``, the value and the rule.

    Examples
    --------
    >>> check_zeta(0.05)
    0.05
    >>> check_zeta(1.0, "range[0].zeta", "p.toml")
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: p.toml: field 'range[0].zeta' = 1.0: must be < 1.0
    """
    return number(zeta, field, low=0.0, high=1.0, high_open=True, path=path,
                  error=ProblemFileError)


def check_vtol(vtol: float, field: str = "vtol",
               path: str | os.PathLike | None = None) -> float:
    """``vtol`` as a tolerable residual vibration fraction: finite, ``0 < vtol <= 1``.

    Parameters
    ----------
    vtol : float
        The value to check.
    field : str, optional
        Argument or dotted problem-file field name for the error message.
    path : str or os.PathLike, optional
        Problem file the value comes from.

    Returns
    -------
    float

    Raises
    ------
    ProblemFileError
        Naming ``field``, the value and the rule.

    Examples
    --------
    >>> check_vtol(1)
    1.0
    >>> check_vtol(0.0)
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: <in-memory description>: field 'vtol' = 0.0: must be > 0.0
    """
    return number(vtol, field, low=0.0, low_open=True, high=1.0, path=path,
                  error=ProblemFileError)


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

    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def duration(self) -> float:
        """Time between the first and the last impulse, s."""
        return float(self.times[-1] - self.times[0])

    def convolve(self, other: Shaper) -> Shaper:
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


def convolve(*shapers: Shaper) -> Shaper:
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


def merge_closest(shaper: Shaper, n_impulses: int) -> Shaper:
    """``shaper`` with its closest adjacent impulses merged until ``n_impulses`` remain.

    Repeatedly the adjacent pair with the smallest time gap (the earliest pair among equal
    gaps) becomes one impulse at the amplitude-weighted mean time (the midpoint for two zero
    amplitudes) with the summed amplitude; the first impulse is then moved to t = 0. A heap
    of the gaps with lazy deletion makes this O(N log N) for N impulses.

    Parameters
    ----------
    shaper : Shaper
    n_impulses : int
        Number of impulses to keep (>= 1); a shaper with no more impulses is returned with
        only its first impulse moved to t = 0.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = merge_closest(Shaper([0.0, 0.1, 1.0, 1.5], [0.25, 0.25, 0.25, 0.25]), 3)
    >>> s.times.tolist(), s.amplitudes.tolist()
    ([0.0, 1.0, 1.5], [0.5, 0.25, 0.25])
    """
    t = shaper.times.tolist()
    a = shaper.amplitudes.tolist()
    m = len(t)
    nxt = list(range(1, m + 1))  # linked list of the surviving impulses
    prv = list(range(-1, m - 1))
    alive = [True] * m
    # (gap, left index, left time, right time): the times tell a stale entry from a live one
    heap = [(t[i + 1] - t[i], i, t[i], t[i + 1]) for i in range(m - 1)]
    heapq.heapify(heap)
    count = m
    while count > n_impulses:
        _, i, ti, tj = heapq.heappop(heap)
        j = nxt[i] if alive[i] else m
        if j >= m or t[i] != ti or t[j] != tj:
            continue
        w = a[i] + a[j]
        t[i] = (a[i] * t[i] + a[j] * t[j]) / w if w > 0 else 0.5 * (t[i] + t[j])
        a[i] = w
        alive[j] = False
        nxt[i] = nxt[j]
        if nxt[i] < m:
            prv[nxt[i]] = i
            heapq.heappush(heap, (t[nxt[i]] - t[i], i, t[i], t[nxt[i]]))
        if prv[i] >= 0:
            heapq.heappush(heap, (t[i] - t[prv[i]], prv[i], t[prv[i]], t[i]))
        count -= 1
    kept = [i for i in range(m) if alive[i]]
    times = [t[i] for i in kept]
    times[0] = 0.0
    return Shaper(times, [a[i] for i in kept])


# --------------------------------------------------------------------------------------
# residual vibration
# --------------------------------------------------------------------------------------
def as_shaper(shaper: Shaper | tuple[ArrayLike, ArrayLike]) -> Shaper:
    """``shaper`` as a :class:`Shaper` (a ``(times, amplitudes)`` pair is converted).

    Parameters
    ----------
    shaper : Shaper or (times, amplitudes)
        Impulse sequence; times in s.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> as_shaper(([0.0, 0.5], [0.5, 0.5])).duration
    0.5
    """
    if isinstance(shaper, Shaper):
        return shaper
    times, amplitudes = shaper
    return Shaper(times, amplitudes)


#: The two definitions of the residual vibration fraction (see :func:`residual_vibration`).
DEFINITIONS = ("eq187", "same_instant")


def _definition(definition):
    if definition not in DEFINITIONS:
        raise ProblemFileError(None, "definition", definition,
                               f"must be one of {', '.join(DEFINITIONS)}")
    return definition == "same_instant"


def residual_vibration(shaper: Shaper | tuple[ArrayLike, ArrayLike], omega: ArrayLike,
                       zeta: ArrayLike = 0.0, *, definition: str = "eq187"
                       ) -> float | np.ndarray:
    """Residual vibration fraction V(ω, ζ) of a shaper (eq. 187–189, or at the same instant).

    ``V = exp(-ζ ω t_n) * sqrt(C² + S²)`` with
    ``C = Σ A_i exp(ζ ω t_i) cos(ω sqrt(1-ζ²) t_i)`` and ``S`` the same with ``sin``: the
    amplitude of the residual oscillation of a mode of natural frequency ``ω`` and damping
    ``ζ`` at the last impulse time, relative to the amplitude of the response to a single
    unit impulse at the moment it is applied (the normalisation of eq. 187: with damping,
    the shaped residual is compared with an unshaped one of the same age, not at the same
    absolute time).
    The dissertation calls it the percentage residual vibration (PRV); here it is a fraction
    (0.05 means 5 %).

    With ``definition="same_instant"`` the factor ``exp(-ζ ω t_n)`` is dropped:
    ``V = sqrt(C² + S²)`` is the residual oscillation of the shaped command divided by that
    of the unshaped command (a unit step at t = 0) *at the same instant*, the same ratio at
    every time after the last impulse. It is never smaller than eq. 187's value (equal when
    undamped), and unlike eq. 187 it cannot be lowered by a tiny late impulse that only
    postpones ``t_n``: that is why the SI design constrains it (:func:`casflex.shaping.si_shaper`).

    Parameters
    ----------
    shaper : Shaper or (times, amplitudes)
        Impulse sequence; times in s.
    omega : float or array_like
        Natural frequency (frequencies), rad/s.
    zeta : float or array_like, optional
        Damping ratio(s), broadcast against ``omega``.
    definition : {"eq187", "same_instant"}, optional
        Normalisation of eq. 187 (default), or relative to the unshaped response at the
        same instant.

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

    A tiny late impulse shrinks eq. 187's V, not the vibration left at the same instant:

    >>> late = Shaper([0.0, 0.064, 2.59], [0.5135, 0.485, 0.0015])
    >>> round(float(residual_vibration(late, 162.6, 0.005)), 3)
    0.059
    >>> round(float(residual_vibration(late, 162.6, 0.005, definition="same_instant")), 3)
    0.487
    """
    same_instant = _definition(definition)
    shaper = as_shaper(shaper)
    omega_b, zeta_b = np.broadcast_arrays(
        np.asarray(omega, dtype=float), np.asarray(zeta, dtype=float)
    )
    w = omega_b.reshape(-1, 1)
    z = zeta_b.reshape(-1, 1)
    t = shaper.times.reshape(1, -1)
    tn = 0.0 if same_instant else shaper.times[-1]
    wd = w * np.sqrt(1.0 - z**2)
    decay = np.exp(-z * w * (tn - t))
    c = (shaper.amplitudes * decay * np.cos(wd * t)).sum(axis=1)
    s = (shaper.amplitudes * decay * np.sin(wd * t)).sum(axis=1)
    v = np.hypot(c, s).reshape(omega_b.shape)
    return float(v) if v.ndim == 0 else v


def residual_vibration_casadi(times: ca.SX | ca.MX | ca.DM | ArrayLike,
                              amplitudes: ca.SX | ca.MX | ca.DM | ArrayLike,
                              omega: ArrayLike, zeta: ArrayLike = 0.0,
                              squared: bool = False, *, definition: str = "eq187"
                              ) -> ca.SX | ca.MX | ca.DM:
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
    definition : {"eq187", "same_instant"}, optional
        See :func:`residual_vibration`.

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

    same_instant = _definition(definition)
    t = _col(times)
    a = _col(amplitudes)
    n = t.numel()
    omega_b, zeta_b = np.broadcast_arrays(
        np.atleast_1d(np.asarray(omega, dtype=float)), np.asarray(zeta, dtype=float)
    )
    w = ca.DM(omega_b.reshape(-1, 1))
    zw = ca.DM((zeta_b * omega_b).reshape(-1, 1))
    wd = ca.DM((omega_b * np.sqrt(1.0 - zeta_b**2)).reshape(-1, 1))
    tn = 0.0 if same_instant else t[n - 1]
    ones_row = ca.DM.ones(1, n)
    phase = ca.mtimes(wd, t.T)  # (m, n)
    decay = ca.exp(-ca.mtimes(zw, ones_row) * (tn - ca.mtimes(ca.DM.ones(w.numel(), 1), t.T)))
    c = ca.mtimes(decay * ca.cos(phase), a)
    s = ca.mtimes(decay * ca.sin(phase), a)
    v2 = c**2 + s**2
    return v2 if squared else ca.sqrt(v2)


def sensitivity_curve(shaper: Shaper, omega_min: float, omega_max: float, zeta: float = 0.0,
                      n: int = 500) -> tuple[np.ndarray, np.ndarray]:
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


def band_maximum(shaper: Shaper, omega_min: float, omega_max: float, zeta: float = 0.0,
                 n_refine: int = 6, *, definition: str = "eq187"
                 ) -> tuple[float, list[tuple[float, float]]]:
    """Largest residual vibration over a band: dense grid refined at its local maxima.

    V oscillates in ω with a period of about 2π / duration; the grid has about 40 points
    per period (400 to 20 000), and the ``n_refine`` largest grid maxima (end points
    included) are refined by a bounded scalar search between their grid neighbours.

    Parameters
    ----------
    shaper : Shaper
    omega_min, omega_max : float
        Band limits, rad/s (equal: a single frequency).
    zeta : float, optional
        Damping ratio.
    n_refine : int, optional
        Number of grid maxima refined.
    definition : {"eq187", "same_instant"}, optional
        See :func:`residual_vibration`.

    Returns
    -------
    vmax : float
        Largest V found (fraction).
    peaks : list of (float, float)
        ``(omega, V)`` of the refined maxima, rad/s.

    Examples
    --------
    >>> vmax, peaks = band_maximum(zv(10.0), 9.0, 11.0)
    >>> round(vmax, 4), [round(float(w), 3) for w, _ in peaks[:2]]
    (0.1564, [9.0, 11.0])
    """
    from scipy import optimize  # here: importing it costs ~0.5 s
    if omega_max == omega_min:
        v = residual_vibration(shaper, omega_min, zeta, definition=definition)
        return v, [(omega_min, v)]
    width = omega_max - omega_min
    # V oscillates in ω with a period of about 2π / duration: ~40 points per period
    per = 2.0 * math.pi / max(shaper.duration, 1e-9)
    npts = int(min(20000, max(400, 40.0 * width / per)))
    w = np.linspace(omega_min, omega_max, npts)
    v = residual_vibration(shaper, w, zeta, definition=definition)
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
            lambda om: -residual_vibration(shaper, om, zeta, definition=definition),
            bounds=(w[i - 1], w[i + 1]),
            method="bounded",
            options={"xatol": 1e-10 * max(1.0, w[i])},
        )
        om = float(res.x)
        vv = float(-res.fun)
        peaks.append((om, vv) if vv >= v[i] else (w[i], v[i]))
    vmax = max(p[1] for p in peaks)
    return float(max(vmax, v.max())), peaks


# --------------------------------------------------------------------------------------
# closed-form shapers
# --------------------------------------------------------------------------------------
def zv(omega: float, zeta: float = 0.0) -> Shaper:
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
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    root = math.sqrt(1.0 - zeta**2)
    k = math.exp(-zeta * math.pi / root)
    return Shaper([0.0, math.pi / (omega * root)], [1.0 / (1.0 + k), k / (1.0 + k)])


def zvd(omega: float, zeta: float = 0.0) -> Shaper:
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
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    root = math.sqrt(1.0 - zeta**2)
    k = math.exp(-zeta * math.pi / root)
    half = math.pi / (omega * root)
    d = (1.0 + k) ** 2
    return Shaper([0.0, half, 2.0 * half], [1.0 / d, 2.0 * k / d, k * k / d])


def _hump_shaper(kind, omega, zeta, vtol):
    tau, amp = ei_family_normalised(kind, zeta, vtol)
    # the family's times are sorted and finite and its amplitudes sum to 1 by construction
    # (checked in tests/shaping/test_ei_family_fit.py): skip the constructor's checks, which
    # would cost more than the fitted form itself
    times = tau / omega
    times.setflags(write=False)
    amp = np.array(amp)
    amp.setflags(write=False)
    shaper = object.__new__(Shaper)
    object.__setattr__(shaper, "times", times)
    object.__setattr__(shaper, "amplitudes", amp)
    return shaper


def ei(omega: float, zeta: float = 0.0, vtol: float = 0.05) -> Shaper:
    """Extra-insensitive (EI) shaper: three impulses, V(ω) = vtol at the design frequency.

    Undamped (``zeta == 0``) the closed form ``A = [(1+V)/4, (1-V)/2, (1+V)/4]`` at
    ``0, T/2, T`` (``T = 2π/ω``) is returned. With damping the shaper meets its defining
    conditions: amplitudes sum to 1, ``V(ω) = vtol`` with a local maximum of V at ω
    (``dV/dω = 0``), and V exactly zero at two frequencies below and above ω (both
    components of the residual vector vanish there); the impulse times are free. They are
    taken from a Chebyshev fit in ζ of the exact solution (microseconds, conditions met to
    1e-9) where it exists, else solved numerically (tens of ms); see
    :func:`casflex.shaping.ei_family_normalised`.

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
    return _hump_shaper("ei", check_omega(omega), check_zeta(zeta), check_vtol(vtol))


def ei_two_hump(omega: float, zeta: float = 0.0, vtol: float = 0.05) -> Shaper:
    """Two-hump extra-insensitive shaper: four impulses over 1.5 damped periods.

    Undamped the classic closed form is used:
    ``X = (V²(sqrt(1-V²)+1))^(1/3)``, ``A1 = A4 = (3X² + 2X + 3V²)/(16X)``,
    ``A2 = A3 = 1/2 - A1`` at ``0, T/2, T, 3T/2``. V is zero at the design frequency with
    two humps of height vtol on either side. With damping the defining conditions (zero at
    ω, humps of height vtol with zero slope at two free frequencies, zeros at two further
    free frequencies, amplitudes summing to 1) are met by the Chebyshev fit in ζ or, outside
    its coverage, solved numerically (:func:`casflex.shaping.ei_family_normalised`).

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
    return _hump_shaper("ei2", check_omega(omega), check_zeta(zeta), check_vtol(vtol))


def ei_three_hump(omega: float, zeta: float = 0.0, vtol: float = 0.05) -> Shaper:
    """Three-hump extra-insensitive shaper: five impulses over two damped periods.

    Undamped the classic closed form is used:
    ``A1 = A5 = (1 + 3V + 2 sqrt(2V(V+1)))/16``, ``A2 = A4 = (1-V)/4``,
    ``A3 = 1 - 2(A1 + A2)`` at ``0, T/2, T, 3T/2, 2T``; V equals vtol at the design
    frequency and at two further humps. With damping the defining conditions (hump of height
    vtol with zero slope at ω and at two free frequencies, four free zeros, amplitudes summing
    to 1) are met by the Chebyshev fit in ζ or, outside its coverage, solved numerically
    (:func:`casflex.shaping.ei_family_normalised`).

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
    return _hump_shaper("ei3", check_omega(omega), check_zeta(zeta), check_vtol(vtol))


# --------------------------------------------------------------------------------------
# shaping a sampled reference
# --------------------------------------------------------------------------------------
def apply_shaper(shaper: Shaper, t: ArrayLike, q: ArrayLike, qd: ArrayLike | None = None,
                 qdd: ArrayLike | None = None
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
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
    shaper = as_shaper(shaper)
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


