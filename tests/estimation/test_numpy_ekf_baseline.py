"""The plain-numpy EKF baseline of benchmarks/bench_ekf.py: no CasADi call in its step,
and the same estimates as the CasADi step to round-off (so the benchmark's C/numpy ratio
compares two implementations of one filter)."""

import importlib.util
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from casflex.estimation import ekf_step_function, run_ekf, tabulate_plant
from casflex.simulate.measurements import simulate_data

ROOT = Path(__file__).resolve().parents[2]


def load_bench():
    spec = importlib.util.spec_from_file_location("bench_ekf",
                                                  ROOT / "benchmarks" / "bench_ekf.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_numpy_baseline_equals_casadi_step_without_calling_casadi(
        arm_model, accel_sensors, move, model_cache, monkeypatch):
    bench = load_bench()
    model, _ = arm_model(3, points=accel_sensors.points, gravity=None)
    # shared with test_ekf_faults (check=False: the check only fills info)
    plant = tabulate_plant(model, order=2, check=False, cache_dir=model_cache)
    Q, R, dt = 5e-6, (250e-6 * 9.8) ** 2, 1e-3
    step = ekf_step_function(plant, accel_sensors, Q, R, dt, jacobians="first_order",
                             update="batch")
    npstep = bench.numpy_step_factory(plant, accel_sensors, Q, R, dt)
    data = simulate_data(model, accel_sensors, move("move1"), dt=dt, t_end=0.3)
    x0, P0 = np.zeros(6), 1e-6 * np.eye(6)
    ref = run_ekf(step, data.u, data.y, x0, P0)
    mask = np.ones(accel_sensors.n_outputs)
    mask[2] = 0.0  # one channel dropped: the masked update path too

    def no_casadi(*args, **kwargs):
        raise AssertionError("the numpy step called CasADi")

    monkeypatch.setattr(ca.Function, "__call__", no_casadi)
    x, P, dev = x0, P0, 0.0
    for k in range(data.u.shape[0]):
        x, P, xp = npstep(x, P, data.u[k], data.y[k], np.ones_like(mask))
        dev = max(dev, float(np.max(np.abs(xp - ref.x[k]))))
    monkeypatch.undo()
    # round-off: the same ~10^4 operations in another order (measured ~3e-15 relative)
    assert dev <= bench.NUMPY_RTOL * np.max(np.abs(ref.x))
    # the masked channel: one step against the CasADi step (masked entry ignored)
    y = data.y[5].copy()
    y[2] = 1e3
    xn, Pn, xp = npstep(ref.x[4], P0, data.u[5], y, mask)
    out = step(ref.x[4], P0, data.u[5], y, mask)
    names = step.name_out()
    xref = np.asarray(out[names.index("x_post")]).ravel()
    assert np.allclose(xp, xref, rtol=0, atol=bench.NUMPY_RTOL * np.max(np.abs(xref)))
    assert np.allclose(Pn, np.asarray(out[names.index("P_next")]), rtol=0,
                       atol=bench.NUMPY_RTOL * np.max(np.abs(Pn)))
