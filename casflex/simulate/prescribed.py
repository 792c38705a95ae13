"""Prescribed joint motion: the joints follow a planned trajectory exactly.

The modal row of eq. 118 gives the modal accelerations ``δ̈`` and is integrated for
``z = [δ; δ̇]`` only; the joint row gives the torques that produce the motion (the
model's ``prescribed`` function, dissertation §3.3.7.1).

* :func:`simulate_prescribed` — the simulation, by fixed-step RK4 (one ``mapaccum`` call
  over all steps, the reference sampled at every node and half step), by an adaptive
  CasADi integrator (``cvodes``/``idas``), or by the polynomial form of
  :mod:`casflex.simulate.poly`;
* :func:`sample_reference` — a reference on the uniform grid of a simulation;
* :func:`simulate_move` — build the model of a robot and simulate one move (the
  ``casflex simulate`` command).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.moves import Move, ShapedMove, reference_function, reference_sampler
from casflex.simulate import poly
from casflex.simulate.integrators import (
    LEFT_LIMIT,
    casadi_integrator,
    integrate,
    rk4_step,
    step_cache,
    time_grid,
)
from casflex.simulate.results import (
    DIVERGED_DEFLECTION,
    SimulationResult,
    check_divergence,
    robot_reach,
    tip_positions,
)

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.robot import Robot

__all__ = ["simulate_prescribed", "sample_reference", "simulate_move"]

#: a planned move, a shaped move or sampled arrays ``(t, q, dq, ddq)``
Reference = Move | ShapedMove | tuple

METHODS = ("rk4", "cvodes", "idas", "poly")


def check_method(method: str, methods: Sequence[str]) -> None:
    """Raise :class:`~casflex.errors.ModelError` unless ``method`` is one of ``methods``.

    Parameters
    ----------
    method : str
    methods : sequence of str

    Examples
    --------
    >>> check_method("rk4", METHODS)
    >>> check_method("euler", METHODS)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: method must be one of ['rk4', 'cvodes', 'idas', 'poly']; got 'euler'
    """
    if method not in methods:
        raise ModelError(f"method must be one of {list(methods)}; got {method!r}")


def _initial(value, m, name):
    if value is None:
        return np.zeros(m)
    v = np.asarray(value, dtype=float).ravel()
    if v.shape != (m,) or not np.all(np.isfinite(v)):
        raise ModelError(f"{name} must hold {m} finite modal values; got {value!r}")
    return v


def sample_reference(reference: Reference, dt: float = 1e-3, t_end: float | None = None,
                     n_joints: int | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Sample a reference (Move or ``(t, q, dq, ddq)``) on a uniform grid.

    Parameters
    ----------
    reference : casflex.moves.Move or casflex.moves.ShapedMove or tuple
        A move, or sampled arrays ``(t, q, dq, ddq)`` [s, rad, rad/s, rad/s²] (shape
        ``(N,)`` and ``(N, n)``), e.g. from :func:`casflex.shaping.apply_shaper`, sampled
        by :func:`casflex.moves.reference_sampler` (between samples ``q`` and ``dq`` are
        cubic Hermite interpolants, ``ddq`` is linear).
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
    sampler, t0, t_last, t_move_end = reference_sampler(reference, n_joints)
    t, _ = time_grid(t0, t_last if t_end is None else float(t_end), float(dt))
    q, dq, ddq = sampler(t)
    return t, q, dq, ddq, t_move_end


def simulate_prescribed(model: FlexibleModel, reference: Reference, dt: float = 1e-3,
                        t_end: float | None = None, method: str = "rk4",
                        delta0: ArrayLike | None = None, ddelta0: ArrayLike | None = None, *,
                        jit: bool | str | Sequence[str] = False,
                        cache_dir: str | Path | None = None,
                        **options) -> SimulationResult:
    """Simulate the arm with joints that follow a prescribed trajectory exactly.

    The modal row of eq. 118, ``M_δq q̈ + M_δδ δ̈ + h_δ = 0``, is integrated for
    ``z = [δ; δ̇]`` with the reference ``q(t), q̇(t), q̈(t)`` as input; the joint row
    gives the torques ``τ = M_qq q̈ + M_qδ δ̈ + h_q`` (the model's ``prescribed``
    function).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
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
        the compiler, so only the first call for a model pays the compilation; later
        calls, also from other processes, load it. Results equal the uncompiled path to
        round-off.
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
        Joint-count mismatch, bad step, times or method; ``"poly"`` with a sampled or planned
        reference or when the interpolation does not reach 1e-10; ``jit`` with another
        method or with ``kinematics="exact"``.
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
    ``∂Ω²/∂q`` and the gravity terms. With ``foreshortening=True`` the model keeps
    ``M_qq`` and ``g_q`` to δ² (the rest of M stays affine): ``M_qq`` gains
    ``½ Σ_jk δ_j δ_k H_jk(q)``, which adds ``−½ q̇ᵀ H_ak q̇`` to ``J_δ,ak`` (the δ rows
    stay of the form above) and terms in ``δ_j δ_k`` and ``δ_j δ̇_k`` to the torques;
    ``F`` then also gives ``H`` (as the coefficients of ``δ_j δ_k``), its q-Jacobian and
    the δ² part of ``g_q``. ``F(q(t))`` is analytic between the switches of
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
    CasADi's virtual machine (measured figures: ``benchmarks/README_model.md``).

    With ``kinematics="exact"`` M and h are not polynomial in δ: ``"poly"`` integrates
    the model whose ``(q, δ)``-coefficients are cut at degree 2 in δ
    (:mod:`casflex.simulate.exact_poly`; its coefficients are functions of ``(q, q̇)``
    interpolated the same way; the truncation measured at 0.1 % of the peak on Table 9
    move 3, ``benchmarks/README_fidelity.md``), equal to
    :func:`casflex.simulate.simulate_taylor` at degree 2 to the interpolation error, not
    to ``"rk4"``; ``jit`` is refused there.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
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
    check_method(method, METHODS)
    if jit is not False and method != "poly":
        raise ModelError(f"jit is an option of method='poly'; got method={method!r}")
    n, m = model.n, model.m
    f = model.functions()
    t, q, dq, ddq, t_move_end = sample_reference(reference, dt, t_end, n_joints=n)
    steps = t.size - 1
    z0 = np.r_[_initial(delta0, m, "delta0"), _initial(ddelta0, m, "ddelta0")]
    start = time.perf_counter()
    info = {}
    if method == "rk4":
        sampler = reference_sampler(reference, n).sample
        qh, dqh, ddqh = sampler(t[:-1] + 0.5 * dt)
        # the last stage of a step takes the left limit of q̈ (a bang-bang switch on a
        # node belongs to the next step); q and q̇ are continuous
        ddq_end = sampler(t[1:] - LEFT_LIMIT * dt)[2]
        P = np.hstack([q[:-1], dq[:-1], ddq[:-1], qh, dqh, ddqh, q[1:], dq[1:], ddq_end])
        acc = _rk4_steps(model, f, float(dt), steps)
        zs, taus, ddds = acc(z0, P.T)
        Z = np.vstack([z0, zs.full().T])
        tau_last, _ = f["prescribed"](q[-1], dq[-1], ddq[-1], Z[-1, :m], Z[-1, m:])
        tau = np.vstack([taus.full().T, tau_last.full().T])
    elif method == "poly":
        Z, tau, info = poly.simulate(model, reference, t, float(dt), z0, jit, cache_dir)
    else:
        Z = _integrate_adaptive(model, f, reference, t, z0, method, options)
        tm = f["prescribed"].map(t.size)
        tau = tm(q.T, dq.T, ddq.T, Z[:, :m].T, Z[:, m:].T)[0].full().T
    wall = time.perf_counter() - start
    hint = (f"the step dt = {dt} s is too large for the highest mode (RK4 needs "
            "omega dt < 2.8), or the move too fast for the model's small deflections")
    check_divergence("simulate_prescribed", t, {"delta": Z[:, :m], "ddelta": Z[:, m:],
                                                "tau": tau}, hint)
    delta, ddelta = Z[:, :m], Z[:, m:]
    tip, tip_rigid = tip_positions(f["tip"], q, delta)
    check_divergence("simulate_prescribed", t, {"tip_deflection": tip - tip_rigid}, hint,
                     limits={"tip_deflection": DIVERGED_DEFLECTION * robot_reach(model.robot)})
    return SimulationResult(t=t, q=q, dq=dq, ddq=ddq, tau=tau, delta=delta, ddelta=ddelta,
                            tip=tip, tip_rigid=tip_rigid, t_move_end=t_move_end,
                            method=method, info={"steps": steps, "wall_s": wall, **info})


