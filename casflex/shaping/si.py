"""Specified-insensitivity (SI) shapers: the NLP, the design loop, its verification.

§6.1.3 of the reference dissertation: minimum-duration positive shapers whose residual
vibration stays below a tolerance on one or more frequency ranges.

* the frequency ranges it is given (:class:`~casflex.shaping.ranges.FrequencyRange`, read
  from problem files by :mod:`casflex.shaping.ranges`);
* one NLP (:func:`solve_si_nlp`), solved by Ipopt through CasADi or by SciPy's SLSQP for
  comparison, on the sample frequencies of an :class:`SISample`;
* the design loop (:func:`si_shaper`): start from convolved EI shapers
  (:func:`initial_si_guess`), prune and merge impulses, and verify every range on a dense
  grid refined at its local maxima, adding the worst frequencies to the samples until
  every range provably holds.

Units are SI: times in s, frequencies in rad/s (``unit = "Hz"`` in a problem file is
converted), damping ratios dimensionless.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from casflex._validate import fail, number
from casflex.errors import ProblemFileError, SolverError
from casflex.shaping.ranges import FrequencyRange, as_ranges
from casflex.shaping.shapers import (
    Shaper,
    as_shaper,
    band_maximum,
    ei,
    ei_three_hump,
    ei_two_hump,
    merge_closest,
    residual_vibration,
    residual_vibration_casadi,
)

__all__ = [
    "SISample",
    "NLPSolution",
    "solve_si_nlp",
    "SIShaperResult",
    "GUESS_MAX_IMPULSES",
    "DEFAULT_TIME_LIMIT",
    "HESSIAN_TERMS_PER_SECOND",
    "initial_si_guess",
    "si_shaper",
    "si_shaper_slsqp",
]


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

    def __len__(self) -> int:
        return int(np.size(self.omega))

    @classmethod
    def from_ranges(cls, ranges: Sequence[FrequencyRange],
                    per_range: int | Sequence[int]) -> SISample:
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

    def with_points(self, omega: ArrayLike, range_index: ArrayLike,
                    ranges: Sequence[FrequencyRange]) -> SISample:
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

#: Ipopt's constraint tolerance on V² relative to the squared limit, used when it is
#: tighter than the default (vtol below about 0.007).
_VIOL_PER_VTOL2 = 2e-6

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


def solve_si_nlp(samples: SISample, guess: Shaper, method: str = "ipopt",
                 options: dict | None = None) -> NLPSolution:
    """Solve one specified-insensitivity shaper NLP from a given start.

    Minimise the last impulse time ``t_n`` over impulse amplitudes ``A`` and times ``t``
    subject to ``V(ω_s, ζ_s)² <= vtol_s²`` at every sample (eq. 192, squared for
    smoothness, with a relative margin of 1e-7 on vtol), ``A_i >= 0``, ``Σ A_i = 1``,
    ``t_1 = 0`` and ``t_i <= t_{i+1}``. The number of impulses is that of ``guess``.
    Ipopt's ``constr_viol_tol`` (1e-10, absolute on V²) is lowered to ``2e-6 vtol²`` for
    the smallest vtol when that is tighter, so that a small vtol is met to a relative 1e-6.

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
    guess = as_shaper(guess)
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
        if m:
            # V² <= vtol² is met to constr_viol_tol (absolute): for small vtol tighten it so
            # that V exceeds vtol by at most a relative 1e-6 (0.5e-6 / (1 - margin)²)
            tight = _VIOL_PER_VTOL2 * float(np.min(lim))
            if tight < opts["constr_viol_tol"]:
                opts["constr_viol_tol"] = tight
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
def _verify(shaper, ranges):
    """Per-range verified max V and the peaks violating the tolerance."""
    maxima = []
    violations = []  # (omega, range index)
    for i, r in enumerate(ranges):
        vmax, peaks = band_maximum(shaper, r.omega_min, r.omega_max, r.zeta)
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
    def duration(self) -> float:
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


