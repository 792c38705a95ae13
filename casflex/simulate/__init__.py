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
``method="rk4"`` (default) is the classical fixed-step Runge–Kutta scheme; for prescribed
motion, ``method="poly"`` takes the same steps on an exact polynomial form of the modal
rows whose configuration-dependent coefficients are interpolated in time (see
:func:`simulate_prescribed`). For prescribed
motion the reference is sampled at every node and half step, one RK4 step is a CasADi
``Function`` (the stage at the node also returns the torque) and the whole simulation is a
single call of ``Function.mapaccum`` over all steps, evaluated by CasADi's virtual machine —
no Python loop over steps. ``method="cvodes"`` or ``"idas"`` use a CasADi integrator with
adaptive steps and output on the same grid (tolerances ``abstol``, ``reltol`` and other
integrator options as keyword arguments).

Cost
----
The model's expressions are large (Table 8 arm, 5 modes: the ``prescribed`` function has
≈ 7e4 SX instructions, ≈ 0.35 ms per RK4 stage in the VM; a 5 s simulation at 1 ms
needs 20 000 stages: 7–9 s). For prescribed moves ``method="poly"`` evaluates only the
configuration arrays, at a few hundred interpolation nodes (0.8–1.2 s for that move), and
``jit=True`` compiles those arrays and the RK4 steps to C once per model (≈ 30 s, cached
on disk; then 0.3 s). Measured figures: ``benchmarks/README_model.md``.

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
_PRESCRIBED_METHODS = _METHODS + ("poly",)


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
        cache = model.functions()
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


