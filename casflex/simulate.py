"""Simulation of the flexible-arm model: prescribed joint motion and torque-driven motion.

Two problems are solved on a :class:`casflex.dynamics.FlexibleModel`:

* :func:`simulate_prescribed` — the joints follow a planned trajectory exactly (perfect
  tracking, dissertation §3.3.7.1). The second (modal) row of eq. 118 gives the modal
  accelerations ``δ̈`` and is integrated for ``z = [δ; δ̇]`` only; the first row gives the
  torques that produce the motion. This is the model's ``prescribed`` function.
* :func:`simulate_torque` — torque-driven forward dynamics of the full state
  ``x = [q; δ; q̇; δ̇]`` (the model's ``ode``), with a controller ``τ = u(t, x)`` held
  constant over each step and an optional generalized disturbance force.

Integration
-----------
``method="rk4"`` (default) is the classical fixed-step Runge–Kutta scheme. For prescribed
motion the reference is sampled at every node and half step, one RK4 step is a CasADi
``Function`` (the stage at the node also returns the torque) and the whole simulation is a
single call of ``Function.mapaccum`` over all steps, evaluated by CasADi's virtual machine —
no Python loop over steps. ``method="cvodes"`` or ``"idas"`` use a CasADi integrator with
adaptive steps and output on the same grid (tolerances ``abstol``, ``reltol`` and other
integrator options as keyword arguments).

Cost
----
The model's expressions are large (Table 8 arm, 5 modes: the ``prescribed`` function has
≈ 1.5e5 SX instructions, 0.7–1.5 ms per evaluation in the VM; a 5 s simulation at 1 ms
needs 20 000 of them). See ``benchmarks/README_model.md`` for measured figures and what was
tried (C code generation of functions this size takes minutes to compile with ``gcc -O1``).

Units: s, rad, m, N m; modal amplitudes are those of the mass-normalised modes.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from casflex.errors import ModelError, SolverError

__all__ = ["SimulationResult", "simulate_prescribed", "simulate_torque", "sample_reference",
           "plot_result"]

_CACHE = weakref.WeakKeyDictionary()
_METHODS = ("rk4", "cvodes", "idas")


@dataclass
class SimulationResult:
    """Time histories of a simulation (rows are time samples).

    Attributes
    ----------
    t : numpy.ndarray, shape (N,)
        Time [s].
    q, dq, ddq : numpy.ndarray, shape (N, n)
        Joint positions [rad], velocities [rad/s], accelerations [rad/s²].
    tau : numpy.ndarray, shape (N, n)
        Joint torques [N m] (prescribed motion: the torques that produce it; torque-driven:
        the applied torques, held over each step).
    delta, ddelta : numpy.ndarray, shape (N, m)
        Modal amplitudes and their rates (mass-normalised modes).
    tip : numpy.ndarray, shape (N, 3)
        Tip position with the deflections [m] (base frame).
    tip_rigid : numpy.ndarray, shape (N, 3)
        Tip position from the rigid kinematics (δ = 0) [m].
    tip_deflection : numpy.ndarray, shape (N, 3)
        ``tip − tip_rigid`` [m].
    t_move_end : float
        End of the planned motion [s] (``nan`` when unknown).
    method : str
    info : dict
        Timing and bookkeeping (``{"steps": ..., "wall_s": ...}``).

    Examples
    --------
    >>> r = SimulationResult(t=np.array([0.0, 1.0]), q=np.zeros((2, 1)), dq=np.zeros((2, 1)),
    ...                      ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
    ...                      delta=np.zeros((2, 1)), ddelta=np.zeros((2, 1)),
    ...                      tip=np.array([[1.0, 0, 0], [1.0, 0, 0.002]]),
    ...                      tip_rigid=np.array([[1.0, 0, 0], [1.0, 0, 0]]), t_move_end=0.5)
    >>> r.max_tip_deflection, r.residual_tip_deflection
    (0.002, 0.002)
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    delta: np.ndarray
    ddelta: np.ndarray
    tip: np.ndarray
    tip_rigid: np.ndarray
    tip_deflection: np.ndarray = None
    t_move_end: float = math.nan
    method: str = "rk4"
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.tip_deflection is None:
            self.tip_deflection = np.asarray(self.tip) - np.asarray(self.tip_rigid)

    @property
    def max_tip_deflection(self):
        """Largest norm of the tip deflection over the whole simulation [m]."""
        return float(np.max(np.linalg.norm(self.tip_deflection, axis=1)))

    @property
    def residual_tip_deflection(self):
        """Largest norm of the tip deflection after the move ends [m] (``nan`` if the
        simulation stops before ``t_move_end`` or the end is unknown)."""
        if not math.isfinite(self.t_move_end):
            return math.nan
        after = self.t >= self.t_move_end - 1e-12
        if not np.any(after):
            return math.nan
        return float(np.max(np.linalg.norm(self.tip_deflection[after], axis=1)))

    @property
    def torque_peak(self):
        """Peak absolute torque per joint [N m]."""
        return np.max(np.abs(self.tau), axis=0)

    def to_dict(self):
        """Plain-Python dictionary (lists and floats) for :mod:`json` (SI units).

        Examples
        --------
        >>> r = SimulationResult(t=np.zeros(1), q=np.zeros((1, 1)), dq=np.zeros((1, 1)),
        ...                      ddq=np.zeros((1, 1)), tau=np.ones((1, 1)),
        ...                      delta=np.zeros((1, 1)), ddelta=np.zeros((1, 1)),
        ...                      tip=np.zeros((1, 3)), tip_rigid=np.zeros((1, 3)))
        >>> sorted(r.to_dict())[:4]
        ['ddelta', 'ddq', 'delta', 'dq']
        """
        out = {}
        for key in ("t", "q", "dq", "ddq", "tau", "delta", "ddelta", "tip", "tip_rigid",
                    "tip_deflection"):
            out[key] = np.asarray(getattr(self, key)).tolist()
        for key in ("max_tip_deflection", "residual_tip_deflection", "t_move_end"):
            v = float(getattr(self, key))
            out[key] = v if math.isfinite(v) else None
        out["torque_peak"] = self.torque_peak.tolist()
        out["method"] = self.method
        out["info"] = {k: v for k, v in self.info.items()
                       if isinstance(v, (int, float, str, bool))}
        return out


