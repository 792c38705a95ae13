"""The design job's planned move: the optimal move next to the shaped one (``[planner]``).

:func:`plan_next_to_shaped` plans the study's move with :func:`casflex.planning.plan_move`
at the limits of the job's own shaped move (its peak torques and velocities with the joints
on it, :func:`casflex.planning.shaped_move_limits`, the rule of ``casflex plan``), with the
shaped move's residual tip deflection as the end bound by default, and verifies the plan
by simulation
(:func:`casflex.planning.verify_plan`). The result is a
:class:`casflex.planning.PlanComparison`, as ``casflex plan`` gives: its ``summary()`` is
the ``planner`` object of ``summary.json`` and :func:`casflex.plotting.plot_plan` draws it.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from casflex.errors import SolverError

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move, ShapedMove
    from casflex.simulate import SimulationResult

__all__ = ["plan_next_to_shaped", "planner_summary"]


def plan_next_to_shaped(model: FlexibleModel, move: Move, shaped: ShapedMove,
                        shaped_run: SimulationResult, settings: dict, *, dt: float,
                        log: Callable[[str], None] | None = None,
                        progress: bool = False,
                        cache_dir: str | os.PathLike | bool | None = None) -> Any:
    """Plan ``move`` at the limits of its shaped version and verify both.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The model the plan is made and verified on.
    move : casflex.moves.Move
    shaped : casflex.moves.ShapedMove
        The job's shaped move.
    shaped_run : casflex.simulate.SimulationResult
        ``shaped`` simulated on ``model`` with the joints on it, to ``shaped.t_end``.
    settings : dict
        The study's ``[planner]`` settings (:attr:`casflex.design.Study.planner`):
        ``objective``, ``duration`` [s], ``weight``, ``robust``, ``robust_steps`` (the
        robust plan through that many problems from the nominal one, default
        :data:`casflex.planning.ROBUST_STEPS`), ``robust_path`` (their path, default
        :func:`casflex.planning.robust_path_for`), ``end`` (``"shaped"``:
        the shaped move's residual, in each robust scenario its residual there;
        ``"rest"``, ``"free"`` or a bound [m]),
        ``intervals``, ``transcription``, ``derivatives`` (default ``"casadi"``;
        ``"points"`` compiled through ``cache_dir``: :func:`casflex.planning.point_compiler`),
        ``max_iter``, ``verify_dt`` (step of the
        verification by simulation [s]; a step that straddles a torque switch integrates
        the jump of q̈ with an error of up to half a step, so the residual of a plan is
        verified finer than the job's step).
    dt : float
        Step of the shaped move's runs at ``±robust`` and of the limits [s].
    log : callable, optional
        ``log(message)``: one line per step.
    progress : bool
        A counter of Ipopt's iterates on stderr while the plan is solved
        (:func:`casflex.planning.plan_move`'s ``progress``).
    cache_dir : str, pathlib.Path, None or False
        Cache of the compiled derivatives (``None``: the default cache; ``False``: none,
        the derivatives interpreted).

    Returns
    -------
    casflex.planning.PlanComparison
        With ``plan`` ``None`` and ``verification["error"]`` the solver's message when no
        plan was found (:class:`casflex.errors.SolverError`).

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move, ShapedMove
    >>> from casflex.robot import load
    >>> from casflex.shaping import zv
    >>> from casflex.simulate import simulate_prescribed
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> move = Move([0.0], [0.5], 1.0, settle=0.5)
    >>> shaped = ShapedMove(move, zv(25.7))
    >>> run = simulate_prescribed(model, shaped, dt=1e-3)
    >>> settings = {"objective": "time", "duration": None, "weight": 0.0, "robust": 0.0,
    ...             "end": "rest", "intervals": 12, "transcription": "collocation",
    ...             "max_iter": 200}
    >>> c = plan_next_to_shaped(model, move, shaped, run, settings, dt=1e-3)
    >>> bool(c.plan.duration < shaped.duration)
    True
    """
    from casflex.planning import (
        BOUND_CORRECTIONS,
        ROBUST_STEPS,
        PlanComparison,
        continuation_ceiling,
        hold_verified_bounds,
        plan_move,
        point_compiler,
        robust_path_for,
        shaped_end,
        shaped_move_limits,
        shaped_reference,
        verify_plan,
    )

    say = log or (lambda message: None)
    robust = float(settings["robust"])
    errors = [-robust, robust] if robust > 0.0 else []
    shaped_check = shaped_reference(model, shaped, errors, dt=dt, run=shaped_run)
    tau_lim, v_lim = shaped_move_limits(model, move, shaped, dt=dt)  # as casflex plan
    end = settings["end"]
    if end == "shaped":  # in each scenario, no more than the shaped move leaves there
        end = shaped_end(shaped_check)
    duration = settings["duration"]
    if settings["objective"] != "time" and duration is None:
        duration = float(shaped.duration)
    say(f"planning {move.name} ({settings['objective']}, end {end}"
        + (f", robust ±{robust:g}" if robust else "") + ") at the shaped move's limits ...")
    limits = {"torque": tau_lim, "velocity": v_lim}
    derivatives = settings.get("derivatives", "casadi")
    steps = settings.get("robust_steps", ROBUST_STEPS)
    path = robust_path_for(end, settings.get("robust_path"))
    try:
        plan = plan_move(model, move, objective=settings["objective"], duration=duration,
                         weight=settings["weight"], intervals=settings["intervals"],
                         torque_limit=tau_lim, velocity_limit=v_lim, end=end, robust=robust,
                         guess=shaped, transcription=settings["transcription"],
                         # a second start when the first stalls near the shaped move
                         fallback_guess="rigid" if settings["objective"] == "time" else None,
                         robust_steps=steps, robust_path=path, log=log,
                         duration_ceiling=continuation_ceiling(
                             settings["objective"], robust, steps, shaped.duration, path),
                         max_iter=settings["max_iter"], progress=progress,
                         derivatives=derivatives,
                         compile_function=point_compiler(derivatives, cache_dir, say))
    except SolverError as exc:
        say(f"the planner found no plan: {exc}")
        return PlanComparison(model=model, move=move, shaped=shaped, plan=None,
                              limits=limits, verification={"error": str(exc)},
                              shaped_verification=shaped_check)
    verify_dt = float(settings.get("verify_dt", dt))
    say(f"planned {plan.duration:.4f} s (shaped {shaped.duration:.4f} s); verifying by "
        f"simulation at dt = {verify_dt:g} s ...")
    verification = verify_plan(model, plan, dt=verify_dt, errors=errors)
    corrections = settings.get("bound_corrections", BOUND_CORRECTIONS)
    if plan.stats.get("end_bounds") is not None and corrections:
        # as casflex plan: a verified residual past its bound is solved again, tighter
        def solve_again(bounds, last):
            return plan_move(model, move, objective=settings["objective"], duration=duration,
                             weight=settings["weight"], intervals=plan.stats["intervals"],
                             torque_limit=tau_lim, velocity_limit=v_lim,
                             end=bounds if robust else bounds[0], robust=robust, guess=last,
                             elastic=last.stats.get("elastic"),
                             transcription=settings["transcription"], log=log,
                             max_iter=settings["max_iter"], progress=progress,
                             derivatives=derivatives,
                             compile_function=point_compiler(derivatives, cache_dir, say))

        plan, verification, _ = hold_verified_bounds(
            solve_again, lambda p: verify_plan(model, p, dt=verify_dt, errors=errors), plan,
            verification, corrections, say)
    return PlanComparison(model=model, move=move, shaped=shaped, plan=plan, limits=limits,
                          verification=verification, shaped_verification=shaped_check)


def planner_summary(comparison: Any, end: str | float) -> dict:
    """The ``planner`` object of ``summary.json``.

    Parameters
    ----------
    comparison : casflex.planning.PlanComparison
        From :func:`plan_next_to_shaped`.
    end : str or float
        The study's ``planner.end``.

    Returns
    -------
    dict
        ``success``; with a plan, :meth:`casflex.planning.PlanComparison.summary`
        (``duration`` [s], ``residual_tip_deflection`` (verified, m), ``torque_peak``
        [N m], ``shaped`` ...) and ``end_bound`` (the residual bound the plan was given, m,
        or ``"rest"``/``"free"``; a robust plan's nominal bound, with ``end_bounds`` the
        bound of each scenario, nominal, −r, +r); without one, ``error`` (the solver's
        message) and the shaped move's ``shaped`` figures.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> c = SimpleNamespace(plan=None, verification={"error": "no plan"},
    ...                     shaped=SimpleNamespace(duration=2.0),
    ...                     shaped_verification={"residual": 0.01, "torque_peak": [1.0]},
    ...                     move=SimpleNamespace(name="m"))
    >>> planner_summary(c, "shaped")["success"]
    False
    """
    if comparison.plan is None:
        s = comparison.shaped_verification
        return {"success": False, "move": comparison.move.name,
                "error": comparison.verification["error"], "end": end,
                "shaped": {"duration": float(comparison.shaped.duration),
                           "residual_tip_deflection": s["residual"],
                           "torque_peak": s["torque_peak"]}}
    summary = comparison.summary()
    summary.pop("timings", None)
    from casflex.planning import asked_bounds

    stats = comparison.plan.stats
    bounds = asked_bounds(stats)  # a plan re-solved for its verified bound was solved tighter
    bound = bounds[0] if bounds else stats.get("end")
    summary["success"] = bool(stats.get("success", False))
    summary["end"] = end
    summary["end_bound"] = bound if bound is not None else end
    if bounds is not None and len(bounds) > 1:
        summary["end_bounds"] = [float(b) for b in bounds]
    return summary
