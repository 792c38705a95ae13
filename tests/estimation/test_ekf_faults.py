"""The guarded EKF step (casflex.estimation.guard) under injected faults (issue 13, part 1).

Truth: the model's exact flexible rows integrated along move 1 (Table 8 arm, three modes,
gravity off) with the two tip accelerometers at 1 kHz and the noise of eq. 185, as in
test_estimation.py. References: the unguarded step on clean data (the guard must change
nothing there), numpy's eigvalsh for positive definiteness, and the fault-free guarded
run for the nominal error.
"""

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.estimation import (
    STATUS_COVARIANCE_RESET,
    STATUS_INPUT_HELD,
    STATUS_SAMPLE_NONFINITE,
    STATUS_SAMPLE_REJECTED,
    STATUS_STATE_RESET,
    Guard,
    ekf_step_function,
    run_ekf,
    simulate_data,
    status_names,
    tabulate_plant,
)
from casflex.moves import load_move

pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")
DT = 1e-3
Q = 5e-6
R_ACC = (250e-6 * 9.8) ** 2
P0 = 1e-6 * np.eye(6)
G = 9.81
K = 1000  # first faulty sample (1 s into move 1, the arm moving)
# Recovery bound after the end of a fault: 0.1 s. Reason: a skipped or rejected sample
# leaves the filter predicting open loop from an accurate state (error grows with the
# model error only, then the next valid samples pull it back within a few filter time
# constants, ~10 ms measured); a held input restarts P from P_reset, i.e. a cold start
# whose transient is the one of test_initial_guess_converges (~35 ms measured here).
RECOVERY = 0.1


@pytest.fixture(scope="module")
def setup(arm_model, accel_sensors, model_cache):
    model, _ = arm_model(3, points=accel_sensors.points, gravity=None)
    # shared with test_numpy_ekf_baseline; the plant's accuracy check (check=True: ~2 s CPU,
    # an info entry only, the same coefficients) is test_estimation's test_plant_tabulation
    plant = tabulate_plant(model, check=False, cache_dir=model_cache)
    move = load_move("problems/moves.toml:move1")
    data = simulate_data(model, accel_sensors, move, dt=DT, t_end=2.5)
    plain = ekf_step_function(plant, accel_sensors, Q, R_ACC, DT)
    guarded = ekf_step_function(plant, accel_sensors, Q, R_ACC, DT, guard=Guard(P0))
    nominal = run_ekf(guarded, data.u, data.y, np.zeros(6), P0)
    return {"plant": plant, "sensors": accel_sensors, "data": data, "plain": plain,
            "guarded": guarded, "nominal": nominal}


def _error(d, xhat):
    return np.sqrt(np.sum((xhat - d.x) ** 2, axis=1))


@pytest.mark.slow
def test_clean_data_unchanged(setup):
    """Where nothing triggers, the guarded step is the unguarded one to the last bit, and
    nominal data are never rejected (gate: χ²(1) quantile of 1 − 1e-9)."""
    d = setup["data"]
    ref = run_ekf(setup["plain"], d.u, d.y, np.zeros(6), P0)
    res = setup["nominal"]
    assert np.count_nonzero(res.status) == 0  # 0 of 2501 x 6 samples rejected
    np.testing.assert_array_equal(res.x, ref.x)
    np.testing.assert_array_equal(res.P, ref.P)


def _fault(kind, d):
    u, y = d.u.copy(), d.y.copy()
    burst = slice(K, K + 100)
    one = slice(K, K + 1)
    {
        "1e4g_one": lambda: y.__setitem__((one, 0), 1e4 * G),
        "1e6g_one": lambda: y.__setitem__((one, 0), 1e6 * G),
        "1e4g_all": lambda: y.__setitem__(one, 1e4 * G),
        "1e6g_all": lambda: y.__setitem__(one, -1e6 * G),
        "nan_y": lambda: y.__setitem__((one, 2), np.nan),
        "inf_y_all": lambda: y.__setitem__(one, np.inf),
        "nan_q": lambda: u.__setitem__((one, 0), np.nan),
        "nan_u_all": lambda: u.__setitem__(one, np.nan),
        "burst_1e6g": lambda: y.__setitem__(burst, 1e6 * G),
        "burst_nan_y": lambda: y.__setitem__(burst, np.nan),
        "burst_nan_u": lambda: u.__setitem__(burst, np.nan),
        "burst_mixed": lambda: y.__setitem__(burst, np.where(
            np.arange(600).reshape(100, 6) % 3 == 0, np.nan, 1e5)),
    }[kind]()
    end = K + (100 if kind.startswith("burst") else 1)
    return u, y, end


EXPECTED = {"1e4g_one": STATUS_SAMPLE_REJECTED, "1e6g_one": STATUS_SAMPLE_REJECTED,
            "1e4g_all": STATUS_SAMPLE_REJECTED, "1e6g_all": STATUS_SAMPLE_REJECTED,
            "nan_y": STATUS_SAMPLE_NONFINITE, "inf_y_all": STATUS_SAMPLE_NONFINITE,
            "nan_q": STATUS_INPUT_HELD | STATUS_COVARIANCE_RESET,
            "nan_u_all": STATUS_INPUT_HELD | STATUS_COVARIANCE_RESET,
            "burst_1e6g": STATUS_SAMPLE_REJECTED, "burst_nan_y": STATUS_SAMPLE_NONFINITE,
            "burst_nan_u": STATUS_INPUT_HELD | STATUS_COVARIANCE_RESET,
            "burst_mixed": STATUS_SAMPLE_REJECTED | STATUS_SAMPLE_NONFINITE}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(EXPECTED))