# ---------------------------------------------------------------------------- helpers


def _functions(model):
    """The model's Functions plus the reduced ones of this module (cached per model)."""
    cache = _CACHE.get(model)
    if cache is None:
        f = model.functions()
        n, m = model.n, model.m
        cache = dict(f)
        cache["dddelta"] = ca.Function(
            "dddelta", [model.q, model.dq, model.ddq, model.delta, model.ddelta],
            [model.prescribed_dddelta], ["q", "dq", "ddq", "delta", "ddelta"], ["dddelta"])
        # generalized force on every coordinate (for disturbances): M Ẍ + h = [τ; 0] + w
        w = ca.SX.sym("w", n + m)
        x = ca.vertcat(model.q, model.delta, model.dq, model.ddelta)
        rhs = ca.vertcat(model.tau, ca.SX.zeros(m)) + w - model.h
        cache["ode_w"] = ca.Function(
            "ode_w", [x, model.tau, w],
            [ca.vertcat(model.dq, model.ddelta, ca.solve(model.M, rhs))],
            ["x", "tau", "w"], ["xdot"])
        cache["_rk4"] = {}
        _CACHE[model] = cache
    return cache


def _hermite(t_ref, y, dy, t):
    """Cubic Hermite interpolation of samples ``y`` with slopes ``dy`` at times ``t``."""
    idx = np.clip(np.searchsorted(t_ref, t, side="right") - 1, 0, t_ref.size - 2)
    h = (t_ref[idx + 1] - t_ref[idx])[:, None]
    s = ((t - t_ref[idx])[:, None] / h).clip(0.0, 1.0)
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    out = h00 * y[idx] + h10 * h * dy[idx] + h01 * y[idx + 1] + h11 * h * dy[idx + 1]
    before, after = t < t_ref[0], t > t_ref[-1]
    out[before] = y[0]
    out[after] = y[-1] + dy[-1] * (t[after] - t_ref[-1])[:, None]
    return out


