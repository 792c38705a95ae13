"""Shapers on a time grid: a linear program per duration, bisection on the duration.

With the impulse times fixed on a grid ``t_k = k h`` the SI constraints become convex in
the amplitudes: the residual vibration at the same instant (the definition the SI design
constrains, see :func:`~casflex.shaping.shapers.residual_vibration`) is the modulus
``|z_s| = |Σ_k A_k exp((ζ_s ω_s + i ω_ds) t_k)|`` of a linear function of ``A``, and
``|z_s| <= vtol_s`` is the intersection of the half-planes
``Re(exp(-iθ) z_s) <= vtol_s`` over all angles θ. Starting from eight angles per sample
(an outer polygon, hence a relaxation) and adding the angle ``arg z_s`` of every sample the
LP solution violates (cutting planes), each LP is solved by HiGHS
(:func:`scipy.optimize.linprog`) until every sample holds to a relative ``1e-5``:

* the relaxation infeasible proves that no shaper on that grid with that duration meets
  the samples, which makes the smallest feasible grid duration a certified grid optimum;
* feasibility in the number of grid steps K is monotone (a longer grid contains the
  shorter one), so bisection on K finds it with about log2(N) feasibility checks.

:func:`grid_optimum` is the global start of :func:`casflex.shaping.si_shaper` and, with the
grid step set to a control loop's sample time, its digital shaper.

Units are SI: times in s, frequencies in rad/s.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize

from casflex.errors import SolverError
from casflex.shaping.shapers import Shaper

__all__ = ["GridOptimum", "grid_optimum", "grid_feasible", "grid_near"]

#: Initial angles of the outer polygon of every sample's disc.
_POLYGON = 8

#: Relative excess of |z_s| over vtol_s at which the cutting planes stop (HiGHS meets
#: its rows to an absolute 1e-7, so a tighter stop would stall; callers that need
#: ``V <= vtol`` exactly pass a vtol reduced by a relative 2e-5).
_CUT_RTOL = 1e-5

#: Cutting-plane rounds per feasibility check before the check counts as infeasible.
_MAX_ROUNDS = 60

#: Relative excess accepted while bisecting (the final K is re-solved to _CUT_RTOL).
_SEARCH_RTOL = 1e-3

#: Steps of the coarse grid that brackets the optimum before the fine grid's bisection.
_COARSE_STEPS = 32

#: Fewest coarse-grid points per period of the highest sample frequency.
_COARSE_PER_PERIOD = 8


def _search(feasible, k0, k_max, step):
    """Smallest feasible K: doubling from k0 up to k_max, then bisection. Returns (K, A,
    largest K proven infeasible)."""
    lo, k = 0, max(1, k0)
    while True:
        best = feasible(k)
        if best is not None:
            break
        if k >= k_max:
            raise SolverError(
                f"no shaper on a grid of {step:.6g} s meets the samples within "
                f"{k_max * step:.6g} s (cutting-plane LP, HiGHS)")
        lo, k = k, min(2 * k, k_max)
    return _bisect_between(feasible, lo, k, best)


def _bisect_between(feasible, lo, hi, best):
    """Bisection with K = lo infeasible (or 0) and K = hi feasible with amplitudes best."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        a = feasible(mid)
        if a is None:
            lo = mid
        else:
            hi, best = mid, a
    return hi, best, lo


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
        Largest grid duration proven infeasible by the relaxation, s (``(K - 1) h``
        unless the last cutting-plane solve moved K up).
    lp_solves : int
        Number of LPs solved.
    complete : bool
        False when ``budget`` stopped the search: the shortest grid shaper found so far
        (met to a relative 1e-3 only) and the best bound proven so far.

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


