"""EKF studies of §5.5 (fast versions) on the Table 8 arm with three modes.

Truth: the model's exact flexible rows integrated along the Table 9 moves (gravity off, as
in the dissertation), sensors sampled at 1 kHz with the noise of eq. 185–186. Errors are
RMS over time of the vector of modal amplitudes (resp. velocities), compared with the RMS
of the true vector.
"""

import dataclasses
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.estimation import (
    ekf_step_function,
    exact_plant_function,
    full_state_step_function,
    highpass,
    highpass_cutoff,
    prefilter_initial,
    run_ekf,
    simulate_data,
    tabulate_plant,
)
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import load_move
from casflex.sensors import SensorSet

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
DT = 1e-3
Q = 5e-6
R_ACC = (250e-6 * 9.8) ** 2
R_SG = 9e-14
P0 = 1e-6 * np.eye(6)


@pytest.fixture(scope="module")
def study(tmp_path_factory, accel_sensors, strain_sensors, arm_model):
    acc, sg = accel_sensors, strain_sensors
    points = acc.points + sg.points
    acc, sg = SensorSet(acc.sensors, points=points), SensorSet(sg.sensors, points=points)
    both = SensorSet(acc.sensors + sg.sensors, points=points)
    model, _ = arm_model(3, points=points, gravity=None)
    plant = tabulate_plant(model, cache_dir=tmp_path_factory.mktemp("plant"))
    data = {}
    # (not the session fixture `move`: the tests below take a parameter of that name)
    for name, t_end in (("move1", 4.0), ("move2", 3.0), ("move3", 3.0)):
        move = load_move(str(ROOT / "problems/moves.toml") + f":{name}")
        data[name] = simulate_data(model, both, move, dt=DT, t_end=t_end)
    return {"model": model, "plant": plant, "acc": acc, "sg": sg, "data": data}


def _split(d, kind):
    cols = slice(0, 6) if kind == "acc" else slice(6, 10)
    return d.u, d.y[:, cols], d.x


def _ratios(x, xhat, rows=slice(None)):
    e = xhat[rows] - x[rows]

    def rms(a):
        return float(np.sqrt(np.mean(np.sum(a**2, axis=1))))

    return rms(x[rows, :3]) / rms(e[:, :3]), rms(x[rows, 3:]) / rms(e[:, 3:])


@pytest.mark.slow
def test_plant_tabulation(study):
    plant = study["plant"]
    assert plant.shape_joints == (2,) and plant.fourier_joints == (1,)  # q1 ∥ gravity axis
    assert plant.info["check_rel_error"] < 2e-2  # 15° grid; 8e-5 on a 7.5° grid
    assert plant.order == 2 and not plant.info["from_cache"]
    # the residual of the exact plant is quadratic in Δ for the first-order part and
    # cubic for the second-order plant, and much smaller
    model = study["model"]
    fex = exact_plant_function(model)
    lin, quad = plant.rhs_function(quadratic=False), plant.rhs_function()
    u = np.r_[0.3, -0.4, 0.0, 0.5, -0.2, 0.3, 1.0, -1.0, 0.5]  # q3 on a grid node
    x = np.array([1e-3, -2e-3, 5e-4, 1e-2, 2e-2, -1e-2])

    def res(f, s):
        return np.abs(np.asarray(fex(u, s * x) - f(u, s * x))).max()

    assert 3.0 < res(lin, 2) / res(lin, 1) < 5.0
    assert 6.0 < res(quad, 2) / res(quad, 1) < 10.0
    assert res(quad, 1) < 0.02 * res(lin, 1)


@pytest.mark.slow
def test_plant_cache(study, arm, tmp_path):
    """A cached plant is read back; a changed model parameter forces a rebuild."""
    robot = arm
    model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    first = tabulate_plant(model, cache_dir=tmp_path)
    again = tabulate_plant(model, cache_dir=tmp_path)
    assert not first.info["from_cache"] and again.info["from_cache"]
    u, x = np.r_[0.1, 0.2, 0.3, 0.4, -0.5, 0.6, 0.7, 0.8, -0.9], np.array([1e-2, -3e-2])
    assert float(again.rhs_function()(u, x)) == float(first.rhs_function()(u, x))
    assert len(list(tmp_path.glob("plant-*.npz"))) == 1
    # stiffer second link (E × 1.21): ω₁ changes, the cache must not be used
    links = list(robot.links)
    mat = links[2].material
    links[2] = dataclasses.replace(links[2], material=dataclasses.replace(mat, E=1.21 * mat.E))
    stiff = dataclasses.replace(robot, links=tuple(links))
    model2 = FlexibleModel(stiff, PointwiseProvider(stiff, [0, 0, 0], 1), gravity=None)
    changed = tabulate_plant(model2, cache_dir=tmp_path)
    assert not changed.info["from_cache"]
    jd = [float(p.function()(np.zeros(9))[1]) for p in (first, changed)]
    w2 = [10.0 * highpass_cutoff(mo, [0, 0, 0]) for mo in (model, model2)]  # ω₁ [rad/s]
    assert jd == pytest.approx([-w2[0] ** 2, -w2[1] ** 2], rel=1e-6)  # J_δ = -ω₁² at rest
    assert w2[1] > 1.02 * w2[0]
    # other options are part of the key as well; a foreign file is never read
    assert not tabulate_plant(model, cache_dir=tmp_path, order=1).info["from_cache"]
    for f in tmp_path.glob("plant-*.npz"):
        f.write_bytes(b"not a cache file")
    assert not tabulate_plant(model, cache_dir=tmp_path).info["from_cache"]
    assert tabulate_plant(model, cache_dir=tmp_path).info["from_cache"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["acc", "sg"])
