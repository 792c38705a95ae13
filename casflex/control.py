"""Modal controllability and feedback control of flexible arms (dissertation §6.2).

Everything here works on a :class:`casflex.dynamics.FlexibleModel` (usually from
:func:`casflex.model.build_model`) and returns plain numpy data or ``casadi.Function``
objects that can be simulated (:func:`simulate_closed_loop`, or
:func:`casflex.simulate.simulate_torque` through :func:`tracking`) and code-generated.

Notation: ``n`` joints, ``m`` modes, ``x = [q; δ; q̇; δ̇]`` (the model's ``ode`` state),
``M = [[M_qq, M_qδ], [M_qδᵀ, M_δδ]]`` with ``M_qδ`` of size n × m, ``K = diag(ω²)``.

How the flattened equations of the dissertation are read
--------------------------------------------------------
* Eq. 201–204: ``B = [0; −M_qδᵀ]`` (2m × n; the printed ``−M_qδ`` has the wrong shape),
  so "row i of M_qδ" in eq. 204 is row ``i`` of ``M_qδᵀ``, i.e. column ``i`` of the model's
  ``M_qδ``: ``a_i(q) = ‖M_qδ[:, i](q, δ=0)‖`` [√kg·m]. Everything is evaluated at δ = 0.
  The rank of ``G_c`` (eq. 203) is computed on a time-scaled copy of ``(A, B)``
  (``A/ω_s``, ``B/ω_s`` with ``ω_s`` the largest natural frequency, states ``[ω_s δ; δ̇]``),
  which has the same rank and keeps the powers ``A^k`` of order one.
* Eq. 210 is the exact input–output linearisation of the model: from the second block row
  ``δ̈ = −M_δδ⁻¹(M_qδᵀ q̈ + h_δ)``, so ``τ = (M_qq − M_qδ M_δδ⁻¹ M_qδᵀ) v + h_q −
  M_qδ M_δδ⁻¹ h_δ`` with ``h = C Ẋ + G + D Ẋ`` (Coriolis, gravity/stiffness, modal damping).
  With ``M_δδ = I`` this is eq. 210 term by term; it is the model's ``prescribed`` form
  evaluated at ``q̈ = v`` (eq. 213).
* Eq. 226: only the symmetric part of ``K̄ = K − α(C_δδ + D) + α² I`` enters the quadratic
  forms (``C_δδ`` is skew-symmetric), so the margin is
  ``λ_min(2α (K + α² I − α D) − K̇)`` along ``q_d(t)``, ``K̇ = ∂K/∂q · q̇_d`` by CasADi
  differentiation [1/s³]. Eq. 225 as printed (``D̄ = C − αI``, "α > 0 guarantees
  xᵀD̄x > 0") has a sign slip: with modal damping ``D`` the requirement is
  ``D − α I ≻ 0``, i.e. ``α < 2ζ ω_min``; :func:`inversion_stability` reports it as
  ``damping_condition``. The rate of eq. 230 is computed so that ``V̇ ≤ −γ V`` really
  holds: ``γ = min(2 λ_min(D − αI), β / λ_max(K̄))`` with ``β`` the worst margin.
* Eq. 232 and the slow law of eq. 248 are the same computed-torque law on the rigid model:
  ``τ = M_qq(q, 0) v + C_qq(q, q̇) q̇ + g_q(q)``.
* Eq. 244–251: ``ε² = 1/k`` with ``k`` the lowest stiffness entry of ``K`` (= ω_min²), so
  ``ε = 1/ω_min`` [s] with ω_min the lowest first natural frequency over the model's table
  ("for any trajectory", 6.35 rad/s in the dissertation), ``K̃ = ε² K``, ``ξ = δ/ε²``,
  fast time ``t_f = t/ε``. The quasi-steady part ``ξ̄`` (eq. 246) is taken as zero ("it is
  assumed that ξ = ξ̄ = 0"), so the boundary-layer state is
  ``z = [η; dη/dt_f] = [δ/ε²; δ̇/ε]`` and ``A_f = [[0, I], [−H_δδ K̃, 0]]``,
  ``B_f = [0; H_δq]`` with ``H = M(q, 0)⁻¹``. The LQR (eq. 252–256) is solved for
  ``(A_f, B_f, Q, R)`` in fast time and ``τ_f = −K_f z``. Eigenvalues reported by
  :func:`composite_stability` are converted back to real time (``λ/ε`` [1/s]).
* The impulse disturbance (§6.2.3.2) is an impulsive tip force ``p`` [N·s] in the base
  frame: ``ΔẊ = M⁻¹ J_tipᵀ p`` at the instant of the impulse.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.dynamics import FlexibleModel, PointwiseProvider
>>> robot = load("problems/arm2link.toml")
>>> q = [0.0, 0.0, -np.pi / 2]
>>> model = FlexibleModel(robot, PointwiseProvider(robot, q, count=3), gravity=None)
>>> accessibility(model, q).round(3).tolist()
[0.495, 0.522, 0.079]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from casflex.errors import ModelError, SolverError

__all__ = [
    "modal_system",
    "controllability",
    "accessibility_function",
    "accessibility",
    "accessibility_map",
    "accessibility_along",
    "reference_function",
    "inversion_controller",
    "feedforward_controller",
    "perturbation_parameter",
    "boundary_layer",
    "fast_gain",
    "GainSchedule",
    "gain_schedule",
    "composite_controller",
    "tracking",
    "closed_loop",
    "ClosedLoopResult",
    "simulate_closed_loop",
    "decay_time",
    "inversion_stability",
    "composite_stability",
    "plot_accessibility",
]

_FIVE_DEG = math.radians(5.0)


def _functions(model):
    """``model.functions()``, built once per model."""
    return model.functions()


def _gain_matrix(value, n, what):
    """Scalar, vector (diagonal) or n × n matrix -> n × n numpy array."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        a = a * np.eye(n)
    elif a.ndim == 1:
        if a.size != n:
            raise ModelError(f"{what}: expected {n} diagonal entries; got {a.size}")
        a = np.diag(a)
    if a.shape != (n, n) or not np.all(np.isfinite(a)):
        raise ModelError(f"{what}: must be a finite scalar, {n}-vector or {n} x {n} matrix; "
                         f"got shape {np.shape(value)}")
    return a


def _q_array(model, q, what="q"):
    q = np.asarray(q, dtype=float).ravel()
    if q.size != model.n or not np.all(np.isfinite(q)):
        raise ModelError(f"{what}: expected {model.n} finite joint values [rad]; got {q}")
    return q


# ================================================================== controllability


def modal_system(model):
    """The flexible subsystem of eq. 201 as a function of the configuration.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel

    Returns
    -------
    casadi.Function
        ``modal_system (q) -> (A, B)`` with ``A = [[0, I], [−K(q), 0]]`` (2m × 2m, 1/s²
        block) and ``B = [0; −M_qδ(q, 0)ᵀ]`` (2m × n); state ``[δ; δ̇]``, input ``q̈``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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


def controllability(model, q, rtol=1e-9):
    """Controllability matrix ``G_c(q)`` of eq. 203 and its numerical rank.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, np.pi / 2, -np.pi / 2]      # vertical: modes 1 and 3 inaccessible
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 3), gravity=None)
    >>> controllability(model, q)[1]
    2
    """
    q = _q_array(model, q)
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


def accessibility_function(model):
    """Accessibility indexes of eq. 204 as a CasADi function.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel

    Returns
    -------
    casadi.Function
        ``accessibility (q) -> a`` with ``a_i = ‖M_qδ[:, i](q, δ = 0)‖`` (m × 1,
        [√kg·m]): the coupling of mode ``i`` to all joint accelerations.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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