def _lp_feasible(k_steps, step, omega, zeta, vtol, angles, counter, rtol=_CUT_RTOL,
                 columns=None):
    """Cutting-plane LP on the grid 0..k_steps (or only its points ``columns``, sorted
    indices that include 0 and k_steps); amplitudes on those points or None
    (infeasible)."""
    t = step * (np.arange(k_steps + 1) if columns is None else np.asarray(columns, float))
    wd = omega * np.sqrt(1.0 - zeta**2)
    growth = np.exp(np.outer(zeta * omega, t))  # (m, K+1)
    re = growth * np.cos(np.outer(wd, t))
    im = growth * np.sin(np.outer(wd, t))
    n = t.size
    a_eq = np.ones((1, n))
    for _ in range(_MAX_ROUNDS):
        rows, rhs = [], []
        for s, th in angles:
            # rows scaled to a right-hand side of 1: HiGHS's absolute row tolerance is
            # then relative to vtol
            rows.append((np.cos(th) * re[s] + np.sin(th) * im[s]) / vtol[s])
            rhs.append(1.0)
        counter[0] += 1
        # cost: the impulses' mean time, so that the vertex found uses the early grid points
        res = optimize.linprog(t / max(t[-1], step), A_ub=np.array(rows), b_ub=np.array(rhs),
                               A_eq=a_eq, b_eq=[1.0], bounds=(0.0, 1.0), method="highs")
        if res.status == 2:
            return None
        if res.status != 0:
            return None
        a = np.clip(res.x, 0.0, None)
        a /= a.sum()
        zr, zi = re @ a, im @ a
        mod = np.hypot(zr, zi)
        bad = np.nonzero(mod > vtol * (1.0 + rtol))[0]
        if bad.size == 0:
            return a
        for s in bad:
            angles.append((int(s), float(math.atan2(zi[s], zr[s]))))
    return None


def grid_feasible(omega: ArrayLike, zeta: ArrayLike, vtol: ArrayLike, step: float,
                  k_steps: int) -> np.ndarray | None:
    """Amplitudes on the grid ``0, h, ..., K h`` meeting ``|z_s| <= vtol_s``, or None.

    ``|z_s|`` is the residual vibration at the same instant at sample ``s``; a result of
    None is proven: the outer-polygon relaxation is infeasible.

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
    omega, zeta, vtol = (np.atleast_1d(np.asarray(x, float)) for x in (omega, zeta, vtol))
    angles = [(s, 2.0 * math.pi * p / _POLYGON) for s in range(omega.size)
              for p in range(_POLYGON)]
    return _lp_feasible(int(k_steps), float(step), omega, zeta, vtol, angles, [0])


class _OutOfBudget(Exception):
    """The search's budget ran out (caught in grid_optimum)."""


def grid_optimum(omega: ArrayLike, zeta: ArrayLike, vtol: ArrayLike, *, step: float,
                 horizon: float, max_doublings: int = 3,
                 check_time: Callable[[], None] | None = None,
                 budget: Callable[[], bool] | None = None) -> GridOptimum:
    """Shortest shaper on the grid ``t_k = k h`` meeting ``V <= vtol`` at every sample.

    V is the residual vibration at the same instant. The smallest feasible number of steps
    K is found by bisection on ``[0, horizon / h]`` (the horizon doubled up to
    ``max_doublings`` times if it is infeasible), each feasibility check a cutting-plane LP
    (module docstring). The cuts found are kept for the later checks: they are valid
    inequalities for every K.

    Parameters
    ----------
    omega, zeta, vtol : array_like, shape (m,)
        Sample frequencies (rad/s), damping ratios and tolerances (< 1).
    step : float
        Grid step h, s.
    horizon : float
        Duration at which the search starts, s (a feasible one saves the doublings).
    max_doublings : int, optional
        Doublings of the horizon allowed before giving up.
    check_time : callable, optional
        Called before every LP; raises to stop the search (a time limit).
    budget : callable, optional
        Called before every LP; False stops the search, which then returns the shortest
        grid shaper found so far (``complete`` False), or raises SolverError if it found
        none.

    Returns
    -------
    GridOptimum

    Raises
    ------
    SolverError
        No feasible grid shaper within ``horizon * 2**max_doublings``.

    Examples
    --------
    At 10 rad/s with a 0.1 % tolerance the shortest grid shaper ends at the ZV shaper's
    half period (π/10 s) on a grid of π/100 s:

    >>> res = grid_optimum([10.0], [0.0], [1e-3], step=math.pi / 100, horizon=1.0)
    >>> round(res.duration * 10.0 / math.pi, 9), round(res.lower_bound * 10.0 / math.pi, 9)
    (1.0, 0.9)
    """
    omega, zeta, vtol = (np.atleast_1d(np.asarray(x, float)) for x in (omega, zeta, vtol))
    step = float(step)
    angles = [(s, 2.0 * math.pi * p / _POLYGON) for s in range(omega.size)
              for p in range(_POLYGON)]
    counter = [0]

    found = {"feasible": None, "infeasible": 0.0}

    def feasible(k, h, rtol=_SEARCH_RTOL):
        if k <= 0:
            return None  # one impulse: V = 1 > vtol
        if check_time is not None:
            check_time()
        if budget is not None and not budget():
            raise _OutOfBudget
        a = _lp_feasible(k, h, omega, zeta, vtol, angles, counter, rtol)
        if a is None and h == step:  # a coarse grid's infeasibility bounds nothing here
            found["infeasible"] = max(found["infeasible"], k * h)
        elif found["feasible"] is None or k * h < found["feasible"][0] * found["feasible"][1]:
            found["feasible"] = (k, h, a)
        return a

    try:
        hi, best, lo = _search_both(feasible, omega, step, horizon, max_doublings)
        # the search accepted 0.1 % excess: the final K is solved to _CUT_RTOL (a K found
        # feasible only within the search tolerance moves up)
        for _ in range(_COARSE_STEPS):
            tight = feasible(hi, step, _CUT_RTOL)
            if tight is not None:
                best = tight
                break
            hi += 1
        else:
            raise SolverError(f"the grid LP did not converge to a relative {_CUT_RTOL:g} "
                              f"near {hi * step:.6g} s (cutting planes, HiGHS)")
    except _OutOfBudget:
        if found["feasible"] is None:
            raise SolverError("the grid LP search ran out of its budget before it found a "
                              "feasible grid shaper") from None
        k, h, a = found["feasible"]
        return _result(a, h, k * h, min(found["infeasible"], k * h), counter[0], False)
    return _result(best, step, hi * step, max(lo, 0) * step, counter[0], True)


