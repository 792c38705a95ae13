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

import contextlib
import hashlib
import math
import os
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError

if TYPE_CHECKING:  # casadi is imported where it is used, as in the rest of casflex.modal
    import casadi as ca

__all__ = ["grid_function", "local_bspline_function", "interpolant_cache", "DEGREE"]

#: degree of the interpolating B-spline (cubic, as ``casadi.interpolant("bspline")``)
DEGREE = 3

_TWO_PI = 2.0 * math.pi

#: the cache root of :func:`interpolant_cache` while its block runs (``None``: off)
_FIT_CACHE: list = [None]


@contextlib.contextmanager
def interpolant_cache(cache_dir: str | os.PathLike | bool | None = None) -> Iterator[None]:
    """Within the block, :func:`grid_function`'s B-spline interpolants are kept in the
    on-disk cache: fitted once, then read back.

    ``casadi.interpolant("bspline")`` fits the spline's coefficients each time it is built
    (tenths of a second for a gain schedule's table); a job that rebuilds the same
    lookups from cached tables on every run (:func:`casflex.design.run_design`) reads the
    built Function instead. The file's key is the name, the method, the grid, the values
    (their bytes), the options and the CasADi version, so a changed table never reads a
    stale fit; the Function read back is the one stored (same coefficients, same
    evaluation, the same serialised graph).

    Parameters
    ----------
    cache_dir : str or pathlib.Path or bool, optional
        Cache root (default the casflex cache directory); ``False``: no caching.

    Examples
    --------
    >>> import tempfile
    >>> axis = np.linspace(0.0, 3.0, 7)
    >>> with interpolant_cache(tempfile.mkdtemp()):
    ...     first = grid_function("sq", [axis], axis**2)
    ...     again = grid_function("sq", [axis], axis**2)   # read back, not fitted
    >>> first.serialize() == again.serialize(), round(float(again(1.25)), 12)
    (True, 1.5625)
    """
    from casflex._cache import cache_root

    previous = _FIT_CACHE[0]
    _FIT_CACHE[0] = cache_root(cache_dir)
    try:
        yield
    finally:
        _FIT_CACHE[0] = previous


def _interpolant(name, method, axes, values, options):
    """``casadi.interpolant(name, method, axes, values, options)``, read from and kept in
    the cache of :func:`interpolant_cache` (B-splines, while it is on)."""
    import casadi as ca

    root = _FIT_CACHE[0]
    if root is None or method != "bspline":  # a linear interpolant has nothing to fit
        return ca.interpolant(name, method, axes, values, options)
    from casflex._cache import digest, load_verified, make_cache_directory, save_verified

    values = np.ascontiguousarray(values, dtype=float)
    key = digest({"name": name, "method": method, "axes": [list(map(float, a)) for a in axes],
                  "values": hashlib.sha256(values.tobytes()).hexdigest(),
                  "shape": list(values.shape), "options": options,
                  "casadi": ca.__version__})
    path = root / "interpolants" / f"{name}-{key[:32]}.npz"
    hit = load_verified(path, key)
    if hit is not None:
        return ca.Function.deserialize(hit["function"].tobytes().decode())
    f = ca.interpolant(name, method, axes, values, options)
    make_cache_directory(path.parent)
    save_verified(path, key, function=np.frombuffer(f.serialize().encode(), dtype=np.uint8))
    return f


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


