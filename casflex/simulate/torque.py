"""Torque-driven motion: forward dynamics of ``x = [q; δ; q̇; δ̇]`` under a torque law.

One machinery integrates the model's forward dynamics for both front ends:

* :func:`simulate_torque` — a law ``τ = u(t, x)`` (a callable, a ``casadi.Function``, a
  constant) held over each step, with an optional generalized disturbance force;
* :func:`simulate_closed_loop` — a tracking controller ``(qd, dqd, ddqd, x) -> τ`` on a
  move: continuous (CVODES or RK4 with substeps) or sampled (zero-order hold), with an
  impulsive tip force and optionally an EKF between the plant and the controller.

The machinery: :func:`~casflex.simulate.integrators.rk4_interval` (RK4 substeps over one
sample with the one :func:`~casflex.simulate.integrators.rk4_step`), :func:`impulse_jump`
(the state after an impulsive tip force), and three runners — a ``mapaccum`` of a
symbolic sample step over the grid (split at the impulse), a loop over the samples for
laws that run in Python (callables, an estimator step that is not a ``casadi.Function``),
and an adaptive CasADi integrator restarted at the switches. With an EKF in the loop the
sample step (measurements, EKF update, controller, plant RK4) is one Function whose
carried state holds the filter's prior and covariance, optionally compiled to C.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from typing import TYPE_CHECKING, NamedTuple

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.moves import reference_function
from casflex.simulate.integrators import (
    call_buffered,
    casadi_integrator,
    integrate,
    rk4_interval,
    rk4_step,
    step_cache,
    time_grid,
)
from casflex.simulate.results import (
    DIVERGED_DEFLECTION,
    ClosedLoopResult,
    SimulationResult,
    check_divergence,
    robot_reach,
    tip_positions,
)

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move, ShapedMove

__all__ = ["simulate_torque", "simulate_closed_loop", "start_closed_loop", "impulse_jump"]

#: a torque law of :func:`simulate_torque`: ``u(t, x)``, a ``casadi.Function`` of
#: ``(t, x)``, constant torques or ``None`` (zero)
TorqueLaw = Callable | ca.Function | ArrayLike | None

METHODS = ("rk4", "cvodes", "idas")

#: compiler flags of a compiled sample step (``jit=True``): ``-O1`` keeps the compile of
#: a large step short; the vectorizer packs the generated code's element-wise loops (the
#: tables' B-spline sums, copies) into SIMD instructions. Without ``-ffast-math`` it
#: reorders no floating-point operation, so the numbers are those of ``-O1`` bit for bit
#: (tested); the design job's loop with the EKF ran 33-40 → 19-23 µs a sample (x86-64,
#: GCC 12, measured side by side).
JIT_FLAGS = ("-O1", "-ftree-vectorize")

# ---------------------------------------------------------------------------- machinery


def impulse_jump(model: FlexibleModel, x: np.ndarray, p: ArrayLike) -> np.ndarray:
    """State after an impulsive tip force ``p`` [N·s] (base frame): ``ΔẊ = M⁻¹ J_tipᵀ p``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    x : numpy.ndarray
        State ``[q; δ; q̇; δ̇]`` before the impulse.
    p : array_like, shape (3,)
        Impulse [N·s].

    Returns
    -------
    numpy.ndarray
        The state after it (the rates jump, the positions do not).

    Examples
    --------
    >>> from casflex.model import FlexibleModel, rigid_provider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> x = impulse_jump(model, np.zeros(6), [0.0, 0.0, 0.0])
    >>> x.tolist()
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    """
    n, m = model.n, model.m
    f = model.functions()
    q, d = x[:n], x[n:n + m]
    J = ca.jacobian(model.tip, model.X)
    Jf = ca.Function("tip_jacobian", [model.q, model.delta], [J])
    M = f["mass"](q, d).full()
    dX = np.linalg.solve(M, Jf(q, d).full().T @ np.asarray(p, dtype=float))
    out = x.copy()
    out[n + m:] += dX
    return out


def _impulse_index(impulse, t):
    """Sample index of an impulse ``(t_d, p)`` (``None`` without one)."""
    if impulse is None:
        return None
    kd = int(round(float(impulse[0]) / (t[1] - t[0])))
    if not 0 <= kd <= t.size - 1:
        raise ModelError(f"impulse time {impulse[0]} s lies outside the run "
                         f"[0, {t[-1]}] s")
    return kd


def _run_mapaccum(step, x0, t, kd=None, jump=None, repeat_last=True):
    """States and torques on the grid from ``step (x_k, t_k) -> (x_{k+1}, τ_k)``, one
    ``mapaccum`` call per segment; the state at sample ``kd`` is replaced by
    ``jump(x)``. The torque at the last sample repeats the previous one
    (``repeat_last``) or is the step's at that sample."""
    N = t.size - 1
    segments = [(0, N)] if kd is None else [(0, kd), (kd, N)]
    X, U = [x0[None]], []
    xc = x0
    for i, (k0, k1) in enumerate(segments):
        if i == 1:
            xc = jump(xc)
            X[-1] = np.vstack([X[-1][:-1], xc[None]])  # the state at t_d: after the jump
        if k1 > k0:
            Xs, Us = step.mapaccum("run", k1 - k0)(xc, t[k0:k1][None, :])
            Xs, Us = np.asarray(Xs).T, np.asarray(Us).T
            X.append(Xs)
            U.append(Us)
            xc = Xs[-1]
    X = np.vstack(X)
    last = U[-1][-1:] if repeat_last else np.asarray(step(X[-1], t[-1])[1]).T
    return X, np.vstack(U + [last])