def _result(best, step, duration, lower_bound, solves, complete):
    keep = best > 1e-12
    times = step * np.arange(best.size)[keep]
    amps = best[keep]
    shaper = Shaper(times - times[0], amps / amps.sum())
    return GridOptimum(shaper=shaper, step=step, duration=duration,
                       lower_bound=lower_bound, lp_solves=solves, complete=complete)


def _search_both(feasible, omega, step, horizon, max_doublings):
    """Coarse bracket, fine walk down and bisection: (K, A, largest infeasible K)."""
    hi = max(1, int(math.ceil(horizon / step)))
    k_max = hi * 2**max_doublings
    # the search doubles from half a period of the highest sample frequency (no shorter
    # shaper can keep V < 1 there): small LPs until the duration is bracketed
    shortest = math.pi / float(np.max(omega))
    # a coarse grid (a multiple of the step, about _COARSE_STEPS steps to the horizon)
    # brackets the optimum cheaply; the fine grid contains it, so r K1 is feasible there.
    # It keeps at least _COARSE_PER_PERIOD points per period of the highest sample
    # frequency: a coarser grid cannot place impulses where that mode needs them
    per_period = 2.0 * math.pi / float(np.max(omega)) / (_COARSE_PER_PERIOD * step)
    ratio = max(1, min(hi // _COARSE_STEPS, int(per_period)))
    if ratio > 1:
        h = step * ratio
        k1, best, _ = _search(lambda k: feasible(k, h), int(shortest / h), -(-k_max // ratio), h)
        hi = k1 * ratio
        spread = np.zeros(hi + 1)
        spread[::ratio] = best
        best = spread
        # walk down in steps of ``ratio`` until a fine-grid duration is proven infeasible
        lo = hi - ratio
        while lo > 0:
            a = feasible(lo, step)
            if a is None:
                break
            hi, best = lo, a
            lo -= ratio
        lo = max(lo, 0)
        hi, best, lo = _bisect_between(lambda k: feasible(k, step), lo, hi, best)
    else:
        hi, best, lo = _search(lambda k: feasible(k, step), int(shortest / step), k_max, step)
    return hi, best, lo


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
    omega, zeta, vtol = (np.atleast_1d(np.asarray(x, float)) for x in (omega, zeta, vtol))
    step = float(step)
    angles = [(s, 2.0 * math.pi * p / _POLYGON) for s in range(omega.size)
              for p in range(_POLYGON)]
    counter = [0]
    centres = np.rint(np.asarray(shaper.times, float) / step).astype(int)

    def feasible(k):
        if check_time is not None:
            check_time()
        near = {0, k}
        for c in centres:
            near.update(j for j in range(c - window, c + window + 1) if 0 < j < k)
        columns = np.array(sorted(near))
        a = _lp_feasible(k, step, omega, zeta, vtol, angles, counter, columns=columns)
        if a is None:
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
    return _result(best, step, hi * step, lo * step, counter[0], True)
