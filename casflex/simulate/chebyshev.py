"""Piecewise Chebyshev interpolation in time of configuration arrays along a reference.

The polynomial form of prescribed motion (:mod:`casflex.simulate.poly`) needs arrays
``F(q(t))`` that depend on the configuration only, at every RK4 stage time. ``F(q(t))``
is analytic between the instants where the reference switches its acceleration or the
shape joints cross a knot of the modal tables (:func:`breaks`); between two breaks it is
interpolated on Chebyshev nodes, doubling the nodes until the interpolant's error is below
a tolerance (:func:`interpolants`), and evaluated by the barycentric formula
(:func:`values_at`) in the piece that serves each time (:func:`piece_index`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.errors import ModelError

if TYPE_CHECKING:
    from collections.abc import Callable

    from casflex.model import FlexibleModel
    from casflex.moves import Move, ShapedMove

    _Sampler = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
    _Piece = tuple[float, float, np.ndarray, np.ndarray, np.ndarray]

__all__ = ["evaluate", "breaks", "chebyshev_nodes", "interpolants", "piece_index", "values_at"]

_START = 5  # Chebyshev intervals per piece in the first round (then 10, 20, ...)
_MAX_NODES = 96


def evaluate(F: ca.Function, qs: np.ndarray, *rates: np.ndarray) -> np.ndarray:
    """Flat rows (len(qs) × R) of ``F`` at the configurations ``qs`` (one map call).

    Parameters
    ----------
    F : casadi.Function
        :func:`configuration_function` (or its compiled form); two or more outputs.
    qs : numpy.ndarray, shape (T, n)
        Joint positions [rad].
    *rates : numpy.ndarray, shape (T, n)
        Further inputs of ``F`` (the joint rates [rad/s] of
        :func:`casflex.simulate.exact_poly.configuration_function`).

    Returns
    -------
    numpy.ndarray, shape (T, R)
        Per row, every output flattened column-major (what :func:`interpolants` interpolates).

    Examples
    --------
    >>> x = ca.SX.sym("q", 2)
    >>> F = ca.Function("F", [x], [ca.diag(x), ca.sum1(x)])
    >>> evaluate(F, np.array([[1.0, 2.0], [3.0, 4.0]]))
    array([[1., 0., 0., 2., 3.],
           [3., 0., 0., 4., 7.]])
    """
    outs = F.map(qs.shape[0], "thread", 2)(qs.T, *[x.T for x in rates])
    # column-major flattening of every output, one row per configuration
    return np.hstack([np.asarray(o.full()).reshape(-1, qs.shape[0], order="F").T
                      if o.numel() else np.zeros((qs.shape[0], 0)) for o in outs])


def _table_knots(model):
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


def breaks(model: FlexibleModel, reference: Move | ShapedMove, sampler: _Sampler,
           t0: float, t1: float) -> np.ndarray:
    """Sorted times in [t0, t1] between which q(t) is a polynomial of degree ≤ 2 and no
    shape joint crosses a knot of the table interpolants (the coefficients are analytic
    there): the ends of the pieces of :func:`interpolants`.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The knots are those of its provider's table (none without a table).
    reference : casflex.moves.Move or casflex.moves.ShapedMove
        Its ``breakpoints`` are the switches of q̈ [s].
    sampler : callable
        ``sampler(t) -> (q, dq, ddq)`` of the reference (``reference_sampler(...).sample``).
    t0, t1 : float
        Simulated interval [s].

    Returns
    -------
    numpy.ndarray
        Break times [s], from ``t0`` to ``t1``.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move, reference_sampler
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=1))
    >>> move = Move([0, 0, 0], [-0.1, 0, 0], 0.4)
    >>> breaks(model, move, reference_sampler(move, 3).sample, 0.0, 0.5).tolist()
    [0.0, 0.2, 0.4, 0.5]
    """
    switches = reference.breakpoints
    phase = np.unique(np.r_[t0, np.clip(np.asarray(switches, dtype=float), t0, t1), t1])
    breaks = [phase]
    knots = _table_knots(model)
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


def chebyshev_nodes(a: float, b: float, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Chebyshev–Lobatto nodes on ``[a, b]`` and their barycentric weights.

    The nodes of ``2 K`` contain those of ``K`` (:func:`interpolants` doubles the count)
    and the end nodes are exactly ``b`` and ``a`` (neighbouring pieces share them).

    Parameters
    ----------
    a, b : float
        Interval [s].
    K : int
        Number of intervals (``K + 1`` nodes).

    Returns
    -------
    t : numpy.ndarray, shape (K + 1,)
        Nodes [s], from ``b`` down to ``a``.
    w : numpy.ndarray, shape (K + 1,)
        Weights of the barycentric formula (second kind).

    Examples
    --------
    >>> t, w = chebyshev_nodes(0.0, 1.0, 2)
    >>> t.tolist(), w.tolist()
    ([1.0, 0.5, 0.0], [0.5, -1.0, 0.5])
    """
    k = np.arange(K + 1)
    x = np.cos(np.pi * k / K)
    w = (-1.0) ** k
    w[0] *= 0.5
    w[-1] *= 0.5
    t = 0.5 * (a + b) + 0.5 * (b - a) * x
    t[0], t[-1] = b, a  # exactly: neighbouring pieces share their end nodes
    return t, w


