"""The guarded rt_step and ekf_step in generated C under injected faults (issue 13, part 1).

Reference: the CasADi evaluation of the same functions in Python, step by step over a
simulated move with the faults injected (same statuses, same numbers to round-off); numpy
for finiteness, the torque limits and positive definiteness of P.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from casflex import codegen
from casflex.cli import main
from casflex.codegen import rtloop
from casflex.errors import ModelError
from casflex.estimation import (
    STATUS_BITS,
    STATUS_INPUT_HELD,
    STATUS_SAMPLE_NONFINITE,
    STATUS_SAMPLE_REJECTED,
    STATUS_TORQUE_CLIPPED,
    STATUS_TORQUE_HELD,
    Guard,
    ekf_step_function,
    simulate_data,
    tabulate_plant,
)

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
DT = 1e-3
Q_EKF = 5e-6
R_EKF = (250e-6 * 9.8) ** 2
P0 = 1e-4 * np.eye(6)
G = 9.81
K = 600  # first faulty sample
N = 900
LIMITS = np.array([40.0, 20.0, 5.0])  # N m; above the torques of move 1


@pytest.fixture(scope="module")
def rt(arm_model, accel_sensors, move, tmp_path_factory, model_cache):
    model, _ = arm_model(3, points=accel_sensors.points, gravity=None, delta_order=0)
    plant = tabulate_plant(model, check=False, cache_dir=model_cache)  # shared: test_rt
    ekf = ekf_step_function(plant, accel_sensors, Q_EKF, R_EKF, DT, guard=Guard(P0))
    ctrl = rtloop.make_controller(model, "inversion")
    py = rtloop.rt_step_function(ekf, ctrl, DT, torque_limits=LIMITS)
    bundle = rtloop.rt_bundle(ekf, ctrl, accel_sensors, DT, tmp_path_factory.mktemp("rtf"),
                              extra=[ekf], torque_limits=LIMITS)
    lib = codegen.build(bundle, flags=("-O1",))
    mv = move("move1")
    data = simulate_data(model, accel_sensors, mv, dt=DT, t_end=(N - 1) * DT)
    ref = mv.sample(data.t)
    plain = rtloop.rt_step_function(ekf_step_function(plant, accel_sensors, Q_EKF, R_EKF, DT),
                                    ctrl, DT)
    return {"py": py, "c": codegen.load(lib, "rt_step"), "plain": plain, "ekf_py": ekf,
            "ekf_c": codegen.load(lib, "ekf_step"), "data": data, "ref": ref,
            "bundle": bundle}


def _run(f, data, ref, faults):
    """Run an rt_step over the data with faults ``{k: {input: value}}``; state fed back."""
    n = 3
    u, y = data.u, data.y
    x, P, dq_prev, q_prev, tau_prev = np.zeros(6), P0, u[0, n:2 * n], u[0, :n], np.zeros(n)
    out = {"tau": [], "x": [], "P": [], "status": []}
    for k in range(N):
        args = {"x": x, "P": P, "dq_prev": dq_prev, "q": u[k, :n], "dq": u[k, n:2 * n],
                "qd": ref[0][k], "dqd": ref[1][k], "ddqd": ref[2][k], "y": y[k],
                "mask": np.ones(6), "q_prev": q_prev, "tau_prev": tau_prev}
        for key, value in faults.get(k, {}).items():
            args[key] = np.array(args[key], dtype=float)
            args[key][value[0]] = value[1]
        res = f(**args)
        tau = np.asarray(res["tau"]).ravel()
        x, P = np.asarray(res["x_next"]).ravel(), np.asarray(res["P_next"])
        dq_prev, q_prev, tau_prev = (np.asarray(res[k]).ravel() for k in
                                     ("dq_next", "q_next", "tau"))
        out["tau"].append(tau)
        out["x"].append(np.asarray(res["x_post"]).ravel())
        out["P"].append(P)
        out["status"].append(int(np.asarray(res["status"]).item()))
    return {k: np.array(v) for k, v in out.items()}


def _burst(key, index, value):
    return {k: {key: (index, value)} for k in range(K, K + 100)}


FAULTS = {
    "1e4g_one": ({K: {"y": (0, 1e4 * G)}}, STATUS_SAMPLE_REJECTED),
    "1e6g_all": ({K: {"y": (slice(None), 1e6 * G)}}, STATUS_SAMPLE_REJECTED),
    "nan_y": ({K: {"y": (1, np.nan)}}, STATUS_SAMPLE_NONFINITE),
    "inf_y_all": ({K: {"y": (slice(None), -np.inf)}}, STATUS_SAMPLE_NONFINITE),
    "nan_q": ({K: {"q": (0, np.nan)}}, STATUS_INPUT_HELD),
    "nan_dq": ({K: {"dq": (2, np.nan)}}, STATUS_INPUT_HELD),
    "nan_reference": ({K: {"ddqd": (1, np.nan)}}, STATUS_TORQUE_HELD),
    "huge_reference": ({K: {"qd": (2, 1e3)}}, STATUS_TORQUE_CLIPPED),
    "burst_1e6g": (_burst("y", slice(None), 1e6 * G), STATUS_SAMPLE_REJECTED),
    "burst_nan_y": (_burst("y", slice(None), np.nan), STATUS_SAMPLE_NONFINITE),
    "burst_nan_q": (_burst("q", slice(None), np.nan), STATUS_INPUT_HELD),
}


@pytest.mark.needs_cc
@pytest.mark.slow
@pytest.mark.parametrize("kind", list(FAULTS))
def test_rt_step_faults_c_equals_python(rt, kind):
    faults, bits = FAULTS[kind]
    c = _run(rt["c"], rt["data"], rt["ref"], faults)
    py = _run(rt["py"], rt["data"], rt["ref"], faults)
    # the same decisions, the same numbers (round-off of two evaluations of one graph)
    np.testing.assert_array_equal(c["status"], py["status"])
    for key in ("tau", "x", "P"):
        scale = np.abs(py[key]).max()
        assert np.abs(c[key] - py[key]).max() <= 1e-10 * scale, key
    # torques always finite and within the limits; P symmetric positive definite
    assert np.all(np.isfinite(c["tau"])) and np.all(np.abs(c["tau"]) <= LIMITS)
    assert np.all(np.isfinite(c["x"]))
    for P in c["P"]:
        assert np.array_equal(P, P.T) and np.linalg.eigvalsh(P).min() > 0
    for k in faults:
        assert c["status"][k] & bits == bits, (k, c["status"][k])


@pytest.mark.needs_cc
@pytest.mark.slow
def test_unfaulted_run_is_the_unguarded_loop(rt):
    """Without faults nothing triggers (status 0; the limits are above the torques of
    move 1) and the guarded C loop gives the unguarded Python loop's numbers."""
    out = _run(rt["c"], rt["data"], rt["ref"], {})
    assert np.all(out["status"] == 0)
    plain, d, (qd, dqd, ddqd) = rt["plain"], rt["data"], rt["ref"]
    x, P, dq_prev = np.zeros(6), P0, d.u[0, 3:6]
    for k in range(N):
        tau, x, P, dq_prev, xp = (np.asarray(v) for v in plain(
            x, P, dq_prev, d.u[k, :3], d.u[k, 3:6], qd[k], dqd[k], ddqd[k], d.y[k],
            np.ones(6)))
        assert np.abs(tau.ravel() - out["tau"][k]).max() <= 1e-10 * np.abs(tau).max()
        assert np.abs(xp.ravel() - out["x"][k]).max() <= 1e-10 * np.abs(xp).max()


