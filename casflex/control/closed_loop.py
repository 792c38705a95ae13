"""Closed-loop simulation of a model under a tracking law (§6.2 studies).

The state is ``x = [q; δ; q̇; δ̇]``. The impulse disturbance (§6.2.3.2) is an impulsive tip
force ``p`` [N·s] in the base frame: ``ΔẊ = M⁻¹ J_tipᵀ p`` at the instant of the impulse.

Examples
--------
>>> r = ClosedLoopResult(t=np.zeros(1), x=np.zeros((1, 4)), tau=np.zeros((1, 1)),
...                      qd=np.zeros((1, 1)), tip=np.zeros((1, 3)),
...                      tip_rigid=np.zeros((1, 3)), n=1, m=1)
>>> r.q.shape, r.delta.shape
((1, 1), (1, 1))
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from casflex.control.laws import reference_function
from casflex.errors import ModelError, SolverError

__all__ = ["ClosedLoopResult", "simulate_closed_loop"]


def _functions(model):
    """``model.functions()``, built once per model."""
    return model.functions()


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
    model : casflex.model.FlexibleModel
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
    >>> from casflex.control import inversion_controller
    >>> from casflex.model import FlexibleModel, PointwiseProvider
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