def accessibility(model, q):
    """Accessibility indexes ``a_i(q)`` (eq. 204) at one or many configurations.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    q : array_like
        ``(n,)`` or ``(N, n)`` configurations [rad].

    Returns
    -------
    numpy.ndarray
        ``(m,)`` or ``(N, m)`` [√kg·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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


def accessibility_map(model, joints=(1, 2), axes=None, q=None, step=_FIVE_DEG):
    """Accessibility indexes over a grid of two joints (Fig. 108–110, 120).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> ax, a = accessibility_map(model, axes=([0.0, 1.0], [0.0]))
    >>> a.shape
    (2, 2, 1)
    """
    j1, j2 = (int(j) for j in joints)
    for j in (j1, j2):
        if not 0 <= j < model.n:
            raise ModelError(f"joints: index {j} out of range for {model.n} joints "
                             "(0-based)")
    if j1 == j2:
        raise ModelError(f"joints: two different joints are needed; got {joints}")
    if axes is None:
        if not step > 0:
            raise ModelError(f"step must be > 0 [rad]; got {step}")
        k = int(round(2 * math.pi / step))
        ax = -math.pi + 2 * math.pi * np.arange(k) / k
        axes = [ax, ax]
    axes = [np.asarray(a, dtype=float).ravel() for a in axes]
    base = np.zeros(model.n) if q is None else _q_array(model, q)
    A1, A2 = np.meshgrid(axes[0], axes[1], indexing="ij")
    Q = np.tile(base, (A1.size, 1))
    Q[:, j1] = A1.ravel()
    Q[:, j2] = A2.ravel()
    a = accessibility(model, Q).reshape(A1.shape + (model.m,))
    return axes, np.moveaxis(a, -1, 0)


def accessibility_along(model, move, t):
    """Accessibility indexes along the planned joint trajectory of a move.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> accessibility_along(model, Move([0, 0, 0], [-1, 0, 0], 2.0), [0, 1, 2]).shape
    (3, 2)
    """
    qd, _, _ = move.sample(np.atleast_1d(np.asarray(t, dtype=float)))
    return accessibility(model, qd)


# ================================================================== references, laws


def reference_function(move):
    """The bang-bang reference of a move as a CasADi function of time.

    Parameters
    ----------
    move : casflex.moves.Move
        A move with ``q0``, ``qf``, ``duration`` and ``peak_acceleration``; a move that
        has its own ``casadi_reference()`` (e.g. :class:`casflex.moves.ShapedMove`)
        supplies its reference itself. Before ``t = 0`` the reference rests at ``q0``,
        after the duration at ``qf``.

    Returns
    -------
    casadi.Function
        ``reference (t) -> (qd, dqd, ddqd)`` [rad, rad/s, rad/s²], equal to
        :meth:`casflex.moves.Move.sample`.

    Examples
    --------
    >>> from casflex.moves import Move
    >>> r = reference_function(Move([0.0], [-1.0], 2.0))
    >>> [float(v) for v in r(1.5)]
    [-0.875, -0.5, 1.0]
    """
    if hasattr(move, "casadi_reference"):  # e.g. casflex.moves.ShapedMove
        return move.casadi_reference()
    t = ca.SX.sym("t")
    T = float(move.duration)
    q0, qf = ca.DM(move.q0), ca.DM(move.qf)
    a = ca.DM(move.peak_acceleration)
    tc = ca.fmin(ca.fmax(t, 0.0), T)
    first = ca.logic_and(t >= 0.0, t < T / 2.0)
    second = ca.logic_and(t >= T / 2.0, t < T)
    q = ca.if_else(t < 0.0, q0, ca.if_else(first, q0 + 0.5 * a * tc**2,
                                           qf - 0.5 * a * (T - tc) ** 2))
    dq = ca.if_else(first, a * tc, ca.if_else(second, a * (T - tc), ca.DM.zeros(q0.shape)))
    ddq = ca.if_else(first, a, ca.if_else(second, -a, ca.DM.zeros(q0.shape)))
    return ca.Function("reference", [t], [q, dq, ddq], ["t"], ["qd", "dqd", "ddqd"])


def _split(model, x):
    n, m = model.n, model.m
    return x[:n], x[n:n + m], x[n + m:2 * n + m], x[2 * n + m:]


def _rigid_terms(model):
    """SX expressions of the rigid model at δ = δ̇ = 0: M_qq, C_qq q̇ and g_q."""
    n, m = model.n, model.m
    sub_in = ca.vertcat(model.delta, model.ddelta)
    zero = ca.SX.zeros(2 * m)
    Mqq = ca.substitute(model.M[:n, :n], sub_in, zero)
    # h at δ = δ̇ = 0: C_qq q̇ q̇ + g_q (stiffness, damping and C_δ terms vanish there)
    hq = ca.substitute(model.h[:n], sub_in, zero)
    return Mqq, hq


def inversion_controller(model, Kp=1.0, Kd=2.0, name="inversion"):
    """Inversion-based tracking controller (eq. 210 with eq. 213).

    ``v = q̈_d + K_d (q̇_d − q̇) + K_p (q_d − q)`` and
    ``τ = (M_qq − M_qδ M_δδ⁻¹ M_qδᵀ) v + h_q − M_qδ M_δδ⁻¹ h_δ`` (module docstring): the
    joints then obey ``q̈ = v`` exactly and the modes are the zero dynamics (eq. 212).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    Kp, Kd : float or array_like
        Gains [N·m/rad → 1/s², 1/s]: scalars, diagonals or n × n matrices (they act on
        accelerations, so their units are 1/s² and 1/s).
    name : str

    Returns
    -------
    casadi.Function
        ``(qd, dqd, ddqd, x) -> tau`` with ``x = [q; δ; q̇; δ̇]`` [N·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> ctrl = inversion_controller(model)
    >>> ctrl.name_in()
    ['qd', 'dqd', 'ddqd', 'x']
    >>> float(ca.norm_inf(ctrl([0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0, 0, 0, 0])))
    0.0
    """
    n = model.n
    Kp, Kd = _gain_matrix(Kp, n, "Kp"), _gain_matrix(Kd, n, "Kd")
    qd, dqd, ddqd = (ca.SX.sym(s, n) for s in ("qd", "dqd", "ddqd"))
    v = ddqd + Kd @ (dqd - model.dq) + Kp @ (qd - model.q)
    tau = ca.substitute(model.prescribed_tau, model.ddq, v)
    x = ca.vertcat(model.q, model.delta, model.dq, model.ddelta)
    return ca.Function(name, [qd, dqd, ddqd, x], [tau], ["qd", "dqd", "ddqd", "x"], ["tau"])


def feedforward_controller(model, Kp=1.0, Kd=2.0, name="feedforward"):
    """Classical computed-torque law on the rigid model (eq. 232; the slow law, eq. 248).

    ``τ = M_qq(q, 0) (q̈_d + K_d (q̇_d − q̇) + K_p (q_d − q)) + C_qq(q, q̇) q̇ + g_q(q)``;
    the deflections are ignored (``g_q`` is zero for a model without gravity).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    Kp, Kd : float or array_like
        Gains [1/s², 1/s].
    name : str

    Returns
    -------
    casadi.Function
        ``(qd, dqd, ddqd, x) -> tau`` [N·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> ff = feedforward_controller(model)
    >>> inv = inversion_controller(model)
    >>> args = ([0.1, 0.2, 0.3], [0.1, 0, 0], [1, 0, 0], [0, 0, 0.3, 0, 0, 0])
    >>> bool(np.allclose(ff(*args).full(), inv(*args).full()))  # identical without modes
    True
    """
    n = model.n
    Kp, Kd = _gain_matrix(Kp, n, "Kp"), _gain_matrix(Kd, n, "Kd")
    qd, dqd, ddqd = (ca.SX.sym(s, n) for s in ("qd", "dqd", "ddqd"))
    v = ddqd + Kd @ (dqd - model.dq) + Kp @ (qd - model.q)
    Mqq, hq = _rigid_terms(model)
    tau = Mqq @ v + hq
    x = ca.vertcat(model.q, model.delta, model.dq, model.ddelta)
    return ca.Function(name, [qd, dqd, ddqd, x], [tau], ["qd", "dqd", "ddqd", "x"], ["tau"])


# ================================================================== singular perturbation


def perturbation_parameter(model, table=None, q=None):
    """``ε = 1/ω_min`` [s], the singular-perturbation parameter (eq. 244).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.5], 2), gravity=None)
    >>> round(1.0 / perturbation_parameter(model, q=[[0, 0, 0.5]]), 2)
    10.42
    """
    if q is not None:
        Q = np.atleast_2d(np.asarray(q, dtype=float))
        if Q.shape[1] != model.n:
            raise ModelError(f"q: expected {model.n} joint values per row; got {Q.shape}")
        fK = _functions(model)["stiffness"]
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


def boundary_layer(model, epsilon):
    """Boundary-layer (fast) subsystem of eq. 251 in the fast time ``t/ε``.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> A, B = boundary_layer(model, 0.1)([0, 0, 0])
    >>> A.shape, B.shape
    ((4, 4), (4, 3))
    """
    n, m = model.n, model.m
    eps = float(epsilon)
    if not eps > 0:
        raise ModelError(f"epsilon must be > 0 [s]; got {epsilon}")
    M0 = ca.substitute(model.M, model.delta, ca.SX.zeros(m))
    K = ca.substitute(model.K, model.delta, ca.SX.zeros(m))
    H = ca.solve(M0, ca.SX.eye(n + m))
    Hdq, Hdd = H[n:, :n], H[n:, n:]
    A = ca.blockcat([[ca.SX.zeros(m, m), ca.SX.eye(m)],
                     [-Hdd @ (eps**2 * K), ca.SX.zeros(m, m)]])
    B = ca.vertcat(ca.SX.zeros(m, n), Hdq)
    return ca.Function("boundary_layer", [model.q], [A, B], ["q"], ["A", "B"])


def _weight(value, size, what):
    return _gain_matrix(value, size, what)


def _lqr(A, B, Q, R):
    import control

    try:
        K, S, E = control.lqr(A, B, Q, R)
    except Exception as exc:  # python-control raises several types (ControlArgument, ...)
        raise SolverError(f"LQR of the boundary-layer system failed: {exc}") from exc
    return np.asarray(K, dtype=float), np.asarray(S, dtype=float), np.asarray(E)


def fast_gain(model, q, Q=1.0, R=10.0, epsilon=None):
    """LQR gain of the boundary-layer system at one configuration (eq. 252–256).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, -np.pi / 2]
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None)
    >>> K, S, E = fast_gain(model, q, epsilon=0.15)
    >>> K.shape, bool(np.all(E.real < 0))
    ((3, 4), True)
    """
    q = _q_array(model, q)
    if epsilon is None:
        epsilon = perturbation_parameter(model)
    A, B = (x.full() for x in boundary_layer(model, epsilon)(q))
    return _lqr(A, B, _weight(Q, 2 * model.m, "Q"), _weight(R, model.n, "R"))


@dataclass
class GainSchedule:
    """LQR gains of the boundary-layer system tabulated over joints.

    Attributes
    ----------
    joints : tuple of int
        0-based joints of the grid axes.
    grid : tuple of numpy.ndarray
        Axes [rad] (full turns, wrapped periodically by ``function``).
    gains : numpy.ndarray
        ``grid_shape + (n, 2m)`` gains.
    epsilon : float
        Perturbation parameter used [s].
    function : casadi.Function
        ``gain (q) -> K`` (n × 2m), cubic B-spline interpolation of ``gains``.
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
    def from_gains(cls, joints, grid, gains, epsilon, n_joints, method="bspline", filled=0,
                   info=None):
        """Build a schedule (its interpolating ``function``) from tabulated gains.

        Parameters
        ----------
        joints : sequence of int
            0-based joints of the grid axes.
        grid : sequence of array_like
            One full-turn axis [rad] per joint.
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
        Kq = fg(ca.vertcat(*[qs[j] for j in joints]))
        fun = ca.Function("fast_gain", [qs], [ca.reshape(Kq, n, m2)], ["q"], ["K"])
        return cls(joints=joints, grid=grid, gains=G, epsilon=float(epsilon), function=fun,
                   filled=int(filled), info=dict(info or {}))


def _dependent_joints(fun, n, rng, samples=3, rtol=1e-9):
    """Joints a numeric function of q (sum of |outputs|) depends on."""
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


def gain_schedule(model, Q=1.0, R=10.0, epsilon=None, joints=None, grid=None, table=None,
                  q=None, method="bspline"):
    """Tabulate the fast LQR gain over the configuration grid and interpolate it.

    The grid is the model table's grid over the shape joints; joints that the
    boundary-layer system depends on but that are not shape joints (e.g. the shoulder of
    the Table 8 arm, through ``M_qδ``) get a uniform full-turn axis with as many points
    as the first shape-joint axis. At points where the pair is not stabilisable (a mode
    with zero accessibility; the LQR fails or leaves an eigenvalue on the imaginary axis)
    the gain is replaced by the mean of its valid neighbours.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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
        joints = _dependent_joints(lambda qq: [x.full() for x in bl(qq)], n,
                                   np.random.default_rng(0))
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
    base = np.zeros(n) if q is None else _q_array(model, q)
    shape = tuple(a.size for a in grid)
    pts = np.array(np.meshgrid(*grid, indexing="ij")).reshape(len(joints), -1).T
    Qall = np.tile(base, (pts.shape[0], 1))
    Qall[:, list(joints)] = pts
    N = Qall.shape[0]
    Aall, Ball = bl.map(N)(Qall.T)
    Aall = np.asarray(Aall).reshape(2 * m, N, 2 * m)
    Ball = np.asarray(Ball).reshape(2 * m, N, n)
    Qw, Rw = _weight(Q, 2 * m, "Q"), _weight(R, n, "R")
    gains = np.zeros((N, n, 2 * m))
    valid = np.zeros(N, dtype=bool)
    worst = -np.inf
    for k in range(N):
        A, B = Aall[:, k, :], Ball[:, k, :]
        try:
            K, _, E = _lqr(A, B, Qw, Rw)
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


