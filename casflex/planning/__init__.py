"""Optimal point-to-point motion on the flexible model (``casflex plan``).

The planner solves the rest-to-rest motion of the arm as an optimal control problem on
the torque-driven flexible model (direct collocation or multiple shooting, Ipopt): minimum time or
energy within per-joint torque, velocity and position limits, with the vibration at the
end as a constraint, optionally robust to a frequency error. Its result is a
:class:`PlannedMove`, usable wherever a move is, and it is verified by simulating it on
paths that do not share the OCP's discretisation.

Planning (:mod:`casflex.planning.ocp`)
--------------------------------------
plan_move
    The optimal control problem: objectives, limits, end conditions, robust scenarios.
predicted_residual
    The residual tip deflection of the free vibration from an end state.
OBJECTIVES
    The objectives of :func:`plan_move`.
TRANSCRIPTIONS
    The transcriptions of :func:`plan_move` (collocation, multiple shooting).
DYNAMICS
    The forms of the collocated dynamics of :func:`plan_move` (implicit, explicit).
WARM_START_OPTIONS
    Ipopt options of a warm start of :func:`plan_move` from a neighbouring plan's
    iterate and multipliers.
LIMIT_STATUSES
    Ipopt's statuses of a solve ended by an iteration or time limit, whose feasible last
    iterate :func:`plan_move` returns.

DERIVATIVES
    How :func:`plan_move` builds the NLP's derivatives (CasADi's, per-interval blocks, or
    per-point blocks).

SOLVERS
    The NLP solvers of :func:`plan_move`: Ipopt, or Fatrop on the stage-ordered OCP
    (:mod:`casflex.planning.staged`).

Derivatives from per-interval blocks (:mod:`casflex.planning.assembly`)
-----------------------------------------------------------------------
block_derivatives
    The NLP's constraint Jacobian and Hessian of the Lagrangian assembled from the
    interval function's own derivatives (Ipopt's ``jac_g`` and ``hess_lag``), or from
    those of one point function (``point``: :func:`casflex.planning.assembly.point_split`,
    the implicit collocation's in :mod:`casflex.planning.derivatives`).
default_derivatives
    The fastest derivatives for a transcription and a solver (``"points"`` with
    collocation and Ipopt): what ``casflex plan`` and the design job use when not told.
point_compiler
    ``plan_move``'s ``compile_function`` for ``"points"``: the point function's
    derivatives compiled and cached — a quick build at once, an optimised one in the
    background for the next solves — or ``None`` without a C compiler.
QUICK_FLAGS, OPTIMISED_FLAGS
    The compiler flags of those two builds.

Stopping (:mod:`casflex.planning.stopping`)
--------------------------------------------
ProgressStop
    The stop of a solve on the progress of its objective at feasible iterates (an Ipopt
    iteration callback).
PROGRESS_STATUS
    The status of a plan that :class:`ProgressStop` ended.
iteration_callback
    Ipopt's iteration callback that hands every iterate's objective and constraint
    violation to listeners (the stop, the display).
SolveProgress
    The live counter of a solve's iterates on stderr (``plan_move(progress=True)``).
PlanInterrupted
    Ctrl-C during a plan (a ``KeyboardInterrupt``), with the best plan reached by then.
INTERRUPTED_STATUS
    The status of that plan when it is the interrupted solve's last iterate.
DurationCeiling
    Gives a minimum-time solve up once its duration rises above a ceiling
    (``plan_move``'s ``duration_ceiling``).
CEILING_STATUS
    The status in the ``SolverError`` of a solve given up so.
ViolationCeiling
    Gives a solve up once its constraint violation rises above a ceiling
    (``plan_move``'s ``violation_ceiling``; a restart's by default).
VIOLATION_CEILING_STATUS
    The status in the ``SolverError`` of a solve given up so.

The result (:mod:`casflex.planning.planned`)
--------------------------------------------
PlannedMove
    Dense trajectory, node values, torques, solver statistics; sampling, torque law, CSV;
    pickles (a plan saved and reused, e.g. as the warm start of a later run).
Propagator
    The OCP's own discretisation of an interval: the state after a node, for sampling.

Limits (:mod:`casflex.planning.limits`)
---------------------------------------
shaped_move_limits
    The torque and velocity limits of a plan from the shaped version of its move.
end_bounds
    :func:`plan_move`'s end condition: one residual bound, or one per scenario.
shaped_end
    The end condition "no more than the shaped move" in every scenario.
plan_limits
    Peak torques and velocities of a reference with the joints on it (the default limits).

Restarts and continuation (:mod:`casflex.planning.restarts`)
-------------------------------------------------------------
solve_with_restarts
    Re-solve a plan warm from itself while it gets shorter (``plan_move``'s ``restarts``).
solve_from_plan
    One warm start from a plan: from its iterate and multipliers, else its iterate alone.
solve_with_fallback
    A second cold start when the first plan barely shortens its start (``plan_move``'s
    ``fallback_guess``).
FALLBACK_SHORTENING
    The shortening below which the second start is tried.
RESTART_VIOLATION_CEILING
    The constraint violation at which a restart is given up.
solve_by_continuation
    A robust plan through a path of problems from the nominal one (``plan_move``'s
    ``robust_steps``).
continuation_steps
    The frequency errors and end bounds of that path.
plan_robustness
    The frequency error a plan was solved for (where a resumed path starts).
continuation_ceiling
    The duration above which a robust problem of that path counts as no plan (the
    shaped move's, by default, for a minimum-time plan).
ROBUST_STEPS
    The problems on that path in ``casflex plan --robust`` and the design job by default.
ROBUST_PATHS
    The paths: the frequency error and the bounds together, or the bounds alone at the
    full error (``plan_move``'s ``robust_path``).
LOOSE_BOUNDS
    The bound path's first bounds, in multiples of those asked for.
PATH_RISE
    The largest rise of a minimum-time plan from one problem of that path to the next.
PATH_STATUSES
    The statuses of a plan that path takes for a problem before its last (converged).
CONTINUATION_HALVINGS
    The shorter steps that path may take in all where a problem finds no plan.
robust_path_for
    The path for an end condition (``casflex plan --robust`` and the design job): the
    bound path with end bounds.

A nominal plan as the start of the robust problem (:mod:`casflex.planning.lifting`)
-----------------------------------------------------------------------------------
BlockLayout
    Where each named block of variables and constraints lies in the planner's NLP (kept
    with a plan).
lifted_start
    A nominal plan's iterate and multipliers in the robust NLP, the scenario rows added.
lifted_scales
    The scales of that NLP: the plan's on its rows.
LIFTED_OPTIONS
    Ipopt options of a solve from a lifted start (SPRAL).

Verification (:mod:`casflex.planning.verify`)
---------------------------------------------
verify_plan
    Residual tip deflections of a plan simulated with the joints on it and under its
    torques, nominal and at frequency errors.
node_step
    The largest simulation step up to a given one that puts every node of a plan on a
    step (the plan's q̈ jumps there).
plan_robot_move
    Build the model of a robot, shape the move, plan it at the shaped move's limits and
    verify both (what ``casflex plan`` runs).
PlanComparison
    Result of :func:`plan_robot_move`.
limit_excess
    How far a plan's verified torque and velocity peaks exceed its limits (between the
    collocation points), per joint.
shaped_reference
    The shaped move a plan is compared with: its residual (nominal and at frequency
    errors) and peaks.

End bounds held by the verified residual (:mod:`casflex.planning.correction`)
-----------------------------------------------------------------------------
hold_verified_bounds
    Re-solve a plan with tighter end bounds until its verified residuals meet the bounds
    asked for (``plan_robot_move``'s ``bound_corrections``).
tightened_bounds
    The next bounds: each scaled by asked / verified where the verified residual passes.
verified_residuals
    A verification's residuals in the order of the plan's scenarios.
asked_bounds
    The end bounds a plan was asked to meet (not the tighter ones it was re-solved with).
BOUND_CORRECTIONS
    The re-solves made at most by default.
BOUND_MARGIN
    How far below the bound asked for a re-solve aims (relative).

Models with shifted frequencies (:mod:`casflex.planning.scenarios`)
-------------------------------------------------------------------
frequency_shifted_model
    The model with every natural frequency off by a factor ``1 + r``.
ScaledFrequencyProvider
    The provider wrapper behind it.
static_deflection
    Modal amplitudes of the arm at rest (zero without gravity).
tip_jacobian
    ``∂tip/∂δ`` at δ = 0.
modal_guess
    A scenario's modal rows simulated under a move's joint motion.
collocated_modal_guess
    The scenarios' modal rows solved from the collocation equations under a plan's.

Examples
--------
>>> import numpy as np
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> from casflex.robot import load
>>> robot = load("problems/onelink.toml")
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
>>> plan = plan_move(model, [0.0], [0.5], torque_limit=0.2, intervals=12)
>>> plan.stats["success"], bool(plan.duration >= 2 * np.sqrt(0.5 * 0.0415 / 0.2))
(True, True)
"""

