"""Shapers on a time grid: a linear program per duration, a secant search on the duration.

With the impulse times fixed on a grid ``t_k = k h`` the SI constraints become convex in
the amplitudes: the residual vibration at the same instant (the definition the SI design
constrains, see :func:`~casflex.shaping.shapers.residual_vibration`) is the modulus
``|z_s| = |Σ_k A_k exp((ζ_s ω_s + i ω_ds) t_k)|`` of a linear function of ``A``, and
``|z_s| <= r vtol_s`` is the intersection of the half-planes
``Re(exp(-iθ) z_s) <= r vtol_s`` over all angles θ. For a number of grid steps K the LP

    minimise r  subject to  Re(exp(-iθ) z_s) / vtol_s <= r  (the cuts kept),
                            Σ A_k = 1,  A_k >= 0,  A_k = 0 for k > K

starts from four angles per sample (an outer polygon, hence a relaxation) and adds the
angle ``arg z_s`` of every sample whose ``|z_s|`` exceeds ``r vtol_s`` by a relative
``1e-5`` (cutting planes). Its optimum ``r(K)`` is the smallest ratio V / vtol any grid
shaper ending by ``K h`` reaches on the samples:

* the relaxation's ``r(K) > 1`` proves that no shaper on that grid with that duration
  meets the samples, which makes the smallest K with ``r(K) <= 1`` a certified grid
  optimum;
* ``r(K)`` decreases with K and ``log r(K)`` is close to linear near the optimum, so a
  secant search on ``log r`` (bisection as a safeguard) finds it in a handful of LPs.

One HiGHS model (``highspy``) is kept for the whole search: K changes column bounds,
columns are added only when K first reaches them, cuts are rows added once and kept
(valid for every K), and rows with a large slack are dropped after each K (they come back
as cuts if they are violated again). Every LP after the first is a warm-started dual
simplex. The search is deterministic: its budget is a number of LP solves, never the
wall clock, so the same problem gives the same shaper on a quiet or a loaded machine.

:func:`grid_optimum` is the global start of :func:`casflex.shaping.si_shaper` and, with the
grid step set to a control loop's sample time, its digital shaper.

Units are SI: times in s, frequencies in rad/s.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

import highspy
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import SolverError
from casflex.shaping.shapers import Shaper

__all__ = ["GridOptimum", "grid_optimum", "grid_feasible", "grid_near", "LP_MAX_SOLVES"]

#: Initial angles of the outer polygon of every sample's disc.
_POLYGON = 4

#: Relative excess of |z_s| over r vtol_s at which the cutting planes stop (HiGHS meets
#: its rows to an absolute 1e-7, so a tighter stop would stall; callers that need
#: ``V <= vtol`` exactly pass a vtol reduced by a relative 2e-5).
_CUT_RTOL = 1e-5

#: Cutting-plane rounds per duration before the LP counts as not converged.
_MAX_ROUNDS = 80

#: Rows whose slack exceeds this share of r are dropped after each duration: the LP stays
#: at the few hundred rows that matter instead of growing by every cut ever made.
_PURGE_SLACK = 0.2

#: Default budget of LP solves (cutting-plane rounds included) of one search.
LP_MAX_SOLVES = 400

_INF = highspy.kHighsInf
_OPTIMAL = highspy.HighsModelStatus.kOptimal


def _silent_highs() -> highspy.Highs:
    """A ``highspy.Highs`` with no output, its banner included.

    HiGHS >= 1.7 prints its copyright banner from C++ to file descriptor 1 when the model
    is constructed, before ``output_flag`` can be set: it would land in the middle of a
    command's ``--json`` output. The descriptor is pointed at the null device for the
    constructor only.
    """
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            highs = highspy.Highs()
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    highs.setOptionValue("output_flag", False)
    return highs


class _GridLP:
    """The minimax LP of the module docstring over grid columns added on demand."""

    def __init__(self, step, omega, zeta, vtol):
        self.step = step
        self.omega, self.zeta, self.vtol = omega, zeta, vtol
        self.wd = omega * np.sqrt(1.0 - zeta**2)
        self.solves = 0
        self.iterations = 0
        h = self.highs = _silent_highs()
        h.setOptionValue("threads", 1)
        h.setOptionValue("presolve", "off")  # keeps the warm start between solves
        # column 0 is r (cost 1), row 0 is Σ A = 1
        h.addCols(1, np.ones(1), np.zeros(1), np.full(1, _INF), 0, np.zeros(1, np.int32),
                  np.zeros(0, np.int32), np.zeros(0))
        h.addRows(1, np.ones(1), np.ones(1), 0, np.zeros(1, np.int32), np.zeros(0, np.int32),
                  np.zeros(0))
        self.cut_sample = np.zeros(0, int)
        self.cut_angle = np.zeros(0)
        self.index = np.zeros(0, int)  # grid index of every LP column after r
        self.column_of = {}
        self.re = np.zeros((omega.size, 0))
        self.im = np.zeros((omega.size, 0))
        self.upper = np.zeros(0)

    def _coefficients(self, index):
        t = self.step * np.asarray(index, float)
        growth = np.exp(np.outer(self.zeta * self.omega, t))
        # rows scaled by 1/vtol: HiGHS's absolute row tolerance is then relative to vtol
        return (growth * np.cos(np.outer(self.wd, t)) / self.vtol[:, None],
                growth * np.sin(np.outer(self.wd, t)) / self.vtol[:, None])

    def _add_columns(self, index):
        new = np.array(sorted(set(int(k) for k in index) - self.column_of.keys()), int)
        if new.size == 0:
            return
        re, im = self._coefficients(new)
        ang = self.cut_angle[:, None]
        values = np.vstack([np.ones((1, new.size)),
                            np.cos(ang) * re[self.cut_sample] + np.sin(ang) * im[self.cut_sample]])
        rows = values.shape[0]
        self.highs.addCols(new.size, np.zeros(new.size), np.zeros(new.size),
                           np.zeros(new.size), rows * new.size,
                           (np.arange(new.size) * rows).astype(np.int32),
                           np.tile(np.arange(rows, dtype=np.int32), new.size),
                           np.ascontiguousarray(values.T).ravel())
        for j, k in enumerate(new):
            self.column_of[int(k)] = self.index.size + j
        self.index = np.concatenate([self.index, new])
        self.re = np.hstack([self.re, re])
        self.im = np.hstack([self.im, im])
        self.upper = np.concatenate([self.upper, np.zeros(new.size)])
        if self.cut_sample.size == 0:
            m = self.omega.size
            self._add_cuts(np.repeat(np.arange(m), _POLYGON),
                           np.tile(2.0 * math.pi * np.arange(_POLYGON) / _POLYGON, m))

    def _add_cuts(self, sample, angle):
        values = (np.cos(angle)[:, None] * self.re[sample]
                  + np.sin(angle)[:, None] * self.im[sample])
        rows, n = values.shape
        values = np.hstack([-np.ones((rows, 1)), values])
        self.highs.addRows(rows, np.full(rows, -_INF), np.zeros(rows), rows * (n + 1),
                           (np.arange(rows) * (n + 1)).astype(np.int32),
                           np.tile(np.arange(n + 1, dtype=np.int32), rows), values.ravel())
        self.cut_sample = np.concatenate([self.cut_sample, sample])
        self.cut_angle = np.concatenate([self.cut_angle, angle])

    def _purge(self, r):
        slack = -np.asarray(self.highs.getSolution().row_value)[1:]
        drop = np.nonzero(slack > _PURGE_SLACK * max(r, 1e-3))[0]
        if drop.size:
            self.highs.deleteRows(drop.size, (drop + 1).astype(np.int32))
            keep = np.ones(self.cut_sample.size, bool)
            keep[drop] = False
            self.cut_sample, self.cut_angle = self.cut_sample[keep], self.cut_angle[keep]

    def solve(self, columns, budget=None):
        """Minimax LP on the grid indices ``columns``: (r, amplitudes over ``columns``).

        r is the relaxation's optimum (a proven lower bound of V / vtol on these columns);
        the amplitudes meet every sample to ``r (1 + _CUT_RTOL)``. ``budget()`` False
        before a solve raises _OutOfBudget."""
        columns = np.asarray(columns, int)
        self._add_columns(columns)
        upper = np.zeros(self.index.size)
        pos = np.array([self.column_of[int(k)] for k in columns], int)
        upper[pos] = 1.0
        changed = np.nonzero(upper != self.upper)[0]
        if changed.size:
            self.highs.changeColsBounds(changed.size, (changed + 1).astype(np.int32),
                                        np.zeros(changed.size), upper[changed])
            self.upper = upper
        for _ in range(_MAX_ROUNDS):
            if budget is not None and not budget():
                raise _OutOfBudget
            self.highs.run()
            self.solves += 1
            self.iterations += int(self.highs.getInfo().simplex_iteration_count)
            status = self.highs.getModelStatus()
            if status != _OPTIMAL:
                raise SolverError("the grid LP (HiGHS) ended with status "
                                  f"{self.highs.modelStatusToString(status)}")
            x = np.asarray(self.highs.getSolution().col_value)
            r = float(x[0])
            a = np.clip(x[1:], 0.0, None) * upper
            a /= a.sum()
            zr, zi = self.re @ a, self.im @ a
            mod = np.hypot(zr, zi)
            bad = np.nonzero(mod > r * (1.0 + _CUT_RTOL) + 1e-12)[0]
            if bad.size == 0:
                self._purge(r)
                return r, a[pos]
            self._add_cuts(bad, np.arctan2(zi[bad], zr[bad]))
        raise SolverError(f"the grid LP's cutting planes did not converge in {_MAX_ROUNDS} "
                          "rounds (HiGHS)")


class _OutOfBudget(Exception):
    """The search's budget ran out (caught in grid_optimum)."""


