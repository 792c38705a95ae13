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

from casflex._validate import fail, number
from casflex.errors import ProblemFileError, SolverError
from casflex.shaping.grid_lp import grid_near, grid_optimum
from casflex.shaping.ranges import FrequencyRange, as_ranges
from casflex.shaping.shapers import (
    Shaper,
    as_shaper,
    band_maximum,
    merge_closest,
    residual_vibration_casadi,
)
from casflex.shaping.si_hessian import si_nlp_with_hessian
from casflex.shaping.si_start import initial_si_guess

__all__ = [
    "SISample",
    "NLPSolution",
    "solve_si_nlp",
    "SIShaperResult",
    "DEFAULT_TIME_LIMIT",
    "HESSIAN_TERMS_PER_SECOND",
    "si_shaper",
    "si_shaper_slsqp",
    "LP_GRID_STEPS",
    "LP_MAX_SAMPLES",
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
    >>> from casflex.shaping import ei
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


#: Relative margin on vtol imposed inside the NLP (and the grid LP) so that the returned
#: shaper satisfies the tolerance itself, not only to the solver's constraint-violation
#: tolerance: verification then accepts V <= vtol with no slack.
_VTOL_MARGIN = 2e-5

#: Ipopt's constraint tolerance on V² relative to the squared limit, used when it is
#: tighter than the default (vtol below about 0.007): V exceeds its limit by at most a
#: relative 1e-6, well inside the margin.
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
    v2 = residual_vibration_casadi(t, a, samples.omega, samples.zeta, squared=True,
                                   definition="same_instant")
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
    subject to ``V(ω_s, ζ_s)² <= vtol_s²`` at every sample (eq. 192 with V the residual
    vibration at the same instant, see :func:`~casflex.shaping.residual_vibration`;
    squared for smoothness, with a relative margin of 2e-5 on vtol), ``A_i >= 0``,
    ``Σ A_i = 1``, ``t_1 = 0`` and ``t_i <= t_{i+1}``. The number of impulses is that of
    ``guess``. Ipopt's ``constr_viol_tol`` (1e-10, absolute on V²) is lowered to
    ``2e-6 vtol²`` for the smallest vtol when that is tighter, so that a small vtol is met
    to a relative 1e-6, inside the margin.

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
    >>> from casflex.shaping import ei
    >>> r = FrequencyRange(2 * math.pi * 0.81, 2 * math.pi * 1.19, 0.0, 0.05)
    >>> sol = solve_si_nlp(SISample.from_ranges([r], 9), ei(2 * math.pi))
    >>> sol.success, round(sol.shaper.duration, 2)
    (True, 0.99)
    """
    from scipy import optimize  # here: importing it costs ~0.5 s
    guess = as_shaper(guess)
    n = len(guess)
    x, f, g_sum, g_order, v2, lim = _si_functions(n, samples)
    x0 = np.concatenate([guess.amplitudes, guess.times - guess.times[0]])
    lbx, ubx = _bounds(n)
    x0 = np.clip(x0, lbx, ubx)
    if method == "ipopt":
        t0 = time.perf_counter()
        # the same NLP in MX with its Hessian as matrix products (no O(m n²) SX build)
        nlp, hess = si_nlp_with_hessian(samples.omega, samples.zeta, n)
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
        solver = ca.nlpsol("si_shaper", "ipopt", nlp, {
            "hess_lag": hess, "ipopt": opts, "print_time": False, "error_on_fail": False})
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
    """Per-range verified max V (same instant) and the peaks above the tolerance."""
    maxima = []
    violations = []  # (omega, range index)
    for i, r in enumerate(ranges):
        vmax, peaks = band_maximum(shaper, r.omega_min, r.omega_max, r.zeta,
                                   definition="same_instant")
        maxima.append(vmax)
        if r.vtol >= 1.0:
            # imposes nothing (V <= 1 for positive shapers); a peak of V = 1 must not be
            # added as a sample, where V <= 1 - margin would be a needless, degenerate
            # constraint (all impulses in phase)
            continue
        for om, vv in peaks:
            if vv > r.vtol:
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
        Verified maximum residual vibration fraction at the same instant (the constrained
        definition) on each range: a dense grid refined at its local maxima, ``<= vtol``.
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
        The start of the first solve (the grid LP's shaper, or the convolved EI shapers).
    max_prv_eq187 : numpy.ndarray, shape (n_ranges,)
        The same maxima with eq. 187's normalisation (the dissertation's numbers; never
        larger than ``max_prv``).
    start : str
        ``"lp"`` (grid LP start), ``"ei"`` (convolved EI shapers), ``"guess"`` (given)
        or ``"digital"`` (the grid LP on the sample grid ``dt``, no polish).
    lp_duration : float or None
        Grid optimum: the shortest shaper on the LP's time grid meeting the samples, s.
    lp_lower_bound : float or None
        Largest grid duration the LP relaxation proved infeasible, s: no shaper with its
        impulses on that grid is shorter (a certificate for grid shapers on the samples,
        not for shapers with free impulse times).
    lp_step : float or None
        Step of the LP's time grid, s (``dt`` for a digital shaper).

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> res = si_shaper([FrequencyRange(0.9 * hz, 1.1 * hz, 0.0, 0.05)])
    >>> res.start, len(res.shaper), bool(res.max_prv[0] <= 0.05)
    ('lp', 3, True)
    >>> round(res.duration, 3), bool(res.lp_gap < 0.01)
    (0.888, True)
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
    max_prv_eq187: np.ndarray | None = None
    start: str = "ei"
    lp_duration: float | None = None
    lp_lower_bound: float | None = None
    lp_step: float | None = None

    @property
    def duration(self) -> float:
        """Duration of the shaper, s."""
        return self.shaper.duration

    @property
    def lp_gap(self) -> float | None:
        """Optimality gap ``duration / lp_lower_bound - 1`` (None without an LP start)."""
        if not self.lp_lower_bound:
            return None
        return self.duration / self.lp_lower_bound - 1.0


#: Default wall-clock limit of :func:`si_shaper`, s.
DEFAULT_TIME_LIMIT = 60.0

#: Terms ``n² m`` of the exact Hessian (n impulses, m samples) that CasADi builds per second
#: of the time limit left: a larger NLP is refused before its build, which cannot be stopped.
HESSIAN_TERMS_PER_SECOND = 20_000


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
    # about four samples per oscillation of V(ω) (period 2π / duration)
    return [int(min(60, max(5, math.ceil(4.0 * (r.omega_max - r.omega_min) * duration
                                         / (2.0 * math.pi)) + 1))) for r in ranges]


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


class _TimeLimitError(SolverError):
    """The design's time limit was reached (never caught by the fallbacks)."""


def _time_limit_error(time_limit, reason):
    return _TimeLimitError(f"SI shaper design stopped by its time limit (time_limit = "
                           f"{time_limit:g} s): {reason}; pass a larger time_limit "
                           "(None: no limit)")


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
    raise _time_limit_error(time_limit, reason)


#: Steps of the LP's time grid up to the horizon (the convolved EI duration); the step is
#: also at most 1/12 of the shortest period of the ranges.
LP_GRID_STEPS = 128

#: Most sample frequencies (all ranges) for which the grid LP start is tried; beyond, the
#: design starts from the convolved EI shapers.
LP_MAX_SAMPLES = 800



def _lp_samples(ranges, duration):
    """Sample frequencies of the grid LP: about four per oscillation of V(ω)."""
    counts = []
    for r in ranges:
        width = r.omega_max - r.omega_min
        counts.append(int(min(200, max(5, math.ceil(4.0 * width * duration / (2.0 * math.pi))
                                       + 1))))
    return SISample.from_ranges(ranges, counts)


def _lp_step(samples, horizon):
    """LP grid step: LP_GRID_STEPS to the horizon, and 12 per shortest period."""
    return min(horizon / LP_GRID_STEPS, 2.0 * math.pi / float(np.max(samples.omega)) / 12.0)


def _cluster(shaper, gap):
    """Adjacent grid impulses (closer than ``gap``) merged: a start for the polish."""
    t, a = [shaper.times[0]], [shaper.amplitudes[0]]
    for ti, ai in zip(shaper.times[1:], shaper.amplitudes[1:], strict=True):
        if ti - t[-1] <= gap and len(t) > 1:
            w = a[-1] + ai
            t[-1] = (a[-1] * t[-1] + ai * ti) / w
            a[-1] = w
        elif ti - t[-1] <= gap:
            a[-1] += ai  # keep the first impulse at t = 0
        else:
            t.append(ti)
            a.append(ai)
    a = np.array(a)
    return Shaper(np.array(t), a / a.sum())


def _grid_design(ranges, samples, step, horizon, check_time, max_rounds=8, lp=None,
                 near=None):
    """Grid LP with the samples augmented until the LP shaper verifies on every range
    (the LP only near the impulses of the shaper ``near`` if it is given)."""
    for _ in range(max_rounds):
        if lp is None and near is not None:
            lp = grid_near(near, samples.omega, samples.zeta,
                           samples.vtol * (1.0 - _VTOL_MARGIN), step=step,
                           check_time=check_time)
        elif lp is None:
            lp = grid_optimum(samples.omega, samples.zeta,
                              samples.vtol * (1.0 - _VTOL_MARGIN), step=step,
                              horizon=horizon, check_time=check_time)
        vmax, violations = _verify(lp.shaper, ranges)
        if not violations:
            return lp, samples, vmax
        samples = samples.with_points(*zip(*violations, strict=True), ranges)
        horizon, lp = lp.duration, None
    raise SolverError(f"the grid LP shaper (grid {step:.6g} s) still violates a range after "
                      f"{max_rounds} rounds of added samples")


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
    start: str = "lp",
    dt: float | None = None,
) -> SIShaperResult:
    """Design a specified-insensitivity (SI) shaper for one or more frequency ranges.

    **What is constrained.** V is the residual vibration *at the same instant*
    (:func:`~casflex.shaping.residual_vibration`, ``definition="same_instant"``): eq. 187
    can be met by a tiny late impulse that only postpones ``t_n`` (its ``exp(-ζ ω t_n)``),
    the same-instant V cannot; it is never below eq. 187's (equal when undamped), which
    ``max_prv_eq187`` reports.

    **Global start and certificate** (``start="lp"``). With the impulse times on a grid the
    problem is a linear program per duration (:func:`~casflex.shaping.grid_lp.grid_optimum`,
    one warm-started HiGHS model): a secant search on the duration gives the shortest grid
    shaper within a budget of LP solves (deterministic, whatever the load), on about four
    samples per oscillation of V, of :data:`LP_GRID_STEPS` steps up to the convolved EI
    duration, with the samples augmented until that shaper verifies on every range. Its
    adjacent impulses merged start the polish. The result records the grid optimum
    (``lp_duration``), the relaxation's lower bound (``lp_lower_bound``) and the gap.

    **Polish** (§6.1.3): minimise the last impulse time subject to ``V <= vtol`` at the
    samples (:func:`solve_si_nlp`), drop impulses below ``eps_amplitude``, merge impulses
    closer than ``eps_time``, verify every range on a dense grid refined at its local
    maxima (``V <= vtol``, no slack; violating peaks become samples) and solve again until
    nothing changes. If that fails or ends longer than the grid LP's shaper, the polish from
    the convolved EI start is tried too, and the shortest verified shaper is returned.

    **Digital shapers** (``dt``): the analogue design first, then the grid LP on the
    sample grid ``t_k = k dt`` restricted to a few samples around each analogue impulse
    (:func:`~casflex.shaping.grid_near`; the LP over the whole grid,
    :func:`~casflex.shaping.grid_optimum`, if that neighbourhood has no shaper). The
    impulses stay on the grid (no polish), verified like the others.

    Ranges with ``vtol >= 1`` are checked and reported but never add samples.

    Parameters
    ----------
    ranges : sequence of FrequencyRange (or (omega_min, omega_max, zeta, vtol) tuples)
        Frequencies in rad/s. Ranges with ``vtol == 1`` impose nothing.
    n_impulses : int, optional
        Maximum number of impulses of the start (closest impulses merged). Default: no
        limit.
    method : {"ipopt", "slsqp"}, optional
        NLP solver used for every solve.
    samples_per_range : int or sequence of int, optional
        Initial number of samples on each range of the polish from an EI or given start
        (default: about four per oscillation of V).
    eps_amplitude : float, optional
        Impulses with smaller amplitude are removed.
    eps_time : float, optional
        Impulses closer than this (s) are merged.
    verify_tol : float, optional
        Smallest vtol accepted: below it V cannot be told from zero in double precision.
        (Verification itself has no slack: V <= vtol.)
    max_solves : int, optional
        Maximum number of NLP solves.
    guess : Shaper, optional
        Start point instead of the grid LP (``start`` is then ``"guess"``).
    options : dict, optional
        Solver options passed to :func:`solve_si_nlp`.
    time_limit : float or None, optional
        Wall-clock limit of the whole design, s (:data:`DEFAULT_TIME_LIMIT`; None: no
        limit). The LP search checks it before every LP; Ipopt gets what is left as
        ``max_wall_time``; an NLP whose exact Hessian has more than
        :data:`HESSIAN_TERMS_PER_SECOND` terms (n² m, n impulses, m samples) per second
        left is refused before it is built; SLSQP is checked between solves.
    start : {"lp", "ei"}, optional
        Start of the polish: the grid LP (default; the convolved EI shapers when the LP
        would have more than :data:`LP_MAX_SAMPLES` samples or finds no grid shaper within
        :data:`~casflex.shaping.grid_lp.LP_MAX_SOLVES` LP solves; the search stopped by that
        budget starts from the shortest grid shaper it found) or the convolved EI shapers
        (the dissertation's algorithm).
    dt : float, optional
        Sample time of the loop that runs the shaper, s: impulses on ``k dt``.

    Returns
    -------
    SIShaperResult

    Raises
    ------
    SolverError
        If no start is feasible, the polish fails with no verified LP shaper to fall back
        on (naming the range and tolerance at fault and the solver status), or the time
        limit is reached (naming ``time_limit``).
    ProblemFileError
        ``max_solves < 1``, ``time_limit <= 0``, ``dt <= 0``, a bad ``start``, or a range
        with ``vtol < verify_tol``.

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> res = si_shaper([FrequencyRange(0.7 * hz, 1.3 * hz, 0.0, 0.05)])
    >>> bool(res.max_prv[0] <= 0.05), bool(1.0 < res.duration < 1.5)
    (True, True)

    On a 10 ms loop:

    >>> d = si_shaper([FrequencyRange(0.7 * hz, 1.3 * hz, 0.0, 0.05)], dt=0.01)
    >>> bool(np.allclose(d.shaper.times / 0.01, np.round(d.shaper.times / 0.01)))
    True
    >>> bool(d.max_prv[0] <= 0.05), bool(d.duration <= res.duration + 0.01)
    (True, True)
    """
    started = time.perf_counter()
    ranges = as_ranges(ranges)
    if int(max_solves) < 1:
        raise ProblemFileError(None, "max_solves", max_solves, "must be >= 1")
    if time_limit is not None:
        time_limit = number(time_limit, "time_limit", low=0.0, low_open=True,
                            error=ProblemFileError)
    if start not in ("lp", "ei"):
        raise fail("start", start, "must be 'lp' or 'ei'", error=ProblemFileError)
    if dt is not None:
        dt = number(dt, "dt", low=0.0, low_open=True, error=ProblemFileError)
    for i, r in enumerate(ranges):
        if r.vtol < verify_tol:
            raise fail(f"range[{i}].vtol", r.vtol, f"must be >= verify_tol ({verify_tol:g}), "
                       "the accuracy to which V is verified", error=ProblemFileError)
    active = [r for r in ranges if r.vtol < 1.0]
    if not active:
        trivial = Shaper([0.0], [1.0])
        vmax, _ = _verify(trivial, ranges)
        return SIShaperResult(trivial, ranges, vmax, 0, [], [], None, trivial, trivial,
                              max_prv_eq187=_eq187_maxima(trivial, ranges), start="trivial")
    deadline = None if time_limit is None else started + time_limit

    def check_time():
        if deadline is not None and time.perf_counter() > deadline:
            raise _time_limit_error(time_limit, "reached during the grid LP search")

    check_time()
    ei_start = initial_si_guess(ranges, n_impulses)
    horizon = max(ei_start.duration, 1e-3)
    if dt is not None:
        # the analogue design first, then its neighbourhood on the sample grid: a few
        # small LPs where the grid LP over the whole duration costs a bisection over
        # duration / dt columns (a second at 1 kHz); the whole grid if the neighbourhood
        # has no shaper
        left = None if deadline is None else max(deadline - time.perf_counter(), 1e-3)
        analogue = si_shaper(ranges, n_impulses, method=method,
                             samples_per_range=samples_per_range,
                             eps_amplitude=eps_amplitude, eps_time=eps_time,
                             verify_tol=verify_tol, max_solves=max_solves, guess=guess,
                             options=options, time_limit=left, start=start)
        samples = _lp_samples(ranges, max(analogue.shaper.duration, 1e-3))
        try:
            lp, samples, vmax = _grid_design(ranges, samples, dt, horizon, check_time,
                                             near=analogue.shaper)
        except SolverError:
            lp, samples, vmax = _grid_design(ranges, samples, dt, horizon, check_time)
        return SIShaperResult(
            lp.shaper, ranges, vmax, 0, [], [], samples, lp.shaper, lp.shaper,
            max_prv_eq187=_eq187_maxima(lp.shaper, ranges), start="digital",
            lp_duration=lp.shaper.duration, lp_lower_bound=lp.lower_bound, lp_step=dt)
    lp = None
    kind = "guess" if guess is not None else start
    if guess is not None:
        first = as_shaper(guess)
    else:
        first = ei_start
        lp_samples = _lp_samples(ranges, horizon)
        if start == "lp" and len(lp_samples) <= LP_MAX_SAMPLES:
            try:
                lp = grid_optimum(lp_samples.omega, lp_samples.zeta,
                                  lp_samples.vtol * (1.0 - _VTOL_MARGIN),
                                  step=_lp_step(lp_samples, horizon), horizon=horizon,
                                  check_time=check_time)
            except _TimeLimitError:
                raise
            except SolverError:
                kind = "ei"  # no grid start found: polish the EI start as before
            else:
                first = _cluster(lp.shaper, 1.5 * lp.step)
                if n_impulses is not None:
                    first = merge_closest(first, int(n_impulses))
        elif start == "lp":
            kind = "ei"
    polish = (samples_per_range, method, options, eps_amplitude, eps_time, max_solves,
              deadline, time_limit)
    try:
        result = _polish(ranges, first, lp_samples if lp is not None else None, *polish)
    except _TimeLimitError:
        raise
    except SolverError:
        if lp is None or (n_impulses is not None and len(lp.shaper) > int(n_impulses)):
            raise
        result = None
    if guess is None and lp is not None and (
            result is None or result[0].duration > lp.shaper.duration):
        # the polish from the grid start failed or stopped in a worse local optimum: the
        # dissertation's EI start too, then the shortest verified of the three
        try:
            other = _polish(ranges, ei_start, None, *polish)
        except _TimeLimitError:
            raise
        except SolverError:
            other = None
        if other is not None and (result is None or other[0].duration < result[0].duration):
            result, kind = other, "ei"
    if lp is not None and (result is None or result[0].duration > lp.shaper.duration):
        # the polish failed or ended longer than the grid optimum: the LP shaper, verified
        # (samples added where it is not), unless it too ends longer
        lp_final, lp_samples, vmax = _grid_design(ranges, lp_samples, lp.step, lp.duration,
                                                  check_time, lp=lp)
        if result is None or result[0].duration > lp_final.shaper.duration:
            statuses, iters = ([], []) if result is None else (result[2], result[3])
            result = (lp_final.shaper, vmax, statuses, iters, lp_samples, first)
            lp = lp_final
    shaper, vmax, statuses, iters, samples, final_guess = result
    return SIShaperResult(
        shaper=shaper, ranges=ranges, max_prv=vmax, iterations=len(statuses),
        statuses=statuses, solver_iterations=iters, samples=samples,
        final_guess=final_guess, initial_guess=first,
        max_prv_eq187=_eq187_maxima(shaper, ranges), start=kind,
        lp_duration=None if lp is None else lp.shaper.duration,
        lp_lower_bound=None if lp is None else lp.lower_bound,
        lp_step=None if lp is None else lp.step,
    )


