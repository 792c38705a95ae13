"""Modal identification against signals built here from known damped sinusoids.

The reference is the signal's own definition: four modes between 1 and 20 Hz with
damping ratios 0.5–5 %, sampled at 5 kHz for 10 s, with the accelerometers' 250 µg white
noise and channel offsets (gravity on one axis). Tolerances: frequencies within 0.2 % and
damping within 10 % relative (the issue's targets; the Cramér–Rao bounds at this noise
are orders of magnitude tighter, so the targets leave room for the estimator, not for
luck), and, stricter, each estimate within 5 of its own standard errors.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError, ProblemFileError
from casflex.identification import identify_modes, read_log, uniform_sample_rate

G = 9.80665
NOISE = 250e-6 * G  # 250 µg [m/s²]
F_TRUE = np.array([1.3, 4.7, 9.1, 17.6])
Z_TRUE = np.array([0.005, 0.012, 0.03, 0.05])
#: initial amplitudes [m/s²] (mode x channel); channel y does not see mode 2
AMPLITUDE = np.array([[0.5, 0.2, 0.1], [0.3, 0.0, 0.4], [0.2, 0.3, 0.1], [0.4, 0.2, 0.3]])
OFFSET = np.array([0.3, -0.1, G])


def decay(t, f=F_TRUE, zeta=Z_TRUE, amplitude=AMPLITUDE, seed=0, noise=NOISE):
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2 * np.pi, amplitude.shape)
    y = np.zeros((t.size, amplitude.shape[1]))
    for k in range(f.size):
        wn = 2 * np.pi * f[k]
        wd = wn * np.sqrt(1 - zeta[k] ** 2)
        y += amplitude[k] * np.exp(-zeta[k] * wn * t)[:, None] * np.cos(
            wd * t[:, None] + phase[k])
    return y + OFFSET[: y.shape[1]] + noise * rng.standard_normal(y.shape)


def check(est, f=F_TRUE, zeta=Z_TRUE):
    assert est.frequency_hz.size == f.size, f"found {est.frequency_hz} (spurious or missed)"
    assert np.all(np.abs(est.frequency_hz / f - 1) < 2e-3)
    assert np.all(np.abs(est.damping / zeta - 1) < 0.1)
    assert np.all(np.abs(est.frequency_hz - f) < 5 * est.frequency_std_hz)
    assert np.all(np.abs(est.damping - zeta) < 5 * est.damping_std)


@pytest.mark.parametrize("seed", [0, 1])
def test_four_modes_5khz_10s_with_noise_and_offset(seed):
    t = np.arange(50_000) / 5000.0
    est = identify_modes(t, decay(t, seed=seed), channels=("x", "y", "z"))
    check(est)
    assert est.sample_rate == 5000.0
    # which channels see each mode: y has no mode 2
    assert est.seen_by[1] == ["x", "z"]
    assert all(len(s) == 3 for i, s in enumerate(est.seen_by) if i != 1)


def test_sample_rate_is_taken_from_the_time_column():
    # a sensor that runs at 4987 Hz while its nominal rate is 5 kHz: frequencies are right
    # only when the rate comes from the time column
    t = np.arange(49_870) / 4987.0
    est = identify_modes(t, decay(t, seed=2))
    assert est.sample_rate == pytest.approx(4987.0, rel=1e-9)
    check(est)


def test_short_record():
    # 3 s: the 1.3 Hz mode shows fewer than four periods, Welch cannot separate it
    t = np.arange(15_000) / 5000.0
    check(identify_modes(t, decay(t, seed=3)))


def test_pure_noise_gives_no_mode():
    rng = np.random.default_rng(4)
    t = np.arange(20_000) / 5000.0
    y = OFFSET + NOISE * rng.standard_normal((t.size, 3))
    with pytest.raises(ModelError, match="no stable pole|spurious|peak"):
        identify_modes(t, y)


def test_n_modes_keeps_the_most_significant():
    t = np.arange(50_000) / 5000.0
    amp = AMPLITUDE.copy()
    amp[2] *= 0.05  # mode 3 weak
    est = identify_modes(t, decay(t, amplitude=amp, seed=5), n_modes=3)
    assert est.frequency_hz == pytest.approx(F_TRUE[[0, 1, 3]], rel=2e-3)


def test_log_round_trip_csv(tmp_path):
    t = np.arange(10_000) / 1000.0
    y = decay(t, f=F_TRUE[:2], zeta=Z_TRUE[:2], amplitude=AMPLITUDE[:2, :2], seed=6)
    path = tmp_path / "log.csv"
    rows = np.column_stack([t, np.zeros_like(t), np.full_like(t, 0.2), y])
    np.savetxt(path, rows, delimiter=",", header="t,q1,q2,tip_x,tip_y", comments="")
    log = read_log(path)
    assert log.names == ("tip_x", "tip_y")
    assert log.configuration.tolist() == [0.0, 0.2]
    check(identify_modes(log.t, log.channels), F_TRUE[:2], Z_TRUE[:2])


def test_bad_logs_are_one_line_errors(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,acc\n0,1\n")
    with pytest.raises(ProblemFileError, match="'t'"):
        read_log(bad)
    t = np.arange(100) / 100.0
    t[50:] += 0.5  # a gap
    with pytest.raises(ProblemFileError, match="not uniform"):
        uniform_sample_rate(t, "x.csv")
    nan = tmp_path / "nan.csv"
    nan.write_text("t,acc\n" + "\n".join(f"{i / 100},{'nan' if i == 5 else 0}"
                                        for i in range(100)))
    with pytest.raises(ProblemFileError, match="finite"):
        read_log(nan)