def test_fault_is_survived_and_recovered(setup, kind):
    d = setup["data"]
    u, y, end = _fault(kind, d)
    res = run_ekf(setup["guarded"], u, y, np.zeros(6), P0, mask=np.ones_like(y))
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.x_prior))
    for P in res.P:
        assert np.array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > 0
    # the fault is reported on every faulty sample, with the bits expected
    for k in range(K, end):
        assert res.status[k] & EXPECTED[kind] == EXPECTED[kind], status_names(res.status[k])
    assert np.all(res.status[:K] == 0)
    # recovery to the nominal error (2x the fault-free guarded run, or 0.1 % of the
    # largest modal state, whichever is larger: the noise of one run against another)
    e, e0 = _error(d, res.x), _error(d, setup["nominal"].x)
    tol = np.maximum(2 * e0, 1e-3 * np.abs(d.x).max())
    late = np.nonzero(e[end:] > tol[end:])[0]
    recovered = 0.0 if late.size == 0 else (late.max() + 1) * DT
    assert recovered <= RECOVERY, recovered


@pytest.mark.slow
def test_unguarded_step_breaks(setup):
    """The failure the guard prevents (issue 13): one NaN sample with mask 1 makes the
    unguarded state non-finite for the rest of the run."""
    d = setup["data"]
    y = d.y.copy()
    y[K, 0] = np.nan
    F = setup["plain"].mapaccum("r", len(y), [0, 1], [0, 1])
    out = F(np.zeros((6, 1)), P0, d.u.T, y.T, np.ones_like(y).T)
    assert not np.all(np.isfinite(np.asarray(out[2])[:, -1]))


@pytest.mark.slow
def test_bad_state_and_covariance_are_reset(setup):
    """Inputs x, P fed from outside: NaN, indefinite, above the ceiling -> P_reset."""
    step, d = setup["guarded"], setup["data"]
    args = (d.u[K], d.y[K], np.ones(6), d.u[K - 1])
    guard = Guard(P0)
    for x, P, bits in (
            (np.zeros(6), np.full((6, 6), np.nan), STATUS_COVARIANCE_RESET),
            (np.zeros(6), -P0, STATUS_COVARIANCE_RESET),
            (np.zeros(6), 2 * guard.ceiling * np.eye(6), STATUS_COVARIANCE_RESET),
            (np.full(6, np.inf), P0, STATUS_STATE_RESET | STATUS_COVARIANCE_RESET)):
        xn, Pn, xp, un, status = (np.asarray(v) for v in step(x, P, *args))
        status = int(status.item())
        assert status & bits == bits, status_names(status)
        assert np.all(np.isfinite(xn)) and np.linalg.eigvalsh(Pn).min() > 0
        # the step restarted from P_reset: the same as a step from (x_reset, P0)
        ref = step(np.zeros(6), P0, *args)
        np.testing.assert_array_equal(Pn, np.asarray(ref[1]))


def test_default_gate_is_the_chi2_quantile():
    """The gate written out in guard.py is scipy's χ²(1) quantile of 1 − 1e-9, to the bit."""
    from scipy.special import erfcinv
    from scipy.stats import chi2

    from casflex.estimation import DEFAULT_GATE

    assert DEFAULT_GATE == float(2.0 * erfcinv(1e-9) ** 2)
    assert DEFAULT_GATE == pytest.approx(chi2.isf(1e-9, 1), rel=1e-12)  # isf: another path


def test_guard_options_are_checked():
    with pytest.raises(ModelError, match="P_reset"):
        Guard(P_reset=np.zeros((2, 2)))
    with pytest.raises(ModelError, match="gate"):
        Guard(P_reset=np.eye(2), gate=-1.0)
    with pytest.raises(ModelError, match="ceiling"):
        Guard(P_reset=np.eye(2), floor=1.0, ceiling=0.5)
    assert Guard(P_reset=np.eye(2), gate=None).gate == np.inf


def test_prefilter_state_and_samples_guarded():
    """With the prefilter: a NaN filter state restarts at rest, a NaN sample holds its
    channel's filter (as a dropout) and the other channel is filtered as without guard."""
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load
    from casflex.sensors import SensorSet, StrainPair

    robot = load("problems/arm2link.toml")
    ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    plant = tabulate_plant(model, cache_dir=False)
    P = np.eye(2) * 1e-4
    g = ekf_step_function(plant, ss, 5e-6, 9e-14, 1e-3, guard=Guard(P, gate=None),
                          prefilter=1.0)
    plain = ekf_step_function(plant, ss, 5e-6, 9e-14, 1e-3, prefilter=1.0)
    out = g([0, 0], P, np.zeros(9), [0, 0], [1, 1], np.full(8, np.nan), np.zeros(9))
    assert status_names(out[5]) == ["state_reset"]
    np.testing.assert_array_equal(np.asarray(out[3]).ravel(), np.zeros(8))
    out = g([0, 0], P, np.zeros(9), [1e-6, np.nan], [1, 1], np.zeros(8), np.zeros(9))
    ref = plain([0, 0], P, np.zeros(9), [1e-6, 0], [1, 0], np.zeros(8))
    assert status_names(out[5]) == ["sample_nonfinite"]
    for a, b in zip(out[:4], ref, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
