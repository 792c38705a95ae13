"""One lookup of the EKF step's one-axis B-spline tables at the shape configuration.

An EKF step evaluates its tables at the same shape configuration ``q_s``: the plant's
coefficient table (:meth:`casflex.estimation.FlexiblePlant.coefficients`) and the
modal-table entries of the sensor signals with their first and second time derivatives
(:func:`casflex.sensors.measurement_with_entries`). Each table through its own
:func:`casflex.modal.local_bspline_function` costs a knot search and a Cox–de Boor
triangle, the derivatives one more call per order (algorithmic differentiation of the
whole lookup), and CasADi writes the weighted sum of the four coefficient rows as seven
passes over the table's width plus a copy. :func:`shared_lookup_function` evaluates the
same interpolating cubic B-spline of every table (the same padded grid and fit, so the
same knots) in one function:

1. tables with rates: the knot interval is located once (binary search), the four
   non-zero basis functions and their first two derivatives come from one triangle
   (Piegl & Tiller, *The NURBS Book*, algorithm A2.3; the values by the operations of
   :func:`casflex.modal.local_bspline_function`, so bit-identical to it), and the time
   derivatives are folded into the weights, ``V̇ = Σ (B'ᵣ q̇) cᵣ``,
   ``V̈ = Σ (B''ᵣ q̇² + B'ᵣ q̈) cᵣ``: three weighted sums of the same four rows, no
   differentiation of the lookup;
2. tables of values only (the plant's 280 coefficients): CasADi's fixed-coefficient
   B-spline node (:func:`casadi.bspline`), the same spline to rounding (de Boor's
   recursion instead of the triangle, ≤ 1e-16 relative). In generated C its call goes
   through casflex's routine (:func:`casflex.codegen.templates.fused_bspline_source`):
   the weighted sum of the four rows in one pass over the table, written into the output
   — for a wide table far fewer instructions than the elementwise sums (measured:
   ``benchmarks/README_ekf.md``, sessions 11 and 13); the same values as CasADi's own
   routine, which the Python step evaluates, bit for bit.

(A dense product of the ``k × 4`` block of rows with the weights would be one pass, but
CasADi's dense multiplication loops over the four rows innermost, which the C compiler
does not vectorise: it is slower than either.)

Periodic axes are padded and wrapped as :func:`casflex.modal.grid_function` does; beyond
a non-periodic axis the value at its end is held (derivatives zero there).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.fits import periodic_axis_kind
from casflex.modal.table_functions import DEGREE

__all__ = ["shared_lookup_function", "basis_derivatives"]


def basis_derivatives(x, knots: list, p: int = DEGREE, n: int = 2) -> list[list]:
    """The ``p + 1`` non-zero B-spline basis functions of degree ``p`` at ``x`` and their
    derivatives up to order ``n`` (Piegl & Tiller, algorithm A2.3).

    Parameters
    ----------
    x : casadi.MX or casadi.SX or float
        The point, in the knot span ``[t_i, t_{i+1})``.
    knots : list
        The ``2 p`` knots around the span, ``knots[j] = t_{i-p+1+j}``.
    p : int
        Degree.
    n : int
        Highest derivative (``n ≤ p``).

    Returns
    -------
    list of list
        ``ders[k][r]``: the ``k``-th derivative of basis function ``i - p + r``.
        ``ders[0]`` is computed by the operations of the Cox–de Boor triangle of
        :func:`casflex.modal.local_bspline_function` (bit-identical values).

    Examples
    --------
    >>> d = basis_derivatives(0.5, [-2.0, -1.0, 0.0, 1.0, 2.0, 3.0])   # uniform knots
    >>> for row in d:
    ...     print([round(v, 12) for v in row])
    [0.020833333333, 0.479166666667, 0.479166666667, 0.020833333333]
    [-0.125, -0.625, 0.625, 0.125]
    [0.5, -0.5, -0.5, 0.5]
    """
    left = [None] + [x - knots[p - j] for j in range(1, p + 1)]   # x - t_{i+1-j}
    right = [None] + [knots[p - 1 + j] - x for j in range(1, p + 1)]  # t_{i+j} - x
    # ndu[r][j] (r ≤ j): basis function i - j + r of degree j; ndu[j][r] (r < j): the knot
    # difference t_{i+r+1} - t_{i+r+1-j} that degree j divides by
    ndu = [[None] * (p + 1) for _ in range(p + 1)]
    ndu[0][0] = 1.0
    for j in range(1, p + 1):
        saved = 0.0
        for r in range(j):
            ndu[j][r] = right[r + 1] + left[j - r]
            temp = ndu[r][j - 1] / ndu[j][r]
            ndu[r][j] = right[r + 1] * temp if r == 0 else saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j][j] = saved
    ders = [[ndu[r][p] for r in range(p + 1)]]
    ders += [[None] * (p + 1) for _ in range(n)]
    for r in range(p + 1):
        a = [[1.0] + [None] * p, [None] * (p + 1)]
        s1, s2 = 0, 1
        for k in range(1, n + 1):
            rk, pk = r - k, p - k
            d = None
            if r >= k:
                a[s2][0] = a[s1][0] / ndu[pk + 1][rk]
                d = a[s2][0] * ndu[rk][pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[s2][j] = (a[s1][j] - a[s1][j - 1]) / ndu[pk + 1][rk + j]
                d = _acc(d, a[s2][j] * ndu[rk + j][pk])
            if r <= pk:
                a[s2][k] = -a[s1][k - 1] / ndu[pk + 1][r]
                d = _acc(d, a[s2][k] * ndu[r][pk])
            ders[k][r] = d
            s1, s2 = s2, s1
    factor = p
    for k in range(1, n + 1):
        ders[k] = [factor * v for v in ders[k]]
        factor *= p - k
    return ders


#: the narrowest table (entries) read through CasADi's B-spline node; the node's own knot
#: search and basis cost more than the shared basis's sum on a narrow table (rt_step's
#: 19-value plant table, session 11: 13 074 -> 13 616 instructions per step with the node
#: and CasADi's generic routine)
BSPLINE_NODE_MIN = 64


def _acc(total, term):
    return term if total is None else total + term


def shared_lookup_function(name: str, axis: ArrayLike, periodic: bool,
                           tables: Mapping[str, tuple[ArrayLike, bool]]) -> ca.Function:
    """Several tables over one grid axis, interpolated by cubic B-splines at one point in
    one function (module docstring).

    Parameters
    ----------
    name : str
        Name of the function (and of its C function).
    axis : array_like
        (n,) the grid of the shape joint [rad], strictly increasing, as in the tables
        (:class:`casflex.modal.ModalTable`).
    periodic : bool
        The axis may span a full turn (:func:`casflex.modal.periodic_axis_kind`): padded
        and the point wrapped, as :func:`casflex.modal.grid_function` does.
    tables : mapping of str to (array_like, bool)
        ``{table name: (values, rates)}``: values ``(n, k)`` at the grid points; ``rates``:
        also the entries' first and second time derivatives along the joint.

    Returns
    -------
    casadi.Function
        ``name(q_shape, dq_shape, ddq_shape)`` (the joint's angle [rad], rate [rad/s] and
        acceleration [rad/s²]) with one output per table (``k × 1``, its entries) and,
        for tables with ``rates``, ``<table>_dot`` and ``<table>_ddot`` after it.
        ``never_inline``: one call node in SX graphs.

    Raises
    ------
    casflex.errors.ModelError
        A grid of fewer than four points or not increasing, or values whose rows do not
        match it.
    Examples
    --------
    >>> grid = np.linspace(0.0, 3.0, 7)
    >>> f = shared_lookup_function("t", grid, False, {"sq": (grid[:, None] ** 2, True),
    ...                                                "one": (np.ones((7, 1)), False)})
    >>> f.name_in(), f.name_out()
    (['q_shape', 'dq_shape', 'ddq_shape'], ['sq', 'sq_dot', 'sq_ddot', 'one'])
    >>> [round(float(v), 12) for v in f(1.25, 0.5, 2.0)]   # x², 2x ẋ, 2ẋ² + 2x ẍ
    [1.5625, 1.25, 5.5, 1.0]
    """
    from scipy.interpolate import make_interp_spline

    grid = np.asarray(axis, dtype=float).ravel()
    if grid.size < DEGREE + 1 or not np.all(np.diff(grid) > 0):
        raise ModelError(f"{name}: the axis must increase strictly and have at least "
                         f"{DEGREE + 1} points; got {grid.size}")
    blocks = {}
    for key, (values, rates) in tables.items():
        v = np.asarray(values, dtype=float)
        v = v[:, None] if v.ndim == 1 else v
        if v.ndim != 2 or v.shape[0] != grid.size:
            raise ModelError(f"{name}: table {key!r} must be ({grid.size}, k); got {v.shape}")
        blocks[key] = (v, bool(rates))
    kind = periodic_axis_kind(grid) if periodic else None
    padded, flat = grid, np.concatenate([v for v, _ in blocks.values()], axis=1)
    if kind is not None:  # three points more on each side, as grid_function pads
        base = grid.size - (kind == "closed")  # a closed axis repeats its first point
        turns, idx = np.divmod(np.arange(-3, base + 3), base)
        padded, flat = grid[idx] + 2.0 * math.pi * turns, flat[idx]
    p = DEGREE
    # one fit of every column (the solve is per column: as each table's own fit)
    spline = make_interp_spline(padded, flat, k=p)
    knots = np.asarray(spline.t, dtype=float)
    coef = np.asarray(spline.c, dtype=float).reshape(-1, flat.shape[1])
    nb = coef.shape[0]
    q, dq, ddq = ca.MX.sym("q_shape"), ca.MX.sym("dq_shape"), ca.MX.sym("ddq_shape")
    if kind is not None:
        x = q - 2.0 * math.pi * ca.floor((q - grid[0]) / (2.0 * math.pi))
        inside = None
    else:  # held at the ends: there the rates are zero
        x = ca.if_else(q < grid[0], grid[0], ca.if_else(q > grid[-1], grid[-1], q))
        inside = ca.logic_and(q >= grid[0], q <= grid[-1])
    # span t_i <= x < t_{i+1}, p <= i <= nb - 1 (clamped by the search)
    i = ca.low(ca.DM(knots[p:nb + 1]), x, {"lookup_mode": "binary"}) + p
    local = ca.MX(ca.DM(knots)).get_nz(False, ca.Slice(0, 2 * p), i - (p - 1))
    ders = basis_derivatives(x, [local[j] for j in range(2 * p)], p, 2)
    value = ders[0]
    d1, d2 = (d if inside is None else [v * inside for v in d] for d in ders[1:])
    rate1 = [b * dq for b in d1]
    dq2 = dq * dq
    rate2 = [b2 * dq2 + b1 * ddq for b1, b2 in zip(d1, d2, strict=True)]
    outs, names, start = [], [], 0
    for key, (v, rates) in blocks.items():
        k = v.shape[1]
        start += k
        table = ca.MX(ca.DM(coef[:, start - k:start].ravel()))  # row-major: k per basis
        if not rates and k >= BSPLINE_NODE_MIN:
            # CasADi's node: one pass per row over the table (axpy), no copies
            outs.append(ca.bspline(x, ca.DM(coef[:, start - k:start].ravel()), [list(knots)],
                                   [p], k, {"lookup_mode": ["binary"]}))
            names.append(key)
            continue
        rows = [table.get_nz(False, ca.Slice(0, k), (i - p + r) * k) for r in range(p + 1)]
        sums = ((value, ""), (rate1, "_dot"), (rate2, "_ddot")) if rates else ((value, ""),)
        for weights, suffix in sums:
            out = weights[0] * rows[0]
            for r in range(1, p + 1):  # the order of local_bspline_function's sum
                out = out + weights[r] * rows[r]
            outs.append(out)
            names.append(key + suffix)
    return ca.Function(name, [q, dq, ddq], outs, ["q_shape", "dq_shape", "ddq_shape"], names,
                       {"never_inline": True})
