"""Tracking laws of flexible arms and how they close the loop (dissertation §6.2).

Every law is a ``casadi.Function`` ``(qd, dqd, ddqd, x) -> tau`` of the reference and the
model's state ``x = [q; δ; q̇; δ̇]`` (``n`` joints, ``m`` modes); :func:`tracking` closes it
over a move's reference, :func:`closed_loop` over the model's ``ode``. Notation:
``M = [[M_qq, M_qδ], [M_qδᵀ, M_δδ]]`` with ``M_qδ`` of size n × m.

How the flattened equations are read
------------------------------------
* Eq. 210 is the exact input–output linearisation of the model: from the second block row
  ``δ̈ = −M_δδ⁻¹(M_qδᵀ q̈ + h_δ)``, so ``τ = (M_qq − M_qδ M_δδ⁻¹ M_qδᵀ) v + h_q −
  M_qδ M_δδ⁻¹ h_δ`` with ``h = C Ẋ + G + D Ẋ`` (Coriolis, gravity/stiffness, modal damping).
  With ``M_δδ = I`` this is eq. 210 term by term; it is the model's ``prescribed`` form
  evaluated at ``q̈ = v`` (eq. 213).
* Eq. 232 and the slow law of eq. 248 are the same computed-torque law on the rigid model:
  ``τ = M_qq(q, 0) v + C_qq(q, q̇) q̇ + g_q(q)``.
* The composite law adds the fast LQR feedback of the boundary layer (eq. 251,
  :mod:`casflex.control.perturbation`): ``τ_f = −K_f(q) [δ/ε²; δ̇/ε]``.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.moves import Move
>>> from casflex.model import FlexibleModel, rigid_provider
>>> robot = load("problems/arm2link.toml")
>>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
>>> law = tracking(inversion_controller(model), Move([0, 0, 0], [1, 0, 0], 2.0))
>>> law.name_in(), law.name_out()
(['t', 'x'], ['tau'])
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import square_matrix
from casflex.control.perturbation import GainSchedule, perturbation_parameter
from casflex.errors import ModelError
from casflex.moves import reference_function

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move

__all__ = [
    "inversion_controller",
    "feedforward_controller",
    "composite_controller",
    "tracking",
    "closed_loop",
]


def _rigid_terms(model):
    """SX expressions of the rigid model at δ = δ̇ = 0: M_qq, C_qq q̇ and g_q."""
    n, m = model.n, model.m
    sub_in = ca.vertcat(model.delta, model.ddelta)
    zero = ca.SX.zeros(2 * m)
    Mqq = ca.substitute(model.M[:n, :n], sub_in, zero)
    # h at δ = δ̇ = 0: C_qq q̇ q̇ + g_q (stiffness, damping and C_δ terms vanish there)
    hq = ca.substitute(model.h[:n], sub_in, zero)
    return Mqq, hq


def inversion_controller(model: FlexibleModel, Kp: ArrayLike = 1.0, Kd: ArrayLike = 2.0,
                         name: str = "inversion") -> ca.Function:
    """Inversion-based tracking controller (eq. 210 with eq. 213).

    ``v = q̈_d + K_d (q̇_d − q̇) + K_p (q_d − q)`` and
    ``τ = (M_qq − M_qδ M_δδ⁻¹ M_qδᵀ) v + h_q − M_qδ M_δδ⁻¹ h_δ`` (module docstring): the
    joints then obey ``q̈ = v`` exactly and the modes are the zero dynamics (eq. 212).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
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
    >>> from casflex.model import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> ctrl = inversion_controller(model)
    >>> ctrl.name_in()
    ['qd', 'dqd', 'ddqd', 'x']
    >>> float(ca.norm_inf(ctrl([0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0, 0, 0, 0])))
    0.0
    """
    n = model.n
    Kp, Kd = square_matrix(Kp, n, "Kp"), square_matrix(Kd, n, "Kd")
    qd, dqd, ddqd = (ca.SX.sym(s, n) for s in ("qd", "dqd", "ddqd"))
    v = ddqd + Kd @ (dqd - model.dq) + Kp @ (qd - model.q)
    tau = ca.substitute(model.prescribed_tau, model.ddq, v)
    x = ca.vertcat(model.q, model.delta, model.dq, model.ddelta)
    return ca.Function(name, [qd, dqd, ddqd, x], [tau], ["qd", "dqd", "ddqd", "x"], ["tau"])


def feedforward_controller(model: FlexibleModel, Kp: ArrayLike = 1.0, Kd: ArrayLike = 2.0,
                           name: str = "feedforward") -> ca.Function:
    """Classical computed-torque law on the rigid model (eq. 232; the slow law, eq. 248).

    ``τ = M_qq(q, 0) (q̈_d + K_d (q̇_d − q̇) + K_p (q_d − q)) + C_qq(q, q̇) q̇ + g_q(q)``;
    the deflections are ignored (``g_q`` is zero for a model without gravity).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
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
    >>> from casflex.model import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> ff = feedforward_controller(model)
    >>> inv = inversion_controller(model)
    >>> args = ([0.1, 0.2, 0.3], [0.1, 0, 0], [1, 0, 0], [0, 0, 0.3, 0, 0, 0])
    >>> bool(np.allclose(ff(*args).full(), inv(*args).full()))  # identical without modes
    True
    """
    n = model.n
    Kp, Kd = square_matrix(Kp, n, "Kp"), square_matrix(Kd, n, "Kd")
    qd, dqd, ddqd = (ca.SX.sym(s, n) for s in ("qd", "dqd", "ddqd"))
    v = ddqd + Kd @ (dqd - model.dq) + Kp @ (qd - model.q)
    Mqq, hq = _rigid_terms(model)
    tau = Mqq @ v + hq
    x = ca.vertcat(model.q, model.delta, model.dq, model.ddelta)
    return ca.Function(name, [qd, dqd, ddqd, x], [tau], ["qd", "dqd", "ddqd", "x"], ["tau"])


def composite_controller(model: FlexibleModel, Kp: ArrayLike = 1.0, Kd: ArrayLike = 2.0,
                         gain: ArrayLike | GainSchedule | ca.Function | None = None,
                         epsilon: float | None = None, fast: bool = True,
                         name: str = "composite") -> ca.Function:
    """Singular-perturbation composite controller (eq. 248 + 251, §6.2.3.1).

    ``τ = τ_s + τ_f`` with the slow computed torque of eq. 248
    (:func:`feedforward_controller`) and the fast LQR feedback
    ``τ_f = −K_f(q) [δ/ε²; δ̇/ε]``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    Kp, Kd : float or array_like
        Slow gains [1/s², 1/s].
    gain : array_like or GainSchedule or casadi.Function, optional
        Fast gain: a fixed n × 2m matrix (e.g. :func:`~casflex.control.fast_gain` at the
        end of the trajectory), a :class:`~casflex.control.GainSchedule`, or a function
        ``q -> K``. Required when ``fast`` is true.
    epsilon : float, optional
        Must be the one the gain was computed with (default: the schedule's, else
        :func:`~casflex.control.perturbation_parameter`).
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
    >>> from casflex.control import fast_gain
    >>> from casflex.model import FlexibleModel, PointwiseProvider
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


def tracking(controller: ca.Function, move: Move) -> ca.Function:
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
    >>> from casflex.model import FlexibleModel, rigid_provider
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


def closed_loop(model: FlexibleModel, controller: ca.Function, move: Move) -> ca.Function:
    """Closed-loop vector field ``(t, x) -> xdot`` of the model under a tracking law.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
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
    >>> from casflex.model import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> f = closed_loop(model, inversion_controller(model), Move([0, 0, 0], [1, 0, 0], 2.0))
    >>> # v = q̈_d + Kd q̇_d + Kp q_d at t = 0.5 s
    >>> (f(0.5, np.zeros(6)).full().ravel()[3:].round(6) + 0.0).tolist()
    [2.125, 0.0, 0.0]
    """
    ode = model.functions()["ode"]
    ctrl = tracking(controller, move)
    t = ca.SX.sym("t")
    x = ca.SX.sym("x", 2 * (model.n + model.m))
    return ca.Function("closed_loop", [t, x], [ode(x, ctrl(t, x))], ["t", "x"], ["xdot"])
