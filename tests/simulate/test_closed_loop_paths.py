"""The closed loop with an EKF: the loop over the samples in Python against one CasADi
Function per sample under ``mapaccum`` (CasADi's VM, and compiled to C).

Reference: ``loop="python"``, the per-sample loop that evaluates the measurement model,
the EKF step and the plant step as separate CasADi calls on numpy arrays and carries the
filter's state, the previous acceleration and the previous joint rates in Python. The
``mapaccum`` paths carry the same quantities inside one symbolic Function.

Tolerance: both paths perform the same floating-point operations on the same doubles
(the symbolic step inlines or calls the same Functions; CSE only shares identical nodes),
so they agree to round-off. A compiled step may differ from CasADi's VM by the C
compiler's contraction of ``a*b + c`` or a libm function's last bit (~1e-16 relative per
operation); the loop is stable and the EKF contracting, so such differences are not
amplified beyond a few hundred ulps over the run. We allow 1e-9 of each signal's range
over the run: far below any physical effect (the EKF's estimation error on these runs is
~1e-2 of the range), and it would catch any bookkeeping error (a sample shifted, a
missing noise draw, a wrong difference), which moves the signals at the 1e-3 level or
more.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex import control
from casflex.moves import Move, ShapedMove, load_move
from casflex.simulate import simulate_closed_loop

#: round-off budget relative to each signal's range (module docstring)
ROUNDOFF = 1e-9


def _assert_same(reference, other):
    for name in ("x", "tau", "x_hat"):
        a, b = getattr(reference, name), getattr(other, name)
        assert a.shape == b.shape
        assert np.all(np.isfinite(b))
        span = np.maximum(np.ptp(a, axis=0), np.abs(a).max(axis=0))  # range or size
        assert np.all(np.abs(a - b) <= ROUNDOFF * span), name
    np.testing.assert_array_equal(reference.t, other.t)


@pytest.fixture(scope="module")
def small_loop(arm_model, accel_sensors):
    """One mode, a 30° grid, the inversion law and an EKF on the two accelerometers."""
    from casflex.estimation import ekf_step_function, tabulate_plant

    model, _ = arm_model(1, step_deg=30, points=accel_sensors.points, gravity=None,
                         delta_order=0)
    dt = 2e-3
    R = (250e-6 * 9.8) ** 2
    ekf = ekf_step_function(tabulate_plant(model, check=False), accel_sensors, 5e-6, R, dt)
    move = load_move("problems/moves.toml:control_move3")
    return model, control.inversion_controller(model, Kp=1.0, Kd=2.0), move, ekf, dt, R


@pytest.mark.parametrize("ddq, noise, impulse", [
    ("difference", "R", None),
    ("plant", "array", (0.3, [0.01, 0.0, 0.01])),
    ("difference", "array", (0.0, [0.0, 0.01, 0.0])),
])
def test_mapaccum_loop_equals_python_loop(small_loop, accel_sensors, ddq, noise, impulse):
    model, ctrl, move, ekf, dt, R = small_loop
    m = model.m
    t_end = 0.6
    est = {"step": ekf, "sensors": accel_sensors, "P0": 1e-4 * np.eye(2 * m),
           "x0": np.zeros(2 * m), "seed": 3, "ddq": ddq}
    if noise == "R":
        est["R"] = R * np.eye(accel_sensors.n_outputs)
    else:
        steps = int(round(t_end / dt)) + 1
        est["noise"] = np.random.default_rng(5).normal(0.0, R ** 0.5,
                                                       (steps, accel_sensors.n_outputs))
    runs = {loop: simulate_closed_loop(model, ctrl, move, t_end=t_end, dt=dt, sampled=True,
                                       estimator=est, impulse=impulse, loop=loop)
            for loop in ("python", "mapaccum")}
    # the run is not trivial: the plant moves and the estimate follows it
    assert np.ptp(runs["python"].x[:, 0]) > 1e-3
    assert np.ptp(runs["python"].x_hat[:, 0]) > 0.0
    _assert_same(runs["python"], runs["mapaccum"])


def test_auto_loop_needs_a_casadi_step_for_mapaccum(small_loop, accel_sensors):
    """A Python callable as the EKF step runs the Python loop ("auto") and is refused
    with ``loop="mapaccum"``."""
    from casflex.errors import ModelError

    model, ctrl, move, ekf, dt, _ = small_loop
    m = model.m
    calls = []

    def step(*args):
        calls.append(1)
        return ekf(*args)

    est = {"step": step, "sensors": accel_sensors, "P0": 1e-4 * np.eye(2 * m),
           "x0": np.zeros(2 * m)}
    r = simulate_closed_loop(model, ctrl, move, t_end=0.1, dt=dt, sampled=True,
                             estimator=est)
    assert len(calls) == r.t.size
    with pytest.raises(ModelError, match="casadi.Function"):
        simulate_closed_loop(model, ctrl, move, t_end=0.1, dt=dt, sampled=True,
                             estimator=est, loop="mapaccum")
    with pytest.raises(ModelError, match="loop must be"):
        simulate_closed_loop(model, ctrl, move, t_end=0.1, dt=dt, sampled=True,
                             estimator=est, loop="fast")


@pytest.mark.needs_cc
def test_vectorized_step_gives_the_plain_O1_numbers_bit_for_bit(small_loop, accel_sensors,
                                                                 tmp_path):
    """``jit=True`` compiles with :data:`JIT_FLAGS` (``-O1`` and the vectorizer, ~1.7x
    faster on the design job's loop): the vectorizer only packs element-wise operations
    into SIMD instructions, it reorders no floating-point operation without
    ``-ffast-math``, so the loop with the EKF (split at an impulse) equals the one
    compiled at plain ``-O1``, the flags before, bit for bit; and both are two libraries."""
    from casflex.simulate.torque import JIT_FLAGS

    model, ctrl, move, ekf, dt, R = small_loop
    m = model.m
    est = {"step": ekf, "sensors": accel_sensors, "P0": 1e-4 * np.eye(2 * m),
           "x0": np.zeros(2 * m), "seed": 3, "ddq": "difference",
           "R": R * np.eye(accel_sensors.n_outputs)}
    runs = [simulate_closed_loop(model, ctrl, move, t_end=0.6, dt=dt, sampled=True,
                                 estimator=est, impulse=(0.3, [0.01, 0.0, 0.01]), jit=jit,
                                 cache_dir=tmp_path) for jit in ("-O1", True)]
    assert "-ftree-vectorize" in JIT_FLAGS
    assert np.ptp(runs[0].x_hat[:, 0]) > 0.0
    for name in ("x", "tau", "x_hat", "tip"):
        np.testing.assert_array_equal(getattr(runs[1], name), getattr(runs[0], name), name)
    assert len(list((tmp_path / "jit").iterdir())) == 2


@pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
@pytest.mark.slow
@pytest.mark.needs_cc
def test_design_job_closed_loop_compiled_equals_python(model_cache, tmp_path):
    """The design job's closed loop with the bundled study's settings (3 modes, 3° grid,
    scheduled composite law, EKF with q̈ from the difference of q̇, noise drawn from R,
    1 ms for the shaped move 1 plus 3 s): Python loop, VM mapaccum and compiled step."""
    from casflex import shaping
    from casflex.design import load_study
    from casflex.estimation import ekf_step_function, tabulate_plant
    from casflex.model import build_model

    study = load_study("problems/studies/arm2link_move1.toml")
    move = study.move
    move = Move(move.q0, move.qf, move.duration, study.simulation["settle"], move.name)
    dt = study.simulation["dt"]
    model, table = build_model(study.robot, study.model["modes"],
                               step=study.model["grid_step"], points=study.sensors.points,
                               gravity=None, delta_order=study.model["delta_order"],
                               cache_dir=model_cache, processes=1)
    design = shaping.shaper_for_move(model, move, vtol=study.shaper["vtol"],
                                     margin=study.shaper["margin"],
                                     n_samples=study.shaper["n_samples"])
    shaped = ShapedMove(move, design.shaper)
    c = study.controller
    eps = control.perturbation_parameter(model, table=table)
    axis = -np.pi + 2.0 * np.pi * np.arange(c["schedule_points"]) / c["schedule_points"]
    gain = control.cached_gain_schedule(model, c["Q"], c["R"], eps, table, axis, model_cache)
    slow = study.slow_gains(float(np.min(design.omega_min)), shaped.duration)
    ctrl = control.composite_controller(model, Kp=slow.Kp, Kd=slow.Kd, gain=gain,
                                        epsilon=eps)
    e = study.estimator
    ekf = ekf_step_function(tabulate_plant(model, cache_dir=model_cache), study.sensors,
                            e["Q"], e["R"], dt)
    m = model.m
    est = {"step": ekf, "sensors": study.sensors, "P0": np.eye(2 * m) * e["P0"],
           "x0": np.zeros(2 * m), "R": np.diag(e["R"]), "seed": e["seed"],
           "ddq": "difference"}
    runs = {}
    for label, loop, jit in (("python", "python", False), ("vm", "mapaccum", False),
                             ("c", "mapaccum", True)):
        runs[label] = simulate_closed_loop(model, ctrl, shaped, t_end=shaped.t_end, dt=dt,
                                           estimator=est, sampled=True, loop=loop, jit=jit,
                                           cache_dir=tmp_path)
    assert runs["python"].t.size > 5000
    assert np.ptp(runs["python"].x_hat[:, 0]) > 0.0
    _assert_same(runs["python"], runs["vm"])
    _assert_same(runs["python"], runs["c"])


@pytest.mark.needs_cc
@pytest.mark.parametrize("sampled", [True, False])
def test_state_feedback_loop_compiled_equals_vm(small_loop, tmp_path, sampled):
    """The loop with the true state fed back (RK4 under ``mapaccum``, the design job's
    "where the tracking error comes from" runs): its step compiled to C against CasADi's
    VM, with an impulse splitting the run. Same budget as the EKF loops (module
    docstring): the same operations on the same doubles, up to contraction and libm."""
    model, ctrl, move, _, dt, _ = small_loop
    runs = [simulate_closed_loop(model, ctrl, move, t_end=0.6, dt=dt, method="rk4",
                                 sampled=sampled, impulse=(0.3, [0.01, 0.0, 0.01]),
                                 jit=jit, cache_dir=tmp_path) for jit in (False, True)]
    assert np.ptp(runs[0].x[:, 0]) > 1e-3  # the plant moves
    for name in ("x", "tau"):
        a, b = getattr(runs[0], name), getattr(runs[1], name)
        assert a.shape == b.shape and np.all(np.isfinite(b))
        span = np.maximum(np.ptp(a, axis=0), np.abs(a).max(axis=0))
        assert np.all(np.abs(a - b) <= ROUNDOFF * span), name
    np.testing.assert_array_equal(runs[0].t, runs[1].t)
    # a second run loads the compiled step from the cache (one library) and repeats it
    again = simulate_closed_loop(model, ctrl, move, t_end=0.6, dt=dt, method="rk4",
                                 sampled=sampled, impulse=(0.3, [0.01, 0.0, 0.01]),
                                 jit=True, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.x, runs[1].x)
    assert len(list((tmp_path / "jit").iterdir())) == 1