def _barycentric(tn, w, fv, t):
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


def interpolants(F: ca.Function, sampler: _Sampler, breaks: np.ndarray, tol: float
                 ) -> tuple[list[_Piece], float, int, int]:
    """Chebyshev interpolants of ``F(q(t))`` (or ``F(q(t), q̇(t))``, as many of the
    sampler's outputs as ``F`` has inputs) on every piece between ``breaks``.

    The node count of every piece doubles (nested Chebyshev–Lobatto nodes) until the
    previous interpolant agrees with ``F`` at the new nodes to ``tol`` relative to the
    largest entry of each output block (a few evaluations of ``F`` per piece, not per step).

    Parameters
    ----------
    F : casadi.Function
        ``q -> arrays`` (:func:`configuration_function`) or ``(q, dq) -> arrays``, two
        or more outputs.
    sampler : callable
        ``sampler(t) -> (q, dq, ddq)`` of the reference.
    breaks : numpy.ndarray
        Sorted piece ends [s] (:func:`breaks`).
    tol : float
        Relative tolerance.

    Returns
    -------
    pieces : list of tuple
        ``(a, b, nodes, weights, values)``: interval [s], :func:`chebyshev_nodes` and the
        rows of ``F`` at the nodes (:func:`evaluate`).
    err : float
        Largest relative error estimate.
    evaluations : int
        Number of configurations at which ``F`` was evaluated.
    nodes : int
        Largest number of intervals of a piece.

    Examples
    --------
    >>> from casflex.moves import Move, reference_sampler
    >>> move, x = Move([0.0], [1.0], 1.0), ca.SX.sym("q")
    >>> F = ca.Function("F", [x], [ca.sin(x), ca.cos(x)])
    >>> sampler = reference_sampler(move, 1).sample
    >>> pieces, err, _, _ = interpolants(F, sampler, move.breakpoints, 1e-10)
    >>> len(pieces), err <= 1e-10
    (2, True)
    >>> bool(np.array_equal(pieces[1][4], evaluate(F, sampler(pieces[1][2])[0])))
    True
    """
    pieces = [(a, b) for a, b in zip(breaks[:-1], breaks[1:], strict=True) if b > a]
    K = _START
    nodes = {}
    vals = {}
    tq = np.concatenate([chebyshev_nodes(a, b, K)[0] for a, b in pieces])
    # F(q(t)) is continuous: a node shared by two pieces is evaluated once
    tu, back = np.unique(tq, return_inverse=True)
    arity = F.n_in()  # F(q) or F(q, q̇): both continuous across the breaks
    raw = evaluate(F, *sampler(tu)[:arity])[back]
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
        if K >= _MAX_NODES:
            worst = max(err[i] for i in todo)
            raise ModelError(
                f"method='poly': the interpolation of the model's configuration arrays "
                f"did not reach {tol:g} relative with {K} Chebyshev nodes per piece "
                f"(reached {worst:.2e}); the modal quantities are not smooth between the "
                "known breakpoints (provider without knot information?). Use method='rk4'")
        new_t = []
        for i in todo:
            a, b = pieces[i]
            tn2, _ = chebyshev_nodes(a, b, 2 * K)
            new_t.append(tn2[1::2])  # the nodes of 2K not already in K
        new_x = sampler(np.concatenate(new_t))[:arity]
        new_raw = evaluate(F, *new_x)
        evaluations += new_x[0].shape[0]
        o = 0
        nxt = []
        for i, tnew in zip(todo, new_t, strict=True):
            a, b = pieces[i]
            tn, w = chebyshev_nodes(a, b, K)
            fnew = new_raw[o:o + tnew.size]
            o += tnew.size
            e = float(np.max(np.abs(_barycentric(tn, w, vals[i], tnew) - fnew) / scale))
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
        tn, w = chebyshev_nodes(a, b, nodes[i])
        out.append((a, b, tn, w, vals[i]))
    return out, max(err.values()) if err else 0.0, evaluations, max(nodes.values())