def _run_samples(x0, t, sample, kd=None, jump=None):
    """States on the grid from a loop over the samples: at sample ``k`` the state
    ``X[k]`` is recorded (after ``jump`` at ``kd``), then ``sample(k, X)`` runs the law
    and returns the state at ``k + 1`` (its return value at the last sample is unused)."""
    X = np.zeros((t.size, x0.size))
    x = x0
    for k in range(t.size):
        if k == kd:
            x = jump(x)
        X[k] = x
        x = sample(k, X)
    return X


def _run_adaptive(dae, x0, t, breaks, kd=None, jump=None, options=None):
    """States on the grid by a CasADi integrator restarted at ``breaks`` (the switches of
    the reference and the impulse), with the jump at sample ``kd``."""
    tend = t[-1]
    td = None if kd is None else t[kd]
    breaks = sorted(b for b in set(breaks) | ({td} if td is not None else set())
                    if 0.0 <= b <= tend)
    X = np.zeros((t.size, x0.size))
    X[0] = x0
    xc = x0.copy()
    if td is not None and td == 0.0:
        xc = X[0] = jump(xc)
    for a, b in zip(breaks[:-1], breaks[1:], strict=True):
        if b - a <= 1e-12 * max(1.0, tend):
            continue
        ks = np.nonzero((t > a + 1e-12) & (t <= b + 1e-12))[0]
        tout = list(t[ks])
        if not tout or abs(tout[-1] - b) > 1e-12:
            tout.append(b)
        integ = casadi_integrator("closed_loop", "cvodes", dae, a, tout, options)
        Xs = integrate(integ, xc)
        X[ks] = Xs[:ks.size]
        xc = Xs[-1]
        if td is not None and abs(b - td) <= 1e-12:
            xc = jump(xc)
            k = int(np.argmin(np.abs(t - td)))
            X[k] = xc
    return X


# ---------------------------------------------------------------------------- simulate_torque


