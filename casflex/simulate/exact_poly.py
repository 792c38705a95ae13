"""The ``poly`` form of the exact-kinematics model, truncated at degree 2 in δ.

``simulate_prescribed(method="poly")`` integrates the modal rows as a polynomial in
``(δ, δ̇)`` whose coefficients are interpolated in time along the reference
(:mod:`casflex.simulate.poly`). A model with ``kinematics="exact"`` has rows that are
not polynomial in δ (the rods are rebuilt by rotations); this module replaces every
coefficient of its rows that depends on ``(q, δ)`` by its Taylor polynomial of degree
:data:`DEGREE` = 2 at δ = 0 — the truncation of
:func:`casflex.simulate.exact_taylor.taylor_modal_rows`, which measured it: 0.10 % of
the peak on Table 9 move 3, 4e-4 % on the planar elbow move (``benchmarks/README_fidelity.md``).

The rows, with ``μ(δ) = [1, δ_1 … δ_m, δ_j δ_k (j ≤ k)]`` (``L = 1 + m + m(m+1)/2``
monomials) and the pairs ``w = [δ̇_j δ̇_k (j ≤ k)]``::

    M(q, δ) ≈ Σ_l μ_l(δ) M_l(q)
    h(q, q̇, δ, δ̇) ≈ Σ_l μ_l(δ) (h0_l(q, q̇) + h1_l(q, q̇) δ̇ + h2_l(q) w)

(``h`` is every force but ``M Ẍ`` and the input: bias forces, gravity, ``Ω² δ``,
``2ζΩ δ̇``; it is exactly quadratic in ``δ̇``, so the split in δ̇ is exact). The modal
rows ``M_δδ(δ) δ̈ = −M_δq(δ) q̈ − h_δ`` and the torques ``τ = M_qq(δ) q̈ + M_qδ(δ) δ̈ +
h_q`` follow with the same coefficients.

Unlike the truncated kinematics' ``F(q)``, the coefficients here are functions of
``(q, q̇)``: the exact model's bias forces are not the Christoffel form of ``M``
(without ``shape_rates`` they freeze the tables), and interpolating ``h``'s coefficients
along ``(q(t), q̇(t))`` — as smooth as ``q(t)`` between the same breaks — spares the
q-Jacobians of ``M`` that :func:`casflex.simulate.poly.rows` contracts with ``q̇``.
The coefficients are CasADi derivatives of the model's ``M`` and ``h`` (first in δ̇,
folded at δ̇ = 0), then in δ at δ = 0 by forward directional derivatives, evaluated
numerically at each interpolation node.

Cost. The parts depending on ``(q, q̇)`` only (the DH chain's trigonometry, the tables'
B-spline calls) are extracted as symbols ``S`` first. The δ-coefficients are then never
one expanded graph for all terms (nested Jacobians in δ built ~``(1 + m + m²)`` times
the rows' graph before δ = 0 folded it: 28 M nodes and > 6 GB at 5 modes, session 11):
one SX function of ``(q, q̇, S, u, w)`` gives ``∂E/∂δ · u`` and ``wᵀ ∂²E/∂δ² u`` at
δ = 0 (forward over forward, ~8× the rows' graph before the fold, whatever m), and
``Function.map`` calls it on the ``m(m+1)/2`` pairs of unit vectors ``(e_j, e_k)``,
``j ≤ k``, per node: the build is linear in the rows' graph, the evaluation
``m(m+1)/2`` times the folded directional function. Measured on the Table 8 arm,
frozen modes, gravity off (``bench_exact_poly.py --build``, README_fidelity.md, session
13): 3 modes, build 4.9 s of CPU, 0.54 GB peak, one evaluation 7.5 M instructions
(session 11's nested Jacobians on the 1.5° table: 14 s, 1.7 GB, 2.6 M); 5 modes 11 s,
0.91 GB, 40 M; 8 modes 28 s, 1.8 GB, 221 M. So it is no fast path: on Table 9 move 3
(31 evaluations) it takes ~0.6× the CPU of RK4 on the exact rows at 3 modes and ~2× at
5; on move 1 (491 evaluations) ~6× at 5. :data:`GRAPH_BUDGET` bounds the directional
function's graph before the fold (``ModelError`` beyond it, use ``method="rk4"``).
``jit`` is refused with this form (graphs of millions of instructions).

Functions: :func:`configuration_function` (the coefficient arrays),
:func:`node_rows` (the stage and torque rows at the interpolation nodes), :func:`stage`
(the RK4 right-hand side), :func:`torque`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.errors import ModelError
from casflex.simulate.integrators import step_cache

if TYPE_CHECKING:
    from casflex.model import FlexibleModel

__all__ = ["DEGREE", "GRAPH_BUDGET", "configuration_function", "instructions", "node_rows",
           "stage", "torque", "monomials"]

#: degree in δ of the truncated coefficients (the error budget: exact_taylor)
DEGREE = 2

#: largest graph (SX nodes, projected) of the directional derivatives before their fold
#: at δ = 0; ~110 bytes a node at peak (8 modes: 16 M nodes, 1.8 GB), so ~4–5 GB
GRAPH_BUDGET = 4e7

#: graph of the forward-over-forward directional derivatives / the rows' graph
#: (measured 8.3 at 2 modes to 8.1 at 8, Table 8 arm)
_DIRECTIONAL_GROWTH = 8.5


def monomials(d):
    """``μ(δ) = [1, δ_1 … δ_m, δ_j δ_k (j ≤ k, pairs in numpy.triu_indices order)]``.

    Parameters
    ----------
    d : casadi.SX (m × 1) or numpy.ndarray (T × m)
        Modal coordinates [√kg m].

    Returns
    -------
    casadi.SX (L × 1) or numpy.ndarray (T × L)

    Examples
    --------
    >>> monomials(np.array([[2.0, 3.0]])).tolist()
    [[1.0, 2.0, 3.0, 4.0, 6.0, 9.0]]
    """
    if isinstance(d, np.ndarray):
        i, k = np.triu_indices(d.shape[1])
        return np.hstack([np.ones((d.shape[0], 1)), d, d[:, i] * d[:, k]])
    i, k = np.triu_indices(d.numel())
    return ca.vertcat(1, d, *[d[int(a)] * d[int(b)] for a, b in zip(i, k, strict=True)])


def _second_order(E, x):
    """``(J, pairs)`` of the column ``E``: its Jacobian in ``x`` (R × m) and the
    coefficients of ``x_j x_k`` (j ≤ k, ``numpy.triu_indices`` order) of its quadratic
    Taylor term, ``½ ∂²E/∂x_j²`` and ``∂²E/∂x_j∂x_k`` (R each), as expressions in x.
    For the δ̇ split only (``h`` is quadratic in δ̇, few rows)."""
    m, R = x.numel(), E.numel()
    J = ca.jacobian(E, x)
    H = ca.jacobian(ca.vec(J), x)                   # H[r + R j, k] = ∂²E_r/∂x_j∂x_k
    pairs = [H[int(j) * R:(int(j) + 1) * R, int(k)] * (0.5 if j == k else 1.0)
             for j, k in zip(*np.triu_indices(m), strict=True)]
    return J, pairs


def _directional(E, args, d):
    """``D(args, u, w) -> (∂E/∂δ · u, wᵀ ∂²E/∂δ² u)`` at δ = 0: two forward directional
    derivatives (each ~2–3× E's graph, never m of them), folded at δ = 0."""
    m = d.numel()
    u, w = ca.SX.sym("u", m), ca.SX.sym("w", m)
    e1 = ca.jtimes(E, d, u)
    e2 = ca.jtimes(e1, d, w)
    folded = ca.Function("directional", [*args, u, w, d], [e1, e2])(
        *args, u, w, ca.DM.zeros(m))
    return ca.Function("exact_poly_directional", [*args, u, w], folded)


def configuration_function(model: FlexibleModel) -> ca.Function:
    """``G(q, q̇)``: the Taylor coefficients (degree 2 in δ) of the exact model's ``M``
    and ``h`` (module docstring), memoised per model.

    Outputs, each with one column per monomial of :func:`monomials` (L columns):
    ``M`` (N(N+1)/2 × L, the upper triangle of M in ``numpy.triu_indices`` order),
    ``h0`` (N × L, h at δ̇ = 0), ``h1`` (N m × L, column-major ``∂h/∂δ̇`` at δ̇ = 0:
    entry ``r + N j`` is ``∂h_r/∂δ̇_j``), ``h2`` (N p × L, entry ``r + N s`` the
    coefficient of the pair ``s`` of ``δ̇_j δ̇_k``), with ``N = n + m`` and
    ``p = m(m+1)/2``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        With ``kinematics="exact"`` and modes.

    Returns
    -------
    casadi.Function
        ``exact_poly_configuration (q, dq) -> (M, h0, h1, h2)`` [SI units].

    Examples
    --------
    One mode: N = 4, so M has 10 upper-triangle rows, and the monomials are 1, δ, δ².

    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None, kinematics="exact")
    >>> G = configuration_function(model)
    >>> G.name_out(), G.size_out(0)
    (['M', 'h0', 'h1', 'h2'], (10, 3))
    """
    if getattr(model, "kinematics", "truncated") != "exact":
        raise ModelError("exact_poly needs a model with kinematics='exact'; got "
                         f"kinematics={getattr(model, 'kinematics', None)!r}")
    if model.m == 0:
        raise ModelError("method='poly' needs a model with modes (m >= 1); use method='rk4'")
    memo = step_cache(model)
    G = memo.get("exact_poly_G")
    if G is not None:
        return G
    n, m = model.n, model.m
    N = n + m
    q, dq, d, v = model.q, model.dq, model.delta, model.ddelta
    iu = np.triu_indices(N)
    upper = ca.vertcat(*[model.M[int(i), int(k)] for i, k in zip(*iu, strict=True)])
    # the parts that depend on (q, q̇) only (the DH chain's trigonometry, the tables'
    # B-spline calls) become symbols S while differentiating in δ and δ̇: their
    # derivatives vanish, and AD through the tables' interpolant calls would otherwise
    # take tens of GB (measured: > 21 GB at 5 modes on the 1.5° table)
    core, S, values = ca.extract_parametric(ca.vertcat(upper, model.h), ca.vertcat(q, dq))
    S, values = ca.vertcat(*S), ca.vertcat(*values)
    upper, h = core[:iu[0].size], core[iu[0].size:]
    # h is quadratic in δ̇: its value, gradient and (constant) Hessian at δ̇ = 0
    h1, pairs = _second_order(h, v)
    at_rest = ca.Function("rates_at_zero", [q, dq, S, d, v],
                          [ca.vertcat(h, ca.vec(h1), *pairs)])(q, dq, S, d, ca.DM.zeros(m))
    E = ca.vertcat(upper, at_rest)
    rows = ca.Function("rows", [q, dq, S, d], [E])
    projected = rows.n_instructions() * _DIRECTIONAL_GROWTH
    if projected > GRAPH_BUDGET:
        raise ModelError(
            f"method='poly' with kinematics='exact' and {m} modes: the directional "
            f"derivatives of its rows would take ~{projected:.3g} SX nodes before folding "
            f"(the rows' graph, {rows.n_instructions()}, times {_DIRECTIONAL_GROWTH}), over "
            f"the budget of {GRAPH_BUDGET:.3g}; use method='rk4'")
    rows = ca.Function("rows_at_rest", [q, dq, S], [rows(q, dq, S, ca.DM.zeros(m))])
    directional = _directional(E, [q, dq, S], d)
    # numerically per node: the values S, then the Jacobian's columns and the Hessian's
    # upper triangle as P = m(m+1)/2 directional pairs (e_j, e_k), j ≤ k, by one map
    j, k = np.triu_indices(m)
    P = j.size
    qm, dqm = ca.MX.sym("q", n), ca.MX.sym("dq", n)
    Sm = ca.Function("configuration_values", [q, dq], [values])(qm, dqm)
    eye = np.eye(m)
    first, second = directional.map(P)(ca.repmat(qm, 1, P), ca.repmat(dqm, 1, P),
                                       ca.repmat(Sm, 1, P), eye[:, j], eye[:, k])
    diagonal = [int(np.flatnonzero((j == i) & (k == i))[0]) for i in range(m)]
    C = ca.horzcat(rows(qm, dqm, Sm), first[:, diagonal],
                   second @ ca.diag(ca.DM(np.where(j == k, 0.5, 1.0))))
    sizes = np.cumsum([0, iu[0].size, N, N * m, N * m * (m + 1) // 2])
    outs = [C[int(a):int(b), :] for a, b in zip(sizes[:-1], sizes[1:], strict=True)]
    G = ca.Function("exact_poly_configuration", [qm, dqm], outs, ["q", "dq"],
                    ["M", "h0", "h1", "h2"])
    memo["exact_poly_G"] = G
    memo["exact_poly_G_instructions"] = int(
        P * directional.n_instructions() + rows.n_instructions()
        + ca.Function("values", [q, dq], [values]).n_instructions())
    return G


def instructions(model: FlexibleModel) -> int:
    """SX instructions of one call of :func:`configuration_function` (its MX graph
    counts calls, not work): ``P`` directional pairs, the rows at δ = 0, the values.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        With ``kinematics="exact"`` and modes.

    Returns
    -------
    int

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1),
    ...                       gravity=None, kinematics="exact")
    >>> instructions(model) > configuration_function(model).n_instructions()
    True
    """
    configuration_function(model)
    return step_cache(model)["exact_poly_G_instructions"]


def _blocks(raw, n, m):
    """The outputs of :func:`configuration_function` at T nodes (flat rows, column-major
    per output) as arrays: ``M`` (T, L, N, N) full, ``h0`` (T, L, N), ``h1``
    (T, L, m, N) (``[t, l, j, r] = ∂h_r/∂δ̇_j``), ``h2`` (T, L, p, N)."""
    N, p = n + m, m * (m + 1) // 2
    L = 1 + m + p
    iu = np.triu_indices(N)
    nt = iu[0].size
    T = raw.shape[0]
    widths = [nt * L, N * L, N * m * L, N * p * L]
    if raw.shape[1] != sum(widths):
        raise ModelError(f"exact poly rows: {raw.shape[1]} columns do not fit n = {n}, "
                         f"m = {m} (expected {sum(widths)})")
    o = np.cumsum([0, *widths])
    index = np.empty((N, N), dtype=int)
    index[iu] = np.arange(nt)
    index[iu[1], iu[0]] = np.arange(nt)
    M = raw[:, o[0]:o[1]].reshape(T, L, nt)[..., index]
    h0 = raw[:, o[1]:o[2]].reshape(T, L, N)
    h1 = raw[:, o[2]:o[3]].reshape(T, L, m, N)
    h2 = raw[:, o[3]:o[4]].reshape(T, L, p, N)
    return M, h0, h1, h2


def node_rows(raw: np.ndarray, n: int, m: int, ddq: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Stage and torque coefficient rows at T nodes, the joint accelerations folded in.

    Parameters
    ----------
    raw : numpy.ndarray, shape (T, R)
        Rows of :func:`configuration_function` at the nodes
        (:func:`~casflex.simulate.chebyshev.evaluate`).
    n, m : int
        Number of joints and of modes.
    ddq : numpy.ndarray, shape (T, n)
        Joint accelerations at the nodes [rad/s²] (the piece's constant q̈).

    Returns
    -------
    modal : numpy.ndarray, shape (T, L (2 m² + m + m p))
        The ``coef`` of :func:`stage`: per monomial ``l`` (C order) ``M_δδ`` ([l, b, a]),
        ``r0`` ([l, a]), ``r1`` ([l, j, a]), ``r2`` ([l, s, a]) with
        ``M_δδ(δ) δ̈ = Σ_l μ_l (r0_l + r1_l δ̇ + r2_l w)``.
    torques : numpy.ndarray, shape (T, L (n + 2 n m + n p))
        The rows of :func:`torque`: ``t0`` ([l, i]), ``tdd`` ([l, i, k]), ``tv``
        ([l, i, j]), ``tvv`` ([l, i, s]).

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> from casflex.simulate.chebyshev import evaluate
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0.3, -0.2], count=1),
    ...                       gravity=None, kinematics="exact")
    >>> q, dq, ddq = np.array([[0.0, 0.3, -0.2]]), np.array([[0.2, -0.1, 0.4]]), \
np.array([[1.0, -0.5, 0.2]])
    >>> raw = evaluate(configuration_function(model), q, dq)
    >>> A, B = node_rows(raw, 3, 1, ddq)
    >>> d, v = np.array([1e-3]), np.array([-0.2])  # small δ: degree 2 is the model to O(δ³)
    >>> z_dot = stage(1)[0](A[0], np.r_[d, v]).full().ravel()
    >>> dd = model.functions()["dddelta"](q[0], dq[0], ddq[0], d, v).full().ravel()
    >>> bool(abs(z_dot[1] - dd[0]) < 1e-6 * abs(dd[0]))
    True
    """
    M, h0, h1, h2 = _blocks(raw, n, m)
    T, L = M.shape[:2]
    q_, d_ = slice(0, n), slice(n, n + m)
    r0 = -(np.einsum("tlab,tb->tla", M[:, :, d_, q_], ddq) + h0[:, :, d_])
    modal = [M[:, :, d_, d_].transpose(0, 1, 3, 2), r0, -h1[..., d_], -h2[..., d_]]
    t0 = np.einsum("tlib,tb->tli", M[:, :, q_, q_], ddq) + h0[:, :, q_]
    torques = [t0, M[:, :, q_, d_], h1[..., q_].transpose(0, 1, 3, 2),
               h2[..., q_].transpose(0, 1, 3, 2)]
    return (np.hstack([a.reshape(T, -1) for a in modal]),
            np.hstack([a.reshape(T, -1) for a in torques]))


def stage(m: int) -> tuple[ca.Function, int]:
    """SX stage ``(coef, z) -> [δ̇; δ̈]`` of the degree-2 form:
    ``Σ_l μ_l(δ) M_l δ̈ = Σ_l μ_l(δ) (r0_l + r1_l δ̇ + r2_l w)`` (coefficients of
    :func:`node_rows`, ``w`` the pairs ``δ̇_j δ̇_k``, ``j ≤ k``).

    Parameters
    ----------
    m : int
        Number of modes.

    Returns
    -------
    rhs : casadi.Function
        ``exact_poly_stage (coef, z) -> ż``, ``z = [δ; δ̇]``.
    size : int
        Length of ``coef``, ``L (2 m² + m + m p)``.

    Examples
    --------
    One mode, ``M_δδ = 2 + δ``, ``r = 4 + δ̇``: at δ = 0, δ̇ = 1, δ̈ = 5 / 2.

    >>> rhs, size = stage(1)  # coef: M per μ = (1, δ, δ²), r0, r1, r2
    >>> coef = [2.0, 1.0, 0.0, 4.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    >>> size, rhs(coef, [0.0, 1.0]).full().ravel().tolist()
    (12, [1.0, 2.5])
    """
    p = m * (m + 1) // 2
    L = 1 + m + p
    sizes = [L * m * m, L * m, L * m * m, L * m * p]
    z = ca.SX.sym("z", 2 * m)
    coef = ca.SX.sym("coef", sum(sizes))
    d, v = z[:m], z[m:]
    o = np.cumsum([0, *sizes])
    A, r0, r1, r2 = (coef[int(a):int(b)] for a, b in zip(o[:-1], o[1:], strict=True))
    mu = monomials(d)
    i, k = np.triu_indices(m)
    w = ca.vertcat(*[v[int(a)] * v[int(b)] for a, b in zip(i, k, strict=True)])
    Mdd = ca.reshape(ca.reshape(A, m * m, L) @ mu, m, m)
    r = (ca.reshape(r0, m, L) @ mu + ca.reshape(r1, m, L * m) @ ca.kron(mu, v)
         + ca.reshape(r2, m, L * p) @ ca.kron(mu, w))
    return (ca.Function("exact_poly_stage", [coef, z], [ca.vertcat(v, ca.solve(Mdd, r))]),
            int(o[-1]))


def torque(R: np.ndarray, n: int, m: int, d: np.ndarray, v: np.ndarray, dd: np.ndarray
           ) -> np.ndarray:
    """Joint torques ``τ = Σ_l μ_l(δ) (t0_l + tdd_l δ̈ + tv_l δ̇ + tvv_l w)`` at T samples
    from the torque rows of :func:`node_rows` (or their interpolation).

    Parameters
    ----------
    R : numpy.ndarray, shape (T, L (n + 2 n m + n p))
    n, m : int
        Number of joints and of modes.
    d, v, dd : numpy.ndarray, shape (T, m)
        δ, δ̇, δ̈.

    Returns
    -------
    numpy.ndarray, shape (T, n)
        Joint torques [N m].

    Examples
    --------
    One joint, one mode: τ = (1 + 2δ) + 3 δ̈ at δ = 0.5, δ̈ = 1 (the other rows 0).

    >>> R = np.zeros((1, 3 * 4)); R[0, [0, 1, 3]] = [1.0, 2.0, 3.0]
    >>> torque(R, 1, 1, np.array([[0.5]]), np.array([[0.0]]), np.array([[1.0]])).tolist()
    [[5.0]]
    """
    p = m * (m + 1) // 2
    L = 1 + m + p
    T = R.shape[0]
    o = np.cumsum([0, L * n, L * n * m, L * n * m, L * n * p])
    t0 = R[:, o[0]:o[1]].reshape(T, L, n)
    tdd = R[:, o[1]:o[2]].reshape(T, L, n, m)
    tv = R[:, o[2]:o[3]].reshape(T, L, n, m)
    tvv = R[:, o[3]:o[4]].reshape(T, L, n, p)
    i, k = np.triu_indices(m)
    w = v[:, i] * v[:, k]
    per = (t0 + np.einsum("tlik,tk->tli", tdd, dd) + np.einsum("tlij,tj->tli", tv, v)
           + np.einsum("tlis,ts->tli", tvv, w))
    return np.einsum("tl,tli->ti", monomials(d), per)
