"""One lookup of several tables at one point (casflex.estimation.lookup) against scipy's
B-splines (an independent evaluation of the same interpolating cubic spline and its
derivatives), and against the local lookup of casflex.modal on a periodic axis."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

from casflex.errors import ModelError
from casflex.estimation.lookup import basis_derivatives, shared_lookup_function
from casflex.modal.table_functions import grid_function


def test_basis_derivatives_match_scipy(rng):
    """The basis functions and their first two derivatives at random points of random
    knot vectors equal scipy's ``BSpline.basis_element`` derivatives."""
    from scipy.interpolate import BSpline

    for _ in range(5):
        t = np.cumsum(rng.uniform(0.2, 1.5, 6))  # t_{i-2} .. t_{i+3}, span [t[2], t[3])
        x = rng.uniform(t[2], t[3])
        ders = basis_derivatives(x, list(t), 3, 2)
        full = np.r_[t[0] - 1.0, t, t[-1] + 1.0]  # knots of the four basis functions
        for r in range(4):
            b = BSpline.basis_element(full[r:r + 5], extrapolate=False)
            for k in range(3):
                ref = float(b.derivative(k)(x)) if k else float(b(x))
                assert abs(ders[k][r] - ref) <= 1e-12 * max(1.0, abs(ref))


def test_values_and_rates_match_scipy(rng):
    """Non-periodic axis: values, ``V̇ = V' q̇`` and ``V̈ = V'' q̇² + V' q̈`` of every
    table equal scipy's not-a-knot spline and its derivatives; held beyond the ends."""
    grid = np.sort(rng.uniform(-1.0, 2.0, 11))
    a, b = rng.normal(size=(11, 5)), rng.normal(size=(11, 2))
    f = shared_lookup_function("t", grid, False, {"a": (a, False), "b": (b, True)})
    assert f.name_out() == ["a", "b", "b_dot", "b_ddot"]
    sa, sb = make_interp_spline(grid, a, k=3), make_interp_spline(grid, b, k=3)
    for q in np.r_[rng.uniform(grid[0], grid[-1], 20), grid[1:-1]]:
        dq, ddq = rng.normal(size=2)
        va, vb, vd, vdd = (np.asarray(v).ravel() for v in f(q, dq, ddq))
        refs = (sa(q), sb(q), sb(q, 1) * dq, sb(q, 2) * dq**2 + sb(q, 1) * ddq)
        for got, ref in zip((va, vb, vd, vdd), refs, strict=True):
            assert np.max(np.abs(got - ref)) <= 1e-12 * max(1.0, np.max(np.abs(ref)))
    va, vb, vd, vdd = (np.asarray(v).ravel() for v in f(grid[-1] + 0.3, 1.0, 1.0))
    assert np.allclose(vb, b[-1], rtol=1e-12, atol=1e-12) and not vd.any() and not vdd.any()


def test_periodic_axis_equals_local_lookup(rng):
    """A full-turn axis (open, 7.5° steps): the values are bit-identical to the local
    lookup of the modal tables (same fit, same operations), the rates equal its
    derivatives by CasADi's differentiation to rounding, and q and q + 2π agree."""
    grid = np.radians(np.arange(-180.0, 180.0, 7.5))
    vals = np.c_[np.sin(grid), np.cos(2 * grid), rng.normal(size=(grid.size, 3))]
    f = shared_lookup_function("p", grid, True, {"v": (vals, True)})
    g = grid_function("v", [grid], vals, periodic=[True], lookup="local")
    q, dq, ddq = ca.SX.sym("q"), ca.SX.sym("dq"), ca.SX.sym("ddq")
    v = g(q)
    rate = ca.jacobian(v, q) * dq
    ref = ca.Function("ref", [q, dq, ddq], [v, rate, ca.jtimes(rate, q, dq)
                                            + ca.jacobian(v, q) * ddq])
    for x in np.r_[rng.uniform(-7.0, 7.0, 20), grid[::5]]:
        dx, ddx = rng.normal(size=2)
        got = [np.asarray(o).ravel() for o in f(x, dx, ddx)]
        want = [np.asarray(o).ravel() for o in ref(x, dx, ddx)]
        assert np.array_equal(got[0], want[0])
        for a, b in zip(got[1:], want[1:], strict=True):
            assert np.max(np.abs(a - b)) <= 1e-12 * max(1.0, np.max(np.abs(b)))
        again = [np.asarray(o).ravel() for o in f(x + 2 * np.pi, dx, ddx)]
        assert np.max(np.abs(again[0] - got[0])) <= 1e-12


def test_bad_tables():
    grid = np.linspace(0.0, 1.0, 5)
    with pytest.raises(ModelError, match="at least 4"):
        shared_lookup_function("t", grid[:3], False, {"a": (np.ones((3, 1)), False)})
    with pytest.raises(ModelError, match="table 'a'"):
        shared_lookup_function("t", grid, False, {"a": (np.ones((4, 1)), False)})
