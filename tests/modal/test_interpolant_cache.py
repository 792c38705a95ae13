"""interpolant_cache: grid_function's B-spline fits kept on disk (issue 17, the design job)."""

from __future__ import annotations

import numpy as np

from casflex.modal import grid_function, interpolant_cache


def _table():
    # a 2-D table of vectors (the shape of a gain schedule's lookup), one axis full-turn
    q2 = np.linspace(-1.0, 1.0, 9)
    q3 = np.linspace(-np.pi, np.pi, 13)
    g2, g3 = np.meshgrid(q2, q3, indexing="ij")
    return [q2, q3], np.stack([np.sin(g2) * np.cos(g3), g2 * g3, np.exp(0.3 * g2)], axis=-1)


def _points():
    rng = np.random.default_rng(3)
    return np.column_stack([rng.uniform(-1.2, 1.2, 40), rng.uniform(-7.0, 7.0, 40)])


def _values(f):
    return np.array([np.asarray(f(x)).ravel() for x in _points()])


def test_read_back_is_the_fit_bit_for_bit(tmp_path):
    grid, data = _table()
    fresh = grid_function("g", grid, data, periodic=(False, True))  # no cache: fitted
    with interpolant_cache(tmp_path):
        stored = grid_function("g", grid, data, periodic=(False, True))  # fitted, stored
        files = list((tmp_path / "interpolants").iterdir())
        again = grid_function("g", grid, data, periodic=(False, True))  # read back
    assert len(files) == 1
    # the same coefficients and evaluation: equal to the last bit, and the same graph
    # (what the compiled loops' and the C bundle's cache keys hash)
    assert np.array_equal(_values(again), _values(fresh))
    assert np.array_equal(_values(stored), _values(fresh))
    assert again.serialize() == fresh.serialize()
    # and its derivatives (the dynamics and the EKF differentiate the lookups)
    import casadi as ca

    x = ca.MX.sym("x", 2)
    jac = [ca.Function("j", [x], [ca.jacobian(f(x), x)]) for f in (fresh, again)]
    assert all(np.array_equal(np.asarray(jac[0](p)), np.asarray(jac[1](p))) for p in _points())


def test_changed_table_or_damaged_file_is_fitted_again(tmp_path):
    grid, data = _table()
    with interpolant_cache(tmp_path):
        grid_function("g", grid, data)
        changed = data.copy()
        changed[4, 6, 1] += 1e-9  # one value, far below any tolerance: another key
        f = grid_function("g", grid, changed)
    assert len(list((tmp_path / "interpolants").iterdir())) == 2
    assert np.array_equal(_values(f), _values(grid_function("g", grid, changed)))
    path = next(p for p in (tmp_path / "interpolants").iterdir())
    path.write_bytes(path.read_bytes()[:-100])  # truncated
    with interpolant_cache(tmp_path):
        for table in (data, changed):
            f = grid_function("g", grid, table)
            assert np.array_equal(_values(f), _values(grid_function("g", grid, table)))


def test_off_outside_the_block_and_with_false(tmp_path):
    grid, data = _table()
    with interpolant_cache(False):
        grid_function("g", grid, data)
    grid_function("g", grid, data)
    with interpolant_cache(tmp_path):
        grid_function("g", grid, data, method="linear")  # nothing to fit: not stored
    assert not (tmp_path / "interpolants").exists()