def composite_controller(model, Kp=1.0, Kd=2.0, gain=None, epsilon=None, fast=True,
                         name="composite"):
    """Singular-perturbation composite controller (eq. 248 + 251, §6.2.3.1).

    ``τ = τ_s + τ_f`` with the slow computed torque of eq. 248
    (:func:`feedforward_controller`) and the fast LQR feedback
    ``τ_f = −K_f(q) [δ/ε²; δ̇/ε]``.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    Kp, Kd : float or array_like
        Slow gains [1/s², 1/s].
    gain : array_like or GainSchedule or casadi.Function, optional
        Fast gain: a fixed n × 2m matrix (e.g. :func:`fast_gain` at the end of the
        trajectory), a :class:`GainSchedule`, or a function ``q -> K``. Required when
        ``fast`` is true.
    epsilon : float, optional
        Must be the one the gain was computed with (default: the schedule's, else
        :func:`perturbation_parameter`).
    fast : bool
        False gives the slow controller alone (the "without fast controller" runs).
    name : str

    Returns
    -------
    casadi.Function
        ``(qd, dqd, ddqd, x) -> tau`` [N·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, -np.pi / 2]
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None)
    >>> K, _, _ = fast_gain(model, q, epsilon=0.15)
    >>> c = composite_controller(model, gain=K, epsilon=0.15)
    >>> x = np.r_[q, 0.01, 0.0, 0, 0, 0, 0, 0]
    >>> tau = c(q, [0, 0, 0], [0, 0, 0], x).full().ravel()
    >>> bool(np.allclose(tau, -K[:, 0] * 0.01 / 0.15**2))
    True
    """
    n, m = model.n, model.m
    slow = feedforward_controller(model, Kp, Kd, name=name + "_slow")
    qd, dqd, ddqd = (ca.SX.sym(s, n) for s in ("qd", "dqd", "ddqd"))
    x = ca.vertcat(model.q, model.delta, model.dq, model.ddelta)
    tau = slow(qd, dqd, ddqd, x)
    if fast:
        if gain is None:
            raise ModelError("composite_controller: give the fast gain (fast_gain or "
                             "gain_schedule), or fast=False")
        if isinstance(gain, GainSchedule):
            if epsilon is None:
                epsilon = gain.epsilon
            Kf = gain.function(model.q)
        elif isinstance(gain, ca.Function):
            Kf = gain(model.q)
        else:
            Kf = np.asarray(gain, dtype=float)
            if Kf.shape != (n, 2 * m):
                raise ModelError(f"gain: expected an {n} x {2 * m} matrix; got {Kf.shape}")
            Kf = ca.DM(Kf)
        if epsilon is None:
            epsilon = perturbation_parameter(model)
        eps = float(epsilon)
        z = ca.vertcat(model.delta / eps**2, model.ddelta / eps)
        tau = tau - Kf @ z
    return ca.Function(name, [qd, dqd, ddqd, x], [tau], ["qd", "dqd", "ddqd", "x"], ["tau"])