def _check_method(method, methods=_METHODS):
    if method not in methods:
        raise ModelError(f"method must be one of {list(methods)}; got {method!r}")


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
                        ddelta0=None, *, jit=False, cache_dir=None, **options):
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
    method : {"rk4", "cvodes", "idas", "poly"}
        Fixed-step RK4 (default, one ``mapaccum`` call), a CasADi integrator, or
        ``"poly"``: the same RK4 steps on the exact polynomial form of the modal rows
        (below). ``"poly"`` needs a :class:`casflex.moves.Move` or
        :class:`casflex.moves.ShapedMove` (a sampled reference raises ``ModelError``).
    delta0, ddelta0 : array_like, optional
        Initial modal amplitudes and rates (default 0).
    jit : bool, str or sequence of str
        ``method="poly"`` only: compile ``F(q)`` and the RK4 steps to C with the system
        compiler (:func:`casflex.codegen.compile_cached`; ``True`` means the flags
        ``("-O1",)``; a string such as ``"-O0"`` or a sequence gives the flags). The
        library is cached on disk, keyed by the serialised CasADi graphs, the flags and
        the compiler, so only the first call for a model pays the compilation
        (≈ 30 s and 0.8 GB of compiler memory for the Table 8 arm with 5 modes at
        ``-O1``); later calls, also from other processes, load it in about a second.
        Results equal the uncompiled path to round-off.
    cache_dir : str or pathlib.Path, optional
        Root of the compiled-library cache (default ``$CASFLEX_CACHE`` or
        ``~/.cache/casflex``).
    **options
        Integrator options for ``cvodes``/``idas`` (default ``abstol=1e-10``,
        ``reltol=1e-8``).

    Returns
    -------
    SimulationResult
        With ``method="poly"``, ``info`` also holds ``poly_pieces``,
        ``poly_F_evaluations``, ``poly_max_nodes_per_piece``, ``poly_interp_rel_err`` (the
        achieved interpolation error, relative), ``poly_F_instructions`` and the timings
        of the stages [s].

    Raises
    ------
    ModelError
        Joint-count mismatch, bad step, times or method; ``"poly"`` with a sampled
        reference or when the interpolation does not reach 1e-10; ``jit`` with another
        method.
    SolverError
        The CasADi integrator failed.
    casflex.codegen.BuildError
        ``jit`` without a working C compiler.

    Notes
    -----
    ``method="poly"`` (exact fast path for prescribed motion). With ``delta_order`` 0 or
    1 the mass matrix is affine in δ, ``M(q, δ) = M0(q) + Σ_j δ_j M_j(q)`` (``M_j =
    ∂M/∂δ_j``), so with ``q(t), q̇(t), q̈(t)`` given the modal rows are

    ``M_δδ(q, δ) δ̈ = r,   M_δδ = M0_δδ + Σ_j δ_j M_j,δδ,
    r = c + J_δ δ + J_δ̇ δ̇ + Σ_jk C_jk δ_j δ̇_k + Σ_jk E_jk δ̇_j δ̇_k``

    exactly (no δδ terms): with ``P = Σ_i q̇_i ∂M/∂q_i`` and
    ``C Ẋ = Ṁ Ẋ − ½ ∂_X(Ẋᵀ M Ẋ)``, row ``a`` of ``−(M_δq q̈ + C Ẋ + G + D Ẋ)`` gives
    ``c_a = −[M0 q̈ + P0 q̇]_a + ½ q̇ᵀ M_a,qq q̇ − g0_a``,
    ``J_δ,aj = −[M_j q̈ + P_j q̇]_a − gd_aj − ω_a² 1_aj``,
    ``J_δ̇,ak = −P0_a,δk − [M_k q̇]_a + q̇ᵀ M_a,qδk − 2 ζ ω_a 1_ak``,
    ``C_ajk = −P_j,aδk`` and ``E_ajk = −M_j,aδk + ½ M_a,δjδk`` (joint rows of
    ``M``, ``P`` in the ``q`` columns; ``g0 + gd δ`` the gravity forces, affine in δ).
    One CasADi function ``F(q)`` gives ``M0``, ``M_j``, their q-Jacobians, ``Ω``,
    ``∂Ω²/∂q`` and the gravity terms. ``F(q(t))`` is analytic between the switches of
    the move and the times at which a shape joint crosses a knot of the modal tables'
    interpolants; on each such piece ``F`` is evaluated at Chebyshev–Lobatto nodes, the
    node count doubling until the previous interpolant matches ``F`` at the new nodes to
    1e-10 of each output's largest entry. On the same nodes the stage coefficients
    (with the reference's ``q̇`` and the piece's constant ``q̈``) and the coefficients of
    the torques ``τ = [M Ẍ + C Ẋ + G]_q`` as a polynomial in ``(δ, δ̇, δ̈)`` are formed
    and interpolated to the RK4 stage times, 250 steps at a time, which drive chunked
    ``mapaccum`` RK4 steps whose stage solves the m × m system. At a switch the piece on
    the reference's side is used (the end stage of a step takes the left limit, as the
    RK4 path does). The result equals ``method="rk4"`` to round-off plus the
    interpolation error; it is faster when the model is large and the reference crosses
    few table knots, and ``jit`` takes the evaluation of ``F`` and the RK4 steps out of
    CasADi's virtual machine (Table 8 arm, 5 modes, move 1: ≈ 0.3 s instead of ≈ 0.7 s,
    see ``benchmarks/README_model.md``).

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
    >>> p = simulate_prescribed(model, move, dt=0.01, method="poly")
    >>> bool(np.abs(p.delta - r.delta).max() < 1e-10 * np.abs(r.delta).max())
    True
    """
    import time

    _check_method(method, _PRESCRIBED_METHODS)
    if jit is not False and method != "poly":
        raise ModelError(f"jit is an option of method='poly'; got method={method!r}")
    n, m = model.n, model.m
    f = _functions(model)
    t, q, dq, ddq, t_move_end = sample_reference(reference, dt, t_end, n_joints=n)
    steps = t.size - 1
    z0 = np.r_[_initial(delta0, m, "delta0"), _initial(ddelta0, m, "ddelta0")]
    start = time.perf_counter()
    info = {}
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
    elif method == "poly":
        Z, tau, info = _simulate_poly(model, f, reference, t, float(dt), z0, jit, cache_dir)
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
                            method=method, info={"steps": steps, "wall_s": wall, **info})


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


# ---------------------------------------------------------------------------- poly method

_POLY_TOL = 1e-10
_POLY_START = 5  # Chebyshev intervals per piece in the first round (then 10, 20, ...)
_POLY_MAX_NODES = 96


def _poly_function(model, f):
    """``F(q)``: the configuration-only arrays of the modal and joint rows (cached).

    Outputs, with ``M(q, δ) = M0(q) + Σ_j δ_j M_j(q)`` (exact: the model keeps M to first
    order in δ): ``M0`` (N × N), ``Mj`` (N × N m, ``[M_1 … M_m]``), ``dM`` (N² (m + 1) × n,
    the q-Jacobian of ``[vec M0; vec M_1; …]``), ``omega`` (m), ``domega2`` (m × n,
    ``∂Ω²/∂q``), ``g0`` (N) and ``gd`` (N × m) with ``g(q, δ) = g0 + gd δ`` the gravity
    forces (affine in δ).
    """
    F = f.get("_poly_F")
    if F is not None:
        return F
    n, m = model.n, model.m
    N = n + m
    q, d = model.q, model.delta
    # M and g are affine in δ, so M_j = M(q, e_j) − M(q, 0) exactly; evaluating the
    # expressions at numeric δ lets CasADi drop the vanishing products (0.18 M SX
    # instructions with the q-Jacobians for the 5-mode Table 8 arm, against 0.46 M from
    # ∂M/∂δ_j at δ = 0)
    g = model.gravity_forces
    at = ca.Function("poly_at_delta", [q, d], [model.M, g])
    M0, g0 = at(q, ca.DM.zeros(m))
    Mj, gd = [], []
    for j in range(m):
        e = ca.DM.zeros(m)
        e[j] = 1.0
        Mk, gk = at(q, e)
        Mj.append(Mk - M0)
        gd.append(gk - g0)
    iu = np.triu_indices(N)

    def upper(A):
        return ca.vertcat(*[A[int(i), int(k)] for i, k in zip(*iu, strict=True)])

    stack = ca.vertcat(upper(M0), *[upper(A) for A in Mj])
    dstack = ca.jacobian(stack, q)
    omega = model.omega if m else ca.SX(0, 1)
    outs = [stack, dstack, omega, ca.jacobian(omega**2, q), g0,
            ca.horzcat(*gd) if m else ca.SX(N, 0)]
    F = ca.Function("poly_configuration", [q], outs, ["q"],
                    ["M", "dM", "omega", "domega2", "g0", "gd"])
    f["_poly_F"] = F
    return F


def _poly_unpack(raw, n, m, dq):
    """Arrays of ``F(q)`` at T times from the flat rows ``raw`` (T × R).

    ``P0``, ``Pj`` are ``Σ_i q̇_i ∂M0/∂q_i`` and ``Σ_i q̇_i ∂M_j/∂q_i`` for the rates ``dq``
    (T × n); ``K0``, ``Kj`` the partial derivatives themselves (torques).
    """
    N = n + m
    iu = np.triu_indices(N)
    nt = iu[0].size
    T = raw.shape[0]
    o = 0

    def take(k):
        nonlocal o
        out = raw[:, o:o + k]
        o += k
        return out

    index = np.empty((N, N), dtype=int)
    index[iu] = np.arange(nt)
    index[iu[1], iu[0]] = np.arange(nt)


    S = take(nt * (m + 1)).reshape(T, m + 1, nt)
    dS = take(nt * (m + 1) * n).reshape(T, n, m + 1, nt)  # column-major: q index slowest
    omega = take(m)
    dw2 = take(m * n).reshape(T, n, m).transpose(0, 2, 1)
    g0 = take(N)
    gd = take(N * m).reshape(T, m, N).transpose(0, 2, 1)
    # full symmetric matrices from their upper triangles (one gather each)
    allM = S[..., index]
    allP = np.einsum("ti,tijk->tjk", dq, dS)[..., index]
    allK = dS[..., index]
    return {"M0": allM[:, 0], "Mj": allM[:, 1:], "P0": allP[:, 0], "Pj": allP[:, 1:],
            "K0": allK[:, :, 0], "Kj": allK[:, :, 1:], "omega": omega, "domega2": dw2,
            "g0": g0, "gd": gd}


def _poly_eval(F, qs):
    """Flat rows (len(qs) × R) of ``F`` at the configurations ``qs`` (one map call)."""
    outs = F.map(qs.shape[0], "thread", 2)(qs.T)
    # column-major flattening of every output, one row per configuration
    return np.hstack([np.asarray(o.full()).reshape(-1, qs.shape[0], order="F").T
                      if o.numel() else np.zeros((qs.shape[0], 0)) for o in outs])


def _poly_knots(model):
    """Breakpoints of the model's table interpolants, per joint (dict joint -> array)."""
    table = getattr(model.provider, "table", None)
    if table is None or getattr(model.provider, "method", "bspline") not in ("bspline",
                                                                               "linear"):
        return {}
    knots = {}
    periodic = tuple(getattr(table, "periodic", ()) or ()) + (False,) * len(table.grid)
    for ax, joint in enumerate(table.shape_joints):
        g = np.asarray(table.grid[ax], dtype=float).ravel()
        if periodic[ax]:
            g = np.concatenate([g + 2.0 * np.pi * k for k in range(-2, 3)])
        knots[int(joint)] = np.unique(g)
    return knots


