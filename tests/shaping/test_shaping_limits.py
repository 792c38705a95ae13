"""Limits of the SI shaper design (issue 13, part 5): many ranges, time limit, tiny vtol."""

from __future__ import annotations

import math

import numpy as np
import pytest

from casflex import cli
from casflex.errors import ProblemFileError, SolverError
from casflex.shaping import (
    GUESS_MAX_IMPULSES,
    FrequencyRange,
    Shaper,
    ei_two_hump,
    initial_si_guess,
    merge_closest,
    si_shaper,
)

HZ = 2.0 * math.pi


def many_ranges(n):
    """``n`` narrow (±5 %) undamped ranges from 1 Hz up in steps of 1.37: 3^n EI impulses."""
    return [FrequencyRange(0.95 * f * HZ, 1.05 * f * HZ, 0.0, 0.05)
            for f in (1.37**k for k in range(n))]


def undamped_prv(times, amplitudes, omega):
    """|Σ A_i exp(iωt_i)| on a grid of ω, written here independently of casflex."""
    phase = np.outer(omega, times)
    return np.hypot(np.cos(phase) @ amplitudes, np.sin(phase) @ amplitudes)


def merge_by_scanning(times, amplitudes, n):
    """The merge of the closest impulses as initial_si_guess did it before (O(N²))."""
    t, a = list(times), list(amplitudes)
    while len(t) > n:
        j = int(np.argmin(np.diff(t)))
        w = a[j] + a[j + 1]
        t[j : j + 2] = [(a[j] * t[j] + a[j + 1] * t[j + 1]) / w if w > 0
                        else 0.5 * (t[j] + t[j + 1])]
        a[j : j + 2] = [w]
    t[0] = 0.0
    return Shaper(t, a)  # sorts: a merged time can round past an equal neighbour


# -------------------------------------------------------------------- bounded guess
@pytest.mark.parametrize("n_ranges", [10, 15, 30])
def test_initial_guess_stays_bounded(n_ranges):
    guess = initial_si_guess(many_ranges(n_ranges))  # 3^30 impulses unbounded
    assert len(guess) == GUESS_MAX_IMPULSES
    assert guess.times[0] == 0.0 and np.all(np.diff(guess.times) > 0.0)
    assert float(guess.amplitudes.sum()) == pytest.approx(1.0, abs=1e-12)
    assert len(initial_si_guess(many_ranges(n_ranges), n_impulses=40)) == 40


def test_merge_closest_is_the_scanning_merge():
    rng = np.random.default_rng(13)
    for trial in range(200):
        m = int(rng.integers(2, 60))
        t = np.sort(rng.random(m))
        if trial % 2:
            t = np.round(t * 10.0) / 10.0  # equal gaps: the earliest pair goes first
            t = np.unique(t) if trial % 4 == 1 else t
        a = rng.random(t.size)
        a /= a.sum()
        n = int(rng.integers(1, t.size + 1))
        merged = merge_closest(Shaper(t, a), n)
        reference = merge_by_scanning(t, a, n)
        assert merged.times.tolist() == reference.times.tolist()
        assert merged.amplitudes.tolist() == reference.amplitudes.tolist()


@pytest.mark.slow
def test_10_ranges_solve():
    ranges = many_ranges(10)
    assert len(initial_si_guess(ranges)) == GUESS_MAX_IMPULSES  # the bounded EI guess
    res = si_shaper(ranges)
    for r in ranges:
        grid = np.linspace(r.omega_min, r.omega_max, 20001)
        assert undamped_prv(res.shaper.times, res.shaper.amplitudes, grid).max() <= r.vtol + 1e-6


def test_30_ranges_fail_cleanly_before_the_build():
    with pytest.raises(SolverError, match=r"time_limit = 60 s\): the NLP with 64 impulses") as e:
        si_shaper(many_ranges(30))
    assert "\n" not in str(e.value)


# -------------------------------------------------------------------- time limit
def test_time_limit_names_the_option():
    ranges = [FrequencyRange(0.9 * HZ, 1.1 * HZ, 0.0, 0.05)]
    with pytest.raises(SolverError, match="time limit .*time_limit = 1e-09 s.*larger time_limit"):
        si_shaper(ranges, time_limit=1e-9)
    # Ipopt stopped by its wall-clock limit inside the time limit
    with pytest.raises(SolverError, match="Maximum_WallTime_Exceeded.*time_limit"):
        si_shaper(ranges, options={"max_wall_time": 1e-9})
    with pytest.raises(ProblemFileError, match="time_limit"):
        si_shaper(ranges, time_limit=0.0)
    unlimited = si_shaper(ranges, time_limit=None)
    assert unlimited.duration == si_shaper(ranges).duration


def test_cli_time_limit(tmp_path, capsys):
    p = tmp_path / "one.toml"
    p.write_text("[[range]]\nomega_min = 5.0\nomega_max = 6.0\nvtol = 0.05\n")
    assert cli.main(["shaper", str(p), "--time-limit", "1e-9"]) != 0
    err = capsys.readouterr().err
    assert "time_limit" in err and "Traceback" not in err
    assert cli.main(["shaper", str(p), "--time-limit", "0", "--json"]) == 0


# -------------------------------------------------------------------- tiny tolerances
def test_single_frequency_vtol_1e6_is_zv_like():
    omega, vtol = 10.0, 1e-6
    res = si_shaper([FrequencyRange(omega, omega, 0.0, vtol)])
    t, a = res.shaper.times, res.shaper.amplitudes
    assert undamped_prv(t, a, [omega])[0] <= vtol
    # two equal impulses just short of the ZV shaper's half period: the shortest positive
    # shaper with V(ω) <= vtol, |cos(ωT/2)| = vtol
    assert len(t) == 2 and a.tolist() == pytest.approx([0.5, 0.5], abs=1e-9)
    assert res.duration == pytest.approx((math.pi - 2.0 * math.asin(vtol)) / omega, rel=1e-9)
    grid = np.linspace(0.5 * omega, 1.5 * omega, 20001)
    np.testing.assert_allclose(undamped_prv(t, a, grid),
                               np.abs(np.cos(0.5 * grid * res.duration)), atol=1e-9)


def test_vtol_below_verify_tol_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ProblemFileError, match=r"range\[0\]\.vtol.*verify_tol"):
        si_shaper([FrequencyRange(10.0, 10.0, 0.0, 1e-300)])
    p = tmp_path / "tiny.toml"
    p.write_text("[[range]]\nomega_min = 10.0\nomega_max = 10.0\nvtol = 1e-300\n")
    assert cli.main(["shaper", str(p)]) != 0
    err = capsys.readouterr().err
    assert "verify_tol" in err and "ZeroDivisionError" not in err
    # the two-hump EI shaper's closed form at vtol -> 0: the ZV shaper convolved thrice
    assert ei_two_hump(10.0, 0.0, 1e-300).amplitudes.tolist() == [0.125, 0.375, 0.375, 0.125]