@pytest.mark.parametrize("move", ["move1", "move2", "move3"])
def test_nominal(study, kind, move):
    """The issue's requirement: RMS errors of δ and δ̇ at least 100x below the states
    (a first-order plant falls short for δ̇: test_first_order_plant_limits_velocities)."""
    u, y, x = _split(study["data"][move], kind)
    step = ekf_step_function(study["plant"], study[kind], Q, R_ACC if kind == "acc" else R_SG,
                             DT)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    r_delta, r_rate = _ratios(x, res.x)
    assert r_delta > 100 and r_rate > 100, (r_delta, r_rate)


@pytest.mark.slow
def test_first_order_plant_limits_velocities(study):
    """Why the plant is second order: without the second-order terms the δ̇ error on
    move 3 is several times larger."""
    u, y, x = _split(study["data"]["move3"], "acc")
    lin = dataclasses.replace(study["plant"], order=1)  # drops the products x_a x_b
    assert lin.pairs == []
    res = run_ekf(ekf_step_function(lin, study["acc"], Q, R_ACC, DT), u, y, np.zeros(6), P0)
    r_delta, r_rate = _ratios(x, res.x)
    assert r_rate < 60, (r_delta, r_rate)


@pytest.mark.slow
def test_first_order_jacobians_same_accuracy(study):
    """``jacobians="first_order"`` (the lean C step) estimates as well as the exact one."""
    u, y, x = _split(study["data"]["move3"], "acc")
    plant, acc = study["plant"], study["acc"]
    lean = run_ekf(ekf_step_function(plant, acc, Q, R_ACC, DT, jacobians="first_order"), u,
                   y, np.zeros(6), P0)
    r_delta, r_rate = _ratios(x, lean.x)
    assert r_delta > 100 and r_rate > 100, (r_delta, r_rate)
    with pytest.raises(ModelError, match="jacobians"):
        ekf_step_function(plant, acc, Q, R_ACC, DT, jacobians="none")


@pytest.mark.slow
@pytest.mark.parametrize("kind,jacobians", [("acc", "first_order"), ("acc", "linearized"),
                                            ("sg", "first_order")])
@pytest.mark.parametrize("move", ["move1", "move2", "move3"])
def test_lean_steps_same_accuracy(study, kind, jacobians, move):
    """The lean steps of the C benchmark (pruned plant, sensor-entry tables, sequential
    scalar Joseph updates; ``jacobians="first_order"``, and ``"linearized"``, whose H is
    taken at Δ = 0) meet the issue's 100x on every study."""
    u, y, x = _split(study["data"][move], kind)
    step = ekf_step_function(study["plant"], study[kind], Q, R_ACC if kind == "acc" else R_SG,
                             DT, jacobians=jacobians)
    r_delta, r_rate = _ratios(x, run_ekf(step, u, y, np.zeros(6), P0).x)
    assert r_delta > 100 and r_rate > 100, (r_delta, r_rate)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["acc", "sg"])
def test_shared_lookup_same_filter(study, kind):
    """The step with the plant's table and the sensor entries in one lookup
    (``shared=True``, default) runs the filter of the step with a lookup per table and
    the entries' rates by differentiation (``shared=False``) to rounding, and has one
    table call where the other has four for the accelerometers (the plant's, the
    entries', their two derivatives) and two for the strain gauges (no rates): a silent
    fallback to the old form fails here."""
    plant, sensors = study["plant"], study[kind]
    u, y, _ = _split(study["data"]["move1"], kind)
    R = R_ACC if kind == "acc" else R_SG
    steps = {s: ekf_step_function(plant, sensors, Q, R, DT, jacobians="first_order",
                                  shared=s) for s in (True, False)}
    calls = {s: sum(f.instruction_id(k) == ca.OP_CALL for k in range(f.n_instructions()))
             for s, f in steps.items()}
    assert calls == {True: 1, False: 4 if kind == "acc" else 2}  # strain: no rates
    new, old = (run_ekf(steps[s], u[:1500], y[:1500], np.zeros(6), P0) for s in (True, False))
    assert np.abs(new.x - old.x).max() <= 1e-12 * np.abs(old.x).max()
    assert np.abs(new.P - old.P).max() <= 1e-12 * np.abs(old.P).max()