@dataclass(frozen=True, eq=False)
class GridOptimum:
    """The shortest shaper whose impulses lie on a time grid (:func:`grid_optimum`).

    Attributes
    ----------
    shaper : Shaper
        The LP solution (impulses on the grid; amplitudes below 1e-12 dropped).
    step : float
        Grid step h, s.
    duration : float
        Smallest feasible grid duration K h, s (the grid optimum on the samples).
    lower_bound : float
        Largest grid duration proven infeasible by the relaxation, s (``(K - 1) h`` when
        the search is complete).
    lp_solves : int
        Number of LPs solved (cutting-plane rounds included).
    complete : bool
        False when the budget of LP solves stopped the search: the shortest grid shaper
        found so far and the best bound proven so far.

    Examples
    --------
    >>> res = grid_optimum([10.0], [0.0], [0.05], step=0.01, horizon=0.5)
    >>> res.duration, res.lower_bound  # |cos(5 t)| <= 0.05 needs t >= 0.3042 s
    (0.31, 0.3)
    """

    shaper: Shaper
    step: float
    duration: float
    lower_bound: float
    lp_solves: int
    complete: bool = True


def _arrays(omega, zeta, vtol):
    return tuple(np.atleast_1d(np.asarray(x, float)) for x in (omega, zeta, vtol))