def _as_reference(reference, n):
    """Return ``(sampler, t_start, t_last, t_move_end)`` for a Move or a sampled tuple."""
    from casflex.moves import Move

    if isinstance(reference, Move) or hasattr(reference, "casadi_reference"):
        # a Move or a closed-form shaped move (casflex.moves.ShapedMove)
        if reference.n_joints != n:
            raise ModelError(f"move '{reference.name}' has {reference.n_joints} joints; the "
                             f"model has {n}")
        return reference.sample, 0.0, reference.t_end, float(reference.duration)
    try:
        t_ref, q, dq, ddq = reference
    except (TypeError, ValueError):
        raise ModelError("reference must be a casflex.moves.Move or a tuple (t, q, dq, ddq) "
                         f"of sampled arrays; got {type(reference).__name__}") from None
    if dq is None or ddq is None:
        raise ModelError("a sampled reference needs q, dq and ddq (e.g. apply_shaper(s, t, "
                         "q, dq, ddq)); got None")
    t_ref = np.asarray(t_ref, dtype=float).ravel()
    arrays = []
    for name, a in (("q", q), ("dq", dq), ("ddq", ddq)):
        a = np.asarray(a, dtype=float)
        if a.ndim == 1:
            a = a[:, None]
        if a.shape != (t_ref.size, n):
            raise ModelError(f"reference {name} has shape {a.shape}; expected "
                             f"({t_ref.size}, {n}) for a model with {n} joints")
        arrays.append(a)
    q, dq, ddq = arrays
    if t_ref.size < 2 or np.any(np.diff(t_ref) <= 0.0) or not np.all(np.isfinite(t_ref)):
        raise ModelError("reference t must hold >= 2 finite, strictly increasing times [s]")
    moving = (np.abs(dq).max(axis=1) > 1e-12) | (np.abs(ddq).max(axis=1) > 1e-12)
    if np.any(moving):
        last = int(np.nonzero(moving)[0][-1])
        t_move_end = float(t_ref[min(last + 1, t_ref.size - 1)])
    else:
        t_move_end = float(t_ref[0])

    def sampler(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        ddq_t = np.column_stack([np.interp(t, t_ref, ddq[:, j]) for j in range(n)])
        return _hermite(t_ref, q, dq, t), _hermite(t_ref, dq, ddq, t), ddq_t

    return sampler, float(t_ref[0]), float(t_ref[-1]), t_move_end


def _time_grid(t_start, t_end, dt):
    if not (math.isfinite(dt) and dt > 0.0):
        raise ModelError(f"dt must be a positive step [s]; got {dt!r}")
    if not (math.isfinite(t_end) and t_end > t_start):
        raise ModelError(f"t_end must be after the start {t_start} s; got {t_end!r}")
    steps = int(round((t_end - t_start) / dt))
    if steps < 1:
        raise ModelError(f"t_end - t_start = {t_end - t_start} s is shorter than dt = {dt} s")
    return t_start + dt * np.arange(steps + 1), steps


def _initial(value, m, name):
    if value is None:
        return np.zeros(m)
    v = np.asarray(value, dtype=float).ravel()
    if v.shape != (m,) or not np.all(np.isfinite(v)):
        raise ModelError(f"{name} must hold {m} finite modal values; got {value!r}")
    return v


def _check_method(method):
    if method not in _METHODS:
        raise ModelError(f"method must be one of {list(_METHODS)}; got {method!r}")


def _tips(f, q, delta):
    N = q.shape[0]
    tipm = f["tip"].map(N)
    tip = tipm(q.T, delta.T).full().T
    tip_rigid = tipm(q.T, np.zeros_like(delta.T)).full().T
    return tip, tip_rigid


def _rk4_prescribed(f, n, m, dt, steps):
    """mapaccum of one RK4 step of z = [δ; δ̇] with the reference as a parameter."""
    key = ("prescribed", float(dt), int(steps))
    cached = f["_rk4"].get(key)
    if cached is not None:
        return cached
    z = ca.MX.sym("z", 2 * m)
    p = ca.MX.sym("p", 9 * n)  # [q dq ddq] at t, t + dt/2, t + dt
    ref = [p[3 * n * k + n * i:3 * n * k + n * (i + 1)] for k in range(3) for i in range(3)]
    qa, dqa, ddqa, qb, dqb, ddqb, qc, dqc, ddqc = ref

    def rhs(q, dq, ddq, zz, first=False):
        d, dd = zz[:m], zz[m:]
        if first:
            tau, ddd = f["prescribed"](q, dq, ddq, d, dd)
            return ca.vertcat(dd, ddd), tau, ddd
        return ca.vertcat(dd, f["dddelta"](q, dq, ddq, d, dd))

    k1, tau0, ddd0 = rhs(qa, dqa, ddqa, z, first=True)
    k2 = rhs(qb, dqb, ddqb, z + 0.5 * dt * k1)
    k3 = rhs(qb, dqb, ddqb, z + 0.5 * dt * k2)
    k4 = rhs(qc, dqc, ddqc, z + dt * k3)
    z_next = z + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("rk4_prescribed", [z, p], [z_next, tau0, ddd0],
                       ["z", "p"], ["z_next", "tau", "dddelta"])
    acc = step.mapaccum("rk4_prescribed_acc", steps, [0], [0])
    f["_rk4"][key] = acc
    return acc


# ---------------------------------------------------------------------------- prescribed


def sample_reference(reference, dt=1e-3, t_end=None, n_joints=None):
    """Sample a reference (Move or ``(t, q, dq, ddq)``) on a uniform grid.

    Parameters
    ----------
    reference : casflex.moves.Move or tuple
        A move, or sampled arrays ``(t, q, dq, ddq)`` [s, rad, rad/s, rad/s²] (shape
        ``(N,)`` and ``(N, n)``), e.g. from :func:`casflex.shaping.apply_shaper`. Between
        samples ``q`` and ``dq`` are cubic Hermite interpolants, ``ddq`` is linear.
    dt : float
        Step [s].
    t_end : float, optional
        End time [s]; default the move's ``t_end`` or the last sample.
    n_joints : int, optional
        Expected number of joints (checked).

    Returns
    -------
    t : numpy.ndarray
    q, dq, ddq : numpy.ndarray, shape (len(t), n)
    t_move_end : float

    Examples
    --------
    >>> from casflex.moves import Move
    >>> t, q, dq, ddq, tm = sample_reference(Move([0.0], [-1.0], 2.0, settle=1.0), dt=0.5)
    >>> t.tolist(), q.ravel().tolist(), tm
    ([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0], [0.0, -0.125, -0.5, -0.875, -1.0, -1.0, -1.0], 2.0)
    """
    if n_joints is None:
        n_joints = reference.n_joints if hasattr(reference, "n_joints") else \
            np.atleast_2d(np.asarray(reference[1]).T).T.shape[1]
    sampler, t0, t_last, t_move_end = _as_reference(reference, n_joints)
    t, _ = _time_grid(t0, t_last if t_end is None else float(t_end), float(dt))
    q, dq, ddq = sampler(t)
    return t, q, dq, ddq, t_move_end


def simulate_prescribed(model, reference, dt=1e-3, t_end=None, method="rk4", delta0=None,
                        ddelta0=None, **options):
    """Simulate the arm with joints that follow a prescribed trajectory exactly.

    The modal row of eq. 118, ``M_δq q̈ + M_δδ δ̈ + h_δ = 0``, is integrated for
    ``z = [δ; δ̇]`` with the reference ``q(t), q̇(t), q̈(t)`` as input; the joint row
    gives the torques ``τ = M_qq q̈ + M_qδ δ̈ + h_q`` (the model's ``prescribed``
    function).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    reference : casflex.moves.Move or tuple
        A move, or sampled ``(t, q, dq, ddq)`` arrays [s, rad, rad/s, rad/s²], e.g. a
        shaped reference from :func:`casflex.shaping.apply_shaper` (interpolated between
        samples: cubic Hermite for ``q`` and ``dq``, linear for ``ddq``).
    dt : float
        Step and output interval [s].
    t_end : float, optional
        End time [s]; default the move's ``duration + settle`` or the last sample.
    method : {"rk4", "cvodes", "idas"}
        Fixed-step RK4 (default, one ``mapaccum`` call) or a CasADi integrator.
    delta0, ddelta0 : array_like, optional
        Initial modal amplitudes and rates (default 0).
    **options
        Integrator options for ``cvodes``/``idas`` (default ``abstol=1e-10``,
        ``reltol=1e-8``).

    Returns
    -------
    SimulationResult

    Raises
    ------
    ModelError
        Joint-count mismatch, bad step, times or method.
    SolverError
        The CasADi integrator failed.

    Examples
    --------
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None)
    >>> move = Move([0.0, 0.0, 0.0], [-0.1, 0.0, 0.0], duration=1.0, settle=0.2)
    >>> r = simulate_prescribed(model, move, dt=0.01)
    >>> r.delta.shape, bool(0.0 < r.max_tip_deflection < 0.05)
    ((121, 1), True)
    """
    import time

    _check_method(method)
    n, m = model.n, model.m
    f = _functions(model)
    t, q, dq, ddq, t_move_end = sample_reference(reference, dt, t_end, n_joints=n)
    steps = t.size - 1
    z0 = np.r_[_initial(delta0, m, "delta0"), _initial(ddelta0, m, "ddelta0")]
    start = time.perf_counter()
    if method == "rk4":
        sampler = _as_reference(reference, n)[0]
        qh, dqh, ddqh = sampler(t[:-1] + 0.5 * dt)
        # the last stage of a step takes the left limit of q̈ (a bang-bang switch on a
        # node belongs to the next step); q and q̇ are continuous
        ddq_end = sampler(t[1:] - 1e-9 * dt)[2]
        P = np.hstack([q[:-1], dq[:-1], ddq[:-1], qh, dqh, ddqh, q[1:], dq[1:], ddq_end])
        acc = _rk4_prescribed(f, n, m, float(dt), steps)
        zs, taus, ddds = acc(z0, P.T)
        Z = np.vstack([z0, zs.full().T])
        tau_last, _ = f["prescribed"](q[-1], dq[-1], ddq[-1], Z[-1, :m], Z[-1, m:])
        tau = np.vstack([taus.full().T, tau_last.full().T])
    else:
        Z = _integrate_prescribed(model, f, reference, t, z0, method, options)
        tm = f["prescribed"].map(t.size)
        tau = tm(q.T, dq.T, ddq.T, Z[:, :m].T, Z[:, m:].T)[0].full().T
    wall = time.perf_counter() - start
    if not np.all(np.isfinite(Z)):
        raise SolverError("simulate_prescribed: the modal state became non-finite (step "
                          f"dt = {dt} s too large for the highest mode?)")
    delta, ddelta = Z[:, :m], Z[:, m:]
    tip, tip_rigid = _tips(f, q, delta)
    return SimulationResult(t=t, q=q, dq=dq, ddq=ddq, tau=tau, delta=delta, ddelta=ddelta,
                            tip=tip, tip_rigid=tip_rigid, t_move_end=t_move_end,
                            method=method, info={"steps": steps, "wall_s": wall})


def _integrator(name, method, dae, t0, grid, options):
    opts = {"abstol": 1e-10, "reltol": 1e-8, "max_num_steps": 1_000_000}
    opts.update(options)
    try:
        return ca.integrator(name, method, dae, t0, list(grid), opts)
    except RuntimeError as exc:
        raise SolverError(f"could not create the {method} integrator: {exc}") from exc


def _run(integ, x0, p=None):
    try:
        args = {"x0": x0} if p is None else {"x0": x0, "p": p}
        return integ(**args)["xf"].full().T
    except RuntimeError as exc:
        raise SolverError(f"integration failed: {exc}") from exc


def _integrate_prescribed(model, f, reference, t, z0, method, options):
    """Adaptive-step integration of z with the reference as a symbolic function of time."""
    from casflex.moves import Move

    m = model.m
    z = ca.SX.sym("z", 2 * m)
    tt = ca.SX.sym("t")
    if hasattr(reference, "casadi_reference"):  # a shaped move in closed form
        q, dq, ddq = reference.casadi_reference()(tt)
    elif isinstance(reference, Move):
        T, a = reference.duration, ca.DM(reference.peak_acceleration)
        q0, qf = ca.DM(reference.q0), ca.DM(reference.qf)
        tc = ca.fmin(ca.fmax(tt, 0.0), T)
        first, second = tt < T / 2.0, tt < T
        q = ca.if_else(first, q0 + 0.5 * a * tc**2, qf - 0.5 * a * (T - tc) ** 2)
        dq = ca.if_else(first, a * tc, ca.if_else(second, a * (T - tc), 0 * a))
        ddq = ca.if_else(first, a, ca.if_else(second, -a, 0 * a))
    else:  # piecewise-linear interpolants of the samples
        t_ref, qs, dqs, ddqs = (np.asarray(v, dtype=float) for v in reference)
        parts = []
        for arr in (qs, dqs, ddqs):
            arr = arr.reshape(t_ref.size, -1)
            li = ca.interpolant("ref", "linear", [t_ref], arr.T.ravel(order="F"))
            parts.append(li(tt))
        q, dq, ddq = parts
    ode = ca.vertcat(z[m:], f["dddelta"](q, dq, ddq, z[:m], z[m:]))
    dae = {"x": z, "t": tt, "ode": ode}
    # restart at the switches of a bang-bang move (the right-hand side jumps there)
    cuts = [float(t[0])]
    if isinstance(reference, Move) or hasattr(reference, "breakpoints"):
        switches = getattr(reference, "breakpoints", None)
        if switches is None:
            switches = (0.5 * reference.duration, reference.duration)
        for tc in switches:
            k = int(np.argmin(np.abs(t - tc)))
            if abs(t[k] - tc) < 1e-9 and t[0] < t[k] < t[-1]:
                cuts.append(float(t[k]))
    cuts.append(float(t[-1]))
    cuts = sorted(set(cuts))
    Z = [z0]
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        grid = t[(t > a + 1e-12) & (t <= b + 1e-12)]
        integ = _integrator("prescribed", method, dae, a, grid, options)
        Z.append(_run(integ, Z[-1][-1] if Z[-1].ndim == 2 else Z[-1]))
    return np.vstack([np.atleast_2d(Z[0])] + Z[1:])


# ---------------------------------------------------------------------------- torque


def simulate_torque(model, controller, x0, t_end, dt=1e-3, method="rk4", disturbance=None,
                    **options):
    """Simulate the torque-driven arm ``x = [q; δ; q̇; δ̇]`` (forward dynamics).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None)
    >>> x0 = np.r_[0.0, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0, 0.0]
    >>> r = simulate_torque(model, None, x0, t_end=0.05, dt=0.01)
    >>> r.q.shape, r.delta.shape
    ((6, 3), (6, 1))
    """
    import time

    _check_method(method)
    n, m = model.n, model.m
    f = _functions(model)
    t, steps = _time_grid(0.0, float(t_end), float(dt))
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
        X, U = _closed_loop_mapaccum(f, n, m, t, dt, x0, controller, const, disturbance)
    else:
        X, U = _closed_loop_python(f, n, m, t, dt, x0, controller, const, disturbance,
                                   method, options)
    wall = time.perf_counter() - start
    if not np.all(np.isfinite(X)):
        raise SolverError("simulate_torque: the state became non-finite (unstable closed "
                          f"loop, or dt = {dt} s too large for the highest mode?)")
    N = t.size
    q, delta, dq, ddelta = X[:, :n], X[:, n:n + m], X[:, n + m:2 * n + m], X[:, 2 * n + m:]
    W = _disturbance_samples(disturbance, t, n, m) if disturbance is not None and \
        not isinstance(disturbance, ca.Function) else np.zeros((N, n + m))
    xdot = f["ode_w"].map(N)(X.T, U.T, W.T).full().T
    ddq = xdot[:, n + m:2 * n + m]
    tip, tip_rigid = _tips(f, q, delta)
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


def _closed_loop_python(f, n, m, t, dt, x0, controller, const, disturbance, method, options):
    ode = f["ode_w"]
    if method == "rk4":
        key = ("rk4_w", float(dt))
        step = f["_rk4"].get(key)
        if step is None:
            x = ca.MX.sym("x", 2 * (n + m))
            u = ca.MX.sym("u", n)
            w = ca.MX.sym("w", n + m, 3)
            k1 = ode(x, u, w[:, 0])
            k2 = ode(x + 0.5 * dt * k1, u, w[:, 1])
            k3 = ode(x + 0.5 * dt * k2, u, w[:, 1])
            k4 = ode(x + dt * k3, u, w[:, 2])
            step = ca.Function("rk4_w", [x, u, w], [x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)])
            f["_rk4"][key] = step
    else:
        x = ca.SX.sym("x", 2 * (n + m))
        u = ca.SX.sym("u", n)
        w = ca.SX.sym("w", n + m)
        dae = {"x": x, "p": ca.vertcat(u, w), "ode": ode(x, u, w)}
        integ = _integrator("torque", method, dae, 0.0, [float(dt)], options)
    X = np.zeros((t.size, x0.size))
    U = np.zeros((t.size, n))
    X[0] = x0
    zero_w = np.zeros(n + m)
    for k in range(t.size):
        tk = float(t[k])
        u_k = const if const is not None else controller(tk, X[k].copy())
        u_k = np.asarray(u_k, dtype=float).ravel()
        if u_k.shape != (n,):
            raise ModelError(f"controller(t, x) must return {n} torques; got {u_k.shape}")
        U[k] = u_k
        if k == t.size - 1:
            break
        if disturbance is None:
            W = np.column_stack([zero_w] * 3)
        else:
            W = np.column_stack([_w_vector(disturbance(tk + c * dt), n, m)
                                 for c in (0.0, 0.5, 1.0)])
        if method == "rk4":
            X[k + 1] = step(X[k], u_k, W).full().ravel()
        else:
            X[k + 1] = _run(integ, X[k], np.r_[u_k, W[:, 0]])[-1]
    return X, U


