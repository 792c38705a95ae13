"""Sensor models: independent numeric checks (finite differences, TMM curvature), files."""

from pathlib import Path

import numpy as np
import pytest

from casflex.errors import ModelError, ProblemFileError
from casflex.estimation import exact_plant_function
from casflex.modal.normalize import local_state
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.robot import Section
from casflex.sensors import (
    Accelerometer,
    SensorSet,
    StrainPair,
    default_strain_distance,
    kinematic_measurement,
    load_sensors,
    measurement_function,
    point_position_function,
    sensors_from_tables,
)
from casflex.simulate.measurements import simulate_data

ROOT = Path(__file__).resolve().parents[2]
ROBOT = ROOT / "problems" / "arm2link.toml"
# coarse test grids: the tracking warning of the modal tables is expected
pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")


@pytest.fixture(scope="module")
def robot(arm):
    """The Table 8 arm of problems/arm2link.toml (ROBOT)."""
    return arm


@pytest.fixture(scope="module")
def inertial_setup(arm_model):
    """Table model (15° grid) with accelerometers in the base frame, no gravity."""
    sensors = SensorSet([
        Accelerometer(2, 0.6, name="a1", frame="inertial", gravity=False),
        Accelerometer(3, 1.0, name="a2", frame="inertial", gravity=False,
                      offset=(0.01, -0.02, 0.0)),
    ])
    model, _ = arm_model(3, points=sensors.points, gravity=None)
    return model, sensors


def test_accelerometer_equals_second_difference_of_position(inertial_setup):
    model, sensors = inertial_setup
    move = Move([0.0, 0.0, 0.3], [-1.0, -0.8, -0.6], 0.6)
    dt = 1e-3
    data = simulate_data(model, sensors, move, dt=dt, t_end=0.9, noise=0.0)
    n = model.n
    pos = point_position_function(model, sensors)
    P = np.stack([np.hstack([np.asarray(v).ravel() for v in pos(q, d)])
                  for q, d in zip(data.u[:, :n], data.x[:, :3], strict=True)])
    fd = (P[2:] - 2 * P[1:-1] + P[:-2]) / dt**2
    model_acc = data.y_clean[1:-1]
    # skip the samples next to the jumps of the bang-bang acceleration (t = 0, 0.3, 0.6 s)
    t = data.t[1:-1]
    keep = np.min(np.abs(t[:, None] - np.array([0.0, 0.3, 0.6])[None]), axis=1) > 2.5 * dt
    err = np.abs(fd[keep] - model_acc[keep])
    scale = np.abs(model_acc[keep]).max()
    assert scale > 0.1
    assert err.max() < 2e-4 * scale, (err.max(), scale)


def test_lean_measurement_equals_full(inertial_setup):
    """``kinematic_measurement(lean=True)``: the same signals to rounding from one spline
    of the table entries used (and its derivatives) instead of the model's spline of every
    quantity; inertial and sensor-frame accelerometers, gravity, an offset, the rigid
    part removed, and strain pairs. The same with that spline evaluated locally
    (``lookup="local"``, the estimator's default): fitted by a direct solve instead of
    CasADi's iterative one (values ≤ 3e-14 apart, test_plant_lookup.py), within the same
    1e-12 of the signals."""
    model, inertial = inertial_setup
    mixed = SensorSet([Accelerometer(3, 1.0, name="tip", rigid=False),
                       Accelerometer(2, 0.6, name="mid", offset=(0.0, 0.01, 0.02)),
                       StrainPair(2, 0.6, (3.5e-3, 2.5e-3), name="sg")],
                      points=inertial.points)
    rng = np.random.default_rng(2)
    for ss in (inertial, mixed):
        full = kinematic_measurement(model, ss)
        lean = kinematic_measurement(model, ss, lean=True)
        local = kinematic_measurement(model, ss, lean=True, lookup="local")
        for _ in range(10):
            args = [1e-2 * rng.normal(size=6),
                    np.r_[rng.uniform(-4, 4, 3), rng.normal(size=6)], rng.normal(size=3)]
            a = np.asarray(full(*args))
            for other in (lean, local):
                b = np.asarray(other(*args))
                assert np.abs(a - b).max() < 1e-12 * np.abs(a).max()