def grid_feasible(omega: ArrayLike, zeta: ArrayLike, vtol: ArrayLike, step: float,
                  k_steps: int) -> np.ndarray | None:
    """Amplitudes on the grid ``0, h, ..., K h`` meeting ``|z_s| <= vtol_s``, or None.

    ``|z_s|`` is the residual vibration at the same instant at sample ``s`` (met to a
    relative 1e-5); a result of None is proven: the outer-polygon relaxation's smallest
    ratio ``max_s |z_s| / vtol_s`` exceeds 1.

    Parameters
    ----------
    omega, zeta, vtol : array_like, shape (m,)
        Sample frequencies (rad/s), damping ratios and tolerances.
    step : float
        Grid step h, s.
    k_steps : int
        Number of grid steps K (the duration is at most K h).

    Returns
    -------
    numpy.ndarray, shape (K + 1,) or None

    Examples
    --------
    >>> a = grid_feasible([10.0], [0.0], [0.05], 0.01, 31)
    >>> bool(abs(a.sum() - 1.0) < 1e-12), grid_feasible([10.0], [0.0], [0.05], 0.01, 29)
    (True, None)
    """
    lp = _GridLP(float(step), *_arrays(omega, zeta, vtol))
    r, a = lp.solve(np.arange(int(k_steps) + 1))
    return a if r <= 1.0 else None


def _log(r):
    return math.log(max(r, 1e-300))


