"""EKF studies of §5.5 (fast versions) on the Table 8 arm with three modes.

Truth: the model's exact flexible rows integrated along the Table 9 moves (gravity off, as
in the dissertation), sensors sampled at 1 kHz with the noise of eq. 185–186. Errors are
RMS over time of the vector of modal amplitudes (resp. velocities), compared with the RMS
of the true vector.
"""

from pathlib import Path

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.estimation import (
    ekf_step_function,
    exact_plant_function,
    highpass,
    highpass_cutoff,
    prefilter_initial,
    run_ekf,
    simulate_data,
    tabulate_plant,
)
from casflex.model import build_model
from casflex.moves import load_move
from casflex.robot import load
from casflex.sensors import SensorSet, load_sensors

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
DT = 1e-3
Q = 5e-6
R_ACC = (250e-6 * 9.8) ** 2
R_SG = 9e-14
P0 = 1e-6 * np.eye(6)


@pytest.fixture(scope="module")
def study():
    robot = load(ROOT / "problems/arm2link.toml")
    acc = load_sensors(ROOT / "problems/sensors/arm2link_accel.toml", robot)
    sg = load_sensors(ROOT / "problems/sensors/arm2link_strain.toml", robot)
    points = acc.points + sg.points
    acc, sg = SensorSet(acc.sensors, points=points), SensorSet(sg.sensors, points=points)
    both = SensorSet(acc.sensors + sg.sensors, points=points)
    model, _ = build_model(robot, n_modes=3, step=np.radians(15), cache_dir=False,
                           processes=1, points=points, gravity=None)
    plant = tabulate_plant(model)
    data = {}
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


def test_plant_tabulation(study):
    plant = study["plant"]
    assert plant.shape_joints == (2,) and plant.fourier_joints == (1,)  # q1 ∥ gravity axis
    assert plant.info["check_rel_error"] < 2e-2  # 15° grid; 8e-5 on a 7.5° grid
    # first order in Δ: the residual of the exact plant is quadratic in Δ
    model = study["model"]
    fex, lean = exact_plant_function(model), plant.rhs_function()
    u = np.r_[0.3, -0.4, 0.0, 0.5, -0.2, 0.3, 1.0, -1.0, 0.5]  # q3 on a grid node
    x = np.array([1e-3, -2e-3, 5e-4, 1e-2, 2e-2, -1e-2])
    e1 = np.abs(np.asarray(fex(u, x) - lean(u, x))).max()
    e2 = np.abs(np.asarray(fex(u, 2 * x) - lean(u, 2 * x))).max()
    assert 3.0 < e2 / e1 < 5.0


@pytest.mark.parametrize("kind", ["acc", "sg"])
@pytest.mark.parametrize("move", ["move1", "move2", "move3"])
def test_nominal(study, kind, move):
    if kind == "sg" and move != "move1":
        pytest.skip("strain feedback on moves 2 and 3: notebooks/03_estimation")
    u, y, x = _split(study["data"][move], kind)
    step = ekf_step_function(study["plant"], study[kind], Q, R_ACC if kind == "acc" else R_SG,
                             DT)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    r_delta, r_rate = _ratios(x, res.x)
    assert r_delta > 100, (r_delta, r_rate)
    # modal velocities: ~100x with accelerometers on moves 1 and 2; strain gauges measure
    # δ only, and move 3 (q1 through π, up to 3.1 rad/s) has large gyroscopic
    # terms: there the first-order plant limits the velocity error to ~25-50x
    floor = {"acc": {"move1": 80, "move2": 80, "move3": 20}, "sg": {"move1": 30}}
    assert r_rate > floor[kind][move], (r_delta, r_rate)


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


def test_stiffness_error_stays_bounded(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    step = ekf_step_function(study["plant"], study["acc"], Q, R_ACC, DT, stiffness_scale=1.4)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P))
    assert np.abs(res.x).max() < 3 * np.abs(x).max()
    r_delta, _ = _ratios(x, res.x)
    assert r_delta > 2  # the dissertation reports ~4x for δ (Fig. 65)
    assert np.all(np.linalg.eigvalsh(res.P[-1]) > 0)


def test_without_coriolis_converges_after_motion(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    step = ekf_step_function(study["plant"], study["acc"], Q, R_ACC, DT, coriolis=False)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    during = _ratios(x, res.x, slice(0, 2000))
    after = _ratios(x, res.x, slice(3000, None))
    assert during[1] < 30  # errors while the joints move
    assert after[0] > 100 and after[1] > 50, (during, after)


def test_dropouts_are_skipped(study):
    u, y, x = _split(study["data"]["move1"], "acc")
    y = y.copy()
    y[500:900, :3] = np.nan  # link-1 accelerometer lost for 0.4 s
    step = ekf_step_function(study["plant"], study["acc"], Q, R_ACC, DT)
    res = run_ekf(step, u, y, np.zeros(6), P0)
    assert np.all(np.isfinite(res.x))
    assert _ratios(x, res.x)[0] > 50


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


def test_bad_noise_matrices(study):
    with pytest.raises(ModelError, match="R must"):
        ekf_step_function(study["plant"], study["acc"], Q, np.ones(5), DT)
    with pytest.raises(ModelError, match="dt"):
        ekf_step_function(study["plant"], study["acc"], Q, R_ACC, 0.0)