# ================================================================== closed loop


def tracking(controller, move):
    """Close a reference-driven controller over a move: ``(t, x) -> tau``.

    The result is the controller form of :func:`casflex.simulate.simulate_torque`.

    Parameters
    ----------
    controller : casadi.Function
        ``(qd, dqd, ddqd, x) -> tau``, e.g. from :func:`inversion_controller`,
        :func:`feedforward_controller` or :func:`composite_controller`.
    move : casflex.moves.Move
        The reference, through :func:`reference_function`.

    Returns
    -------
    casadi.Function
        ``<controller>_tracking (t, x) -> tau`` [s, state ``[q; δ; q̇; δ̇]`` -> N·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> f = tracking(feedforward_controller(model), Move([0, 0, 0], [1, 0, 0], 2.0))
    >>> f.name_in()
    ['t', 'x']
    """
    ref = reference_function(move)
    t = ca.SX.sym("t")
    x = ca.SX.sym("x", controller.size1_in(3))
    qd, dqd, ddqd = ref(t)
    return ca.Function(controller.name() + "_tracking", [t, x], [controller(qd, dqd, ddqd, x)],
                       ["t", "x"], ["tau"])


def closed_loop(model, controller, move):
    """Closed-loop vector field ``(t, x) -> xdot`` of the model under a tracking law.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    controller : casadi.Function
        ``(qd, dqd, ddqd, x) -> tau``.
    move : casflex.moves.Move
        The reference (:func:`reference_function`).

    Returns
    -------
    casadi.Function
        ``closed_loop (t, x) -> xdot`` with ``x = [q; δ; q̇; δ̇]``: the model's ``ode``
        evaluated at the controller's torque.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> f = closed_loop(model, inversion_controller(model), Move([0, 0, 0], [1, 0, 0], 2.0))
    >>> # v = q̈_d + Kd q̇_d + Kp q_d at t = 0.5 s
    >>> (f(0.5, np.zeros(6)).full().ravel()[3:].round(6) + 0.0).tolist()
    [2.125, 0.0, 0.0]
    """
    ode = _functions(model)["ode"]
    ctrl = tracking(controller, move)
    t = ca.SX.sym("t")
    x = ca.SX.sym("x", 2 * (model.n + model.m))
    return ca.Function("closed_loop", [t, x], [ode(x, ctrl(t, x))], ["t", "x"], ["xdot"])