def piece_index(pieces: Sequence[_Piece], t: np.ndarray, ddq: np.ndarray,
                piece_ddq: np.ndarray, left: bool = False) -> np.ndarray:
    """Index of the piece that gives the rows at each time ``t`` whose reference
    acceleration is ``ddq`` (T × n). Inside a piece that piece; at a break the later
    piece (``left=False``: the reference is right-continuous) or the earlier one
    (``left=True``: the left limit), and in either case the neighbour whose constant
    ``q̈`` (``piece_ddq``) is the reference's, should a break and a switch of the
    reference differ by round-off.

    Parameters
    ----------
    pieces : sequence of tuple
        Pieces of :func:`interpolants` (their intervals are used).
    t : numpy.ndarray, shape (T,)
        Sorted times [s].
    ddq : numpy.ndarray, shape (T, n)
        Reference acceleration at ``t`` [rad/s²].
    piece_ddq : numpy.ndarray, shape (len(pieces), n)
        Acceleration of every piece [rad/s²].
    left : bool
        At a break, take the earlier piece.

    Returns
    -------
    numpy.ndarray of int, shape (T,)

    Examples
    --------
    >>> tn, w = chebyshev_nodes(0.0, 1.0, 2)
    >>> pieces = [(0.0, 1.0, tn, w, None), (1.0, 2.0, tn + 1.0, w, None)]
    >>> acc = np.array([[1.0], [-1.0]])
    >>> piece_index(pieces, np.array([0.5, 1.0]), acc, acc).tolist()
    [0, 1]
    >>> piece_index(pieces, np.array([1.0 - 1e-15]), np.array([[-1.0]]), acc).tolist()
    [1]
    """
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


def values_at(pieces: Sequence[_Piece], values: Sequence[np.ndarray], t: np.ndarray,
              idx: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Rows of ``values`` (one array of node values per piece, nodes of ``pieces``)
    interpolated at the times ``t`` from the pieces ``idx`` (sorted), by the barycentric
    formula: the stage and torque rows at the RK4 times.

    Parameters
    ----------
    pieces : sequence of tuple
        Pieces of :func:`interpolants` (their nodes and weights are used).
    values : sequence of numpy.ndarray
        Per piece, the rows at its nodes, shape (number of nodes, R).
    t : numpy.ndarray, shape (T,)
        Times [s].
    idx : numpy.ndarray of int, shape (T,)
        Piece of every time (:func:`piece_index`).
    out : numpy.ndarray, shape (T, R), optional
        Array to fill and return.

    Returns
    -------
    numpy.ndarray, shape (T, R)

    Examples
    --------
    >>> tn, w = chebyshev_nodes(0.0, 1.0, 2)
    >>> pieces = [(0.0, 1.0, tn, w, None)]
    >>> values_at(pieces, [tn[:, None] ** 2], np.array([0.25, 0.5]), np.array([0, 0]))  # t²
    array([[0.0625],
           [0.25  ]])
    """
    width = values[0].shape[1]
    if out is None:
        out = np.empty((t.size, width))
    cut = np.r_[0, np.nonzero(np.diff(idx))[0] + 1, t.size]
    for lo, hi in zip(cut[:-1], cut[1:], strict=True):
        if hi > lo:
            i = idx[lo]
            _, _, tn, w, _ = pieces[i]
            out[lo:hi] = _barycentric(tn, w, values[i], t[lo:hi])
    return out
