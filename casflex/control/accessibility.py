"""Modal controllability and accessibility of a flexible arm (dissertation eq. 201–204).

Notation: ``n`` joints, ``m`` modes, ``x = [q; δ; q̇; δ̇]`` (the model's ``ode`` state),
``M = [[M_qq, M_qδ], [M_qδᵀ, M_δδ]]`` with ``M_qδ`` of size n × m, ``K = diag(ω²)``.

How the flattened equations are read
------------------------------------
Eq. 201–204: ``B = [0; −M_qδᵀ]`` (2m × n; the printed ``−M_qδ`` has the wrong shape), so
"row i of M_qδ" in eq. 204 is row ``i`` of ``M_qδᵀ``, i.e. column ``i`` of the model's
``M_qδ``: ``a_i(q) = ‖M_qδ[:, i](q, δ=0)‖`` [√kg·m]. Everything is evaluated at δ = 0.
The rank of ``G_c`` (eq. 203) is computed on a time-scaled copy of ``(A, B)``
(``A/ω_s``, ``B/ω_s`` with ``ω_s`` the largest natural frequency, states ``[ω_s δ; δ̇]``),
which has the same rank and keeps the powers ``A^k`` of order one.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> robot = load("problems/arm2link.toml")
>>> q = [0.0, 0.0, -np.pi / 2]
>>> model = FlexibleModel(robot, PointwiseProvider(robot, q, count=3), gravity=None)
>>> accessibility(model, q).round(3).tolist()
[0.495, 0.522, 0.079]
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import fail, number, vector
from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move
    from casflex.robot import Robot

__all__ = [
    "modal_system",
    "controllability",
    "accessibility_function",
    "accessibility",
    "accessibility_map",
    "accessibility_along",
    "robot_accessibility_map",
]

_FIVE_DEG = math.radians(5.0)


def modal_system(model: FlexibleModel) -> ca.Function:
    """The flexible subsystem of eq. 201 as a function of the configuration.

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    casadi.Function
        ``modal_system (q) -> (A, B)`` with ``A = [[0, I], [−K(q), 0]]`` (2m × 2m, 1/s²
        block) and ``B = [0; −M_qδ(q, 0)ᵀ]`` (2m × n); state ``[δ; δ̇]``, input ``q̈``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> A, B = modal_system(model)([0, 0, 0])
    >>> A.shape, B.shape
    ((4, 4), (4, 3))
    """
    n, m = model.n, model.m
    q = model.q
    zero = ca.SX.zeros(m)
    M0 = ca.substitute(model.M, model.delta, zero)
    K = ca.substitute(model.K, model.delta, zero)
    A = ca.blockcat([[ca.SX.zeros(m, m), ca.SX.eye(m)], [-K, ca.SX.zeros(m, m)]])
    B = ca.vertcat(ca.SX.zeros(m, n), -M0[:n, n:].T)
    return ca.Function("modal_system", [q], [A, B], ["q"], ["A", "B"])


def controllability(model: FlexibleModel, q: ArrayLike,
                    rtol: float = 1e-9) -> tuple[np.ndarray, int, np.ndarray]:
    """Controllability matrix ``G_c(q)`` of eq. 203 and its numerical rank.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like
        Configuration [rad].
    rtol : float
        Singular values below ``rtol · σ_max`` count as zero.

    Returns
    -------
    Gc : numpy.ndarray
        ``[B, AB, …, A^{2m−1}B]`` of the time-scaled pair (module docstring), 2m × 2mn.
    rank : int
        Full controllability of the modes is ``rank == 2m``.
    sigma : numpy.ndarray
        Singular values of ``Gc`` (descending).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, np.pi / 2, -np.pi / 2]      # vertical: modes 1 and 3 inaccessible
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 3), gravity=None)
    >>> controllability(model, q)[1]
    2
    """
    q = vector(q, model.n, "q", unit="rad")
    A, B = (x.full() for x in modal_system(model)(q))
    m = model.m
    ws = math.sqrt(max(float(np.max(-np.diag(A[m:, :m]))), 1e-300))
    A, B = A / ws, B / ws
    A[:m, m:] *= ws  # states [ws δ; δ̇]: A = [[0, ws I], [−K/ws, 0]] / ws
    A[m:, :m] /= ws
    blocks = [B]
    for _ in range(2 * m - 1):
        blocks.append(A @ blocks[-1])
    Gc = np.hstack(blocks)
    sigma = np.linalg.svd(Gc, compute_uv=False)
    rank = int(np.sum(sigma > rtol * sigma[0])) if sigma.size and sigma[0] > 0 else 0
    return Gc, rank, sigma


def accessibility_function(model: FlexibleModel) -> ca.Function:
    """Accessibility indexes of eq. 204 as a CasADi function.

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    casadi.Function
        ``accessibility (q) -> a`` with ``a_i = ‖M_qδ[:, i](q, δ = 0)‖`` (m × 1,
        [√kg·m]): the coupling of mode ``i`` to all joint accelerations.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> accessibility_function(model).name_out()
    ['a']
    """
    n, m = model.n, model.m
    M0 = ca.substitute(model.M, model.delta, ca.SX.zeros(m))
    Mqd = M0[:n, n:]
    a = ca.vertcat(*[ca.sqrt(ca.sumsqr(Mqd[:, i])) for i in range(m)]) if m \
        else ca.SX(0, 1)
    return ca.Function("accessibility", [model.q], [a], ["q"], ["a"])


def accessibility(model: FlexibleModel, q: ArrayLike) -> np.ndarray:
    """Accessibility indexes ``a_i(q)`` (eq. 204) at one or many configurations.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like
        ``(n,)`` or ``(N, n)`` configurations [rad].

    Returns
    -------
    numpy.ndarray
        ``(m,)`` or ``(N, m)`` [√kg·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, np.pi / 2, -np.pi / 2]
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 3), gravity=None)
    >>> accessibility(model, q).round(6).tolist()
    [0.0, 0.522314, 0.0]
    """
    Q = np.asarray(q, dtype=float)
    single = Q.ndim == 1
    Q = np.atleast_2d(Q)
    if Q.shape[1] != model.n:
        raise ModelError(f"q: expected {model.n} joint values per configuration; got "
                         f"shape {np.shape(q)}")
    f = accessibility_function(model)
    out = np.asarray(f.map(Q.shape[0])(Q.T)).T.reshape(Q.shape[0], model.m)
    out = np.abs(out) + 0.0
    return out[0] if single else out


def accessibility_map(model: FlexibleModel, joints: Sequence[int] = (1, 2),
                      axes: Sequence[ArrayLike] | None = None, q: ArrayLike | None = None,
                      step: float = _FIVE_DEG) -> tuple[list[np.ndarray], np.ndarray]:
    """Accessibility indexes over a grid of two joints (Fig. 108–110, 120).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    joints : (int, int)
        0-based indexes of the two joints varied.
    axes : (array_like, array_like), optional
        Values of the two joints [rad]; default a full turn ``[−π, π)`` with ``step``.
    q : array_like, optional
        Values of the other joints [rad] (default zeros).
    step : float
        Grid step [rad] when ``axes`` is not given.

    Returns
    -------
    axes : list of numpy.ndarray
    index : numpy.ndarray
        ``(m, len(axes[0]), len(axes[1]))``; ``index[k, i, j]`` is ``a_k`` at the
        ``i``-th value of the first joint and the ``j``-th of the second.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> ax, a = accessibility_map(model, axes=([0.0, 1.0], [0.0]))
    >>> a.shape
    (2, 2, 1)
    """
    j1, j2 = (int(j) for j in joints)
    for j in (j1, j2):
        number(j, "joints", low=0, high=model.n - 1)  # 0-based
    if j1 == j2:
        raise ModelError(f"joints: two different joints are needed; got {joints}")
    if axes is None:
        number(step, "step", low=0.0, low_open=True)  # [rad]
        k = int(round(2 * math.pi / step))
        ax = -math.pi + 2 * math.pi * np.arange(k) / k
        axes = [ax, ax]
    axes = [np.asarray(a, dtype=float).ravel() for a in axes]
    base = np.zeros(model.n) if q is None else vector(q, model.n, "q", unit="rad")
    A1, A2 = np.meshgrid(axes[0], axes[1], indexing="ij")
    Q = np.tile(base, (A1.size, 1))
    Q[:, j1] = A1.ravel()
    Q[:, j2] = A2.ravel()
    a = accessibility(model, Q).reshape(A1.shape + (model.m,))
    return axes, np.moveaxis(a, -1, 0)


def accessibility_along(model: FlexibleModel, move: Move, t: ArrayLike) -> np.ndarray:
    """Accessibility indexes along the planned joint trajectory of a move.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    move : casflex.moves.Move
    t : array_like
        Times [s].

    Returns
    -------
    numpy.ndarray
        ``(len(t), m)`` [√kg·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> accessibility_along(model, Move([0, 0, 0], [-1, 0, 0], 2.0), [0, 1, 2]).shape
    (3, 2)
    """
    qd, _, _ = move.sample(np.atleast_1d(np.asarray(t, dtype=float)))
    return accessibility(model, qd)


def robot_accessibility_map(robot: Robot, joints: Sequence[int], step: float,
                            q: ArrayLike | None = None, n_modes: int = 3,
                            cache_dir: str | os.PathLike | bool | None = None,
                            log: Callable[[str], None] | None = None,
                            ) -> tuple[list[np.ndarray], np.ndarray]:
    """Accessibility maps of a robot over two joints: tabulate its modes, then
    :func:`accessibility_map` on a full-turn grid.

    The model is the one of the control studies (no gravity, ``delta_order=0``). A shape
    joint that is mapped is tabulated on the map's own axis (no interpolation between
    table points); the other shape joints on :func:`casflex.model.default_grid` with
    ``step``.

    Parameters
    ----------
    robot : casflex.robot.Robot
    joints : (int, int)
        0-based indexes of the two joints varied.
    step : float
        Grid step [rad]; the axis of both joints is ``−π + 2π k/N``, ``N =
        round(2π/step) >= 8``.
    q : array_like, optional
        Values of the other joints [rad] (default zeros).
    n_modes : int
        Number of modes.
    cache_dir : path, None or False
        Modal-table cache (a path, ``None`` for the default, ``False`` for none).
    log : callable, optional
        ``log(message)`` receives one line saying what is tabulated.

    Returns
    -------
    axes : list of numpy.ndarray
    index : numpy.ndarray
        ``(n_modes, N, N)`` [√kg·m] (see :func:`accessibility_map`).

    Examples
    --------
    >>> from casflex.robot import load
    >>> ax, a = robot_accessibility_map(load("problems/arm2link.toml"), (1, 2), np.pi / 4,
    ...                                 n_modes=1, cache_dir=False)
    >>> a.shape
    (1, 8, 8)
    """
    from casflex.modal.tables import shape_joints
    from casflex.model import build_model, default_grid

    n = robot.n_joints
    j1, j2 = (int(j) for j in joints)
    for j in (j1, j2):
        number(j, "joints", low=0, high=n - 1)  # 0-based
    if j1 == j2:
        raise ModelError(f"joints: two different joints are needed; got {joints}")
    number(n_modes, "n_modes", low=1, integer=True)
    number(step, "step", low=0.0, low_open=True)  # [rad]
    count = int(round(2 * math.pi / step))
    if count < 8:
        raise fail("step", step, "must give at least 8 points per turn [rad]")
    axis = -math.pi + 2 * math.pi * np.arange(count) / count
    q = np.zeros(n) if q is None else vector(q, n, "q", unit="rad")
    sj = shape_joints(robot)
    grid = default_grid(robot, sj, step)
    # shape joints that are mapped are tabulated on the map's own axis: no interpolation
    grid = [axis if k in (j1, j2) else g for k, g in zip(sj, grid, strict=True)]
    if log is not None:
        log(f"tabulating {n_modes} modes of {robot.name} over joints "
            f"{[k + 1 for k in sj]} ({count} points per turn)")
    model, _ = build_model(robot, n_modes, grid=grid, gravity=None, delta_order=0,
                           cache_dir=cache_dir)
    return accessibility_map(model, joints=(j1, j2), axes=(axis, axis), q=q)