@dataclass
class ClosedLoopResult:
    """A closed-loop run (:func:`simulate_closed_loop`).

    Attributes
    ----------
    t : numpy.ndarray
        (N,) times [s].
    x : numpy.ndarray
        (N, 2(n+m)) states ``[q, δ, q̇, δ̇]``.
    tau : numpy.ndarray
        (N, n) torques applied from ``t[k]`` to ``t[k+1]`` [N·m] (last row repeated).
    qd : numpy.ndarray
        (N, n) reference [rad].
    tip, tip_rigid : numpy.ndarray
        (N, 3) tip position with and without deflection [m], base frame.
    x_hat : numpy.ndarray or None
        (N, 2m) estimates ``[δ̂, δ̂̇]`` used by the controller when an estimator ran.
    n, m : int
        Numbers of joints and modes (they split ``x``).

    Examples
    --------
    Usually from :func:`simulate_closed_loop`; the properties split the state:

    >>> r = ClosedLoopResult(t=np.array([0.0, 0.1]),
    ...                      x=np.array([[0.0, 0.01, 0.0, 0.0], [0.2, -0.01, 1.0, 0.5]]),
    ...                      tau=np.zeros((2, 1)), qd=np.array([[0.0], [0.25]]),
    ...                      tip=np.array([[1.0, 0.0, 0.0], [0.98, 0.2, 0.0]]),
    ...                      tip_rigid=np.array([[1.0, 0.0, 0.0], [0.98, 0.199, 0.0]]),
    ...                      n=1, m=1)
    >>> r.q.ravel().tolist(), r.delta.ravel().tolist(), r.dq.ravel().tolist()
    ([0.0, 0.2], [0.01, -0.01], [0.0, 1.0])
    >>> r.tracking_error.ravel().round(6).tolist()
    [0.0, -0.05]
    >>> r.tip_deflection[1].round(6).tolist()
    [0.0, 0.001, 0.0]
    """

    t: np.ndarray
    x: np.ndarray
    tau: np.ndarray
    qd: np.ndarray
    tip: np.ndarray
    tip_rigid: np.ndarray
    n: int
    m: int
    x_hat: np.ndarray | None = None

    @property
    def q(self):
        """Joint angles [rad]."""
        return self.x[:, :self.n]

    @property
    def delta(self):
        """Modal amplitudes [√kg·m]."""
        return self.x[:, self.n:self.n + self.m]

    @property
    def dq(self):
        """Joint rates [rad/s]."""
        return self.x[:, self.n + self.m:2 * self.n + self.m]

    @property
    def ddelta(self):
        """Modal rates."""
        return self.x[:, 2 * self.n + self.m:]

    @property
    def tip_deflection(self):
        """(N, 3) tip position minus that of the undeformed arm [m]."""
        return self.tip - self.tip_rigid

    @property
    def tracking_error(self):
        """(N, n) ``q − q_d`` [rad]."""
        return self.q - self.qd


def _rk4(f, x, u, dt):
    k1 = f(x, u)
    k2 = f(x + 0.5 * dt * k1, u)
    k3 = f(x + 0.5 * dt * k2, u)
    k4 = f(x + dt * k3, u)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def _impulse_jump(model, x, p):
    """State after an impulsive tip force ``p`` [N·s]: ``ΔẊ = M⁻¹ J_tipᵀ p``."""
    n, m = model.n, model.m
    f = _functions(model)
    q, d = x[:n], x[n:n + m]
    J = ca.jacobian(model.tip, model.X)
    Jf = ca.Function("tip_jacobian", [model.q, model.delta], [J])
    M = f["mass"](q, d).full()
    dX = np.linalg.solve(M, Jf(q, d).full().T @ np.asarray(p, dtype=float))
    out = x.copy()
    out[n + m:] += dX
    return out


def simulate_closed_loop(model, controller, move, x0=None, t_end=None, dt=1e-3,
                         impulse=None, method="cvodes", substeps=1, sampled=False,
                         estimator=None, rtol=1e-8, atol=1e-10):
    """Simulate the model under a tracking controller.

    By default the control law acts continuously, as in the dissertation's simulations,
    and the closed loop is integrated by CVODES (BDF, variable step: the computed-torque
    loops are stiff, with real poles near −2000 1/s where the residual joint inertia
    ``M_qq − M_qδ M_qδᵀ`` is small), in segments between the switching times of the
    reference and the impulse, with output every ``dt``. ``method="rk4"`` uses
    ``substeps`` classical RK4 steps per ``dt`` instead (one ``mapaccum``; the reference
    is evaluated just inside each step so its jumps fall between steps). With
    ``sampled=True`` (always with an estimator) the law runs at ``t_k = k·dt`` and its
    torque is held until ``t_{k+1}``, as in the real-time loop, with RK4. Sampling has a
    limit on the Table 8 model: where the residual joint inertia ``M_qq − M_qδ M_qδᵀ``
    nearly vanishes (mid ``control_move1``, smallest eigenvalue 2e-5 kg·m²) the
    computed-torque loops on ``M_qq`` have real poles beyond −1300 1/s and a 1 ms (even
    0.2 ms) zero-order hold diverges, for the slow law alone too; ``control_move3`` runs
    sampled at 1 ms.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    controller : casadi.Function
        ``(qd, dqd, ddqd, x) -> tau``.
    move : casflex.moves.Move
        Reference (a move with ``q0 == qf`` holds a configuration).
    x0 : array_like, optional
        Initial state ``[q, δ, q̇, δ̇]`` (default: at rest at ``move.q0``).
    t_end : float, optional
        Default ``move.t_end`` [s].
    dt : float
        Sample time [s].
    impulse : (float, array_like), optional
        ``(t_d, p)``: impulsive tip force ``p`` [N·s] (base frame) at ``t_d``.
    method : {"cvodes", "rk4"}
    substeps : int
        RK4 steps per ``dt``.
    sampled : bool
        Zero-order hold of the torque over each ``dt``.
    estimator : dict, optional
        Output feedback: ``{"step": ekf_step, "sensors": SensorSet, "P0": P0,
        "x0": x̂0, "R": R (noise covariance, optional), "seed": 0, "noise": array
        (optional), "ddq": "plant" | "difference"}``. At every sample ``t_k`` the exact
        signals of the plant (its acceleration just before ``t_k``, under the torque of
        the previous sample) plus noise — the rows of ``noise`` ((N + 1, r) samples, if
        given) or draws of covariance ``R`` — go to the EKF of
        :func:`casflex.estimation.ekf_step_function` with ``u = [q, q̇, q̈]``: ``q̈`` is
        the plant's (``"plant"``, default) or the backward difference of the joint rates
        ``(q̇_k − q̇_{k−1})/dt`` (``"difference"``, what the real-time ``rt_step`` of
        :mod:`casflex.rtloop` computes from the encoders). The controller gets
        ``[q, δ̂, q̇, δ̂̇]`` with the filtered estimate ``x̂_{k|k}``.
    rtol, atol : float
        CVODES tolerances.

    Returns
    -------
    ClosedLoopResult

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> move = Move([0, 0, 0], [-0.1, 0, 0], 0.5, settle=0.0)
    >>> r = simulate_closed_loop(model, inversion_controller(model), move, dt=5e-3)
    >>> bool(np.max(np.abs(r.tracking_error)) < 1e-6)
    True
    """
    n, m = model.n, model.m
    nx = 2 * (n + m)
    dt = float(dt)
    if not dt > 0:
        raise ModelError(f"dt must be > 0 [s]; got {dt}")
    if method not in ("cvodes", "rk4"):
        raise ModelError(f"method must be 'cvodes' or 'rk4'; got {method!r}")
    t_end = move.t_end if t_end is None else float(t_end)
    N = int(round(t_end / dt))
    if N < 1:
        raise ModelError(f"t_end = {t_end} s is shorter than one step dt = {dt} s")
    if x0 is None:
        x0 = np.r_[move.q0, np.zeros(m), np.zeros(n), np.zeros(m)]
    x0 = np.asarray(x0, dtype=float).ravel()
    if x0.size != nx:
        raise ModelError(f"x0: expected {nx} values [q, delta, dq, ddelta]; got {x0.size}")
    f = _functions(model)
    ode = f["ode"]
    ref = reference_function(move)
    t = np.arange(N + 1) * dt
    t_s = ca.SX.sym("t")
    x_s = ca.SX.sym("x", nx)
    if estimator is None and method == "cvodes" and not sampled:
        X = _run_cvodes(model, controller, ref, move, x0, t, impulse, rtol, atol)
        tau_all = np.asarray(controller.map(N + 1)(*ref.map(N + 1)(t[None, :]), X.T)).T
        x_hat = None
    elif estimator is None:
        qd, dqd, ddqd = ref(t_s)
        tau = controller(qd, dqd, ddqd, x_s)
        h = dt / substeps
        xn = x_s
        for i in range(substeps):
            if sampled:
                xn = _rk4(ode, xn, tau, h)
            else:
                ti = t_s + i * h

                def fcl(xx, tt):
                    return ode(xx, controller(*ref(tt), xx))

                # the end stages are evaluated just inside the step, so that the jumps
                # of a bang-bang q̈_d on the grid fall between steps, not on a stage
                k1 = fcl(xn, ti + 1e-9 * h)
                k2 = fcl(xn + 0.5 * h * k1, ti + 0.5 * h)
                k3 = fcl(xn + 0.5 * h * k2, ti + 0.5 * h)
                k4 = fcl(xn + h * k3, ti + (1.0 - 1e-9) * h)
                xn = xn + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        step = ca.Function("cl_step", [x_s, t_s], [xn, tau], {"cse": True})
        segments = _segments(t, impulse)
        X = [x0[None]]
        U = []
        xc = x0
        for k0, k1, jump in segments:
            if jump is not None:
                xc = _impulse_jump(model, xc, jump)
                X[-1] = np.vstack([X[-1][:-1], xc[None]])  # the state at t_d: after the jump
            if k1 > k0:
                Xs, Us = step.mapaccum("cl", k1 - k0)(xc, t[k0:k1][None, :])
                Xs, Us = np.asarray(Xs).T, np.asarray(Us).T
                X.append(Xs)
                U.append(Us)
                xc = Xs[-1]
        X = np.vstack(X)
        tau_all = np.vstack(U + [U[-1][-1:]])
        x_hat = None
    else:
        X, tau_all, x_hat = _run_with_estimator(model, controller, ref, x0, t, dt,
                                                substeps, impulse, estimator)
    qd_all = np.asarray(ref.map(N + 1)(t[None, :])[0]).T
    tipf = f["tip"].map(N + 1)
    tip = np.asarray(tipf(X[:, :n].T, X[:, n:n + m].T)).T
    tip_rigid = np.asarray(tipf(X[:, :n].T, np.zeros((m, N + 1)))).T
    return ClosedLoopResult(t=t, x=X, tau=tau_all, qd=qd_all, tip=tip, tip_rigid=tip_rigid,
                            n=n, m=m, x_hat=x_hat)


