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
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp

__all__ = ["block_derivatives"]


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
                      compile_function: Any = None, hessian: bool = True) -> dict:
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

    # the interval function's derivatives, on its stacked inputs
    zin = [ca.SX.sym(f"z{i}", G.sparsity_in(i)) for i in range(G.n_in())]
    z = ca.vertcat(*[ca.vec(s) for s in zin])
    gout = G.call(zin)
    y = ca.vertcat(*[ca.vec(gout[j]) for j in outputs])
    mu = ca.SX.sym("mu", y.shape[0])
    Jz = ca.jacobian(y, z)
    Hz = ca.triu(ca.hessian(ca.dot(mu, y), z)[0]) if hessian else ca.SX(z.shape[0], z.shape[0])
    jac_f = ca.Function("interval_jac", [z], [ca.vertcat(*Jz.nonzeros())])
    hess_f = ca.Function("interval_hess", [z, mu], [ca.vertcat(*Hz.nonzeros())])
    if compile_function is not None:
        jac_f, hess_f = compile_function([jac_f, hess_f] if hessian else [jac_f]) + \
            ([] if hessian else [hess_f])
    jrow, jcol = Jz.sparsity().get_triplet()
    hrow, hcol = Hz.sparsity().get_triplet()
    jrow, jcol, hrow, hcol = (np.asarray(a, dtype=int) for a in (jrow, jcol, hrow, hcol))

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
    nz = int(z.shape[0])
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
    nj, nh = jrow.size, hrow.size
    ks = np.repeat(np.arange(n), nj)
    es = np.tile(np.arange(nj), n)
    tr = row_of[ks, jrow[es]]
    tc = var[ks, jcol[es]]
    coef = fac[ks, jcol[es]] / (div_of[ks, jrow[es]] * gscale_of[ks, jrow[es]])
    on = coef != 0.0
    jac_dyn_sp, jac_map = _scatter(tr[on], tc[on], (ks * nj + es)[on], coef[on], ng, nx,
                                   n * nj)
    # Hessian: entry e of interval k's upper triangle (z rows hrow, columns hcol) goes to
    # the upper triangle at its two variables; an off-diagonal entry whose two inputs are
    # the same variable counts twice
    ks = np.repeat(np.arange(n), nh)
    es = np.tile(np.arange(nh), n)
    v1, v2 = var[ks, hrow[es]], var[ks, hcol[es]]
    coef = fac[ks, hrow[es]] * fac[ks, hcol[es]] * np.where(
        (hrow[es] != hcol[es]) & (v1 == v2), 2.0, 1.0)
    on = coef != 0.0
    hess_dyn_sp, hess_map = _scatter(np.minimum(v1, v2)[on], np.maximum(v1, v2)[on],
                                     (ks * nh + es)[on], coef[on], nx, nx, n * nh)
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
    nlp = ca.Function("nlp", [x, opti.p], [opti.g, g_rest, opti.f, *args])
    g_all, g_rest, f, *margs = nlp.call([xu, p])
    g_all, g_rest, f = g_all / gs, g_rest / gs, f / fs
    Z = _stacked_inputs(G, margs, n)
    jac_rest = ca.jacobian(g_rest, xt)
    hess_rest = ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g * keep, g_rest), xt)[0]) \
        if hessian else None
    jblocks = jac_f.map(n)(Z)
    jac_dyn = ca.MX(jac_dyn_sp, ca.mtimes(jac_map, ca.vec(jblocks)))
    if hessian:
        muk = ca.reshape(lam_g[mu_rows] * mu_scale, ny, n)
        hblocks = hess_f.map(n)(Z, muk)
        hess_dyn = ca.MX(hess_dyn_sp, ca.mtimes(hess_map, ca.vec(hblocks)))
    jac_g = ca.Function("nlp_jac_g", [xt, p], [g_all, jac_rest + jac_dyn],
                        ["x", "p"], ["g", "jac_g_x"])
    if not hessian:
        return {"jac_g": jac_g}
    hess_lag = ca.Function("nlp_hess_l", [xt, p, lam_f, lam_g], [hess_rest + hess_dyn],
                           ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    return {"jac_g": jac_g, "hess_lag": hess_lag}


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
