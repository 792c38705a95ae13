"""Generated C of the EKF and of the model: built, loaded back, compared with Python."""

import json
from pathlib import Path

import numpy as np
import pytest

from casflex import codegen
from casflex.cli import main
from casflex.codegen import covariance_run, ekf_bundle, model_bundle
from casflex.estimation import ekf_step_function, run_ekf, simulate_data, tabulate_plant

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
Q, R, DT = 5e-6, (250e-6 * 9.8) ** 2, 1e-3


@pytest.fixture(scope="module")
def setup(arm_model, accel_sensors):
    sensors = accel_sensors
    model, _ = arm_model(3, step_deg=30, points=sensors.points, gravity=None)
    plant = tabulate_plant(model, check=False)
    return model, sensors, plant


@pytest.fixture(scope="module")
def ekf_lib(setup, tmp_path_factory):
    model, sensors, plant = setup
    bundle = ekf_bundle(model, sensors, tmp_path_factory.mktemp("ekf"), Q, R, DT, plant=plant)
    return bundle, codegen.build(bundle, flags=("-O1",))


def _rel(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.mark.needs_cc
@pytest.mark.slow
def test_ekf_step_c_equals_python(setup, ekf_lib):
    model, sensors, plant = setup
    bundle, lib = ekf_lib
    rng = np.random.default_rng(0)
    step_py = ekf_step_function(plant, sensors, Q, R, DT)
    step_c = codegen.load(lib, "ekf_step")
    for _ in range(5):
        A = rng.normal(size=(6, 6))
        args = [1e-3 * rng.normal(size=6), 1e-4 * (A @ A.T + np.eye(6)),
                np.r_[rng.uniform(-3, 3, 3), rng.normal(size=6)], rng.normal(size=6),
                (rng.uniform(size=6) > 0.2).astype(float)]
        for a, b in zip(step_c(*args), step_py(*args), strict=True):
            assert _rel(a, b) < 1e-10
    meas_c = codegen.load(lib, "measurement")
    from casflex.sensors import kinematic_measurement

    meas_py = kinematic_measurement(model, sensors)
    args = [1e-3 * rng.normal(size=6), rng.normal(size=9), rng.normal(size=3)]
    assert _rel(meas_c(*args), meas_py(*args)) < 1e-10
    plant_c = codegen.load(lib, "plant")
    u = rng.normal(size=9)
    for a, b in zip(plant_c(u), plant.function()(u), strict=True):
        assert _rel(a, b) < 1e-10
    text = bundle.readme.read_text()
    assert "reentrant" in text and "ekf_step_SZ_W" in text
    assert bundle.reentrant


@pytest.mark.needs_cc
@pytest.mark.slow
@pytest.mark.parametrize("jacobians,update", [("first_order", "auto"),
                                              ("linearized", "auto"),
                                              ("first_order", "batch")])
def test_lean_step_with_native_flags_equals_python(setup, tmp_path, jacobians, update):
    """The benchmarked configuration: second-order plant (pruned), ``jacobians=
    "first_order"``, sequential scalar updates, the sensor-entry tables, built with ``-O3
    -march=native -ffp-contract=off``: within 1e-10 relative; likewise ``"linearized"``
    and the batch update. (With FMA contractions, i.e. without ``-ffp-contract=off``, the
    deviation on these random inputs reaches ~2e-7: rounding differences amplified by
    ill-conditioned updates.)"""
    _, sensors, plant = setup
    assert plant.order == 2 and plant.keep is not None
    step_py = ekf_step_function(plant, sensors, Q, R, DT, jacobians=jacobians,
                                update=update)
    bundle = codegen.generate([step_py], tmp_path, name="lean")
    step_c = codegen.load(codegen.build(
        bundle, flags=("-O3", "-march=native", "-ffp-contract=off")), "ekf_step")
    rng = np.random.default_rng(4)
    for _ in range(5):
        A = rng.normal(size=(6, 6))
        args = [1e-2 * rng.normal(size=6), 1e-4 * (A @ A.T + np.eye(6)),
                np.r_[rng.uniform(-3, 3, 3), rng.normal(size=6)], rng.normal(size=6),
                (rng.uniform(size=6) > 0.2).astype(float)]
        for a, b in zip(step_c(*args), step_py(*args), strict=True):
            assert _rel(a, b) < 1e-10


@pytest.mark.needs_cc
@pytest.mark.slow
def test_forward_dynamics_c_equals_python(setup, tmp_path):
    model, _, _ = setup
    bundle = model_bundle(model, tmp_path)
    f_c = codegen.load(codegen.build(bundle, flags=("-O0",)), "forward")
    f_py = model.functions()["forward"]
    rng = np.random.default_rng(1)
    for _ in range(3):
        args = [rng.uniform(-3, 3, 3), rng.normal(size=3), 1e-3 * rng.normal(size=3),
                1e-2 * rng.normal(size=3), rng.normal(size=3)]
        for a, b in zip(f_c(*args), f_py(*args), strict=True):
            assert _rel(a, b) < 1e-10


@pytest.fixture(scope="module")
def recorded(setup, move):
    model, sensors, _ = setup
    move = move("move1")
    return simulate_data(model, sensors, move, dt=DT, t_end=0.4)


@pytest.mark.needs_cc
@pytest.mark.slow
def test_c_harness_run_equals_python_run(setup, ekf_lib, recorded):
    _, sensors, plant = setup
    bundle, _ = ekf_lib
    d = recorded
    y = d.y.copy()
    y[50:60, 2] = np.nan  # a dropout: skipped in both
    mask = np.isfinite(y).astype(float)
    x0, P0 = np.zeros(6), 1e-6 * np.eye(6)
    res = codegen.run_harness(bundle, "ekf_step",
                              {"u": d.u, "y": np.nan_to_num(y), "mask": mask},
                              {"x": x0, "P": P0}, feedback={"x_next": "x", "P_next": "P"},
                              flags=("-O1",), timing=False)
    py = run_ekf(ekf_step_function(plant, sensors, Q, R, DT), d.u, y, x0, P0)
    assert _rel(res.outputs["x_post"], py.x) < 1e-9
    assert _rel(res.outputs["P_next"], py.P[1:]) < 1e-9


@pytest.mark.needs_cc
@pytest.mark.slow
def test_million_steps_covariance_stays_spd(ekf_lib, recorded):
    bundle, _ = ekf_lib
    d = recorded
    out = covariance_run(bundle, d.u, d.y, np.zeros(6), 1e-6 * np.eye(6), 1_000_000)
    assert out["steps"] == 1_000_000
    assert out["not_positive_definite"] == 0 and out["not_finite"] == 0
    assert out["max_rel_asymmetry"] == 0.0  # symmetrised every step
    assert out["min_rel_cholesky_pivot"] > 1e-12
    assert np.all(np.isfinite(out["x_final"]))


def test_cli_codegen_json(tmp_path, capsys):
    status = main(["codegen", str(ROOT / "problems/arm2link.toml"), "--sensors",
                   str(ROOT / "problems/sensors/arm2link_strain.toml"), "--out",
                   str(tmp_path), "--step", "30deg", "--no-model", "--json"])
    assert status == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"files", "functions"}
    assert out["functions"] == ["ekf_step", "plant", "measurement", "rigid_signals"]
    assert all(Path(f).exists() for f in out["files"])
    assert any(f.endswith(".h") for f in out["files"])