def _poly_breaks(model, reference, sampler, t0, t1):
    """Sorted times in [t0, t1] between which q(t) is a polynomial of degree ≤ 2 and no
    shape joint crosses a knot of the table interpolants (the coefficients are analytic
    there)."""
    switches = getattr(reference, "breakpoints", None)
    if switches is None:
        T = float(reference.duration)
        switches = (0.0, 0.5 * T, T)
    phase = np.unique(np.r_[t0, np.clip(np.asarray(switches, dtype=float), t0, t1), t1])
    breaks = [phase]
    knots = _poly_knots(model)
    for a, b in zip(phase[:-1], phase[1:], strict=True):
        if b - a <= 0.0:
            continue
        qa, dqa, _ = sampler(np.array([a]))
        ddq = sampler(np.array([0.5 * (a + b)]))[2][0]
        for j, kn in knots.items():
            # q_j(a + s) = qa + dqa s + ddq s² / 2 = κ  for s in (0, b - a)
            A, B, C = 0.5 * ddq[j], dqa[0, j], qa[0, j] - kn
            roots = []
            if abs(A) > 0.0:
                disc = B * B - 4.0 * A * C
                ok = disc >= 0.0
                sq = np.sqrt(np.where(ok, disc, 0.0))
                for r in ((-B + sq) / (2.0 * A), (-B - sq) / (2.0 * A)):
                    roots.append(r[ok])
            elif abs(B) > 0.0:
                roots.append(-C / B)
            if roots:
                s = np.concatenate(roots)
                s = s[(s > 1e-12 * (b - a)) & (s < (1.0 - 1e-12) * (b - a))]
                breaks.append(a + s)
    out = np.unique(np.concatenate(breaks))
    # merge breaks closer than 1e-12 s (a knot at a switch)
    keep = np.r_[True, np.diff(out) > 1e-12]
    return out[keep]