@pytest.mark.needs_cc
@pytest.mark.slow
def test_ekf_step_c_equals_python_on_faults(rt):
    d = rt["data"]
    ekf_c, ekf_py = rt["ekf_c"], rt["ekf_py"]
    x, P, u_last = np.zeros(6), P0, d.u[0]
    for k in range(N):
        u, y = d.u[k].copy(), d.y[k].copy()
        if k % 50 == 7:
            y[k % 6] = (np.nan, np.inf, 1e6 * G)[k % 3]
        if k % 70 == 3:
            u[k % 9] = np.nan
        out_c = [np.asarray(v) for v in ekf_c(x, P, u, y, np.ones(6), u_last)]
        out_p = [np.asarray(v) for v in ekf_py(x, P, u, y, np.ones(6), u_last)]
        assert out_c[4].item() == out_p[4].item()
        for a, b in zip(out_c, out_p, strict=True):
            assert np.abs(a - b).max() <= 1e-10 * max(np.abs(b).max(), 1e-300)
        x, P, u_last = out_c[0].ravel(), out_c[1], out_c[3].ravel()
        assert np.linalg.eigvalsh(P).min() > 0


@pytest.mark.needs_cc
@pytest.mark.slow
def test_header_defines_status_bits_and_limits(rt):
    text = rt["bundle"].header.read_text()
    for name, bit in STATUS_BITS.items():
        assert f"#define CASFLEX_STATUS_{name.upper()} {bit}\n" in text
    assert "#define CASFLEX_TORQUE_LIMIT_3 5.0" in text