def _closed_loop_mapaccum(f, n, m, t, dt, x0, controller, const, disturbance):
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

    k1 = ode(x, u, w_at(tk))
    k2 = ode(x + 0.5 * dt * k1, u, w_at(tk + 0.5 * dt))
    k3 = ode(x + 0.5 * dt * k2, u, w_at(tk + 0.5 * dt))
    k4 = ode(x + dt * k3, u, w_at(tk + dt))
    x_next = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("rk4_cl", [x, tk], [x_next, u])
    steps = t.size - 1
    acc = step.mapaccum("rk4_cl_acc", steps, [0], [0])
    xs, us = acc(x0, t[:-1][None, :])
    X = np.vstack([x0, xs.full().T])
    u_last = step(X[-1], t[-1])[1].full().ravel()
    U = np.vstack([us.full().T, u_last])
    return X, U


# ---------------------------------------------------------------------------- plotting


def plot_result(result, title=None):
    """Joint angles, torques, modal amplitudes and tip deflection, one panel each.

    Parameters
    ----------
    result : SimulationResult
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> r = SimulationResult(t=np.arange(3.0), q=np.zeros((3, 1)), dq=np.zeros((3, 1)),
    ...                      ddq=np.zeros((3, 1)), tau=np.zeros((3, 1)),
    ...                      delta=np.zeros((3, 2)), ddelta=np.zeros((3, 2)),
    ...                      tip=np.zeros((3, 3)), tip_rigid=np.zeros((3, 3)))
    >>> len(plot_result(r).axes)
    4
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 7), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    t = result.t
    for j in range(result.q.shape[1]):
        axes[0, 0].plot(t, result.q[:, j], label=f"q{j + 1}")
        axes[0, 1].plot(t, result.tau[:, j], label=f"τ{j + 1}")
    for j in range(result.delta.shape[1]):
        axes[1, 0].plot(t, result.delta[:, j], label=f"δ{j + 1}")
    for k, c in enumerate("xyz"):
        axes[1, 1].plot(t, 1e3 * result.tip_deflection[:, k], label=c)
    axes[1, 1].plot(t, 1e3 * np.linalg.norm(result.tip_deflection, axis=1), "k--", lw=0.8,
                    label="|·|")
    labels = [("joint angle [rad]", axes[0, 0]), ("torque [N m]", axes[0, 1]),
              ("modal amplitude δ [√kg m]", axes[1, 0]),
              ("tip deflection [mm]", axes[1, 1])]
    for label, ax in labels:
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small", ncol=2)
        if math.isfinite(result.t_move_end):
            ax.axvline(result.t_move_end, color="0.6", lw=0.8, ls=":")
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    if title:
        fig.suptitle(title)
    return fig
