"""Warm restarts of the planner: re-solve from the plan just found.

Ipopt often stops (at its tolerance, at the progress rule of
:class:`casflex.planning.ProgressStop` or at an iteration limit) at a duration that a solve
started from that plan's iterate and multipliers shortens again: on move 1 of the design
study one restart took the plan from 2.918 s to 2.133 s (session 15). A restart is the
same problem warm-started from the previous pass (``guess=plan``: its iterate and
multipliers, :data:`casflex.planning.WARM_START_OPTIONS`); the passes stop when the
objective improves by less than ``restart_rtol`` of its value, when a pass fails or
lengthens the plan (the better plan is kept), or after ``restarts`` restarts. A restart
that fails from the previous iterate and multipliers is tried once more from the iterate
alone (the multipliers of an iterate where Ipopt was stopped early can mislead it); both
attempts are passes. The attempt with the multipliers starts feasible, and one whose
iterates leave the constraints far behind is given up there
(:data:`RESTART_VIOLATION_CEILING`).

A minimum-time plan from a cold start that ends near it may be a solve that stalled
there: :func:`solve_with_fallback` (``plan_move``'s ``fallback_guess``) then solves the
problem again from a second start and keeps the shorter plan.

A robust plan can be found by continuation (:func:`solve_by_continuation`, ``plan_move``'s
``robust_steps``): a path of robust problems from the nominal one to the one asked for,
each warm-started from the plan of the one before.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

from casflex._validate import choice, fail, number
from casflex.errors import SolverError
from casflex.planning.limits import end_bounds
from casflex.planning.planned import PlannedMove
from casflex.planning.stopping import PROGRESS_STATUS, PlanInterrupted

__all__ = ["check_restarts", "solve_from_plan", "solve_with_restarts", "solve_with_fallback",
           "FALLBACK_SHORTENING", "RESTART_VIOLATION_CEILING", "continuation_steps",
           "solve_by_continuation", "continuation_ceiling", "plan_robustness",
           "ROBUST_STEPS", "ROBUST_PATHS", "LOOSE_BOUNDS", "robust_path_for",
           "CONTINUATION_HALVINGS", "PATH_RISE", "PATH_STATUSES"]

#: robust problems on the continuation path of ``casflex plan --robust`` and of the design
#: job's robust planner by default. Move 1 of the design study at r = 0.1: solved directly
#: from the shaped move, no result after an hour of CPU (session 17); through 4 problems
#: from the nominal plan, 2.39 s in one run and no plan at the last problem in another;
#: through 8, a 3.74 s plan (benchmarks/README_planning.md, session 18)
ROBUST_STEPS = 4

#: the paths of a robust continuation (:func:`continuation_steps`): the frequency error
#: and the scenarios' bounds moved together from the nominal problem, or the bounds
#: alone tightened at the full error from a loose problem that the nominal plan starts
ROBUST_PATHS = ("frequency", "bounds")

#: the scenarios' end bounds of the bound path's first problem, in multiples of those
#: asked for. The nominal plan of move 1 of the design study leaves 4.3 and 4.6 times the
#: shaped move's residuals at ∓10 % (87.3 / 30.6 mm simulated, 103.9 / ~35 mm in the OCP's
#: measure): at 10 times those bounds are inactive at the lifted start
#: (benchmarks/README_planning.md, session 29)
LOOSE_BOUNDS = 10.0

#: shorter steps a continuation may take in all: a problem of the path that finds no plan
#: from the last plan reached is retried after the problem half-way between them. On move 1
#: of the design study the bound path's problem at 0.5 (the first where the scenarios'
#: bounds hold the plan) needed two halvings in two draws of seven (session 31), and in
#: thirteen draws of session 33 none in eight, one or two in four and all five in one;
#: session 32's CI rehearsal spent its three and failed (benchmarks/README_planning.md,
#: session 33)
CONTINUATION_HALVINGS = 5

#: the largest rise of a minimum-time plan's duration from one problem of a continuation to
#: the next, relative to the last plan reached: a solve whose iterate rises above it has
#: left the path (``duration_ceiling``, :class:`casflex.planning.DurationCeiling`), and
#: the continuation takes a shorter step. Along move 1's bound path the plans rise by
#: 0.002-0.25 % a problem (2.13331 to 2.14482 s in all) and the successful solves' iterates
#: by at most 1.6 %; in session 32's CI rehearsal a solve that had left rose to 2.65 s
#: (+24 %) and was taken, and the path failed two problems later
#: (benchmarks/README_planning.md, session 33)
PATH_RISE = 0.1

#: the statuses of a plan that a continuation takes for a problem before its last: Ipopt
#: converged, or the progress rule stopped it at a feasible iterate. A plan that ended at
#: Ipopt's acceptable level or at an iteration limit counts as a step too long: on move 1
#: every plan that left the bound path for a longer one of the same problem (2.24, 2.28,
#: 2.30, 2.65 s where the path's are 2.135-2.140 s) ended at the acceptable level, every
#: plan of a successful path in one of these two (benchmarks/README_planning.md,
#: session 33). The last problem's plan is the result and is taken as any plan is.
PATH_STATUSES = ("Solve_Succeeded", PROGRESS_STATUS)

#: a minimum-time plan from a cold start (a move as ``guess``) less than this fraction
#: shorter than that move is taken for a solve that stalled near its start, and
#: ``plan_move``'s ``fallback_guess`` is tried. On move 1 of the design study, with the
#: derivatives perturbed by one part in 1e9, the start from the shaped move ended at
#: 4 % shorter and 3.5 % longer in two of five draws, 33.5 % shorter in the other three;
#: moves 2 and 3 plan 32 % and 28 % shorter (benchmarks/README_planning.md, session 26)
FALLBACK_SHORTENING = 0.1

#: ``violation_ceiling`` of a restart from the plan's iterate and multipliers
#: (:class:`casflex.planning.ViolationCeiling`). On move 1 of the design study (15 cold
#: solves, the derivatives perturbed by one part in 1e9) such restarts that found a plan
#: stayed below a violation of 1.2; 8 of the 10 that found none in 500 iterations (75 s
#: each) had risen above 2 within 40 iterates, the other two never did
#: (benchmarks/README_planning.md, session 27). The retry from the iterate alone gets
#: none: its first steps jump (up to 1.7) and come back
RESTART_VIOLATION_CEILING = 2.0

#: what every pass records in ``stats["passes"]``
PASS_KEYS = ("duration", "objective_value", "iterations", "status", "solve_s", "solve_cpu_s")


def check_restarts(restarts: Any, restart_rtol: Any) -> tuple[int, float]:
    """``(restarts, restart_rtol)`` checked.

    Parameters
    ----------
    restarts : int
        Warm restarts at most (>= 0).
    restart_rtol : float
        Relative improvement of the objective below which the restarts stop (>= 0) [1].

    Returns
    -------
    (int, float)

    Raises
    ------
    casflex.errors.ModelError
        A negative or non-integer ``restarts``, a negative ``restart_rtol``.

    Examples
    --------
    >>> check_restarts(2, 1e-3)
    (2, 0.001)
    """
    restarts = number(restarts, "restarts", low=0, integer=True)
    restart_rtol = number(restart_rtol, "restart_rtol", low=0.0)
    return int(restarts), float(restart_rtol)


def _pass(plan) -> dict:
    s = plan.stats
    return {"duration": float(plan.duration), "objective_value": s.get("objective_value"),
            "iterations": s.get("iterations"), "status": s.get("status"),
            "solve_s": s.get("solve_s"), "solve_cpu_s": s.get("solve_cpu_s")}


def _failed(exc: SolverError, **extra: Any) -> dict:
    """The record of an attempt that found no plan (``duration`` None; its solve's time
    and iterations when the error carries them, ``exc.solve``: a failed pass of 500
    iterations is most of a run's time)."""
    spent = getattr(exc, "solve", None) or {}
    return {**dict.fromkeys(PASS_KEYS), **{k: spent.get(k) for k in
                                           ("iterations", "solve_s", "solve_cpu_s")},
            "status": f"SolverError: {exc}", **extra}


def _line(duration: float, status: Any, iterations: Any) -> str:
    return f"{duration:.6g} s ({status}, {iterations} iterations)"


def _totals(records: list[dict]) -> tuple[float, float, int]:
    """Wall and CPU seconds and iterations summed over the attempts that ran."""
    done = [p for p in records if p["solve_s"] is not None]
    return (float(sum(p["solve_s"] for p in done)), float(sum(p["solve_cpu_s"] for p in done)),
            int(sum(p["iterations"] for p in done)))


def solve_from_plan(solve: Callable[..., Any], arguments: dict, plan: Any,
                    violation_ceiling: float | None = None) -> tuple[Any, list[SolverError]]:
    """``solve(**arguments)`` warm-started from ``plan``; if that fails and the solve used
    the plan's multipliers (or the scales they belong to), once more from its iterate alone.

    The multipliers of an iterate where Ipopt was stopped early can lead it astray: from
    move 1's 2.952 s iterate (stopped on progress) the restart with multipliers found no
    feasible point in 500 iterations, from the iterate alone it went on to 2.745 s and
    the next restart to 2.133 s (benchmarks/README_planning.md, session 17). Where the
    solve could not use them (the nominal plan as the start of a robust problem: other
    variables and constraints) the retry would repeat it to the last digit (a minute of
    move 1's robust path, twice, in session 22): it is left out.

    Parameters
    ----------
    solve : callable
        :func:`casflex.planning.plan_move`.
    arguments : dict
        Its keyword arguments (``guess`` is replaced by ``plan``).
    plan : PlannedMove
        The start.
    violation_ceiling : float, optional
        ``violation_ceiling`` of the attempt from the plan's iterate and multipliers, if
        ``arguments`` has none (the retry from the iterate alone gets ``arguments``'):
        :func:`solve_with_restarts` gives :data:`RESTART_VIOLATION_CEILING`.

    Returns
    -------
    (PlannedMove or None, list of SolverError)
        The plan (``None`` if every attempt failed) and the failures met on the way.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.planning import plan_move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> p = plan_move(model, [0.0], [1.0], torque_limit=0.1, intervals=20)
    >>> q, failures = solve_from_plan(plan_move, {"model": model, "start": [0.0],
    ...                               "goal": [1.0], "torque_limit": 0.08, "intervals": 20}, p)
    >>> failures, q.duration > p.duration
    ([], True)
    """
    failures = []
    attempts = [{**arguments, "guess": plan}]
    if getattr(plan, "solution", None) is not None:
        if arguments.get("violation_ceiling") is None and violation_ceiling is not None:
            attempts[0]["violation_ceiling"] = violation_ceiling
        attempts.append({**arguments, "guess": dataclasses.replace(plan, solution=None)})
    for attempt in attempts:
        try:
            return solve(**attempt), failures
        except SolverError as exc:
            failures.append(exc)
            if not (getattr(exc, "solve", None) or {}).get("used_guess_solution", True):
                break
    return None, failures


def solve_with_restarts(solve: Callable[..., Any], arguments: dict, restarts: int,
                        restart_rtol: float) -> Any:
    """``solve(**arguments)``, then up to ``restarts`` warm re-solves from the best plan.

    Parameters
    ----------
    solve : callable
        :func:`casflex.planning.plan_move` (called with ``restarts=0``).
    arguments : dict
        Its keyword arguments (``guess`` is replaced by the previous plan in a restart;
        a restart from its iterate and multipliers gets ``violation_ceiling`` =
        :data:`RESTART_VIOLATION_CEILING` unless one is given: give a large one, e.g.
        1e9, to let it wander).
    restarts : int
        Restarts at most (>= 0).
    restart_rtol : float
        The restarts stop when a pass improves the objective by less than this fraction
        of the previous pass's (>= 0) [1].

    Returns
    -------
    PlannedMove
        The plan of the pass with the smallest objective. Its ``stats`` gain ``passes``
        (one dict per pass, in order: ``duration`` [s], ``objective_value``,
        ``iterations``, ``status``, ``solve_s`` and ``solve_cpu_s`` [s]), ``restarts``
        (restarts made), ``best_pass`` (index in ``passes``) and the totals
        ``solve_s_total``, ``solve_cpu_s_total`` [s], ``iterations_total``; its other
        stats are the best pass's.

    Raises
    ------
    casflex.errors.SolverError
        The first pass found no plan (a failed restart keeps the previous plan).

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.planning import plan_move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> p = plan_move(model, [0.0], [1.0], torque_limit=0.1, intervals=20, restarts=1)
    >>> len(p.stats["passes"]) in (1, 2), p.stats["restarts"] <= 1
    (True, True)
    """
    restarts, restart_rtol = check_restarts(restarts, restart_rtol)
    arguments = {**arguments, "restarts": 0}
    say = arguments.get("log") or (lambda message: None)
    best = solve(**arguments)
    passes = [_pass(best)]
    best_pass = 0
    say("  pass 0: " + _line(best.duration, best.stats.get("status"),
                              best.stats.get("iterations")))
    for k in range(restarts):
        try:
            plan, failures = solve_from_plan(solve, arguments, best,
                                             violation_ceiling=RESTART_VIOLATION_CEILING)
        except PlanInterrupted as exc:  # the better of the finished passes and the iterate
            if exc.plan is not None and \
                    exc.plan.stats["objective_value"] < best.stats["objective_value"]:
                raise
            raise PlanInterrupted(best, f"the best of {len(passes)} finished pass(es), "
                                  f"{best.stats['status']}") from exc
        passes += [_failed(exc) for exc in failures]
        for exc in failures:
            say(f"  restart {k + 1}: {exc}")
        if plan is None:
            break
        passes.append(_pass(plan))
        say(f"  restart {k + 1}: " + _line(plan.duration, plan.stats.get("status"),
                                           plan.stats.get("iterations")))
        old, new = float(best.stats["objective_value"]), float(plan.stats["objective_value"])
        if new < old:
            best, best_pass = plan, len(passes) - 1
        if not old - new > restart_rtol * abs(old):
            break
    stats = best.stats
    stats["passes"] = passes
    stats["restarts"] = len(passes) - 1
    stats["best_pass"] = best_pass
    stats["solve_s_total"], stats["solve_cpu_s_total"], stats["iterations_total"] = \
        _totals(passes)
    return best



def _start_record(name: str, plan: Any = None, error: SolverError | None = None) -> dict:
    """One start of :func:`solve_with_fallback`: the plan's totals over its restarts, or
    the error's cost."""
    return {**(_failed(error) if plan is None else _pass_totals(plan)), "guess": name}


def _pass_totals(plan) -> dict:
    """A plan's pass record with its totals over its restarts (if any)."""
    record = _pass(plan)
    record.update({k: plan.stats.get(f"{k}_total", record[k])
                   for k in ("solve_s", "solve_cpu_s", "iterations")})
    return record


def _guess_name(guess: Any) -> str:
    return guess if isinstance(guess, str) else str(getattr(guess, "name", type(guess).__name__))


def solve_with_fallback(solve: Callable[..., Any], arguments: dict, fallback: Any) -> Any:
    """A minimum-time plan from ``arguments["guess"]`` (a move), and from ``fallback``
    too when that one is not at least :data:`FALLBACK_SHORTENING` shorter than the move
    or found no plan; the shorter plan is kept.

    Ipopt's path on the planner's problem hinges on the last digits: on move 1 of the
    design study the cold solve from the shaped move, with the derivatives perturbed by
    one part in 10⁹, stopped near its start (3.08 s, 3.32 s against the shaped 3.21 s)
    in two of five draws where the others reached 2.133 s, and its restarts did not leave
    there; from the rigid bang-bang start the same two draws reached 2.133 s
    (benchmarks/README_planning.md, session 26). A plan that barely shortens its start
    is the sign of such a stall; the second start is a second draw, paid for only then.

    Parameters
    ----------
    solve : callable
        :func:`casflex.planning.plan_move` (called with ``fallback_guess=None``).
    arguments : dict
        Its keyword arguments: ``objective="time"`` and a ``guess`` with a ``duration``
        (a move, a shaped move; not a plan).
    fallback : "rigid" or move-like
        The second start (``guess`` of the second solve), with the same restarts.

    Returns
    -------
    PlannedMove
        The shorter plan (the first one on a tie). Its ``stats`` gain ``starts`` (one dict
        per start solved: ``guess`` (the start's name), ``duration`` [s] (None if it found
        no plan), ``status``, and ``iterations``, ``solve_s``, ``solve_cpu_s`` over its
        restarts), ``best_start`` (index in ``starts``), and ``solve_s_total``,
        ``solve_cpu_s_total``, ``iterations_total`` become the sums over the starts.

    Raises
    ------
    casflex.errors.SolverError
        Neither start found a plan (the first start's error, the second's in its note).
    casflex.planning.PlanInterrupted
        Ctrl-C in the second start: its ``plan`` is the shorter of the first start's plan
        and the interrupted solve's feasible iterate.

    Examples
    --------
    The one-link arm from a move that lasts about the minimum time already: the plan is
    barely shorter, so the rigid start is solved too, and reaches the same plan.

    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.planning import plan_move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> p = solve_with_fallback(plan_move, {"model": model, "start": [0.0], "goal": [1.0],
    ...                         "torque_limit": 0.1, "intervals": 20,
    ...                         "guess": Move([0.0], [1.0], 1.35)}, "rigid")
    >>> [(s["guess"], round(s["duration"], 6)) for s in p.stats["starts"]]
    [('move', 1.288936), ('rigid', 1.288936)]
    """
    arguments = {**arguments, "fallback_guess": None}
    guess = arguments.get("guess")
    if arguments.get("objective", "time") != "time" or isinstance(guess, (str, PlannedMove)) \
            or not hasattr(guess, "duration"):
        raise fail("fallback_guess", _guess_name(fallback),
                   f"needs objective 'time' and a move as guess (a cold start with a "
                   f"duration); got objective {arguments.get('objective', 'time')!r}, "
                   f"guess {type(guess).__name__}")
    say = arguments.get("log") or (lambda message: None)
    names = [_guess_name(guess), _guess_name(fallback)]
    try:
        first, error = solve(**arguments), None
    except SolverError as exc:
        first, error = None, exc
    records = [_start_record(names[0], first, error)]
    limit = (1.0 - FALLBACK_SHORTENING) * float(guess.duration)
    if first is not None and first.duration <= limit:
        return first
    say(f"the plan from {names[0]} "
        + (f"({first.duration:.6g} s) is not {100 * FALLBACK_SHORTENING:g} % shorter than "
           f"it ({float(guess.duration):.6g} s)" if first is not None else
           f"failed ({error})")
        + f": solving again from {names[1]}")
    try:
        second, second_error = solve(**{**arguments, "guess": fallback}), None
    except PlanInterrupted as exc:  # the better of the first plan and the iterate
        if first is None or (exc.plan is not None and exc.plan.stats["objective_value"]
                             < first.stats["objective_value"]):
            raise
        raise PlanInterrupted(first, f"the plan from {names[0]} (the second start, "
                              f"from {names[1]}, was interrupted)") from exc
    except SolverError as exc:
        second, second_error = None, exc
    records.append(_start_record(names[1], second, second_error))
    say(f"  from {names[1]}: " + (_line(second.duration, second.stats.get("status"),
                                        records[-1]["iterations"])
                                  if second is not None else f"no plan ({second_error})"))
    if first is None and second is None:
        error.add_note(f"from the fallback guess {names[1]}: {second_error}")
        raise error
    best_start = 1 if first is None or (
        second is not None
        and second.stats["objective_value"] < first.stats["objective_value"]) else 0
    best = (first, second)[best_start]
    stats = best.stats
    stats["starts"], stats["best_start"] = records, best_start
    stats["solve_s_total"], stats["solve_cpu_s_total"], stats["iterations_total"] = \
        _totals(records)
    return best


def continuation_steps(robust: float, end: Any, steps: int,
                       path: str = "frequency") -> list[tuple[float, Any]]:
    """The robust problems of a continuation: ``(r_k, end_k)`` along ``path``.

    ``"frequency"`` (k = 1..K): step k is the robust problem at ``r_k = robust k / K``
    with every scenario's end bound moved from the nominal bound by the fraction k / K
    towards its own: the path starts at the nominal problem (k = 0: every scenario the
    nominal model, bounded as it) and ends at the problem asked for. Fixed bounds would
    not do: with the bounds of ``±robust`` (e.g. the shaped move's residuals there, one
    of them below the nominal one) at a smaller error, the near-nominal scenarios must
    meet the tighter bound, a harder problem than the last (move 1 of the design study
    at r = 0.025: 3.97 s against 2.13 s nominal; benchmarks/README_planning.md,
    session 18).

    ``"bounds"`` (k = 0..K): every step at the full error ``robust``, the scenarios'
    bounds ``b L^(1 − k / K)`` with ``L =`` :data:`LOOSE_BOUNDS` (the nominal bound kept):
    step 0 is loose enough that the nominal plan, lifted into the robust NLP with its
    multipliers (:mod:`casflex.planning.lifting`), starts near its solution, and the
    bounds then tighten geometrically to those asked for (the path that found move 1's
    robust plan, session 29). Each problem starts beyond its bounds (at the plan of the
    looser ones); ``plan_move``'s ``elastic`` softens them so that the start is
    feasible (measured on move 1: not more reliable, benchmarks/README_planning.md,
    session 30). Needs end bounds (not ``"rest"`` or ``"free"``).

    Parameters
    ----------
    robust : float
        The frequency error r of the last problem (0 < r < 1).
    end : "rest" or "free" or float or sequence of float
        Its end condition, as :func:`casflex.planning.plan_move` takes it (one bound per
        scenario: nominal, −r, +r) [m].
    steps : int
        K >= 1.
    path : {"frequency", "bounds"}
        :data:`ROBUST_PATHS`.

    Returns
    -------
    list of (float, end)

    Raises
    ------
    casflex.errors.ModelError
        ``robust`` not in (0, 1), ``steps`` not an integer >= 1, a malformed ``end``, an
        unknown ``path``, or ``"bounds"`` without end bounds.

    Examples
    --------
    >>> [(r, [round(b, 4) for b in e]) for r, e in continuation_steps(0.1, [0.01, 0.02, 0.006], 2)]
    [(0.05, [0.01, 0.015, 0.008]), (0.1, [0.01, 0.02, 0.006])]
    >>> continuation_steps(0.1, "rest", 2)
    [(0.05, 'rest'), (0.1, 'rest')]
    >>> [(r, [round(b, 4) for b in e])
    ...  for r, e in continuation_steps(0.1, [0.01, 0.02, 0.006], 2, "bounds")]
    [(0.1, [0.01, 0.2, 0.06]), (0.1, [0.01, 0.0632, 0.019]), (0.1, [0.01, 0.02, 0.006])]
    """
    robust = number(robust, "robust", low=0.0, high=1.0, low_open=True, high_open=True)
    steps = int(number(steps, "robust_steps", low=1, integer=True))
    path = choice(path, "robust_path", ROBUST_PATHS)
    _, bounds = end_bounds(end, 3)  # checked
    if path == "bounds" and bounds is None:
        raise fail("end", end, "must be end bounds [m] for robust_path='bounds' (the path "
                   "tightens them)")
    first = 0 if path == "bounds" else 1
    return [_on_path(path, robust, end, k / steps) for k in range(first, steps + 1)]


def continuation_ceiling(objective: str, robust: float, robust_steps: int,
                         reference_duration: float,
                         path: str = "frequency") -> float | None:
    """The ``duration_ceiling`` of a robust plan reached by continuation from a reference
    move that meets every problem's constraints (the shaped move: the planner's limits are
    its peaks and its end bounds its residuals): that move's duration, for a minimum-time
    plan through more than one problem; else None (no ceiling).

    What ``casflex plan --robust`` (:func:`casflex.planning.plan_robot_move`) and the
    design job's robust planner use: a robust problem whose solve rises above the shaped
    move's duration has lost its way, and the continuation takes a shorter step
    (:func:`solve_by_continuation`).

    Parameters
    ----------
    objective : str
        The plan's objective (:data:`casflex.planning.OBJECTIVES`).
    robust : float
        Its frequency error r.
    robust_steps : int
        Problems on the path (1 on the frequency path: the robust problem directly from
        the reference, which starts at the ceiling: none).
    reference_duration : float
        The reference move's duration [s].
    path : {"frequency", "bounds"}
        The path (:data:`ROBUST_PATHS`; the bound path is one even with one step).

    Returns
    -------
    float or None

    Examples
    --------
    >>> continuation_ceiling("time", 0.1, 4, 3.2), continuation_ceiling("time", 0.1, 1, 3.2)
    (3.2, None)
    >>> continuation_ceiling("energy", 0.1, 4, 3.2) is None
    True
    >>> continuation_ceiling("time", 0.1, 1, 3.2, "bounds")
    3.2
    """
    if objective != "time" or not robust or (robust_steps <= 1 and path == "frequency"):
        return None
    return float(reference_duration)


def robust_path_for(end: Any, path: str | None = None) -> str:
    """The path of a robust continuation for the end condition ``end``: ``path`` if given,
    else the bound path where ``end`` is end bounds and the frequency path for
    ``"rest"`` or ``"free"`` (which have no bounds to tighten).

    What ``casflex plan --robust`` and the design job's robust planner use. On move 1 of
    the design study the frequency path reached a 2.39 s robust plan in one run and none
    in another (session 18), none in the stored run (session 28); the bound path found
    one in two runs of seven (session 30), and since warm starts regularise the
    constraint rows (:data:`casflex.planning.WARM_START_OPTIONS`) the same 2.1448 s plan
    in seven of seven (benchmarks/README_planning.md, session 31).

    Parameters
    ----------
    end : "rest" or "free" or float or sequence of float
        The end condition (:func:`casflex.planning.plan_move`).
    path : {"frequency", "bounds"}, optional
        :data:`ROBUST_PATHS`.

    Returns
    -------
    str

    Raises
    ------
    casflex.errors.ModelError
        An unknown ``path``.

    Examples
    --------
    >>> robust_path_for([0.01, 0.02, 0.006]), robust_path_for("rest")
    ('bounds', 'frequency')
    >>> robust_path_for(0.01, "frequency")
    'frequency'
    """
    if path is not None:
        return choice(path, "robust_path", ROBUST_PATHS)
    return "frequency" if isinstance(end, str) else "bounds"


def plan_robustness(plan: PlannedMove) -> float:
    """The frequency error r a plan was solved for (its scenarios at ``±r``; 0: nominal).

    Parameters
    ----------
    plan : PlannedMove

    Returns
    -------
    float

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.planning import plan_move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> p = plan_move(model, [0.0], [1.0], torque_limit=0.1, intervals=20, end=2e-3,
    ...               robust=0.05)
    >>> plan_robustness(p)
    0.05
    """
    return float(max((abs(r) for r in plan.stats.get("scenarios", ())), default=0.0))


def _on_path(path, robust, end, f):
    """The problem at fraction ``f`` of the path (``None``: the nominal problem)."""
    nominal, bounds = end_bounds(end, 3)
    if f is None:
        return 0.0, nominal
    if path == "bounds":
        return robust, end if f == 1.0 else \
            [nominal, *(b * LOOSE_BOUNDS ** (1.0 - f) for b in bounds[1:])]
    if bounds is None or f == 1.0:
        return robust * f, end
    return robust * f, [nominal + f * (b - nominal) for b in bounds]


def _path_ceiling(ceiling, plan, arguments):
    """The ``duration_ceiling`` of a problem of the path after ``plan``: ``ceiling`` or
    :data:`PATH_RISE` above ``plan``, the lower (a minimum-time plan; else ``ceiling``)."""
    if arguments.get("objective", "time") != "time" or not isinstance(plan, PlannedMove):
        return ceiling
    rise = (1.0 + PATH_RISE) * float(plan.duration)
    return rise if ceiling is None else min(float(ceiling), rise)


def _resumed(plan, path, robust, end):
    """Where a path resumes from ``plan``: the fraction of the last problem it solved
    (0 on the frequency path: the nominal problem), or ``None`` (the bound path's first
    problem next)."""
    r = plan_robustness(plan)
    if path == "frequency":
        return min(1.0, r / robust)
    bounds, solved = end_bounds(end, 3)[1], plan.stats.get("end_bounds")
    if not math.isclose(r, robust, rel_tol=1e-12) or not isinstance(solved, list) or \
            len(solved) != 3:
        return None
    return min(1.0, max(0.0, min(1.0 - math.log(s / b) / math.log(LOOSE_BOUNDS)
                                 for s, b in zip(solved[1:], bounds[1:], strict=True))))


def solve_by_continuation(solve: Callable[..., Any], arguments: dict, steps: int,
                          path: str = "frequency") -> Any:
    """The robust plan of ``arguments`` by a continuation of ``steps`` problems.

    The path starts at the nominal problem (``robust = 0``, the nominal bound), solved
    from ``arguments["guess"]`` unless that is already a plan (a
    :class:`casflex.planning.PlannedMove`: the nominal plan, or a robust one further on
    the path — the last plan of a path that failed or was interrupted — after which the
    path resumes: :func:`plan_robustness`, and on the bound path the plan's end bounds),
    then goes through the problems of :func:`continuation_steps` along ``path``, each
    warm-started from the plan before
    (:func:`solve_from_plan`: its iterate and multipliers, or its iterate alone). A
    problem that finds no plan from the last plan reached is retried after the problem
    half-way between them, :data:`CONTINUATION_HALVINGS` times in all (on move 1 of the
    design study the same four-step path reached r = 0.1 in one run and failed at its last
    step in another: Ipopt's path through these problems is that sensitive,
    benchmarks/README_planning.md, session 18). ``restarts`` apply to the nominal problem
    and to the last one, ``fallback_guess`` to the nominal one. ``duration_ceiling``
    (:class:`casflex.planning.DurationCeiling`)
    applies to every problem but the nominal one: a robust problem whose solve rises
    above it counts as finding no plan, so the path takes a shorter step instead of
    following Ipopt to long plans (move 1 of the design study: 5.37 s from one nominal
    plan where another led to 2.31 s, session 19). A minimum-time problem's ceiling is
    besides :data:`PATH_RISE` above the last plan reached, and a problem before the last
    whose plan did not converge (its status not in :data:`PATH_STATUSES`) counts as
    finding no plan too: a solve that leaves the path for a longer plan of the same
    problem (move 1: 2.24 and 2.65 s where the path's plan is 2.135 s, session 33) is not
    taken for the path's.

    Parameters
    ----------
    solve : callable
        :func:`casflex.planning.plan_move` (called with ``robust_steps=1``).
    arguments : dict
        Its keyword arguments (``robust`` > 0, ``end``, ``guess``, ``restarts``...).
    steps : int
        Robust problems on the path after its first (>= 1; 1 on the frequency path: the
        robust problem from the nominal plan).
    path : {"frequency", "bounds"}
        :data:`ROBUST_PATHS` (:func:`continuation_steps`).

    Returns
    -------
    PlannedMove
        The last problem's plan; ``stats["continuation"]`` holds one dict per problem
        solved: ``robust``, ``end_bounds`` (one per scenario [m], or ``"rest"`` /
        ``"free"``) and the pass keys (``duration`` [s], ``status``, ``iterations``,
        ``solve_s``, ``solve_cpu_s``: over the problem's restarts...; a failed attempt
        from the multipliers is its own entry, ``duration`` None), and ``continuation_solve_s`` /
        ``continuation_solve_cpu_s`` / ``continuation_iterations`` their totals.

    Raises
    ------
    casflex.errors.SolverError
        A problem of the path found no plan after the halvings: the message names it (its
        place on the path, ``r`` and bounds) and the error met there; the error's ``plan``
        is the last plan the path reached (``None`` at the first problem) and its
        ``continuation`` the records so far.

    Examples
    --------
    The one-link arm: the robust plan by a path of two problems is the robust plan
    solved directly (1.2879228904 s either way, benchmarks/README_planning.md, session 18).

    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.planning import plan_move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> kw = {"torque_limit": 0.1, "intervals": 40, "end": 2e-3, "robust": 0.1}
    >>> p = solve_by_continuation(plan_move, {"model": model, "start": [0.0], "goal": [1.0],
    ...                                       **kw}, 2)
    >>> [c["robust"] for c in p.stats["continuation"]]
    [0.0, 0.05, 0.1]
    >>> direct = plan_move(model, [0.0], [1.0], **kw)
    >>> abs(p.duration - direct.duration) < 1e-6
    True
    """
    # every problem of the path solved directly
    arguments = {**arguments, "robust_steps": 1, "robust_path": "frequency"}
    restarts = arguments.get("restarts", 0)
    end = arguments.get("end", "rest")
    robust = arguments["robust"]
    # the nominal problem starts from the caller's guess (the shaped move: at the ceiling)
    ceiling = arguments.get("duration_ceiling")
    continuation_steps(robust, end, steps, path)  # the arguments checked
    # the bound path's problem 0 is its loose one (the frequency path's, the nominal one)
    fractions = [k / steps for k in range(0 if path == "bounds" else 1, steps + 1)]
    plan, record = arguments.get("guess"), []
    # the fraction of the last problem solved (None: none on the path yet; the nominal
    # problem is the frequency path's 0)
    reached = None
    if isinstance(plan, PlannedMove):
        # a plan given: the nominal one, or the last plan of a path that failed or was
        # interrupted further on: resume after it
        reached = _resumed(plan, path, robust, end)
        fractions = [f for f in fractions if reached is None or f > reached] or [1.0]
    else:  # the nominal problem from the guess first
        fractions.insert(0, None)
    halvings = 0
    say = arguments.get("log") or (lambda message: None)
    i = 0
    while i < len(fractions):
        f = fractions[i]
        r, end_k = _on_path(path, robust, end, f)
        step = {**arguments, "robust": r, "end": end_k,
                "restarts": restarts if f in (None, 1.0) else 0,
                "duration_ceiling": None if f is None else _path_ceiling(ceiling, plan,
                                                                         arguments),
                # a second cold start is for the nominal problem (the others start warm)
                "fallback_guess": arguments.get("fallback_guess") if f is None else None}
        bounds = end_bounds(end_k, 3 if r > 0.0 else 1)[1] or end_k
        say(("continuation, the nominal problem" if f is None else
             f"continuation, problem at {f:.4g} of the path") + f": robust {r:.6g}, end "
            + (end_k if isinstance(end_k, str) else
               f"{[float(f'{1e3 * b:.4g}') for b in bounds]} mm"))
        try:
            if isinstance(plan, PlannedMove):
                new, failures = solve_from_plan(solve, step, plan)
            else:  # the nominal problem from the caller's guess (or solve's default)
                try:
                    new, failures = solve(**step), []
                except SolverError as exc:
                    new, failures = None, [exc]
        except PlanInterrupted as exc:  # the interrupted problem's iterate, else the last
            if exc.plan is not None or not isinstance(plan, PlannedMove):  # plan reached
                raise
            raise PlanInterrupted(plan, "the plan of the last problem finished" + (
                f", at {reached:.4g} of the path" if reached is not None else
                " (the nominal one)")) from exc
        if new is not None and f not in (None, 1.0) and \
                new.stats.get("status") not in PATH_STATUSES:
            # not converged: taken for a solve that left the path (its time counted)
            error = SolverError(f"plan_move: the plan ended {new.stats.get('status')} at "
                                f"{new.duration:.6g} s, not converged (PATH_STATUSES)")
            error.solve = {k: v for k, v in _pass_totals(new).items()
                           if k in ("iterations", "solve_s", "solve_cpu_s")}
            failures.append(error)
            new = None
        record += [_failed(exc, robust=r, end_bounds=bounds) for exc in failures]
        if new is None and reached is not None and f is not None and reached < f \
                and halvings < CONTINUATION_HALVINGS:
            # a shorter step from the last plan reached
            fractions.insert(i, 0.5 * (reached + f))
            halvings += 1
            say(f"  no plan: {failures[-1]}; halving the step")
            continue
        if new is None:
            where = "the nominal problem" if f is None else f"{f:.4g} of its path"
            error = SolverError(f"plan_move: the continuation found no plan at {where} "
                                f"(robust = {r:.6g}, end = {end_k}, after "
                                f"{halvings} halving(s)): {failures[-1]}")
            error.plan, error.continuation = plan, record  # what the path had reached
            raise error
        plan = new
        if f is not None or path == "frequency":
            reached = f or 0.0
        done = _pass_totals(plan)  # with restarts: their totals
        say("  " + _line(plan.duration, done["status"], done["iterations"]))
        record.append({**done, "robust": r, "end_bounds": bounds})
        i += 1
    stats = plan.stats
    stats["continuation"] = record
    stats["continuation_solve_s"], stats["continuation_solve_cpu_s"], \
        stats["continuation_iterations"] = _totals(record)
    return plan