def _run_cvodes(model, controller, ref, move, x0, t, impulse, rtol, atol):
    """Continuous closed loop with CVODES, in segments between breakpoints."""
    nx = x0.size
    ode = _functions(model)["ode"]
    xs, ts = ca.SX.sym("x", nx), ca.SX.sym("t")
    qd, dqd, ddqd = ref(ts)
    dae = {"x": xs, "t": ts, "ode": ode(xs, controller(qd, dqd, ddqd, xs))}
    T = float(move.duration)
    dt = t[1] - t[0]
    tend = t[-1]
    breaks = {0.0, T / 2.0, T, tend}
    td = None
    if impulse is not None:
        kd = int(round(float(impulse[0]) / dt))
        if not 0 <= kd <= t.size - 1:
            raise ModelError(f"impulse time {impulse[0]} s lies outside the run "
                             f"[0, {tend}] s")
        td = t[kd]
        breaks.add(td)
    breaks = sorted(b for b in breaks if 0.0 <= b <= tend)
    X = np.zeros((t.size, nx))
    X[0] = x0
    xc = x0.copy()
    if td is not None and td == 0.0:
        xc = X[0] = _impulse_jump(model, xc, impulse[1])
    opts = {"abstol": atol, "reltol": rtol, "max_num_steps": 1000000}
    for a, b in zip(breaks[:-1], breaks[1:], strict=True):
        if b - a <= 1e-12 * max(1.0, tend):
            continue
        ks = np.nonzero((t > a + 1e-12) & (t <= b + 1e-12))[0]
        tout = list(t[ks])
        if not tout or abs(tout[-1] - b) > 1e-12:
            tout.append(b)
        try:
            F = ca.integrator("closed_loop", "cvodes", dae, a, tout, opts)
            Xs = np.asarray(F(x0=xc)["xf"]).T
        except RuntimeError as exc:
            raise SolverError(f"CVODES failed on [{a}, {b}] s: {exc}") from exc
        X[ks] = Xs[:ks.size]
        xc = Xs[-1]
        if td is not None and abs(b - td) <= 1e-12:
            xc = _impulse_jump(model, xc, impulse[1])
            k = int(np.argmin(np.abs(t - td)))
            X[k] = xc
    return X


def _segments(t, impulse):
    """Index ranges of the steps between impulses: [(k0, k1, jump_before_k0), ...]."""
    N = t.size - 1
    if impulse is None:
        return [(0, N, None)]
    td, p = impulse
    kd = int(round(float(td) / (t[1] - t[0])))
    if not 0 <= kd <= N:
        raise ModelError(f"impulse time {td} s lies outside the run [0, {t[-1]}] s")
    return [(0, kd, None), (kd, N, np.asarray(p, dtype=float))]