@pytest.mark.slow
def test_cli_codegen_jacobians(tmp_path, capsys):
    """``--jacobians``: the default is the lean benchmarked step (first-order Jacobians),
    smaller than ``exact``; ``linearized`` is leaner still."""
    sizes = {}
    for jac in ("exact", None, "linearized"):
        argv = ["codegen", str(ROOT / "problems/arm2link.toml"), "--sensors",
                str(ROOT / "problems/sensors/arm2link_accel.toml"), "--out",
                str(tmp_path / str(jac)), "--step", "30deg", "--no-model", "--json"]
        assert main(argv + (["--jacobians", jac] if jac else [])) == 0
        out = json.loads(capsys.readouterr().out)
        # the bundle's other functions are the same: its source grows with the step
        sizes[jac] = Path(next(f for f in out["files"] if f.endswith(".c"))).stat().st_size
    assert sizes["linearized"] < sizes[None] < sizes["exact"], sizes


def test_cli_codegen_bad_sensor_file(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[sensor]]\ntype = "strain"\nlink = "link1"\ns = 3.0\n')
    status = main(["codegen", str(ROOT / "problems/arm2link.toml"), "--sensors", str(bad),
                   "--out", str(tmp_path), "--json"])
    assert status == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "sensor[0].s" in captured.err