def _rk4_steps(model, f, dt, steps):
    """mapaccum of one RK4 step of z = [δ; δ̇] with the reference as a parameter; the
    first stage also gives the torque and δ̈ at the start of the step (memoised)."""
    memo = step_cache(model)
    key = ("prescribed", float(dt), int(steps))
    cached = memo.get(key)
    if cached is not None:
        return cached
    n, m = model.n, model.m
    z = ca.MX.sym("z", 2 * m)
    p = ca.MX.sym("p", 9 * n)  # [q dq ddq] at t, t + dt/2, t + dt
    stages = [[p[3 * n * k + n * i:3 * n * k + n * (i + 1)] for i in range(3)]
              for k in range(3)]
    start = {}

    def rhs(zz, stage):  # stage: 0 (start), 1 (middle) or 2 (end of the step)
        q, dq, ddq = stages[stage]
        d, dd = zz[:m], zz[m:]
        if stage == 0:
            start["tau"], start["dddelta"] = f["prescribed"](q, dq, ddq, d, dd)
            return ca.vertcat(dd, start["dddelta"])
        return ca.vertcat(dd, f["dddelta"](q, dq, ddq, d, dd))

    z_next = rk4_step(rhs, z, dt, 0, 1, 2)
    step = ca.Function("rk4_prescribed", [z, p], [z_next, start["tau"], start["dddelta"]],
                       ["z", "p"], ["z_next", "tau", "dddelta"])
    acc = step.mapaccum("rk4_prescribed_acc", steps, [0], [0])
    memo[key] = acc
    return acc


