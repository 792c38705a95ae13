"""What keeps ``casflex codegen`` fast and its C small: compact constant tables, the lean
measurement function, the cached coarse gain schedule of the composite controller."""

import re

import casadi as ca
import numpy as np
import pytest

from casflex import codegen, control
from casflex.codegen import rtloop
from casflex.sensors import kinematic_measurement


def _tables(source):
    """Every ``static const casadi_real`` table of a C source, as floats."""
    found = re.findall(r"static const casadi_real casadi_c\d+\[\d+\] = \s*\{([^}]*)\};",
                       source)
    return [np.array([float(v) for v in body.split(",")]) for body in found]


def test_tables_are_written_short_and_exact(tmp_path):
    # an interpolant whose coefficients need all 17 digits: CasADi writes them with
    # %.16e; the bundle writes the shortest decimal that reads back to the same double
    grid = np.linspace(0.0, 1.0, 9)
    rng = np.random.default_rng(3)
    values = rng.normal(size=9) / 3.0
    values[2] = 1e-300                     # tiny, and an exact zero
    values[5] = 0.0
    f = ca.interpolant("lut", "linear", [grid], values)
    x = ca.MX.sym("x")
    fun = ca.Function("lookup", [x], [f(x)], ["x"], ["y"])
    b = codegen.generate([fun], tmp_path, name="tabs")
    text = b.source.read_text()
    assert "e+00" not in text.split("casadi_f0")[0]   # no %.16e literal before the code
    tables = _tables(text)
    # the grid and the values, bit for bit (a float read back from its repr is the same)
    assert any(t.size == grid.size and np.array_equal(t, grid) for t in tables)
    assert any(t.size == values.size and np.array_equal(t, values) for t in tables)


@pytest.mark.needs_cc
def test_compact_tables_compile_to_the_same_numbers(tmp_path):
    grid = np.linspace(-np.pi, np.pi, 13)
    coeffs = np.sin(3.0 * grid) / 7.0
    f = ca.interpolant("lut", "bspline", [grid], coeffs)
    x = ca.MX.sym("x")
    fun = ca.Function("lookup", [x], [f(x), ca.jacobian(f(x), x)], ["x"], ["y", "dy"])
    b = codegen.generate([fun], tmp_path, name="tabs_cc")
    c = codegen.load(codegen.build(b, flags=("-O1",)), "lookup")
    for q in np.linspace(-3.0, 3.0, 17):
        # same arithmetic on the same doubles: C and CasADi's VM agree to the last bit
        # (x86-64 without FMA contraction, as in the bench's README), within 1 ulp elsewhere
        for a, ref in zip(c(q), fun(q), strict=True):
            assert float(a) == pytest.approx(float(ref), rel=2.3e-16, abs=1e-300)


@pytest.mark.slow
def test_lean_measurement_matches_the_model(arm_model, accel_sensors):
    model, _ = arm_model(2, points=accel_sensors.points)
    full = kinematic_measurement(model, accel_sensors)
    funcs, _ = codegen.rt_functions(model, accel_sensors, Q=5e-6, dt=1e-3)
    lean = funcs["measurement"]
    rng = np.random.default_rng(7)
    for _ in range(8):
        x = 1e-3 * rng.normal(size=2 * model.m)
        u = np.r_[rng.uniform(-np.pi, np.pi, model.n), rng.normal(size=2 * model.n)]
        acc = rng.normal(size=model.m)
        a = np.asarray(lean(x, u, acc)).ravel()
        b = np.asarray(full(x, u, acc)).ravel()
        # one B-spline of the used entries vs the model's spline of all entries and its
        # derivatives: the same expressions to rounding (a few ulp of the ~10 m/s^2 signals)
        assert np.max(np.abs(a - b)) <= 1e-12 * np.max(np.abs(b))


@pytest.mark.slow
def test_composite_schedule_is_coarse_cached_and_exact_on_its_grid(arm_model, tmp_path):
    model, table = arm_model(1, delta_order=0)
    ctrl = rtloop.make_controller(model, "composite", schedule_points=8, cache_dir=tmp_path)
    assert ctrl.n_in() == 4
    assert len(list(tmp_path.glob("gains-*.npz"))) == 1
    eps = control.perturbation_parameter(model, table=table)
    axis = -np.pi + 2.0 * np.pi * np.arange(8) / 8
    sched = control.cached_gain_schedule(model, 1.0, 10.0, eps, table, axis, tmp_path)
    assert sched.info == {"from_cache": True}    # the controller's schedule was stored
    # the interpolating spline passes through the LQR gains at its grid points, which
    # fast_gain (one LQR at one configuration) recomputes independently
    q = np.zeros(model.n)
    q[list(sched.joints)] = axis[3]
    K = control.fast_gain(model, q, 1.0, 10.0, epsilon=eps)[0]
    got = sched.function(q).full()
    assert np.allclose(got, K, rtol=1e-8, atol=1e-10 * np.max(np.abs(K)))