from __future__ import annotations

from casflex.planning.assembly import block_derivatives
from casflex.planning.correction import (
    BOUND_CORRECTIONS,
    BOUND_MARGIN,
    asked_bounds,
    hold_verified_bounds,
    tightened_bounds,
    verified_residuals,
)
from casflex.planning.derivatives import (
    OPTIMISED_FLAGS,
    QUICK_FLAGS,
    default_derivatives,
    point_compiler,
)
from casflex.planning.lifting import LIFTED_OPTIONS, BlockLayout, lifted_scales, lifted_start
from casflex.planning.limits import end_bounds, plan_limits, shaped_end, shaped_move_limits
from casflex.planning.ocp import (
    DERIVATIVES,
    DYNAMICS,
    LIMIT_STATUSES,
    OBJECTIVES,
    SOLVERS,
    TRANSCRIPTIONS,
    WARM_START_OPTIONS,
    plan_move,
    predicted_residual,
)
from casflex.planning.planned import PlannedMove, Propagator
from casflex.planning.progress import SolveProgress
from casflex.planning.restarts import (
    CONTINUATION_HALVINGS,
    FALLBACK_SHORTENING,
    LOOSE_BOUNDS,
    PATH_RISE,
    PATH_STATUSES,
    RESTART_VIOLATION_CEILING,
    ROBUST_PATHS,
    ROBUST_STEPS,
    continuation_ceiling,
    continuation_steps,
    plan_robustness,
    robust_path_for,
    solve_by_continuation,
    solve_from_plan,
    solve_with_fallback,
    solve_with_restarts,
)
from casflex.planning.scenarios import (
    ScaledFrequencyProvider,
    collocated_modal_guess,
    frequency_shifted_model,
    modal_guess,
    static_deflection,
    tip_jacobian,
)
from casflex.planning.stopping import (
    CEILING_STATUS,
    INTERRUPTED_STATUS,
    PROGRESS_STATUS,
    VIOLATION_CEILING_STATUS,
    DurationCeiling,
    PlanInterrupted,
    ProgressStop,
    ViolationCeiling,
    iteration_callback,
)
from casflex.planning.verify import (
    PlanComparison,
    limit_excess,
    node_step,
    plan_robot_move,
    shaped_reference,
    verify_plan,
)

