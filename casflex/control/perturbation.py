"""Singular-perturbation design of the fast feedback (dissertation eq. 244–256).

The arm is split into a slow (rigid) and a fast (boundary-layer) subsystem; the fast one
gets an LQR gain, at one configuration (:func:`fast_gain`) or tabulated over the
configurations it depends on (:func:`gain_schedule`, cached on disk by
:func:`cached_gain_schedule`). Notation: ``n`` joints, ``m`` modes, ``M = [[M_qq, M_qδ],
[M_qδᵀ, M_δδ]]``, ``K = diag(ω²)``.

How the flattened equations are read
------------------------------------
Eq. 244–251: ``ε² = 1/k`` with ``k`` the lowest stiffness entry of ``K`` (= ω_min²), so
``ε = 1/ω_min`` [s] with ω_min the lowest first natural frequency over the model's table
("for any trajectory", 6.35 rad/s in the dissertation), ``K̃ = ε² K``, ``ξ = δ/ε²``, fast
time ``t_f = t/ε``. The quasi-steady part ``ξ̄`` (eq. 246) is taken as zero ("it is
assumed that ξ = ξ̄ = 0"), so the boundary-layer state is ``z = [η; dη/dt_f] = [δ/ε²;
δ̇/ε]`` and ``A_f = [[0, I], [−H_δδ K̃, 0]]``, ``B_f = [0; H_δq]`` with ``H = M(q, 0)⁻¹``.
The LQR (eq. 252–256) is solved for ``(A_f, B_f, Q, R)`` in fast time and
``τ_f = −K_f z``.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> robot = load("problems/arm2link.toml")
>>> q = [0.0, 0.0, -np.pi / 2]
>>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None)
>>> K, S, E = fast_gain(model, q, epsilon=0.15)
>>> bool(np.all(E.real < 0))
True
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import number, square_matrix, vector
from casflex.errors import ModelError, SolverError

if TYPE_CHECKING:
    from casflex.modal.tables import ModalTable
    from casflex.model import FlexibleModel
    from casflex.robot import Robot

__all__ = [
    "perturbation_parameter",
    "boundary_layer",
    "lqr",
    "fast_gain",
    "GainSchedule",
    "schedule_axes",
    "dependent_joints",
    "gain_schedule",
    "cached_gain_schedule",
]


def perturbation_parameter(model: FlexibleModel, table: ModalTable | None = None,
                           q: ArrayLike | None = None) -> float:
    """``ε = 1/ω_min`` [s], the singular-perturbation parameter (eq. 244).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    table : casflex.modal.tables.ModalTable, optional
        Take ω_min over every configuration of the table (default: the model's own
        table when its provider has one).
    q : array_like, optional
        ``(N, n)`` configurations [rad] to take ω_min over instead (e.g. a trajectory).

    Returns
    -------
    float

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.5], 2), gravity=None)
    >>> round(1.0 / perturbation_parameter(model, q=[[0, 0, 0.5]]), 2)
    10.42
    """
    if q is not None:
        Q = np.atleast_2d(np.asarray(q, dtype=float))
        if Q.shape[1] != model.n:
            raise ModelError(f"q: expected {model.n} joint values per row; got {Q.shape}")
        fK = model.functions()["stiffness"]
        w2 = np.array([np.diag(fK(qi).full()) for qi in Q])
        wmin = float(np.sqrt(np.min(w2)))
    else:
        if table is None:
            table = getattr(model.provider, "table", None)
        if table is None:
            raise ModelError("perturbation_parameter needs the model's table or "
                             "configurations q: the model's provider has no table")
        wmin = float(np.min(np.asarray(table.omega, dtype=float)[..., :model.m]))
    if not wmin > 0:
        raise ModelError(f"the lowest natural frequency is {wmin} rad/s; it must be > 0")
    return 1.0 / wmin


def boundary_layer(model: FlexibleModel, epsilon: float) -> ca.Function:
    """Boundary-layer (fast) subsystem of eq. 251 in the fast time ``t/ε``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    epsilon : float
        Perturbation parameter [s] (:func:`perturbation_parameter`).

    Returns
    -------
    casadi.Function
        ``boundary_layer (q) -> (A, B)``: ``A = [[0, I], [−H_δδ ε² K, 0]]`` (2m × 2m),
        ``B = [0; H_δq]`` (2m × n) with ``H = M(q, 0)⁻¹``; state ``[δ/ε²; δ̇/ε]``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> A, B = boundary_layer(model, 0.1)([0, 0, 0])
    >>> A.shape, B.shape
    ((4, 4), (4, 3))
    """
    n, m = model.n, model.m
    eps = number(float(epsilon), "epsilon", low=0.0, low_open=True)  # [s]
    M0 = ca.substitute(model.M, model.delta, ca.SX.zeros(m))
    K = ca.substitute(model.K, model.delta, ca.SX.zeros(m))
    H = ca.solve(M0, ca.SX.eye(n + m))
    Hdq, Hdd = H[n:, :n], H[n:, n:]
    A = ca.blockcat([[ca.SX.zeros(m, m), ca.SX.eye(m)],
                     [-Hdd @ (eps**2 * K), ca.SX.zeros(m, m)]])
    B = ca.vertcat(ca.SX.zeros(m, n), Hdq)
    return ca.Function("boundary_layer", [model.q], [A, B], ["q"], ["A", "B"])


def lqr(A: ArrayLike, B: ArrayLike, Q: ArrayLike,
        R: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous-time LQR of ``(A, B)`` with weights ``Q``, ``R`` (python-control).

    Parameters
    ----------
    A, B : array_like
        System and input matrices.
    Q, R : array_like
        State and input weights (matrices).

    Returns
    -------
    K : numpy.ndarray
        Gain of ``u = −K x``.
    S : numpy.ndarray
        Solution of the Riccati equation.
    E : numpy.ndarray
        Closed-loop eigenvalues.

    Raises
    ------
    casflex.errors.SolverError
        The LQR failed (e.g. the pair is not stabilisable).

    Examples
    --------
    >>> K, S, E = lqr([[0.0]], [[1.0]], [[1.0]], [[1.0]])
    >>> K.round(9).tolist(), E.real.round(9).tolist()
    ([[1.0]], [-1.0])
    """
    import control

    try:
        K, S, E = control.lqr(A, B, Q, R)
    except Exception as exc:  # python-control raises several types (ControlArgument, ...)
        raise SolverError(f"LQR of the boundary-layer system failed: {exc}") from exc
    return np.asarray(K, dtype=float), np.asarray(S, dtype=float), np.asarray(E)


