"""The locally evaluated B-spline (casflex.modal.table_functions) against two independent
references: scipy's interpolating spline (value and derivatives) and CasADi's bspline
interpolant (through ModalTable.function, periodic and clamped axes)."""

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

from casflex.errors import ModelError
from casflex.modal.table_functions import local_bspline_function
from casflex.modal.tables import ModalTable

# Both sides evaluate the same cubic on the same span with ~10 operations: round-off of a
# few ulps of the largest coefficient (values O(1) here); 1e-13 leaves a margin of ~50 ulp.
SCIPY_ATOL = 1e-13
# CasADi fits its interpolating B-spline by iterative least squares: its values at the grid
# points miss the data by up to 3e-14 (measured), ours by ~1e-16; 1e-12 of the largest
# value covers that fit error and the derivatives' (grid step 0.13 rad: ×8, ×60 for q'').
CASADI_RTOL = (1e-12, 1e-11, 1e-10)


def _derivatives(f):
    """Value, first and second derivative of f (scalar input) as one SX function."""
    x = ca.SX.sym("x")
    v = ca.SX(f(x))
    d1 = ca.jacobian(v, x)
    return ca.Function("d", [x], [v, d1, ca.jacobian(d1, x)])


def test_value_and_derivatives_equal_scipys_spline():
    rng = np.random.default_rng(1)
    grid = np.sort(rng.uniform(-1.0, 2.0, 23))  # non-uniform knots
    values = rng.normal(size=(23, 5))
    f = local_bspline_function("t", grid, values)
    ref = make_interp_spline(grid, values, k=3)
    d = _derivatives(f)
    xs = np.r_[rng.uniform(grid[0], grid[-1], 200), grid]  # inside and at every knot
    for x in xs:
        v, d1, d2 = (np.array(o).ravel() for o in d(x))
        scale = [np.max(np.abs(ref(xs, nu=nu))) for nu in range(3)]
        assert np.max(np.abs(v - ref(x))) <= SCIPY_ATOL * scale[0]
        assert np.max(np.abs(d1 - ref(x, nu=1))) <= SCIPY_ATOL * 10 * scale[1]
        assert np.max(np.abs(d2 - ref(x, nu=2))) <= SCIPY_ATOL * 10 * scale[2]


@pytest.mark.parametrize("periodic", [True, False])
def test_table_lookup_local_equals_casadi_interpolant(periodic):
    rng = np.random.default_rng(2)
    if periodic:  # full turn, closed: the tables of a revolute shape joint
        grid = np.linspace(-np.pi, np.pi, 49)
        data = np.sin(grid)[:, None, None] * rng.normal(size=(1, 3, 2))
        data += np.cos(2 * grid)[:, None, None] * rng.normal(size=(1, 3, 2))
    else:  # a limited axis: held at its ends
        grid = np.linspace(-1.0, 1.5, 30)
        data = np.exp(grid)[:, None, None] * rng.normal(size=(1, 3, 2))
    table = ModalTable(grid=(grid,), shape_joints=(1,), values={"m": data},
                       omega=np.ones((grid.size, 1)), periodic=(periodic,))
    local = table.function("m", lookup="local")
    interp = table.function("m")
    assert local.size_out(0) == interp.size_out(0) == (3, 2)
    a, b = _derivatives(local), _derivatives(interp)
    xs = np.r_[rng.uniform(-4.0, 4.0, 150), grid, grid + 2 * np.pi, -np.pi, np.pi]
    ra = [np.array([np.array(o).ravel() for o in a(x)]) for x in xs]
    rb = [np.array([np.array(o).ravel() for o in b(x)]) for x in xs]
    for nu in range(3):
        ref = np.array([r[nu] for r in rb])
        got = np.array([r[nu] for r in ra])
        assert np.max(np.abs(got - ref)) <= CASADI_RTOL[nu] * np.max(np.abs(ref))


def test_nan_and_far_points_stay_inside_the_table():
    grid = np.linspace(0.0, 1.0, 8)
    f = local_bspline_function("t", grid, np.c_[grid, grid**2])
    assert np.all(np.isnan(np.array(f(np.nan))))
    # far outside: the end polynomial, read from inside the coefficient array
    ref = make_interp_spline(grid, np.c_[grid, grid**2], k=3)
    for x in (-20.0, 20.0):  # cubic round-off grows as |x|³: kept moderate
        np.testing.assert_allclose(np.array(f(x)).ravel(), ref(x), rtol=1e-9)


def test_generated_c_has_no_generic_de_boor(tmp_path):
    grid = np.linspace(-np.pi, np.pi, 25)
    table = ModalTable(grid=(grid,), shape_joints=(0,), values={"v": np.c_[np.sin(grid)]},
                       omega=np.ones((25, 1)), periodic=(True,))
    cg = ca.CodeGenerator("lookup.c")
    cg.add(table.function("v", lookup="local"))
    code = cg.dump()
    assert "nd_boor_eval" not in code and "casadi_low" in code


def test_bad_input_is_refused():
    with pytest.raises(ModelError, match="at least 4"):
        local_bspline_function("t", [0.0, 1.0, 2.0], np.zeros((3, 1)))
    with pytest.raises(ModelError, match="increase"):
        local_bspline_function("t", [0.0, 2.0, 1.0, 3.0], np.zeros((4, 1)))
    with pytest.raises(ModelError, match="values must be"):
        local_bspline_function("t", [0.0, 1.0, 2.0, 3.0], np.zeros((5, 1)))
    table = ModalTable(grid=(np.linspace(0, 1, 5),), shape_joints=(0,),
                       values={"v": np.zeros((5, 1))}, omega=np.ones((5, 1)))
    with pytest.raises(ModelError, match="lookup='fast'"):
        table.function("v", lookup="fast")