@pytest.mark.slow
def test_pruned_plant_and_update_forms(study):
    """``tabulate_plant(prune=1e-6)`` drops only the round-off harmonics (coefficients
    equal to 1e-8 relative, 2/3 of the table values left out); the sequential update
    equals the batch one to rounding, masks included; the options are checked."""
    plant, acc = study["plant"], study["acc"]
    assert plant.keep is not None and plant.info["pruned"] > 0.6 * plant.keep.size
    full = dataclasses.replace(plant, keep=None)
    fp, ff = plant.function(), full.function()
    rng = np.random.default_rng(5)
    for _ in range(5):
        uu = np.r_[rng.uniform(-np.pi, np.pi, 3), rng.normal(size=6)]
        for a, b in zip(fp(uu), ff(uu), strict=True):
            a, b = np.asarray(a), np.asarray(b)
            assert np.abs(a - b).max() <= 1e-8 * np.abs(b).max()
    assert fp.n_instructions() < 0.5 * ff.n_instructions()
    u, y, x = _split(study["data"]["move1"], "acc")
    y = y.copy()
    y[200:300, 3:] = np.nan  # link-2 accelerometer lost for 0.1 s
    n = 800
    seq = run_ekf(ekf_step_function(plant, acc, Q, R_ACC, DT, update="sequential"), u[:n],
                  y[:n], np.zeros(6), P0)
    batch = run_ekf(ekf_step_function(plant, acc, Q, R_ACC, DT, update="batch"), u[:n],
                    y[:n], np.zeros(6), P0)
    assert np.abs(seq.x - batch.x).max() < 1e-9 * np.abs(batch.x).max()
    assert np.abs(seq.P - batch.P).max() < 1e-9 * np.abs(batch.P).max()
    assert np.all(seq.P[-1] == seq.P[-1].T)  # exactly symmetric
    with pytest.raises(ModelError, match="diagonal R"):
        ekf_step_function(plant, acc, Q, R_ACC, DT, update="sequential", sqrt=True)
    with pytest.raises(ModelError, match="update"):
        ekf_step_function(plant, acc, Q, R_ACC, DT, update="scalar")


@pytest.mark.slow
@pytest.mark.parametrize("move", ["move1", "move3"])
def test_full_state_from_encoders_and_accelerometers(study, move):
    """Full state [q, q̇, q̈, δ, δ̇] from encoder angles (noise 1e-4 rad) and the two
    accelerometers, started with q̇ = q̈ = 0 and δ = 0: converges and tracks."""
    d = study["data"][move]
    u, y, x = _split(d, "acc")
    rng = np.random.default_rng(3)
    n = 3
    enc = u[:, :n] + 1e-4 * rng.normal(size=(u.shape[0], n))
    step = full_state_step_function(study["plant"], study["acc"], Q, R_ACC, DT, Q_jerk=10.0,
                                    R_encoder=1e-8)
    z0 = np.zeros(3 * n + 6)
    Pz = np.diag([1e-6] * n + [1e-4] * n + [1e-2] * n + [1e-6] * 6)
    res = run_ekf(step, None, np.hstack([enc, y]), z0, Pz)
    assert np.all(np.isfinite(res.x))

    def rms(a):
        return np.sqrt(np.mean(a**2, axis=0))

    err = res.x[:, :3 * n] - u
    assert rms(err[:, :n]).max() < 5e-5  # below the encoder noise
    assert rms(err[:, n:2 * n]).max() < 0.02 * rms(u[:, n:2 * n]).max()  # q̇
    r_delta, r_rate = _ratios(x, res.x[:, 3 * n:])
    # δ as well as with measured q̇, q̈; δ̇ limited by the q̈ steps of the bang-bang moves,
    # which the jerk model follows only within ~0.2 rad/s² RMS (measured: 640/70, 1200/100)
    assert r_delta > 100 and r_rate > 50, (r_delta, r_rate)
    with pytest.raises(ModelError, match="R_encoder"):
        full_state_step_function(study["plant"], study["acc"], Q, R_ACC, DT, Q_jerk=10.0,
                                 R_encoder=np.ones(2))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["acc", "sg"])
