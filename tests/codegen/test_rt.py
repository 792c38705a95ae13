"""casflex.codegen.rtloop: the rt_step bundle (EKF + controller in one C call), the C closed loop.

Independent references: the CasADi evaluation of the same graph (C loaded back), and the
Python closed-loop simulation of casflex.control (a Python loop over samples calling the
EKF step, the controller and an RK4 step of the plant one by one, with the sensor
signals from the exact measurement model) against the closed loop run entirely in C
(plant ode, kinematic accelerometer model, rt_step) by the codegen harness.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from casflex import codegen
from casflex.cli import main
from casflex.codegen import rtloop
from casflex.estimation import ekf_step_function, tabulate_plant
from casflex.simulate import simulate_closed_loop

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
DT = 1e-3
Q_EKF = 5e-6
R_EKF = (250e-6 * 9.8) ** 2  # (250e-6 g)^2, eq. 185


@pytest.fixture(scope="module")
def setup(arm_model, accel_sensors, model_cache):
    sensors = accel_sensors
    model, _ = arm_model(3, points=sensors.points, gravity=None, delta_order=0)
    plant = tabulate_plant(model, check=False, cache_dir=model_cache)  # shared: test_rt_faults
    ekf = ekf_step_function(plant, sensors, Q_EKF, R_EKF, DT)
    composite = rtloop.make_controller(model, "composite")
    return model, sensors, ekf, composite


@pytest.fixture(scope="module")
def rt_lib(setup, tmp_path_factory):
    model, sensors, ekf, composite = setup
    inv = rtloop.make_controller(model, "inversion")
    inv_step = rtloop.rt_step_function(ekf, inv, DT, name="rt_step_inversion")
    bundle = rtloop.rt_bundle(ekf, composite, sensors, DT, tmp_path_factory.mktemp("rt"),
                              extra=[inv_step])
    return bundle, codegen.build(bundle, flags=("-O1",)), inv_step


def _rel(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.mark.needs_cc
@pytest.mark.slow
def test_rt_step_c_equals_python(setup, rt_lib):
    model, sensors, ekf, composite = setup
    bundle, lib, inv_step = rt_lib
    py = {"rt_step": rtloop.rt_step_function(ekf, composite, DT),
          "rt_step_inversion": inv_step}
    rng = np.random.default_rng(3)
    for name, f in py.items():
        c = codegen.load(lib, name)
        assert c.name_out() == ["tau", "x_next", "P_next", "dq_next", "x_post"]
        for _ in range(5):
            A = rng.normal(size=(6, 6))
            q = rng.uniform(-3, 3, 3)
            args = [1e-3 * rng.normal(size=6), 1e-4 * (A @ A.T + np.eye(6)),
                    rng.normal(size=3), q, rng.normal(size=3), q + 0.1 * rng.normal(size=3),
                    rng.normal(size=3), rng.normal(size=3), rng.normal(size=6),
                    (rng.uniform(size=6) > 0.2).astype(float)]
            got, want = c(*args), f(*args)
            for a, b in zip(got, want, strict=True):
                assert _rel(a, b) < 1e-10
            # the pieces: torque of the controller on the filtered estimate
            xn, Pn, xp = ekf(args[0], args[1], np.r_[q, args[4], (args[4] - args[2]) / DT],
                             args[8], args[9])
            xp = xp.full().ravel()
            xc = np.r_[q, xp[:3], args[4], xp[3:]]
            ctrl = composite if name == "rt_step" else rtloop.make_controller(model,
                                                                              "inversion")
            assert _rel(got[0], ctrl(args[5], args[6], args[7], xc)) < 1e-10
            assert _rel(got[1], xn) < 1e-10 and _rel(got[2], Pn) < 1e-10


@pytest.mark.needs_cc
@pytest.mark.slow
def test_closed_loop_in_c_matches_python_simulation(setup, tmp_path, move):
    """Move 3 under the scheduled composite law, EKF on noisy accelerometers, in C."""
    model, sensors, ekf, composite = setup
    move = move("control_move3")
    N = 2500
    rt = rtloop.rt_step_function(ekf, composite, DT)
    noise = np.random.default_rng(7).normal(size=(N + 1, 6)) * np.sqrt(R_EKF)
    bundle = rtloop.closed_loop_bundle(model, sensors, rt, DT, tmp_path)
    c = rtloop.run_closed_loop_c(bundle, move, N, DT, noise=noise[:N], flags=("-O1",))
    est = {"step": ekf, "sensors": sensors, "P0": 1e-4 * np.eye(6), "x0": np.zeros(6),
           "noise": noise, "ddq": "difference"}
    py = simulate_closed_loop(model, composite, move, t_end=N * DT, dt=DT,
                              estimator=est)
    np.testing.assert_allclose(c["t"], py.t, atol=1e-12)
    assert np.all(np.isfinite(c["x"]))
    scale = np.abs(py.x).max(axis=0) + 1e-12
    assert np.max(np.abs(c["x"] - py.x) / scale) < 1e-8
    assert _rel(c["tau"], py.tau[:N]) < 1e-8
    assert _rel(c["x_hat"], py.x_hat[:N]) < 1e-8
    # the loop does something: the move is tracked and the estimates follow the modes
    assert abs(c["x"][-1, 0] - move.qf[0]) < 0.05
    m = model.m
    err = c["x_hat"][:, :m] - c["x"][:N, 3:3 + m]
    assert np.sqrt(np.mean(err[:, 0] ** 2)) < 0.2 * np.sqrt(np.mean(c["x"][:N, 3] ** 2))
    assert c["timing"]["steps"] == N


@pytest.mark.slow
def test_cli_codegen_controller(tmp_path, capsys, monkeypatch, model_cache):
    # the run's shared cache: test_cli_codegen_guarded builds the same 30° table and plant
    monkeypatch.setenv("CASFLEX_CACHE", str(model_cache))
    argv = ["codegen", str(ROOT / "problems/arm2link.toml"), "--sensors",
            str(ROOT / "problems/sensors/arm2link_accel.toml"), "--out", str(tmp_path / "c"),
            "--step", "30deg", "--no-model", "--controller", "inversion", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert "rt_step" in out["functions"] and "ekf_step" in out["functions"]
    manifest = json.loads(Path(next(f for f in out["files"] if f.endswith(".json")))
                          .read_text())
    rt = next(f for f in manifest["functions"] if f["name"] == "rt_step")
    assert [p["name"] for p in rt["inputs"]] == ["x", "P", "dq_prev", "q", "dq", "qd", "dqd",
                                                 "ddqd", "y", "mask"]
    assert rt["outputs"][0]["unit"] == "N m"
    with pytest.raises(SystemExit):
        main(argv[:-3] + ["--controller", "pid", "--json"])
