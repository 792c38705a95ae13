"""The NLP's constraint Jacobian and Hessian of the Lagrangian assembled from per-interval
blocks (the planner's ``derivatives="blocks"``).

CasADi builds the derivatives of an ``Opti`` problem by forward and reverse sweeps
through the whole expression graph: for the interval function mapped over the ``N``
intervals of :func:`casflex.planning.plan_move`, one sweep per colour of the Jacobian's
sparsity, each through all ``N`` copies (move 1 of the design study: 0.77 s for the
Jacobian and 0.90 s for the Hessian per Ipopt iteration, session 9). Here the interval
function's own symbolic Jacobian ``∂G/∂z`` and the Hessian of ``μᵀG`` are evaluated once
per interval (one mapped call each) and their nonzeros scattered into the NLP's sparse
matrices through constant sparse maps (one sparse product each); the rest of the
problem (the linear constraints, the end condition, the objective) keeps CasADi's own
derivatives, with the interval function's rows taken out.

Everything the maps need is read from the ``Opti`` object: which NLP variables every
argument of the mapped call selects (its Jacobian with respect to ``opti.x``, constant:
the arguments must be linear in the variables), which rows of ``opti.g`` every output
fills (``vec(out / scale)``, rows given by the caller) and Opti's linear scaling of the
variables and constraints (``x = s x̃ + o``, ``g̃ = g / s_g``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp

__all__ = ["block_derivatives", "PointSplit", "point_split", "point_values"]


@dataclass(frozen=True)
class PointSplit:
    """An interval function written as ``y(z) = L z + Σ_j S_j φ(E_j z)``: a linear part
    and ``K`` calls of one point function ``φ`` on selections of the interval's stacked
    inputs ``z`` (:func:`point_split`).

    Attributes
    ----------
    phi : casadi.Function
        ``φ(w) -> y_p`` (SX; one column input of ``nw`` entries, one column output of
        ``nyp``).
    inputs : numpy.ndarray, shape (K, nw)
        Index in ``z`` of every entry of every point's ``w``.
    rows : numpy.ndarray, shape (K, nyp)
        Index in ``y`` (the stacked constraint outputs) of every point's output entries.
    linear : scipy.sparse.csr_matrix, shape (ny, nz)
        ``L``.
    outputs : tuple of int
        The interval function's outputs that ``y`` stacks.

    Examples
    --------
    >>> import casadi as ca, numpy as np, scipy.sparse as sp
    >>> w = ca.SX.sym("w")
    >>> s = PointSplit(phi=ca.Function("phi", [w], [ca.sin(w)]), inputs=np.array([[0], [1]]),
    ...                rows=np.array([[0], [1]]), linear=sp.csr_matrix((2, 2)), outputs=(0,))
    >>> s.inputs.shape  # K = 2 points of one input entry each
    (2, 1)
    """

    phi: ca.Function
    inputs: np.ndarray
    rows: np.ndarray
    linear: sp.csr_matrix
    outputs: tuple


def _selection(A, what):
    """Column of the one unit entry of every row of the constant ``A`` (else ValueError)."""
    A = _to_csr(A)
    A.eliminate_zeros()
    if np.any(np.diff(A.indptr) != 1) or np.any(A.data != 1.0):
        raise ValueError(f"point_split: {what} must be a selection (one entry 1 per row)")
    return A.indices.copy()


def point_split(name: str, zin: Sequence[ca.SX], points: Sequence[ca.SX], phi: ca.Function,
                Y: ca.SX, outs: Sequence[ca.SX], outputs: Sequence[int]
                ) -> tuple[ca.Function, PointSplit]:
    """The interval function built from ``K`` calls of a point function, and its split.

    Parameters
    ----------
    name : str
        Name of the interval function.
    zin : sequence of casadi.SX
        Its input symbols.
    points : sequence of casadi.SX
        ``w_j`` of every point (columns): selections of entries of ``zin``.
    phi : casadi.Function
        ``φ(w) -> y_p`` (SX).
    Y : casadi.SX
        Symbols ``(nyp, K)`` standing for ``φ(w_j)`` in ``outs``.
    outs : sequence of casadi.SX
        The interval function's outputs in ``zin`` and ``Y``; those of ``outputs`` linear
        in them, each entry of ``Y`` in exactly one entry with factor 1.
    outputs : sequence of int
        The outputs that are constraint rows (:func:`block_derivatives`).

    Returns
    -------
    (casadi.Function, PointSplit)
        The interval function (``φ`` substituted, expanded to SX) and its split.

    Examples
    --------
    >>> x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    >>> w = ca.SX.sym("w", 2)
    >>> phi = ca.Function("phi", [w], [ca.sin(w[0]) * w[1]])
    >>> Y = ca.SX.sym("Y", 1, 2)
    >>> G, split = point_split("G", [x, u], [ca.vertcat(x[0], u), ca.vertcat(x[1], u)],
    ...                        phi, Y, [Y - x.T], [0])
    >>> round(float(G([1.0, 2.0], 3.0)[0, 1]), 12)   # sin(2) * 3 - 2
    0.727892280477
    >>> split.inputs.tolist(), split.rows.tolist()
    ([[0, 2], [1, 2]], [[0], [1]])
    """
    K = len(points)
    z = ca.vertcat(*[ca.vec(s) for s in zin])
    W = ca.horzcat(*points)
    G = ca.Function(name, list(zin), [ca.substitute(o, ca.vec(Y), ca.vec(phi.map(K)(W)))
                                      for o in outs])
    y = ca.vertcat(*[ca.vec(outs[j]) for j in outputs])
    probe = ca.Function("probe", [z, ca.vec(Y)],
                        [ca.jacobian(y, z), ca.jacobian(y, ca.vec(Y)),
                         ca.jacobian(ca.vec(W), z)])
    if any(ca.depends_on(e, ca.vertcat(z, ca.vec(Y))) for e in
           (ca.jacobian(y, z), ca.jacobian(y, ca.vec(Y)), ca.jacobian(ca.vec(W), z))):
        raise ValueError("point_split: the outputs and the points must be linear in the "
                         "inputs and the point values")
    L, S, E = probe(np.zeros(z.shape[0]), np.zeros(Y.numel()))
    rows = _selection(S.T, "where every point value enters the outputs")
    inputs = _selection(E, "every point's input")
    nw, nyp = W.shape[0], Y.shape[0]
    return G, PointSplit(phi, inputs.reshape(K, nw), rows.reshape(K, nyp), _to_csr(L),
                         tuple(outputs))


def _to_csr(A):
    A = ca.DM(A)
    rows, cols = A.sparsity().get_triplet()
    return sp.csr_matrix((np.asarray(A.nonzeros(), dtype=float), (rows, cols)),
                         shape=A.shape)


def _interval_inputs(G, arg_shapes, n):
    """Per interval k: the constant map ``z_k = P_k x`` (sparse, rows = the interval
    function's stacked input entries) from the per-argument selections."""
    blocks = []
    for k in range(n):
        parts = []
        for i, (A, (rows, cols)) in enumerate(arg_shapes):
            w = G.size2_in(i)
            if cols == w:  # broadcast to every interval (the interval length)
                parts.append(A)
            else:
                first = k * w * rows
                parts.append(A[first:first + w * rows])
        blocks.append(sp.vstack(parts).tocsr())
    return blocks


def block_derivatives(opti: Any, G: ca.Function, args: Sequence[Any], mapped: Sequence[Any],
                      outputs: Sequence[int], rows: Sequence[int],
                      scales: Sequence[np.ndarray], n: int,
                      compile_function: Any = None, hessian: bool = True,
                      point: PointSplit | None = None) -> dict:
    """``jac_g`` and ``hess_lag`` for ``opti.solver`` from per-interval blocks.

    The constraints of ``opti`` must be complete. Output ``outputs[j]`` of the mapped call
    ``G.map(n)(*args)`` must appear in ``opti.g`` exactly once, as the rows
    ``rows[j] ... rows[j] + size - 1`` holding ``vec(out / scales[j])``, and in no other
    constraint or the objective.

    Parameters
    ----------
    opti : casadi.Opti
    G : casadi.Function
        The interval function (SX; its inputs are one interval's columns of ``args``, or
        the whole argument where it has as many columns as the input: broadcast).
    args : sequence of casadi.MX
        Arguments of the mapped call, linear in ``opti.x``.
    mapped : sequence of casadi.MX
        The mapped call's outputs, the very expressions the constraints were built from.
    outputs : sequence of int
        Outputs of ``G`` that are constraint rows.
    rows : sequence of int
        First row in ``opti.g`` of each.
    scales : sequence of numpy.ndarray
        The divisor of each (the shape of the mapped output) [units of the output].
    n : int
        Intervals (the map's size).
    compile_function : callable, optional
        ``compile_function(list of Function) -> list of Function`` (e.g. compiled C);
        default: the SX functions interpreted.
    hessian : bool
        Also the Hessian of the Lagrangian (else only ``jac_g``: Ipopt's Hessian stays
        CasADi's).
    point : PointSplit, optional
        ``G`` as a linear part and calls of one point function (:func:`point_split`): the
        blocks come from the point function's Jacobian and Hessian, evaluated at every
        point of every interval in one mapped call (small functions: quick to compile),
        instead of the whole interval's.

    Returns
    -------
    dict
        ``{"jac_g": Function, "hess_lag": Function}`` (without ``hess_lag`` when
        ``hessian`` is false): CasADi's ``nlpsol`` options.

    Examples
    --------
    >>> import casadi as ca
    >>> G = ca.Function("G", [x := ca.SX.sym("x", 2), h := ca.SX.sym("h")],
    ...                 [ca.vertcat(h * x[0] ** 2 - x[1])])
    >>> opti = ca.Opti()
    >>> X, T = opti.variable(2, 3), opti.variable()
    >>> opti.minimize(T ** 2 + ca.sumsqr(X))
    >>> r0 = opti.ng
    >>> out = G.map(3)(X, T / 3)
    >>> opti.subject_to(ca.vec(out / 2.0) == 0)
    >>> d = block_derivatives(opti, G, [X, T / 3], [out], [0], [r0], [np.full((1, 3), 2.0)],
    ...                       3)
    >>> sorted(d)
    ['hess_lag', 'jac_g']
    """
    x = opti.x
    nx = x.shape[0]
    args = [a if isinstance(a, ca.MX) else ca.MX(ca.DM(a)) for a in args]
    adv = opti.advanced
    xs = np.asarray(adv.x_linear_scale, dtype=float).ravel() if nx else np.zeros(0)
    xo = np.asarray(adv.x_linear_scale_offset, dtype=float).ravel() if nx else np.zeros(0)
    gs = np.asarray(adv.g_linear_scale, dtype=float).ravel()
    fs = float(adv.f_linear_scale)
    ng = opti.ng
    if xs.size != nx:
        xs, xo = np.ones(nx), np.zeros(nx)
    if gs.size != ng:
        gs = np.ones(ng)

    # the interval's derivatives on its stacked inputs z: entries (row in y, column in z)
    # whose values are ``coef`` times entry ``src`` of the interval's value vector
    if point is None:
        jd, hd = _interval_entries(G, outputs, hessian, compile_function)
    else:
        if tuple(outputs) != tuple(point.outputs):
            raise ValueError("block_derivatives: the point split covers other outputs")
        jd, hd = _point_entries(point, hessian, compile_function)
    nz = int(sum(G.sparsity_in(i).numel() for i in range(G.n_in())))

    # the NLP's rows of every output entry, per interval, and their divisors
    sizes = [G.sparsity_out(j).numel() for j in outputs]
    ny = int(sum(sizes))
    row_of = np.zeros((n, ny), dtype=int)
    div_of = np.zeros((n, ny))
    offset = 0
    for j, r0, size, scale in zip(outputs, rows, sizes, scales, strict=True):
        r_per, c_per = G.size1_out(j), G.size2_out(j)
        scale = np.broadcast_to(np.asarray(scale, dtype=float), (r_per, c_per * n))
        for k in range(n):
            cols = np.arange(k * c_per, (k + 1) * c_per)
            idx = (cols[:, None] * r_per + np.arange(r_per)[None, :]).ravel()
            row_of[k, offset:offset + size] = r0 + idx
            div_of[k, offset:offset + size] = scale[:, cols].T.ravel()
        offset += size
    dyn_rows = np.unique(row_of)
    if dyn_rows.size != row_of.size:
        raise ValueError("block_derivatives: two outputs claim the same rows of opti.g")
    gscale_of = gs[row_of]

    # z_k = P_k x + c_k; in the scaled variables, dz/dx̃ = P_k diag(s)
    sel = [(_to_csr(ca.Function("sel", [x], [ca.jacobian(ca.vec(a), x)])(np.zeros(nx))),
            a.shape) for a in args]
    for a in args:
        if ca.depends_on(ca.jacobian(ca.vec(a), x), x):
            raise ValueError("block_derivatives: an argument of the mapped call is not "
                             "linear in the NLP's variables")
    P = _interval_inputs(G, sel, n)
    # every input entry of an interval is one NLP variable times a constant (a selection,
    # or T / N): var[k, i] and its factor, in the scaled variables
    var = np.zeros((n, nz), dtype=int)
    fac = np.zeros((n, nz))
    for k in range(n):
        Pk = P[k].tocsr()
        Pk.eliminate_zeros()
        count = np.diff(Pk.indptr)
        if np.any(count > 1):
            raise ValueError("block_derivatives: every input entry of an interval must be "
                             "one NLP variable times a constant, or a constant")
        has = count == 1  # the others are constants (a fixed duration): no derivative
        var[k, has] = Pk.indices
        fac[k, has] = Pk.data * xs[Pk.indices]
    # Jacobian: entry e of interval k's block goes to NLP row row_of[k, jrow[e]], column
    # var[k, jcol[e]]
    jrow, jcol, jsrc, jcoef = jd["row"], jd["col"], jd["src"], jd["coef"]
    nj, nvj = jrow.size, jd["values"]
    ks = np.repeat(np.arange(n), nj)
    es = np.tile(np.arange(nj), n)
    tr = row_of[ks, jrow[es]]
    tc = var[ks, jcol[es]]
    coef = jcoef[es] * fac[ks, jcol[es]] / (div_of[ks, jrow[es]] * gscale_of[ks, jrow[es]])
    on = coef != 0.0
    jac_dyn_sp, jac_map = _scatter(tr[on], tc[on], (ks * nvj + jsrc[es])[on], coef[on], ng,
                                   nx, n * nvj)
    if hessian:
        # Hessian: entry e of interval k's upper triangle (z rows hrow, columns hcol) goes
        # to the upper triangle at its two variables; an off-diagonal entry whose two
        # inputs are the same variable counts twice
        hrow, hcol, hsrc = hd["row"], hd["col"], hd["src"]
        nh, nvh = hrow.size, hd["values"]
        ks = np.repeat(np.arange(n), nh)
        es = np.tile(np.arange(nh), n)
        v1, v2 = var[ks, hrow[es]], var[ks, hcol[es]]
        coef = fac[ks, hrow[es]] * fac[ks, hcol[es]] * np.where(
            (hrow[es] != hcol[es]) & (v1 == v2), 2.0, 1.0)
        on = coef != 0.0
        hess_dyn_sp, hess_map = _scatter(np.minimum(v1, v2)[on], np.maximum(v1, v2)[on],
                                         (ks * nvh + hsrc[es])[on], coef[on], nx, nx,
                                         n * nvh)
    mu_rows = row_of.ravel()
    mu_scale = 1.0 / (div_of * gscale_of).ravel()

    # the NLP in Opti's scaled variables
    xt = ca.MX.sym("x", nx)
    p = ca.MX.sym("p", opti.p.shape[0])
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", ng)
    xu = xs * xt + xo
    keep = np.ones(ng)
    keep[dyn_rows] = 0.0
    # the rest of the problem: Opti's expressions with the interval rows taken out
    g_rest = ca.graph_substitute(opti.g, [mapped[j] for j in outputs],
                                 [ca.MX.zeros(mapped[j].sparsity()) for j in outputs])
    # the derivatives of the rest from a function of its own: differentiated through a
    # call of a function that also returns opti.g, CasADi's sweeps would run through
    # the mapped interval function too (move 1 of the design study: ~1.2 s per Hessian)
    nlp = ca.Function("nlp", [x, opti.p], [opti.g, *args])
    rest = ca.Function("rest", [x, opti.p], [g_rest, opti.f])
    g_all, *margs = nlp.call([xu, p])
    g_rest, f = rest.call([xu, p])
    g_all, g_rest, f = g_all / gs, g_rest / gs, f / fs
    Z = _stacked_inputs(G, margs, n)
    jac_rest = _expanded("nlp_jac_rest", [xt, p], ca.jacobian(g_rest, xt))
    hess_rest = _expanded("nlp_hess_rest", [xt, p, lam_f, lam_g], ca.triu(ca.hessian(
        lam_f * f + ca.dot(lam_g * keep, g_rest), xt)[0])) if hessian else None
    jac_dyn = ca.MX(jac_dyn_sp, ca.mtimes(jac_map, ca.vec(jd["evaluate"](Z, n))))
    if hessian:
        muk = ca.reshape(lam_g[mu_rows] * mu_scale, ny, n)
        hess_dyn = ca.MX(hess_dyn_sp, ca.mtimes(hess_map, ca.vec(hd["evaluate"](Z, muk, n))))
    jac_g = ca.Function("nlp_jac_g", [xt, p], [g_all, jac_rest + jac_dyn],
                        ["x", "p"], ["g", "jac_g_x"])
    if not hessian:
        return {"jac_g": jac_g}
    hess_lag = ca.Function("nlp_hess_l", [xt, p, lam_f, lam_g], [hess_rest + hess_dyn],
                           ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    return {"jac_g": jac_g, "hess_lag": hess_lag}


def _expanded(name, inputs, expr):
    """``expr`` evaluated through an SX function of ``inputs`` (CasADi's ``expand``): the
    rest of the NLP is scalar operations on a few entries each, which SX evaluates
    without MX's per-node overhead; where it cannot be expanded, the MX expression."""
    try:
        return ca.Function(name, inputs, [expr]).expand().call(inputs)[0]
    except RuntimeError:
        return expr


def _interval_entries(G, outputs, hessian, compile_function):
    """The entries of the interval function's Jacobian and upper-triangular Hessian of
    ``μᵀy`` (one value each, from its own symbolic derivatives) and their evaluation over
    the intervals (``evaluate(Z, n)``, ``evaluate(Z, μ, n)``: one column per interval)."""
    zin = [ca.SX.sym(f"z{i}", G.sparsity_in(i)) for i in range(G.n_in())]
    z = ca.vertcat(*[ca.vec(s) for s in zin])
    gout = G.call(zin)
    y = ca.vertcat(*[ca.vec(gout[j]) for j in outputs])
    Jsp, Hsp, jac_f, hess_f = _derivative_functions("interval", z, y, hessian,
                                                    compile_function)
    return (_entries(Jsp, lambda Z, n: jac_f.map(n)(Z)),
            _entries(Hsp, lambda Z, mu, n: hess_f.map(n)(Z, mu)))


def _derivative_functions(name, z, y, hessian, compile_function):
    """Sparsities of ``∂y/∂z`` and of the upper triangle of ``∂²(μᵀy)/∂z²``, and the SX
    functions of their nonzeros, ``name_jac(z)`` and ``name_hess(z, μ)`` (compiled by
    ``compile_function`` when given)."""
    mu = ca.SX.sym("mu", y.shape[0])
    Jz = ca.jacobian(y, z)
    Hz = ca.triu(ca.hessian(ca.dot(mu, y), z)[0]) if hessian else ca.SX(z.shape[0], z.shape[0])
    jac_f = ca.Function(f"{name}_jac", [z], [ca.vertcat(*Jz.nonzeros())])
    hess_f = ca.Function(f"{name}_hess", [z, mu], [ca.vertcat(*Hz.nonzeros())])
    if compile_function is not None:
        jac_f, hess_f = compile_function([jac_f, hess_f] if hessian else [jac_f]) + \
            ([] if hessian else [hess_f])
    return Jz.sparsity(), Hz.sparsity(), jac_f, hess_f


def _entries(sparsity, evaluate):
    rows, cols = (np.asarray(a, dtype=int) for a in sparsity.get_triplet())
    return {"row": rows, "col": cols, "src": np.arange(rows.size), "coef": np.ones(rows.size),
            "values": rows.size, "evaluate": evaluate}


def _point_entries(point, hessian, compile_function):
    """:func:`_interval_entries` from a :class:`PointSplit`: the point function's Jacobian
    and Hessian evaluated at all ``K n`` points in one mapped call, the interval's entries
    being the points' entries at their rows and columns plus the constant ``L``."""
    phi = point.phi
    K, nw = point.inputs.shape
    nyp = point.rows.shape[1]
    w = ca.SX.sym("w", nw)
    Jsp, Hsp, jac_f, hess_f = _derivative_functions(phi.name(), w, phi(w), hessian,
                                                    compile_function)
    take = point.inputs.ravel().tolist()
    take_mu = point.rows.ravel().tolist()

    def points_of(Z, n):  # w of every point, one column each (interval-major)
        return ca.reshape(Z[take, :], nw, K * n)

    jr, jc = (np.asarray(a, dtype=int) for a in Jsp.get_triplet())
    nnz = jr.size
    L = point.linear.tocoo()
    jac = {"row": np.r_[point.rows[:, jr].ravel(), L.row],
           "col": np.r_[point.inputs[:, jc].ravel(), L.col],
           "src": np.r_[np.arange(K * nnz), np.full(L.nnz, K * nnz)],
           "coef": np.r_[np.ones(K * nnz), L.data], "values": K * nnz + 1,
           "evaluate": lambda Z, n: ca.vertcat(
               ca.reshape(jac_f.map(K * n)(points_of(Z, n)), K * nnz, n), ca.DM.ones(1, n))}
    hr, hc = (np.asarray(a, dtype=int) for a in Hsp.get_triplet())
    hess = {"row": point.inputs[:, hr].ravel(), "col": point.inputs[:, hc].ravel(),
            "src": np.arange(K * hr.size), "values": K * hr.size,
            "evaluate": lambda Z, muk, n: ca.reshape(
                hess_f.map(K * n)(points_of(Z, n), ca.reshape(muk[take_mu, :], nyp, K * n)),
                K * hr.size, n)}
    return jac, hess


def point_values(G: ca.Function, point: PointSplit, args: Sequence[Any], n: int,
                 compile_function: Any = None) -> list:
    """The constraint outputs of ``G.map(n)(*args)`` from the point split: the point
    function evaluated at all ``K n`` points in one mapped call (compiled by
    ``compile_function`` when given) plus the linear part.

    The same values as the mapped interval function's, to round-off; CasADi's
    expression graph of the NLP then evaluates the constraints through the small
    point function (compiled: move 1 of the design study, 0.040 s per evaluation of the
    NLP's ``g`` through the interval function's SX, a few ms compiled). The outputs
    have no derivatives of their own when compiled: they are for
    :func:`block_derivatives` (``mapped``), which assembles the derivatives from the
    point function's.

    Parameters
    ----------
    G : casadi.Function
        The interval function of the split.
    point : PointSplit
    args : sequence of casadi.MX
        Arguments of the mapped call (as for :func:`block_derivatives`).
    n : int
        Intervals.
    compile_function : callable, optional
        ``compile_function(list of Function) -> list of Function``.

    Returns
    -------
    list of casadi.MX
        The outputs ``point.outputs`` of the mapped call, in their mapped shapes.

    Examples
    --------
    >>> x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    >>> w = ca.SX.sym("w", 2)
    >>> phi = ca.Function("phi", [w], [ca.sin(w[0]) * w[1]])
    >>> Y = ca.SX.sym("Y", 1, 2)
    >>> G, split = point_split("G", [x, u], [ca.vertcat(x[0], u), ca.vertcat(x[1], u)],
    ...                        phi, Y, [Y - x.T], [0])
    >>> X = ca.DM([[1.0, 0.5], [2.0, 0.1]])
    >>> out = point_values(G, split, [ca.MX(X), ca.MX(ca.DM([[3.0, 4.0]]))], 2)[0]
    >>> float(ca.norm_inf(ca.evalf(out) - G.map(2)(X, ca.DM([[3.0, 4.0]]))))
    0.0
    """
    phi = point.phi
    if compile_function is not None:
        phi = compile_function([phi])[0]
    K, nw = point.inputs.shape
    nyp = point.rows.shape[1]
    args = [a if isinstance(a, ca.MX) else ca.MX(ca.DM(a)) for a in args]
    Z = _stacked_inputs(G, args, n)
    W = ca.reshape(Z[point.inputs.ravel().tolist(), :], nw, K * n)
    Yp = ca.reshape(phi.map(K * n)(W), K * nyp, n)
    ny = point.linear.shape[0]
    S = sp.csr_matrix((np.ones(K * nyp), (point.rows.ravel(), np.arange(K * nyp))),
                      shape=(ny, K * nyp))
    y = ca.mtimes(_to_dm(point.linear), Z) + ca.mtimes(_to_dm(S), Yp)
    out, first = [], 0
    for j in point.outputs:
        r, c = G.size1_out(j), G.size2_out(j)
        out.append(ca.reshape(y[first:first + r * c, :], r, c * n))
        first += r * c
    return out


def _to_dm(A):
    A = sp.csc_matrix(A)
    A.sort_indices()
    return ca.DM(ca.Sparsity(A.shape[0], A.shape[1], A.indptr.tolist(), A.indices.tolist()),
                 A.data.tolist())


def _stacked_inputs(G, args, n):
    """The interval function's stacked inputs of every interval, one column each (MX)."""
    parts = []
    for i, a in enumerate(args):
        rows_i, w = G.size1_in(i), G.size2_in(i)
        if a.shape[1] == w and n > 1 and w * n != a.shape[1]:
            parts.append(ca.repmat(ca.vec(a), 1, n))
        else:
            parts.append(ca.reshape(a, rows_i * w, n))
    return ca.vertcat(*parts)


def _scatter(tr, tc, src, coef, nrow, ncol, nsrc):
    """The sparsity of the target entries ``(tr, tc)`` and the constant sparse map from the
    source vector (length ``nsrc``) to its nonzeros (column-major, CasADi's order);
    sources that land on the same entry are summed."""
    key = np.asarray(tc, dtype=np.int64) * nrow + np.asarray(tr, dtype=np.int64)
    uniq, target = np.unique(key, return_inverse=True)
    rows = (uniq % nrow).astype(int)
    cols = (uniq // nrow).astype(int)
    sparsity = ca.Sparsity.triplet(nrow, ncol, rows.tolist(), cols.tolist())
    M = sp.csc_matrix((np.asarray(coef, dtype=float), (target.ravel(), np.asarray(src))),
                      shape=(uniq.size, nsrc))
    M.sum_duplicates()
    M.sort_indices()
    dm = ca.DM(ca.Sparsity(uniq.size, nsrc, M.indptr.tolist(), M.indices.tolist()),
               M.data.tolist())
    return sparsity, dm