__all__ = [
    # planning
    "plan_move",
    "plan_limits",
    "predicted_residual",
    "OBJECTIVES",
    "TRANSCRIPTIONS",
    "DYNAMICS",
    "WARM_START_OPTIONS",
    "LIMIT_STATUSES",
    "DERIVATIVES",
    "SOLVERS",
    # derivatives from blocks
    "block_derivatives",
    "default_derivatives",
    "point_compiler",
    "QUICK_FLAGS",
    "OPTIMISED_FLAGS",
    # stopping
    "ProgressStop",
    "PROGRESS_STATUS",
    "iteration_callback",
    "SolveProgress",
    "PlanInterrupted",
    "INTERRUPTED_STATUS",
    "DurationCeiling",
    "CEILING_STATUS",
    "ViolationCeiling",
    "VIOLATION_CEILING_STATUS",
    # the result
    "PlannedMove",
    "Propagator",
    # restarts and continuation
    "solve_with_restarts",
    "solve_with_fallback",
    "FALLBACK_SHORTENING",
    "RESTART_VIOLATION_CEILING",
    "solve_from_plan",
    "solve_by_continuation",
    "continuation_steps",
    "continuation_ceiling",
    "plan_robustness",
    "ROBUST_STEPS",
    "ROBUST_PATHS",
    "LOOSE_BOUNDS",
    "PATH_RISE",
    "PATH_STATUSES",
    "CONTINUATION_HALVINGS",
    "robust_path_for",
    # a nominal plan lifted into the robust problem
    "BlockLayout",
    "lifted_start",
    "lifted_scales",
    "LIFTED_OPTIONS",
    # limits
    "shaped_move_limits",
    "end_bounds",
    "shaped_end",
    # verification
    "verify_plan",
    "node_step",
    "plan_robot_move",
    "PlanComparison",
    # end bounds held by the verified residual
    "hold_verified_bounds",
    "asked_bounds",
    "tightened_bounds",
    "verified_residuals",
    "BOUND_CORRECTIONS",
    "BOUND_MARGIN",
    "limit_excess",
    "shaped_reference",
    # models with shifted frequencies
    "frequency_shifted_model",
    "ScaledFrequencyProvider",
    "static_deflection",
    "tip_jacobian",
    "modal_guess",
    "collocated_modal_guess",
]
