"""The polynomial form of the modal rows: the fast exact path of prescribed motion.

With ``delta_order`` 0 or 1 the mass matrix is affine in δ, so with the joint motion given
the modal rows are a polynomial in ``(δ, δ̇)`` whose coefficients depend on the
configuration only (the derivation is in the Notes of
:func:`casflex.simulate.simulate_prescribed`, ``method="poly"``). With
``foreshortening=True`` ``M_qq`` is quadratic in δ, which adds a term linear in δ to the
modal rows and quadratic ones to the torques (:func:`configuration_function`). The
configuration arrays ``F(q(t))`` are interpolated in time by Chebyshev pieces, then RK4
runs on the polynomial form. A model with ``kinematics="exact"`` is not polynomial in δ:
its form, truncated at degree 2, is :mod:`casflex.simulate.exact_poly`, which
:func:`simulate` runs through the same interpolation and RK4 chunks.

Configuration arrays
    :func:`configuration_function` (``F(q)``), :func:`unpack` (the flat rows as matrices).
Interpolation in time
    :mod:`casflex.simulate.chebyshev`: where ``F(q(t))`` stops being analytic, the
    adaptive Chebyshev pieces between those breaks, and their values at any time.
The polynomial form
    :func:`rows` (every coefficient except the factors of q̈), :func:`modal` (stage
    coefficients), :func:`stage` (the stage ``(coef, z) -> ż``), :func:`torque_rows`,
    :func:`torque` (the joint torques).
Simulation
    :func:`simulate` (``method="poly"``, optionally compiled to C).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.errors import ModelError
from casflex.moves import reference_sampler
from casflex.simulate import exact_poly
from casflex.simulate.chebyshev import breaks, interpolants, piece_index, values_at
from casflex.simulate.integrators import LEFT_LIMIT, call_buffered, rk4_step, step_cache

if TYPE_CHECKING:
    from collections.abc import Callable

    from casflex.model import FlexibleModel
    from casflex.moves import Move, ShapedMove

    _Sampler = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
    _Piece = tuple[float, float, np.ndarray, np.ndarray, np.ndarray]

__all__ = ["configuration_function", "unpack", "rows", "modal", "stage",
           "torque_rows", "torque", "simulate"]

#: error bound of the interpolation in time, relative to each array's range
INTERPOLATION_TOL = 1e-10


def configuration_function(model: FlexibleModel) -> ca.Function:
    """``F(q)``: the configuration-only arrays of the modal and joint rows (memoised per
    model in :func:`~casflex.simulate.integrators.step_cache`).

    Outputs, with ``M(q, δ) = M0(q) + Σ_j δ_j M_j(q)`` (exact: the model keeps M to first
    order in δ): ``M0`` (N × N), ``Mj`` (N × N m, ``[M_1 … M_m]``), ``dM`` (N² (m + 1) × n,
    the q-Jacobian of ``[vec M0; vec M_1; …]``), ``omega`` (m), ``domega2`` (m × n,
    ``∂Ω²/∂q``), ``g0`` (N) and ``gd`` (N × m) with ``g(q, δ) = g0 + gd δ`` the gravity
    forces (affine in δ).

    With ``foreshortening=True`` the model keeps ``M_qq`` and the gravity potential to
    second order in δ (the rest of M stays affine): ``M_qq`` gains ``Σ_{j≤k} δ_j δ_k
    Q_jk(q)`` and ``g_q`` gains ``Σ_{j≤k} δ_j δ_k γ_jk(q)`` (``g_δ`` stays affine), and
    ``F`` has three more outputs: ``Mqq2`` (the upper triangles of ``Q_jk``, pairs
    ``j ≤ k`` in the order of ``numpy.triu_indices(m)``), ``dMqq2`` (its q-Jacobian) and
    ``gq2`` (``[γ_jk]``, n per pair). The δ rows then gain ``−½ q̇ᵀ ∂M_qq/∂δ_a q̇``, a
    term linear in δ (the geometric stiffening), and the torques terms in ``δ_j δ_k`` and
    ``δ_j δ̇_k``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    casadi.Function
        ``poly_configuration (q) -> (M, dM, omega, domega2, g0, gd)`` (and ``Mqq2,
        dMqq2, gq2`` with foreshortening); ``M`` stacks the upper triangles of
        ``M0, M_1, …, M_m``.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None)
    >>> configuration_function(model).name_out()
    ['M', 'dM', 'omega', 'domega2', 'g0', 'gd']
    """
    if getattr(model, "kinematics", "truncated") == "exact":
        raise ModelError("configuration_function needs M and g polynomial in delta; a "
                         "model with kinematics='exact' is not: its degree-2 coefficients "
                         "are casflex.simulate.exact_poly.configuration_function")
    memo = step_cache(model)
    F = memo.get("poly_F")
    if F is not None:
        return F
    n, m = model.n, model.m
    N = n + m
    q, d = model.q, model.delta
    second = bool(getattr(model, "foreshortening", False)) and m > 0
    # M and g are polynomials in δ (affine, or with foreshortening quadratic in M_qq and
    # g_q), so their coefficients are exact combinations of values at numeric δ; evaluating
    # the expressions there lets CasADi drop the vanishing products (far fewer SX
    # instructions with the q-Jacobians than ∂M/∂δ_j at δ = 0)
    g = model.gravity_forces
    at = ca.Function("poly_at_delta", [q, d], [model.M, g])
    iu = np.triu_indices(N)

    def upper(A, idx=iu):
        return ca.vertcat(*[A[int(i), int(k)] for i, k in zip(*idx, strict=True)])

    def unit(*js):
        e = ca.DM.zeros(m)
        for j in js:
            e[j] += 1.0
        return e

    M0, g0 = at(q, ca.DM.zeros(m))
    plus = [at(q, unit(j)) for j in range(m)]
    Mj = [Mk - M0 for Mk, _ in plus]
    gd = [gk - g0 for _, gk in plus]
    if second:
        # M_qq and g_q are quadratic in δ (the rest affine, so M_j and g_δ are exact
        # above): from their values at ±e_j and e_j + e_k (the joint rows alone, a third
        # of M's expression), the coefficients of δ_j δ_k (j ≤ k) Q_jj = ½ (f(e_j) +
        # f(−e_j)) − f(0), Q_jk = f(e_j + e_k) − f(e_j) − f(e_k) + f(0), and the joint
        # rows of M_j = ½ (f(e_j) − f(−e_j))
        iq = np.triu_indices(n)
        at_q = ca.Function("poly_at_delta_q", [q, d], [upper(model.M[:n, :n], iq), g[:n]])
        f0 = (upper(M0[:n, :n], iq), g0[:n])
        fp = [(upper(Mk[:n, :n], iq), gk[:n]) for Mk, gk in plus]
        fm = [at_q(q, -unit(j)) for j in range(m)]
        Q, G2 = [], []
        for j, k in zip(*np.triu_indices(m), strict=True):
            j, k = int(j), int(k)
            if j == k:
                Q.append(0.5 * (fp[j][0] + fm[j][0]) - f0[0])
                G2.append(0.5 * (fp[j][1] + fm[j][1]) - f0[1])
            else:
                Mjk, gjk = at_q(q, unit(j, k))
                Q.append(Mjk - fp[j][0] - fp[k][0] + f0[0])
                G2.append(gjk - fp[j][1] - fp[k][1] + f0[1])
        for j in range(m):
            half = 0.5 * (fp[j][0] - fm[j][0])
            for r, (a, c) in enumerate(zip(*iq, strict=True)):
                Mj[j][int(a), int(c)] = half[r]
                Mj[j][int(c), int(a)] = half[r]
            gd[j][:n] = 0.5 * (fp[j][1] - fm[j][1])

    stack = ca.vertcat(upper(M0), *[upper(A) for A in Mj])
    dstack = ca.jacobian(stack, q)
    omega = model.omega if m else ca.SX(0, 1)
    outs = [stack, dstack, omega, ca.jacobian(omega**2, q), g0,
            ca.horzcat(*gd) if m else ca.SX(N, 0)]
    names = ["M", "dM", "omega", "domega2", "g0", "gd"]
    if second:
        Q = ca.vertcat(*Q)
        outs += [Q, ca.jacobian(Q, q), ca.vertcat(*G2)]
        names += ["Mqq2", "dMqq2", "gq2"]
    F = ca.Function("poly_configuration", [q], outs, ["q"], names)
    memo["poly_F"] = F
    return F


def unpack(raw: np.ndarray, n: int, m: int, dq: np.ndarray) -> dict[str, np.ndarray]:
    """Arrays of ``F(q)`` at T times from the flat rows ``raw`` (T × R).

    Full matrices from their upper triangles; ``P0``, ``Pj`` are ``Σ_i q̇_i ∂M0/∂q_i``,
    ``Σ_i q̇_i ∂M_j/∂q_i`` for the rates ``dq``, ``K0``, ``Kj`` the derivatives (torques).
    Rows of a foreshortening model (wider: the outputs ``Mqq2, dMqq2, gq2`` of
    :func:`configuration_function`) also give the second derivatives in δ
    ``H`` (``H_jk = ∂²M_qq/∂δ_j∂δ_k``), ``dH`` (their q-derivatives) and ``Gamma``
    (``∂²g_q/∂δ_j∂δ_k``).

    Parameters
    ----------
    raw : numpy.ndarray, shape (T, R)
        Rows of ``F`` (:func:`~casflex.simulate.chebyshev.evaluate` or
        :func:`~casflex.simulate.chebyshev.values_at`), SI units.
    n, m : int
        Number of joints and of modes (``N = n + m``).
    dq : numpy.ndarray, shape (T, n)
        Joint rates [rad/s].

    Returns
    -------
    dict of numpy.ndarray
        ``M0``, ``P0`` (T, N, N); ``Mj``, ``Pj`` (T, m, N, N); ``K0`` (T, n, N, N); ``Kj``
        (T, n, m, N, N); ``omega`` (T, m) [rad/s]; ``domega2`` (T, m, n); ``g0`` (T, N);
        ``gd`` (T, N, m); with foreshortening also ``H`` (T, m, m, n, n), ``dH``
        (T, n, m, m, n, n) and ``Gamma`` (T, m, m, n).

    Examples
    --------
    Rigid one-joint arm (n = 1, m = 0), ``M(q) = 2 + q / 2``, g = 9.8 N m, q = 0, q̇ = 3:

    >>> A = unpack(np.array([[2.0, 0.5, 9.8]]), 1, 0, np.array([[3.0]]))
    >>> A["M0"].tolist(), A["P0"].tolist(), A["K0"].tolist(), A["g0"].tolist()
    ([[[2.0]]], [[[1.5]]], [[[[0.5]]]], [[9.8]])
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
    out = {"M0": allM[:, 0], "Mj": allM[:, 1:], "P0": allP[:, 0], "Pj": allP[:, 1:],
           "K0": allK[:, :, 0], "Kj": allK[:, :, 1:], "omega": omega, "domega2": dw2,
           "g0": g0, "gd": gd}
    if o == raw.shape[1]:
        return out
    # foreshortening: coefficients of δ_j δ_k (j ≤ k) of M_qq and g_q
    p = m * (m + 1) // 2
    iq = np.triu_indices(n)
    nq = iq[0].size
    if raw.shape[1] - o != nq * p * (n + 1) + n * p:
        raise ModelError(f"poly rows: {raw.shape[1]} columns fit neither the first-order "
                         f"nor the foreshortening layout (n = {n}, m = {m})")
    qindex = np.empty((n, n), dtype=int)
    qindex[iq] = np.arange(nq)
    qindex[iq[1], iq[0]] = np.arange(nq)
    Q = take(nq * p).reshape(T, p, nq)[..., qindex]                  # (T, p, n, n)
    dQ = take(nq * p * n).reshape(T, n, p, nq)[..., qindex]          # (T, n, p, n, n)
    G2 = take(n * p).reshape(T, p, n)                                # (T, p, n)
    # second derivatives: H_jk = Q_jk for j < k and 2 Q_jj (Σ_{j≤k} Q δδ = ½ Σ_jk H δδ)
    pair = np.empty((m, m), dtype=int)
    im = np.triu_indices(m)
    pair[im] = np.arange(p)
    pair[im[1], im[0]] = np.arange(p)
    twice = 1.0 + np.eye(m)
    out["H"] = Q[:, pair] * twice[None, :, :, None, None]
    out["dH"] = dQ[:, :, pair] * twice[None, None, :, :, None, None]
    out["Gamma"] = G2[:, pair] * twice[None, :, :, None]
    return out