def _run_with_estimator(model, controller, ref, x0, t, dt, substeps, impulse, est):
    """Closed loop with an EKF between plant and controller (Python loop over samples)."""
    from casflex.sensors import measurement_function

    n, m = model.n, model.m
    nx = 2 * (n + m)
    ode = _functions(model)["ode"]
    ekf = est["step"]
    sensors = est["sensors"]
    h = measurement_function(model, sensors)
    ny = sensors.n_outputs
    rng = np.random.default_rng(est.get("seed", 0))
    ddq_source = est.get("ddq", "plant")
    if ddq_source not in ("plant", "difference"):
        raise ModelError(f"estimator['ddq'] must be 'plant' or 'difference'; got "
                         f"{ddq_source!r}")
    noise = est.get("noise")
    if noise is not None:
        noise = np.asarray(noise, dtype=float)
        if noise.shape != (t.size, ny):
            raise ModelError(f"estimator['noise']: expected shape {(t.size, ny)} (one row "
                             f"of {ny} signals per sample); got {noise.shape}")
    Rn = est.get("R")
    Lr = None if Rn is None else np.linalg.cholesky(
        np.atleast_2d(np.asarray(Rn, dtype=float)) * np.eye(ny) if np.ndim(Rn) < 2
        else np.asarray(Rn, dtype=float))
    # one sample: torque from (reference, plant joints, estimate), then RK4 of the plant
    t_s = ca.SX.sym("t")
    x_s = ca.SX.sym("x", nx)
    xh = ca.SX.sym("xh", 2 * m)
    qd, dqd, ddqd = ref(t_s)
    xc = ca.vertcat(x_s[:n], xh[:m], x_s[n + m:2 * n + m], xh[m:])
    tau = controller(qd, dqd, ddqd, xc)
    xn = x_s
    for _ in range(substeps):
        xn = _rk4(ode, xn, tau, dt / substeps)
    acc = ode(xn, tau)[n + m:2 * (n + m)]  # what the sensors see just before t_{k+1}
    plant_step = ca.Function("plant_step", [x_s, xh, t_s], [xn, tau, acc], {"cse": True})
    N = t.size - 1
    X = np.zeros((N + 1, nx))
    TAU = np.zeros((N + 1, n))
    XH = np.zeros((N + 1, 2 * m))
    x = x0.copy()
    xprior = np.asarray(est.get("x0", np.zeros(2 * m)), dtype=float)
    P = np.asarray(est.get("P0", np.eye(2 * m) * 1e-4), dtype=float)
    ddq_prev = np.zeros(n)
    kd = None if impulse is None else int(round(float(impulse[0]) / dt))
    mask = np.ones(ny)
    for k in range(N + 1):
        if kd is not None and k == kd:
            x = _impulse_jump(model, x, impulse[1])
        X[k] = x
        u = np.r_[x[:n], x[n + m:2 * n + m], ddq_prev]
        y = np.asarray(h(np.r_[x[n:n + m], x[2 * n + m:]], u)[-1]).ravel()
        if noise is not None:
            y = y + noise[k]
        elif Lr is not None:
            y = y + Lr @ rng.standard_normal(ny)
        if ddq_source == "difference":
            dq_k = x[n + m:2 * n + m]
            u = np.r_[x[:n], dq_k, (dq_k - (X[k - 1, n + m:2 * n + m] if k else dq_k)) / dt]
        xprior_next, P, xpost = ekf(xprior, P, u, y, mask)
        xpost = np.asarray(xpost).ravel()
        XH[k] = xpost
        if k == N:
            break
        xn_, tau_, acc_ = plant_step(x, xpost, t[k])
        TAU[k] = np.asarray(tau_).ravel()
        acc_ = np.asarray(acc_).ravel()
        ddq_prev = acc_[:n]
        x = np.asarray(xn_).ravel()
        xprior = np.asarray(xprior_next).ravel()
    TAU[N] = TAU[N - 1]
    return X, TAU, XH


def decay_time(t, signal, t0=0.0, fraction=0.05, floor=0.0):
    """Time after ``t0`` from which ``‖signal‖`` stays below a fraction of its peak.

    Parameters
    ----------
    t : array_like
        (N,) times [s].
    signal : array_like
        (N,) or (N, k) samples (the Euclidean norm over columns is used).
    t0 : float
        Start of the window (e.g. the instant of a disturbance) [s].
    fraction : float
        Threshold as a fraction of the peak of ``‖signal‖`` after ``t0``.
    floor : float
        Absolute threshold added to the relative one.

    Returns
    -------
    float
        Seconds from ``t0``; ``inf`` if the signal is still above the threshold in the
        last tenth of the window (it does not decay within the run).

    Examples
    --------
    >>> tt = np.linspace(0, 10, 1001)
    >>> round(decay_time(tt, np.exp(-tt) * np.cos(20 * tt)), 1)
    3.0
    """
    t = np.asarray(t, dtype=float)
    s = np.asarray(signal, dtype=float)
    s = np.linalg.norm(s, axis=1) if s.ndim == 2 else np.abs(s)
    sel = t >= t0
    tt, ss = t[sel], s[sel]
    if tt.size == 0:
        raise ModelError(f"decay_time: no samples after t0 = {t0} s")
    thr = fraction * float(np.max(ss)) + floor
    above = np.nonzero(ss > thr)[0]
    if above.size == 0:
        return 0.0
    last = tt[above[-1]]
    if last >= tt[-1] - 0.1 * (tt[-1] - tt[0]):
        return math.inf
    return float(last - t0)


# ================================================================== stability checks


def _trajectory(move, t, dt):
    if t is None:
        t = np.arange(int(round(move.duration / dt)) + 1) * dt
    t = np.atleast_1d(np.asarray(t, dtype=float))
    return (t, *move.sample(t))


def inversion_stability(model, move, alpha=None, Kp=1.0, t=None, dt=1e-2):
    """Stability condition of the zero dynamics (eq. 226) along a move, rate (eq. 230).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    move : casflex.moves.Move
    alpha : float, optional
        The constant of eq. 216 [1/s]. Default: ``ζ ω_min`` (half the bound
        ``2ζω_min`` of ``D − αI ≻ 0``) with modal damping, else ``√K_p`` (the slow
        closed-loop rate; eq. 225 cannot hold without damping, which is reported).
    Kp : float
        Used only for the default ``alpha``.
    t : array_like, optional
        Times [s] (default the move's duration at step ``dt``).
    dt : float

    Returns
    -------
    dict
        ``t``, ``margin`` (λ_min(2α K̄ − K̇) per time [1/s³]), ``worst_margin``,
        ``worst_time``, ``stable`` (margin > 0 throughout), ``alpha``,
        ``damping_condition`` (``D − αI ≻ 0``), ``gamma`` (eq. 230, [1/s]; > 0 means
        exponential stability), ``time_scale_max`` (largest factor by which the move
        may be run faster, duration/s, keeping eq. 226; ``inf`` if unbounded).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> r = inversion_stability(model, Move([0, 0, 0], [-1, 0, 0], 2.0), alpha=1.0)
    >>> r["stable"], r["time_scale_max"]   # frozen shapes: K̇ = 0
    (True, inf)
    """
    m = model.m
    t, qd, dqd, _ = _trajectory(move, t, dt)
    zeta = model.damping_ratio
    K = ca.substitute(model.K, model.delta, ca.SX.zeros(m))
    D = ca.substitute(model.D, model.delta, ca.SX.zeros(m))
    Kdot = ca.reshape(ca.jtimes(ca.vec(K), model.q, model.dq), m, m)
    fK = ca.Function("KD", [model.q, model.dq], [K, D, Kdot])
    Ks, Ds, Kds = fK.map(t.size)(qd.T, dqd.T)
    Ks = np.asarray(Ks).reshape(m, t.size, m).transpose(1, 0, 2)
    Ds = np.asarray(Ds).reshape(m, t.size, m).transpose(1, 0, 2)
    Kds = np.asarray(Kds).reshape(m, t.size, m).transpose(1, 0, 2)
    wmin = float(np.sqrt(np.min(np.diagonal(Ks, axis1=1, axis2=2))))
    if alpha is None:
        alpha = zeta * wmin if zeta > 0 else math.sqrt(float(np.max(np.atleast_1d(Kp))))
    alpha = float(alpha)
    if not alpha > 0:
        raise ModelError(f"alpha must be > 0 [1/s]; got {alpha}")
    I = np.eye(m)
    margin = np.zeros(t.size)
    smax = math.inf
    kbar_max = 0.0
    dmin = math.inf
    for k in range(t.size):
        Kbar = Ks[k] + alpha**2 * I - alpha * 0.5 * (Ds[k] + Ds[k].T)
        Kd_ = 0.5 * (Kds[k] + Kds[k].T)
        margin[k] = float(np.min(np.linalg.eigvalsh(2 * alpha * Kbar - Kd_)))
        kbar_max = max(kbar_max, float(np.max(np.linalg.eigvalsh(Kbar))))
        dmin = min(dmin, float(np.min(np.linalg.eigvalsh(0.5 * (Ds[k] + Ds[k].T)))) - alpha)
        # largest s with 2αK̄ − s K̇ ⪰ 0: 1 / λ_max(L⁻¹ K̇ L⁻ᵀ), 2αK̄ = L Lᵀ
        try:
            L = np.linalg.cholesky(2 * alpha * Kbar)
        except np.linalg.LinAlgError:
            smax = 0.0
            continue
        Li = np.linalg.inv(L)
        lam = float(np.max(np.linalg.eigvalsh(Li @ Kd_ @ Li.T)))
        if lam > 0:
            smax = min(smax, 1.0 / lam)
    iw = int(np.argmin(margin))
    beta = float(margin[iw])
    gamma = min(2.0 * dmin, beta / kbar_max if kbar_max > 0 else math.inf)
    return {"t": t, "margin": margin, "worst_margin": beta, "worst_time": float(t[iw]),
            "worst_q": qd[iw], "stable": bool(beta > 0), "alpha": alpha,
            "damping_condition": bool(dmin > 0), "gamma": float(gamma),
            "time_scale_max": smax}