def grid_optimum(omega: ArrayLike, zeta: ArrayLike, vtol: ArrayLike, *, step: float,
                 horizon: float, max_doublings: int = 3,
                 check_time: Callable[[], None] | None = None,
                 max_solves: int | None = LP_MAX_SOLVES) -> GridOptimum:
    """Shortest shaper on the grid ``t_k = k h`` meeting ``V <= vtol`` at every sample.

    V is the residual vibration at the same instant. The smallest number of steps K whose
    LP optimum ``r(K) <= 1`` (module docstring) is found from half a period of the highest
    sample frequency upwards, extrapolating ``log r`` linearly (at most doubling K) until a
    K is feasible, then by a secant search on ``log r`` inside the bracket (bisection when
    the secant keeps moving the same end), up to ``horizon * 2**max_doublings``. A
    feasible K whose LP shaper ends earlier moves the bracket's upper end to that
    impulse at no cost. All LPs share one HiGHS model (module docstring).

    Parameters
    ----------
    omega, zeta, vtol : array_like, shape (m,)
        Sample frequencies (rad/s), damping ratios and tolerances (< 1).
    step : float
        Grid step h, s.
    horizon : float
        A duration the search may reach without doubling, s (``horizon * 2**max_doublings``
        is the longest tried).
    max_doublings : int, optional
        Doublings of the horizon allowed before giving up.
    check_time : callable, optional
        Called before every LP; raises to stop the search (a time limit).
    max_solves : int or None, optional
        Budget of LP solves (:data:`LP_MAX_SOLVES`; None: no budget). When it runs out the
        search returns the shortest grid shaper found so far (``complete`` False), or
        raises SolverError if it found none. Counting solves instead of seconds makes the
        result independent of the machine's load.

    Returns
    -------
    GridOptimum

    Raises
    ------
    SolverError
        No feasible grid shaper within ``horizon * 2**max_doublings``, the budget ran out
        before one was found, or HiGHS failed.

    Examples
    --------
    At 10 rad/s with a 0.1 % tolerance the shortest grid shaper ends at the ZV shaper's
    half period (π/10 s) on a grid of π/100 s:

    >>> res = grid_optimum([10.0], [0.0], [1e-3], step=math.pi / 100, horizon=1.0)
    >>> round(res.duration * 10.0 / math.pi, 9), round(res.lower_bound * 10.0 / math.pi, 9)
    (1.0, 0.9)
    """
    omega, zeta, vtol = _arrays(omega, zeta, vtol)
    step = float(step)
    lp = _GridLP(step, omega, zeta, vtol)
    k_max = max(1, int(math.ceil(horizon / step))) * 2 ** int(max_doublings)

    def budget():
        if check_time is not None:
            check_time()
        return max_solves is None or lp.solves < max_solves

    def log_ratio(k):
        r, a = lp.solve(np.arange(k + 1), budget)
        return _log(r), a

    lo, log_lo = 0, math.inf  # largest K proven infeasible (K = 0: one impulse, V = 1)
    hi, best, log_hi = None, None, None
    try:
        # upwards from half a period of the highest sample frequency (no shorter grid
        # shaper keeps V < 1 there): extrapolate log r to 0, at most doubling K
        k = min(k_max, max(1, int(math.pi / float(np.max(omega)) / step)))
        previous = None
        while True:
            log_r, a = log_ratio(k)
            if log_r <= 0.0:
                hi, best, log_hi = k, a, log_r
                break
            lo, log_lo = k, log_r
            if k >= k_max:
                raise SolverError(
                    f"no shaper on a grid of {step:.6g} s meets the samples within "
                    f"{k_max * step:.6g} s (cutting-plane LP, HiGHS)")
            target = 2 * k
            if previous is not None and log_r < previous[1]:
                slope = (log_r - previous[1]) / (k - previous[0])
                target = k + int(math.ceil(-log_r / slope)) + 1
            previous = (k, log_r)
            k = min(max(target, k + 1), 2 * k, k_max)
        side, streak = None, 0  # which end the last LPs moved, and how many times
        while True:
            # the LP shaper may end before K: that shorter K is feasible too
            hi = int(np.nonzero(best > 1e-12)[0][-1])
            best = best[:hi + 1]
            if hi - lo <= 1:
                break
            if math.isfinite(log_lo) and streak < 2:
                m = lo + log_lo / (log_lo - log_hi) * (hi - lo)
                k = min(max(int(round(m)), lo + 1), hi - 1)
            else:  # the secant keeps moving one end: bisect once
                k, streak = (lo + hi) // 2, 0
            log_r, a = log_ratio(k)
            moved = "hi" if log_r <= 0.0 else "lo"
            streak, side = (streak + 1 if moved == side else 1), moved
            if log_r <= 0.0:
                hi, best, log_hi = k, a, log_r
            else:
                lo, log_lo = k, log_r
    except _OutOfBudget:
        if best is None:
            raise SolverError("the grid LP search ran out of its budget of "
                              f"{max_solves} LP solves before it found a feasible grid "
                              "shaper") from None
        hi = int(np.nonzero(best > 1e-12)[0][-1])
        return _result(best[:hi + 1], step, hi * step, lo * step, lp.solves, False)
    return _result(best, step, hi * step, lo * step, lp.solves, True)


