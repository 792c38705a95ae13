"""One C function for the real-time loop: estimator and controller in a single call.

:func:`rt_step_function` combines an EKF step (:func:`casflex.estimation.ekf_step_function`)
and a tracking controller (:mod:`casflex.control`) into ``rt_step``; :func:`rt_bundle`
generates its C bundle (:mod:`casflex.codegen`). One call per sample ``t_k``::

    rt_step(x[2m], P[2m x 2m], dq_prev[n], q[n], dq[n], qd[n], dqd[n], ddqd[n], y[r],
            mask[r] (, f[4r]))
        -> tau[n], x_next[2m], P_next[2m x 2m], dq_next[n], x_post[2m] (, f_next[4r])

1. the joint acceleration the EKF needs (``u = [q; q̇; q̈]``, eq. 158) is the backward
   difference of the joint rates, ``q̈_k = (q̇_k − q̇_{k−1}) / dt`` (encoders and
   tachometers give ``q`` and ``q̇`` only; the dissertation differentiates the encoder
   signal, §5.6);
2. the EKF updates the prior ``(x, P)`` with the accelerometer sample ``y`` (``mask``: 1
   valid, 0 missing) and predicts the next prior ``(x_next, P_next)``;
3. the controller computes the torque from the reference and ``[q; δ̂; q̇; δ̂̇]`` with the
   filtered estimate ``x_post`` = ``x̂_{k|k}``.

The state carried from one call to the next is ``(x, P, dq_prev)`` (feed ``x_next``,
``P_next``, ``dq_next`` back); start with ``dq_prev = dq`` of the first sample. This is
exactly the loop of :func:`casflex.simulate.simulate_closed_loop` with
``estimator={..., "ddq": "difference"}``.

Guarded ``rt_step``
-------------------
With a guarded EKF step (``ekf_step_function(..., guard=Guard(P0))``,
:mod:`casflex.estimation.guard`) and per-joint ``torque_limits``, ``rt_step`` survives
bad samples and always returns finite torques within the limits::

    rt_step(x, P, dq_prev, q, dq, qd, dqd, ddqd, y, mask (, f), q_prev[n], tau_prev[n])
        -> tau, x_next, P_next, dq_next, x_post (, f_next), q_next[n], status

* a non-finite encoder reading (``q`` or ``dq``) is replaced by the last valid one
  (``q_prev``, ``dq_prev``; feed ``q_next``, ``dq_next`` back; ``q̈ = 0`` for that
  sample) by the EKF's own input hold, which reports ``STATUS_INPUT_HELD`` and restarts
  ``P`` from ``P_reset`` (``STATUS_COVARIANCE_RESET``);
* a non-finite torque of the controller (e.g. from a non-finite reference) is replaced
  by the previous torque ``tau_prev`` (feed ``tau`` back; 0 for the first call), status
  ``STATUS_TORQUE_HELD``: a drive that keeps its last command is the least surprising
  reaction for one bad sample — the loop must act on the status if it persists;
* every torque is clipped to ``[−limit_j, limit_j]`` [N·m] (``STATUS_TORQUE_CLIPPED``);
  the limits are constants of the generated code, given when the bundle is generated
  (:func:`rt_bundle`, ``torque_limits``);
* the EKF's own checks (samples, gating, covariance) and status bits as in
  :mod:`casflex.estimation.guard`; the status word is their sum (disjoint bits).

Closing the loop in C
---------------------
:func:`loop_step_function` wraps ``rt_step`` with the plant: the sensor sample at
``t_k`` (the kinematic accelerometer model with the plant's accelerations just before
``t_k``, under the torque of the previous sample, plus given noise), ``rt_step``, and
``substeps`` RK4 steps of the model's ``ode`` under the held torque. Its C code runs in
the :func:`casflex.codegen.run_harness` program with the plant state, the previous torque
and the estimator state fed back (:func:`run_closed_loop_c`): the whole closed loop runs
in C, with the reference and the noise read from the data file.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> from casflex.sensors import SensorSet, Accelerometer
>>> from casflex.estimation import tabulate_plant, ekf_step_function
>>> from casflex import control
>>> robot = load("problems/arm2link.toml")
>>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
...                       gravity=None, delta_order=0)
>>> ekf = ekf_step_function(tabulate_plant(model, check=False), ss, 5e-6, 6e-6, 1e-3)
>>> f = rt_step_function(ekf, control.inversion_controller(model), 1e-3)
>>> f.name_out()
['tau', 'x_next', 'P_next', 'dq_next', 'x_post']
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._json import jsonable
from casflex._validate import choice, number, vector
from casflex.codegen.bundle import Bundle, generate
from casflex.codegen.estimator import add_status_defines, ekf_units
from casflex.codegen.replay import run_harness
from casflex.errors import ModelError
from casflex.estimation import guard as gd
from casflex.simulate.integrators import rk4_step

if TYPE_CHECKING:
    from casflex.control import GainSchedule
    from casflex.model import FlexibleModel
    from casflex.moves import Move
    from casflex.sensors import SensorSet

__all__ = [
    "make_controller",
    "rt_step_function",
    "rt_units",
    "rt_bundle",
    "loop_step_function",
    "closed_loop_bundle",
    "run_closed_loop_c",
]

_CONTROLLERS = ("composite", "inversion")


def make_controller(model: FlexibleModel, kind: str, Kp: ArrayLike = 1.0, Kd: ArrayLike = 2.0,
                    Q: ArrayLike = 1.0, R: ArrayLike = 10.0,
                    gain: ArrayLike | GainSchedule | None = None,
                    epsilon: float | None = None, schedule_points: int = 30,
                    cache_dir: str | os.PathLike | bool | None = None) -> ca.Function:
    """The controller of the real-time loop by name.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    kind : {"composite", "inversion"}
        ``"composite"``: :func:`casflex.control.composite_controller` with the fast
        gains scheduled over the configuration grid (B-spline interpolated, so they
        code-generate) unless ``gain`` is given: for a model with a modal table, a
        full-turn axis of ``schedule_points`` points per scheduled joint, cached on disk
        (:func:`casflex.control.cached_gain_schedule`, as the design job does); else
        :func:`casflex.control.gain_schedule` on its default grid;
        ``"inversion"``: :func:`casflex.control.inversion_controller`.
    Kp, Kd : float or array_like
        Joint gains [1/s², 1/s].
    Q, R : float or array_like
        LQR weights of the fast part (composite).
    gain : array_like or casflex.control.GainSchedule, optional
        Fast gain instead of the schedule (composite).
    epsilon : float, optional
        Perturbation parameter [s] (default :func:`casflex.control.perturbation_parameter`).
    schedule_points : int
        Points of the schedule's full-turn axis per scheduled joint (composite, model with
        a table; default 30, the design studies' ``controller.schedule_points``). The
        table's own grid (240 points per joint for the Table 8 arm) would mean 57 600 LQR
        solutions and a 31 MB C source for gains that vary smoothly.
    cache_dir : str, os.PathLike or False, optional
        Cache directory of the schedule (default ``$CASFLEX_CACHE``, else
        ``~/.cache/casflex``; ``False``: none).

    Returns
    -------
    casadi.Function
        ``(qd, dqd, ddqd, x) -> tau`` [N·m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, rigid_provider
    >>> model = FlexibleModel(load("problems/arm2link.toml"), rigid_provider(
    ...     load("problems/arm2link.toml")), gravity=None)
    >>> make_controller(model, "inversion").name()
    'inversion'
    >>> make_controller(model, "pid")
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: controller = 'pid': must be one of 'composite', 'inversion'
    """
    from casflex import control

    choice(kind, "controller", _CONTROLLERS)
    if kind == "inversion":
        return control.inversion_controller(model, Kp=Kp, Kd=Kd)
    if gain is None:
        table = getattr(model.provider, "table", None)
        if table is None:
            gain = control.gain_schedule(model, Q=Q, R=R, epsilon=epsilon)
        else:
            points = number(schedule_points, "schedule_points", low=8, integer=True)
            if epsilon is None:
                epsilon = control.perturbation_parameter(model, table=table)
            axis = -np.pi + 2.0 * np.pi * np.arange(points) / points
            gain = control.cached_gain_schedule(model, jsonable(Q), jsonable(R), epsilon,
                                                table, axis, cache_dir)
    return control.composite_controller(model, Kp=Kp, Kd=Kd, gain=gain, epsilon=epsilon)


def rt_step_function(ekf_step: ca.Function, controller: ca.Function, dt: float,
                     name: str = "rt_step", *,
                     torque_limits: ArrayLike | None = None) -> ca.Function:
    """Estimator and controller in one SX function (module docstring).

    Parameters
    ----------
    ekf_step : casadi.Function
        ``(x, P, u, y, mask[, f]) -> (x_next, P_next, x_post[, f_next])`` from
        :func:`casflex.estimation.ekf_step_function` (plain or square-root form, with or
        without prefilter; the covariance ports keep their names, ``P`` or ``S``).
    controller : casadi.Function
        ``(qd, dqd, ddqd, x) -> tau`` with ``x = [q; δ; q̇; δ̇]``.
    dt : float
        Sample time [s] (the backward difference of the joint rates).
    name : str
    torque_limits : float or array_like, optional
        Per-joint torque limits [N·m] (positive; a scalar for all joints). Required with
        a guarded ``ekf_step`` (one with the input ``u_last``), which makes the guarded
        ``rt_step`` of the module docstring; not allowed without.

    Returns
    -------
    casadi.Function
        Inputs ``x, P, dq_prev, q, dq, qd, dqd, ddqd, y, mask[, f]``; outputs ``tau,
        x_next, P_next, dq_next, x_post[, f_next]`` (``dq_next`` = ``dq``). Guarded:
        inputs ``q_prev, tau_prev`` and outputs ``q_next, status`` appended.

    Raises
    ------
    ModelError
        Sizes of the EKF and of the controller do not fit, ``dt <= 0``, or
        ``torque_limits`` missing for a guarded step (given for an unguarded one).

    Examples
    --------
    A toy "EKF" (one joint, one mode) that adds q̈ to its state, and a controller
    ``τ = q + 10 δ̂``:

    >>> x, P, u = ca.SX.sym("x", 2), ca.SX.sym("P", 2, 2), ca.SX.sym("u", 3)
    >>> y, k = ca.SX.sym("y"), ca.SX.sym("k")
    >>> ekf = ca.Function("e", [x, P, u, y, k], [x + u[2], P, x],
    ...                   ["x", "P", "u", "y", "mask"], ["x_next", "P_next", "x_post"])
    >>> q = [ca.SX.sym(s) for s in ("qd", "dqd", "ddqd")]
    >>> xc = ca.SX.sym("xc", 4)
    >>> ctrl = ca.Function("c", [*q, xc], [xc[0] + 10 * xc[1]])
    >>> f = rt_step_function(ekf, ctrl, 0.5)
    >>> out = f([0.1, 0.0], np.eye(2), 1.0, 2.0, 2.0, 0, 0, 0, 0, 1)  # q̈ = (2 − 1)/0.5
    >>> [np.asarray(v).ravel().tolist() for v in (out[0], out[1], out[3], out[4])]
    [[3.0], [2.1, 2.0], [2.0], [0.1, 0.0]]
    """
    dt = number(dt, "dt", low=0.0, low_open=True)
    nx = ekf_step.size1_in(0)
    n = controller.size1_in(0)
    m = nx // 2
    if ekf_step.size1_in(2) != 3 * n or controller.size1_in(3) != 2 * (n + m):
        raise ModelError(f"rt_step_function: the EKF takes u of {ekf_step.size1_in(2)} and "
                         f"x of {nx} values, the controller {n} joints and a state of "
                         f"{controller.size1_in(3)}; they must be 3n, 2m and 2(n + m)")
    guarded = "u_last" in ekf_step.name_in()
    if guarded != (torque_limits is not None):
        raise ModelError("rt_step_function: torque_limits must be given with a guarded "
                         "ekf_step (guard=Guard(...)) and only with one")
    if guarded:
        lim = np.asarray(torque_limits, dtype=float).ravel()
        torque_limits = vector(np.full(n, lim[0]) if lim.size == 1 else lim, n,
                               "torque_limits")
        if not np.all(torque_limits > 0) or not np.all(np.isfinite(torque_limits)):
            raise ModelError(f"torque_limits = {torque_limits.tolist()}: must be positive "
                             "finite torques [N m]")
    cov = ekf_step.name_in(1)
    x = ca.SX.sym("x", nx)
    P = ca.SX.sym(cov, ekf_step.size1_in(1), ekf_step.size2_in(1))
    dq_prev, q, dq, qd, dqd, ddqd = (ca.SX.sym(s, n) for s in
                                     ("dq_prev", "q", "dq", "qd", "dqd", "ddqd"))
    r = ekf_step.size1_in(3)
    y, mask = ca.SX.sym("y", r), ca.SX.sym("mask", r)
    extra = [ca.SX.sym("f", ekf_step.size1_in("f"))] if "f" in ekf_step.name_in() else []
    if guarded:
        # the EKF holds a non-finite entry of u at u_last (and reports it, restarting P):
        # q, q̇ at their last valid values, q̈ = 0 (its backward difference is unknown)
        q_prev, tau_prev = ca.SX.sym("q_prev", n), ca.SX.sym("tau_prev", n)
        u = ca.vertcat(q, dq, (dq - dq_prev) / dt)
        outs = ekf_step(x, P, u, y, mask, *extra, ca.vertcat(q_prev, dq_prev, ca.SX.zeros(n)))
        u_held = outs[ekf_step.index_out("u_next")]
        q_in, dq_in = u_held[:n], u_held[n:2 * n]
    else:
        q_in, dq_in = q, dq
        u = ca.vertcat(q, dq, (dq - dq_prev) / dt)
        outs = ekf_step(x, P, u, y, mask, *extra)
    xn, Pn, xp = outs[:3]
    xc = ca.vertcat(q_in, xp[:m], dq_in, xp[m:])
    tau = controller(qd, dqd, ddqd, xc)
    ins = [x, P, dq_prev, q, dq, qd, dqd, ddqd, y, mask, *extra]
    names_in = ["x", cov, "dq_prev", "q", "dq", "qd", "dqd", "ddqd", "y", "mask"]
    names_in += ["f"] if extra else []
    res = [tau, xn, Pn, dq_in, xp] + ([outs[3]] if extra else [])
    names_out = ["tau", "x_next", cov + "_next", "dq_next", "x_post"]
    names_out += ["f_next"] if extra else []
    if guarded:
        tau, flags = _safe_torque(tau, tau_prev, torque_limits)
        status_ekf = outs[ekf_step.index_out("status")]
        res[0] = tau
        ins += [q_prev, tau_prev]
        names_in += ["q_prev", "tau_prev"]
        res += [q_in, status_ekf + sum(gd.STATUS_BITS[k] * v for k, v in flags.items())]
        names_out += ["q_next", "status"]
    return ca.Function(name, ins, res, names_in, names_out, {"cse": True})


def _safe_torque(tau, tau_prev, limits):
    """Finite torques within ``±limits``: a non-finite one is the previous (0 if that
    is not finite either), then all are clipped; the flags of both."""
    n = tau.numel()
    before, _ = gd.held(tau_prev, ca.DM.zeros(n))
    ok = gd.is_finite(tau)
    held = ca.vertcat(*[ca.if_else(ok[i], tau[i], before[i]) for i in range(n)])
    lim = ca.DM(limits)
    out = ca.fmin(ca.fmax(held, -lim), lim)
    clipped = gd.any_of([ca.fabs(held[i]) > limits[i] for i in range(n)])
    return out, {"torque_held": gd.any_of([1 - ok[i] for i in range(n)]),
                 "torque_clipped": clipped}


def rt_units(sensors: SensorSet, cov: str = "P",
             guarded: bool = False) -> dict[str, dict[str, str]]:
    """Units of the ``rt_step`` ports for the bundle README.

    Parameters
    ----------
    sensors : casflex.sensors.SensorSet
        The signals' unit comes from the sensor kinds.
    cov : {"P", "S"}
        Name of the covariance port (``"S"``: square-root form).
    guarded : bool
        Add the ports of the guarded ``rt_step`` (module docstring).

    Returns
    -------
    dict
        ``{"rt_step": {port: unit}}``.

    Examples
    --------
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> rt_units(SensorSet([Accelerometer(2, 1.0)]))["rt_step"]["tau"]
    'N m'
    """
    e = ekf_units(sensors)["ekf_step"]
    xu = e["x"]
    more = {"q_prev": "rad", "q_next": "rad", "tau_prev": "N m",
            "status": "status bits (CASFLEX_STATUS_*), cast to int"} if guarded else {}
    return {"rt_step": {**more, "x": xu, "x_next": xu, "x_post": xu, "y": e["y"],
                        "mask": e["mask"], "dq_prev": "rad/s", "dq_next": "rad/s",
                        "q": "rad", "dq": "rad/s", "qd": "rad", "dqd": "rad/s",
                        "ddqd": "rad/s^2", "tau": "N m",
                        cov: "covariance of x" if cov == "P" else "square root of P",
                        cov + "_next": "covariance of x_next" if cov == "P"
                        else "square root of P_next"}}


def rt_bundle(ekf_step: ca.Function, controller: ca.Function, sensors: SensorSet, dt: float,
              out_dir: str | os.PathLike, *, name: str = "casflex_rt",
              extra: Sequence[ca.Function] = (),
              torque_limits: ArrayLike | None = None) -> Bundle:
    """Generate the C bundle of ``rt_step`` (and optionally other functions).

    With a guarded ``ekf_step`` the header also defines the status bits
    (``CASFLEX_STATUS_*``) and the torque limits (``CASFLEX_TORQUE_LIMIT_<j>``).

    Parameters
    ----------
    ekf_step, controller, dt
        As for :func:`rt_step_function`.
    sensors : casflex.sensors.SensorSet
        For the units.
    out_dir : str or pathlib.Path
    name : str
        Bundle name.
    extra : sequence of casadi.Function
        More functions for the same bundle (e.g. the controller alone).
    torque_limits : float or array_like, optional
        Per-joint torque limits [N·m] of a guarded ``rt_step``
        (:func:`rt_step_function`); they become constants of the generated code.

    Returns
    -------
    casflex.codegen.Bundle

    Examples
    --------
    >>> import tempfile
    >>> x, P, u = ca.SX.sym("x", 2), ca.SX.sym("P", 2, 2), ca.SX.sym("u", 3)
    >>> y, k = ca.SX.sym("y"), ca.SX.sym("k")
    >>> ekf = ca.Function("e", [x, P, u, y, k], [x + u[2], P, x],
    ...                   ["x", "P", "u", "y", "mask"], ["x_next", "P_next", "x_post"])
    >>> q = [ca.SX.sym(s) for s in ("qd", "dqd", "ddqd")]
    >>> xc = ca.SX.sym("xc", 4)
    >>> ctrl = ca.Function("c", [*q, xc], [xc[0]])
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> b = rt_bundle(ekf, ctrl, SensorSet([Accelerometer(2, 1.0, axes="x")]), 1e-3,
    ...               tempfile.mkdtemp())
    >>> [f.name for f in b.functions], b.function("rt_step").outputs[0].unit
    (['rt_step'], 'N m')
    """
    f = rt_step_function(ekf_step, controller, dt, torque_limits=torque_limits)
    guarded = "status" in f.name_out()
    units = rt_units(sensors, cov=ekf_step.name_in(1), guarded=guarded)
    if "f" in ekf_step.name_in():
        units["rt_step"].update({"f": "prefilter state", "f_next": "prefilter state"})
    bundle = generate([f, *extra], out_dir, name=name, units=units)
    if guarded:
        limits = np.broadcast_to(np.asarray(torque_limits, float), (f.size1_in("q"),))
        add_status_defines(bundle, limits)
    return bundle


def loop_step_function(model: FlexibleModel, sensors: SensorSet, rt_step: ca.Function,
                       dt: float, substeps: int = 1, name: str = "rt_loop_step") -> ca.Function:
    """One sample of the closed loop: plant, sensors and ``rt_step`` (module docstring).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The plant (its ``ode``), built with ``points=sensors.points``.
    sensors : casflex.sensors.SensorSet
    rt_step : casadi.Function
        From :func:`rt_step_function` (plain EKF form, no prefilter).
    dt : float
        Sample time [s].
    substeps : int
        RK4 steps of the plant per sample.
    name : str

    Returns
    -------
    casadi.Function
        An MX function (the model's ``ode`` and ``rt_step`` are called, not inlined, so
        their C code appears once): inputs ``xs`` (plant state ``[q; δ; q̇; δ̇]``),
        ``tau_prev``, ``x``, ``P``, ``dq_prev``, ``qd``, ``dqd``, ``ddqd``, ``noise`` (added
        to the exact signals), ``mask``; outputs ``xs_next``, ``tau``, ``x_next``,
        ``P_next``, ``dq_next``, ``x_post``, ``y``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> from casflex.estimation import tabulate_plant, ekf_step_function
    >>> from casflex import control
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None, delta_order=0)
    >>> ekf = ekf_step_function(tabulate_plant(model, check=False), ss, 5e-6, 6e-6, 1e-3)
    >>> rt = rt_step_function(ekf, control.inversion_controller(model), 1e-3)
    >>> loop_step_function(model, ss, rt, 1e-3).name_out()[:2]
    ['xs_next', 'tau']
    """
    from casflex.sensors import kinematic_measurement

    n, m = model.n, model.m
    if rt_step.n_in() != 10 or rt_step.size1_in(3) != n or rt_step.size1_in(0) != 2 * m:
        raise ModelError("loop_step_function: rt_step must be the plain form (10 inputs, "
                         f"no prefilter) for {n} joints and {m} modes")
    substeps = number(substeps, "substeps", low=1, integer=True)
    ode = model.functions()["ode"]
    kin = kinematic_measurement(model, sensors)
    r = sensors.n_outputs
    nx = 2 * (n + m)
    xs = ca.MX.sym("xs", nx)
    tau_prev = ca.MX.sym("tau_prev", n)
    x = ca.MX.sym("x", 2 * m)
    P = ca.MX.sym("P", 2 * m, 2 * m)
    dq_prev, qd, dqd, ddqd = (ca.MX.sym(s, n) for s in ("dq_prev", "qd", "dqd", "ddqd"))
    noise, mask = ca.MX.sym("noise", r), ca.MX.sym("mask", r)
    q, d, dq, dd = xs[:n], xs[n:n + m], xs[n + m:nx - m], xs[nx - m:]
    acc = ode(xs, tau_prev)[n + m:]  # accelerations just before t_k
    y = kin(ca.vertcat(d, dd), ca.vertcat(q, dq, acc[:n]), acc[n:]) + noise
    tau, xn, Pn, dqn, xp = rt_step(x, P, dq_prev, q, dq, qd, dqd, ddqd, y, mask)
    h = float(dt) / substeps
    xnext = xs
    for _ in range(substeps):
        xnext = rk4_step(ode, xnext, h, tau)  # torque held over the sample
    return ca.Function(name, [xs, tau_prev, x, P, dq_prev, qd, dqd, ddqd, noise, mask],
                       [xnext, tau, xn, Pn, dqn, xp, y],
                       ["xs", "tau_prev", "x", "P", "dq_prev", "qd", "dqd", "ddqd", "noise",
                        "mask"],
                       ["xs_next", "tau", "x_next", "P_next", "dq_next", "x_post", "y"])


def closed_loop_bundle(model: FlexibleModel, sensors: SensorSet, rt_step: ca.Function,
                       dt: float, out_dir: str | os.PathLike, *, substeps: int = 1,
                       name: str = "casflex_rtloop") -> Bundle:
    """Generate the bundle of :func:`loop_step_function` (plant + sensors + ``rt_step``).

    Parameters
    ----------
    model, sensors, rt_step, dt, substeps
        As for :func:`loop_step_function`.
    out_dir : str or pathlib.Path
    name : str
        Bundle name.

    Returns
    -------
    casflex.codegen.Bundle
        With the one function ``rt_loop_step`` (run it with :func:`run_closed_loop_c`).

    Examples
    --------
    >>> import tempfile
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> from casflex.estimation import tabulate_plant, ekf_step_function
    >>> from casflex import control
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None, delta_order=0)
    >>> ekf = ekf_step_function(tabulate_plant(model, check=False), ss, 5e-6, 6e-6, 1e-3)
    >>> rt = rt_step_function(ekf, control.inversion_controller(model), 1e-3)
    >>> closed_loop_bundle(model, ss, rt, 1e-3, tempfile.mkdtemp()).functions[0].name
    'rt_loop_step'
    """
    f = loop_step_function(model, sensors, rt_step, dt, substeps=substeps)
    return generate([f], out_dir, name=name)


_FEEDBACK = {"xs_next": "xs", "tau": "tau_prev", "x_next": "x", "P_next": "P",
             "dq_next": "dq_prev"}


def run_closed_loop_c(bundle: Bundle, move: Move, steps: int, dt: float, *,
                      x0: ArrayLike | None = None, xhat0: ArrayLike | None = None,
                      P0: ArrayLike | None = None, noise: ArrayLike | None = None,
                      repeat: int = 1, flags: Sequence[str] = ("-O1",),
                      compiler: str | Sequence[str] | None = None) -> dict:
    """Run the closed loop in C (the harness of ``rt_loop_step``) over a move.

    Parameters
    ----------
    bundle : casflex.codegen.Bundle
        From :func:`closed_loop_bundle`.
    move : casflex.moves.Move
        Reference, sampled at ``t_k = k dt`` (:meth:`casflex.moves.Move.sample`).
    steps : int
        Number of samples ``N``.
    dt : float
    x0 : array_like, optional
        Plant state ``[q; δ; q̇; δ̇]`` at ``t_0`` (default at rest at ``move.q0``).
    xhat0, P0 : array_like, optional
        EKF prior (default 0 and ``1e-4 I``, as :func:`casflex.simulate.simulate_closed_loop`).
    noise : array_like, optional
        ``(N, r)`` noise added to the signals (default none).
    repeat : int
        Repetitions of the whole run (timing).
    flags, compiler
        As for :func:`casflex.codegen.build`.

    Returns
    -------
    dict
        ``t`` (N + 1), ``x`` (N + 1, 2(n+m)) plant states, ``tau`` (N, n), ``x_hat``
        (N, 2m) filtered estimates, ``y`` (N, r) signals, ``timing`` (harness JSON: the
        median time of one closed-loop sample inside C, plant included).

    Examples
    --------
    >>> import tempfile
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> from casflex.estimation import tabulate_plant, ekf_step_function
    >>> from casflex import control
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None, delta_order=0)
    >>> ekf = ekf_step_function(tabulate_plant(model, check=False), ss, 5e-6, 6e-6, 1e-3)
    >>> rt = rt_step_function(ekf, control.inversion_controller(model), 1e-3)
    >>> b = closed_loop_bundle(model, ss, rt, 1e-3, tempfile.mkdtemp())
    >>> r = run_closed_loop_c(b, Move([0, 0, 0], [0.1, 0, 0], 0.2), 300, 1e-3,
    ...                       flags=("-O0",))
    >>> r["x"].shape, bool(abs(r["x"][-1, 0] - 0.1) < 5e-3)   # q1 near 0.1 rad
    ((301, 8), True)
    """
    info = bundle.function("rt_loop_step")
    nx = info.inputs[0].rows
    n = info.inputs[1].rows
    m2 = info.inputs[2].rows
    r = info.inputs[8].rows
    steps = number(steps, "steps", low=1, integer=True)
    t = np.arange(steps + 1) * float(dt)
    qd, dqd, ddqd = move.sample(t[:-1])
    if x0 is None:
        x0 = np.r_[move.q0, np.zeros(nx - n)]
    x0 = vector(x0, nx, "x0")
    noise = np.zeros((steps, r)) if noise is None else np.asarray(noise, dtype=float)
    if noise.shape != (steps, r):
        raise ModelError(f"run_closed_loop_c: noise must have shape {(steps, r)}; got "
                         f"{noise.shape}")
    initial = {"xs": x0, "tau_prev": np.zeros(n),
               "x": np.zeros(m2) if xhat0 is None else np.asarray(xhat0, dtype=float),
               "P": 1e-4 * np.eye(m2) if P0 is None else np.asarray(P0, dtype=float),
               "dq_prev": x0[n + m2 // 2:2 * n + m2 // 2]}
    res = run_harness(bundle, "rt_loop_step",
                      {"qd": qd, "dqd": dqd, "ddqd": ddqd, "noise": noise,
                       "mask": np.ones((steps, r))},
                      initial, feedback=_FEEDBACK, repeat=repeat, flags=flags,
                      compiler=compiler)
    out = res.outputs
    return {"t": t, "x": np.vstack([x0, out["xs_next"]]), "tau": out["tau"],
            "x_hat": out["x_post"], "y": out["y"], "timing": res.timing}