def _integrate_adaptive(model, f, reference, t, z0, method, options):
    """Adaptive-step integration of z with the reference as a symbolic function of time,
    restarted at the switches of a move (the right-hand side jumps there)."""
    m = model.m
    z = ca.SX.sym("z", 2 * m)
    tt = ca.SX.sym("t")
    q, dq, ddq = reference_function(reference)(tt)
    ode = ca.vertcat(z[m:], f["dddelta"](q, dq, ddq, z[:m], z[m:]))
    dae = {"x": z, "t": tt, "ode": ode}
    # Every switch inside the run is a restart, on the output grid or not (a plan's nodes
    # seldom are): an adaptive step across a jump is as good as its step control's luck.
    # A switch within 1e-9 s of an output time is that time.
    cuts = [float(t[0])]
    for tc in getattr(reference, "breakpoints", ()):
        k = int(np.argmin(np.abs(t - tc)))
        tc = float(t[k]) if abs(t[k] - tc) < 1e-9 else float(tc)
        if t[0] < tc < t[-1]:
            cuts.append(tc)
    cuts.append(float(t[-1]))
    cuts = sorted(set(cuts))
    rows, x = [np.atleast_1d(np.asarray(z0, dtype=float))], z0
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        out = t[(t > a + 1e-12) & (t <= b + 1e-12)]
        on_grid = out.size and abs(out[-1] - b) <= 1e-12
        grid = out if on_grid else np.r_[out, b]  # integrate to the switch itself
        Z = integrate(casadi_integrator("prescribed", method, dae, a, grid, options), x)
        x = Z[-1]
        rows.append(Z if on_grid else Z[:-1])
    return np.vstack(rows)


def simulate_move(robot: Robot, move: Move, n_modes: int = 5, *, dt: float = 1e-3,
                  step: float | None = None, gravity: bool = False, method: str = "rk4",
                  jit: bool = False, cache_dir: str | Path | None = None,
                  progress: bool = True, shape_rates: bool = False,
                  foreshortening: bool = False, kinematics: str = "truncated"
                  ) -> tuple[SimulationResult, object, object]:
    """Build the modal model of a robot and simulate a move with perfect joint tracking.

    Parameters
    ----------
    robot : casflex.robot.Robot
    move : casflex.moves.Move
    n_modes : int
        Tracked modes.
    dt : float
        Step [s].
    step : float, optional
        Grid step of the modal tables [rad] (default of :func:`casflex.model.build_model`).
    gravity : bool
        Include the robot's gravity (neglected by default, as in §3.3.7.1).
    method : {"rk4", "poly", "cvodes", "idas"}
    jit : bool
        With ``method="poly"``: compile to C (:func:`simulate_prescribed`).
    cache_dir : str or pathlib.Path, optional
        Cache of the modal tables and of the compiled library.
    progress : bool
        Progress bar of the table build on stderr.
    shape_rates, foreshortening : bool
        Options of :class:`casflex.model.FlexibleModel` (off by default; fidelity on
        fast moves against their cost: ``benchmarks/README_fidelity.md``).
    kinematics : {"truncated", "exact"}
        The :class:`casflex.model.FlexibleModel` option (``"exact"``: the links rebuilt
        from the modal strains; with ``method="poly"`` truncated at degree 2 in δ, see
        :func:`simulate_prescribed`).

    Returns
    -------
    result : SimulationResult
        ``info["model_s"]`` holds the time spent building the model [s].
    model : casflex.model.FlexibleModel
    table : casflex.modal.ModalTable

    Examples
    --------
    >>> from casflex.robot import load
    >>> r, model, table = simulate_move(load("problems/arm2link.toml"),
    ...                                 Move([0, 0, 0], [-0.1, 0, 0], 0.5, settle=0.1),
    ...                                 n_modes=1, dt=0.01, step=np.radians(30),
    ...                                 cache_dir=False, progress=False)
    >>> float(r.t[-1]), model.m
    (0.6, 1)
    """
    from casflex.model import build_model

    t0 = time.perf_counter()
    model, table = build_model(robot, n_modes, step=step, cache_dir=cache_dir,
                               progress=progress, gravity="robot" if gravity else None,
                               shape_rates=shape_rates, foreshortening=foreshortening,
                               kinematics=kinematics)
    model_s = time.perf_counter() - t0
    options = {"jit": True, "cache_dir": cache_dir} if jit else {}
    result = simulate_prescribed(model, move, dt=dt, method=method, **options)
    result.info["model_s"] = model_s
    return result, model, table