def composite_stability(model, move, gain=None, epsilon=None, Q=1.0, R=10.0, t=None,
                        dt=1e-2, tol=1e-9):
    """Is the fast closed loop ``A_f − B_f K_f`` Hurwitz along the move (§6.2.3.1)?

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    move : casflex.moves.Move
    gain : array_like or GainSchedule or casadi.Function, optional
        Default: :func:`fast_gain` at the end of the move (the dissertation's choice).
    epsilon : float, optional
    Q, R : float or array_like
        LQR weights for the default gain.
    t : array_like, optional
    dt : float
    tol : float
        Real parts above ``−tol`` [1/s] count as not Hurwitz.

    Returns
    -------
    dict
        ``t``, ``real`` (largest real part of the fast closed-loop eigenvalues per time,
        real time [1/s]), ``worst_real``, ``worst_time``, ``worst_q``,
        ``worst_margin`` (``−worst_real``), ``stable``, ``epsilon``.

    Notes
    -----
    With the gains fixed at the end of ``control_move1`` (the dissertation's choice) the
    Table 8 model reports the fast loop unstable over the first ~0.5 s (largest real
    part +87 1/s at ``q0 = [0, 1, 6.2]``, 70 at 0.2 s, 27 at 0.4 s; 3-mode table, 15°
    grid), while gains scheduled over the grid keep it Hurwitz. This is the model, not
    the boundary-layer formula (frames, signs and the ε scaling were checked: the
    eigenvalues are invariant to ε up to the gain it implies, and ``A_f, B_f`` follow
    from ``M(q, 0)⁻¹``): independently of this function,

    * the full 12-state linearisation of the model under the composite law (finite
      differences of :func:`closed_loop`) at ``q0`` has an eigenvalue at +26 1/s with the
      end gains (+19 at 0.2 s, +8 at 0.4 s, stable from 0.6 s), −0.75 1/s with the
      schedule;
    * holding ``q0`` from a deflection of 1e-5 the state grows by ~5·10⁵ in 0.4 s with the
      end gains and stays bounded with the schedule; along move 1 the joints leave the
      plan by 5.6 rad within 0.6 s (0.04 rad with the schedule);

    (``tests/test_control.py::test_end_gains_instability_is_in_the_model_not_the_boundary_layer``).
    The cause is the small residual joint inertia of this arm, ``M_qq − M_qδ M_qδᵀ``
    (smallest eigenvalue 4.5e-4 kg·m² at ``q0``, 2.1e-5 at mid-move, against 0.016–0.26
    for ``M_qq``): ``B_f = [0; H_δq]`` is large and turns with the configuration
    (‖B_f‖ = 340 at ``q0``, 1000 at ``qf``), the LQR at ``qf`` is high-gain (fast poles
    −2025 and −1124 1/s) and the same gain with the ``B_f`` of ``q0`` has a real
    eigenvalue in the right half-plane. The dissertation's arm may differ in its motor
    inertias; for this model use :func:`gain_schedule`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, -np.pi / 2]
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None)
    >>> r = composite_stability(model, Move(q, q, 1.0), epsilon=0.15)
    >>> r["stable"]
    True
    """
    n, m = model.n, model.m
    t, qd, _, _ = _trajectory(move, t, dt)
    if isinstance(gain, GainSchedule) and epsilon is None:
        epsilon = gain.epsilon
    if epsilon is None:
        epsilon = perturbation_parameter(model)
    if gain is None:
        gain, _, _ = fast_gain(model, move.qf, Q=Q, R=R, epsilon=epsilon)
    bl = boundary_layer(model, epsilon)
    A, B = bl.map(t.size)(qd.T)
    A = np.asarray(A).reshape(2 * m, t.size, 2 * m)
    B = np.asarray(B).reshape(2 * m, t.size, n)
    if isinstance(gain, GainSchedule):
        gf = gain.function
    elif isinstance(gain, ca.Function):
        gf = gain
    else:
        gf = None
        Kc = np.asarray(gain, dtype=float)
    if gf is not None:
        Ks = np.asarray(gf.map(t.size)(qd.T)).reshape(n, t.size, 2 * m)
    real = np.zeros(t.size)
    for k in range(t.size):
        Kk = Ks[:, k, :] if gf is not None else Kc
        ev = np.linalg.eigvals(A[:, k, :] - B[:, k, :] @ Kk)
        real[k] = float(np.max(ev.real)) / float(epsilon)
    iw = int(np.argmax(real))
    return {"t": t, "real": real, "worst_real": float(real[iw]),
            "worst_margin": float(-real[iw]), "worst_time": float(t[iw]),
            "worst_q": qd[iw], "stable": bool(real[iw] < -tol), "epsilon": float(epsilon)}


# ================================================================== plotting


def plot_accessibility(axes, index, joints=(2, 3), fig=None):
    """Maps of the accessibility indexes, one panel per mode (Fig. 108–110).

    Parameters
    ----------
    axes : (array_like, array_like)
        Grid values [rad] of the two joints.
    index : array_like
        ``(m, len(axes[0]), len(axes[1]))`` from :func:`accessibility_map`.
    joints : (int, int)
        Joint numbers for the labels (1-based).
    fig : matplotlib.figure.Figure, optional

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> ax = [np.linspace(-3, 3, 4)] * 2
    >>> fig = plot_accessibility(ax, np.ones((2, 4, 4)))
    >>> len(fig.axes)
    4
    """
    import matplotlib.pyplot as plt

    index = np.asarray(index, dtype=float)
    m = index.shape[0]
    if fig is None:
        fig = plt.figure(figsize=(4.2 * m, 3.6))
    for k in range(m):
        ax = fig.add_subplot(1, m, k + 1)
        mesh = ax.pcolormesh(np.degrees(axes[1]), np.degrees(axes[0]), index[k],
                             shading="auto", cmap="viridis")
        fig.colorbar(mesh, ax=ax)
        ax.set_title(f"a{k + 1} [√kg·m]")
        ax.set_xlabel(f"q{joints[1]} [deg]")
        ax.set_ylabel(f"q{joints[0]} [deg]")
    fig.tight_layout()
    return fig
