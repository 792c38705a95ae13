"""The on-disk cache of SI designs (casflex/shaping/si_cache.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from casflex.errors import SolverError
from casflex.shaping import FrequencyRange, cached_si_design, si_shaper

HZ = 2 * math.pi
#: two ranges, one damped: a design with an LP start, several solves and a sample set
RANGES = [FrequencyRange(0.8 * HZ, 1.2 * HZ, 0.0, 0.05),
          FrequencyRange(2.5 * HZ, 3.0 * HZ, 0.02, 0.1)]


def _fields(result):
    """Every field of an SIShaperResult as plain values (arrays as lists of floats)."""
    def shaper(s):
        return None if s is None else (s.times.tolist(), s.amplitudes.tolist())

    samples = result.samples
    return {
        "shaper": shaper(result.shaper), "final_guess": shaper(result.final_guess),
        "initial_guess": shaper(result.initial_guess),
        "ranges": [(r.omega_min, r.omega_max, r.zeta, r.vtol) for r in result.ranges],
        "max_prv": np.asarray(result.max_prv).tolist(),
        "max_prv_eq187": np.asarray(result.max_prv_eq187).tolist(),
        "iterations": result.iterations, "statuses": list(result.statuses),
        "solver_iterations": list(result.solver_iterations), "start": result.start,
        "lp": (result.lp_duration, result.lp_lower_bound, result.lp_step),
        "samples": None if samples is None else [
            np.asarray(getattr(samples, k)).tolist()
            for k in ("omega", "zeta", "vtol", "range_index")],
    }


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    """One design through the cache, and the calls the cache made to design()."""
    cache = tmp_path_factory.mktemp("si_cache")
    calls = []

    def design():
        calls.append(1)
        return si_shaper(RANGES, dt=1e-3)

    first = cached_si_design(RANGES, {"dt": 1e-3}, design, cache)
    return first, cache, calls


def test_a_stored_design_is_read_back_equal_in_every_field(designed):
    first, cache, calls = designed
    again = cached_si_design(RANGES, {"dt": 1e-3}, lambda: pytest.fail("designed again"),
                             cache)
    assert len(calls) == 1
    assert _fields(again) == _fields(first)  # floats compared exactly
    assert first.samples is not None and first.iterations >= 0


def test_a_changed_range_or_option_designs_again(designed):
    first, cache, _ = designed
    seen = []

    def design():
        seen.append(1)
        return first

    wider = [FrequencyRange(0.8 * HZ, 1.2 * HZ * (1 + 1e-15), 0.0, 0.05), RANGES[1]]
    cached_si_design(wider, {"dt": 1e-3}, design, cache)  # the last bit of one bound
    cached_si_design(RANGES, {"dt": 2e-3}, design, cache)
    cached_si_design(RANGES, {"dt": 1e-3, "n_impulses": 4}, design, cache)
    assert len(seen) == 3


def test_a_failed_design_is_not_stored(tmp_path):
    def failing():
        raise SolverError("no shaper")

    with pytest.raises(SolverError):
        cached_si_design(RANGES, {}, failing, tmp_path)
    assert not list(tmp_path.rglob("*.npz"))


def test_options_that_are_not_json_or_no_cache_design_every_time(designed, tmp_path):
    first = designed[0]
    seen = []

    def design():
        seen.append(1)
        return first

    for _ in range(2):
        cached_si_design(RANGES, {"guess": first.shaper}, design, tmp_path)  # a Shaper
        cached_si_design(RANGES, {}, design, False)
    assert len(seen) == 4 and not list(tmp_path.rglob("*.npz"))


def test_a_truncated_entry_is_designed_again(designed, tmp_path):
    first = designed[0]
    cached_si_design(RANGES, {}, lambda: first, tmp_path)
    (path,) = tmp_path.rglob("*.npz")
    path.write_bytes(path.read_bytes()[:-100])  # an interrupted copy, say
    seen = []

    def design():
        seen.append(1)
        return first

    assert _fields(cached_si_design(RANGES, {}, design, tmp_path)) == _fields(first)
    assert seen == [1]