def _cheb(a, b, K):
    k = np.arange(K + 1)
    x = np.cos(np.pi * k / K)
    w = (-1.0) ** k
    w[0] *= 0.5
    w[-1] *= 0.5
    t = 0.5 * (a + b) + 0.5 * (b - a) * x
    t[0], t[-1] = b, a  # exactly: neighbouring pieces share their end nodes
    return t, w


def _bary(tn, w, fv, t):
    """Barycentric interpolation (second kind) of node values ``fv`` at times ``t``."""
    D = t[:, None] - tn[None, :]
    exact = D == 0.0
    D[exact] = 1.0
    C = w / D
    out = (C @ fv) / C.sum(axis=1)[:, None]
    hit = np.nonzero(exact.any(axis=1))[0]
    if hit.size:
        out[hit] = fv[np.argmax(exact[hit], axis=1)]
    return out


def _poly_interpolants(F, sampler, breaks, tol):
    """Chebyshev interpolants of ``F(q(t))`` on every piece between ``breaks``.

    The node count of every piece doubles (nested Chebyshev–Lobatto nodes) until the
    previous interpolant agrees with ``F`` at the new nodes to ``tol`` relative to the
    largest entry of each output block. Returns ``(pieces, err, evaluations, nodes)``.
    """
    pieces = [(a, b) for a, b in zip(breaks[:-1], breaks[1:], strict=True) if b > a]
    K = _POLY_START
    nodes = {}
    vals = {}
    tq = np.concatenate([_cheb(a, b, K)[0] for a, b in pieces])
    # F(q(t)) is continuous: a node shared by two pieces is evaluated once
    tu, back = np.unique(tq, return_inverse=True)
    raw = _poly_eval(F, sampler(tu)[0])[back]
    evaluations = tu.size
    sizes = [F.numel_out(i) for i in range(F.n_out())]
    edges = np.r_[0, np.cumsum(sizes)]
    scale = np.ones(raw.shape[1])
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        if hi > lo:
            scale[lo:hi] = max(float(np.abs(raw[:, lo:hi]).max()), 1e-300)
    o = 0
    for i, _ in enumerate(pieces):
        nodes[i] = K
        vals[i] = raw[o:o + K + 1]
        o += K + 1
    todo = list(range(len(pieces)))
    err = {}
    while todo:
        if K >= _POLY_MAX_NODES:
            worst = max(err[i] for i in todo)
            raise ModelError(
                f"method='poly': the interpolation of the model's configuration arrays "
                f"did not reach {tol:g} relative with {K} Chebyshev nodes per piece "
                f"(reached {worst:.2e}); the modal quantities are not smooth between the "
                "known breakpoints (provider without knot information?). Use method='rk4'")
        new_t = []
        for i in todo:
            a, b = pieces[i]
            tn2, _ = _cheb(a, b, 2 * K)
            new_t.append(tn2[1::2])  # the nodes of 2K not already in K
        new_q = sampler(np.concatenate(new_t))[0]
        new_raw = _poly_eval(F, new_q)
        evaluations += new_q.shape[0]
        o = 0
        nxt = []
        for i, tnew in zip(todo, new_t, strict=True):
            a, b = pieces[i]
            tn, w = _cheb(a, b, K)
            fnew = new_raw[o:o + tnew.size]
            o += tnew.size
            e = float(np.max(np.abs(_bary(tn, w, vals[i], tnew) - fnew) / scale))
            err[i] = e
            merged = np.empty((2 * K + 1, raw.shape[1]))
            merged[0::2] = vals[i]
            merged[1::2] = fnew
            vals[i] = merged
            nodes[i] = 2 * K
            if e > tol:
                nxt.append(i)
        todo = nxt
        K *= 2
    out = []
    for i, (a, b) in enumerate(pieces):
        tn, w = _cheb(a, b, nodes[i])
        out.append((a, b, tn, w, vals[i]))
    return out, max(err.values()) if err else 0.0, evaluations, max(nodes.values())