def simulate_torque(model: FlexibleModel, controller: TorqueLaw, x0: ArrayLike, t_end: float,
                    dt: float = 1e-3, method: str = "rk4",
                    disturbance: Callable | ca.Function | None = None,
                    **options) -> SimulationResult:
    """Simulate the torque-driven arm ``x = [q; δ; q̇; δ̇]`` (forward dynamics).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    controller : callable or casadi.Function or array_like or None
        ``controller(t, x) -> tau`` [N m], evaluated at the start of every step and held
        over it (zero-order hold). A ``casadi.Function`` ``(t, x) -> tau`` runs the closed
        loop as one ``mapaccum`` call (``disturbance`` then has to be ``None`` or a
        ``casadi.Function`` of ``t`` too); a constant array or ``None`` (zero torque) as
        well.
    x0 : array_like, shape (2 (n + m),)
        Initial state.
    t_end : float
        End time [s] (the simulation starts at 0).
    dt : float
        Step and output interval [s].
    method : {"rk4", "cvodes", "idas"}
        Fixed-step RK4 or a CasADi integrator between the steps.
    disturbance : callable, optional
        ``disturbance(t) -> w``: generalized force on ``[q; δ]`` (``n + m`` values, or
        ``n`` joint torques) added to ``[τ; 0]`` [N m]; evaluated at the RK4 stage times
        (for ``cvodes``/``idas``: held over each step).
    **options
        Integrator options for ``cvodes``/``idas``.

    Returns
    -------
    SimulationResult
        ``ddq`` are the joint accelerations at the samples, ``tau`` the applied torques.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None)
    >>> x0 = np.r_[0.0, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0, 0.0]
    >>> r = simulate_torque(model, None, x0, t_end=0.05, dt=0.01)
    >>> r.q.shape, r.delta.shape
    ((6, 3), (6, 1))
    """
    if method not in METHODS:
        raise ModelError(f"method must be one of {list(METHODS)}; got {method!r}")
    n, m = model.n, model.m
    f = model.functions()
    t, steps = time_grid(0.0, float(t_end), float(dt))
    x0 = np.asarray(x0, dtype=float).ravel()
    if x0.shape != (2 * (n + m),) or not np.all(np.isfinite(x0)):
        raise ModelError(f"x0 must hold 2 (n + m) = {2 * (n + m)} finite values "
                         f"[q; delta; dq; ddelta]; got shape {x0.shape}")
    start = time.perf_counter()
    const = None
    if controller is None:
        const = np.zeros(n)
    elif not callable(controller) and not isinstance(controller, ca.Function):
        const = np.asarray(controller, dtype=float).ravel()
        if const.shape != (n,):
            raise ModelError(f"a constant controller must hold {n} torques; got {const.shape}")
    if isinstance(controller, ca.Function) or (const is not None and disturbance is None
                                               and method == "rk4"):
        step = _held_step(f, n, m, dt, controller, const, disturbance)
        X, U = _run_mapaccum(step, x0, t, repeat_last=False)
    else:
        X, U = _held_loop(model, f, n, m, t, dt, x0, controller, const, disturbance,
                          method, options)
    wall = time.perf_counter() - start
    hint = (f"an unstable closed loop, torques too large, or dt = {dt} s too large for the "
            "highest mode (RK4 needs omega dt < 2.8)")
    check_divergence("simulate_torque", t, {"q": X[:, :n], "delta": X[:, n:n + m],
                                            "dq": X[:, n + m:2 * n + m],
                                            "ddelta": X[:, 2 * n + m:], "tau": U}, hint)
    N = t.size
    q, delta, dq, ddelta = X[:, :n], X[:, n:n + m], X[:, n + m:2 * n + m], X[:, 2 * n + m:]
    W = _disturbance_samples(disturbance, t, n, m) if disturbance is not None and \
        not isinstance(disturbance, ca.Function) else np.zeros((N, n + m))
    xdot = f["ode_w"].map(N)(X.T, U.T, W.T).full().T
    ddq = xdot[:, n + m:2 * n + m]
    tip, tip_rigid = tip_positions(f["tip"], q, delta)
    check_divergence("simulate_torque", t, {"tip_deflection": tip - tip_rigid}, hint,
                     limits={"tip_deflection": DIVERGED_DEFLECTION * robot_reach(model.robot)})
    return SimulationResult(t=t, q=q, dq=dq, ddq=ddq, tau=U, delta=delta, ddelta=ddelta,
                            tip=tip, tip_rigid=tip_rigid, t_move_end=math.nan, method=method,
                            info={"steps": steps, "wall_s": wall})


def _w_vector(value, n, m):
    w = np.asarray(value, dtype=float).ravel()
    if w.size == n:
        return np.r_[w, np.zeros(m)]
    if w.size != n + m:
        raise ModelError(f"disturbance(t) must return n = {n} joint torques or n + m = "
                         f"{n + m} generalized forces; got {w.size} values")
    return w


def _disturbance_samples(disturbance, t, n, m):
    return np.array([_w_vector(disturbance(float(tk)), n, m) for tk in t])


def _held_step(f, n, m, dt, controller, const, disturbance):
    """``step (x, t) -> (x_next, τ)``: RK4 over one step with the law's torque held and
    a ``casadi.Function`` disturbance at the stage times."""
    ode = f["ode_w"]
    x = ca.MX.sym("x", 2 * (n + m))
    tk = ca.MX.sym("t")
    if const is not None:
        u = ca.MX(ca.DM(const))
    else:
        if controller.n_in() != 2 or controller.n_out() < 1:
            raise ModelError("a casadi.Function controller must map (t, x) -> tau")
        u = controller(tk, x)
        u = u[0] if isinstance(u, (list, tuple)) else u
        if u.numel() != n:
            raise ModelError(f"controller must return {n} torques; got {u.numel()}")

    def w_at(tt):
        if disturbance is None:
            return ca.MX.zeros(n + m)
        if not isinstance(disturbance, ca.Function):
            raise ModelError("with a casadi.Function controller the disturbance must be a "
                             "casadi.Function of t too (or None)")
        wv = disturbance(tt)
        wv = wv[0] if isinstance(wv, (list, tuple)) else wv
        if wv.numel() == n:
            wv = ca.vertcat(wv, ca.MX.zeros(m))
        return wv

    x_next = rk4_interval(lambda xx, s: ode(xx, u, w_at(s)), x, tk, dt)
    return ca.Function("rk4_cl", [x, tk], [x_next, u])


