"""Verification of a plan by other paths than the OCP's, and the shaped-vs-planned study.

:func:`verify_plan` simulates a :class:`~casflex.planning.PlannedMove` twice, with the
simulators of :mod:`casflex.simulate` at their own step (1 ms by default), not with the
OCP's discretisation:

* the planned joint motion with the prescribed-motion simulator (the joints on the plan,
  as a stiff joint servo would impose it);
* the planned torques, open loop, with the torque-driven simulator;

and reports both residual tip deflections next to the OCP's own prediction, for the
nominal model and for the models whose frequencies are off by the given errors.

:func:`plan_robot_move` is what ``casflex plan`` runs: the model of a robot, the
SI-shaped version of a move (:func:`casflex.shaping.shaper_for_move`), the plan at the
shaped move's peak torques and velocities, and the verification of both.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from casflex._validate import fail, number
from casflex.model import FlexibleModel
from casflex.planning.correction import BOUND_CORRECTIONS, asked_bounds, hold_verified_bounds
from casflex.planning.limits import shaped_end, shaped_move_limits
from casflex.planning.ocp import plan_move
from casflex.planning.planned import PlannedMove
from casflex.planning.restarts import ROBUST_STEPS, continuation_ceiling, robust_path_for
from casflex.planning.scenarios import frequency_shifted_model, static_deflection

if TYPE_CHECKING:
    from casflex.moves import Move
    from casflex.robot import Robot

__all__ = ["verify_plan", "plan_robot_move", "PlanComparison", "limit_excess",
           "shaped_reference", "node_step"]


def _residual_after(t, deflection, t_from):
    sel = t >= t_from - 1e-12
    return float(np.max(np.linalg.norm(deflection[sel], axis=1)))


def _plus(total, more):
    return total if total is None or not more else total + sum(more)


def _bound_excess(residual, end):
    if isinstance(end, str) or end is None:
        return None
    return max(0.0, float(residual) / float(end) - 1.0)


def shaped_reference(model: FlexibleModel, shaped: Any, errors: Sequence[float] = (),
                     dt: float = 1e-3, run: Any = None) -> dict:
    """The shaped move a plan is compared with: its residual tip deflection, nominal and at
    each frequency error, and its peaks, simulated with the joints on it.

    One definition for ``casflex plan`` (:func:`plan_robot_move`) and the design job's
    ``[planner]``: the residual is the largest tip deflection after the shaped move ends
    (:attr:`~casflex.simulate.SimulationResult.residual_tip_deflection`), on the nominal
    model and on :func:`~casflex.planning.frequency_shifted_model` at each error.

    Parameters
    ----------
    model : FlexibleModel
    shaped : casflex.moves.ShapedMove
        The shaped move (or any move) to simulate.
    errors : sequence of float
        Relative frequency errors of the other scenarios (e.g. ``[-0.1, 0.1]``).
    dt : float
        Step of the prescribed-motion simulations [s].
    run : SimulationResult, optional
        The nominal simulation, when the caller has it already (not simulated again).

    Returns
    -------
    dict
        ``residual`` [m], ``torque_peak`` [N m] and ``velocity_peak`` [rad/s] per joint,
        ``errors`` (a list of ``{"error", "residual"}``, in the order given) and ``run``
        (the nominal :class:`~casflex.simulate.SimulationResult`): what
        :func:`~casflex.planning.shaped_end` and :func:`verify_plan`'s callers read.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> ref = shaped_reference(model, Move([0.0], [0.5], 1.0, settle=0.5), errors=[0.1])
    >>> [e["error"] for e in ref["errors"]], ref["residual"] > 0.0
    ([0.1], True)
    """
    from casflex.simulate import simulate_prescribed

    if run is None:
        run = simulate_prescribed(model, shaped, dt=dt, t_end=shaped.t_end)
    out = {"residual": run.residual_tip_deflection,
           "torque_peak": run.torque_peak.tolist(),
           "velocity_peak": np.max(np.abs(run.dq), axis=0).tolist(),
           "errors": [], "run": run}
    for r in errors:
        shifted = simulate_prescribed(frequency_shifted_model(model, r), shaped, dt=dt,
                                      t_end=shaped.t_end)
        out["errors"].append({"error": float(r),
                              "residual": shifted.residual_tip_deflection})
    return out


def limit_excess(peak: Sequence[float], limit: Sequence[float]) -> list[float | None]:
    """How far verified peaks exceed the limits a plan was given, per joint.

    The OCP bounds the torque on every interval and the velocity at the nodes and the
    collocation points; the motion between them, recomputed by a simulation, may pass a
    limit by a little (0.07-1.5 % on move 1 of the design study).

    Parameters
    ----------
    peak : sequence of float
        Verified peaks (``torque_peak`` [N m] or ``velocity_peak`` [rad/s] of
        :func:`verify_plan`).
    limit : sequence of float
        The plan's limits, same units (``inf``: none).

    Returns
    -------
    list of float or None
        ``max(0, peak / limit − 1)`` per joint; ``None`` where the joint has no limit.

    Examples
    --------
    >>> e = limit_excess([0.2014, 0.05, 1.0], [0.2, 0.1, float("inf")])
    >>> round(e[0], 6), e[1:]
    (0.007, [0.0, None])
    """
    return [None if not np.isfinite(b) else max(0.0, float(a) / float(b) - 1.0)
            for a, b in zip(peak, limit, strict=True)]


def node_step(plan: PlannedMove, dt: float) -> float:
    """The largest simulation step ``<= dt`` that divides the plan's (equal) intervals.

    A plan's q̈ jumps at every node (its torques are constant over the intervals), and a
    fixed step that straddles a jump integrates it to first order; on the nodes the
    simulators take it exactly (:func:`verify_plan` steps so; session 32 of
    ``benchmarks/README_planning.md``).

    Parameters
    ----------
    plan : PlannedMove
    dt : float
        Largest step [s] (> 0).

    Returns
    -------
    float
        ``h / ceil(h / dt)`` [s], ``h`` the plan's interval; ``dt`` when its nodes are not
        equally spaced.

    Examples
    --------
    Only the plan's node times matter: intervals of 0.1 s and at most 0.03 s take four
    steps of 0.025 s each.

    >>> from types import SimpleNamespace
    >>> round(node_step(SimpleNamespace(node_t=np.linspace(0.0, 1.2, 13)), 0.03), 12)
    0.025
    """
    dt = number(dt, "dt", low=0.0, low_open=True)
    h = np.diff(np.asarray(plan.node_t, dtype=float))
    if h.size == 0 or not np.allclose(h, h[0], rtol=1e-9, atol=0.0):
        return dt
    return float(h[0]) / math.ceil(float(h[0]) / dt * (1.0 - 1e-12))


def verify_plan(model: FlexibleModel, plan: PlannedMove, *, dt: float = 1e-3,
                errors: Sequence[float] = (), torque: bool = True,
                settle: float | None = None) -> dict:
    """Residual tip deflections of ``plan`` simulated with the joints on it and under its
    torques.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The model the plan is checked on (the nominal one).
    plan : PlannedMove
    dt : float
        Largest simulation step [s]. The step taken divides the plan's intervals (the
        largest ``h / k <= dt``, ``h`` the interval), so that the torque switches and the
        jumps of q̈ at the nodes fall on steps: an RK4 step that straddles one is first
        order (move 1 of the design study at 0.1 ms: 10.854 mm off the nodes, 10.9286 mm
        on them at every step down to 0.02 ms, the OCP's own 10.9275 mm).
    errors : sequence of float
        Relative frequency errors at which the plan is simulated too
        (:func:`casflex.planning.frequency_shifted_model`).
    torque : bool
        Also run the torque-driven simulations.
    settle : float, optional
        Time simulated after the move [s] (default ``plan.settle``).

    Returns
    -------
    dict
        ``ocp`` (the OCP's prediction, m), ``prescribed`` and ``torque`` (residual tip
        deflection, largest ‖tip deflection‖ after ``duration``, m; ``torque`` is
        ``None`` without ``torque``), ``torque_peak`` (of the prescribed run, N m),
        ``velocity_peak`` (rad/s), ``end_error`` (‖q − qf‖ at the end of the torque run,
        rad), ``dt`` (the step taken, s) and ``errors``: one dict ``{"error",
        "prescribed", "torque"}`` per error.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> plan = plan_move(model, [0.0], [0.5], torque_limit=0.5, intervals=12, settle=0.5)
    >>> v = verify_plan(model, plan, dt=1e-4)
    >>> bool(v["prescribed"] < 2e-4 and v["torque"] < 2e-4)
    True
    """
    from casflex.simulate import simulate_prescribed, simulate_torque

    dt = node_step(plan, dt)
    T = plan.duration
    t_end = T + (plan.settle if settle is None else number(settle, "settle", low=0.0))
    n = model.n

    def runs(mod):
        m = mod.m
        d0 = static_deflection(mod, plan.q0)
        pres = simulate_prescribed(mod, plan, dt=dt, t_end=t_end, delta0=d0 if m else None)
        out = {"prescribed": _residual_after(pres.t, pres.tip_deflection, T),
               "torque": None, "run": pres, "torque_run": None}
        if torque:
            x0 = np.r_[plan.q0, d0, np.zeros(n + m)]
            # the law as a casadi.Function: one mapaccum, not a Python loop over the steps
            tr = simulate_torque(mod, plan.torque_function(), x0, t_end=t_end, dt=dt)
            out["torque"] = _residual_after(tr.t, tr.tip_deflection, T)
            out["torque_run"] = tr
        return out

    nominal = runs(model)
    pres = nominal["run"]
    result = {
        "ocp": float(plan.stats.get("ocp_residual", float("nan"))), "dt": dt,
        "prescribed": nominal["prescribed"],
        "torque": nominal["torque"],
        "torque_peak": pres.torque_peak.tolist(),
        "velocity_peak": np.max(np.abs(pres.dq), axis=0).tolist(),
        "end_error": None,
        "errors": [],
        "runs": {"prescribed": pres, "torque": nominal["torque_run"]},
    }
    if nominal["torque_run"] is not None:
        tr = nominal["torque_run"]
        k = int(np.searchsorted(tr.t, T - 1e-12))
        result["end_error"] = float(np.linalg.norm(tr.q[min(k, tr.t.size - 1)] - plan.qf))
    for r in errors:
        shifted = runs(frequency_shifted_model(model, float(r)))
        result["errors"].append({"error": float(r), "prescribed": shifted["prescribed"],
                                 "torque": shifted["torque"]})
    return result


@dataclass
class PlanComparison:
    """A planned move next to the SI-shaped version of the same move
    (:func:`plan_robot_move`).

    Attributes
    ----------
    model : casflex.model.FlexibleModel
    move : casflex.moves.Move
    shaped : casflex.moves.ShapedMove
    plan : PlannedMove
    limits : dict
        ``torque`` [N m] and ``velocity`` [rad/s] limits the plan was given.
    verification : dict
        :func:`verify_plan` of the plan.
    shaped_verification : dict
        ``residual`` (m), ``torque_peak`` (N m), ``velocity_peak`` (rad/s) of the shaped
        move with the joints on it, and ``errors`` (``{"error", "residual"}``).
    timings : dict
        Seconds spent in each step.
    ocp_model : casflex.model.FlexibleModel, optional
        The model the plan was optimised on, when not ``model`` (fewer modes, fits).

    Examples
    --------
    >>> c = PlanComparison(model=None, move=None, shaped=None, plan=None, limits={},
    ...                    verification={}, shaped_verification={"residual": 0.01})
    >>> c.shaped_verification["residual"]
    0.01
    """

    model: Any
    move: Any
    shaped: Any
    plan: Any
    limits: dict
    verification: dict
    shaped_verification: dict
    timings: dict = field(default_factory=dict)
    ocp_model: Any = None

    def summary(self) -> dict:
        """The JSON result of ``casflex plan`` (SI units).

        Returns
        -------
        dict
            ``duration``, ``torque_peak``, ``velocity_peak``, ``residual_tip_deflection``
            (verified: prescribed-motion run, m), ``residual_torque_driven``,
            ``residual_ocp``, ``robust`` (residuals at the frequency errors), ``shaped``
            {``duration``, ``residual_tip_deflection``, ``torque_peak``, ...},
            ``solve_s`` and ``iterations`` (totals over the restarts, the starts and a
            robust plan's continuation), ``passes`` (each pass's, :mod:`casflex.planning.restarts`;
            ``None`` without restarts), ``starts`` (each cold start's, ``None`` when the
            fallback start was not needed, :func:`casflex.planning.solve_with_fallback`),
            ``continuation`` (each problem's on a robust
            plan's path; ``None`` without one),
            ``status`` (of the plan's pass), ``intervals``, ``substeps``,
            ``limits``, ``shortening`` (1 − planned / shaped duration), ``limit_excess``
            (``torque`` and ``velocity``: per joint, how far the verified peak exceeds the
            limit the plan was given, relative, 0 when within it; ``None`` for no limit:
            the OCP bounds the torque per interval and the velocity at the nodes and
            collocation points, and between them the motion may pass a limit slightly),
            ``end_bound_excess`` (how far the verified residual passes the plan's end
            bound, relative, 0 within it; ``None`` for ``end="rest"``/``"free"``: the
            judge of a plan that Ipopt or :class:`~casflex.planning.ProgressStop` ended),
            ``bound_corrections`` (the re-solves for the verified bound,
            :func:`casflex.planning.hold_verified_bounds`; ``None`` without any: their
            seconds and iterations are in ``solve_s`` and ``iterations``).

        Examples
        --------
        >>> import numpy as np
        >>> t = np.array([0.0, 1.0])
        >>> p = PlannedMove(t=t, q=np.zeros((2, 1)), dq=np.zeros((2, 1)),
        ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
        ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
        ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
        ...                 hold_torque=np.zeros(1), stats={"status": "Solve_Succeeded"})
        >>> class Shaped:
        ...     duration = 2.0
        >>> c = PlanComparison(None, None, Shaped(), p, {"torque": [1.0], "velocity": [1.0]},
        ...                    {"prescribed": 0.0, "torque": 0.0, "ocp": 0.0, "errors": [],
        ...                     "torque_peak": [0.0], "velocity_peak": [0.0]},
        ...                    {"residual": 0.0, "torque_peak": [1.0], "velocity_peak": [1.0],
        ...                     "errors": []})
        >>> c.summary()["shortening"]
        0.5
        >>> c.summary()["limit_excess"]
        {'torque': [0.0], 'velocity': [0.0]}
        >>> c.plan.stats["end"] = 0.01   # a residual bound [m]: the verified 0 is within it
        >>> c.summary()["end_bound_excess"]
        0.0
        """
        v, s, p = self.verification, self.shaped_verification, self.plan
        first = p.stats.get("first_solve", p.stats)  # the re-solves for the bound: below
        again = p.stats.get("bound_corrections") or []
        return {
            "move": getattr(self.move, "name", None),
            "duration": p.duration,
            "torque_peak": v["torque_peak"],
            "velocity_peak": v["velocity_peak"],
            "residual_tip_deflection": v["prescribed"],
            "residual_torque_driven": v["torque"],
            "residual_ocp": v["ocp"],
            "end_error_torque_driven": v.get("end_error"),
            "robust": [{"error": e["error"], "residual_tip_deflection": e["prescribed"],
                        "residual_torque_driven": e["torque"],
                        "shaped_residual_tip_deflection": se["residual"]}
                       for e, se in zip(v["errors"], s["errors"], strict=True)],
            "shaped": {"duration": float(self.shaped.duration),
                       "residual_tip_deflection": s["residual"],
                       "torque_peak": s["torque_peak"],
                       "velocity_peak": s["velocity_peak"]},
            "shortening": 1.0 - p.duration / float(self.shaped.duration),
            "limits": {k: list(map(float, val)) for k, val in self.limits.items()},
            "limit_excess": {k: limit_excess(v[f"{k}_peak"], self.limits[k])
                             for k in ("torque", "velocity") if k in self.limits},
            "end_bound_excess": _bound_excess(v["prescribed"], (asked_bounds(p.stats)
                                                                or [p.stats.get("end")])[0]),
            "solve_s": _plus(first.get("continuation_solve_s", first.get(
                "solve_s_total", first.get("solve_s"))), [r["solve_s"] or 0.0 for r in again]),
            "status": p.stats.get("status"),
            "hessian": p.stats.get("hessian"),
            "iterations": _plus(first.get("continuation_iterations", first.get(
                "iterations_total", first.get("iterations"))),
                [r.get("iterations") or 0 for r in again]),
            "passes": first.get("passes"),
            "starts": first.get("starts"),
            "continuation": first.get("continuation"),
            "bound_corrections": p.stats.get("bound_corrections"),
            "intervals": p.stats.get("intervals"),
            "substeps": p.stats.get("substeps"),
            "objective": p.stats.get("objective"),
            "timings": dict(self.timings),
        }


def plan_robot_move(robot: Robot, move: Move, n_modes: int = 3, *, objective: str = "time",
                    duration: float | None = None, robust: float = 0.0,
                    intervals: int | None = None, end: str | float | None = None,
                    step: float | None = None, delta_order: int = 1,
                    vtol: float = 0.05, margin: float = 0.20, dt: float = 1e-3,
                    cache_dir: str | os.PathLike | None = None,
                    processes: int | None = None, progress: bool = False,
                    log: Callable[[str], None] | None = None,
                    ocp_modes: int | None = None, ocp_fit: str | None = None,
                    restarts: int = 2, robust_steps: int = ROBUST_STEPS,
                    robust_path: str | None = None,
                    bound_corrections: int = BOUND_CORRECTIONS,
                    **plan_options: Any) -> PlanComparison:
    """Plan a move of a robot at the limits of its SI-shaped version and verify both.

    The model is :func:`casflex.model.build_model` without gravity (as the shaper's,
    :func:`casflex.shaping.shaper_for_robot_move`: the deflection is vibration only); for
    a robot without a shape joint (:func:`casflex.modal.tables.shape_joints`), whose
    modes do not depend on the configuration, it is the model of the modes at ``q = 0``
    (:class:`casflex.model.PointwiseProvider`: no table to build). The
    SI shaper of the move (:func:`casflex.shaping.shaper_for_move`) gives the shaped move;
    its peak torques and velocities with the joints on it (:func:`shaped_move_limits`) are the
    planner's limits, so the comparison is fair. A joint the move holds (start = goal) has
    no torque limit (its servo holds it against the reaction of the others' motion,
    which a faster move raises) and a velocity limit of 1e-3 of the moving joints'. The
    plan's end condition is, by default, the residual tip deflection of the shaped move
    (with the joints on it), in each scenario of a robust plan the shaped move's at that
    frequency error. Both are simulated at ``dt`` (:func:`verify_plan`), and at
    ``±robust`` when ``robust > 0``.

    Parameters
    ----------
    robot : casflex.robot.Robot
    move : casflex.moves.Move
    n_modes : int
        Modes of the model.
    objective, duration, robust, intervals
        As for :func:`casflex.planning.plan_move` (an ``"energy"`` plan lasts as long as
        the shaped move unless ``duration`` [s] is given).
    end : "rest" or "free" or float or sequence of float, optional
        End condition of the plan (default: the shaped move's residual [m]; with
        ``robust``, its residual at each of 0, −r, +r as that scenario's bound).
    step : float, optional
        Grid step of the modal tables [rad].
    delta_order : {1, 0}
        Of the model (:class:`casflex.model.FlexibleModel`).
    vtol, margin : float
        Of the shaper (:func:`casflex.shaping.shaper_for_move`).
    dt : float
        Simulation step of the verification [s].
    cache_dir, processes
        For the modal tables (:func:`casflex.model.build_model`).
    progress : bool
        Progress bars of the modal tables and a counter of Ipopt's iterates (on stderr).
    log : callable, optional
        ``log(message)``: one line per step.
    ocp_modes : int, optional
        Modes of the OCP's model (default ``n_modes``); the shaper, the limits and the
        verification keep the ``n_modes`` model, so a plan on fewer modes is judged on
        all of them.
    ocp_fit : {None, "chebyshev"}
        The OCP's model from Chebyshev fits of the model terms instead of the tables'
        B-splines (:func:`casflex.model.build_model`'s ``fit``); verified on the tables'
        model.
    restarts : int
        Warm re-solves from the plan at most (:func:`casflex.planning.plan_move`'s
        ``restarts``; on move 1 of the design study one restart shortened the plan from
        2.918 to 2.133 s).
    robust_steps : int
        With ``robust``: the robust plan through this many problems from the nominal plan
        (:func:`casflex.planning.plan_move`'s ``robust_steps``; 1: solved directly from the
        shaped move). A minimum-time robust problem of that path whose solve rises above
        the shaped move's duration counts as no plan (``duration_ceiling``, unless given
        in ``plan_options``): the continuation takes a shorter step.
    robust_path : {"frequency", "bounds"}, optional
        The path of that continuation (:func:`casflex.planning.plan_move`'s
        ``robust_path``; default :func:`casflex.planning.robust_path_for`: the bound path
        with end bounds, the shaped move's by default).
    bound_corrections : int
        With a residual bound (``end`` not ``"rest"``/``"free"``): when a verified
        residual passes its bound (the OCP's discretisation), the plan is solved again
        with the bounds tightened by bound / verified residual, at most this many times,
        warm from the last plan (:func:`casflex.planning.hold_verified_bounds`; the
        re-solves in ``summary()["bound_corrections"]``); 0: the plan as solved.
    **plan_options
        More keywords of :func:`casflex.planning.plan_move` (``torque_limit``... override
        the shaped move's). A minimum-time plan from the shaped move has
        ``fallback_guess="rigid"`` unless given (``None``: one start): from the rigid
        bang-bang move when the plan from the shaped one is not
        :data:`casflex.planning.FALLBACK_SHORTENING` shorter.

    Returns
    -------
    PlanComparison

    Examples
    --------
    Not run as a doctest: on the two-link arm the tabulation and the OCP take minutes
    (``tests/planning/test_plan_cli.py`` runs the same through ``casflex plan``).

    >>> import tempfile
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> c = plan_robot_move(robot, Move([0.0, 0.0, 0.0], [-0.5, 0.0, 0.0], 2.0, settle=1.0),
    ...                     n_modes=1, intervals=10, step=np.radians(30.0), processes=1,
    ...                     cache_dir=tempfile.mkdtemp())  # doctest: +SKIP
    >>> s = c.summary()  # doctest: +SKIP
    >>> bool(s["duration"] < s["shaped"]["duration"])  # doctest: +SKIP
    True
    """
    from casflex.modal.tables import shape_joints
    from casflex.model import PointwiseProvider, build_model
    from casflex.moves import ShapedMove
    from casflex.shaping import shaper_for_move

    if move.n_joints != robot.n_joints:
        raise fail("move", move.name, f"has {move.n_joints} joint(s) but robot "
                   f"'{robot.name}' has {robot.n_joints}")
    # a start or goal outside the robot's joint limits is refused before any heavy work
    robot.within_limits(move.q0, f"move '{move.name}' start q0")
    robot.within_limits(move.qf, f"move '{move.name}' goal qf")
    robust = number(robust, "robust", low=0.0, high=1.0, high_open=True)
    ocp_modes = n_modes if ocp_modes is None else number(ocp_modes, "ocp_modes", low=1,
                                                         high=n_modes, integer=True)
    if ocp_fit is not None and ocp_fit != "chebyshev":
        raise fail("ocp_fit", ocp_fit, "must be None (the tables) or 'chebyshev'")
    if (ocp_modes != n_modes or ocp_fit is not None) and not shape_joints(robot):
        raise fail("ocp_fit" if ocp_fit else "ocp_modes", ocp_fit or ocp_modes,
                   f"needs a robot with a shape joint; '{robot.name}' has none")
    say = log or (lambda message: None)
    timings = {}
    t0 = time.perf_counter()
    if shape_joints(robot):
        say(f"building the {n_modes}-mode model of '{robot.name}' (tables cached)")
        model, _ = build_model(robot, n_modes=n_modes, step=step, gravity=None,
                               delta_order=delta_order, cache_dir=cache_dir,
                               processes=processes, progress=progress)
    else:
        # no joint changes the structure's shape: the modes of one configuration hold
        # everywhere, so there is nothing to tabulate
        say(f"building the {n_modes}-mode model of '{robot.name}' (no shape joint: the "
            "modes of one configuration)")
        model = FlexibleModel(robot, PointwiseProvider(robot, np.zeros(robot.n_joints),
                                                       count=n_modes),
                              gravity=None, delta_order=delta_order)
    ocp_model = model
    if ocp_modes != n_modes or ocp_fit is not None:
        say(f"building the OCP's {ocp_modes}-mode model"
            + (" (Chebyshev fits)" if ocp_fit else ""))
        ocp_model, _ = build_model(robot, n_modes=ocp_modes, step=step, gravity=None,
                                   delta_order=delta_order, cache_dir=cache_dir,
                                   processes=processes, progress=progress, fit=ocp_fit)
    timings["model_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(f"designing the SI shaper of {move.name} (margin ±{100 * margin:g} %)")
    design = shaper_for_move(model, move, vtol=vtol, margin=margin)
    shaped = ShapedMove(move, design.shaper)
    timings["shaper_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    errors = [-robust, robust] if robust > 0.0 else []
    shaped_check = shaped_reference(model, shaped, errors, dt=dt)
    # the shaped move's peaks; a joint the move holds is not torque-limited (limits.py)
    tau_lim, v_lim = shaped_move_limits(model, move, shaped, dt=dt)
    limits = {"torque": plan_options.pop("torque_limit", tau_lim),
              "velocity": plan_options.pop("velocity_limit", v_lim)}
    limits = {k: np.broadcast_to(np.asarray(val, dtype=float), (robot.n_joints,))
              for k, val in limits.items()}
    timings["shaped_s"] = time.perf_counter() - t0
    if end is None:
        # every scenario's bound is the shaped move's residual there (nominal, -r, +r):
        # the plan leaves no more than the shaped move at each frequency error
        end = shaped_end(shaped_check)
    path = robust_path_for(end, robust_path)
    say(f"planning {move.name}: objective {objective}, {intervals or 'default'} intervals, limits "
        f"torque {np.round(limits['torque'], 4).tolist()} N m, velocity "
        f"{np.round(limits['velocity'], 4).tolist()} rad/s, end {end}"
        + (f", robust ±{robust:g}" + (f" through {robust_steps} problems from the nominal"
                                     f" ({path} path)"
                                     if robust_steps > 1 or path == "bounds" else "")
           if robust else ""))
    if objective == "energy" and duration is None:
        duration = float(shaped.duration)
    plan_options.setdefault("duration_ceiling", continuation_ceiling(
        objective, robust, robust_steps, shaped.duration, path))
    guess = plan_options.pop("guess", shaped)
    if objective == "time" and not isinstance(guess, PlannedMove):
        plan_options.setdefault("fallback_guess", "rigid")
    t0 = time.perf_counter()
    plan = plan_move(ocp_model, move, objective=objective, duration=duration,
                     intervals=intervals, torque_limit=limits["torque"],
                     velocity_limit=limits["velocity"], end=end, robust=robust,
                     guess=guess, restarts=restarts,
                     robust_steps=robust_steps, robust_path=path, log=log,
                     progress=progress,
                     **plan_options)
    timings["plan_s"] = time.perf_counter() - t0
    say(f"planned {plan.duration:.4f} s (shaped {shaped.duration:.4f} s), Ipopt "
        f"{plan.stats['status']} in {plan.stats['iterations']} iterations, "
        f"{plan.stats['solve_s']:.2f} s"
        + (f", {plan.stats['restarts']} restart(s)" if plan.stats.get("passes") else "")
        + (f", {len(plan.stats['starts'])} starts" if plan.stats.get("starts") else "")
        + (f": {plan.stats['solve_s_total']:.2f} s in all"
           if "solve_s_total" in plan.stats else ""))
    t0 = time.perf_counter()
    say(f"verifying: prescribed-motion and torque-driven simulations at dt = {dt:g} s")
    verification = verify_plan(model, plan, dt=dt, errors=errors)
    timings["verify_s"] = time.perf_counter() - t0
    if plan.stats.get("end_bounds") is not None and bound_corrections:
        t0 = time.perf_counter()

        def solve_again(bounds, last):
            return plan_move(ocp_model, move, objective=objective, duration=duration,
                             intervals=plan.stats["intervals"],
                             torque_limit=limits["torque"], velocity_limit=limits["velocity"],
                             end=bounds if robust else bounds[0], robust=robust, guess=last,
                             log=log, progress=progress,
                             # the NLP of the plan it starts from (its multipliers fit)
                             **{**plan_options, "fallback_guess": None,
                                "elastic": last.stats.get("elastic")})

        plan, verification, _ = hold_verified_bounds(
            solve_again, lambda p: verify_plan(model, p, dt=dt, errors=errors), plan,
            verification, bound_corrections, log)
        timings["bound_corrections_s"] = time.perf_counter() - t0
    return PlanComparison(model=model, move=move, shaped=shaped, plan=plan,
                          limits=limits, verification=verification,
                          shaped_verification=shaped_check, timings=timings,
                          ocp_model=ocp_model)
