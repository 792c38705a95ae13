"""The planner's limits from the shaped version of a move (a fair comparison), and its
end condition per scenario.

:func:`shaped_move_limits` is the rule ``casflex plan`` and the design job's ``[planner]``
share: the peak torques and velocities of the shaped move with the joints on it
(:func:`casflex.planning.plan_limits`), except for the joints the move holds.
:func:`end_bounds` reads :func:`casflex.planning.plan_move`'s ``end``;
:func:`diagnose_failure` names the limits active where a solve failed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from casflex._validate import choice, fail, number

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move, ShapedMove

__all__ = ["shaped_move_limits", "plan_limits", "end_bounds", "shaped_end", "joint_bounds",
           "diagnose_failure"]


def shaped_end(shaped_check: dict) -> float | list[float]:
    """The end condition "no more than the shaped move": the shaped move's residual tip
    deflection [m] in every scenario (nominal, then each frequency error of
    ``shaped_check["errors"]``), as :func:`casflex.planning.plan_move`'s ``end``.

    Parameters
    ----------
    shaped_check : dict
        ``residual`` (the shaped move's, nominal model) [m] and ``errors``, a list of
        ``{"error", "residual"}`` (the shaped move's residual [m] at each frequency error).

    Returns
    -------
    float or list of float
        The nominal residual [m], or with errors one bound per scenario: nominal, then in
        the order of ``errors``.

    Examples
    --------
    >>> shaped_end({"residual": 0.01, "errors": []})
    0.01
    >>> shaped_end({"residual": 0.01, "errors": [{"error": -0.1, "residual": 0.02},
    ...                                          {"error": 0.1, "residual": 0.005}]})
    [0.01, 0.02, 0.005]
    """
    bounds = [float(shaped_check["residual"])]
    bounds += [float(e["residual"]) for e in shaped_check["errors"]]
    return bounds[0] if len(bounds) == 1 else bounds


def end_bounds(end: Any, scenarios: int) -> tuple[str | float, list[float] | None]:
    """:func:`casflex.planning.plan_move`'s ``end`` as ``(end, bounds)``.

    Parameters
    ----------
    end : "rest" or "free" or float or sequence of float
        The end condition: the modes at rest, none, one residual tip deflection bound
        [m] for every scenario, or one bound per scenario [m] in the order of
        ``stats["scenarios"]`` (nominal, ``-r``, ``+r``).
    scenarios : int
        Scenarios of the plan (1, or 3 with ``robust > 0``).

    Returns
    -------
    (str or float, list of float or None)
        ``"rest"`` / ``"free"`` and ``None``, or the nominal bound and the bound of every
        scenario [m].

    Raises
    ------
    casflex.errors.ModelError
        ``end`` is none of these, or a bound is not finite and > 0, or a sequence's
        length is not ``scenarios``.

    Examples
    --------
    >>> end_bounds(0.01, 3)
    (0.01, [0.01, 0.01, 0.01])
    >>> end_bounds([0.01, 0.02, 0.005], 3)
    (0.01, [0.01, 0.02, 0.005])
    >>> end_bounds([0.01, 0.02], 3)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: end = [0.01, 0.02]: must be one residual bound [m] per ...
    """
    if isinstance(end, str):
        return choice(end, "end", ("rest", "free")), None
    if np.ndim(end) == 0:
        bound = number(end, "end", low=0.0, low_open=True)
        return bound, [bound] * scenarios
    try:
        values = list(end)
    except TypeError:
        raise fail("end", end, "must be 'rest', 'free', a residual bound [m] or one bound "
                   "per scenario") from None
    if len(values) != scenarios:
        raise fail("end", end, f"must be one residual bound [m] per scenario ({scenarios}"
                   + (": nominal, -r, +r" if scenarios == 3 else ": the nominal model")
                   + f"), got {len(values)}")
    bounds = [number(v, f"end[{k}]", low=0.0, low_open=True) for k, v in enumerate(values)]
    return bounds[0], bounds


def shaped_move_limits(model: FlexibleModel, move: Move, shaped: ShapedMove, *,
                       dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Torque and velocity limits of a plan of ``move``: those of its shaped version.

    A joint the move drives gets the peak ``|τ|`` and ``|q̇|`` of the shaped move with the
    joints on it (at least 1e-6 of the largest, so that Ipopt has an interior). A joint the
    move holds (start = goal) is held by its servo: its torque is the reaction to the
    others' motion, which a faster move raises, so it is not limited (``inf``); its
    velocity is limited to 1e-3 of the moving joints' largest limit.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    move : casflex.moves.Move
        The move (its ``q0`` and ``qf`` say which joints it holds).
    shaped : casflex.moves.ShapedMove
        Its shaped version.
    dt : float
        Simulation step of the shaped move [s].

    Returns
    -------
    torque_limit : numpy.ndarray, shape (n,)
        [N m] (``inf`` for a held joint).
    velocity_limit : numpy.ndarray, shape (n,)
        [rad/s].

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move, ShapedMove
    >>> from casflex.robot import load
    >>> from casflex.shaping import zv
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> move = Move([0.0], [0.5], 1.0)
    >>> tau, v = shaped_move_limits(model, move, ShapedMove(move, zv(25.0)))
    >>> bool(tau[0] > 0.0 and v[0] > 0.5)
    True
    """
    tau_lim, v_lim = plan_limits(model, shaped, dt=dt)
    held = np.asarray(move.q0, dtype=float) == np.asarray(move.qf, dtype=float)
    moving_v = float(v_lim[~held].max()) if np.any(~held) else float(v_lim.max())
    tau_lim = np.where(held, np.inf,
                       np.maximum(tau_lim, 1e-6 * max(float(tau_lim.max()), 1e-12)))
    v_lim = np.where(held, 1e-3 * max(moving_v, 1e-9),
                     np.maximum(v_lim, 1e-6 * max(float(v_lim.max()), 1e-12)))
    return tau_lim, v_lim


def plan_limits(model: FlexibleModel, reference: Any, dt: float = 1e-3
                ) -> tuple[np.ndarray, np.ndarray]:
    """Peak joint torques and velocities of a reference with the joints on it.

    The comparison of a planned and a shaped move is fair when the planner gets the
    shaped move's peaks as its limits (:func:`casflex.simulate.simulate_prescribed`
    gives the torques that produce the shaped motion).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    reference : casflex.moves.Move or ShapedMove or PlannedMove
    dt : float
        Simulation step [s].

    Returns
    -------
    torque_peak : numpy.ndarray, shape (n,)
        [N m]
    velocity_peak : numpy.ndarray, shape (n,)
        [rad/s]

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> tau, v = plan_limits(model, Move([0.0], [1.0], 2.0, settle=0.0))
    >>> tau.shape, round(float(v[0]), 6)
    ((1,), 1.0)
    """
    from casflex.simulate import simulate_prescribed

    run = simulate_prescribed(model, reference, dt=dt, t_end=float(reference.duration))
    return run.torque_peak, np.max(np.abs(run.dq), axis=0)


def joint_bounds(model: FlexibleModel, position_limits: Any, q0: np.ndarray,
                 qf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper joint bounds [rad] (``±inf`` where a joint is free): the given ones,
    or the robot's joint limits; the start and the goal must lie within them.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    position_limits : (array_like, array_like) or None
        Lower and upper bounds [rad], one value or one per joint; ``None``: the robot's
        joint limits.
    q0, qf : numpy.ndarray
        Start and goal [rad].

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Lower and upper bounds [rad].

    Raises
    ------
    casflex.errors.ModelError
        Malformed bounds, or the start or the goal outside them.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> joint_bounds(model, (-1.0, 2.0), np.zeros(1), np.ones(1))
    (array([-1.]), array([2.]))
    """
    n = model.n
    if position_limits is None:
        source = f"the joint limits of robot '{model.robot.name}'"
        limits = model.robot.joint_limits or (None,) * n
        lo = np.array([-np.inf if lim is None else lim[0] for lim in limits], dtype=float)
        hi = np.array([np.inf if lim is None else lim[1] for lim in limits], dtype=float)
    else:
        source = "position_limits"
        if len(position_limits) != 2:
            raise fail("position_limits", position_limits, "must be (lower, upper) [rad]")
        bounds = []
        for k, (side, inf) in enumerate((("lower", -np.inf), ("upper", np.inf))):
            field = f"position_limits[{k}]"
            value = np.broadcast_to(np.asarray(position_limits[k], dtype=float), (n,)) \
                if np.ndim(position_limits[k]) == 0 else np.asarray(position_limits[k],
                                                                    dtype=float).ravel()
            if value.size != n or np.any(np.isnan(value)) or np.any(value == -inf):
                raise fail(field, position_limits[k], f"must be {n} {side} bounds [rad] "
                           f"(or {'+' if inf > 0 else '-'}inf for none)")
            bounds.append(value.copy())
        lo, hi = bounds
        if np.any(lo >= hi):
            raise fail("position_limits", [lo.tolist(), hi.tolist()],
                       "every lower bound must be < its upper bound [rad]")
    for label, q in (("start", q0), ("goal", qf)):
        outside = np.flatnonzero((q < lo) | (q > hi))
        if outside.size:
            j = int(outside[0])
            raise fail(label, q.tolist(), f"joint {j + 1} ({q[j]:.6g} rad) lies outside "
                       f"{source}: [{lo[j]:.6g}, {hi[j]:.6g}] rad")
    return lo, hi


def diagnose_failure(status: str, T: float, max_duration: float, U: np.ndarray,
                     X: np.ndarray, tau_max: np.ndarray, v_max: np.ndarray, n: int, m: int,
                     N: int, duration: float | None, solver: str = "Ipopt") -> str:
    """One line on why the solver failed: its status and the limits active at its last
    iterate (a torque limit on at least half the intervals, a velocity limit at 30 % of
    the nodes, the duration at its upper bound).

    Parameters
    ----------
    status : str
        The solver's return status.
    T : float
        The last iterate's duration [s].
    max_duration : float
        Its upper bound [s].
    U : ndarray, shape (n, N)
        The last iterate's torques [N m].
    X : ndarray, shape (2 (n + m), N + 1)
        Its states (joints, modes, their rates) [rad, 1, rad/s, 1/s].
    tau_max, v_max : ndarray, shape (n,)
        Torque [N m] and velocity [rad/s] limits (``inf``: none).
    n, m, N : int
        Joints, modes, intervals.
    duration : float or None
        The fixed duration of an energy plan [s] (None: free).
    solver : str
        Named in the message.

    Returns
    -------
    str

    Examples
    --------
    >>> U = np.full((1, 4), 0.1)
    >>> X = np.zeros((2, 5))
    >>> diagnose_failure("Infeasible_Problem_Detected", 2.0, 40.0, U, X, np.array([0.1]),
    ...                  np.array([np.inf]), 1, 0, 4, None)  # doctest: +NORMALIZE_WHITESPACE
    'plan_move: Ipopt found no plan (Infeasible_Problem_Detected); active at the last
    iterate: the torque limit of joint 1 (0.1 N m) on 100 % of the intervals - the limits
    are too low to reach the goal'
    """
    active = []
    for j in range(n):
        if np.isfinite(tau_max[j]):
            share = float(np.mean(np.abs(U[j]) >= tau_max[j] * (1.0 - 1e-3)))
            if share >= 0.5:
                active.append(f"the torque limit of joint {j + 1} ({tau_max[j]:.6g} N m) "
                              f"on {100 * share:.0f} % of the intervals")
        if np.isfinite(v_max[j]):
            share = float(np.mean(np.abs(X[n + m + j]) >= v_max[j] * (1.0 - 1e-3)))
            if share >= 0.3:
                active.append(f"the velocity limit of joint {j + 1} ({v_max[j]:.6g} rad/s) "
                              f"at {100 * share:.0f} % of the nodes")
    if duration is None and T >= max_duration * (1.0 - 1e-3):
        active.append(f"the duration at its upper bound max_duration = {max_duration:.6g} s")
    where = "; active at the last iterate: " + ", ".join(active) if active else \
        " (no limit is active at the last iterate)"
    why = (" - the limits are too low to reach the goal"
           + (f" in {duration:.6g} s" if duration is not None else "")) if active else ""
    return f"plan_move: {solver} found no plan ({status}){where}{why}"