def _held_loop(model, f, n, m, t, dt, x0, controller, const, disturbance, method, options):
    """A Python law held over each step: RK4 (the disturbance sampled at the stage times)
    or a CasADi integrator (the disturbance held)."""
    ode = f["ode_w"]
    if method == "rk4":
        memo = step_cache(model)
        key = ("rk4_w", float(dt))
        step = memo.get(key)
        if step is None:
            x = ca.MX.sym("x", 2 * (n + m))
            u = ca.MX.sym("u", n)
            w = ca.MX.sym("w", n + m, 3)
            x_next = rk4_step(lambda xx, wk: ode(xx, u, wk), x, dt, w[:, 0], w[:, 1],
                              w[:, 2])
            step = memo[key] = ca.Function("rk4_w", [x, u, w], [x_next])
    else:
        x = ca.SX.sym("x", 2 * (n + m))
        u = ca.SX.sym("u", n)
        w = ca.SX.sym("w", n + m)
        dae = {"x": x, "p": ca.vertcat(u, w), "ode": ode(x, u, w)}
        integ = casadi_integrator("torque", method, dae, 0.0, [float(dt)], options)
    U = np.zeros((t.size, n))
    zero_w = np.zeros(n + m)

    def sample(k, X):
        tk = float(t[k])
        u_k = const if const is not None else controller(tk, X[k].copy())
        u_k = np.asarray(u_k, dtype=float).ravel()
        if u_k.shape != (n,):
            raise ModelError(f"controller(t, x) must return {n} torques; got {u_k.shape}")
        U[k] = u_k
        if k == t.size - 1:
            return None
        if disturbance is None:
            W = np.column_stack([zero_w] * 3)
        else:
            W = np.column_stack([_w_vector(disturbance(tk + c * dt), n, m)
                                 for c in (0.0, 0.5, 1.0)])
        if method == "rk4":
            return step(X[k], u_k, W).full().ravel()
        return integrate(integ, X[k], np.r_[u_k, W[:, 0]])[-1]

    return _run_samples(x0, t, sample), U


# ---------------------------------------------------------------------------- closed loop