def _poly_piece_index(pieces, t, ddq, piece_ddq, left=False):
    """Index of the piece that gives the rows at each time ``t`` whose reference
    acceleration is ``ddq`` (T × n). Inside a piece that piece; at a break the later
    piece (``left=False``: the reference is right-continuous) or the earlier one
    (``left=True``: the left limit), and in either case the neighbour whose constant
    ``q̈`` (``piece_ddq``) is the reference's, should a break and a switch of the
    reference differ by round-off."""
    starts = np.array([p[0] for p in pieces])
    ends = np.array([p[1] for p in pieces])
    side = "left" if left else "right"
    idx = np.clip(np.searchsorted(starts, t, side=side) - 1, 0, len(pieces) - 1)
    eps = 1e-9 * max(float(ends[-1] - starts[0]), 1.0)
    near = np.nonzero((np.abs(t - starts[idx]) <= eps) | (np.abs(t - ends[idx]) <= eps))[0]
    for k in near:
        i = idx[k]
        if np.array_equal(piece_ddq[i], ddq[k]):
            continue
        for j in (i - 1, i + 1):
            if 0 <= j < len(pieces) and np.array_equal(piece_ddq[j], ddq[k]):
                idx[k] = j
                break
    return idx


def _poly_at(pieces, values, t, idx, out=None):
    """Rows of ``values`` (one array of node values per piece, nodes of ``pieces``)
    interpolated at the times ``t`` from the pieces ``idx`` (sorted)."""
    width = values[0].shape[1]
    if out is None:
        out = np.empty((t.size, width))
    cut = np.r_[0, np.nonzero(np.diff(idx))[0] + 1, t.size]
    for lo, hi in zip(cut[:-1], cut[1:], strict=True):
        if hi > lo:
            i = idx[lo]
            _, _, tn, w, _ = pieces[i]
            out[lo:hi] = _bary(tn, w, values[i], t[lo:hi])
    return out


def _sym_pairs(B):
    """Coefficients of ``x_j x_k`` (j ≤ k) of the quadratic form ``Σ_jk x_j x_k B[..., j, k]``
    (off-diagonal entries of the symmetrised ``B`` doubled)."""
    m = B.shape[-1]
    iu = np.triu_indices(m)
    S = B + np.swapaxes(B, -1, -2)
    S[..., np.arange(m), np.arange(m)] *= 0.5
    return S[..., iu[0], iu[1]]


def _poly_rows(A, dq, n, m, zeta):
    """Every array of the modal stage and of the joint torques at T times, except the
    factors of ``q̈`` (kept apart: ``q̈`` jumps at the move's switches while these rows
    are continuous in time, so they are interpolated across switches).

    ``A``: arrays of :func:`_poly_unpack` at the rates ``dq`` (T × n).

    The modal rows ``M_δδ(δ) δ̈ = r`` have ``M_δδ(δ) = Mdd0 + Σ_j δ_j Add_j`` and
    ``r = c + Jd δ + Jv δ̇ + Σ_jk C_ajk δ_j δ̇_k + Σ_jk E_ajk δ̇_j δ̇_k`` with
    ``c = c_row + c_acc q̈`` and ``Jd = Jd_row + Jd_acc q̈`` (r's parts stored negated,
    the layout of :func:`_poly_stage`). The torques
    ``τ = [M Ẍ + Ṁ Ẋ]_q − ½ Ẋᵀ (∂M/∂q) Ẋ + G_q`` are the polynomial of
    :func:`_poly_torque`.
    """
    N = n + m
    q_, d_ = slice(0, n), slice(n, N)
    M0, Mj, P0, Pj, K0, Kj = (A[k] for k in ("M0", "Mj", "P0", "Pj", "K0", "Kj"))
    w = A["omega"]
    ar = np.arange(m)
    # L_δ = M_δq(δ) q̈ + [Ṁ Ẋ]_δ − ½ ∂_δ(Ẋᵀ M Ẋ) + G_δ + D δ̇ (negated below)
    c = (np.einsum("tab,tb->ta", P0[:, d_, q_], dq)
         - 0.5 * np.einsum("ti,taij,tj->ta", dq, Mj[:, :, q_, q_], dq, optimize=True)
         + A["g0"][:, d_])
    Jd = np.einsum("tjab,tb->taj", Pj[:, :, d_, q_], dq) + A["gd"][:, d_, :]
    Jd[:, ar, ar] += w**2
    Jv = (P0[:, d_, d_] + np.einsum("tkab,tb->tak", Mj[:, :, d_, q_], dq)
          - np.einsum("ti,taik->tak", dq, Mj[:, :, q_, d_]))
    Jv[:, ar, ar] += 2.0 * zeta * w
    Mdd = Mj[:, :, d_, d_]
    # torques: Σ_a q̇_a ∂M[a, :]/∂q_i of M0 and of every M_j
    dqK0 = np.einsum("ta,tiab->tib", dq, K0[:, :, q_, :])
    dqKj = np.einsum("ta,tijab->tijb", dq, Kj[:, :, :, q_, :])
    return {
        "Mdd0": M0[:, d_, d_], "Add": Mdd, "c": -c, "Jd": -Jd, "Jv": -Jv,
        "C": -Pj[:, :, d_, d_].transpose(0, 2, 1, 3),  # [t, a, j, k] = P_j[a, δk]
        "E": -(Mdd.transpose(0, 2, 1, 3) - 0.5 * Mdd),  # M_j[a, δk] − ½ M_a[δj, δk]
        "c_acc": -M0[:, d_, q_],
        "Jd_acc": -Mj[:, :, d_, q_].transpose(0, 2, 1, 3),  # [t, a, j, b]
        "t0": (np.einsum("tib,tb->ti", P0[:, q_, q_], dq)
               - 0.5 * np.einsum("tib,tb->ti", dqK0[:, :, q_], dq) + A["g0"][:, q_]),
        "t0_acc": M0[:, q_, q_],
        "td": (np.einsum("tjib,tb->tij", Pj[:, :, q_, q_], dq)
               - 0.5 * np.einsum("tijb,tb->tij", dqKj[..., q_], dq) + A["gd"][:, q_, :]),
        "td_acc": Mj[:, :, q_, q_].transpose(0, 2, 1, 3),  # [t, i, j, b]
        "tv": (np.einsum("tjib,tb->tij", Mj[:, :, q_, q_], dq) + P0[:, q_, d_]
               - dqK0[:, :, d_]),
        "tdd": M0[:, q_, d_],
        "tdd2": 0.5 * A["domega2"].transpose(0, 2, 1),
        "t_d_dd": Mj[:, :, q_, d_].transpose(0, 2, 1, 3),  # [t, i, j, k]
        "t_d_v": Pj[:, :, q_, d_].transpose(0, 2, 1, 3) - dqKj[..., d_],
        "t_v_v": _sym_pairs(Mj[:, :, q_, d_].transpose(0, 2, 1, 3)
                            - 0.5 * K0[:, :, d_, d_]),
        "t_d_v_v": _sym_pairs(-0.5 * Kj[:, :, :, d_, d_]),
    }