def _eq187_maxima(shaper, ranges):
    return np.array([band_maximum(shaper, r.omega_min, r.omega_max, r.zeta)[0] for r in ranges])


def _polish(ranges, start, samples, samples_per_range, method, options, eps_amplitude,
            eps_time, max_solves, deadline, time_limit):
    """The §6.1.3 loop: solve, verify (adding violating peaks), prune; until it settles."""
    if samples is None:
        counts = _initial_samples_per_range(ranges, max(start.duration, 1e-3),
                                            samples_per_range)
        samples = SISample.from_ranges(ranges, counts)
    current = start
    statuses, iters = [], []

    def solve(guess_now):
        return _timed_solve(samples, guess_now, method, options, deadline, time_limit,
                            len(statuses))

    for _ in range(int(max_solves)):
        sol = solve(current)
        statuses.append(sol.status)
        iters.append(sol.iterations)
        if not sol.success and current is not start:
            # from the pruned previous solution (infeasible for the added samples) Ipopt's
            # restoration can end in local infeasibility: restart on the same samples
            retry = solve(start)
            statuses.append(retry.status)
            iters.append(retry.iterations)
            if retry.success:
                sol = retry
        if not sol.success:
            _fail(ranges, sol.shaper, sol.status, "SI shaper NLP did not converge")
        pruned = _prune(sol.shaper, eps_amplitude, eps_time)
        vmax, violations = _verify(sol.shaper, ranges)
        if violations:
            samples = samples.with_points(*zip(*violations, strict=True), ranges)
        if violations or len(pruned) != len(sol.shaper):
            current = pruned
            continue
        return sol.shaper, vmax, statuses, iters, samples, current
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