def _result(best, step, duration, lower_bound, solves, complete):
    keep = best > 1e-12
    times = step * np.arange(best.size)[keep]
    amps = best[keep]
    shaper = Shaper(times - times[0], amps / amps.sum())
    return GridOptimum(shaper=shaper, step=step, duration=duration,
                       lower_bound=lower_bound, lp_solves=solves, complete=complete)


def grid_near(shaper: Shaper, omega: ArrayLike, zeta: ArrayLike, vtol: ArrayLike, *,
              step: float, window: int = 8, max_extra_steps: int = 64,
              check_time: Callable[[], None] | None = None) -> GridOptimum:
    """The shortest shaper on the grid ``t_k = k h`` with its impulses near ``shaper``'s.

    The local form of :func:`grid_optimum`: the LP's impulse times are only the grid
    points within ``window`` steps of one of ``shaper``'s impulses, and the final grid
    point K is searched upwards from the one nearest ``shaper``'s end. The LPs are small
    (a few hundred columns, not ``duration / h``), so a shaper of a second on a 1 kHz
    grid takes a few LPs instead of a bisection over a thousand-column LP. Used to put a
    polished analogue shaper on a loop's sample grid (:func:`casflex.shaping.si_shaper`
    with ``dt``); the result is a grid shaper near the analogue one, not the global grid
    optimum (``lower_bound`` is the largest K proven infeasible for this neighbourhood).

    Parameters
    ----------
    shaper : Shaper
        The analogue shaper whose neighbourhood is searched.
    omega, zeta, vtol : array_like, shape (m,)
        Sample frequencies (rad/s), damping ratios and tolerances (< 1).
    step : float
        Grid step h (the loop's sample time), s.
    window : int, optional
        Grid steps on each side of every analogue impulse that the LP may use.
    max_extra_steps : int, optional
        Grid steps beyond the analogue end tried before giving up.
    check_time : callable, optional
        Called before every LP; raises to stop the search (a time limit).

    Returns
    -------
    GridOptimum

    Raises
    ------
    SolverError
        No grid shaper in the neighbourhood within ``max_extra_steps`` of the end.

    Examples
    --------
    A ZV shaper at 10 rad/s (0.3142 s) keeps V within 5 % on ±2 %; on a 10 ms grid the
    nearest shaper that does so spreads its second impulse over 0.31 and 0.32 s:

    >>> from casflex.shaping import zv
    >>> res = grid_near(zv(10.0), [9.8, 10.0, 10.2], [0.0] * 3, [0.05] * 3, step=0.01)
    >>> res.duration, len(res.shaper)
    (0.32, 3)
    """
    omega, zeta, vtol = _arrays(omega, zeta, vtol)
    step = float(step)
    lp = _GridLP(step, omega, zeta, vtol)
    centres = np.rint(np.asarray(shaper.times, float) / step).astype(int)

    def feasible(k):
        if check_time is not None:
            check_time()
        near = {0, k}
        for c in centres:
            near.update(j for j in range(c - window, c + window + 1) if 0 < j < k)
        columns = np.array(sorted(near))
        r, a = lp.solve(columns)
        if r > 1.0:
            return None
        full = np.zeros(k + 1)
        full[columns] = a
        return full

    k0 = max(1, int(centres[-1]))
    lo = 0  # largest K proven infeasible for this neighbourhood
    for k in range(k0, k0 + max_extra_steps + 1):
        best = feasible(k)
        if best is not None:
            break
        lo = k
    else:
        raise SolverError(f"no shaper on the {step:g} s grid within {window} steps of the "
                          f"analogue impulses and {max_extra_steps} steps of its end "
                          f"({shaper.duration:.6g} s)")
    hi = k
    while hi - 1 > lo:  # walk down while a shorter grid end is feasible
        a = feasible(hi - 1)
        if a is None:
            lo = hi - 1
            break
        hi, best = hi - 1, a
    return _result(best, step, hi * step, lo * step, lp.solves, True)
