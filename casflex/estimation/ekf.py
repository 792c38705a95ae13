"""The extended Kalman filter of the modal states as CasADi functions (dissertation
§5.4–5.5).

The joint motion ``u = [q; q̇; q̈]`` is measured (encoders, eq. 158); the filter estimates
``x = Δ = [δ; δ̇]`` from accelerometer or strain signals (:mod:`casflex.sensors`) with the
tabulated plant of :mod:`casflex.estimation.plant`.

One step of :func:`ekf_step_function` takes the prior ``x̂_{k|k−1}``, ``P_{k|k−1}``, the
inputs ``u_k`` and the signals ``y_k`` and

1. evaluates the plant coefficients at ``u_k`` (held over the step; evaluating them at
   the RK4 stage times changes nothing measurable);
2. **update** with ``y_k``: ``h(x, u_k)`` is the kinematic measurement model with ``δ̈``
   from the plant; ``H = ∂h/∂x`` by CasADi differentiation; ``S = H P Hᵀ + R`` is
   factored by an unrolled Cholesky; ``K = P Hᵀ S⁻¹``; ``x̂⁺ = x̂ + K (y − h)``; Joseph
   form ``P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ``, symmetrised. With a diagonal ``R`` the
   same update is done channel by channel (scalar updates ``P − k bᵀ``, ``b = P hᵀ``,
   or in Joseph form, ``H`` linearised at the prior; ``update`` and ``joseph`` of
   :func:`ekf_step_function`);
3. **prediction** over ``dt`` by one classical RK4 step of the plant
   (:func:`casflex.simulate.integrators.rk4_step`); ``Φ = ∂x_{k+1}/∂x̂⁺``, by CasADi
   differentiation through that RK4 step for a second-order plant with ``jacobians =
   "exact"``, else (the RK4 step of the first-order part is linear) in closed form,
   ``Φ = Σ_{j≤4} (A dt)ʲ / j!`` with ``A = [0 I; J_δ J_δ̇]``; ``P_{k+1|k} = Φ P⁺ Φᵀ + Q
   dt``, symmetrised.

``Q`` is the continuous-time process-noise intensity of eq. 179 (``Ṗ = AP + PAᵀ + Q``),
applied as ``Q·dt`` per step; ``R`` is the covariance of one sample of the signals (eq.
185–186). Sensor dropouts: the ``mask`` input (1 valid, 0 missing) zeroes that channel's
innovation (NaN-safe: the masked ``y`` is never used in arithmetic) and its gain: the
sequential update gates the channel's ``1 / (h b + r)`` by the mask (``gate / (h b + r + 1 −
gate)``), the batch and square-root updates zero its row of ``H`` and replace its variance
by 1 with no correlation. Either way the gain column of that channel is exactly zero — the
update of that channel is skipped without branches, in Python and in C.

Bad samples: with ``guard=Guard(P0)`` (:mod:`casflex.estimation.guard`) the step skips
non-finite samples and samples that fail a per-channel innovation gate (as dropouts),
holds a non-finite ``u`` at its last valid value, resets a non-finite state or a
covariance outside its bounds, and returns a status word; on clean data it computes the
same numbers as the unguarded step.

The square-root form (§5.4.4.1, ``sqrt=True``) carries ``S`` with ``P = S Sᵀ`` and
replaces both covariance steps by triangularisations of the array algorithms,
``[√R, H S; 0, S] → [S_e, 0; K̄, S⁺]`` and ``[Φ S⁺, √(Q dt)] → [S_{k+1}, 0]`` (QR of the
transposed arrays); ``P`` stays symmetric positive semi-definite by construction.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> from casflex.sensors import SensorSet, StrainPair
>>> from casflex.estimation.plant import tabulate_plant
>>> robot = load("problems/arm2link.toml")
>>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3), name="sg")])
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
>>> plant = tabulate_plant(model)
>>> step = ekf_step_function(plant, ss, Q=5e-6, R=9e-14, dt=1e-3)
>>> step.name_in(), step.name_out()
(['x', 'P', 'u', 'y', 'mask'], ['x_next', 'P_next', 'x_post'])
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import choice, fail, number, square_matrix
from casflex.estimation import guard as gd
from casflex.estimation.lookup import shared_lookup_function
from casflex.estimation.plant import FlexiblePlant, tabulate_plant
from casflex.sensors import SensorSet, kinematic_measurement, measurement_with_entries
from casflex.simulate.integrators import rk4_step

if TYPE_CHECKING:
    from casflex.model import FlexibleModel

__all__ = [
    "ekf_step_function",
    "full_state_step_function",
    "ekf_functions",
    "rigid_signal_function",
]


def _chol(S):
    """Unrolled Cholesky factor (lower) of a symmetric positive definite SX matrix."""
    r = S.shape[0]
    L = ca.SX(r, r)
    for j in range(r):
        s = S[j, j]
        for k in range(j):
            s = s - L[j, k] ** 2
        L[j, j] = ca.sqrt(s)
        for i in range(j + 1, r):
            t = S[i, j]
            for k in range(j):
                t = t - L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    return L


def _lower_solve(L, B):
    """Solve L X = B by forward substitution (L lower triangular)."""
    r = L.shape[0]
    rows = []
    for i in range(r):
        t = B[i, :]
        for k in range(i):
            t = t - L[i, k] * rows[k]
        rows.append(t / L[i, i])
    return ca.vertcat(*rows)


def _upper_solve(U, B):
    """Solve U X = B by back substitution (U upper triangular)."""
    r = U.shape[0]
    rows = [None] * r
    for i in reversed(range(r)):
        t = B[i, :]
        for k in range(i + 1, r):
            t = t - U[i, k] * rows[k]
        rows[i] = t / U[i, i]
    return ca.vertcat(*rows)


def _tria(A):
    """Lower-triangular L with L Lᵀ = A Aᵀ (QR of Aᵀ), shape rows(A) × rows(A)."""
    _, R = ca.qr(A.T)
    return R.T[:, :A.shape[0]]


def ekf_step_function(plant: FlexiblePlant, sensors: SensorSet, Q: ArrayLike, R: ArrayLike,
                      dt: float, *, sqrt: bool = False, coriolis: bool = True,
                      stiffness_scale: float = 1.0, rigid_removed: bool = False,
                      linear_measurement: bool = False, prefilter: float | None = None,
                      name: str = "ekf_step", jacobians: str = "exact", cse: bool = True,
                      update: str = "auto", lean: bool = True, joseph: bool = False,
                      guard: gd.Guard | None = None, recursive: bool = True,
                      shared: bool = True) -> ca.Function:
    """One EKF step as an SX ``casadi.Function`` (module docstring).

    Parameters
    ----------
    plant : FlexiblePlant
    sensors : casflex.sensors.SensorSet
        The model of ``plant`` must tabulate ``sensors.points``.
    Q : float, array_like
        Continuous process-noise intensity on ``[δ; δ̇]`` (scalar × I, diagonal or
        matrix), applied as ``Q dt`` per step.
    R : float, array_like
        Covariance of one sample of the signals.
    dt : float
        Sample time [s].
    sqrt : bool
        Square-root form: the covariance input/outputs are ``S`` (``P = S Sᵀ``), named
        ``S``, ``S_next``.
    coriolis, stiffness_scale
        Estimator-model variations (:meth:`FlexiblePlant.coefficients`).
    rigid_removed : bool
        The signals given are ``y − y_rigid(u)`` (rigid-motion part of the accelerometers
        removed, e.g. before a high-pass prefilter); the model subtracts it as well.
    linear_measurement : bool
        Use the measurement model linearised at Δ = 0 (eq. 164–167) instead of the full
        kinematic one (default). Cheaper, but the neglected second-order terms (e.g. the
        centripetal acceleration of the flexible rotation rates) are large for an arm
        whose tip deflects by several cm (Table 8 arm): the velocity estimates fail.
    prefilter : float, optional
        Cut-off ω_c [rad/s] of a first-order high-pass applied to the signals against
        offsets (§5.5.1.1; :func:`highpass_cutoff` gives one decade below the lowest
        natural frequency). The same filter is applied to the predicted signals
        ``h(x̂⁻, u)`` and the innovation is the difference of the two filtered signals:
        filtering the measurements alone (the dissertation's set-up) also removes the
        low-frequency part of the flexible signals during a move, which biases the
        velocity estimates. Adds the input ``f`` and output ``f_next`` (filter state,
        4 r numbers, start at 0: the filter at rest).
    name : str
    jacobians : {"exact", "first_order", "linearized"}
        ``"exact"``: ``Φ`` by CasADi differentiation through the RK4 step and ``H`` through
        ``h`` and the plant at the estimate. ``"first_order"`` (second-order plants): the
        means use the full plant, but ``Φ`` and the plant's share of ``H`` are those of
        its first-order part (``∂δ̈/∂x = [J_δ, J_δ̇]``, i.e. the small second-order terms
        are left out of the covariance propagation): fewer operations. The same as
        ``"exact"`` for first-order plants. ``"linearized"``: as ``"first_order"``, and
        ``∂h/∂[x; δ̈]`` taken at ``Δ = 0`` (``δ̈ = r₀``), i.e. ``H`` is that of the
        expansion of the measurement to first order in Δ, a function of ``u`` only; ``h``
        itself stays the full kinematic model. Fewer operations again; the δ̇ errors
        change somewhat on the Table 9 studies with accelerometers (all still > 100×
        below the states).
    cse : bool
        Common-subexpression elimination of the SX graph (CasADi option ``cse``; same
        operations, so the same results, fewer instructions).
    update : {"auto", "batch", "sequential"}
        Measurement update. ``"batch"``: all channels at once (``S = H P Hᵀ + R``,
        unrolled Cholesky, ``K = P Hᵀ S⁻¹``, Joseph form). ``"sequential"`` (diagonal
        ``R``, not with ``sqrt``): one scalar update per channel (form: ``joseph``)
        evaluated on one triangle and mirrored (exactly symmetric), with ``H`` linearised at
        the prior for every channel, so the same update as ``"batch"`` up to rounding
        (no square roots, no triangular solves: fewer operations).
        ``"auto"``: ``"sequential"`` when ``R`` is diagonal and ``sqrt`` is false.
    joseph : bool
        With the sequential update: each scalar covariance update in Joseph form
        ``(I − k h) P (I − k h)ᵀ + k r kᵀ`` (six operations per entry of one triangle);
        ``False`` (default): the standard form ``P − k bᵀ``, ``b = P hᵀ`` (two), the
        same for the optimal gain ``k = b / (h b + r)`` to rounding
        (``tests/estimation/test_ekf_structure.py``). The batch and square-root updates
        are unchanged.
    lean : bool
        Evaluate in the measurement model only the modal-table entries it uses, from one
        small B-spline (:func:`casflex.sensors.kinematic_measurement`, ``lean``): the
        same expressions to rounding; ``False``: the model's spline of every quantity.
    recursive : bool
        The accelerometer signals by a recursive pass over the factors of their pose
        (:func:`casflex.sensors.kinematic_measurement`, ``recursive``): the same signals to
        rounding on a smaller graph, so ``h`` and its Jacobian ``H`` take fewer operations;
        ``False``: the time derivatives of the whole pose (the step before).
    shared : bool
        With ``lean`` and the plant's local lookup over the model's one-axis grid: the
        plant's spline table and the sensor entries with their time derivatives in one
        lookup function (the entries and their rates from one knot search and one basis,
        the plant's wide table by CasADi's B-spline node: :mod:`casflex.estimation.
        lookup`), the same splines to rounding; ``False``: each table by its own lookup
        and the entries' derivatives by differentiation (the step before).
    guard : casflex.estimation.Guard, optional
        Guarded step (:mod:`casflex.estimation.guard`: non-finite inputs, innovation
        gating, covariance bounds, status word; not with ``sqrt``). Adds the input
        ``u_last`` (the last valid ``u``, feed ``u_next`` back) and the outputs ``u_next``
        and ``status``. Where no check triggers, the outputs are those of the unguarded
        step.

    Returns
    -------
    casadi.Function
        ``(x, P, u, y, mask[, f][, u_last]) -> (x_next, P_next, x_post[, f_next][, u_next,
        status])``: the prior of the next step, its covariance, and the filtered estimate
        ``x̂_{k|k}`` (and, with ``guard``, the input held and the status word).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> f = ekf_step_function(tabulate_plant(model), ss, 5e-6, 9e-14, 1e-3)
    >>> x1, P1, xp = f([1e-3, 0], np.eye(2) * 1e-4, np.zeros(9), [0, 0], [1, 1])
    >>> bool(abs(float(xp[0])) < 1e-4)   # strain zero: the estimate moves toward δ = 0
    True
    >>> g = ekf_step_function(tabulate_plant(model), ss, 5e-6, 9e-14, 1e-3, update="batch",
    ...                       jacobians="linearized")
    >>> xb = g([1e-3, 0], np.eye(2) * 1e-4, np.zeros(9), [0, 0], [1, 1])[2]
    >>> bool(np.allclose(xb, xp, rtol=1e-9, atol=1e-15))   # strain is linear in δ: same H
    True

    Guarded: a sample of 1 (a strain of 100 %) is rejected, the step only predicts:

    >>> from casflex.estimation import Guard, status_names
    >>> h = ekf_step_function(tabulate_plant(model), ss, 5e-6, 9e-14, 1e-3,
    ...                       guard=Guard(np.eye(2) * 1e-4))
    >>> out = h([1e-3, 0], np.eye(2) * 1e-4, np.zeros(9), [1.0, 0], [1, 1], np.zeros(9))
    >>> status_names(out[4])
    ['sample_rejected']
    """
    model = plant.model
    n, m = model.n, model.m
    nx = 2 * m
    ny = sensors.n_outputs
    dt = number(float(dt), "dt", low=0.0, low_open=True)
    choice(jacobians, "jacobians", ("exact", "first_order", "linearized"))
    Qc = square_matrix(Q, nx, "Q", psd=True)
    Rm_ = square_matrix(R, ny, "R", psd=True)
    if guard is not None and sqrt:
        raise fail("guard", "Guard(...)", "needs the plain form (sqrt=False)")
    if guard is not None and guard.P_reset.shape != (nx, nx):
        raise fail("guard.P_reset", guard.P_reset.shape, f"must be {nx} x {nx}")
    x = ca.SX.sym("x", nx)
    Pin = ca.SX.sym("S" if sqrt else "P", nx, nx)
    u = ca.SX.sym("u", 3 * n)
    y = ca.SX.sym("y", ny)
    mask = ca.SX.sym("mask", ny)
    filt = ca.SX.sym("f", 4 * ny)
    q, dq, ddq = u[:n], u[n:2 * n], u[2 * n:]
    measure, spline_values = _measurement_and_tables(plant, sensors, u, name, lean, recursive,
                                                     shared)
    # placeholders: no derivative ever flows into the coefficient tables (AD through the
    # spline call nodes would evaluate their derivative splines for nothing)
    coef = plant.coefficients(q, dq, ddq, coriolis, stiffness_scale, quadratic=True,
                              spline_values=spline_values)
    r0, Jd, Jv = ca.SX.sym("r0", m), ca.SX.sym("Jd", m, m), ca.SX.sym("Jv", m, m)
    W = ca.SX.sym("W", coef[3].shape)
    holders = ca.vertcat(r0, ca.vec(Jd), ca.vec(Jv), ca.vec(W))
    values = ca.vertcat(coef[0], ca.vec(coef[1]), ca.vec(coef[2]), ca.vec(coef[3]))

    def accel(xx):
        out = r0 + Jd @ xx[:m] + Jv @ xx[m:]
        return out + W @ plant.quadratic_terms(xx) if plant.pairs else out

    def f(xx):
        return ca.vertcat(xx[m:], accel(xx))

    exact_jac = jacobians == "exact" or not plant.pairs

    if linear_measurement:
        # eq. 164: y = h0(u) + ∂h/∂x x + ∂h/∂δ̈ δ̈ at Δ = 0, δ̈ from the plant
        h0, Jx = measure(ca.DM.zeros(nx), ca.DM.zeros(m))
        hx = h0 + Jx @ ca.vertcat(x, accel(x))
        H = ca.jacobian(hx, x)
    else:
        # ∂h/∂[x; δ̈] at (x, δ̈(x)), then the chain rule through δ̈ = r0 + Jd δ + Jv δ̇
        hx, Jxa = measure(x, accel(x))
        if jacobians == "linearized":
            # ∂h/∂[x; δ̈] at Δ = 0 (δ̈ = r0 there): H of the expansion of h to first order
            Jxa = measure(ca.DM.zeros(nx), r0)[1]
        dacc = ca.jacobian(accel(x), x) if exact_jac else ca.horzcat(Jd, Jv)
        H = Jxa[:, :nx] + Jxa[:, nx:] @ dacc
    if rigid_removed:
        hx = hx - rigid_signal_function(model, sensors)(u)
    valid = ca.vertcat(*[mask[i] > 0.5 for i in range(ny)])
    if prefilter is not None:
        wc = number(float(prefilter), "prefilter", low=0.0, low_open=True)

    # a guarded step never does arithmetic with a non-finite sample
    yv = y if guard is None else ca.vertcat(*[ca.if_else(gd.is_finite(y[i]), y[i], 0)
                                              for i in range(ny)])

    def innovation(valid):
        if prefilter is None:
            return ca.vertcat(*[ca.if_else(valid[i], yv[i] - hx[i], 0)
                                for i in range(ny)]), None
        # the same first-order high-pass (Tustin) on the signals and on the predicted
        # signals; the innovation compares the two (offsets and the low-frequency part
        # drop out of both). State f = [y_prev, hp_y, h_prev, hp_h]; a missing sample
        # holds the filter of its channel.
        fa = (2.0 - wc * dt) / (2.0 + wc * dt)
        fb = 2.0 / (2.0 + wc * dt)
        yprev, hpy, hprev, hph = (filt[i * ny:(i + 1) * ny] for i in range(4))
        yin = ca.vertcat(*[ca.if_else(valid[i], yv[i], yprev[i]) for i in range(ny)])
        hin = ca.vertcat(*[ca.if_else(valid[i], hx[i], hprev[i]) for i in range(ny)])
        hpy_n = fa * hpy + fb * (yin - yprev)
        hph_n = fa * hph + fb * (hin - hprev)
        e = ca.vertcat(*[ca.if_else(valid[i], hpy_n[i] - hph_n[i], 0) for i in range(ny)])
        return e, ca.vertcat(yin, hpy_n, hin, hph_n)

    flags = {}
    if guard is not None:
        # a non-finite sample is a dropout (y itself is replaced by 0 below)
        finite_y = gd.is_finite(y)
        flags["sample_nonfinite"] = gd.any_of([ca.logic_and(valid[i], 1 - finite_y[i])
                                               for i in range(ny)])
        valid = ca.vertcat(*[ca.logic_and(valid[i], finite_y[i]) for i in range(ny)])
    e, f_next = innovation(valid)
    if guard is not None and np.isfinite(guard.gate):
        # normalised innovation of every channel against the prior: ν² / S_ii > gate
        Pg = 0.5 * (Pin + Pin.T)
        reject = []
        for i in range(ny):
            Sii = ca.dot(H[i, :].T, Pg @ H[i, :].T) + float(Rm_[i, i])
            reject.append(ca.logic_and(valid[i], e[i] * e[i] > guard.gate * Sii))
        flags["sample_rejected"] = gd.any_of(reject)
        valid = ca.vertcat(*[ca.logic_and(valid[i], 1 - reject[i]) for i in range(ny)])
        e, f_next = innovation(valid)
    diagonal_r = not np.any(Rm_ - np.diag(np.diag(Rm_)))
    choice(update, "update", ("auto", "batch", "sequential"))
    if update == "sequential" and (sqrt or not diagonal_r):
        raise fail("update", update, "needs a diagonal R and sqrt=False")
    sequential = update == "sequential" or (update == "auto" and diagonal_r and not sqrt)
    if not sequential:  # a masked channel has the row 0 and the variance 1: no gain
        Mv = ca.diag(valid)
        Hm = Mv @ H
        Rm = Mv @ ca.DM(Rm_) @ Mv + ca.diag(1 - valid)
    I = ca.SX.eye(nx)
    if sequential:
        # one scalar update per channel (diagonal R: the same update as the batch
        # one, H linearised at the prior); a masked channel gets the gain k = 0 (its
        # valid flag gates 1 / (h b + r): no masked copy of H and R to form)
        # The correction dx = x_post - x is summed on its own (its first term is k e, not
        # x + k e - x): the innovations of the linearised model need it, not x_post
        P = 0.5 * (Pin + Pin.T)
        dx = ca.SX.zeros(nx)
        for j in range(ny):
            hj = H[j, :]
            ej = e[j] - hj @ dx  # innovation of the linearised model at the prior
            dx, P = _scalar_update(P, dx, hj, ej, float(Rm_[j, j]), joseph, valid[j])
        xp, Pp = x + dx, P
    elif not sqrt:
        P = 0.5 * (Pin + Pin.T)
        PHt = P @ Hm.T
        Sinn = Hm @ PHt + Rm
        Ls = _chol(Sinn)
        Kt = _upper_solve(Ls.T, _lower_solve(Ls, PHt.T))  # K^T = S^-1 H P
        K = Kt.T
        xp = x + K @ e
        IKH = I - K @ Hm
        # Joseph form, each symmetric product evaluated on one triangle and mirrored
        Pp = _sandwich(IKH, P) + _sandwich(K, Rm)
    else:
        S = Pin
        sqR = _chol(Rm)
        pre = ca.blockcat([[sqR, Hm @ S], [ca.SX(nx, ny), S]])
        post = _tria(pre)
        Se, Kbar, Sp = post[:ny, :ny], post[ny:, :ny], post[ny:, ny:]
        xp = x + Kbar @ _lower_solve(Se, e)
    # prediction: one RK4 step of the (affine) plant, coefficients held at u_k
    xs = ca.SX.sym("xs", nx)
    xn_s = rk4_step(f, xs, dt)
    if exact_jac and plant.pairs:
        Phi = ca.substitute(ca.jacobian(xn_s, xs), xs, xp)
    else:  # RK4 of the (first-order part of the) plant: a polynomial in its matrix
        Phi = _rk4_transition(Jd, Jv, dt)
    xn = ca.substitute(xn_s, xs, xp)
    Qd = Qc * dt
    if not sqrt:
        Pn = _sandwich(Phi, Pp) + ca.DM(Qd)
    else:
        sqQ = ca.DM(np.linalg.cholesky(Qd) if np.all(np.linalg.eigvalsh(Qd) > 0)
                    else _psd_sqrt(Qd))
        Pn = _tria(ca.horzcat(Phi @ Sp, sqQ))
    cov = "S" if sqrt else "P"
    ins, names_in = [x, Pin, u, y, mask], ["x", cov, "u", "y", "mask"]
    outs, names_out = [xn, Pn, xp], ["x_next", cov + "_next", "x_post"]
    if prefilter is not None:
        ins.append(filt)
        names_in.append("f")
        outs.append(f_next)
        names_out.append("f_next")
    keys = list(flags)
    both = ca.substitute([*outs, *flags.values()], [holders], [values])
    outs, flags = both[:len(outs)], dict(zip(keys, both[len(outs):], strict=True))
    if guard is not None:
        u_last = ca.SX.sym("u_last", 3 * n)
        outs = _guarded(outs, flags, guard, x, Pin, u, u_last,
                        filt if prefilter is not None else None)
        ins.append(u_last)
        names_in.append("u_last")
        names_out += ["u_next", "status"]
    return ca.Function(name, ins, outs, names_in, names_out, {"cse": bool(cse)})


def _measurement_and_tables(plant, sensors, u, name, lean, recursive, shared):
    """The measurement of the step at ``u``, ``(x, dddelta) -> (y, ∂y/∂[x; dddelta])``,
    and the plant's spline values at ``u`` (None: :meth:`FlexiblePlant.coefficients` looks
    them up). With ``shared`` and one common one-axis grid, both tables come from one
    :func:`shared_lookup_function` call at the shape joint of ``u``; else the measurement
    looks its entries up itself."""
    model, n = plant.model, plant.n
    table, provider = plant.table, model.provider
    common = (shared and lean and plant.lookup == "local" and table is not None
              and len(plant.shape_joints) == 1
              and getattr(provider, "method", None) == "bspline"
              and tuple(getattr(provider, "shape_joints", ())) == plant.shape_joints
              and getattr(provider, "table", None) is not None
              and len(provider.table.grid) == 1
              and np.array_equal(provider.table.grid[0], table.grid[0])
              and tuple(provider.table.periodic) == tuple(table.periodic))
    lean_h = measurement_with_entries(model, sensors, recursive=recursive) if common else None
    if lean_h is None:
        hj = _with_jacobian(kinematic_measurement(model, sensors, lean=lean,
                                                  lookup=plant.lookup, recursive=recursive))
        return (lambda xx, acc: hj(xx, u, acc)), None
    hfun, cols = lean_h
    j = plant.shape_joints[0]
    sym = hfun.sx_in()
    rates = ca.depends_on(hfun.call(sym)[0], ca.vertcat(sym[4], sym[5]))  # accelerometers
    tables = {"coef": (plant.spline_columns(), False)}
    if cols.shape[-1]:
        tables["sensor_entries"] = (cols, rates)
    look = shared_lookup_function(f"{name}_tables", table.grid[0], bool(table.periodic[0]),
                                  tables)
    out = look(u[j], u[n + j], u[2 * n + j])
    k = cols.shape[-1]
    entries = (out[1:] if rates else [out[1], ca.SX.zeros(k), ca.SX.zeros(k)]) if k \
        else [ca.SX(0, 1)] * 3

    hj = _with_jacobian(hfun)
    return (lambda xx, acc: hj(xx, u, acc, *entries)), out[0]


def _with_jacobian(hfun):
    """``hfun`` (inputs ``x, u, dddelta, ...``, output ``y``) with ``J = ∂y/∂[x; dddelta]`` as
    a second output, differentiated on ``hfun``'s own symbols (its table entries are
    inputs or its own lookups, not yet the outputs of the step's shared lookup call).

    Forward mode (one sweep per column of ``J``) or reverse (one per signal), whichever
    gives fewer operations: forward is ~360 of the default step's ~5 900 fewer, but on a
    graph with lookup calls inside it carries zero tangents through each of them (a
    derivative call each) into every product that uses an entry, ~1 000 more."""
    sym = hfun.sx_in()
    y = hfun.call(sym)[0]
    z = ca.vertcat(sym[0], sym[2])
    candidates = [ca.Function(hfun.name() + "_jac", sym, [y, J], {"cse": True})
                  for J in (ca.jtimes(y, z, ca.SX.eye(z.numel())),
                            ca.jtimes(y, z, ca.SX.eye(y.numel()), True).T)]
    return min(candidates, key=lambda f: f.n_instructions())


def _guarded(outs, flags, guard, x, Pin, u, u_last, filt=None):
    """The outputs of a step with the input checks substituted and the outputs checked
    (:mod:`casflex.estimation.guard`); ``[..., u_next, status]`` appended. A non-finite
    entry of the prefilter state ``filt`` is restarted at 0 (reported as a state reset)."""
    P_reset, x_reset = ca.DM(guard.P_reset), ca.DM(guard.x_reset)
    u_in, u_held = gd.held(u, u_last)
    x_ok = gd.all_of(gd.is_finite(x))
    Psym = 0.5 * (Pin + Pin.T)
    P_ok = ca.logic_and(x_ok, gd.covariance_ok(Psym, guard.floor, guard.ceiling))
    x_in = ca.if_else(x_ok, x, x_reset)
    P_in = ca.if_else(P_ok, Psym, P_reset)
    keys = list(flags)
    old, new = [x, Pin, u], [x_in, P_in, u_in]
    f_bad = ca.SX(0)
    if filt is not None:
        f_in, f_bad = gd.held(filt, ca.DM.zeros(filt.numel()))
        old.append(filt)
        new.append(f_in)
    both = ca.substitute([*outs, *flags.values()], old, new)
    outs, flags = both[:len(outs)], dict(zip(keys, both[len(outs):], strict=True))
    xn, Pn, xp = outs[:3]
    xn_ok = ca.logic_and(gd.all_of(gd.is_finite(xn)), gd.all_of(gd.is_finite(xp)))
    Pn_ok = ca.logic_and(xn_ok, gd.covariance_ok(Pn, guard.floor, guard.ceiling))
    # a held input makes the prediction uncertain by an unknown amount: restart from P_reset
    # (else the gate may reject the true samples that follow, whose innovations grew)
    Pn_ok = ca.logic_and(Pn_ok, 1 - u_held)
    outs[0] = ca.if_else(xn_ok, xn, x_reset)
    outs[1] = ca.if_else(Pn_ok, Pn, P_reset)
    outs[2] = ca.if_else(xn_ok, xp, x_reset)
    flags["input_held"] = u_held  # of the raw u: not substituted
    flags["state_reset"] = ca.logic_or(ca.logic_or(1 - x_ok, 1 - xn_ok), f_bad)
    flags["covariance_reset"] = ca.logic_or(1 - P_ok, 1 - Pn_ok)
    status = sum(gd.STATUS_BITS[k] * v for k, v in flags.items())
    return [*outs, u_in, status]


def _rk4_transition(Jd, Jv, dt):
    """``Φ = I + hA + (hA)²/2 + (hA)³/6 + (hA)⁴/24`` for ``A = [0 I; J_δ J_δ̇]``: the
    Jacobian of one classical RK4 step of ``ẋ = A x + r₀`` (exactly what
    :func:`casflex.simulate.integrators.rk4_step` computes for a linear right-hand side),
    by Horner's rule on the block structure of ``A``: its zero and identity blocks stay
    structural, so no product with them is formed."""
    m = Jd.shape[0]
    A = ca.blockcat([[ca.SX(m, m), ca.SX.eye(m)], [Jd, Jv]])
    eye = ca.SX.eye(2 * m)
    Phi = eye + A * (dt / 4.0)
    for c in (3.0, 2.0, 1.0):
        Phi = eye + (dt / c) * (A @ Phi)
    return Phi


def _scalar_update(P, x, h, e, r, joseph=True, gate=1.0):
    """Update of ``(x, P)`` (P symmetric) with one scalar measurement: row ``h``,
    innovation ``e``, variance ``r``; its lower triangle evaluated and mirrored (exactly
    symmetric). ``gate`` (1 or 0, SX) replaces ``1 / (h b + r)`` by ``gate / (h b + r + 1 −
    gate)``: 0 gives ``k = 0``, no update (a masked channel); 1 the same values.

    ``joseph``: Joseph form ``(I − k h) P (I − k h)ᵀ + k r kᵀ`` in closed form for the
    rank-one ``k h`` (valid for any gain ``k``): with ``b = P hᵀ``, ``(I − k h) P = P − k
    bᵀ``, and times ``(I − k h)ᵀ`` it is ``P − k bᵀ − c kᵀ`` with ``c = b − k (h b)``.
    Else the standard form ``P − k bᵀ`` (the same for the optimal gain ``k = b / (h b +
    r)``, two operations per entry instead of six)."""
    nx = P.shape[0]
    b = P @ h.T
    hb = ca.dot(h.T, b)
    if isinstance(gate, float) and gate == 1.0:
        inv = 1.0 / (hb + r)
    else:  # 1 - gate keeps the denominator >= 1 where gate = 0 (also for r = 0, h = 0);
        # (if_else nodes would spread through every product with k in CasADi's graph)
        inv = gate / ((hb + r) + (1 - gate))
    k = b * inv
    if joseph:
        c = b - k * hb
        rk = r * k
    out = ca.SX(nx, nx)
    for i in range(nx):
        for l in range(i + 1):
            if joseph:
                v = P[i, l] - k[i] * b[l] - c[i] * k[l] + rk[i] * k[l]
            else:
                v = P[i, l] - k[i] * b[l]
            out[i, l] = v
            if i != l:
                out[l, i] = v
    return x + k * e, out


def _sandwich(A, P):
    """``A P Aᵀ`` for symmetric ``P``: the lower triangle evaluated, the upper mirrored
    (exactly symmetric, fewer operations than the full product)."""
    B = A @ P
    r = A.shape[0]
    out = ca.SX(r, r)
    for i in range(r):
        for j in range(i + 1):
            v = ca.dot(B[i, :].T, A[j, :].T)
            out[i, j] = v
            if i != j:
                out[j, i] = v
    return out


def full_state_step_function(plant: FlexiblePlant, sensors: SensorSet, Q: ArrayLike,
                             R: ArrayLike, dt: float, *, Q_jerk: ArrayLike,
                             R_encoder: ArrayLike, coriolis: bool = True,
                             name: str = "ekf_full_step") -> ca.Function:
    """One step of the full-state EKF: joints and modes from encoders and sensors.

    For set-ups with encoders and accelerometers but no measured ``q̇``, ``q̈``: the state is
    ``z = [q; q̇; q̈; δ; δ̇]`` (3n + 2m). The joints follow a kinematic model driven by
    white jerk (``d q̈/dt = w``, intensity ``Q_jerk``; no torques or joint dynamics needed),
    the modes the tabulated plant at the joint states of ``z``. The measurements are the
    encoder angles ``q`` and the signals of ``sensors``, ``y = [q_enc; y_sensors]``.

    The step is that of :func:`ekf_step_function` (update with Joseph form, then one RK4
    step; Jacobians by CasADi differentiation, through the plant's spline tables as well):
    the plant coefficients are evaluated at the posterior joint state and held over the
    step (the joints move by ``q̇ dt`` in it), the RK4 step integrates the joint chain and
    the modes together.

    Parameters
    ----------
    plant : FlexiblePlant
    sensors : casflex.sensors.SensorSet
    Q : float or array_like
        Continuous process-noise intensity on ``[δ; δ̇]`` (as in :func:`ekf_step_function`).
    R : float or array_like
        Covariance of one sample of the sensor signals.
    dt : float
        Sample time [s].
    Q_jerk : float or array_like
        Continuous intensity of the joint jerk [rad²/s⁵] (scalar, n variances or n × n).
    R_encoder : float or array_like
        Covariance of one encoder sample [rad²].
    coriolis : bool
        As in :func:`ekf_step_function`.
    name : str

    Returns
    -------
    casadi.Function
        ``(x, P, u, y, mask) -> (x_next, P_next, x_post)`` with ``x`` the full state
        ``z``, ``u`` empty (0 × 1, the joint motion is estimated) and ``y``, ``mask`` of
        ``n + r`` rows (encoders first). Runs with :func:`run_ekf` (``u=None``).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, axes="xy")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> f = full_state_step_function(tabulate_plant(model, cache_dir=False), ss, 5e-6,
    ...                              6e-6, 1e-3, Q_jerk=1e2, R_encoder=1e-8)
    >>> f.size1_in("x"), f.size1_in("y")
    (11, 5)
    """
    model = plant.model
    n, m = model.n, model.m
    nx = 3 * n + 2 * m
    ns = sensors.n_outputs
    ny = n + ns
    dt = number(float(dt), "dt", low=0.0, low_open=True)
    Qf = square_matrix(Q, 2 * m, "Q", psd=True)
    Qj = square_matrix(Q_jerk, n, "Q_jerk", psd=True)
    Rs = square_matrix(R, ns, "R", psd=True)
    Re = square_matrix(R_encoder, n, "R_encoder", psd=True)
    Rall = np.zeros((ny, ny))
    Rall[:n, :n], Rall[n:, n:] = Re, Rs
    Qc = np.zeros((nx, nx))
    Qc[2 * n:3 * n, 2 * n:3 * n] = Qj
    Qc[3 * n:, 3 * n:] = Qf
    hkin = kinematic_measurement(model, sensors)
    x = ca.SX.sym("x", nx)
    Pin = ca.SX.sym("P", nx, nx)
    u = ca.SX.sym("u", 0, 1)
    y = ca.SX.sym("y", ny)
    mask = ca.SX.sym("mask", ny)

    def parts(z):
        return z[:n], z[n:2 * n], z[2 * n:3 * n], z[3 * n:]

    def coefs(z):
        q, dq, ddq, _ = parts(z)
        return plant.coefficients(q, dq, ddq, coriolis, quadratic=True)

    def accel(c, xf):
        r0, Jd, Jv, W = c
        out = r0 + Jd @ xf[:m] + Jv @ xf[m:]
        return out + W @ plant.quadratic_terms(xf) if plant.pairs else out

    def meas(z):
        q, dq, ddq, xf = parts(z)
        uu = ca.vertcat(q, dq, ddq)
        return ca.vertcat(q, hkin(xf, uu, accel(coefs(z), xf)))

    # update
    hx = meas(x)
    H = ca.jacobian(hx, x)
    valid = ca.vertcat(*[mask[i] > 0.5 for i in range(ny)])
    e = ca.vertcat(*[ca.if_else(valid[i], y[i] - hx[i], 0) for i in range(ny)])
    Mv = ca.diag(valid)
    Hm = Mv @ H
    Rm = Mv @ ca.DM(Rall) @ Mv + ca.diag(1 - valid)
    P = 0.5 * (Pin + Pin.T)
    PHt = P @ Hm.T
    Ls = _chol(Hm @ PHt + Rm)
    K = _upper_solve(Ls.T, _lower_solve(Ls, PHt.T)).T
    xp = x + K @ e
    Pp = _sandwich(ca.SX.eye(nx) - K @ Hm, P) + _sandwich(K, Rm)
    # prediction: RK4 of the joint chain and the modes, coefficients held at the posterior
    xs = ca.SX.sym("xs", nx)
    c = coefs(xs)

    def f(z):
        _, dq, ddq, xf = parts(z)
        return ca.vertcat(dq, ddq, ca.SX.zeros(n), xf[m:], accel(c, xf))

    xn_s = rk4_step(f, xs, dt)
    Phi_s = ca.jacobian(xn_s, xs)
    xn = ca.substitute(xn_s, xs, xp)
    Phi = ca.substitute(Phi_s, xs, xp)
    Pn = _sandwich(Phi, Pp) + ca.DM(Qc * dt)
    return ca.Function(name, [x, Pin, u, y, mask], [xn, Pn, xp],
                       ["x", "P", "u", "y", "mask"], ["x_next", "P_next", "x_post"],
                       {"cse": True})


def _psd_sqrt(A):
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    return V @ np.diag(np.sqrt(np.clip(w, 0, None)))


def rigid_signal_function(model: FlexibleModel, sensors: SensorSet) -> ca.Function:
    """``u -> y_rigid``: the rigid-motion part contained in the signals (zero for strain
    gauges and for accelerometers declared with ``rigid = false``).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Must tabulate ``sensors.points``.
    sensors : casflex.sensors.SensorSet

    Returns
    -------
    casadi.Function
        ``y_rigid (u) -> y`` with ``u = [q; q̇; q̈]`` (3n), ``sensors.n_outputs`` signals.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, axes="z")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> float(rigid_signal_function(model, ss)(np.zeros(9)))  # local z points down
    -9.81
    """
    return kinematic_measurement(model, sensors, name="y_rigid", rigid_part=True)


def ekf_functions(model: FlexibleModel, sensors: SensorSet, Q: ArrayLike, R: ArrayLike,
                  dt: float, *, plant: FlexiblePlant | None = None, sqrt: bool = False,
                  coriolis: bool = True, stiffness_scale: float = 1.0,
                  rigid_removed: bool = False, prefix: str = "",
                  jacobians: str = "exact") -> dict[str, ca.Function]:
    """The named functions of a real-time estimator, ready to combine or generate.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Must tabulate ``sensors.points``.
    sensors : casflex.sensors.SensorSet
    Q, R, dt
        Process-noise intensity, signal covariance and sample time [s]
        (:func:`ekf_step_function`).
    plant : FlexiblePlant, optional
        Default :func:`tabulate_plant` of ``model``.
    sqrt, coriolis, stiffness_scale, rigid_removed, jacobians
        Passed on to :func:`ekf_step_function` (``coriolis`` and ``stiffness_scale`` to
        the ``plant`` function as well).
    prefix : str
        Prepended to every function name (several estimators in one C bundle).

    Returns
    -------
    dict of str to casadi.Function
        ``ekf_step`` (:func:`ekf_step_function`, ``jacobians`` passed on), ``measurement``
        ``(x, u, dddelta) -> y`` (kinematic model), ``plant`` ``u -> (r0, Jd, Jv[, W])``
        (:meth:`FlexiblePlant.function`), ``rigid_signals`` ``u -> y_rigid``. Names get
        ``prefix``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> sorted(ekf_functions(model, ss, 5e-6, 9e-14, 1e-3))
    ['ekf_step', 'measurement', 'plant', 'rigid_signals']
    """
    if plant is None:
        plant = tabulate_plant(model)
    step = ekf_step_function(plant, sensors, Q, R, dt, sqrt=sqrt, coriolis=coriolis,
                             stiffness_scale=stiffness_scale, rigid_removed=rigid_removed,
                             name=prefix + "ekf_step", jacobians=jacobians)

    def rename(f, new):
        return ca.Function(new, f.sx_in(), f.call(f.sx_in()), f.name_in(), f.name_out())

    return {
        "ekf_step": step,
        "measurement": rename(kinematic_measurement(model, sensors), prefix + "measurement"),
        "plant": rename(plant.function(coriolis, stiffness_scale), prefix + "plant"),
        "rigid_signals": rename(rigid_signal_function(model, sensors),
                                prefix + "rigid_signals"),
    }