def _poly_modal(rows, ddq):
    """Stage coefficient rows ``[Mdd0, Add, c, Jd, Jv, C, E]`` (C order) at T times with
    the accelerations ``ddq`` (T × n)."""
    T = ddq.shape[0]
    c = rows["c"] + np.einsum("tab,tb->ta", rows["c_acc"], ddq)
    Jd = rows["Jd"] + np.einsum("tajb,tb->taj", rows["Jd_acc"], ddq)
    parts = [rows["Mdd0"], rows["Add"], c, Jd, rows["Jv"], rows["C"], rows["E"]]
    return np.hstack([p.reshape(T, -1) for p in parts])


_POLY_TORQUE = ("t0", "td", "tv", "tdd", "tdd2", "t_d_dd", "t_d_v", "t_v_v", "t_d_v_v")


def _poly_torque_rows(rows, ddq):
    """Flat torque-coefficient rows (T × R, parts :data:`_POLY_TORQUE` in C order) with
    the accelerations ``ddq`` (T × n) folded into the constant and the δ terms."""
    T = ddq.shape[0]
    folded = dict(rows)
    folded["t0"] = rows["t0"] + np.einsum("tib,tb->ti", rows["t0_acc"], ddq)
    folded["td"] = rows["td"] + np.einsum("tijb,tb->tij", rows["td_acc"], ddq)
    return np.hstack([folded[k].reshape(T, -1) for k in _POLY_TORQUE])


def _poly_torque(R, n, m, d, v, dd):
    """Joint torques at T samples from torque-coefficient rows ``R`` of
    :func:`_poly_torque_rows`: per joint a polynomial in ``(δ, δ̇, δ̈)`` with the terms 1,
    δ_j, δ̇_j, δ̈_j, δ_j², δ_j δ̈_k, δ_j δ̇_k, δ̇_j δ̇_k (j ≤ k) and δ_j δ̇_k δ̇_l (k ≤ l)."""
    T = R.shape[0]
    p = m * (m + 1) // 2
    shapes = {"t0": (n,), "td": (n, m), "tv": (n, m), "tdd": (n, m), "tdd2": (n, m),
              "t_d_dd": (n, m, m), "t_d_v": (n, m, m), "t_v_v": (n, p),
              "t_d_v_v": (n, m, p)}
    r, o = {}, 0
    for k in _POLY_TORQUE:
        size = math.prod(shapes[k])
        r[k] = R[:, o:o + size].reshape((T, *shapes[k]))
        o += size
    iu = np.triu_indices(m)
    vv = v[:, iu[0]] * v[:, iu[1]]
    return (r["t0"]
            + np.einsum("tij,tj->ti", r["td"], d)
            + np.einsum("tij,tj->ti", r["tv"], v)
            + np.einsum("tij,tj->ti", r["tdd"], dd)
            + np.einsum("tij,tj->ti", r["tdd2"], d * d)
            + np.einsum("tijk,tj,tk->ti", r["t_d_dd"], d, dd, optimize=True)
            + np.einsum("tijk,tj,tk->ti", r["t_d_v"], d, v, optimize=True)
            + np.einsum("tip,tp->ti", r["t_v_v"], vv)
            + np.einsum("tijp,tj,tp->ti", r["t_d_v_v"], d, vv, optimize=True))