def test_sensor_frame_and_gravity(robot):
    # at q = 0 link 2 hangs down (tip at z = -1 m): its local z axis is vertical
    ss = SensorSet([Accelerometer(3, 1.0, name="tip"),
                    Accelerometer(3, 1.0, name="tip0", frame="inertial"),
                    Accelerometer(3, 0.5, name="mid", rigid=False)])
    model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2, ss.points))
    hk = kinematic_measurement(model, ss)
    y = np.asarray(hk(np.zeros(4), np.zeros(9), np.zeros(2))).ravel()
    np.testing.assert_allclose(y[3:6], [0, 0, 9.81], atol=1e-12)  # specific force -g
    np.testing.assert_allclose(np.abs(y[:3]), [0, 0, 9.81], atol=1e-12)
    # the rigid part removed (eq. 163): zero without deflection, whatever q, q̇, q̈
    u = np.r_[0.3, -0.2, 0.4, 0.5, 0.1, -0.3, 1.0, -2.0, 0.5]
    np.testing.assert_allclose(np.asarray(hk(np.zeros(4), u, np.zeros(2))).ravel()[6:], 0,
                               atol=1e-12)
    # ... and the full signal minus the rigid one otherwise
    x = np.array([1e-3, -2e-3, 0.01, 0.02])
    full = SensorSet([Accelerometer(3, 0.5, name="m")])
    hf = kinematic_measurement(FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 2,
                                                                      full.points)), full)
    rig = np.asarray(hf(np.zeros(4), u, np.zeros(2))).ravel()
    got = np.asarray(hk(x, u, [0.3, -0.1])).ravel()[6:]
    np.testing.assert_allclose(got, np.asarray(hf(x, u, [0.3, -0.1])).ravel() - rig,
                               atol=1e-12)
    # the exact model: δ̈ from the flexible rows (at rest under gravity δ̈ = -g_δ ≠ 0)
    h = measurement_function(model, ss)
    acc = np.asarray(exact_plant_function(model)(np.zeros(9), np.zeros(4))).ravel()
    np.testing.assert_allclose(np.asarray(h(np.zeros(4), np.zeros(9))[3]).ravel(),
                               np.asarray(hk(np.zeros(4), np.zeros(9), acc)).ravel(),
                               atol=1e-12)


def test_sensor_frame_is_rotated_inertial(robot):
    ss = SensorSet([Accelerometer(3, 0.7, name="s"),
                    Accelerometer(3, 0.7, name="i", frame="inertial")])
    provider = PointwiseProvider(robot, [0, 0, 0.4], 2, ss.points)
    model = FlexibleModel(robot, provider)
    h = measurement_function(model, ss)
    rng = np.random.default_rng(3)
    x = 1e-3 * rng.normal(size=4)
    u = np.r_[0.2, -0.3, 0.4, rng.normal(size=6)]
    ys, yi = (np.asarray(v).ravel() for v in h(x, u)[:2])
    # independent rotation: differentiate the sensor position along the link (local z) and
    # across it via the offset (local x) with the model's kinematics
    ex = SensorSet([Accelerometer(3, 0.7, name="o", offset=(1e-6, 0, 0)),
                    Accelerometer(3, 0.7 + 1e-6, name="z")])
    pm = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.4], 2,
                                                ss.points + ex.points[1:]))
    pos = point_position_function(pm, SensorSet(list(ss.sensors[:1]) + list(ex.sensors),
                                                points=ss.points + ex.points[1:]))
    p0, px, pz = (np.asarray(v).ravel() for v in pos(u[:3], x[:2]))
    ex_, ez_ = (px - p0) / 1e-6, (pz - p0) / 1e-6
    assert abs(np.linalg.norm(ex_) - 1) < 1e-3 and abs(np.linalg.norm(ez_) - 1) < 1e-2
    assert abs(ys[0] - ex_ @ yi) < 1e-3 * np.abs(yi).max()
    assert abs(ys[2] - ez_ @ yi) < 2e-2 * np.abs(yi).max()