#: Most impulses the initial guess keeps while the ranges' shapers are convolved one by one
#: (4³: three two-hump EI shapers convolve unmerged); beyond it the closest impulses are
#: merged after each convolution, so that the guess and its NLP stay bounded (3^n else).
GUESS_MAX_IMPULSES = 64

#: Default wall-clock limit of :func:`si_shaper`, s.
DEFAULT_TIME_LIMIT = 60.0

#: Terms ``n² m`` of the exact Hessian (n impulses, m samples) that CasADi builds per second
#: of the time limit left: a larger NLP is refused before its build, which cannot be stopped.
HESSIAN_TERMS_PER_SECOND = 20_000


def initial_si_guess(ranges: FrequencyRange | Iterable, n_impulses: int | None = None
                     ) -> Shaper:
    """Start point of the SI design: EI shapers at the range midpoints convolved (§6.1.3).

    Ranges with ``vtol >= 1`` impose nothing and are skipped. The shapers are convolved one
    by one; whenever a convolution has more than :data:`GUESS_MAX_IMPULSES` impulses, the
    closest adjacent impulses are merged (amplitude-weighted time, summed amplitude) down to
    that number, so that the guess stays bounded for many ranges. With ``n_impulses`` the
    closest impulses of the result are then merged until at most that many remain.

    Parameters
    ----------
    ranges : list of FrequencyRange
    n_impulses : int, optional
        Maximum number of impulses of the guess.

    Returns
    -------
    Shaper

    Raises
    ------
    ProblemFileError
        ``n_impulses < 1``.

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> g = initial_si_guess([FrequencyRange(3 * hz, 4 * hz, 0.0, 0.05),
    ...                       FrequencyRange(9 * hz, 13 * hz, 0.0, 0.05),
    ...                       FrequencyRange(20 * hz, 24 * hz, 0.0, 0.05)])
    >>> round(g.duration, 3)
    0.422

    Ten ranges would convolve to 3^10 = 59049 impulses:

    >>> many = [FrequencyRange(f * hz, 1.1 * f * hz, 0.0, 0.05) for f in range(1, 11)]
    >>> len(initial_si_guess(many)) == GUESS_MAX_IMPULSES
    True
    """
    ranges = as_ranges(ranges)
    if n_impulses is not None:
        n_impulses = int(n_impulses)
        if n_impulses < 1:
            raise ProblemFileError(None, "n_impulses", n_impulses, "must be >= 1")
    parts = [_guess_component(r) for r in ranges if r.vtol < 1.0]
    if not parts:
        return Shaper([0.0], [1.0])
    guess = parts[0]
    for part in parts[1:]:
        guess = guess.convolve(part)
        if len(guess) > GUESS_MAX_IMPULSES:
            guess = merge_closest(guess, GUESS_MAX_IMPULSES)
    if n_impulses is not None:
        guess = merge_closest(guess, n_impulses)
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


def _timed_solve(samples, guess, method, options, deadline, time_limit, done):
    """:func:`solve_si_nlp` within what is left before ``deadline`` (None: no limit)."""
    if deadline is None:
        return solve_si_nlp(samples, guess, method=method, options=options)
    left = deadline - time.perf_counter()
    terms = len(guess) ** 2 * len(samples)
    reason = None
    if left <= 0.0:
        reason = f"{time_limit:g} s used after {done} NLP solve(s)"
    elif method == "ipopt" and terms > HESSIAN_TERMS_PER_SECOND * left:
        reason = (f"the NLP with {len(guess)} impulses and {len(samples)} samples "
                  f"({terms:.3g} Hessian terms) cannot be built in the {left:.3g} s left")
    else:
        if method == "ipopt":
            options = dict(options or {})
            options["max_wall_time"] = min(left, options.get("max_wall_time", left))
        sol = solve_si_nlp(samples, guess, method=method, options=options)
        if not sol.status.startswith("Maximum_") or "Time" not in sol.status:
            return sol
        reason = f"Ipopt stopped with status '{sol.status}' in NLP solve {done + 1}"
    raise SolverError(f"SI shaper design stopped by its time limit (time_limit = "
                      f"{time_limit:g} s): {reason}; pass a larger time_limit (None: no limit)")