def _poly_stage(m):
    """SX stage ``(coef, z) -> [δ̇; δ̈]`` of the polynomial form of the modal rows."""
    z = ca.SX.sym("z", 2 * m)
    sizes = [m * m, m**3, m, m * m, m * m, m**3, m**3]
    coef = ca.SX.sym("coef", sum(sizes))
    d, v = z[:m], z[m:]
    parts, o = [], 0
    for s in sizes:
        parts.append(coef[o:o + s])
        o += s
    Mdd0, Add, c, Jd, Jv, C, E = parts

    def mat(x, rows, cols):  # C-order block
        return ca.reshape(x, cols, rows).T

    Mdd = mat(Mdd0, m, m)
    for j in range(m):
        Mdd += d[j] * mat(Add[j * m * m:(j + 1) * m * m], m, m)
    dv = ca.kron(d, v)
    vv = ca.kron(v, v)
    r = c + mat(Jd, m, m) @ d + mat(Jv, m, m) @ v + mat(C, m, m * m) @ dv \
        + mat(E, m, m * m) @ vv
    return ca.Function("poly_stage", [coef, z], [ca.vertcat(v, ca.solve(Mdd, r))]), \
        sum(sizes)


_POLY_CHUNK = 250


def _poly_rk4(f, m, dt):
    """``mapaccum`` over ``_POLY_CHUNK`` RK4 steps with the coefficients at t, t + dt/2 and
    t + dt as the per-step input (building a mapaccum costs time linear in its length, so
    a long simulation calls this chunk repeatedly)."""
    key = ("poly", m, float(dt))
    cached = f["_rk4"].get(key)
    if cached is not None:
        return cached
    stage, nc = _poly_stage(m)
    z = ca.SX.sym("z", 2 * m)
    p = ca.SX.sym("p", 3 * nc)
    pa, pb, pc = p[:nc], p[nc:2 * nc], p[2 * nc:]
    k1 = stage(pa, z)
    k2 = stage(pb, z + 0.5 * dt * k1)
    k3 = stage(pb, z + 0.5 * dt * k2)
    k4 = stage(pc, z + dt * k3)
    step = ca.Function("poly_rk4", [z, p], [z + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4),
                                            k1[m:]], ["z", "p"], ["z_next", "dddelta"])
    acc = step.mapaccum("poly_rk4_acc", _POLY_CHUNK, [0], [0])
    f["_rk4"][key] = (acc, stage)
    return acc, stage


