"""Optimal point-to-point motion of a flexible arm as an optimal control problem (Ipopt).

:func:`plan_move` takes the arm from rest at ``start`` to rest at ``goal``:

* dynamics: the torque-driven model ``ẋ = ode(x, τ)``, ``x = [q; δ; q̇; δ̇]``
  (:meth:`casflex.model.FlexibleModel.functions`: configuration-dependent tables through
  the interpolants, gravity and damping as the model has them);
* transcription: ``N`` intervals of equal length ``T / N`` with the torque constant on
  each, either direct collocation (the default: Gauss–Legendre, ``degree`` points per
  interval, the states there NLP variables; one SX function of an interval, expanded,
  mapped over the intervals, so the NLP's Jacobian and Hessian come from one compact
  function) or direct multiple shooting with ``substeps`` steps of
  :func:`casflex.simulate.integrators.rk4_step` per interval; the free final time ``T``
  is the time-scaling variable;
* objectives: ``"time"`` (min ``T``), ``"energy"`` (min ``∫ τᵀτ dt`` for a given
  duration) and ``"weighted"`` (min ``T + weight ∫ τᵀτ dt``);
* constraints: per-joint torque bounds on every interval, velocity and position bounds
  at every node and collocation point, joints at rest at both ends, the modes at
  rest at the start (``δ`` = its static value — zero without gravity — and ``δ̇ = 0``)
  and at the end either the same (``end="rest"``) or the residual tip deflection below a tolerance
  (``end=<float>``, m) or nothing (``end="free"``); optionally the tip deflection at
  every node below a bound;
* robust option: with ``robust=r`` the modal rows of the models whose frequencies are
  off by ``±r`` (:func:`casflex.planning.frequency_shifted_model`) are driven by the same
  joint motion (that of the nominal model under the shared torques, as a joint servo
  would impose it) and must meet the same end condition.

The residual tip deflection at the end uses the tip Jacobian ``v_j = ∂tip/∂δ_j`` at the
goal (the kinematics of the model, as the simulators compute the tip deflection) and the
amplitude ``A_j = ((δ_j − δ_sj)² + (δ̇_j / ω_j)²)^½`` of every mode's free vibration:
``Σ_j ‖v_j‖ A_j`` bounds ``max_t ‖Σ_j v_j (δ_j(t) − δ_sj)‖`` of the undamped free
vibration from above, so it is the constraint; the OCP's own prediction of the residual
(``stats["ocp_residual"]``) is that maximum, sampled over the settle time.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import choice, fail, number, vector
from casflex.errors import ModelError, SolverError
from casflex.model import FlexibleModel
from casflex.moves import Move
from casflex.planning.assembly import block_derivatives, point_values
from casflex.planning.derivatives import collocation_matrices as _collocation_matrices
from casflex.planning.derivatives import implicit_collocation_function, static_lookup
from casflex.planning.guess import (
    guess_on_grid,
    highest_free_frequency,
    rigid_bang_bang_duration,
    time_scaled,
    warm_duals,
)
from casflex.planning.lifting import LIFTED_OPTIONS, BlockLayout, lifted_scales, lifted_start
from casflex.planning.limits import diagnose_failure, end_bounds, joint_bounds
from casflex.planning.planned import PlannedMove, Propagator
from casflex.planning.progress import check_progress, progress_listener
from casflex.planning.restarts import (
    check_restarts,
    solve_by_continuation,
    solve_with_fallback,
    solve_with_restarts,
)
from casflex.planning.scenarios import (
    collocated_modal_guess,
    frequency_shifted_model,
    modal_guess,
    static_deflection,
    tip_jacobian,
)
from casflex.planning.staged import (
    fatrop_options,
    kept_scales,
    power_of_two,
    stage_order,
    stage_variables,
    state_scales,
)
from casflex.planning.stopping import (
    INTERRUPTED_STATUS,
    PROGRESS_STATUS,
    DurationCeiling,
    PlanInterrupted,
    ProgressStop,
    ViolationCeiling,
    iteration_callback,
)
from casflex.planning.transcription import (
    augmented_ode,
    explicit_collocation_function,
    shooting_interval_function,
)

__all__ = ["plan_move", "predicted_residual", "OBJECTIVES", "TRANSCRIPTIONS",
           "DYNAMICS", "DERIVATIVES", "SOLVERS", "WARM_START_OPTIONS", "LIMIT_STATUSES"]

#: the objectives of :func:`plan_move`
OBJECTIVES = ("time", "energy", "weighted")

#: the transcriptions of :func:`plan_move`
TRANSCRIPTIONS = ("collocation", "shooting")

#: the forms of the dynamics in the collocation of :func:`plan_move`
DYNAMICS = ("implicit", "explicit")

#: how :func:`plan_move` builds the NLP's derivatives: CasADi's sweeps through the whole
#: problem, per-interval blocks (:func:`casflex.planning.block_derivatives`), the
#: constraint Jacobian from blocks and the Hessian CasADi's, or both from the blocks of
#: one collocation point (:mod:`casflex.planning.derivatives`)
DERIVATIVES = ("casadi", "blocks", "blocks-jacobian", "points")

#: the NLP solvers of :func:`plan_move`: Ipopt (MUMPS) on the NLP as posed, or Fatrop on
#: the stage-ordered NLP (:mod:`casflex.planning.staged`)
SOLVERS = ("ipopt", "fatrop")

#: largest ω h of one RK4 substep (RK4 phase error per step ~ (ω h)^5 / 120 ≈ 8e-6 at 0.25)
_OMEGA_H = 0.25
#: largest ω h of one collocation interval by default (3 Gauss points, order 6 at the
#: nodes: the phase error per interval ~ (ω h)^7 / 100 000 ≈ 1e-5 at 1)
_OMEGA_H_COLLOCATION = 1.0
#: Ipopt options of a warm start from a neighbouring solution's iterate and multipliers:
#: the iterate, slacks and bound multipliers pushed 1e-4 off their bounds. At 1e-6 the
#: fraction-to-the-boundary rule cut the first steps to α ≈ 1e-3 at the active bounds of
#: a bang-bang plan: over 20 neighbouring problems of moves 1–3 of the design study a
#: median of ~36 iterations against 21.5 (benchmarks/README_planning.md, session 26)
#: ``perturb_always_cd``: the constraint rows regularised at every factorisation; near a
#: solution active bounds are linearly dependent (velocity at a node and its points) and
#: a Hessian regularisation cannot fix that inertia (it rose to 1e9, multipliers to 1e11)
WARM_START_OPTIONS = {"warm_start_init_point": "yes", "warm_start_bound_push": 1e-4,
                      "warm_start_slack_bound_push": 1e-4, "warm_start_mult_bound_push": 1e-4,
                      "mu_init": 1e-6, "perturb_always_cd": "yes"}

#: iterates in a row that must pass Ipopt's acceptable test (optimality 1e-2, constraints
#: 1e-6) before it stops there. A feasible guess on its own limits (the shaped move at its
#: peaks, what `casflex plan` starts from) can pass the test for a few iterates: on move 1
#: of the design study the optimality error there is 3.6e-3 (|∂f/∂T| = 3.2 in the scaled
#: problem), Ipopt's adaptive barrier falls to 1e-11 within 7 iterations with the Hessian
#: regularised (steps of 1e-4), and with 3 iterates the solve ended at the start (3.233 s
#: against the shaped 3.208 s). The 9th iterate leaves that plateau (optimality 0.93);
#: a solve that has converged, creeping in T, passes 15 in a row at the cost of ~12 more
#: iterations (on the one-link arm those reach the 1e-8 optimality instead)
_ACCEPTABLE_ITER = 15
#: largest constraint violation of a last iterate returned at an iteration or time limit
#: (Ipopt's ``acceptable_constr_viol_tol`` of the planner, ProgressStop's feasibility)
_FEASIBLE = 1e-6
#: Ipopt's statuses of a solve ended by a limit, not a failure: a feasible last iterate is
#: returned, its status kept (``stats["success"]`` True, ``stats["converged"]`` False)
LIMIT_STATUSES = ("Maximum_Iterations_Exceeded", "Maximum_CpuTime_Exceeded",
                  "Maximum_WallTime_Exceeded")
#: the excess over an elastic end bound that still counts as within it, relative to the
#: bound (at an interior point's solution the excess is ~ its barrier over the price)
_EXCESS_ALLOWED = 1e-3


def _limit(value, n, field, unit):
    if value is None:
        return np.full(n, np.inf)
    try:
        v = np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy() \
            if np.ndim(value) == 0 else np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        v = None
    if v is None or v.size != n or np.any(np.isnan(v)) or np.any(v <= 0.0):
        raise fail(field, value, f"must be one value or {n} values > 0 [{unit}] "
                   "(inf: no limit)")
    return v


def _residual_terms(v_norm, omega, d, dd, d_static, eps):
    """Σ_j ‖v_j‖ A_j with the free-vibration amplitude A_j (smoothed by ``eps``)."""
    total = 0
    for j in range(omega.size):
        a2 = (d[j] - d_static[j]) ** 2 + (dd[j] / omega[j]) ** 2
        total += v_norm[j] * ca.sqrt(a2 + eps**2)
    return total


def predicted_residual(model: FlexibleModel, q: ArrayLike, delta: ArrayLike,
                       ddelta: ArrayLike, t_span: float = 3.0) -> float:
    """Largest tip deflection of the undamped free vibration from ``(δ, δ̇)`` at rest at
    ``q`` (linear in δ, frequencies at ``q``), sampled over ``t_span``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like, shape (n,)
        Joint values at rest [rad].
    delta, ddelta : array_like, shape (m,)
        Modal amplitudes [√kg m] and rates at the end of the move.
    t_span : float
        Time span sampled [s] (4000 samples per second).

    Returns
    -------
    float
        [m], relative to the static deflection at ``q``.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> round(predicted_residual(model, [0.0], [1e-3], [0.0]), 6)
    0.006506
    """
    q = np.asarray(q, dtype=float).ravel()
    if not model.m:
        return 0.0
    _refuse_full_stiffness(model)
    V = tip_jacobian(model, q)
    omega = np.sqrt(np.diag(model.functions()["stiffness"](q).full()))
    d = np.asarray(delta, dtype=float).ravel() - static_deflection(model, q)
    dd = np.asarray(ddelta, dtype=float).ravel()
    t = np.linspace(0.0, t_span, max(int(4000 * t_span), 2))
    modal = d[None, :] * np.cos(omega * t[:, None]) + \
        (dd / omega)[None, :] * np.sin(omega * t[:, None])
    return float(np.max(np.linalg.norm(modal @ V.T, axis=1)))


def _refuse_full_stiffness(model):
    """The end conditions take each mode's free vibration on its own ω (diagonal K):
    a rotated (smooth) basis, whose K̃ couples the modes, would be silently wrong."""
    if getattr(model, "full_stiffness", False):
        raise ModelError("planning needs a diagonal modal stiffness; this model has a full "
                         "K̃ (a smooth mode basis): build it with basis='eigen'")


def plan_move(model: FlexibleModel, start: ArrayLike | Move, goal: ArrayLike | None = None,
              *, objective: str = "time", duration: float | None = None,
              weight: float = 0.0, intervals: int | None = None,
              substeps: int | None = None,
              torque_limit: ArrayLike | None = None, velocity_limit: ArrayLike | None = None,
              position_limits: tuple[ArrayLike, ArrayLike] | None = None,
              end: str | float = "rest", deflection_bound: float | None = None,
              robust: float = 0.0, guess: str | Any = "rigid",
              fallback_guess: str | Any | None = None,
              transcription: str = "collocation", degree: int = 3,
              dynamics: str = "implicit",
              max_duration: float | None = None, duration_ceiling: float | None = None,
              violation_ceiling: float | None = None,
              max_iter: int = 500, ipopt_options: dict | None = None, settle: float | None = None,
              name: str | None = None,
              progress_stop: ProgressStop | bool = True,
              derivatives: str = "casadi",
              compile_function: Callable[[list], list] | None = None,
              solver: str = "ipopt", restarts: int = 0,
              restart_rtol: float = 1e-3, robust_steps: int = 1,
              robust_path: str = "frequency", elastic: float | None = None,
              log: Callable[[str], None] | None = None,
              progress: bool | Callable[[int, float, float], Any] = False) -> PlannedMove:
    """Plan a rest-to-rest motion of the flexible arm with Ipopt (module docstring).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    start : array_like or casflex.moves.Move
        Start joint values [rad], or a move: its ``q0`` and ``qf`` (then ``goal`` must be
        ``None``), its ``settle`` and name, and — for ``objective="energy"`` without
        ``duration`` — its duration.
    goal : array_like, optional
        End joint values [rad].
    objective : {"time", "energy", "weighted"}
        Minimum time, minimum ``∫ τᵀτ dt`` [N² m² s] for the given ``duration``, or
        minimum ``T + weight ∫ τᵀτ dt``.
    duration : float, optional
        Duration [s] of an ``"energy"`` plan (required there, not allowed otherwise).
    weight : float
        Weight of the energy in ``"weighted"`` [1 / (N² m²)].
    intervals : int, optional
        Intervals N (torque constant on each). Default: 40 for ``"shooting"``; for
        ``"collocation"`` enough that ``ω_max T / N <= 1`` at the initial duration (the
        frequencies taken along the straight path and at ``1 + robust``), at least 20.
    substeps : int, optional
        RK4 steps per interval of the shooting transcription, and of the dense output
        and :attr:`PlannedMove.propagator` of both (default: enough that
        ``ω_max h <= 0.25`` for the initial duration).
    torque_limit, velocity_limit : float or array_like, optional
        Per-joint bounds on ``|τ|`` [N m] and ``|q̇|`` [rad/s] (default none; ``inf``:
        none for that joint).
    position_limits : (array_like, array_like), optional
        Lower and upper joint bounds [rad] at every node and collocation point (``±inf``
        for none). Default: the joint limits of ``model.robot`` (none where a joint has
        none). The start and the goal must lie within them.
    end : "rest" or "free" or float or sequence of float
        End condition of the modes: at rest (``δ`` static, ``δ̇ = 0``), no condition, or
        the residual tip deflection bound (module docstring) [m], one for all scenarios or
        one per scenario (nominal, −r, +r; ``stats["end"]`` the nominal, ``end_bounds`` all).
    deflection_bound : float, optional
        Bound on the tip deflection ‖tip − tip_rigid‖ at every node [m].
    robust : float
        Relative frequency error r (0 <= r < 1): the modal rows of the models at ``1 ± r``
        must meet the end condition too.
    transcription : {"collocation", "shooting"}
        Gauss–Legendre collocation of ``degree`` points per interval (states at the
        collocation points are NLP variables; one compact SX function mapped over the
        intervals), or multiple shooting with ``substeps`` RK4 steps per interval.
    degree : int
        Collocation points per interval (1 to 5).
    dynamics : {"implicit", "explicit"}
        Of the collocation: ``"implicit"`` makes the joint accelerations at the
        collocation points NLP variables, with the torques of the model's
        prescribed-motion form equal to the interval's torque as constraints (no
        ``(n + m)`` square solve inside the derivatives); ``"explicit"`` collocates
        ``ẋ = ode(x, τ)``.
    guess : "rigid" or move-like
        Initial guess: ``"rigid"`` (the bang-bang move whose diagonal inertia meets the
        limits), or any reference with ``duration`` and ``sample`` (a ``Move``, a
        ``ShapedMove``, a ``PlannedMove``; a ``PlannedMove`` with the same number of
        intervals is taken node by node: a warm start; if its OCP had the same variables
        and constraints, e.g. another end bound or other limits, its multipliers too,
        with :data:`WARM_START_OPTIONS`).
    fallback_guess : "rigid" or move-like, optional
        A second cold start for a minimum-time plan from a move (``guess`` a move, not a
        plan): solved too when the plan from ``guess`` (after its restarts) is less than
        :data:`casflex.planning.FALLBACK_SHORTENING` shorter than that move, or found
        none; the shorter plan is kept (:func:`casflex.planning.solve_with_fallback`,
        ``stats["starts"]``). Default: none.
    max_duration : float, optional
        Upper bound on T [s] (default 20 times the guess's duration).
    duration_ceiling : float, optional
        Give the solve up (``SolverError``, status
        :data:`casflex.planning.CEILING_STATUS`) at the first iterate whose duration is
        above this [s], or not positive (:class:`casflex.planning.DurationCeiling`;
        ``objective="time"`` only). Unlike ``max_duration`` it is no constraint: Ipopt's
        path is the same until it leaves. For a solve that starts below the ceiling and
        where a longer plan is worth nothing (the robust problems of a continuation: the
        shaped move meets their constraints at its own duration). With ``robust_steps >
        1`` it applies to the robust problems of the path, not to the nominal one solved
        first.
    violation_ceiling : float, optional
        Give the solve up (status :data:`casflex.planning.VIOLATION_CEILING_STATUS`) at the
        first iterate whose largest constraint violation (the rows scaled as Ipopt sees
        them) is above this (:class:`casflex.planning.ViolationCeiling`; no constraint
        either). With ``restarts``, a restart from a plan's iterate and multipliers
        gets :data:`casflex.planning.RESTART_VIOLATION_CEILING` unless one is given.
    max_iter : int
        Ipopt iteration limit.
    ipopt_options : dict, optional
        Extra Ipopt options (``{"tol": 1e-8}``...). With ``{"hessian_approximation":
        "limited-memory"}`` (quasi-Newton: no second derivatives, no inertia
        correction) the block derivatives build and compile no Hessian.
    settle : float, optional
        ``settle`` of the result [s] (default the move's, or 3).
    name : str, optional
        Name of the result (default the move's name with ``+planned``).
    progress_stop : ProgressStop or bool
        Also stop when the objective has stopped moving at feasible iterates
        (:class:`casflex.planning.ProgressStop`; ``True``: its defaults, or
        :meth:`ProgressStop.near_solution` for a warm start with multipliers; ``False``:
        only Ipopt's own tests). Such
        a plan has ``stats["status"] == "Stopped_On_Progress"``; the simulations of
        :func:`casflex.planning.verify_plan` judge it. ``stats["objective_trace"]``
        holds the objective and the constraint violation of every iterate.
    derivatives : {"casadi", "blocks", "blocks-jacobian", "points"}
        How the NLP's constraint Jacobian and Hessian of the Lagrangian are built:
        CasADi's sweeps through the whole problem, or (implicit collocation only) the
        interval function's own Jacobian and Hessian evaluated per interval and
        scattered into the NLP's matrices (:func:`casflex.planning.block_derivatives`),
        or the Jacobian so and the Hessian CasADi's, or both from the Jacobian and
        Hessian of the dynamics at one collocation point, evaluated at all points in one
        mapped call (:mod:`casflex.planning.derivatives`: small functions that compile
        to C in seconds). Equal to round-off, at another cost (move 1, CPU seconds per
        call, Jacobian / Hessian: 0.36 / 0.63 ``blocks-jacobian``, benchmarks/README_planning.md
        for ``points``).
    compile_function : callable, optional
        With ``derivatives="blocks"`` or ``"points"``: ``compile_function(functions) ->
        functions``, the Jacobian and Hessian functions replaced by compiled ones (e.g. C
        through :func:`casflex.codegen.compile_cached`, which the planning package may
        not import: the caller passes it); with ``"points"`` the OCP's dynamics then read
        the tables through static local B-splines
        (:func:`casflex.planning.derivatives.static_lookup`). Default: interpreted.
    solver : {"ipopt", "fatrop"}
        Ipopt (MUMPS) on the NLP as posed, or Fatrop, an interior point whose Newton step
        is a Riccati recursion over the intervals (cost per iteration linear in N), on the
        same OCP in stage order (:mod:`casflex.planning.staged`: node state and T per
        stage, torque and collocation variables its controls). Fatrop needs implicit
        collocation and ``derivatives="casadi"`` (it takes no ``jac_g`` / ``hess_lag``);
        of ``ipopt_options`` it takes ``max_iter``, ``tol``, ``mu_init``, ``bound_push``,
        ``bound_frac``, ``print_level``; no ``progress_stop`` (no iteration callback)
        and no multipliers from ``guess``. The same plan to the solvers' tolerance (one-link
        arm: T to 1e-7 relative); not yet a faster route on the design study: on its move 1
        Fatrop's cold solve ended infeasible (benchmarks/README_planning.md, "Session 13:
        fatrop"), and CasADi's derivative sweeps it needs cost ~1 s per iteration there.
    restarts, restart_rtol : int, float
        Warm re-solves from the plan at most, stopped when the objective improves by less
        than ``restart_rtol`` of it (:mod:`casflex.planning.restarts`: ``stats["passes"]``).
    robust_steps : int
        With ``robust``: reach the robust problem by a continuation of this many problems
        from the nominal one (r and the scenarios' bounds moved together, each warm from
        the plan before; the nominal problem solved first unless ``guess`` is a plan;
        :func:`casflex.planning.solve_by_continuation`, ``stats["continuation"]``).
        Default 1: the robust problem directly.
    robust_path : {"frequency", "bounds"}
        The continuation's path (:data:`casflex.planning.ROBUST_PATHS`): the frequency
        error and the bounds moved together from the nominal problem, or (``"bounds"``,
        with end bounds; a continuation even with ``robust_steps`` 1) every problem at
        the full error, the scenarios' bounds tightened from loose ones, the first
        problem started from the nominal plan lifted into the robust NLP with its
        multipliers (:func:`casflex.planning.continuation_steps`,
        :mod:`casflex.planning.lifting`).
    elastic : float, optional
        Price [objective units per m, s/m for ``"time"``] of an excess over the end bounds
        of the robust scenarios (not the nominal one): each bound gets a variable
        ``e >= 0`` (``residual <= bound + e``) and the objective ``elastic e``, and ``e``
        starts at the start's excess, so a start beyond the bounds (a plan for looser ones)
        is feasible (SNOPT's elastic mode). Above the bounds' multipliers the price makes
        the excess zero at the solution; a solve that ends with an excess above 1e-3 of
        a bound is no plan. With ``duration_ceiling`` the ceiling is raised by the start's
        price (the objective is ``T`` plus it). Default: the bounds as constraints.
    log : callable, optional
        ``log(message)``: one line per restart and per problem of a continuation.
    progress : bool or callable
        ``True``: a counter of Ipopt's iterates on stderr, with the objective and the
        largest constraint violation of the last one (one per solve:
        :class:`casflex.planning.progress.SolveProgress`); a callable:
        ``progress(iteration, objective, violation)`` at every iterate (0: the guess).
        Not with ``solver="fatrop"`` (no iteration callback).

    Returns
    -------
    PlannedMove

    Raises
    ------
    casflex.planning.PlanInterrupted
        Ctrl-C while Ipopt ran (a ``KeyboardInterrupt``); its ``plan`` is the best plan
        reached by then (the interrupted solve's last iterate if feasible, else the best
        finished pass or continuation problem; None if none), a ``guess`` that continues
        the work.
    casflex.errors.ModelError
        Malformed arguments (one line naming the argument).
    casflex.errors.SolverError
        No feasible plan: the torque limit cannot hold the arm against gravity at the start
        or the goal, or Ipopt failed; the message names the limits active at its last
        iterate. A solve that ends at an iteration or time limit
        (:data:`LIMIT_STATUSES`) with its last iterate feasible (constraints to 1e-6) is
        not a failure: that iterate is returned with its status
        (``stats["converged"]`` False) for the simulations to judge. The error's ``solve`` holds
        that solve's ``iterations``, ``solve_s`` and ``solve_cpu_s`` [s].

    Examples
    --------
    A rest-to-rest move of the one-link flexible arm at its torque limit takes at least the
    rigid minimum time ``2 √(θ J / τ_max)`` (1.288 s here):

    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> p = plan_move(model, [0.0], [1.0], torque_limit=0.1, intervals=20)
    >>> p.stats["success"], round(p.duration, 2)
    (True, 1.29)
    """
    if (robust_steps != 1 or robust_path != "frequency") and \
            number(robust, "robust", low=0.0) > 0.0:
        return solve_by_continuation(plan_move, {**locals()}, robust_steps, robust_path)
    if fallback_guess is not None:
        return solve_with_fallback(plan_move, {**locals()}, fallback_guess)
    if check_restarts(restarts, restart_rtol)[0]:
        return solve_with_restarts(plan_move, {**locals()}, restarts, restart_rtol)
    n, m = model.n, model.m
    _refuse_full_stiffness(model)
    move = start if isinstance(start, Move) or hasattr(start, "casadi_reference") else None
    if move is not None:
        if goal is not None:
            raise fail("goal", goal, "must be None when start is a move")
        q0, qf = np.asarray(move.q0, dtype=float), np.asarray(move.qf, dtype=float)
        if move.n_joints != n:
            raise fail("start", move.name, f"has {move.n_joints} joints; the model has {n}")
    else:
        q0 = vector(start, n, "start", unit="rad")
        if goal is None:
            raise fail("goal", None, "is required when start is not a move")
        qf = vector(goal, n, "goal", unit="rad")
    objective = choice(objective, "objective", OBJECTIVES)
    if duration_ceiling is not None and objective != "time":
        raise fail("duration_ceiling", duration_ceiling, "needs objective='time' (the "
                   "ceiling is on the objective, the duration)")
    guards = [rule(value) for rule, value in ((DurationCeiling, duration_ceiling),
                                              (ViolationCeiling, violation_ceiling))
              if value is not None]
    if objective == "energy":
        if duration is None and move is not None:
            duration = float(move.duration)
        if duration is None:
            raise fail("duration", None, "is required for objective 'energy' [s]")
        duration = number(duration, "duration", low=0.0, low_open=True)
    elif duration is not None:
        raise fail("duration", duration, f"is fixed only for objective 'energy'; "
                   f"'{objective}' minimises the duration")
    weight = number(weight, "weight", low=0.0)
    transcription = choice(transcription, "transcription", TRANSCRIPTIONS)
    degree = number(degree, "degree", low=1, high=5, integer=True)
    dynamics = choice(dynamics, "dynamics", DYNAMICS)
    implicit = transcription == "collocation" and dynamics == "implicit"
    derivatives = choice(derivatives, "derivatives", DERIVATIVES)
    blocks = derivatives != "casadi"
    solver = choice(solver, "solver", SOLVERS)
    fatrop = solver == "fatrop"
    if fatrop and not implicit:
        raise fail("solver", solver, "needs transcription 'collocation' with dynamics "
                   "'implicit' (the stage-ordered OCP)")
    if fatrop and blocks:  # CasADi's Fatrop takes no jac_g / hess_lag option
        raise fail("derivatives", derivatives, "must be 'casadi' with solver 'fatrop' "
                   "(Fatrop differentiates the NLP itself)")
    if blocks and not implicit:
        raise fail("derivatives", derivatives, "needs transcription 'collocation' with "
                   "dynamics 'implicit'")
    if fatrop and guards:
        raise fail("solver", solver, "takes no duration_ceiling or violation_ceiling "
                   "(CasADi's Fatrop calls no iteration callback)")
    tau_max = _limit(torque_limit, n, "torque_limit", "N m")
    v_max = _limit(velocity_limit, n, "velocity_limit", "rad/s")
    robust = number(robust, "robust", low=0.0, high=1.0, high_open=True)
    end, end_list = end_bounds(end, 3 if robust > 0.0 and m else 1)
    if deflection_bound is not None:
        deflection_bound = number(deflection_bound, "deflection_bound", low=0.0,
                                  low_open=True)
    max_iter = number(max_iter, "max_iter", low=1, integer=True)
    check_progress(progress)
    settle = float(move.settle) if settle is None and move is not None else \
        (3.0 if settle is None else number(settle, "settle", low=0.0))
    if name is None:
        name = f"{move.name}+planned" if move is not None else "planned"
    lo, hi = joint_bounds(model, position_limits, q0, qf)

    f = model.functions()
    d0, df = static_deflection(model, q0), static_deflection(model, qf)
    # holding torques at rest: the joint rows of the potential forces
    hold0 = f["potential_forces"](q0, d0).full().ravel()[:n]
    holdf = f["potential_forces"](qf, df).full().ravel()[:n]
    for label, hold in (("start", hold0), ("goal", holdf)):
        over = np.flatnonzero(np.abs(hold) > tau_max)
        if over.size:
            j = int(over[0])
            raise SolverError(
                f"plan_move: no feasible plan: the torque limit of joint {j + 1} "
                f"({tau_max[j]:.6g} N m) is below the torque that holds the arm against "
                f"gravity at the {label} ({abs(hold[j]):.6g} N m)")

    # scenarios: the modal rows of the frequency-shifted models
    errors = [-robust, robust] if robust > 0.0 and m else []
    shifted = [frequency_shifted_model(model, r) for r in errors]
    nx = 2 * (n + m)
    nxa = nx + 2 * m * len(shifted)
    x0 = np.r_[q0, d0, np.zeros(n + m)]
    z0s = [np.r_[static_deflection(s, q0), np.zeros(m)] for s in shifted]
    xa0 = np.r_[x0, *z0s] if shifted else x0

    # the initial guess, the intervals and the substeps
    if intervals is None and isinstance(guess, PlannedMove):
        intervals = guess.node_tau.shape[0]
    warm = isinstance(guess, PlannedMove) and guess.node_tau.shape[0] == intervals and \
        guess.node_x.shape[1] == nx and guess.propagator is not None
    if isinstance(guess, str):
        choice(guess, "guess", ("rigid",))
        # the rigid bang-bang stretched by 30 %: a start that the flexible end conditions
        # leave feasible (at the rigid bound itself Ipopt may stall in restoration)
        T_guess = duration if duration is not None else \
            1.3 * rigid_bang_bang_duration(model, q0, qf, tau_max, v_max)
        reference = Move(q0, qf, T_guess, settle=0.0)
    else:
        if not hasattr(guess, "sample") or not hasattr(guess, "duration"):
            raise fail("guess", type(guess).__name__, "must be 'rigid' or a move")
        reference = guess
        T_guess = duration if duration is not None else float(guess.duration)
    if max_duration is None:
        max_duration = 20.0 * T_guess
    max_duration = number(max_duration, "max_duration", low=0.0, low_open=True)
    omega_max = highest_free_frequency(model, q0, qf) * (1.0 + robust)
    chosen = intervals is None
    if chosen:
        intervals = 40 if transcription == "shooting" else \
            max(20, math.ceil(omega_max * T_guess / _OMEGA_H_COLLOCATION))
    N = number(intervals, "intervals", low=2, integer=True)
    if substeps is None:
        substeps = max(1, math.ceil(omega_max * 1.5 * T_guess / (N * _OMEGA_H)))
    substeps = number(substeps, "substeps", low=1, integer=True)
    if log is not None and not warm:
        # the size decides the cost: an arm whose free joints let its modes vibrate fast
        # (a light hub) needs many intervals, and each Ipopt iteration costs in proportion
        log(f"{name}: {N} {transcription} intervals"
            + (f" ({degree} points each)" if transcription == "collocation" else
               f" ({substeps} RK4 substeps each)")
            + (f", from ω_max h <= {_OMEGA_H_COLLOCATION:g} at the guess's {T_guess:.4g} s "
               f"(ω_max {omega_max:.1f} rad/s with the joints free)"
               if chosen and transcription == "collocation" else ""))
    tc = np.r_[ca.collocation_points(degree, "legendre")] \
        if transcription == "collocation" else np.zeros(0)
    if warm:
        T_guess = guess.duration
        X_guess, U_guess = guess.node_x, guess.node_tau
        hg = T_guess / N
        k = np.repeat(np.arange(N), tc.size)
        Xc_guess, Ac_guess = np.zeros((0, nx)), np.zeros((0, n))
        if tc.size:
            xc, xcdot = guess.propagator(k, np.tile(tc * hg, N))
            Xc_guess = np.asarray(xc).T
            Ac_guess = np.asarray(xcdot).T[:, n + m:2 * n + m]
    else:
        if not isinstance(guess, str) and T_guess != float(guess.duration):
            reference = time_scaled(guess, T_guess)
        X_guess, U_guess, Xc_guess, Ac_guess = guess_on_grid(model, reference, T_guess, N,
                                                             substeps, x0, tc)

    # each shifted model's modal rows from its own simulation of the guess's joint motion
    times = ((np.arange(N)[:, None] + tc[None, :]) * (T_guess / N)).ravel()
    scenario_guess = [modal_guess(s, reference, T_guess, N * substeps,
                                  np.arange(N + 1) * substeps, times) for s in shifted]
    if implicit:
        G, split = implicit_collocation_function(
            static_lookup(model) if compile_function and derivatives == "points"
            else model, len(errors), degree)
    # a nominal plan lifted into this robust NLP (casflex.planning.lifting), its scenario
    # rows on the collocation grid under its joint motion
    lifting = warm and implicit and bool(shifted) and not fatrop and solver == "ipopt" and \
        (guess.solution or {}).get("layout") is not None and \
        guess.solution["scales"]["x"].size == nx
    if lifting:
        scenario_guess = collocated_modal_guess(G, [1.0 + r for r in errors], X_guess,
                                                Xc_guess, Ac_guess, U_guess, T_guess / N,
                                                scenario_guess)

    def augmented(states, points=False):
        return np.hstack([states, *[g[int(points)] for g in scenario_guess]]).T

    ode = augmented_ode(model, shifted)
    opti, layout = ca.Opti(), BlockLayout()
    # the modal states are orders of magnitude smaller than the joints': every state row,
    # the torques and T are scaled by their magnitude in the guess, and the dynamics
    # constraints of a row by the row's scale
    sx = state_scales(augmented(X_guess), n, m)
    su = np.where(np.isfinite(tau_max), tau_max,
                  np.maximum(np.max(np.abs(U_guess), axis=0), 1e-3))
    sa = np.maximum(np.max(np.abs(Ac_guess), axis=0), 0.1) if implicit else None
    sT = T_guess
    # a warm start with the guess's multipliers solves in the guess's scales (kept_scales)
    kept = kept_scales(guess.solution, nxa, n, implicit) if warm and solver == "ipopt" and \
        guess.stats.get("solver", "ipopt") == "ipopt" else None
    if lifting:
        kept = lifted_scales(guess.solution, sx, n, implicit)
    sx, su, sa, sT = kept or (sx, su, sa, sT)
    if fatrop:  # stage order, T a state (casflex.planning.staged)
        sx, sT = power_of_two(sx), power_of_two(sT)
        (X, *Tk), (U, Xc, Ac), stages = stage_variables(
            opti, N, [sx] + ([np.array([sT])] if duration is None else []),
            [(su, 1), (sx, degree), (sa, degree)])
        T = Tk[0][0] if duration is None else duration
        h = Tk[0][:N] / N if duration is None else duration / N
    else:
        X = layout.variable(opti, "X", nxa, N + 1)
        U = layout.variable(opti, "U", n, N)
        opti.set_linear_scale(X, np.repeat(sx[:, None], N + 1, axis=1))
        opti.set_linear_scale(U, np.repeat(su[:, None], N, axis=1))
        T = layout.variable(opti, "T") if duration is None else duration
        if duration is None:
            opti.set_linear_scale(T, sT)
        h = T / N
    if duration is None:
        layout.subject_to(opti, "duration", opti.bounded(1e-3, T, max_duration))
        opti.set_initial(Tk[0] if fatrop else T, T_guess * np.ones((1, N + 1))
                         if fatrop else T_guess)
    if transcription == "collocation":
        if not fatrop:
            Xc = layout.variable(opti, "Xc", nxa, N * degree)
            opti.set_linear_scale(Xc, np.repeat(sx[:, None], N * degree, axis=1))
        if implicit:
            if not fatrop:
                Ac = layout.variable(opti, "Ac", n, N * degree)
                opti.set_linear_scale(Ac, np.repeat(sa[:, None], N * degree, axis=1))
            opti.set_initial(Ac, Ac_guess.T)
            # the scenarios' frequency factors: an input of G, so that every problem of a
            # robust continuation compiles to the same library
            block_args = [X[:, :N], Xc, Ac, U, h, ca.DM([1.0 + r for r in errors])]
            defects, torque_defects, Xf = G.map(N)(*block_args)
            if derivatives == "points" and compile_function:  # g through the compiled φ
                defects, torque_defects = point_values(G, split, block_args, N,
                                                       compile_function)
            if blocks:
                # the interval's end state is linear in its states: outside G, so that
                # only the defects need G's derivatives
                _, D = _collocation_matrices(degree)
                Xf = D[0] * X[:, :N] + sum(D[j + 1] * Xc[:, j::degree]
                                           for j in range(degree))
            torque_scale = np.repeat(su[:, None], N * degree, axis=1)
            block_rows = [opti.ng]
            layout.subject_to(opti, "torque defects", ca.vec(torque_defects / torque_scale)
                              == 0, rows=n)
        else:
            G = explicit_collocation_function(ode, nxa, n, degree)
            defects, Xf = G.map(N)(X[:, :N], Xc, U, h)
        defect_scale = np.repeat(sx[:, None], N * degree, axis=1)
        if implicit:
            block_rows.insert(0, opti.ng)
        layout.subject_to(opti, "defects", ca.vec(defects / defect_scale) == 0, rows=nxa)
        opti.set_initial(Xc, augmented(Xc_guess, points=True))
    else:
        Xc = None
        F = shooting_interval_function(ode, nxa, n, substeps)
        Xf, _ = F.map(N)(X[:, :N], U, T / (N * substeps))
    # the gaps: with fatrop the identity on x_{k+1}, the scale being the variable's
    layout.subject_to(opti, "gaps", (X[:, 1:] - Xf) / np.repeat(sx[:, None], N, axis=1) == 0,
                      rows=nxa)
    if fatrop and duration is None:
        layout.subject_to(opti, "duration gaps", (Tk[0][1:] - Tk[0][:N]) / sT == 0)
    # the end points' rows in the states' scales, as the gaps: in the states' units a modal
    # start row's coefficient was its scale (2e-4 on move 1), an ill-conditioned Jacobian
    layout.subject_to(opti, "start", (X[:, 0] - xa0) / sx == 0)
    layout.subject_to(opti, "goal", (X[:n, N] - qf) / sx[:n] == 0)
    layout.subject_to(opti, "goal velocity", X[n + m:2 * n + m, N] / sx[n + m:2 * n + m] == 0)
    finite_tau = np.isfinite(tau_max)
    for j in np.flatnonzero(finite_tau):
        layout.subject_to(opti, f"torque {j}", opti.bounded(-tau_max[j], U[int(j), :],
                                                              tau_max[j]))
    # velocity and position limits at the nodes and the collocation points. (On an arc at
    # the limit the node's bound follows from its interval's through the polynomial, so
    # the active bounds are linearly dependent; with the bounds at the collocation points
    # only, move 1 of the design study took Ipopt to T = 2.95 s in 30 iterations where
    # both reach 2.396 s in 32 (benchmarks/README_planning.md): both are kept.)
    points = {"nodes": X[:, 1:N], **({"points": Xc} if Xc is not None else {})}
    for j in np.flatnonzero(np.isfinite(v_max)):
        for at, P in points.items():
            layout.subject_to(opti, f"velocity {j} {at}",
                              opti.bounded(-v_max[j], P[n + m + int(j), :], v_max[j]))
    for j in range(n):
        for at, P in points.items():
            if np.isfinite(lo[j]):
                layout.subject_to(opti, f"lower {j} {at}", P[j, :] >= lo[j])
            if np.isfinite(hi[j]):
                layout.subject_to(opti, f"upper {j} {at}", P[j, :] <= hi[j])
    # end condition of the modes, in every scenario
    scen = [(model, X[n:n + m, N], X[2 * n + m:nx, N])] + [
        (s, X[nx + 2 * m * k:nx + 2 * m * k + m, N], X[nx + 2 * m * k + m:nx + 2 * m * (k + 1), N])
        for k, s in enumerate(shifted)]
    v_norm = np.linalg.norm(tip_jacobian(model, qf), axis=0) if m else np.zeros(0)
    residual_cons, excesses = [], []
    if m and end != "free":
        for k, (s, d, dd) in enumerate(scen):
            ds = static_deflection(s, qf)
            if end == "rest":
                layout.subject_to(opti, f"end {k} deflection", d == ds)
                layout.subject_to(opti, f"end {k} rate", dd == 0)
            else:
                omega = np.sqrt(np.diag(s.functions()["stiffness"](qf).full()))
                b = end_list[len(residual_cons)]
                residual_cons.append(_residual_terms(v_norm, omega, d, dd, ds, 1e-3 * b / m))
                if elastic is None or k == 0:
                    layout.subject_to(opti, f"end {k} residual", residual_cons[-1] <= b)
                    continue
                excess = layout.variable(opti, f"end {k} excess")
                opti.set_linear_scale(excess, b)
                layout.subject_to(opti, f"end {k} excess sign", excess >= 0)
                layout.subject_to(opti, f"end {k} residual", residual_cons[-1] <= b + excess)
                excesses.append((excess, residual_cons[-1], b))
    if deflection_bound is not None and m:
        tip = f["tip"]
        for k in range(1, N + 1):
            qk, dk = X[:n, k], X[n:n + m, k]
            defl = tip(qk, dk) - tip(qk, ca.DM.zeros(m))
            layout.subject_to(opti, f"deflection {k}", ca.sumsqr(defl) <= deflection_bound**2)
    energy = ca.sumsqr(U) * T / N
    price = sum(elastic * e for e, _, _ in excesses)
    if objective == "time":
        opti.minimize(T + price)
    elif objective == "energy":
        opti.minimize(energy + price)
    else:
        opti.minimize(T + weight * energy + price)
    opti.set_initial(X, augmented(X_guess))
    opti.set_initial(U, np.clip(U_guess.T, -tau_max[:, None], tau_max[:, None]))
    # optimality to 1e-8, or to an acceptable 1e-2 over _ACCEPTABLE_ITER iterates in a row
    # where the constraints hold to 1e-6: on the flexible arm the last digits of the
    # minimum time cost more iterations than the whole descent (the reduced Hessian is
    # indefinite and Ipopt's steps shrink), and the verification by simulation judges the
    # plan. Why not 3 iterates: _ACCEPTABLE_ITER's comment.
    options = {"max_iter": max_iter, "print_level": 0, "sb": "yes", "tol": 1e-8,
               "acceptable_tol": 1e-2, "acceptable_iter": _ACCEPTABLE_ITER,
               "acceptable_constr_viol_tol": 1e-6, "mu_strategy": "adaptive"}
    # Fatrop: the rows in stage order, before any multiplier is set
    equality = stage_order(opti, stages) if fatrop else None
    duals = warm_duals(guess, opti.nx, opti.ng, solver) if warm else None
    if lifting and duals is None:
        duals = lifted_start(guess.solution, layout, opti.value(opti.x, opti.initial()),
                             opti.ng)
    if duals is not None:
        # a neighbouring problem of the same shape: start from the guess's iterate with
        # its multipliers, and keep Ipopt near it (a barrier restarted at 0.1 and the
        # multipliers re-estimated walk away from it first: 136 iterations on move 1)
        opti.set_initial(opti.x, duals["x"])
        opti.set_initial(opti.lam_g, duals["lam_g"])
        options.update(WARM_START_OPTIONS)
        options.update(LIFTED_OPTIONS if duals.get("lifted") else {})
    for e, residual, b in excesses:  # the start's excess: a feasible start
        start_excess = max(float(opti.value(residual, opti.initial())) - b, 0.0) + 1e-3 * b
        opti.set_initial(e, start_excess)
        for guard in guards:
            guard.ceiling += elastic * start_excess if isinstance(guard, DurationCeiling) else 0
    options.update(ipopt_options or {})
    hessian = ("limited-memory" if options.get("hessian_approximation") == "limited-memory"
               else "exact")
    # from a neighbouring solution's iterate and multipliers the start is near the
    # optimum: the objective need not leave it before the rule may stop, and it settles
    # within a few Newton steps (ProgressStop.near_solution)
    rule = progress_stop or None
    if progress_stop is True:
        rule = ProgressStop() if duals is None else ProgressStop.near_solution()
    if fatrop:  # CasADi's Fatrop calls no iteration_callback: Fatrop's own tests only
        rule = None
    listeners = []
    if rule is not None:
        if not isinstance(rule, ProgressStop):
            raise fail("progress_stop", progress_stop, "must be a ProgressStop or a bool")
        rule = dataclasses.replace(rule)  # a fresh copy: no trace or history of a solve
        listeners.append(rule.update)
    listeners += [guard.update for guard in guards]
    display, close_display = progress_listener(False if fatrop else progress,
                                               f"Ipopt {name}", objective)
    if display is not None:
        listeners.append(display)
    plugin = {"print_time": False}
    callback = None
    if listeners:
        bounds = [np.asarray(opti.value(b, opti.initial()), dtype=float)
                  for b in (opti.lbg, opti.ubg)]
        # the elastic excesses beyond the allowance count as violation, relative to their
        # bounds (Ipopt's x is e / bound: set_linear_scale)
        soft = ([o for name, o, _, _ in layout.x if name.endswith(" excess")],
                np.ones(len(excesses)), _EXCESS_ALLOWED)
        callback = iteration_callback(*bounds, opti.nx, listeners, soft=soft)
        plugin["iteration_callback"] = callback
    if blocks:
        plugin.update(block_derivatives(opti, G, block_args, [defects, torque_defects],
                                        [0, 1], block_rows, [defect_scale, torque_scale], N,
                                        compile_function=compile_function,
                                        hessian=derivatives != "blocks-jacobian"
                                        and hessian == "exact",
                                        point=split if derivatives == "points" else None))
        if derivatives == "points" and compile_function:  # g has no derivatives of its own
            plugin.update(no_nlp_grad=True)
    if fatrop:
        opti.solver("fatrop", {**plugin, "structure_detection": "auto", "equality": equality,
                               "fatrop": fatrop_options(options)})
    else:
        opti.solver("ipopt", plugin, options)
    t_start, c_start = time.perf_counter(), time.process_time()
    try:
        sol = opti.solve()
        ok = True
        values = sol.value
    except RuntimeError:
        values = opti.debug.value
        status = str(opti.stats().get("return_status", "unknown"))
        # stopped by the rule, or by an iteration / time limit at a feasible iterate: the
        # plan is returned with its status and the simulations judge it (move 1 of the
        # design study ended max_iter at T = 2.407 s, feasible, 25 % below the shaped
        # move); an infeasible last iterate is no plan
        ok = (rule is not None and rule.stopped) or (
            status in LIMIT_STATUSES and _violation(opti, values) <= _FEASIBLE)
    finally:
        close_display()
    # a Ctrl-C (or a listener's error) stopped Ipopt: not a failure of the plan. An
    # interrupt keeps the last iterate when it is feasible (PlanInterrupted.plan)
    error = callback.error if callback is not None else None
    interrupted = isinstance(error, KeyboardInterrupt)
    if error is not None and not interrupted:
        raise error
    if interrupted:
        if not _violation(opti, values) <= _FEASIBLE:
            raise PlanInterrupted(None, "the interrupted solve's last iterate is not "
                                  "feasible") from error
        ok = True
    # above a ceiling is no plan, even at a feasible iterate (a Ctrl-C wins)
    escaped = None if interrupted else next((g for g in guards if g.exceeded is not None), None)
    ok = ok and escaped is None
    # an excess left over an elastic bound: no plan within the bounds
    over = [(k + 1, float(values(e)), b) for k, (e, _, b) in enumerate(excesses)
            if float(values(e)) > _EXCESS_ALLOWED * b]
    ok = ok and not over
    solve_s = time.perf_counter() - t_start
    solve_cpu_s = time.process_time() - c_start
    stats = opti.stats()
    status = str(stats.get("return_status", "unknown"))
    if fatrop:  # Fatrop's return code (0: converged)
        status = "Solve_Succeeded" if stats.get("success") else f"Fatrop_Return_{status}"
    if rule is not None and rule.stopped:
        status = PROGRESS_STATUS
    if interrupted:
        status = INTERRUPTED_STATUS
    if escaped is not None:
        status = escaped.status
    Tv = float(values(T)) if duration is None else float(T)
    Xv = np.asarray(values(X), dtype=float).reshape(nxa, N + 1)
    Uv = np.asarray(values(U), dtype=float).reshape(n, N)
    info_violation = _violation(opti, values)
    if not ok:
        if escaped is not None:
            error = SolverError(f"plan_move: {solver.capitalize()} found no plan ({status}): "
                                f"{escaped.reason()}")
        elif over:
            error = SolverError("plan_move: no plan within the end bounds: " + ", ".join(
                f"scenario {k} ends {1e3 * e:.4g} mm above its {1e3 * b:.4g} mm"
                for k, e, b in over) + f" (elastic price {elastic:g}; {status})")
        else:
            error = SolverError(diagnose_failure(status, Tv, max_duration, Uv, Xv, tau_max,
                                                 v_max, n, m, N, duration,
                                                 solver.capitalize())
                                + f" (largest constraint violation of the last iterate "
                                  f"{info_violation:.1e})")
        # what the failed solve cost (the restarts' and the continuation's totals count it)
        error.solve = {"iterations": int(stats.get("iter_count", -1)), "solve_s": solve_s,
                       "solve_cpu_s": solve_cpu_s,
                       # whether the guess's multipliers or scales shaped this solve (if
                       # not, a retry from its iterate alone is the same solve again)
                       "used_guess_solution": duals is not None or kept is not None}
        raise error
    # the dense trajectory: ``substeps`` samples per interval, from the interval's own
    # discretisation (the RK4 substeps, or the collocation polynomial)
    hv = Tv / N
    node_x, node_tau = Xv[:nx].T.copy(), Uv.T.copy()
    propagate = Propagator(model.functions()["ode"], node_x, node_tau, hv, substeps,
                           tc if Xc is not None else None,
                           values(Xc)[:nx].T.reshape(-1, nx) if Xc is not None else None)
    k = np.r_[np.repeat(np.arange(N), substeps), N - 1]
    s_in = np.r_[np.tile(np.arange(substeps) * (hv / substeps), N), hv]
    dense, xdot = (a.T for a in propagate(k, s_in))
    dense[0], dense[-1] = node_x[0], node_x[-1]  # the OCP's end points exactly
    t_dense = np.r_[np.arange(N * substeps) * (hv / substeps), Tv]
    tau_dense = node_tau[k]
    ddq = xdot[:, n + m:2 * n + m]
    ocp_residual = predicted_residual(model, qf, Xv[n:n + m, N], Xv[2 * n + m:nx, N],
                                      max(settle, 1.0)) if m else 0.0
    info = {
        "status": status, "success": bool(stats.get("success", False) or ok),
        "converged": bool(stats.get("success", False)),
        "iterations": int(stats.get("iter_count", -1)), "solve_s": solve_s,
        "solve_cpu_s": solve_cpu_s,
        "objective": objective, "objective_value": float(values(opti.f)),
        "energy": float(values(energy)), "intervals": N, "substeps": substeps,
        "scenarios": [0.0, *errors], "end": end, "end_bounds": end_list,
        "ocp_residual": ocp_residual,
        "transcription": transcription, "degree": degree if tc.size else None,
        "dynamics": dynamics if tc.size else None,
        "derivatives": derivatives, "solver": solver,
        "hessian": hessian,
        "warm_start": warm,
    }
    info["warm_start_duals"] = duals is not None
    info["lifted_start"] = duals is not None and bool(duals.get("lifted"))
    # CPU seconds and calls of every function Ipopt evaluated (t_proc_nlp_jac_g...)
    info["timings"] = {k: float(v) for k, v in stats.items()
                       if k.startswith(("t_proc_", "n_call_")) and np.isscalar(v)}
    info["constraint_violation"] = info_violation
    if rule is not None:  # (objective, constraint violation) of every Ipopt iterate
        info["objective_trace"] = [list(pair) for pair in rule.trace]
    if residual_cons:
        info["residual_bound"] = [float(values(e)) for e in residual_cons]
    if excesses:  # [m], over the robust scenarios' bounds, and their price
        info["end_excess"] = [float(values(e)) for e, _, _ in excesses]
        info["elastic"] = elastic
    solution = {"x": np.asarray(values(opti.x), dtype=float).ravel(),
                "lam_g": np.asarray(values(opti.lam_g), dtype=float).ravel(),
                "scales": {"x": np.asarray(sx, dtype=float), "tau": np.asarray(su, dtype=float),
                           "ddq": None if sa is None else np.asarray(sa, dtype=float),
                           "T": float(sT)},
                "layout": None if fatrop else layout.to_dict()}
    plan = PlannedMove(
        t=t_dense, q=dense[:, :n], dq=dense[:, n + m:2 * n + m], ddq=ddq, tau=tau_dense,
        delta=dense[:, n:n + m], ddelta=dense[:, 2 * n + m:], node_t=np.linspace(0, Tv, N + 1),
        node_x=node_x, node_tau=node_tau, hold_torque=holdf, stats=info,
        settle=settle, name=name, propagator=propagate, solution=solution,
        description=f"{objective}-optimal plan, {N} intervals ({transcription}), end {end!r}"
                    + (f", robust ±{robust:g}" if errors else ""))
    if interrupted:
        raise PlanInterrupted(plan, f"the interrupted solve's last iterate (feasible, "
                              f"{objective} {info['objective_value']:.6g})") from error
    return plan


def _violation(opti, values):
    """Largest constraint violation of an iterate, as the constraints are posed (the
    planner's rows scaled by their magnitudes, as Ipopt and :class:`ProgressStop` see
    them)."""
    g = np.asarray(values(opti.g), dtype=float).ravel()
    lbg = np.asarray(values(opti.lbg), dtype=float).ravel()
    ubg = np.asarray(values(opti.ubg), dtype=float).ravel()
    excess = np.r_[lbg - g, g - ubg, 0.0]
    return float(np.max(excess[np.isfinite(excess)]))