def fast_gain(model: FlexibleModel, q: ArrayLike, Q: ArrayLike = 1.0, R: ArrayLike = 10.0,
              epsilon: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LQR gain of the boundary-layer system at one configuration (eq. 252–256).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like
        Configuration [rad] (the dissertation uses the end of the trajectory).
    Q, R : float or array_like
        State (2m) and input (n) weights; the case study uses ``Q = I``, ``R = 10 I``.
    epsilon : float, optional
        Default :func:`perturbation_parameter`.

    Returns
    -------
    K : numpy.ndarray
        n × 2m gain, ``τ_f = −K [δ/ε²; δ̇/ε]``.
    S : numpy.ndarray
        Solution of the Riccati equation (eq. 256).
    E : numpy.ndarray
        Closed-loop eigenvalues in fast time.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, -np.pi / 2]
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None)
    >>> K, S, E = fast_gain(model, q, epsilon=0.15)
    >>> K.shape, bool(np.all(E.real < 0))
    ((3, 4), True)
    """
    q = vector(q, model.n, "q", unit="rad")
    if epsilon is None:
        epsilon = perturbation_parameter(model)
    A, B = (x.full() for x in boundary_layer(model, epsilon)(q))
    return lqr(A, B, square_matrix(Q, 2 * model.m, "Q"), square_matrix(R, model.n, "R"))


@dataclass
class GainSchedule:
    """LQR gains of the boundary-layer system tabulated over joints.

    Attributes
    ----------
    joints : tuple of int
        0-based joints of the grid axes.
    grid : tuple of numpy.ndarray
        Axes [rad]: full turns (wrapped periodically by ``function``) or intervals
        (joint limits, a move's box; clamped at their ends by ``function``).
    gains : numpy.ndarray
        ``grid_shape + (n, 2m)`` gains.
    epsilon : float
        Perturbation parameter used [s].
    function : casadi.Function
        ``gain (q) -> K`` (n × 2m), cubic B-spline (or linear) interpolation of
        ``gains``; a full-turn axis is wrapped periodically, and a joint beyond the ends
        of a shorter axis (joint limits, the box of a move) gets the gain at the nearest
        end, never an extrapolation.
    filled : int
        Grid points where the pair was not stabilisable (an inaccessible mode) whose gain
        was replaced by the mean of the neighbouring points.
    info : dict
        Free-form notes of the builder (e.g. the LQR weights).

    Examples
    --------
    Usually from :func:`gain_schedule`; here two gains tabulated over joint 0 by hand:

    >>> ax = np.linspace(-np.pi, np.pi, 4, endpoint=False)
    >>> G = np.zeros((4, 1, 2))
    >>> G[:, 0, 0] = [1.0, 2.0, 3.0, 4.0]
    >>> s = GainSchedule.from_gains((0,), [ax], G, 0.15, n_joints=1, method="linear")
    >>> s.joints, s.gains.shape, s.epsilon
    ((0,), (4, 1, 2), 0.15)
    >>> s.function([ax[2]]).full().round(9).tolist()
    [[3.0, 0.0]]
    """

    joints: tuple
    grid: tuple
    gains: np.ndarray
    epsilon: float
    function: ca.Function
    filled: int = 0
    info: dict = field(default_factory=dict)

    @classmethod
    def from_gains(cls, joints: Sequence[int], grid: Sequence[ArrayLike], gains: ArrayLike,
                   epsilon: float, n_joints: int, method: str = "bspline", filled: int = 0,
                   info: dict | None = None) -> GainSchedule:
        """Build a schedule (its interpolating ``function``) from tabulated gains.

        Parameters
        ----------
        joints : sequence of int
            0-based joints of the grid axes.
        grid : sequence of array_like
            One axis [rad] per joint: a full turn (wrapped periodically) or an interval
            (inside joint limits; the joint is clamped to its ends).
        gains : array_like
            ``grid_shape + (n, 2m)`` gains.
        epsilon : float
            Perturbation parameter the gains were computed with [s].
        n_joints : int
            Number of joints of the model (length of the ``q`` input).
        method : {"bspline", "linear"}
        filled : int
        info : dict, optional

        Returns
        -------
        GainSchedule

        Examples
        --------
        >>> ax = np.linspace(-np.pi, np.pi, 8, endpoint=False)
        >>> G = np.ones((8, 1, 2)) * np.arange(8.0)[:, None, None]
        >>> s = GainSchedule.from_gains((0,), [ax], G, 0.1, n_joints=1)
        >>> s.function([ax[3]]).full().round(9).tolist()
        [[3.0, 3.0]]
        """
        from casflex.modal.fits import periodic_axis_kind
        from casflex.modal.tables import ModalTable

        joints = tuple(int(j) for j in joints)
        grid = tuple(np.asarray(a, dtype=float).ravel() for a in grid)
        G = np.asarray(gains, dtype=float)
        shape = tuple(a.size for a in grid)
        n, m2 = G.shape[-2], G.shape[-1]
        if G.shape != shape + (n, m2) or len(joints) != len(grid):
            raise ModelError(f"gains of shape {G.shape} do not fit the grid {shape} of "
                             f"joints {joints}")
        tab = ModalTable(grid=grid, shape_joints=joints, values={"gain": G},
                         omega=np.zeros(shape + (1,)), periodic=(True,) * len(joints))
        fg = tab.function("gain", method=method)
        qs = ca.SX.sym("q", int(n_joints))
        args = []
        for j, a in zip(joints, grid, strict=True):
            if periodic_axis_kind(a) is not None:
                args.append(qs[j])
            else:  # the nearest end's gain outside the interval: no extrapolation
                args.append(ca.fmin(ca.fmax(qs[j], float(a[0])), float(a[-1])))
        Kq = fg(ca.vertcat(*args))
        fun = ca.Function("fast_gain", [qs], [ca.reshape(Kq, n, m2)], ["q"], ["K"])
        return cls(joints=joints, grid=grid, gains=G, epsilon=float(epsilon), function=fun,
                   filled=int(filled), info=dict(info or {}))


def schedule_axes(robot: Robot, joints: Sequence[int], points_per_turn: int, *,
                  limits: bool = True,
                  box: tuple[ArrayLike, ArrayLike] | None = None) -> tuple[np.ndarray, ...]:
    """Axes of a gain schedule: a uniform step of ``2π / points_per_turn`` over each joint's
    range — its joint limits, or the box a move spans, or a full turn.

    The cost of a schedule is one LQR per grid point, the product of the axes' sizes, so
    over three joints a full-turn grid of 30 points per axis is 27 000 LQRs (and a spline
    through them); the joint limits and, for a design job, the box of its move shrink that
    product without coarsening the step.

    Parameters
    ----------
    robot : casflex.robot.Robot
        Its ``joint_limits`` bound the axes.
    joints : sequence of int
        0-based joints of the schedule.
    points_per_turn : int
        Points a full turn would have; the step is ``2π / points_per_turn`` [rad].
    limits : bool
        Stay inside the joint limits (a joint without limits spans a full turn).
    box : (array_like, array_like), optional
        Lowest and highest value of every joint along a move [rad] (``n_joints`` each):
        each axis spans this interval widened by one step on either side (so that the
        loop's small excursions stay inside), clipped to the joint limits; a range of a
        full turn or more gives the full-turn axis.

    Returns
    -------
    tuple of numpy.ndarray
        One axis [rad] per joint: the full turn ``−π + k·2π/points_per_turn`` (wrapped
        periodically by :class:`GainSchedule`), or ``lo .. hi`` with both ends included
        and a step no larger than ``2π / points_per_turn``.

    Examples
    --------
    >>> import dataclasses
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> limited = dataclasses.replace(robot, joint_limits=(None, None, (-1.0, 1.0)))
    >>> a1, a2 = schedule_axes(limited, (1, 2), 12)
    >>> a1.size, a2.size, float(a2[0]), float(a2[-1])
    (12, 5, -1.0, 1.0)
    >>> b1, b2 = schedule_axes(limited, (1, 2), 12, box=([0, 0.0, 0.2], [0, 0.5, 0.4]))
    >>> np.round(b1, 4).tolist(), np.round(b2, 4).tolist()
    ([-0.5236, -0.0079, 0.5079, 1.0236], [-0.3236, 0.0921, 0.5079, 0.9236])
    """
    points = int(number(points_per_turn, "points_per_turn", low=4, integer=True))
    step = 2 * np.pi / points
    full = -np.pi + step * np.arange(points)
    joint_limits = tuple(robot.joint_limits) or (None,) * robot.n_joints
    axes = []
    for j in (int(k) for k in joints):
        lo, hi = -np.inf, np.inf
        if limits and joint_limits[j] is not None:
            lo, hi = (float(v) for v in joint_limits[j])
        if box is not None:
            low = vector(box[0], robot.n_joints, "box[0]", unit="rad")[j] - step
            high = vector(box[1], robot.n_joints, "box[1]", unit="rad")[j] + step
            if high - low < 2 * np.pi:
                lo, hi = max(lo, low), min(hi, high)
        if not np.isfinite(lo) or hi - lo >= 2 * np.pi:
            axes.append(full.copy())
            continue
        count = max(int(np.ceil((hi - lo) / step - 1e-9)) + 1, 2)
        axes.append(np.linspace(lo, hi, count))
    return tuple(axes)


def dependent_joints(fun: Callable[[np.ndarray], Sequence[ArrayLike]], n: int,
                     rng: np.random.Generator, samples: int = 3,
                     rtol: float = 1e-9) -> tuple[int, ...]:
    """Joints a numeric function of ``q`` depends on, by random probing.

    Joint ``j`` counts when moving it by 0.7 rad from one of ``samples`` random
    configurations changes some output by more than ``rtol`` times the largest one.

    Parameters
    ----------
    fun : callable
        ``fun(q) -> sequence of arrays`` for ``q`` of ``n`` joint values [rad].
    n : int
        Number of joints.
    rng : numpy.random.Generator
        Source of the probe configurations (seed it for a reproducible answer).
    samples : int
        Probes per joint.
    rtol : float

    Returns
    -------
    tuple of int
        0-based joints, ascending.

    Examples
    --------
    >>> dependent_joints(lambda q: [np.cos(q[1]) * q[2]], 3, np.random.default_rng(0))
    (1, 2)
    """
    deps = []
    for j in range(n):
        for _ in range(samples):
            q = rng.uniform(-np.pi, np.pi, n)
            q2 = q.copy()
            q2[j] += 0.7
            a = np.concatenate([np.ravel(v) for v in fun(q)])
            b = np.concatenate([np.ravel(v) for v in fun(q2)])
            if np.max(np.abs(a - b)) > rtol * max(np.max(np.abs(a)), 1e-300):
                deps.append(j)
                break
    return tuple(deps)


def _boundary_layer_joints(model, bl):
    """The joints the boundary-layer function ``bl`` depends on (fixed random probes)."""
    return dependent_joints(lambda qq: [x.full() for x in bl(qq)], model.n,
                            np.random.default_rng(0))


def gain_schedule(model: FlexibleModel, Q: ArrayLike = 1.0, R: ArrayLike = 10.0,
                  epsilon: float | None = None, joints: Sequence[int] | None = None,
                  grid: Sequence[ArrayLike] | None = None, table: ModalTable | None = None,
                  q: ArrayLike | None = None, method: str = "bspline") -> GainSchedule:
    """Tabulate the fast LQR gain over the configuration grid and interpolate it.

    The grid is the model table's grid over the shape joints; joints that the
    boundary-layer system depends on but that are not shape joints (e.g. the shoulder of
    the Table 8 arm, through ``M_qδ``) get a uniform full-turn axis with as many points
    as the first shape-joint axis. At points where the pair is not stabilisable (a mode
    with zero accessibility; the LQR fails or leaves an eigenvalue on the imaginary axis)
    the gain is replaced by the mean of its valid neighbours.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    Q, R : float or array_like
        LQR weights.
    epsilon : float, optional
        Default :func:`perturbation_parameter`.
    joints : sequence of int, optional
        0-based joints to tabulate over (default: those the boundary layer depends on).
    grid : sequence of array_like, optional
        One full-turn axis per joint [rad] (default as described above).
    table : casflex.modal.tables.ModalTable, optional
        Default the model provider's table.
    q : array_like, optional
        Values of the joints not tabulated [rad] (default zeros).
    method : {"bspline", "linear"}

    Returns
    -------
    GainSchedule

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> ax = np.linspace(-np.pi, np.pi, 8, endpoint=False)
    >>> s = gain_schedule(model, epsilon=0.15, joints=(1,), grid=[ax])
    >>> s.gains.shape, s.function([0, ax[3], 0]).shape
    ((8, 3, 2), (3, 2))
    >>> bool(np.allclose(s.function([0, ax[3], 0]).full(), s.gains[3]))
    True
    """
    n, m = model.n, model.m
    if epsilon is None:
        epsilon = perturbation_parameter(model, table=table)
    bl = boundary_layer(model, epsilon)
    if table is None:
        table = getattr(model.provider, "table", None)
    if joints is None:
        joints = _boundary_layer_joints(model, bl)
    joints = tuple(int(j) for j in joints)
    if not joints:
        raise ModelError("gain_schedule: the boundary-layer system depends on no joint; "
                         "use fast_gain at one configuration")
    if grid is None:
        shape_axes = {}
        if table is not None:
            for k, ax in zip(table.shape_joints, table.grid, strict=True):
                shape_axes[int(k)] = np.asarray(ax, dtype=float)
        count = len(next(iter(shape_axes.values()))) if shape_axes else 60
        default = -np.pi + 2 * np.pi * np.arange(count) / count
        grid = [shape_axes.get(j, default) for j in joints]
    grid = tuple(np.asarray(a, dtype=float).ravel() for a in grid)
    if len(grid) != len(joints):
        raise ModelError(f"gain_schedule: {len(grid)} grid axes for joints {joints}")
    base = np.zeros(n) if q is None else vector(q, n, "q", unit="rad")
    shape = tuple(a.size for a in grid)
    pts = np.array(np.meshgrid(*grid, indexing="ij")).reshape(len(joints), -1).T
    Qall = np.tile(base, (pts.shape[0], 1))
    Qall[:, list(joints)] = pts
    N = Qall.shape[0]
    Aall, Ball = bl.map(N)(Qall.T)
    Aall = np.asarray(Aall).reshape(2 * m, N, 2 * m)
    Ball = np.asarray(Ball).reshape(2 * m, N, n)
    Qw, Rw = square_matrix(Q, 2 * m, "Q"), square_matrix(R, n, "R")
    gains = np.zeros((N, n, 2 * m))
    valid = np.zeros(N, dtype=bool)
    worst = -np.inf
    for k in range(N):
        A, B = Aall[:, k, :], Ball[:, k, :]
        try:
            K, _, E = lqr(A, B, Qw, Rw)
        except SolverError:
            continue
        if np.all(np.isfinite(K)) and np.max(E.real) < -1e-9:
            gains[k], valid[k] = K, True
            worst = max(worst, float(np.max(E.real)))
    if not np.any(valid):
        raise SolverError("gain_schedule: the boundary-layer system is not stabilisable "
                          "anywhere on the grid")
    G = gains.reshape(shape + (n, 2 * m))
    V = valid.reshape(shape)
    filled = int(np.sum(~V))
    for _ in range(max(shape)):  # fill holes from valid neighbours, repeatedly
        if V.all():
            break
        acc = np.zeros_like(G)
        cnt = np.zeros(shape)
        for ax in range(len(shape)):
            for s in (1, -1):
                acc += np.roll(G * V[..., None, None], s, axis=ax)
                cnt += np.roll(V, s, axis=ax)
        new = (~V) & (cnt > 0)
        G[new] = acc[new] / cnt[new][:, None, None]
        V = V | new
    return GainSchedule.from_gains(joints, grid, G, epsilon, n, method=method, filled=filled,
                                   info={"worst_fast_eigenvalue": worst, "points": N})


def cached_gain_schedule(model: FlexibleModel, Q: ArrayLike, R: ArrayLike, epsilon: float,
                         table: ModalTable, axis: ArrayLike,
                         cache_dir: str | os.PathLike | bool | None = None, *,
                         limits: bool = False,
                         box: tuple[ArrayLike, ArrayLike] | None = None,
                         method: str = "bspline") -> GainSchedule:
    """:func:`gain_schedule` on the full-turn ``axis`` of every joint the boundary layer
    depends on (or on its step over the joint limits or a move's box), cached on disk.

    A coarse ``axis`` keeps the schedule cheap (one LQR per grid point) where the model
    table's own grid would be needlessly fine. The file lives in the cache directory,
    ``gains-<key>.npz``, under a key made of everything the gains depend on (the robot,
    the table, the modes, the weights, ε, the axis, the joints and the source of the
    functions that compute them); a stale or corrupt file is recomputed and overwritten.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    Q, R : float or array_like
        LQR weights (JSON-able: a number or nested lists).
    epsilon : float
        Perturbation parameter [s] (:func:`perturbation_parameter`).
    table : casflex.modal.tables.ModalTable
        The model's table (its ``info["key"]`` enters the cache key; a table without one,
        such as a :class:`casflex.modal.fits.ChebyshevFit`, is never cached, since two
        different tables would share a key).
    axis : array_like
        Full-turn axis [rad] used for every scheduled joint (with ``limits`` or ``box``:
        only its number of points counts, see :func:`schedule_axes`).
    cache_dir : path, None or False
        Cache directory (``None`` the default of :func:`casflex._cache.default_cache_dir`,
        ``False`` no cache).
    limits : bool
        Keep every axis inside its joint's limits (:func:`schedule_axes`).
    box : (array_like, array_like), optional
        Lowest and highest joint values of a move [rad]: the axes span that box, one step
        wider on each side (:func:`schedule_axes`).
    method : {"bspline", "linear"}
        Interpolation of the gains between the grid points.

    Returns
    -------
    GainSchedule
        ``info["from_cache"]`` is true when the gains were loaded from the cache.

    Examples
    --------
    >>> import tempfile
    >>> from casflex.model import build_model
    >>> from casflex.robot import load
    >>> model, table = build_model(load("problems/arm2link.toml"), 1, step=np.pi / 4,
    ...                            cache_dir=False, processes=1)
    >>> axis = -np.pi + 2 * np.pi * np.arange(8) / 8
    >>> cache = tempfile.mkdtemp()
    >>> s = cached_gain_schedule(model, 1.0, 10.0, 0.15, table, axis, cache_dir=cache)
    >>> s.joints, s.info.get("from_cache", False)
    ((1, 2), False)
    >>> cached_gain_schedule(model, 1.0, 10.0, 0.15, table, axis, cache_dir=cache).info
    {'from_cache': True}
    """
    from casflex import __version__
    from casflex._cache import cache_root, digest, load_verified, save_verified, source_digest

    axis = np.asarray(axis, dtype=float)
    bl = boundary_layer(model, epsilon)
    joints = _boundary_layer_joints(model, bl)
    if limits or box is not None:
        axes = schedule_axes(model.robot, joints, axis.size, limits=limits, box=box)
    else:
        axes = (axis,) * len(joints)
    # Without the table's own key two different tables would share one cache file.
    root = cache_root(cache_dir) if table.info.get("key") is not None else None
    if root is None:
        return gain_schedule(model, Q=Q, R=R, epsilon=epsilon, table=table, joints=joints,
                             grid=axes, method=method)
    ident = {
        "version": __version__, "robot": repr(model.robot), "table": table.info.get("key"),
        "modes": model.m, "delta_order": model.delta_order, "modal_mass": model.modal_mass,
        "shape_rates": model.shape_rates,
        "foreshortening": getattr(model, "foreshortening", False),
        # (only when set: the keys of existing truncated-kinematics schedules stay valid)
        **({"kinematics": "exact"} if getattr(model, "kinematics", "") == "exact" else {}),
        "Q": Q, "R": R, "epsilon": float(epsilon), "axis": axis.tolist(),
        "joints": list(joints),
        **({"axes": [a.tolist() for a in axes]} if limits or box is not None else {}),
        **({} if method == "bspline" else {"method": method}),
        "source": source_digest(gain_schedule, boundary_layer, lqr, GainSchedule,
                                schedule_axes),
    }
    key = digest(ident)
    path = root / f"gains-{key[:32]}.npz"
    hit = load_verified(path, key)
    if hit is not None:
        return GainSchedule.from_gains(joints, axes, hit["gains"], epsilon, model.n,
                                       method=method, filled=int(hit["filled"]),
                                       info={"from_cache": True})
    sched = gain_schedule(model, Q=Q, R=R, epsilon=epsilon, table=table, joints=joints,
                          grid=axes, method=method)
    save_verified(path, key, gains=sched.gains, filled=np.array(sched.filled))
    return sched
