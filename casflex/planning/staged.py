"""Stage-ordered decision variables of the planner's OCP, for structure-exploiting solvers.

Fatrop (CasADi's ``nlpsol("fatrop")`` with ``structure_detection="auto"``) solves the
Newton systems of an interior point by a Riccati recursion over the stages of an optimal
control problem, at a cost linear in the number of intervals. It reads the stage structure
from the NLP itself, so the NLP must have it:

* the variables in stage order: per stage ``k`` the state ``x_k`` then the controls
  ``u_k``, the last stage a state only;
* the dynamics as gap constraints ``x_{k+1} = F_k(x_k, u_k)`` with the identity on
  ``x_{k+1}`` (no scaling of those rows nor of the state: Fatrop eliminates ``x_{k+1}``
  with that identity), before the other constraints.

The planner's collocation maps onto that as rockit does: the state of stage ``k`` is the
node state and the free final time (``T_{k+1} = T_k``, so that every stage sees its own
copy), the controls the interval's torque, collocation states and joint accelerations.
The scaling by magnitudes of :func:`casflex.planning.plan_move` (``opti.set_linear_scale``
there) is done here by hand: the NLP variables are the scaled ones and the physical
quantities linear expressions of them, so that the gap rows keep the identity.
:func:`state_scales` gives those magnitudes for both solvers.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from casflex._validate import fail

__all__ = ["stage_variables", "stage_order", "fatrop_options", "power_of_two", "state_scales",
           "kept_scales"]


def stage_variables(opti: ca.Opti, N: int, states: Sequence[np.ndarray],
                    controls: Sequence[tuple[np.ndarray, int]]) -> tuple[list, list, list]:
    """Declare the variables of ``N`` intervals in stage order; return the physical ones.

    Parameters
    ----------
    opti : casadi.Opti
        The problem, no variables declared yet.
    N : int
        Intervals (``N + 1`` stages).
    states : sequence of array
        Per state block the scale [its unit] of each of its rows (one column per stage).
    controls : sequence of (array, int)
        Per control block the scale of each of its rows and the block's columns per
        interval (the collocation points: ``degree``).

    Returns
    -------
    (list of casadi.MX, list of casadi.MX, list of casadi.MX)
        The state blocks ``(rows, N + 1)`` and the control blocks ``(rows, N columns)``,
        physical (scale times the NLP variable), and the NLP variables of every stage
        (for :func:`stage_order`).

    Examples
    --------
    >>> opti = ca.Opti()
    >>> (X,), (U,), stages = stage_variables(opti, 2, [np.ones(2)], [(np.full(1, 5.0), 1)])
    >>> X.shape, U.shape, [v.numel() for v in stages]
    ((2, 3), (1, 2), [3, 3, 2])
    """
    xs = [[] for _ in states]
    us = [[] for _ in controls]
    stages = []
    for k in range(N + 1):
        raw = []
        for block, scale in zip(xs, states, strict=True):
            raw.append(opti.variable(len(scale)))
            block.append(np.asarray(scale, dtype=float)[:, None] * raw[-1])
        if k < N:
            for block, (scale, cols) in zip(us, controls, strict=True):
                raw.append(opti.variable(len(scale), cols))
                block.append(np.asarray(scale, dtype=float)[:, None] * raw[-1])
        stages.append(ca.vertcat(*[ca.vec(v) for v in raw]))
    return [ca.horzcat(*b) for b in xs], [ca.horzcat(*b) for b in us], stages


def stage_order(opti: ca.Opti, stages: Sequence[ca.MX]) -> list[bool]:
    """Pose ``opti``'s constraints again, in stage order: per stage its gap constraint (the
    rows that reach into the next stage) then its other rows, the last stage's at the end.

    A row belongs to the first stage whose variables it reads; within that order the rows
    keep the order in which they were posed. The rows are posed again as one bounded
    constraint; which of them are equalities is returned, for Fatrop's option
    ``"equality"`` (it tells the gaps by them).

    Parameters
    ----------
    opti : casadi.Opti
        With the variables of :func:`stage_variables` and its constraints posed.
    stages : sequence of casadi.MX
        The NLP variables of every stage (:func:`stage_variables`).

    Returns
    -------
    list of bool
        Per row (in the new order) whether it is an equality.

    Raises
    ------
    casflex.errors.ModelError
        A row reads the variables of stages more than one apart, or a variable of a stage
        is in no constraint nor the objective (no stage structure).

    Examples
    --------
    >>> opti = ca.Opti()
    >>> (X,), (U,), stages = stage_variables(opti, 2, [np.ones(1)], [(np.ones(1), 1)])
    >>> opti.subject_to(X[:, 2] == 1)
    >>> opti.subject_to(X[:, 1:] == X[:, :2] + U)
    >>> opti.subject_to(X[:, 0] == 0)
    >>> stage_order(opti, stages)
    [True, True, True, True]
    >>> g = ca.Function("g", [opti.x], [opti.g])  # rows at (x0, u0, x1, u1, x2) = 0..4
    >>> g(np.arange(5.0)).full().ravel().tolist()  # gap 0, x0, gap 1, x2 (bound 1)
    [1.0, 0.0, -1.0, 4.0]
    """
    g = opti.g
    lbg = np.asarray(opti.value(opti.lbg, opti.initial()), dtype=float).ravel()
    ubg = np.asarray(opti.value(opti.ubg, opti.initial()), dtype=float).ravel()
    every = ca.vertcat(*stages)
    if opti.nx != every.numel():  # Opti leaves out the variables that nothing reads
        raise fail("variables", f"{every.numel() - opti.nx} of {every.numel()}",
                   "must all appear in a constraint or the objective (stage structure)")
    of = np.repeat(np.arange(len(stages)), [v.numel() for v in stages])
    stage = of[np.asarray(ca.jacobian_sparsity(opti.x, every).get_col())]
    sp = ca.jacobian_sparsity(g, opti.x)
    cols, rows = np.asarray(sp.get_col()), np.asarray(sp.row())
    first = np.full(g.shape[0], stage[-1])
    last = np.zeros(g.shape[0], dtype=int)
    np.minimum.at(first, rows, stage[cols])
    np.maximum.at(last, rows, stage[cols])
    if np.any(last - first > 1):
        bad = int(np.flatnonzero(last - first > 1)[0])
        raise fail("constraints", f"row {bad}", "must read the variables of one stage or "
                   "of two neighbouring ones (stage structure)")
    order = np.lexsort((np.arange(g.shape[0]), last == first, first))
    opti.subject_to()
    # one constraint (Opti's cost per constraint grows with the problem); which rows are
    # equalities is Fatrop's option "equality"
    opti.subject_to(opti.bounded(lbg[order], g[order.tolist()], ubg[order]))
    return (lbg == ubg)[order].tolist()


def state_scales(states: np.ndarray, n: int, m: int) -> np.ndarray:
    """Scale of every state row of the OCP from its magnitude in the initial guess.

    Joint rows are at least 0.1 [rad, rad/s]. A modal row the guess leaves at round-off
    (below 1e-6 of the largest modal row: a mode the move does not excite, e.g. move 3 of
    the design study holds joints 2 and 3 and leaves the second mode at 1e-18) takes the
    smallest scale of the modal rows the guess does excite; every other modal row keeps its
    own magnitude. Measured on the design study (benchmarks/README_planning.md, session
    17): with a floor of 1e-6 or 1e-4 of the largest modal row move 3 stopped at 5.96 s or
    2.81 s (shaped 2.87 s), with 1e-3 at 2.063 s after 405 iterations, with 1e-2 at 2.063 s
    after 109, and with this rule at 2.063 s after 86; a floor as high as 1e-2 also raised
    the small third-mode rows of move 1 and with them its warm re-solve from 59 to 151
    iterations, which this rule leaves as they were.

    Parameters
    ----------
    states : numpy.ndarray, shape (rows, samples)
        The guess's states, rows ``[q (n), δ (m), q̇ (n), δ̇ (m), ...]``: rows after
        ``2 (n + m)`` (the frequency-shifted scenarios' modal rows) count as modal.
    n, m : int
        Joints and modes.

    Returns
    -------
    numpy.ndarray, shape (rows,)
        Scales [the rows' units], each at least the row's largest magnitude.

    Examples
    --------
    >>> states = np.array([[0.0, 2.0], [1e-3, -2e-3], [0.5, 0.0], [0.0, 0.0]])
    >>> state_scales(states, 1, 1).tolist()
    [2.0, 0.002, 0.5, 0.002]
    """
    scale = np.max(np.abs(states), axis=1)
    rows = np.arange(states.shape[0])
    joint = (rows < n) | ((rows >= n + m) & (rows < 2 * n + m))
    scale = np.where(joint, np.maximum(scale, 0.1), scale)
    modal = ~joint
    excited = modal & (scale > 1e-6 * np.max(scale[modal], initial=0.0))
    if np.any(excited):
        scale[modal & ~excited] = np.min(scale[excited])
    else:  # a guess with no vibration at all: modal coordinates of order one
        scale[modal] = 1.0
    return scale


def kept_scales(solution: dict | None, rows: int, n: int,
                implicit: bool) -> tuple | None:
    """The scales of the NLP a plan's multipliers belong to, for a warm start with them.

    The dynamics rows are divided by the state scales, so a multiplier means something
    only in the scales it was found in: a warm start from a plan's iterate and multipliers
    solves in that plan's scales (``PlannedMove.solution["scales"]``), not in scales from
    the plan's own magnitudes.

    Parameters
    ----------
    solution : dict or None
        ``PlannedMove.solution``.
    rows, n : int
        State rows of the new NLP (scenarios included) and joints.
    implicit : bool
        Whether the new NLP has collocated accelerations (and so their scales).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray or None, float) or None
        The scales of the states, torques [N m], accelerations and T [s]; ``None`` when
        there are none or their sizes do not fit the new NLP.

    Examples
    --------
    >>> scales = {"x": np.ones(4), "tau": np.ones(1), "ddq": np.ones(1), "T": 2.0}
    >>> kept_scales({"scales": scales}, 4, 1, True)[3]
    2.0
    >>> kept_scales({"scales": scales}, 6, 1, True) is None
    True
    """
    scales = (solution or {}).get("scales")
    if scales is None or scales["x"].size != rows or scales["tau"].size != n or \
            (scales["ddq"] is None) == implicit:
        return None
    return scales["x"], scales["tau"], scales["ddq"], scales["T"]


def power_of_two(scale: np.ndarray) -> np.ndarray:
    """The nearest powers of two of positive scales.

    Fatrop checks at every iteration that a gap row's Jacobian on ``x_{k+1}`` is the
    identity, exactly; with the state ``s x̃`` and the row divided by ``s`` the entry is
    ``s (1 / s)``, which is 1 in floating point for every power of two (and not for
    ``s = 49``: 0.9999999999999999).

    Parameters
    ----------
    scale : numpy.ndarray
        Scales > 0 [the unit of what they scale].

    Returns
    -------
    numpy.ndarray

    Examples
    --------
    >>> power_of_two(np.array([0.1, 3.0, 49.0])).tolist()
    [0.125, 4.0, 64.0]
    """
    return 2.0 ** np.round(np.log2(np.asarray(scale, dtype=float)))


#: the planner's Ipopt options that Fatrop has under the same name and meaning
#: (CasADi 3.8's Fatrop has no acceptable_tol, warm_start_init_point, mu_strategy)
_SHARED = ("max_iter", "tol", "mu_init", "bound_push", "bound_frac", "print_level")


def fatrop_options(options: dict) -> dict:
    """Fatrop's options from the planner's Ipopt options: those Fatrop shares (same name
    and meaning: the iteration limit, the tolerance, the barrier's start, the print level
    (at 10 Fatrop prints its timing table)); the others (MUMPS, the adaptive barrier, the acceptable
    test, the warm-start pushes) have no Fatrop counterpart and are dropped.

    Parameters
    ----------
    options : dict
        Ipopt options.

    Returns
    -------
    dict

    Examples
    --------
    >>> fatrop_options({"tol": 1e-8, "mu_strategy": "adaptive", "print_level": 0})
    {'tol': 1e-08, 'print_level': 0}
    """
    return {k: v for k, v in options.items() if k in _SHARED}
