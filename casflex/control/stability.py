"""Stability checks of the tracking laws along a move (§6.2.2–6.2.3).

Notation: ``n`` joints, ``m`` modes, ``K = diag(ω²)``, modal damping ``D``, ``C_δδ`` the
modal block of the Coriolis matrix.

How the flattened equations are read
------------------------------------
* Eq. 226: only the symmetric part of ``K̄ = K − α(C_δδ + D) + α² I`` enters the quadratic
  forms (``C_δδ`` is skew-symmetric), so the margin is
  ``λ_min(2α (K + α² I − α D) − K̇)`` along ``q_d(t)``, ``K̇ = ∂K/∂q · q̇_d`` by CasADi
  differentiation [1/s³]. Eq. 225 as printed (``D̄ = C − αI``, "α > 0 guarantees
  xᵀD̄x > 0") has a sign slip: with modal damping ``D`` the requirement is
  ``D − α I ≻ 0``, i.e. ``α < 2ζ ω_min``; :func:`inversion_stability` reports it as
  ``damping_condition``. The rate of eq. 230 is computed so that ``V̇ ≤ −γ V`` really
  holds: ``γ = min(2 λ_min(D − αI), β / λ_max(K̄))`` with ``β`` the worst margin.
* The composite law is checked through its fast loop ``A_f − B_f K_f`` (eq. 251,
  :mod:`casflex.control.perturbation`), which lives in the fast time ``t/ε``: the
  eigenvalues reported by :func:`composite_stability` are converted back to real time
  (``λ/ε`` [1/s]).

"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import choice, number
from casflex.control.perturbation import (
    GainSchedule,
    boundary_layer,
    fast_gain,
    gain_schedule,
    perturbation_parameter,
)
from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.modal.tables import ModalTable
    from casflex.model import FlexibleModel
    from casflex.moves import Move
    from casflex.robot import Robot

__all__ = [
    "inversion_stability",
    "composite_stability",
    "mass_matrix_condition",
    "mass_matrix_over_box",
    "schedule_stability",
    "check_stability",
    "slow_loop_condition",
]


def _trajectory(move, t, dt):
    if t is None:
        t = np.arange(int(round(move.duration / dt)) + 1) * dt
    t = np.atleast_1d(np.asarray(t, dtype=float))
    return (t, *move.sample(t))


def inversion_stability(model: FlexibleModel, move: Move, alpha: float | None = None,
                        Kp: ArrayLike = 1.0, t: ArrayLike | None = None,
                        dt: float = 1e-2) -> dict:
    """Stability condition of the zero dynamics (eq. 226) along a move, rate (eq. 230).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
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
        ``worst_time``, ``alpha``, ``conditions`` (one verdict per condition, see
        below), ``stable`` (true only when every condition holds), ``damping_condition``
        (``D − αI ≻ 0``, as in ``conditions``), ``gamma`` (eq. 230, [1/s]; > 0 means
        exponential stability, which needs both conditions), ``time_scale_max``
        (largest factor by which the move may be run faster, duration/s, keeping
        eq. 226; ``inf`` if unbounded).

        ``conditions`` maps a name to ``{"holds", "value", "unit", "rule"}``:
        ``"zero_dynamics_margin"`` (eq. 226: the worst margin > 0 along the move,
        [1/s³]) and ``"modal_damping"`` (eq. 225: ``λ_min(D) − α > 0`` throughout, [1/s];
        without modal damping it fails, and the zero dynamics are then not
        exponentially stable whatever eq. 226 says).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2), gravity=None)
    >>> r = inversion_stability(model, Move([0, 0, 0], [-1, 0, 0], 2.0), alpha=1.0)
    >>> r["conditions"]["zero_dynamics_margin"]["holds"], r["time_scale_max"]  # K̇ = 0
    (True, inf)
    >>> r["conditions"]["modal_damping"]["holds"], r["stable"]  # Table 8: no damping
    (False, False)
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
    alpha = number(float(alpha), "alpha", low=0.0, low_open=True)  # [1/s]
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
    conditions = {
        "zero_dynamics_margin": _verdict(
            beta > 0, beta, "1/s^3", "eq. 226: lambda_min(2 alpha Kbar - dK/dt) > 0 along "
            "the move"),
        "modal_damping": _verdict(
            dmin > 0, dmin, "1/s", "eq. 225: D - alpha I positive definite along the move "
            "(alpha < 2 zeta omega_min)"),
    }
    return {"t": t, "margin": margin, "worst_margin": beta, "worst_time": float(t[iw]),
            "worst_q": qd[iw], "stable": _all_hold(conditions), "conditions": conditions,
            "alpha": alpha, "damping_condition": bool(dmin > 0), "gamma": float(gamma),
            "time_scale_max": smax}