def simulate_closed_loop(model: FlexibleModel, controller: ca.Function,
                         move: Move | ShapedMove, x0: ArrayLike | None = None,
                         t_end: float | None = None, dt: float = 1e-3,
                         impulse: tuple[float, ArrayLike] | None = None,
                         method: str = "cvodes", substeps: int = 1, sampled: bool = False,
                         estimator: dict | None = None, rtol: float = 1e-8,
                         atol: float = 1e-10, loop: str = "auto",
                         jit: bool | str | Sequence[str] = False,
                         cache_dir: str | os.PathLike | None = None) -> ClosedLoopResult:
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
    move : casflex.moves.Move or casflex.moves.ShapedMove
        Reference (:func:`casflex.moves.reference_function`; a move with ``q0 == qf``
        holds a configuration).
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
    loop : {"auto", "mapaccum", "python"}
        With an estimator: one CasADi Function per sample (plant RK4, controller,
        measurements, EKF update) run by ``mapaccum`` over the samples, or the loop over
        the samples in Python (needed when ``estimator["step"]`` is a Python callable);
        ``"auto"``: ``mapaccum`` when the step is a ``casadi.Function``. Both give the
        same numbers to round-off.
    jit : bool or str or sequence of str
        With ``loop="mapaccum"`` (an estimator) or ``method="rk4"``/``sampled=True``
        (the state fed back): compile the step Function to C
        (:func:`casflex.codegen.jit.compile_cached`; ``True`` is :data:`JIT_FLAGS`, or
        the compiler flags), kept in the on-disk cache so a later run only loads it. The
        compiled step gives the numbers of CasADi's VM to round-off (bit for bit on
        x86-64 without FMA contraction). Not used by the adaptive ``method="cvodes"``.
    cache_dir : str or pathlib.Path, optional
        Cache root of the compiled library (default the casflex cache directory).

    Returns
    -------
    ClosedLoopResult

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> move = Move([0, 0, 0], [-0.1, 0, 0], 0.5, settle=0.0)
    >>> from casflex.control import inversion_controller
    >>> r = simulate_closed_loop(model, inversion_controller(model), move, dt=5e-3)
    >>> bool(np.max(np.abs(r.tracking_error)) < 1e-6)
    True
    """
    return _closed_loop(None, model, controller, move, x0, t_end, dt, impulse, method,
                        substeps, sampled, estimator, rtol, atol, loop, jit, cache_dir)()


def start_closed_loop(executor: Executor, model: FlexibleModel, controller: ca.Function,
                      move: Move | ShapedMove, **options) -> Callable[[], ClosedLoopResult]:
    """Start :func:`simulate_closed_loop` in a worker process; the result comes later.

    The sample steps of a loop with the state fed back (``method="rk4"`` or
    ``sampled=True``, no ``impulse``, no ``estimator``) run in a worker of ``executor``
    (one ``mapaccum`` call of the step Function, compiled when ``jit``: the worker loads
    the same library), and the worker finishes their result (divergence checks, tip
    positions); the step is built here first. Any other loop runs here, now. The returned
    callable waits for the worker: the same numbers as :func:`simulate_closed_loop`,
    which a caller can overlap with other work, such as another loop in this process.

    Parameters
    ----------
    executor : concurrent.futures.Executor
        A process pool (:func:`casflex._parallel.worker_pool`'s ``executor``), or
        ``None`` to run here.
    model, controller, move
        As for :func:`simulate_closed_loop`.
    **options
        The keyword arguments of :func:`simulate_closed_loop` (``x0``, ``t_end``, ``dt``
        [s], ``method``, ``sampled``, ``jit``, ``cache_dir`` ...).

    Returns
    -------
    callable
        ``finish() -> ClosedLoopResult`` (raises what :func:`simulate_closed_loop` would:
        :class:`~casflex.errors.SolverError` for a diverged loop).

    Examples
    --------
    >>> from concurrent.futures import ProcessPoolExecutor
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.control import inversion_controller
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> move = Move([0, 0, 0], [-0.1, 0, 0], 0.5, settle=0.0)
    >>> with ProcessPoolExecutor(1) as pool:
    ...     finish = start_closed_loop(pool, model, inversion_controller(model), move,
    ...                                dt=5e-3, sampled=True)
    ...     r = finish()
    >>> here = simulate_closed_loop(model, inversion_controller(model), move, dt=5e-3,
    ...                             sampled=True)
    >>> bool(np.array_equal(r.x, here.x))
    True
    """
    defaults = dict(x0=None, t_end=None, dt=1e-3, impulse=None, method="cvodes", substeps=1,
                    sampled=False, estimator=None, rtol=1e-8, atol=1e-10, loop="auto",
                    jit=False, cache_dir=None)
    unknown = set(options) - set(defaults)
    if unknown:
        raise ModelError(f"start_closed_loop: unknown options {sorted(unknown)}")
    o = {**defaults, **options}
    return _closed_loop(executor, model, controller, move, o["x0"], o["t_end"], o["dt"],
                        o["impulse"], o["method"], o["substeps"], o["sampled"],
                        o["estimator"], o["rtol"], o["atol"], o["loop"], o["jit"],
                        o["cache_dir"])


def _closed_loop(executor, model, controller, move, x0, t_end, dt, impulse, method,
                 substeps, sampled, estimator, rtol, atol, loop, jit, cache_dir):
    """:func:`simulate_closed_loop` as ``finish() -> ClosedLoopResult``, its state-feedback
    sample steps in a worker of ``executor`` when there is one (:func:`start_closed_loop`)."""
    n, m = model.n, model.m
    nx = 2 * (n + m)
    dt = float(dt)
    if method not in ("cvodes", "rk4"):
        raise ModelError(f"method must be 'cvodes' or 'rk4'; got {method!r}")
    if loop not in ("auto", "mapaccum", "python"):
        raise ModelError(f"loop must be 'auto', 'mapaccum' or 'python'; got {loop!r}")
    t, N = time_grid(0.0, move.t_end if t_end is None else float(t_end), dt)
    if x0 is None:
        x0 = np.r_[move.q0, np.zeros(m), np.zeros(n), np.zeros(m)]
    x0 = np.asarray(x0, dtype=float).ravel()
    if x0.size != nx:
        raise ModelError(f"x0: expected {nx} values [q, delta, dq, ddelta]; got {x0.size}")
    f = model.functions()
    ode = f["ode"]
    ref = reference_function(move)
    kd = _impulse_index(impulse, t)
    context = _ResultContext(f["tip"], ref, n, m, robot_reach(model.robot), dt)

    def jump(x):
        return impulse_jump(model, x, impulse[1])

    t_s = ca.SX.sym("t")
    x_s = ca.SX.sym("x", nx)
    x_hat = pending = X = tau_all = None
    if estimator is None and method == "cvodes" and not sampled:
        # the law acts continuously: CVODES between the switches of the reference
        dae = {"x": x_s, "t": t_s, "ode": ode(x_s, controller(*ref(t_s), x_s))}
        # restarted where the reference's acceleration jumps: a move's start, half time
        # and end, a shaped move's impulses, a planned move's nodes
        T = float(move.duration)
        switches = getattr(move, "breakpoints", (0.0, T / 2.0, T))
        X = _run_adaptive(dae, x0, t, (0.0, *map(float, switches), T, t[-1]), kd, jump,
                          {"abstol": atol, "reltol": rtol, "max_num_steps": 1000000})
        tau_all = np.asarray(controller.map(N + 1)(*ref.map(N + 1)(t[None, :]), X.T)).T
    elif estimator is None:
        if jit is False:
            step = _state_feedback_step(ode, controller, ref, nx, dt, substeps, sampled)
        else:  # MX: calls to the model's functions, each generated once in the C
            step = _compiled_sample_step(_state_feedback_step(
                ode, controller, ref, nx, dt, substeps, sampled, ca.MX), jit, cache_dir)
        if executor is not None and kd is None:  # the steps and the result in a worker
            pending = executor.submit(_run_and_finish, step, x0, t, context)
        else:
            X, tau_all = _run_mapaccum(step, x0, t, kd, jump)
    else:
        X, tau_all, x_hat = _run_with_estimator(model, controller, ref, x0, t, dt,
                                                substeps, kd, jump, estimator, loop, jit,
                                                cache_dir)

    def finish():
        if pending is None:
            return _closed_loop_result(context, t, X, tau_all, x_hat)
        return pending.result()

    return finish


class _ResultContext(NamedTuple):
    """What :func:`_closed_loop_result` needs of the model and the move (picklable: a
    worker finishes its loop's result, :func:`_run_and_finish`)."""

    tip: ca.Function  # the model's ``tip (q, δ) -> p``
    ref: ca.Function  # the move's reference ``t -> (qd, q̇d, q̈d)``
    n: int
    m: int
    reach: float  # :func:`~casflex.simulate.results.robot_reach` [m]
    dt: float  # sample time [s], for the divergence hint


def _run_and_finish(step, x0, t, context):
    """Worker side of :func:`start_closed_loop`: the samples by :func:`_run_mapaccum` and
    their :class:`ClosedLoopResult` (or the :class:`~casflex.errors.SolverError` of a
    diverged loop, raised when the caller asks for the result)."""
    return _closed_loop_result(context, t, *_run_mapaccum(step, x0, t), None)


def _closed_loop_result(context, t, X, tau_all, x_hat):
    """The :class:`ClosedLoopResult` of the states and torques on the grid ``t``, checked
    for divergence (:class:`~casflex.errors.SolverError`)."""
    n, m, dt = context.n, context.m, context.dt
    ref = context.ref
    N = t.size - 1
    hint = (f"an unstable closed loop, or dt = {dt} s too large for the highest mode (RK4 "
            "needs omega dt < 2.8)")
    check_divergence("simulate_closed_loop", t, {"q": X[:, :n], "delta": X[:, n:n + m],
                                                 "dq": X[:, n + m:2 * n + m],
                                                 "ddelta": X[:, 2 * n + m:]}, hint)
    qd_all = np.asarray(ref.map(N + 1)(t[None, :])[0]).T
    tip, tip_rigid = tip_positions(context.tip, X[:, :n], X[:, n:n + m])
    check_divergence("simulate_closed_loop", t, {"tip_deflection": tip - tip_rigid}, hint,
                     limits={"tip_deflection": DIVERGED_DEFLECTION * context.reach})
    return ClosedLoopResult(t=t, x=X, tau=tau_all, qd=qd_all, tip=tip, tip_rigid=tip_rigid,
                            n=n, m=m, x_hat=x_hat)


def _state_feedback_step(ode, controller, ref, nx, dt, substeps, sampled, sym=ca.SX):
    """``(x_k, t_k) -> (x_{k+1}, τ_k)`` of the loop with the state fed back: RK4 under the
    torque held over the sample (``sampled``) or under the law acting at every stage.
    ``sym=ca.SX`` inlines everything (fastest in CasADi's VM), ``ca.MX`` keeps calls to
    the model's and the controller's functions (for compiling)."""
    t_s = sym.sym("t")
    x_s = sym.sym("x", nx)
    tau = controller(*ref(t_s), x_s)
    if sampled:  # the torque of t_k held until t_k+1
        xn = rk4_interval(lambda xx, s: ode(xx, tau), x_s, t_s, dt, substeps)
    else:
        xn = rk4_interval(lambda xx, s: ode(xx, controller(*ref(s), xx)), x_s, t_s, dt,
                          substeps, nudge=1e-9)
    name = "casflex_closed_loop_sampled" if sampled else "casflex_closed_loop_rk4"
    return ca.Function(name if sym is ca.MX else "cl_step", [x_s, t_s], [xn, tau],
                       {"cse": sym is ca.SX})


def _run_with_estimator(model, controller, ref, x0, t, dt, substeps, kd, jump, est, loop,
                        jit, cache_dir):
    """Sampled closed loop with an EKF between plant and controller: the sample step in
    Python (``loop="python"``) or one CasADi Function per sample under ``mapaccum``."""
    from casflex.sensors import measurement_function

    m = model.m
    ekf = est["step"]
    sensors = est["sensors"]
    h = measurement_function(model, sensors)
    ny = sensors.n_outputs
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
    else:
        Rn = est.get("R")
        if Rn is None:
            noise = np.zeros((t.size, ny))
        else:
            Lr = np.linalg.cholesky(
                np.atleast_2d(np.asarray(Rn, dtype=float)) * np.eye(ny) if np.ndim(Rn) < 2
                else np.asarray(Rn, dtype=float))
            # one draw of ny per sample, in sample order (as many calls of size ny would)
            draws = np.random.default_rng(est.get("seed", 0)).standard_normal((t.size, ny))
            noise = np.array([Lr @ z for z in draws])
    xprior0 = np.asarray(est.get("x0", np.zeros(2 * m)), dtype=float).ravel()
    P0 = np.asarray(est.get("P0", np.eye(2 * m) * 1e-4), dtype=float)
    if loop == "auto":
        loop = "mapaccum" if isinstance(ekf, ca.Function) else "python"
    if loop == "python":
        return _estimator_python(model, controller, ref, x0, t, dt, substeps, kd, jump, ekf,
                                 h, noise, ddq_source, xprior0, P0)
    if not isinstance(ekf, ca.Function):
        raise ModelError("loop='mapaccum' needs the estimator's 'step' as a casadi.Function "
                         "(casflex.estimation.ekf_step_function)")
    if jit is False:
        step = _estimator_sample_step(model, controller, ref, dt, substeps, ekf, h, ny,
                                      ddq_source)
    else:
        step = _compiled_sample_step(
            _estimator_sample_step(model, controller, ref, dt, substeps, ekf, h, ny,
                                   ddq_source, ca.MX), jit, cache_dir)
    return _estimator_mapaccum(step, model, x0, t, kd, jump, noise, xprior0, P0)


def _plant_sample(model, controller, ref, dt, substeps, x_s, xh, t_s):
    """Torque from (reference, plant joints, estimate ``xh``) held over one sample, the
    plant's RK4 over it, and its joint accelerations just before the next sample."""
    n, m = model.n, model.m
    ode = model.functions()["ode"]
    xc = ca.vertcat(x_s[:n], xh[:m], x_s[n + m:2 * n + m], xh[m:])
    tau = controller(*ref(t_s), xc)
    xn = rk4_interval(lambda xx, s: ode(xx, tau), x_s, t_s, dt, substeps)
    acc = ode(xn, tau)[n + m:2 * (n + m)]  # what the sensors see just before t_{k+1}
    return xn, tau, acc[:n]


def _estimator_python(model, controller, ref, x0, t, dt, substeps, kd, jump, ekf, h, noise,
                      ddq_source, xprior0, P0):
    """The loop over the samples in Python (an estimator step that is not a Function)."""
    n, m = model.n, model.m
    nx = 2 * (n + m)
    t_s = ca.SX.sym("t")
    x_s = ca.SX.sym("x", nx)
    xh = ca.SX.sym("xh", 2 * m)
    plant_step = ca.Function("plant_step", [x_s, xh, t_s],
                             list(_plant_sample(model, controller, ref, dt, substeps, x_s,
                                                xh, t_s)), {"cse": True})
    ny = noise.shape[1]
    N = t.size - 1
    TAU = np.zeros((N + 1, n))
    XH = np.zeros((N + 1, 2 * m))
    state = {"xprior": xprior0, "P": P0, "ddq_prev": np.zeros(n)}
    mask = np.ones(ny)

    def sample(k, X):
        x = X[k].copy()
        u = np.r_[x[:n], x[n + m:2 * n + m], state["ddq_prev"]]
        y = np.asarray(h(np.r_[x[n:n + m], x[2 * n + m:]], u)[-1]).ravel() + noise[k]
        if ddq_source == "difference":
            dq_k = x[n + m:2 * n + m]
            u = np.r_[x[:n], dq_k, (dq_k - (X[k - 1, n + m:2 * n + m] if k else dq_k)) / dt]
        out = ekf(state["xprior"], state["P"], u, y, mask)
        xpost = np.asarray(out[2]).ravel()
        XH[k] = xpost
        if k == N:
            return None
        xn_, tau_, acc_ = plant_step(x, xpost, t[k])
        TAU[k] = np.asarray(tau_).ravel()
        state["ddq_prev"] = np.asarray(acc_).ravel()
        state["xprior"] = np.asarray(out[0]).ravel()
        state["P"] = out[1]
        return np.asarray(xn_).ravel()

    X = _run_samples(x0, t, sample, kd, jump)
    TAU[N] = TAU[N - 1]
    return X, TAU, XH


def _estimator_sample_step(model, controller, ref, dt, substeps, ekf, h, ny, ddq_source,
                           sym=ca.SX):
    """One sample of the loop with the EKF as one SX Function
    ``(s_k, t_k, noise_k) -> (s_{k+1}, x̂_{k|k}, τ_k)``, with the carried state
    ``s = [x; x̂_prior; vec P; q̈_prev; q̇_prev]`` (``q̇_prev``: the joint rates of the
    previous sample, for the backward difference). ``sym=ca.SX`` inlines everything (the
    fastest in CasADi's VM); ``ca.MX`` keeps calls to the model's, the controller's and
    the EKF's Functions (built in milliseconds instead of seconds, for compiling)."""
    n, m = model.n, model.m
    nx, nh = 2 * (n + m), 2 * m
    s = sym.sym("s", nx + nh + nh * nh + 2 * n)
    t_s = sym.sym("t")
    e = sym.sym("noise", ny)
    x = s[:nx]
    xprior = s[nx:nx + nh]
    P = ca.reshape(s[nx + nh:nx + nh + nh * nh], nh, nh)
    ddq_prev = s[nx + nh + nh * nh:nx + nh + nh * nh + n]
    dq_prev = s[nx + nh + nh * nh + n:]
    q, dq = x[:n], x[n + m:2 * n + m]
    u = ca.vertcat(q, dq, ddq_prev)
    y = h.call([ca.vertcat(x[n:n + m], x[2 * n + m:]), u])[-1] + e
    if ddq_source == "difference":
        u = ca.vertcat(q, dq, (dq - dq_prev) / dt)
    out = ekf.call([xprior, P, u, y, ca.DM.ones(ny)])
    xpost = out[2]
    xn, tau, acc = _plant_sample(model, controller, ref, dt, substeps, x, xpost, t_s)
    s_next = ca.vertcat(xn, out[0], ca.reshape(out[1], nh * nh, 1), acc, dq)
    return ca.Function("casflex_closed_loop_ekf", [s, t_s, e], [s_next, xpost, tau],
                       {"cse": sym is ca.SX})


def _compiled_sample_step(step, jit, cache_dir):
    """The sample step compiled to C (:func:`casflex.codegen.jit.compile_cached`: built
    once, then loaded from the on-disk cache); ``jit=True`` uses :data:`JIT_FLAGS`."""
    from casflex.codegen.jit import compile_cached, jit_flags

    flags = jit_flags(jit, JIT_FLAGS)
    funs, _ = compile_cached([step], step.name(), cache_dir=cache_dir, flags=flags)
    return funs[step.name()]


def _estimator_mapaccum(step, model, x0, t, kd, jump, noise, xprior0, P0):
    """States, torques and filtered estimates from ``step`` under ``mapaccum`` over the
    samples ``0 … N`` (split at the impulse sample ``kd``; the plant step of sample N is
    not used)."""
    n, m = model.n, model.m
    nx = 2 * (n + m)
    N = t.size - 1
    s = np.r_[x0, xprior0, P0.ravel(order="F"), np.zeros(n), x0[n + m:2 * n + m]]
    segments = [(0, N + 1)] if kd is None else [(0, kd), (kd, N + 1)]
    X = np.zeros((N + 1, nx))
    XH = np.zeros((N + 1, 2 * m))
    TAU = np.zeros((N + 1, n))
    for i, (k0, k1) in enumerate(segments):
        if i == 1:
            s = s.copy()
            s[:nx] = jump(s[:nx])
            if k0 == 0:  # the difference at sample 0 is zero: q̇_prev is the jumped q̇
                s[-n:] = s[n + m:2 * n + m]
        if k1 == k0:
            continue
        L = k1 - k0  # the outputs written straight into numpy (no DM of 60 x L)
        S, XH[k0:k1], TAU[k0:k1] = call_buffered(
            step.mapaccum("closed_loop_ekf", L), [s, t[k0:k1], noise[k0:k1]],
            [(L, s.size), (L, 2 * m), (L, n)])
        X[k0] = s[:nx]
        X[k0 + 1:k1] = S[:-1, :nx]
        s = S[-1]
    TAU[N] = TAU[N - 1]
    return X, TAU, XH
