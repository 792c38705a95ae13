"""Benchmark of the transfer-matrix modal analysis (issue 2, §6).

* ``per_configuration_s``: median wall time of the first 5 natural frequencies and mode
  shapes (51 points per link) of the Table 8 arm at one configuration
  (``casflex.tmm.modes``), over configurations spread along q3.
* ``sweep_s``: the q3 sweep at 1.5° over 360° (240 configurations, 5 frequencies each)
  with ``casflex.tmm.sweep_frequencies``, median of repeated runs.

Targets on one core: ≤ 5 ms per configuration, ≤ 1 s for the sweep.

Usage: ``python benchmarks/bench_tmm.py [--json] [--repeat N]``
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

from casflex.robot import load
from casflex.tmm import modes, sweep_frequencies

ROOT = Path(__file__).resolve().parents[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=5, help="sweep repetitions")
    args = parser.parse_args()

    robot = load(ROOT / "problems" / "arm2link.toml")
    q3 = np.linspace(-np.pi, np.pi, 40, endpoint=False)
    modes(robot, [0.0, 0.0, 0.0], count=5)  # warm-up (imports, caches)
    single = []
    for value in q3:
        t = time.perf_counter()
        modes(robot, [0.0, 0.0, value], count=5)
        single.append(time.perf_counter() - t)

    qs = np.zeros((240, 3))
    qs[:, 2] = np.radians(np.arange(240) * 1.5 - 180.0)
    sweeps = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        sweep_frequencies(robot, qs, 5)
        sweeps.append(time.perf_counter() - t)

    result = {
        "per_configuration_s": statistics.median(single),
        "sweep_s": statistics.median(sweeps),
        "configurations": int(qs.shape[0]),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"machine: {platform.processor() or platform.machine()}, "
              f"{os.cpu_count()} cores, Python {platform.python_version()}")
        print(f"per configuration (5 modes + shapes): {1e3 * result['per_configuration_s']:.2f} ms"
              " (target ≤ 5 ms)")
        print(f"q3 sweep, {result['configurations']} configurations: "
              f"{result['sweep_s']:.3f} s (target ≤ 1 s)")


if __name__ == "__main__":
    main()
