"""Benchmark of modal identification and model updating (issue 16).

* ``identify_s``: median wall time of :func:`casflex.identification.identify_modes` on a
  synthetic impulse test: 4 modes (1.3–17.6 Hz, ζ 0.5–5 %), 3 channels, 5 kHz, 10 s,
  250 µg noise and offsets.
* ``calibrate_s``: median wall time of :func:`casflex.identification.calibrate` of the
  Table 8 arm (link 2's E and a tip mass on link 2, 2 parameters) to the 4 lowest natural
  frequencies at 8 configurations (made by the TMM with E × 0.9 and 0.1 kg), with the
  default process choice. ``calibrate_by_processes_s`` gives the same fit with 1 and 2
  worker processes (one pool kept for the whole fit, :func:`casflex._parallel.worker_pool`),
  measured side by side: ``[min, median, max]``.
* ``pool_start_s``: start, one trivial call and shutdown of a 2-process pool
  (``[min, median, max]``): what a pool per Jacobian (the previous behaviour of
  ``calibrate``) paid on each of the fit's ~25 TMM batches.
* ``tmm_evaluations``: TMM natural-frequency solutions of one fit (configurations ×
  parameter sets).

Target: ``calibrate_s`` ≤ 10 s on two cores.

Usage: ``python benchmarks/bench_calibration.py [--json] [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from casflex._parallel import parallel_map, worker_pool
from casflex.identification import (
    FitParameter,
    Measurements,
    calibrate,
    identify_modes,
    model_frequencies,
    parse_parameter_path,
    with_parameters,
)
from casflex.robot import load

ROOT = Path(__file__).resolve().parents[1]


def synthetic_log(seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(50_000) / 5000.0
    f = np.array([1.3, 4.7, 9.1, 17.6])
    zeta = np.array([0.005, 0.012, 0.03, 0.05])
    amp = np.array([[0.5, 0.2, 0.1], [0.3, 0.0, 0.4], [0.2, 0.3, 0.1], [0.4, 0.2, 0.3]])
    y = np.array([0.3, -0.1, 9.81]) + 250e-6 * 9.81 * rng.standard_normal((t.size, 3))
    for k in range(4):
        wn = 2 * np.pi * f[k]
        y += amp[k] * np.exp(-zeta[k] * wn * t)[:, None] * np.cos(
            wn * np.sqrt(1 - zeta[k] ** 2) * t[:, None] + rng.uniform(0, 6, 3))
    return t, y


def calibration_case():
    robot = load(ROOT / "problems" / "arm2link.toml")
    E = parse_parameter_path("link2.material.E", robot)
    m = parse_parameter_path("link2.tip.mass", robot)
    rng = np.random.default_rng(0)
    q = np.column_stack([np.zeros(8), rng.uniform(-1.5, 1.5, 8), rng.uniform(-2.5, 2.5, 8)])
    f = model_frequencies(with_parameters(robot, [E, m], [0.9 * 69e9, 0.1]), q, 4)
    params = [FitParameter(E, 30e9, 120e9, 69e9), FitParameter(m, 0.0, 1.0, 0.0)]
    return robot, Measurements(q, f, None), params


def pool_round_trip():
    with worker_pool(2) as pool:
        return list(parallel_map(abs, [(0, (-1,)), (1, (-2,))], pool=pool))


def timed(func, repeat):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t)
    return times, out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions of each timing")
    args = parser.parse_args()

    t, y = synthetic_log()
    identify_modes(t[:5000], y[:5000])  # warm-up (imports)
    id_times, est = timed(lambda: identify_modes(t, y), args.repeat)

    robot, data, params = calibration_case()
    calibrate(robot, data, params, processes=1)  # warm-up
    cal_times, fit = timed(lambda: calibrate(robot, data, params), args.repeat)
    by_processes = {}
    for p in (1, 2):  # side by side, interleaved
        by_processes[str(p)] = []
    for _ in range(args.repeat):
        for p in (1, 2):
            by_processes[str(p)].append(timed(
                lambda p=p: calibrate(robot, data, params, processes=p), 1)[0][0])
    pool_times, _ = timed(pool_round_trip, max(args.repeat, 5))
    result = {
        "identify_s": statistics.median(id_times),
        "calibrate_s": statistics.median(cal_times),
        "tmm_evaluations": fit.tmm_evaluations,
        "identify_range_s": [min(id_times), max(id_times)],
        "calibrate_range_s": [min(cal_times), max(cal_times)],
        "calibrate_by_processes_s": {k: [min(v), statistics.median(v), max(v)]
                                     for k, v in by_processes.items()},
        "pool_start_s": [min(pool_times), statistics.median(pool_times), max(pool_times)],
        "identified_hz": est.frequency_hz.tolist(),
        "fitted": fit.values.tolist(),
        "load_average": list(os.getloadavg()),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
    }
    if args.json:
        print(json.dumps(result))
        return
    print(f"identify (4 modes, 3 channels, 5 kHz, 10 s): {result['identify_s']:.3f} s "
          f"(range {min(id_times):.3f}–{max(id_times):.3f})")
    print(f"calibrate (8 configurations, 4 modes, 2 parameters): {result['calibrate_s']:.3f} s "
          f"(range {min(cal_times):.3f}–{max(cal_times):.3f}), "
          f"{fit.tmm_evaluations} TMM solutions")
    for k, v in result["calibrate_by_processes_s"].items():
        print(f"  processes={k}: min {v[0]:.3f} s, median {v[1]:.3f} s, max {v[2]:.3f} s")
    v = result["pool_start_s"]
    print(f"  2-process pool start + call + shutdown: min {v[0]:.3f} s, median {v[1]:.3f} s, "
          f"max {v[2]:.3f} s")
    print(f"load average {result['load_average']}, {result['cpus']} CPUs")


if __name__ == "__main__":
    main()