def si_shaper(
    ranges: FrequencyRange | Iterable,
    n_impulses: int | None = None,
    *,
    method: str = "ipopt",
    samples_per_range: int | Sequence[int] | None = None,
    eps_amplitude: float = 1e-4,
    eps_time: float = 1e-5,
    verify_tol: float = 1e-6,
    max_solves: int = 40,
    guess: Shaper | None = None,
    options: dict | None = None,
    time_limit: float | None = DEFAULT_TIME_LIMIT,
) -> SIShaperResult:
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
    time_limit : float or None, optional
        Wall-clock limit of the whole design, s (:data:`DEFAULT_TIME_LIMIT`; None: no
        limit). Ipopt gets what is left as ``max_wall_time``; an NLP whose exact Hessian has
        more than :data:`HESSIAN_TERMS_PER_SECOND` terms (n² m, n impulses, m samples) per
        second left is refused before it is built; SLSQP is checked between solves.

    Returns
    -------
    SIShaperResult

    Raises
    ------
    SolverError
        If a solve fails (naming the range and tolerance at fault and the solver status),
        the loop does not settle within ``max_solves`` solves, or the time limit is reached
        (naming ``time_limit``).
    ProblemFileError
        ``max_solves < 1``, ``time_limit <= 0``, or a range with ``vtol < verify_tol``
        (which the verification could not tell from zero).

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> res = si_shaper([FrequencyRange(0.7 * hz, 1.3 * hz, 0.0, 0.05)])
    >>> bool(res.max_prv[0] <= 0.05 + 1e-6), bool(1.0 < res.duration < 1.5)
    (True, True)
    """
    started = time.perf_counter()
    ranges = as_ranges(ranges)
    if int(max_solves) < 1:
        raise ProblemFileError(None, "max_solves", max_solves, "must be >= 1")
    if time_limit is not None:
        time_limit = number(time_limit, "time_limit", low=0.0, low_open=True,
                            error=ProblemFileError)
    for i, r in enumerate(ranges):
        if r.vtol < verify_tol:
            raise fail(f"range[{i}].vtol", r.vtol, f"must be >= verify_tol ({verify_tol:g}), "
                       "the accuracy to which V is verified", error=ProblemFileError)
    active = [r for r in ranges if r.vtol < 1.0]
    if not active:
        trivial = Shaper([0.0], [1.0])
        vmax, _ = _verify(trivial, ranges)
        return SIShaperResult(trivial, ranges, vmax, 0, [], [], None, trivial, trivial)
    start = as_shaper(guess) if guess is not None else initial_si_guess(ranges, n_impulses)
    counts = _initial_samples_per_range(ranges, max(start.duration, 1e-3), samples_per_range)
    samples = SISample.from_ranges(ranges, counts)
    current = start
    statuses, iters = [], []
    deadline = None if time_limit is None else started + time_limit

    def solve(guess_now):
        return _timed_solve(samples, guess_now, method, options, deadline, time_limit,
                            len(statuses))

    for _ in range(int(max_solves)):
        sol = solve(current)
        statuses.append(sol.status)
        iters.append(sol.iterations)
        if not sol.success and current is not start:
            # The pruned previous solution violates the newly added samples; from such an
            # infeasible start Ipopt's restoration phase can end in a point of local
            # infeasibility. Start again from the initial guess on the same samples.
            retry = solve(start)
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


def si_shaper_slsqp(ranges: FrequencyRange | Iterable, n_impulses: int | None = None,
                    **kwargs) -> SIShaperResult:
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