def _poly_integrate(acc, z0, stage_rows, steps, m):
    """Run the chunked RK4 over ``steps`` steps; ``stage_rows(k0, k1)`` gives the
    coefficient rows ``[a | b | c]`` of steps ``k0 .. k1 - 1`` (assembled chunk by chunk:
    a whole 5 s move at 1 ms would be ~55 MB)."""
    L = _POLY_CHUNK
    chunks = -(-steps // L)
    zs = np.empty((chunks * L, 2 * m))
    dds = np.empty((chunks * L, m))
    z = np.ascontiguousarray(z0[None, :], dtype=float)
    for c in range(chunks):
        k0, k1 = c * L, min((c + 1) * L, steps)
        P = stage_rows(k0, k1)
        if k1 - k0 < L:
            P = np.vstack([P, np.repeat(P[-1:], L - (k1 - k0), axis=0)])
        zc, dc = _call_buffered(acc, [z, P], [(L, 2 * m), (L, m)])
        zs[k0:k0 + L] = zc
        dds[k0:k0 + L] = dc
        z = np.ascontiguousarray(zc[k1 - k0 - 1:k1 - k0])
    return zs[:steps], dds[:steps]


def _call_buffered(fun, args, shapes):
    """Evaluate ``fun`` without converting large arrays to DM: CasADi reads and writes the
    numpy buffers directly (column-major, so an input of shape (r, c) is passed as a
    C-contiguous (c, r) array)."""
    buf, run = fun.buffer()
    keep = []
    for i, a in enumerate(args):
        a = np.ascontiguousarray(a, dtype=float)
        keep.append(a)
        buf.set_arg(i, memoryview(a))
    outs = [np.zeros(s) for s in shapes]
    for i, o in enumerate(outs):
        buf.set_res(i, memoryview(o))
    run()
    return outs


def _poly_compiled(f, F, acc, jit, cache_dir):
    """``F`` and the RK4 chunk ``acc`` compiled to C (cached per model and flags)."""
    if jit is True:
        flags = ("-O1",)
    elif isinstance(jit, str):
        flags = tuple(jit.split())
    else:
        try:
            flags = tuple(str(x) for x in jit)
        except TypeError:
            raise ModelError(f"jit must be True, False, a flags string or a sequence of "
                             f"compiler flags; got {jit!r}") from None
    key = ("_poly_jit", flags, str(cache_dir))
    hit = f.get(key)
    if hit is not None:
        return hit + ({"poly_jit_s": 0.0, "poly_jit_built": False},)
    from casflex.codegen import compile_cached

    funs_F, info_F = compile_cached([F], "casflex_poly_F", cache_dir=cache_dir, flags=flags)
    funs_a, info_a = compile_cached([acc], "casflex_poly_rk4", cache_dir=cache_dir,
                                    flags=flags)
    f[key] = (funs_F[F.name()], funs_a[acc.name()])
    return f[key] + ({"poly_jit_s": info_F["seconds"] + info_a["seconds"],
                      "poly_jit_built": info_F["built"] or info_a["built"]},)


def _simulate_poly(model, f, reference, t, dt, z0, jit=False, cache_dir=None):
    """Integrate z with the polynomial form of the modal rows; returns (Z, tau, info)."""
    import time

    from casflex.moves import Move

    n, m = model.n, model.m
    if not (isinstance(reference, Move) or hasattr(reference, "breakpoints")):
        raise ModelError("method='poly' needs the reference as a casflex.moves.Move or "
                         "ShapedMove (known switching times); got sampled arrays — use "
                         "method='rk4'")
    if m == 0:
        raise ModelError("method='poly' needs a model with modes (m >= 1); use method='rk4'")
    if model.delta_order not in (0, 1):
        raise ModelError(f"method='poly' needs delta_order 0 or 1; got {model.delta_order}")
    info = {}
    start = time.perf_counter()
    F = _poly_function(model, f)
    acc, stage = _poly_rk4(f, m, float(dt))
    info["poly_build_s"] = time.perf_counter() - start
    info["poly_F_instructions"] = int(F.n_instructions())
    if jit is not False:
        F, acc, jinfo = _poly_compiled(f, F, acc, jit, cache_dir)
        info.update(jinfo)
    sampler = _as_reference(reference, n)[0]
    start = time.perf_counter()
    breaks = _poly_breaks(model, reference, sampler, float(t[0]), float(t[-1]))
    pieces, err, evals, kmax = _poly_interpolants(F, sampler, breaks, _POLY_TOL)
    info.update(poly_pieces=len(pieces), poly_F_evaluations=int(evals),
                poly_max_nodes_per_piece=int(kmax) + 1, poly_interp_rel_err=err,
                poly_interp_s=time.perf_counter() - start)
    start = time.perf_counter()
    zeta = model.damping_ratio
    # stage and torque coefficients on the nodes of every piece, with the piece's q̈
    # (constant between the breaks; the nodes at a break take their own piece's side)
    sizes = [p[2].size for p in pieces]
    tn_all = np.concatenate([p[2] for p in pieces])
    dq_nodes = sampler(tn_all)[1]
    piece_ddq = sampler(np.array([0.5 * (p[0] + p[1]) for p in pieces]))[2]
    ddq_nodes = np.repeat(piece_ddq, sizes, axis=0)
    rows = _poly_rows(_poly_unpack(np.vstack([p[4] for p in pieces]), n, m, dq_nodes),
                      dq_nodes, n, m, zeta)
    cut = np.cumsum(sizes)[:-1]
    modal = np.split(_poly_modal(rows, ddq_nodes), cut)
    torque = np.split(_poly_torque_rows(rows, ddq_nodes), cut)
    th = t[:-1] + 0.5 * dt
    ddq = sampler(t)[2]
    ddqh = sampler(th)[2]
    ddq_end = sampler(t[1:] - 1e-9 * dt)[2]  # the end stage takes q̈ from the left
    ia = _poly_piece_index(pieces, t, ddq, piece_ddq)
    ib = _poly_piece_index(pieces, th, ddqh, piece_ddq)
    ic = _poly_piece_index(pieces, t[1:], ddq_end, piece_ddq, left=True)
    nc = modal[0].shape[1]

    def stage_rows(k0, k1):
        P = np.empty((k1 - k0, 3 * nc))
        _poly_at(pieces, modal, t[k0:k1], ia[k0:k1], P[:, :nc])
        _poly_at(pieces, modal, th[k0:k1], ib[k0:k1], P[:, nc:2 * nc])
        _poly_at(pieces, modal, t[k0 + 1:k1 + 1], ic[k0:k1], P[:, 2 * nc:])
        return P

    info["poly_assembly_s"] = time.perf_counter() - start
    start = time.perf_counter()
    zs, dds = _poly_integrate(acc, z0, stage_rows, t.size - 1, m)
    Z = np.vstack([z0, zs])
    # δ̈ at the last sample from its own stage
    last = _poly_at(pieces, modal, t[-1:], ia[-1:])[0]
    dd_last = stage(last, Z[-1]).full().ravel()[m:]
    DD = np.vstack([dds, dd_last])
    info["poly_integrate_s"] = time.perf_counter() - start
    start = time.perf_counter()
    tau = _poly_torque(_poly_at(pieces, torque, t, ia), n, m, Z[:, :m], Z[:, m:], DD)
    info["poly_torque_s"] = time.perf_counter() - start
    return Z, tau, info


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
