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
attempts are passes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from casflex._validate import number
from casflex.errors import SolverError

__all__ = ["check_restarts", "solve_from_plan", "solve_with_restarts"]

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


def solve_from_plan(solve: Callable[..., Any], arguments: dict,
                    plan: Any) -> tuple[Any, list[SolverError]]:
    """``solve(**arguments)`` warm-started from ``plan``; if that fails and the plan carries
    its multipliers, once more from its iterate alone.

    The multipliers of an iterate where Ipopt was stopped early can lead it astray: from
    move 1's 2.952 s iterate (stopped on progress) the restart with multipliers found no
    feasible point in 500 iterations, from the iterate alone it went on to 2.745 s and
    the next restart to 2.133 s (benchmarks/README_planning.md, session 17).

    Parameters
    ----------
    solve : callable
        :func:`casflex.planning.plan_move`.
    arguments : dict
        Its keyword arguments (``guess`` is replaced by ``plan``).
    plan : PlannedMove
        The start.

    Returns
    -------
    (PlannedMove or None, list of SolverError)
        The plan (``None`` if both attempts failed) and the failures met on the way.

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
    guesses = [plan]
    if getattr(plan, "solution", None) is not None:
        guesses.append(dataclasses.replace(plan, solution=None))
    for guess in guesses:
        try:
            return solve(**{**arguments, "guess": guess}), failures
        except SolverError as exc:
            failures.append(exc)
    return None, failures


def solve_with_restarts(solve: Callable[..., Any], arguments: dict, restarts: int,
                        restart_rtol: float) -> Any:
    """``solve(**arguments)``, then up to ``restarts`` warm re-solves from the best plan.

    Parameters
    ----------
    solve : callable
        :func:`casflex.planning.plan_move` (called with ``restarts=0``).
    arguments : dict
        Its keyword arguments (``guess`` is replaced by the previous plan in a restart).
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
    best = solve(**arguments)
    passes = [_pass(best)]
    best_pass = 0
    for _ in range(restarts):
        plan, failures = solve_from_plan(solve, arguments, best)
        passes += [{**dict.fromkeys(PASS_KEYS), "status": f"SolverError: {exc}"}
                   for exc in failures]
        if plan is None:
            break
        passes.append(_pass(plan))
        old, new = float(best.stats["objective_value"]), float(plan.stats["objective_value"])
        if new < old:
            best, best_pass = plan, len(passes) - 1
        if not old - new > restart_rtol * abs(old):
            break
    stats = best.stats
    stats["passes"] = passes
    stats["restarts"] = len(passes) - 1
    stats["best_pass"] = best_pass
    done = [p for p in passes if p["solve_s"] is not None]
    stats["solve_s_total"] = float(sum(p["solve_s"] for p in done))
    stats["solve_cpu_s_total"] = float(sum(p["solve_cpu_s"] for p in done))
    stats["iterations_total"] = int(sum(p["iterations"] for p in done))
    return best