def test_strain_equals_distance_times_tmm_curvature(robot):
    q = [0.0, 0.0, 0.5]
    pairs = [StrainPair(2, 0.05, (3.5e-3, 2.5e-3), name="s1"),
             StrainPair(3, 0.37, (3.5e-3, 2.5e-3), name="s2")]
    ss = SensorSet(pairs)
    provider = PointwiseProvider(robot, q, 3, ss.points)
    model = FlexibleModel(robot, provider)
    h = measurement_function(model, ss)
    u = np.r_[q, np.zeros(6)]
    hs = 1e-3
    for j in range(3):
        x = np.zeros(6)
        x[j] = 1.0
        got = np.asarray(h(x, u)[2]).ravel()
        want = []
        for beam, sp in enumerate(pairs):
            z = local_state(robot, provider.shapes, beam, [sp.s - hs, sp.s, sp.s + hs])
            w2 = (z[j, 2, :2] - 2 * z[j, 1, :2] + z[j, 0, :2]) / hs**2  # w'' from u(s)
            want += [-sp.distance[0] * w2[0], -sp.distance[1] * w2[1]]
        want = np.array(want)
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6 * np.abs(want).max())


def test_shipped_sensor_files(robot):
    acc = load_sensors(ROOT / "problems/sensors/arm2link_accel.toml", robot)
    sg = load_sensors(ROOT / "problems/sensors/arm2link_strain.toml", robot)
    assert acc.points == [(2, 1.0), (3, 1.0)] and acc.n_outputs == 6
    assert sg.points == [(2, 0.05), (3, 0.05)] and sg.n_outputs == 4
    np.testing.assert_allclose(acc.noise_std, 250e-6 * 9.8, rtol=1e-12)
    np.testing.assert_allclose(sg.noise_std**2, 9e-14, rtol=1e-12)


def test_default_strain_distance_is_the_half_depth(robot):
    # the gauges sit on the faces: c_x = b/2 (side b along local x), c_y = a/2 (side a
    # along local y), from problems/arm2link.toml's section a = 5 mm, b = 7 mm; a tube's
    # faces are at the outer radius
    sg = sensors_from_tables([{"type": "strain", "link": "link1", "s": 0.1}], robot)
    assert sg.sensors[0].distance == pytest.approx((0.007 / 2, 0.005 / 2), rel=1e-12)
    tube = Section.tube(0.0127, 0.00041)
    assert default_strain_distance(tube) == pytest.approx((0.0127 / 2, 0.0127 / 2),
                                                          rel=1e-12)


def test_sensor_tables_in_robot_file(robot, tmp_path):
    text = ROBOT.read_text() + '\n[[sensor]]\ntype = "accelerometer"\nlink = 3\ns = 0.5\n'
    path = tmp_path / "robot_with_sensors.toml"
    path.write_text(text)
    ss = load_sensors(path, robot)
    assert ss.sensors[0].row == 3 and ss.sensors[0].name == "acc3_0p5"


@pytest.mark.parametrize("table, field, rule", [
    ({"type": "accelerometer", "link": "link9", "s": 0.5}, "sensor[0].link", "unknown link"),
    ({"type": "accelerometer", "link": "shoulder", "s": 0.5}, "sensor[0].link", "rigid"),
    ({"type": "accelerometer", "link": 7, "s": 0.5}, "sensor[0].link", "out of range"),
    ({"type": "strain", "link": "link1", "s": 1.2}, "sensor[0].s", "must lie on the link"),
    ({"type": "strain", "link": "link1", "s": -0.1}, "sensor[0].s", "must lie on the link"),
    ({"type": "gyro", "link": "link1", "s": 0.1}, "sensor[0].type", "accelerometer"),
    ({"type": "strain", "link": "link1", "s": 0.1, "offset": [0, 0, 0]}, "sensor[0].offset",
     "unknown key"),
    ({"type": "accelerometer", "link": "link1", "s": 0.1, "axes": "zx"}, "sensor[0].axes",
     "ordered"),
    ({"type": "accelerometer", "link": "link1", "s": 0.1, "frame": "world"},
     "sensor[0].frame", "sensor"),
    ({"type": "strain", "link": "link1", "s": 0.1, "distance": -1.0}, "sensor[0].distance",
     "positive"),
])
def test_sensor_file_errors(robot, table, field, rule):
    with pytest.raises(ProblemFileError) as info:
        sensors_from_tables([table], robot, path="s.toml")
    assert info.value.field == field and rule in info.value.rule and info.value.path == "s.toml"


def test_model_without_sensor_points(robot):
    ss = SensorSet([Accelerometer(3, 1.0)])
    model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1))
    with pytest.raises(ModelError, match="points"):
        measurement_function(model, ss)
