"""Table lookups for generated code: the interpolating cubic B-spline evaluated locally.

``casadi.interpolant("bspline")`` evaluates a table through CasADi's generic de Boor
routine (``casadi_nd_boor_eval``): per call it searches the knot interval, runs the
general de Boor recursion, and keeps a separate coefficient array (and call) for every
derivative its users take. :func:`local_bspline_function` is the same spline — the
interpolating cubic B-spline with not-a-knot end conditions, CasADi's default, fitted
here by a direct solve (``scipy.interpolate.make_interp_spline``) instead of CasADi's
iterative least squares, so the two agree to rounding of that fit (≈ 1e-14 of the
values) — written as a small CasADi graph that the C code generator turns into straight
code:

1. the knot interval ``i`` is located once (binary search over the distinct knots);
2. the four non-zero cubic basis functions at ``x`` come from the six knots around ``i``
   (the Cox–de Boor triangle, a few dozen scalar operations shared by every entry);
3. the value of every entry is the weighted sum of its four local coefficients, read from
   the one coefficient array through a pointer offset (no copy, no search per entry).

Derivatives are those of the same graph (algorithmic differentiation of the basis
weights), so the first and second derivatives use the same coefficient array: no extra
tables in the generated C.

How the coefficient rows are read (``rows``):

* ``"pointer"`` (default, the EKF plant's): a pointer offset into the table, the fewest
  instructions. CasADi counts the table as work memory of the function (casadi/casadi#4386:
  an MX constant gets work slots although the C code only points at it), so the
  ``<f>_SZ_W`` of a function that calls the lookup grows by the table's size.
* ``"static"``: through a one-axis linear ``casadi.interpolant`` over the row indices,
  evaluated at whole numbers (weights exactly 1 and 0, so the rows come out bit-identical).
  The table is the interpolant's own data, a ``static const`` array in C, and the work
  size stays a few dozen doubles. A few more instructions per lookup (each row read is a
  short loop instead of a pointer): the choice for large tables whose users allocate
  the work themselves (the model bundle).

The graph is a ``casadi.Function`` with ``never_inline``: called with SX arguments (the
models and the estimator build SX graphs) it stays one call node, whose C code the bundle
contains once.

Examples
--------
>>> import numpy as np
>>> grid = np.linspace(0.0, 3.0, 7)
>>> f = local_bspline_function("sq", grid, (grid**2)[:, None])
>>> round(float(f(1.25)), 12)   # a cubic spline reproduces a quadratic exactly
1.5625
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError

if TYPE_CHECKING:  # casadi is imported where it is used, as in the rest of casflex.modal
    import casadi as ca

__all__ = ["local_bspline_function", "DEGREE"]

#: degree of the interpolating B-spline (cubic, as ``casadi.interpolant("bspline")``)
DEGREE = 3


def local_bspline_function(name: str, axis: ArrayLike, values: ArrayLike, *,
                           rows: str = "pointer") -> ca.Function:
    """The interpolating cubic B-spline of ``values`` over ``axis``, evaluated locally.

    Parameters
    ----------
    name : str
        Name of the returned function (its C function is named after it).
    axis : array_like
        (n,) strictly increasing grid [rad, or the unit of the table's axis], n ≥ 4.
    values : array_like
        (n, k) values of ``k`` entries at the grid points.
    rows : {"pointer", "static"}
        How the coefficient rows are read (module docstring): ``"static"`` keeps the
        table out of the declared work memory.

    Returns
    -------
    casadi.Function
        ``name(x) -> (k × 1)``: the spline at ``x``; beyond the grid the end polynomials
        are extrapolated (callers wrap or clamp ``x`` first, as
        :meth:`casflex.modal.tables.ModalTable.function` does). Differentiable (first and
        second derivatives from the same coefficients); ``never_inline`` (one call node in
        SX graphs).

    Raises
    ------
    casflex.errors.ModelError
        For fewer than four grid points, a grid that does not increase, or values whose
        rows do not match the grid, or an unknown ``rows``.

    Examples
    --------
    >>> import casadi as ca
    >>> grid = np.linspace(0.0, 1.0, 9)
    >>> f = local_bspline_function("cube", grid, np.c_[grid**3, 2.0 + 0 * grid])
    >>> np.round(np.array(f(0.3)).ravel(), 12).tolist()
    [0.027, 2.0]
    >>> x = ca.SX.sym("x")
    >>> d2 = ca.Function("d2", [x], [ca.jacobian(ca.jacobian(f(x)[0], x), x)])
    >>> round(float(d2(0.3)), 9)   # (x³)'' = 6 x
    1.8
    >>> wide = np.c_[np.sin(grid)] * np.ones((1, 100))   # 9 x 100 coefficients
    >>> local_bspline_function("a", grid, wide).sz_w()   # the table counted as work
    1136
    >>> local_bspline_function("b", grid, wide, rows="static").sz_w()
    238
    """
    axis = np.asarray(axis, dtype=float).ravel()
    values = np.asarray(values, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    if axis.size < DEGREE + 1:
        raise ModelError(f"{name}: the cubic B-spline needs at least {DEGREE + 1} grid "
                         f"points; got {axis.size}")
    if not np.all(np.diff(axis) > 0):
        raise ModelError(f"{name}: the grid must increase strictly")
    if values.ndim != 2 or values.shape[0] != axis.size:
        raise ModelError(f"{name}: values must be ({axis.size}, k); got {values.shape}")
    if rows not in ("pointer", "static"):
        raise ModelError(f"{name}: rows must be 'pointer' or 'static'; got {rows!r}")
    import casadi as ca
    from scipy.interpolate import make_interp_spline

    k = values.shape[1]
    spline = make_interp_spline(axis, values, k=DEGREE)  # not-a-knot, as CasADi's
    knots = np.asarray(spline.t, dtype=float)
    coef = np.asarray(spline.c, dtype=float).reshape(-1, k)  # (basis functions, k)
    nb = coef.shape[0]
    p = DEGREE
    breaks = knots[p:nb + 1]  # distinct knots: the spans [t_p, t_nb]
    x = ca.MX.sym("x")
    # span t_i <= x < t_{i+1}, p <= i <= nb - 1 (clamped by the search, also for NaN):
    # every offset below stays inside its array
    i = ca.low(ca.DM(breaks), x, {"lookup_mode": "binary"}) + p
    local = ca.MX(ca.DM(knots)).get_nz(False, ca.Slice(0, 2 * p), i - (p - 1))
    t = [local[j] for j in range(2 * p)]  # t[j] = knot i - p + 1 + j

    def knot(offset):  # knot i + offset, -p + 1 <= offset <= p
        return t[offset + p - 1]

    left = [None] + [x - knot(1 - j) for j in range(1, p + 1)]
    right = [None] + [knot(j) - x for j in range(1, p + 1)]
    basis = [ca.MX(1.0)] + [None] * p
    for j in range(1, p + 1):  # Cox–de Boor (Piegl & Tiller, algorithm A2.2)
        saved = ca.MX(0.0)
        for r in range(j):
            temp = basis[r] / (right[r + 1] + left[j - r])
            basis[r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        basis[j] = saved
    if rows == "static":
        # row j of the table is the linear interpolant at the whole number j: weights 1
        # and 0 exactly, the "exact" lookup of an equidistant axis (no search)
        read = ca.interpolant(f"{name}_rows", "linear", [np.arange(nb, dtype=float)],
                              coef.ravel(), {"lookup_mode": ["exact"]})
    else:
        table = ca.MX(ca.DM(coef.ravel()))  # row-major: the k entries of a basis function

        def read(row):  # a pointer offset into the table
            return table.get_nz(False, ca.Slice(0, k), row * k)
    out = 0
    for r in range(p + 1):  # basis function i - p + r
        out = out + basis[r] * read(i - p + r)
    return ca.Function(name, [x], [out], ["x"], ["f"], {"never_inline": True})