def _sym_pairs(B):
    """Coefficients of ``x_j x_k`` (j ≤ k) of the quadratic form ``Σ_jk x_j x_k B[..., j, k]``
    (off-diagonal entries of the symmetrised ``B`` doubled)."""
    m = B.shape[-1]
    iu = np.triu_indices(m)
    S = B + np.swapaxes(B, -1, -2)
    S[..., np.arange(m), np.arange(m)] *= 0.5
    return S[..., iu[0], iu[1]]


def rows(A: dict[str, np.ndarray], dq: np.ndarray, n: int, m: int, zeta: float
         ) -> dict[str, np.ndarray]:
    """Every array of the modal stage and of the joint torques at T times, except the
    factors of ``q̈`` (kept apart: ``q̈`` jumps at the move's switches while these rows
    are continuous in time, so they are interpolated across switches).

    The modal rows ``M_δδ(δ) δ̈ = r`` have ``M_δδ(δ) = Mdd0 + Σ_j δ_j Add_j`` and
    ``r = c + Jd δ + Jv δ̇ + Σ_jk C_ajk δ_j δ̇_k + Σ_jk E_ajk δ̇_j δ̇_k`` with
    ``c = c_row + c_acc q̈`` and ``Jd = Jd_row + Jd_acc q̈`` (r's parts stored negated,
    the layout of :func:`stage`). The torques
    ``τ = [M Ẍ + Ṁ Ẋ]_q − ½ Ẋᵀ (∂M/∂q) Ẋ + G_q`` are the polynomial of
    :func:`torque`.

    Parameters
    ----------
    A : dict of numpy.ndarray
        Arrays of :func:`unpack` at the rates ``dq``.
    dq : numpy.ndarray, shape (T, n)
        Joint rates [rad/s].
    n, m : int
        Number of joints and of modes.
    zeta : float
        Modal damping ratio ζ.

    Returns
    -------
    dict of numpy.ndarray
        The coefficients above, time first; ``c_acc``, ``Jd_acc``, ``t0_acc``, ``td_acc``
        (and ``t_d_d_acc`` with foreshortening) multiply ``q̈``.

    Examples
    --------
    >>> A = unpack(np.array([[2.0, 0.5, 9.8]]), 1, 0, np.array([[3.0]]))  # see unpack
    >>> R = rows(A, np.array([[3.0]]), 1, 0, 0.0)
    >>> R["t0"].tolist(), R["t0_acc"].tolist()  # τ = 2 q̈ + ½ M'(q) q̇² + 9.8
    ([[12.05]], [[[2.0]]])
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
    dd_torque = 0.5 * A["domega2"][:, :, :, None] * np.eye(m)[None, :, None, :]
    dd_torque = dd_torque.transpose(0, 2, 1, 3)  # [t, i, j, k]: ½ ∂ω_j²/∂q_i on j = k
    dv_torque = np.zeros((dq.shape[0], n, m, m))
    dd_acc = None
    if "H" in A:
        # foreshortening: M_qq = … + ½ Σ_jk δ_j δ_k H_jk, g_q = … + ½ Σ_jk δ_j δ_k Γ_jk
        H, dH = A["H"], A["dH"]
        Hv = np.einsum("tjkab,tb->tjka", H, dq)                          # H_jk q̇
        Jd -= 0.5 * np.einsum("tjka,ta->tjk", Hv, dq)    # −½ q̇ᵀ ∂M_qq/∂δ_a q̇
        Hdot_v = np.einsum("tijkab,ti,tb->tjka", dH, dq, dq, optimize=True)  # Ḣ_jk q̇
        dH_vv = np.einsum("tijkab,ta,tb->tjki", dH, dq, dq, optimize=True)  # q̇ᵀ ∂_i H q̇
        dd_torque = dd_torque + 0.5 * (Hdot_v - 0.5 * dH_vv + A["Gamma"]).transpose(
            0, 3, 1, 2)
        dv_torque = Hv.transpose(0, 3, 1, 2)              # δ̇_j δ_k H_jk q̇, [t, i, j, k]
        dd_acc = _sym_pairs(0.5 * H.transpose(0, 3, 4, 1, 2)).transpose(0, 1, 3, 2)
    Jv = (P0[:, d_, d_] + np.einsum("tkab,tb->tak", Mj[:, :, d_, q_], dq)
          - np.einsum("ti,taik->tak", dq, Mj[:, :, q_, d_]))
    Jv[:, ar, ar] += 2.0 * zeta * w
    Mdd = Mj[:, :, d_, d_]
    # torques: Σ_a q̇_a ∂M[a, :]/∂q_i of M0 and of every M_j
    dqK0 = np.einsum("ta,tiab->tib", dq, K0[:, :, q_, :])
    dqKj = np.einsum("ta,tijab->tijb", dq, Kj[:, :, :, q_, :])
    out = {
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
        "t_d_d": _sym_pairs(dd_torque),
        "t_d_dd": Mj[:, :, q_, d_].transpose(0, 2, 1, 3),  # [t, i, j, k]
        "t_d_v": Pj[:, :, q_, d_].transpose(0, 2, 1, 3) - dqKj[..., d_] + dv_torque,
        "t_v_v": _sym_pairs(Mj[:, :, q_, d_].transpose(0, 2, 1, 3)
                            - 0.5 * K0[:, :, d_, d_]),
        "t_d_v_v": _sym_pairs(-0.5 * Kj[:, :, :, d_, d_]),
    }
    if dd_acc is not None:
        out["t_d_d_acc"] = dd_acc  # [t, i, pair, b]
    return out


def modal(rows: dict[str, np.ndarray], ddq: np.ndarray) -> np.ndarray:
    """Stage coefficient rows ``[Mdd0, Add, c, Jd, Jv, C, E]`` (C order) at T times with
    the accelerations ``ddq`` (T × n) folded in: the ``coef`` of :func:`stage`.

    Parameters
    ----------
    rows : dict of numpy.ndarray
        Coefficients of :func:`rows`.
    ddq : numpy.ndarray, shape (T, n)
        Joint accelerations [rad/s²].

    Returns
    -------
    numpy.ndarray, shape (T, 3 m³ + 3 m² + m)

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1))
    >>> q, dq = np.array([[0.0, 0.3, -0.2]]), np.array([[0.2, -0.1, 0.4]])
    >>> from casflex.simulate.chebyshev import evaluate
    >>> A = unpack(evaluate(configuration_function(model), q), model.n, model.m, dq)
    >>> R = rows(A, dq, model.n, model.m, model.damping_ratio)
    >>> ddq, d, v = np.array([[1.0, -0.5, 0.2]]), np.array([0.01]), np.array([-0.2])
    >>> z_dot = stage(model.m)[0](modal(R, ddq)[0], np.r_[d, v]).full().ravel()
    >>> dd = model.functions()["dddelta"](q[0], dq[0], ddq[0], d, v).full().ravel()
    >>> bool(np.allclose(z_dot[model.m:], dd, rtol=1e-12))  # the model's δ̈
    True
    """
    T = ddq.shape[0]
    c = rows["c"] + np.einsum("tab,tb->ta", rows["c_acc"], ddq)
    Jd = rows["Jd"] + np.einsum("tajb,tb->taj", rows["Jd_acc"], ddq)
    parts = [rows["Mdd0"], rows["Add"], c, Jd, rows["Jv"], rows["C"], rows["E"]]
    return np.hstack([p.reshape(T, -1) for p in parts])


_TORQUE_PARTS = ("t0", "td", "tv", "tdd", "t_d_d", "t_d_dd", "t_d_v", "t_v_v", "t_d_v_v")


def torque_rows(rows: dict[str, np.ndarray], ddq: np.ndarray) -> np.ndarray:
    """Flat torque-coefficient rows (T × R, parts :data:`_TORQUE_PARTS` in C order) with
    the accelerations ``ddq`` (T × n) folded into the constant and the δ terms.

    Parameters
    ----------
    rows : dict of numpy.ndarray
        Coefficients of :func:`rows`.
    ddq : numpy.ndarray, shape (T, n)
        Joint accelerations [rad/s²].

    Returns
    -------
    numpy.ndarray, shape (T, R)
        ``R = n (1 + 3 m + 2 m² + 2 p + m p)``, ``p = m (m + 1) / 2``.

    Examples
    --------
    >>> A = unpack(np.array([[2.0, 0.5, 9.8]]), 1, 0, np.array([[3.0]]))  # see unpack
    >>> torque_rows(rows(A, np.array([[3.0]]), 1, 0, 0.0), np.array([[1.0]])).tolist()  # q̈ = 1
    [[14.05]]
    """
    T = ddq.shape[0]
    folded = dict(rows)
    folded["t0"] = rows["t0"] + np.einsum("tib,tb->ti", rows["t0_acc"], ddq)
    folded["td"] = rows["td"] + np.einsum("tijb,tb->tij", rows["td_acc"], ddq)
    if "t_d_d_acc" in rows:
        folded["t_d_d"] = rows["t_d_d"] + np.einsum("tipb,tb->tip", rows["t_d_d_acc"], ddq)
    return np.hstack([folded[k].reshape(T, -1) for k in _TORQUE_PARTS])


def torque(R: np.ndarray, n: int, m: int, d: np.ndarray, v: np.ndarray, dd: np.ndarray
           ) -> np.ndarray:
    """Joint torques at T samples from torque-coefficient rows ``R`` of
    :func:`torque_rows`: per joint a polynomial in ``(δ, δ̇, δ̈)`` with the terms 1,
    δ_j, δ̇_j, δ̈_j, δ_j δ_k (j ≤ k), δ_j δ̈_k, δ_j δ̇_k, δ̇_j δ̇_k (j ≤ k) and
    δ_j δ̇_k δ̇_l (k ≤ l).

    Parameters
    ----------
    R : numpy.ndarray, shape (T, R)
        Rows of :func:`torque_rows` (or interpolated by
        :func:`~casflex.simulate.chebyshev.values_at`).
    n, m : int
        Number of joints and of modes.
    d, v, dd : numpy.ndarray, shape (T, m)
        δ, δ̇ and δ̈.

    Returns
    -------
    numpy.ndarray, shape (T, n)
        Joint torques [N m].

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1))
    >>> q, dq = np.array([[0.0, 0.3, -0.2]]), np.array([[0.2, -0.1, 0.4]])
    >>> from casflex.simulate.chebyshev import evaluate
    >>> A = unpack(evaluate(configuration_function(model), q), model.n, model.m, dq)
    >>> R = rows(A, dq, model.n, model.m, model.damping_ratio)
    >>> ddq, d, v = np.array([[1.0, -0.5, 0.2]]), np.array([[0.01]]), np.array([[-0.2]])
    >>> tau, dd = (x.full() for x in model.functions()["prescribed"](q[0], dq[0], ddq[0], d, v))
    >>> bool(np.allclose(torque(torque_rows(R, ddq), 3, 1, d, v, dd.T), tau.T, rtol=1e-12))
    True
    """
    T = R.shape[0]
    p = m * (m + 1) // 2
    shapes = {"t0": (n,), "td": (n, m), "tv": (n, m), "tdd": (n, m), "t_d_d": (n, p),
              "t_d_dd": (n, m, m), "t_d_v": (n, m, m), "t_v_v": (n, p),
              "t_d_v_v": (n, m, p)}
    r, o = {}, 0
    for k in _TORQUE_PARTS:
        size = math.prod(shapes[k])
        r[k] = R[:, o:o + size].reshape((T, *shapes[k]))
        o += size
    iu = np.triu_indices(m)
    vv = v[:, iu[0]] * v[:, iu[1]]
    dd2 = d[:, iu[0]] * d[:, iu[1]]
    return (r["t0"]
            + np.einsum("tij,tj->ti", r["td"], d)
            + np.einsum("tij,tj->ti", r["tv"], v)
            + np.einsum("tij,tj->ti", r["tdd"], dd)
            + np.einsum("tip,tp->ti", r["t_d_d"], dd2)
            + np.einsum("tijk,tj,tk->ti", r["t_d_dd"], d, dd, optimize=True)
            + np.einsum("tijk,tj,tk->ti", r["t_d_v"], d, v, optimize=True)
            + np.einsum("tip,tp->ti", r["t_v_v"], vv)
            + np.einsum("tijp,tj,tp->ti", r["t_d_v_v"], d, vv, optimize=True))


def stage(m: int) -> tuple[ca.Function, int]:
    """SX stage ``(coef, z) -> [δ̇; δ̈]`` of the polynomial form of the modal rows.

    ``(Mdd0 + Σ_j δ_j Add_j) δ̈ = c + Jd δ + Jv δ̇ + C (δ ⊗ δ̇) + E (δ̇ ⊗ δ̇)`` with the
    coefficients of :func:`modal`: the right-hand side of the RK4 steps.

    Parameters
    ----------
    m : int
        Number of modes.

    Returns
    -------
    rhs : casadi.Function
        ``poly_stage (coef, z) -> ż``, ``z = [δ; δ̇]``.
    size : int
        Length of ``coef`` (``3 m³ + 3 m² + m``).

    Examples
    --------
    >>> rhs, size = stage(1)  # one mode: Mdd0 = 2, c = 4, the other coefficients 0
    >>> rhs([2.0, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0]).full().ravel().tolist()
    [1.0, 2.0]
    """
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


_CHUNK = 250


def _form(model):
    """``(F, stage_of, node_rows, torque)`` of the model's polynomial form: the
    truncated kinematics' (this module) or the exact kinematics' at degree 2 in δ
    (:mod:`casflex.simulate.exact_poly`). ``stage_of(m)`` builds the stage ``(rhs,
    size)``, ``node_rows(raw, dq, ddq)`` gives the stage and torque rows at the
    interpolation nodes, ``torque(R, d, v, dd)`` the torques."""
    n, m = model.n, model.m
    if getattr(model, "kinematics", "truncated") == "exact":
        return (exact_poly.configuration_function(model), exact_poly.stage,
                lambda raw, dq, ddq: exact_poly.node_rows(raw, n, m, ddq),
                lambda R, d, v, dd: exact_poly.torque(R, n, m, d, v, dd))
    zeta = model.damping_ratio

    def node_rows(raw, dq, ddq):
        R = rows(unpack(raw, n, m, dq), dq, n, m, zeta)
        return modal(R, ddq), torque_rows(R, ddq)

    return (configuration_function(model), stage, node_rows,
            lambda R, d, v, dd: torque(R, n, m, d, v, dd))


def _rk4_chunk(model, dt, stage_of):
    """``mapaccum`` over ``_CHUNK`` RK4 steps with the coefficients at t, t + dt/2 and
    t + dt as the per-step input (building a mapaccum costs time linear in its length, so
    a long simulation calls this chunk repeatedly); ``stage_of(m)`` builds the stage."""
    m = model.m
    memo = step_cache(model)
    key = ("poly", getattr(model, "kinematics", "truncated"), m, float(dt))
    cached = memo.get(key)
    if cached is not None:
        return cached
    rhs, nc = stage_of(m)
    z = ca.SX.sym("z", 2 * m)
    p = ca.SX.sym("p", 3 * nc)
    k = {}

    def derivative(zz, coef):
        out = rhs(coef, zz)
        k.setdefault("k1", out)  # the first stage: δ̈ at the start of the step
        return out

    z_next = rk4_step(derivative, z, dt, p[:nc], p[nc:2 * nc], p[2 * nc:])
    step = ca.Function("poly_rk4", [z, p], [z_next, k["k1"][m:]], ["z", "p"],
                       ["z_next", "dddelta"])
    acc = step.mapaccum("poly_rk4_acc", _CHUNK, [0], [0])
    memo[key] = (acc, rhs)
    return acc, rhs


def _integrate(acc, z0, stage_rows, steps, m):
    """Run the chunked RK4 over ``steps`` steps; ``stage_rows(k0, k1)`` gives the
    coefficient rows ``[a | b | c]`` of steps ``k0 .. k1 - 1`` (assembled chunk by chunk:
    the rows of a whole long move would take tens of MB)."""
    L = _CHUNK
    chunks = -(-steps // L)
    zs = np.empty((chunks * L, 2 * m))
    dds = np.empty((chunks * L, m))
    z = np.ascontiguousarray(z0[None, :], dtype=float)
    for c in range(chunks):
        k0, k1 = c * L, min((c + 1) * L, steps)
        P = stage_rows(k0, k1)
        if k1 - k0 < L:
            P = np.vstack([P, np.repeat(P[-1:], L - (k1 - k0), axis=0)])
        zc, dc = call_buffered(acc, [z, P], [(L, 2 * m), (L, m)])
        zs[k0:k0 + L] = zc
        dds[k0:k0 + L] = dc
        z = np.ascontiguousarray(zc[k1 - k0 - 1:k1 - k0])
    return zs[:steps], dds[:steps]


def _compiled(model, F, acc, jit, cache_dir):
    """``F`` and the RK4 chunk ``acc`` compiled to C (cached per model and flags)."""
    from casflex.codegen.jit import compile_cached, jit_flags

    flags = jit_flags(jit, ("-O1",))
    memo = step_cache(model)
    key = ("poly_jit", flags, str(cache_dir))
    hit = memo.get(key)
    if hit is not None:
        return hit + ({"poly_jit_s": 0.0, "poly_jit_built": False},)
    funs_F, info_F = compile_cached([F], "casflex_poly_F", cache_dir=cache_dir, flags=flags)
    funs_a, info_a = compile_cached([acc], "casflex_poly_rk4", cache_dir=cache_dir,
                                    flags=flags)
    memo[key] = (funs_F[F.name()], funs_a[acc.name()])
    return memo[key] + ({"poly_jit_s": info_F["seconds"] + info_a["seconds"],
                      "poly_jit_built": info_F["built"] or info_a["built"]},)


def simulate(model: FlexibleModel, reference: Move | ShapedMove, t: np.ndarray, dt: float,
             z0: np.ndarray, jit: bool | str | Sequence[str] = False,
             cache_dir: str | Path | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Integrate ``z = [δ; δ̇]`` with the polynomial form of the modal rows (the
    ``method="poly"`` of :func:`casflex.simulate.simulate_prescribed`, which checks the
    arguments and documents the method).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    reference : casflex.moves.Move or casflex.moves.ShapedMove
    t : numpy.ndarray
        Uniform output grid [s].
    dt : float
        Its step [s].
    z0 : numpy.ndarray
        Initial ``[δ; δ̇]``.
    jit : bool, str or sequence of str
        Compile ``F`` and the RK4 steps to C (compiler flags).
    cache_dir : str or pathlib.Path, optional
        Root of the compiled-library cache.

    Returns
    -------
    Z : numpy.ndarray, shape (len(t), 2 m)
    tau : numpy.ndarray, shape (len(t), n)
    info : dict
        Bookkeeping of the interpolation and the timings of the stages [s].

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None)
    >>> t = np.linspace(0.0, 0.5, 51)
    >>> Z, tau, info = simulate(model, Move([0, 0, 0], [-0.1, 0, 0], 0.4), t, 0.01,
    ...                         np.zeros(2))
    >>> Z.shape, tau.shape, info["poly_pieces"]
    ((51, 2), (51, 3), 3)
    """
    from casflex.moves import Move, ShapedMove

    n, m = model.n, model.m
    if not isinstance(reference, (Move, ShapedMove)):
        # the stage coefficients take q̈ constant between the breakpoints: true of a
        # bang-bang move and its shaped version, not of a planned move or samples
        raise ModelError("method='poly' needs the reference as a casflex.moves.Move or "
                         "ShapedMove (q̈ constant between known switching times); got "
                         f"{type(reference).__name__} — use method='rk4'")
    if m == 0:
        raise ModelError("method='poly' needs a model with modes (m >= 1); use method='rk4'")
    if model.delta_order not in (0, 1):
        raise ModelError(f"method='poly' needs delta_order 0 or 1; got {model.delta_order}")
    if getattr(model, "full_stiffness", False):
        # its stage rows take the stiffness as diag(ω²): a rotated basis has a full K̃
        raise ModelError("method='poly' needs a diagonal modal stiffness; this model has a "
                         "full K̃ (a smooth mode basis) — use method='rk4'")
    if getattr(model, "kinematics", "truncated") == "exact" and jit is not False:
        # measured: its coefficient function is 7.5 M SX instructions at 3 modes, 40 M at 5
        raise ModelError("jit is not offered with kinematics='exact' and method='poly': "
                         "the coefficient function is too large to compile; use jit=False")
    info = {}
    start = time.perf_counter()
    F, stage_of, node_rows, torque_of = _form(model)
    acc, rhs = _rk4_chunk(model, float(dt), stage_of)
    info["poly_build_s"] = time.perf_counter() - start
    info["poly_F_instructions"] = (exact_poly.instructions(model)
                                   if getattr(model, "kinematics", "truncated") == "exact"
                                   else int(F.n_instructions()))
    if jit is not False:
        F, acc, jinfo = _compiled(model, F, acc, jit, cache_dir)
        info.update(jinfo)
    sampler = reference_sampler(reference, n).sample
    start = time.perf_counter()
    cuts = breaks(model, reference, sampler, float(t[0]), float(t[-1]))
    pieces, err, evals, kmax = interpolants(F, sampler, cuts, INTERPOLATION_TOL)
    info.update(poly_pieces=len(pieces), poly_F_evaluations=int(evals),
                poly_max_nodes_per_piece=int(kmax) + 1, poly_interp_rel_err=err,
                poly_interp_s=time.perf_counter() - start)
    start = time.perf_counter()
    # stage and torque coefficients on the nodes of every piece, with the piece's q̈
    # (constant between the breaks; the nodes at a break take their own piece's side)
    sizes = [p[2].size for p in pieces]
    tn_all = np.concatenate([p[2] for p in pieces])
    dq_nodes = sampler(tn_all)[1]
    piece_ddq = sampler(np.array([0.5 * (p[0] + p[1]) for p in pieces]))[2]
    ddq_nodes = np.repeat(piece_ddq, sizes, axis=0)
    modal_rows, torque_rows_ = node_rows(np.vstack([p[4] for p in pieces]), dq_nodes,
                                         ddq_nodes)
    cut = np.cumsum(sizes)[:-1]
    modal_nodes = np.split(modal_rows, cut)
    torque_nodes = np.split(torque_rows_, cut)
    th = t[:-1] + 0.5 * dt
    ddq = sampler(t)[2]
    ddqh = sampler(th)[2]
    ddq_end = sampler(t[1:] - LEFT_LIMIT * dt)[2]  # the end stage takes q̈ from the left
    ia = piece_index(pieces, t, ddq, piece_ddq)
    ib = piece_index(pieces, th, ddqh, piece_ddq)
    ic = piece_index(pieces, t[1:], ddq_end, piece_ddq, left=True)
    nc = modal_nodes[0].shape[1]

    def stage_rows(k0, k1):
        P = np.empty((k1 - k0, 3 * nc))
        values_at(pieces, modal_nodes, t[k0:k1], ia[k0:k1], P[:, :nc])
        values_at(pieces, modal_nodes, th[k0:k1], ib[k0:k1], P[:, nc:2 * nc])
        values_at(pieces, modal_nodes, t[k0 + 1:k1 + 1], ic[k0:k1], P[:, 2 * nc:])
        return P

    info["poly_assembly_s"] = time.perf_counter() - start
    start = time.perf_counter()
    zs, dds = _integrate(acc, z0, stage_rows, t.size - 1, m)
    Z = np.vstack([z0, zs])
    # δ̈ at the last sample from its own stage
    last = values_at(pieces, modal_nodes, t[-1:], ia[-1:])[0]
    dd_last = rhs(last, Z[-1]).full().ravel()[m:]
    DD = np.vstack([dds, dd_last])
    info["poly_integrate_s"] = time.perf_counter() - start
    start = time.perf_counter()
    tau = torque_of(values_at(pieces, torque_nodes, t, ia), Z[:, :m], Z[:, m:], DD)
    info["poly_torque_s"] = time.perf_counter() - start
    return Z, tau, info