def test_initial_guess_converges(study, kind):
    u, y, x = _split(study["data"]["move1"], kind)
    step = ekf_step_function(study["plant"], study[kind], Q, R_ACC if kind == "acc" else R_SG,
                             DT)
    res = run_ekf(step, u, y, np.full(6, 0.1), 1e-2 * np.eye(6))
    assert np.all(np.isfinite(res.x))
    last = slice(-1000, None)
    r_delta, r_rate = _ratios(x, res.x, last)
    assert r_delta > 100 and r_rate > 20, (r_delta, r_rate)


@pytest.mark.slow
def test_offset_with_prefilter_is_zero_mean(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    y_off = y + 0.5
    model, plant, acc = study["model"], study["plant"], study["acc"]
    raw = run_ekf(ekf_step_function(plant, acc, Q, R_ACC, DT), u, y_off, np.zeros(6), P0)
    wc = highpass_cutoff(model, u[0, :3])
    assert 0.5 < wc < 1.5  # one decade below ω1 ≈ 8.3 rad/s
    step = ekf_step_function(plant, acc, Q, R_ACC, DT, prefilter=wc)
    f0 = prefilter_initial(plant, acc, np.zeros(6), u[0], y_off[0])
    hp = run_ekf(step, u, y_off, np.zeros(6), P0, f0=f0)
    scale = np.sqrt(np.mean(x**2, axis=0))
    mean_raw = np.abs((raw.x - x).mean(axis=0)) / scale
    mean_hp = np.abs((hp.x - x).mean(axis=0)) / scale
    assert mean_raw[3:5].min() > 1.0  # without the filter: biased, as in Fig. 63
    assert mean_hp.max() < 0.05, mean_hp  # with it: zero-mean
    r_delta, r_rate = _ratios(x, hp.x)
    assert r_delta > 100 and r_rate > 30


@pytest.mark.slow
def test_stiffness_error_stays_bounded(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    step = ekf_step_function(study["plant"], study["acc"], Q, R_ACC, DT, stiffness_scale=1.4)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P))
    assert np.abs(res.x).max() < 3 * np.abs(x).max()
    r_delta, _ = _ratios(x, res.x)
    assert r_delta > 2  # the dissertation reports ~4x for δ (Fig. 65)
    assert np.all(np.linalg.eigvalsh(res.P[-1]) > 0)


@pytest.mark.slow
def test_without_coriolis_converges_after_motion(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    step = ekf_step_function(study["plant"], study["acc"], Q, R_ACC, DT, coriolis=False)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    during = _ratios(x, res.x, slice(0, 2000))
    after = _ratios(x, res.x, slice(3000, None))
    assert during[1] < 30  # errors while the joints move
    assert after[0] > 100 and after[1] > 50, (during, after)


@pytest.mark.slow
def test_dropouts_are_skipped(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    y = y.copy()
    y[500:900, :3] = np.nan  # link-1 accelerometer lost for 0.4 s
    step = ekf_step_function(study["plant"], study["acc"], Q, R_ACC, DT)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    assert np.all(np.isfinite(res.x))
    assert _ratios(x, res.x)[0] > 50


@pytest.mark.slow
def test_square_root_form_agrees(study):
    u, y, x = _split(study["data"]["move1"], "sg")
    plant, sg = study["plant"], study["sg"]
    n = 1500
    plain = run_ekf(ekf_step_function(plant, sg, Q, R_SG, DT), u[:n], y[:n], np.zeros(6), P0)
    sq = run_ekf(ekf_step_function(plant, sg, Q, R_SG, DT, sqrt=True), u[:n], y[:n],
                 np.zeros(6), np.sqrt(P0))
    assert np.abs(sq.x - plain.x).max() < 1e-6 * np.abs(x[:n]).max()
    np.testing.assert_allclose(sq.P[-1], plain.P[-1], rtol=1e-5, atol=1e-14)


def test_highpass_and_errors():
    y = highpass(np.sin(np.linspace(0, 50, 5000)) + 3.0, 0.01, 0.1, start="first")
    assert abs(y[-2000:].mean()) < 0.05
    with pytest.raises(ModelError):
        highpass(np.zeros(3), 0.01, 1.0, start="never")


@pytest.mark.slow
def test_bad_noise_matrices(study):
    with pytest.raises(ModelError, match=r"^R = .*: must be"):
        ekf_step_function(study["plant"], study["acc"], Q, np.ones(5), DT)
    with pytest.raises(ModelError, match="dt"):
        ekf_step_function(study["plant"], study["acc"], Q, R_ACC, 0.0)