def _verdict(holds, value, unit, rule):
    return {"holds": bool(holds), "value": float(value), "unit": unit, "rule": rule}


def _all_hold(conditions):
    return all(c["holds"] for c in conditions.values())


def composite_stability(model: FlexibleModel, move: Move,
                        gain: ArrayLike | GainSchedule | ca.Function | None = None,
                        epsilon: float | None = None, Q: ArrayLike = 1.0, R: ArrayLike = 10.0,
                        t: ArrayLike | None = None, dt: float = 1e-2,
                        tol: float = 1e-9) -> dict:
    """Is the fast closed loop ``A_f − B_f K_f`` Hurwitz along the move (§6.2.3.1)?

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    move : casflex.moves.Move
    gain : array_like or GainSchedule or casadi.Function, optional
        Default: :func:`~casflex.control.fast_gain` at the end of the move (the
        dissertation's choice).
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
        ``worst_margin`` (``−worst_real``), ``conditions`` (``"fast_loop_hurwitz"``:
        ``{"holds", "value", "unit", "rule"}``, the value the worst real part [1/s]),
        ``stable`` (every condition holds), ``epsilon``.

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
      differences of :func:`~casflex.control.closed_loop`) at ``q0`` has an eigenvalue at
      +26 1/s with the end gains (+19 at 0.2 s, +8 at 0.4 s, stable from 0.6 s), −0.75
      1/s with the schedule;
    * holding ``q0`` from a deflection of 1e-5 the state grows by ~5·10⁵ in 0.4 s with the
      end gains and stays bounded with the schedule; along move 1 the joints leave the
      plan by 5.6 rad within 0.6 s (0.04 rad with the schedule);

    (``tests/simulate/test_torque.py::``
    ``test_end_gains_instability_is_in_the_model_not_the_boundary_layer``).
    The cause is the small residual joint inertia of this arm, ``M_qq − M_qδ M_qδᵀ``
    (smallest eigenvalue 4.5e-4 kg·m² at ``q0``, 2.1e-5 at mid-move, against 0.016–0.26
    for ``M_qq``): ``B_f = [0; H_δq]`` is large and turns with the configuration
    (‖B_f‖ = 340 at ``q0``, 1000 at ``qf``), the LQR at ``qf`` is high-gain (fast poles
    −2025 and −1124 1/s) and the same gain with the ``B_f`` of ``q0`` has a real
    eigenvalue in the right half-plane. The dissertation's arm may differ in its motor
    inertias; for this model use :func:`~casflex.control.gain_schedule`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
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
    conditions = {"fast_loop_hurwitz": _verdict(
        real[iw] < -tol, real[iw], "1/s", "§6.2.3.1: every eigenvalue of A_f - B_f K_f has "
        "a negative real part along the move")}
    return {"t": t, "real": real, "worst_real": float(real[iw]),
            "worst_margin": float(-real[iw]), "worst_time": float(t[iw]),
            "worst_q": qd[iw], "stable": _all_hold(conditions), "conditions": conditions,
            "epsilon": float(epsilon)}


def mass_matrix_condition(model: FlexibleModel, move: Move, t: ArrayLike | None = None,
                          dt: float = 1e-2) -> dict:
    """Verdict on the model's mass matrix along a move: is ``M(q, 0)`` positive definite?

    Every physical mass matrix is. The number checked is the residual joint inertia, the
    smallest eigenvalue of the Schur complement ``M_qq − M_qδ M_δδ⁻¹ M_qδᵀ`` [kg m²] (the
    inertia the joints keep when the modes follow freely). For exact mode integrals it is
    positive by Bessel's inequality; a negative value means the model's tabulated terms
    are wrong there (e.g. interpolated across a swap of two near-equal modes), and the
    boundary layer, the controller and every simulation that inverts ``M`` inherit it.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    move : casflex.moves.Move
    t : array_like, optional
        Times [s] (default the move's duration at step ``dt``).
    dt : float
        Step of the default times [s].

    Returns
    -------
    dict
        ``{"holds", "value", "unit", "rule"}`` (value: the smallest residual joint
        inertia along the move [kg m²]; when ``M_δδ`` itself is not positive definite,
        its smallest eigenvalue) plus ``"time"`` [s] and ``"q"`` [rad] where it is
        smallest.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, -np.pi / 2]
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None)
    >>> v = mass_matrix_condition(model, Move(q, q, 1.0))
    >>> v["holds"], v["unit"]
    (True, 'kg m^2')
    """
    n, m = model.n, model.m
    t, qd, _, _ = _trajectory(move, t, dt)
    M0 = ca.Function("M0", [model.q], [ca.substitute(model.M, model.delta, ca.SX.zeros(m))])
    Ms = np.asarray(M0.map(t.size)(qd.T)).reshape(n + m, t.size, n + m).transpose(1, 0, 2)
    value = np.empty(t.size)
    for k, M in enumerate(Ms):
        M = 0.5 * (M + M.T)
        low = float(np.min(np.linalg.eigvalsh(M[n:, n:]))) if m else 1.0
        if low <= 0:
            value[k] = low
            continue
        schur = M[:n, :n] - M[:n, n:] @ np.linalg.solve(M[n:, n:], M[n:, :n])
        value[k] = float(np.min(np.linalg.eigvalsh(0.5 * (schur + schur.T))))
    iw = int(np.argmin(value))
    verdict = _verdict(value[iw] > 0, value[iw], "kg m^2", "M(q, 0) positive definite along "
                       "the move: residual joint inertia M_qq - M_qd M_dd^-1 M_qd^T > 0")
    return {**verdict, "time": float(t[iw]), "q": qd[iw].tolist()}


def mass_matrix_over_box(model: FlexibleModel, table: ModalTable | None = None, *,
                         q: ArrayLike | None = None, points: int = 60,
                         max_points: int = 20000) -> dict:
    """Verdict on the model's mass matrix over the joint box of its shape joints: is
    ``M(q, 0)`` positive definite at every point and every cell centre of its grid?

    The number checked is the residual joint inertia, as in
    :func:`mass_matrix_condition`. Interpolated tables are exact at their grid points and
    worst between them (cubic B-splines overshoot where tracked modes swap), so the cell
    centres are checked too.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    table : casflex.modal.tables.ModalTable, optional
        Its grid (default the model provider's table). Without one, ``points`` uniform
        points per axis over :func:`casflex.modal.joint_box` (the joint limits, else a
        full turn).
    q : array_like, optional
        Values of the other joints [rad] (default zeros).
    points : int
        Points per axis without a table.
    max_points : int
        At most this many configurations: every axis is thinned evenly beyond it.

    Returns
    -------
    dict
        ``{"holds", "value", "unit", "rule"}`` (value: the smallest residual joint inertia
        over the configurations [kg m²]; when ``M_δδ`` itself is not positive definite,
        its smallest eigenvalue), ``"points"`` (configurations checked) and ``"q"`` [rad]
        where the value is smallest.

    Examples
    --------
    A two-mode model tabulated at four elbow angles: seven configurations checked.

    >>> from casflex.robot import load
    >>> from casflex.model import build_model
    >>> robot = load("problems/arm2link.toml")
    >>> model, _ = build_model(robot, 2, grid=[np.radians([0, 10, 20, 30])], gravity=None,
    ...                        cache_dir=False, processes=1)
    >>> v = mass_matrix_over_box(model)
    >>> v["holds"], v["points"], v["unit"]
    (True, 7, 'kg m^2')
    """
    from casflex.modal.fits import joint_box, periodic_axis_kind

    n, m = model.n, model.m
    number(points, "points", low=2, integer=True)
    number(max_points, "max_points", low=1, integer=True)
    joints = tuple(int(j) for j in model.provider.shape_joints)
    table = table if table is not None else getattr(model.provider, "table", None)
    if table is not None:
        axes = [np.asarray(a, dtype=float) for a in table.grid]
    else:
        axes = []
        for lo, hi in joint_box(model.robot, joints):
            full = abs(hi - lo - 2 * np.pi) <= 1e-9 * 2 * np.pi
            axes.append(np.linspace(lo, hi, points, endpoint=not full))
    fine = []
    for a in axes:
        mid = 0.5 * (a[:-1] + a[1:])
        if periodic_axis_kind(a) == "open":  # the cell that closes the turn
            mid = np.r_[mid, a[-1] + 0.5 * (a[0] + 2 * np.pi - a[-1])]
        fine.append(np.sort(np.r_[a, mid]))
    total = int(np.prod([a.size for a in fine])) if fine else 1
    if total > max_points:
        stride = math.ceil((total / max_points) ** (1.0 / len(fine)))
        fine = [a[::stride] for a in fine]
    base = np.zeros(n) if q is None else np.asarray(q, dtype=float).ravel()
    Q = base[None, :].copy()  # no shape joint: M is the same everywhere but for the
    if fine:                  # rigid joints, checked at q
        pts = np.array(np.meshgrid(*fine, indexing="ij")).reshape(len(fine), -1).T
        Q = np.tile(base, (pts.shape[0], 1))
        Q[:, list(joints)] = pts
    M0 = ca.Function("M0", [model.q], [ca.substitute(model.M, model.delta, ca.SX.zeros(m))])
    value = np.empty(Q.shape[0])
    for start in range(0, Q.shape[0], 2048):  # bounded memory on large boxes
        chunk = Q[start:start + 2048]
        Ms = np.asarray(M0.map(chunk.shape[0])(chunk.T)).reshape(n + m, -1, n + m)
        for k in range(chunk.shape[0]):
            M = 0.5 * (Ms[:, k, :] + Ms[:, k, :].T)
            low = float(np.min(np.linalg.eigvalsh(M[n:, n:]))) if m else 1.0
            if low <= 0:
                value[start + k] = low
                continue
            schur = M[:n, :n] - M[:n, n:] @ np.linalg.solve(M[n:, n:], M[n:, :n])
            value[start + k] = float(np.min(np.linalg.eigvalsh(0.5 * (schur + schur.T))))
    iw = int(np.argmin(value))
    verdict = _verdict(value[iw] > 0, value[iw], "kg m^2", "M(q, 0) positive definite over "
                       "the joint box (grid points and cell centres): residual joint inertia "
                       "> 0")
    return {**verdict, "points": int(Q.shape[0]), "q": Q[iw].tolist()}


def schedule_stability(model: FlexibleModel, schedule: GainSchedule, q: ArrayLike | None = None,
                       tol: float = 1e-9) -> dict:
    """The fast loop and the mass matrix checked over a gain schedule's whole grid, at the
    centres of its cells: the configurations farthest from the points the gains were
    computed at, where the interpolated gain is least like the LQR's.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    schedule : GainSchedule
        Over one or more joints (:func:`~casflex.control.gain_schedule`).
    q : array_like, optional
        Values of the joints the schedule does not cover [rad] (default zeros).
    tol : float
        Real parts above ``−tol`` [1/s] count as not Hurwitz.

    Returns
    -------
    dict
        ``conditions``: ``"fast_loop_hurwitz_cells"`` (the largest real part of the
        eigenvalues of ``A_f − B_f K(q)`` over the cell centres, real time [1/s]) and
        ``"mass_matrix_cells"`` (the smallest residual joint inertia there [kg m²], as
        :func:`mass_matrix_condition`), each ``{"holds", "value", "unit", "rule"}``;
        ``stable``; ``points`` (cell centres checked); ``worst_q`` [rad] of each.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.control import gain_schedule
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> ax = np.linspace(-np.pi, np.pi, 8, endpoint=False)
    >>> s = gain_schedule(model, epsilon=0.15, joints=(1,), grid=[ax])
    >>> r = schedule_stability(model, s)
    >>> r["points"], sorted(r["conditions"])
    (8, ['fast_loop_hurwitz_cells', 'mass_matrix_cells'])
    """
    from casflex.modal.fits import periodic_axis_kind

    n, m = model.n, model.m
    base = np.zeros(n) if q is None else np.asarray(q, dtype=float).ravel()
    centres = []
    for axis in schedule.grid:
        a = np.asarray(axis, dtype=float)
        mid = 0.5 * (a[:-1] + a[1:])
        if periodic_axis_kind(a) == "open":  # the cell that closes the turn
            mid = np.r_[mid, a[-1] + 0.5 * (a[0] + 2 * np.pi - a[-1])]
        centres.append(mid)
    pts = np.array(np.meshgrid(*centres, indexing="ij")).reshape(len(centres), -1).T
    Q = np.tile(base, (pts.shape[0], 1))
    Q[:, list(schedule.joints)] = pts
    N = Q.shape[0]
    eps = float(schedule.epsilon)
    A, B = boundary_layer(model, eps).map(N)(Q.T)
    A = np.asarray(A).reshape(2 * m, N, 2 * m)
    B = np.asarray(B).reshape(2 * m, N, n)
    K = np.asarray(schedule.function.map(N)(Q.T)).reshape(n, N, 2 * m)
    M0 = ca.Function("M0", [model.q], [ca.substitute(model.M, model.delta, ca.SX.zeros(m))])
    Ms = np.asarray(M0.map(N)(Q.T)).reshape(n + m, N, n + m)
    real = np.empty(N)
    inertia = np.empty(N)
    for k in range(N):
        real[k] = float(np.max(np.linalg.eigvals(A[:, k, :] - B[:, k, :] @ K[:, k, :]).real))
        M = 0.5 * (Ms[:, k, :] + Ms[:, k, :].T)
        schur = M[:n, :n] - M[:n, n:] @ np.linalg.solve(M[n:, n:], M[n:, :n])
        inertia[k] = float(np.min(np.linalg.eigvalsh(0.5 * (schur + schur.T))))
    real /= eps  # fast time -> real time
    iw, im = int(np.argmax(real)), int(np.argmin(inertia))
    conditions = {
        "fast_loop_hurwitz_cells": _verdict(
            real[iw] < -tol, real[iw], "1/s", "A_f - B_f K(q) Hurwitz at the centre of "
            "every cell of the gain schedule (interpolated gains)"),
        "mass_matrix_cells": _verdict(
            inertia[im] > 0, inertia[im], "kg m^2", "M(q, 0) positive definite at the "
            "centre of every cell of the gain schedule"),
    }
    return {"conditions": conditions, "stable": _all_hold(conditions), "points": N,
            "worst_q": {"fast_loop_hurwitz_cells": Q[iw].tolist(),
                        "mass_matrix_cells": Q[im].tolist()}}


def slow_loop_condition(Kp: float, Kd: float) -> dict:
    """Verdict on the reduced (rigid) loop ë + K_d ė + K_p e = 0 (Tikhonov's slow loop).

    Parameters
    ----------
    Kp : float
        Slow proportional gain [1/s²].
    Kd : float
        Slow derivative gain [1/s].

    Returns
    -------
    dict
        ``{"holds", "value", "unit", "rule"}``: ``value`` is the slowest real part of the
        roots of s² + K_d s + K_p [1/s]; the condition holds when it is negative.

    Examples
    --------
    >>> v = slow_loop_condition(1.0, 2.0)
    >>> v["holds"], round(v["value"], 6)
    (True, -1.0)
    """
    roots = np.roots([1.0, Kd, Kp])
    worst = float(np.max(roots.real))
    return _verdict(worst < 0, worst, "1/s", "Tikhonov: the slow (rigid) loop "
                    "e'' + Kd e' + Kp e = 0 is exponentially stable (Kp, Kd > 0)")


def check_stability(robot: Robot, move: Move, controller: str, n_modes: int = 3,
                    step: float = math.radians(6.0), dt: float = 1e-2, Kp: float = 1.0,
                    alpha: float | None = None, Q: float = 1.0, R: float = 10.0,
                    schedule: bool = False, Kd: float = 2.0,
                    cache_dir: str | os.PathLike | bool | None = None) -> dict:
    """Stability of a tracking law of a robot along a planned move (``casflex check``).

    Builds the model of the control studies (no gravity, ``delta_order=0``), then runs
    :func:`inversion_stability` (eq. 226) or :func:`composite_stability` (fast loop
    Hurwitz) with the LQR gains of ``Q I``, ``R I`` fixed at the end of the move or
    scheduled over the configuration grid.

    Parameters
    ----------
    robot : casflex.robot.Robot
    move : casflex.moves.Move
    controller : {"inversion", "composite"}
    n_modes : int
        Number of modes of the model.
    step : float
        Grid step of the modal tables [rad].
    dt : float
        Time step of the check along the move [s].
    Kp : float
        Slow proportional gain [1/s²] (inversion: for the default ``alpha``; composite:
        the slow loop's condition).
    alpha : float, optional
        Constant of eq. 216 [1/s] (inversion; see :func:`inversion_stability`).
    Q, R : float
        LQR weights ``Q I`` and ``R I`` (composite).
    schedule : bool
        Composite: gains scheduled over the grid (:func:`~casflex.control.gain_schedule`)
        instead of fixed at the end of the move.
    Kd : float
        Slow derivative gain [1/s] (composite: the slow loop's condition).
    cache_dir : path, None or False
        Modal-table cache (a path, ``None`` for the default, ``False`` for none).

    Returns
    -------
    dict
        ``conditions``: one verdict per condition, ``{"holds", "value", "unit",
        "rule"}`` by name; ``stable``: true only when every condition holds.
        ``mass_matrix_box``: :func:`mass_matrix_over_box` over the model's table (the
        other joints at the move's start), a diagnosis of the model's terms, not one of
        the law's conditions.
        Inversion: conditions ``zero_dynamics_margin`` (eq. 226) and ``modal_damping``
        (eq. 225), with ``worst_margin`` [1/s³], ``worst_time`` [s], ``worst_q`` [rad],
        ``alpha`` [1/s], ``gamma`` [1/s], ``damping_condition``, ``time_scale_max``.
        Composite: conditions ``slow_loop`` (the rigid loop under ``Kp``, ``Kd``) and
        ``fast_loop_hurwitz`` (§6.2.3.1), with ``worst_margin``, ``worst_time`` [s],
        ``worst_real`` [1/s], ``worst_q`` [rad], ``epsilon`` [s], ``gains``
        (``"scheduled"`` or ``"end of move"``).

    Raises
    ------
    casflex.errors.ModelError
        A move for another number of joints, ``n_modes < 1``, ``dt`` or ``step`` not
        positive, an unknown ``controller``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> robot = load("problems/arm2link.toml")
    >>> check_stability(robot, Move([0, 0], [1, 0], 1.0), "inversion")
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: move 'move' has 2 joints; robot 'arm2link' has 3
    """
    from casflex.model import build_model

    if move.n_joints != robot.n_joints:
        raise ModelError(f"move '{move.name}' has {move.n_joints} joints; robot "
                         f"'{robot.name}' has {robot.n_joints}")
    for end in ("q0", "qf"):  # bang-bang moves are monotone: the ends bound the path
        robot.within_limits(getattr(move, end), f"move '{move.name}' {end}")
    choice(controller, "controller", ("inversion", "composite"))
    number(n_modes, "n_modes", low=1, integer=True)
    number(dt, "dt", low=0.0, low_open=True)  # [s]
    number(step, "step", low=0.0, low_open=True)  # [rad]
    number(Kp, "Kp", low=0.0, low_open=True)  # [1/s²]
    number(Kd, "Kd", low=0.0, low_open=True)  # [1/s]
    model, table = build_model(robot, n_modes, step=step, gravity=None, delta_order=0,
                               cache_dir=cache_dir, progress=False)
    box = mass_matrix_over_box(model, table, q=move.q0)
    if controller == "inversion":
        r = inversion_stability(model, move, alpha=alpha, Kp=Kp, dt=dt)
        return {"stable": r["stable"], "conditions": r["conditions"],
                "worst_margin": r["worst_margin"],
                "worst_time": r["worst_time"], "worst_q": r["worst_q"],
                "alpha": r["alpha"], "gamma": r["gamma"],
                "damping_condition": r["damping_condition"],
                "time_scale_max": r["time_scale_max"], "mass_matrix_box": box}
    eps = perturbation_parameter(model, table=table)
    if schedule:
        gain = gain_schedule(model, Q=Q, R=R, epsilon=eps, table=table)
    else:
        gain, _, _ = fast_gain(model, move.qf, Q=Q, R=R, epsilon=eps)
    r = composite_stability(model, move, gain=gain, epsilon=eps, dt=dt)
    conditions = {"slow_loop": slow_loop_condition(Kp, Kd), **r["conditions"]}
    return {"stable": _all_hold(conditions), "conditions": conditions,
            "worst_margin": r["worst_margin"],
            "worst_time": r["worst_time"], "worst_real": r["worst_real"],
            "worst_q": r["worst_q"], "epsilon": eps,
            "gains": "scheduled" if schedule else "end of move", "mass_matrix_box": box}