def grid_function(name: str, grid: Sequence[ArrayLike], data: ArrayLike, *,
                  periodic: Sequence[bool] | None = None, method: str = "bspline",
                  lookup: str = "interpolant") -> ca.Function:
    """``casadi.Function`` interpolating gridded values (the lookup of a modal table).

    Parameters
    ----------
    name : str
        Name of the returned Function and of its output.
    grid : sequence of array_like
        One increasing axis per shape joint (rad).
    data : array_like
        Values on the grid, shape ``grid shape + value shape`` (value shape ``()``,
        ``(n,)``, ``(r, c)`` or higher).
    periodic : sequence of bool, optional
        Per axis, whether it may span a full turn: such an axis
        (:func:`casflex.modal.periodic_axis_kind`) is padded by three points on each side
        and its argument wrapped into the period. Default: no axis.
    method : {"bspline", "linear"}
        ``casadi.interpolant`` plugin; B-splines (cubic, interpolating, needing at least
        4 points per axis) give smooth derivatives for the dynamics.
    lookup : {"interpolant", "local", "static"}
        ``"local"``: a one-axis B-spline by :func:`local_bspline_function` (the same
        spline, leaner C); ``"static"``: the same with its table kept out of the declared
        work memory (``rows="static"``); else ``casadi.interpolant``.

    Returns
    -------
    casadi.Function
        ``f(q_shape) -> value``. Scalars and vectors come out as column vectors, matrices
        with their shape, higher arrays flattened in C order. Beyond a non-periodic
        axis's ends the value at the end is held.

    Examples
    --------
    >>> axis = np.linspace(0.0, 3.0, 7)
    >>> f = grid_function("sq", [axis], axis**2)
    >>> round(float(f(1.25)), 12)   # a cubic spline reproduces a quadratic exactly
    1.5625
    >>> float(f(5.0))               # held at the end of the axis
    9.0
    """
    import casadi as ca

    from casflex.modal.fits import periodic_axis_kind
    if method not in ("bspline", "linear") or lookup not in ("interpolant", "local", "static"):
        raise ModelError(f"method must be 'bspline' or 'linear'; got {method!r}, {lookup=}")
    data = np.asarray(data, dtype=float)
    nd = len(grid)
    vshape = data.shape[nd:]
    flat = _flatten_values(data, nd)
    axes = [np.asarray(a, dtype=float) for a in grid]
    periodic = periodic or (False,) * nd
    wrap = []
    for ax in range(nd):
        kind = periodic_axis_kind(axes[ax]) if periodic[ax] else None
        if kind is not None:
            axes[ax], flat = _pad_periodic(axes[ax], flat, ax, kind)
        wrap.append(None if kind is None else (float(grid[ax][0]), _TWO_PI))
    need = 4 if method == "bspline" else 2
    for ax, a in enumerate(axes):
        if a.size < need:
            raise ModelError(f"axis {ax} of the table has {a.size} points; the "
                             f"{method!r} interpolant needs at least {need}")
    x = ca.MX.sym("q_shape", nd)
    if flat.shape[-1] == 0:  # e.g. no joint springs: an empty quantity
        empty = ca.MX(ca.DM.zeros(*(vshape if len(vshape) == 2 else (0, 1))))
        return ca.Function(name, [x], [empty], ["q_shape"], [name])
    if lookup in ("local", "static") and method == "bspline" and nd == 1:
        rows = "static" if lookup == "static" else "pointer"
        interp = local_bspline_function(f"{name}_local", axes[0], flat, rows=rows)
    else:  # binary search: bit-identical to CasADi's default scan, in log2(n) steps
        interp = _interpolant(f"{name}_{method}", method, [list(a) for a in axes],
                              np.moveaxis(flat, -1, 0).ravel(order="F"),
                              {"lookup_mode": ["binary"] * nd})
    parts = []
    for ax in range(nd):
        xi = x[ax]
        if wrap[ax] is not None:
            lo, period = wrap[ax]
            xi = xi - period * ca.floor((xi - lo) / period)
        else:  # held at the ends: CasADi's B-splines are 0 beyond their knots
            lo, hi = axes[ax][0], axes[ax][-1]  # (fmin's derivative is ½ at a tie)
            xi = ca.if_else(xi < lo, lo, ca.if_else(xi > hi, hi, xi))
        parts.append(xi)
    out = interp(ca.vertcat(*parts))
    if len(vshape) == 2:
        out = ca.reshape(out, vshape[0], vshape[1])
    return ca.Function(name, [x], [out], ["q_shape"], [name])


def _flatten_values(data, nd):
    """grid_shape + value_shape -> grid_shape + (n,), matrices column-major (casadi)."""
    if data.ndim - nd == 2:  # column-major flattening of each matrix
        data = np.swapaxes(data, nd, nd + 1)
    return data.reshape(data.shape[:nd] + (-1,))


def _pad_periodic(axis, flat, ax, kind, pad=3):
    """Extend a full-turn axis (and the data along it) by ``pad`` points on each side."""
    if kind == "closed":
        base_axis = axis[:-1]
        base = np.take(flat, np.arange(axis.size - 1), axis=ax)
    else:
        base_axis, base = axis, flat
    n = base_axis.size
    pad = min(pad, n)
    left_axis = base_axis[n - pad:] - _TWO_PI
    right_axis = base_axis[:pad] + _TWO_PI
    new_axis = np.concatenate([left_axis, base_axis, right_axis])
    left = np.take(base, np.arange(n - pad, n), axis=ax)
    right = np.take(base, np.arange(pad), axis=ax)
    return new_axis, np.concatenate([left, base, right], axis=ax)