def test_torque_limits_go_with_a_guarded_step():
    import casadi as ca

    x, P, u = ca.SX.sym("x", 2), ca.SX.sym("P", 2, 2), ca.SX.sym("u", 3)
    y, k = ca.SX.sym("y"), ca.SX.sym("k")
    ekf = ca.Function("e", [x, P, u, y, k], [x, P, x], ["x", "P", "u", "y", "mask"],
                      ["x_next", "P_next", "x_post"])
    xc = ca.SX.sym("xc", 4)
    ctrl = ca.Function("c", [ca.SX.sym("a"), ca.SX.sym("b"), ca.SX.sym("d"), xc], [xc[0]])
    with pytest.raises(ModelError, match="torque_limits"):
        rtloop.rt_step_function(ekf, ctrl, 1e-3, torque_limits=[1.0])


@pytest.mark.slow
def test_cli_codegen_guarded(tmp_path, capsys, monkeypatch, model_cache):
    # the run's shared cache: test_cli_codegen_controller builds the same 30° table and plant
    monkeypatch.setenv("CASFLEX_CACHE", str(model_cache))
    argv = ["codegen", str(ROOT / "problems/arm2link.toml"), "--sensors",
            str(ROOT / "problems/sensors/arm2link_accel.toml"), "--out", str(tmp_path / "c"),
            "--step", "30deg", "--no-model", "--controller", "inversion", "--guard",
            "--torque-limit", "30", "20", "10", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    manifest = json.loads(Path(next(f for f in out["files"] if f.endswith(".json")))
                          .read_text())
    rt = next(f for f in manifest["functions"] if f["name"] == "rt_step")
    assert [p["name"] for p in rt["inputs"]][-2:] == ["q_prev", "tau_prev"]
    assert [p["name"] for p in rt["outputs"]][-2:] == ["q_next", "status"]
    ekf = next(f for f in manifest["functions"] if f["name"] == "ekf_step")
    assert [p["name"] for p in ekf["outputs"]][-1] == "status"
    header = Path(next(f for f in out["files"] if f.endswith(".h"))).read_text()
    assert "#define CASFLEX_STATUS_SAMPLE_REJECTED 1\n" in header
    assert "#define CASFLEX_TORQUE_LIMIT_3 10.0" in header


@pytest.mark.parametrize("extra, message", [
    (["--torque-limit", "5"], "--torque-limit and --gate need --guard"),
    (["--guard", "--controller", "inversion"], "--torque-limit must be given"),
    (["--guard", "--sqrt"], "not with --sqrt"),
    (["--guard", "--gate", "-1"], "--gate: must be > 0"),
])
def test_cli_codegen_guard_errors(tmp_path, capsys, extra, message):
    argv = ["codegen", str(ROOT / "problems/arm2link.toml"), "--sensors",
            str(ROOT / "problems/sensors/arm2link_accel.toml"), "--out", str(tmp_path / "c"),
            *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
