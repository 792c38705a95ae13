"""Benchmark of the modal tables (casflex.modal.tables) and the ``sweep`` verb.

``tables_s``
    :func:`casflex.modal.build_table` of the Table 8 arm (``problems/arm2link.toml``):
    q3 over [-π, π] every 1.5° (241 points), 5 modes (+2 tracked extra), default
    quantities (mass normalisation + configuration integrals when available), empty
    cache, local process pool over all CPUs.
``dask_1_worker_s``, ``dask_2_workers_s``, ``dask_speedup_2_workers``
    the testbed (``problems/testbed.toml``) on a 2-D grid q2 × q3 (10 × 12 points),
    4 modes, default quantities, no cache, on a ``dask.distributed.LocalCluster`` with
    one and with two single-threaded worker processes (warmed up before timing; workers
    started with ``MALLOC_TRIM_THRESHOLD_`` = 128 MiB instead of Dask's 64 KiB, without
    the workers' statistical profiler and with a 2 s system monitor: ``DASK_CONFIG``);
    both clusters up at once and the runs alternated, best of ``--repeat``.
``cpu_capacity_2_processes``
    speed-up of a pure-Python loop on 2 processes over 1, before and after: what the
    machine offers at the time (other jobs on the same cores lower it); read the Dask
    speed-up against it.
``sweep_s``
    ``casflex sweep problems/arm2link.toml --joint 3 --from -180deg --to 180deg
    --step 1.5deg --track`` (in-process call of :func:`casflex.cli.main`).

Usage::

    python benchmarks/bench_tables.py [--json] [--repeat N]

Timings are the minimum over ``--repeat`` runs (default 1).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which makes glibc hand
#: memory back to the OS after every TMM evaluation and doubles its cost (measured: 120
#: testbed points 5.0 s vs 2.6 s in one worker); the benchmark's clusters use 128 MiB.
TRIM_KEY = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"
TRIM_VALUE = 1 << 27
#: Dask settings of the benchmark's clusters: the trim threshold above, and no statistical
#: profiler in the workers (it samples every worker's stack every 10 ms; the tasks here
#: are tens of ms of numpy) and a 2 s system monitor instead of 0.5 s (on 2 cores the
#: scheduler's and nannies' background work competes with the workers). Measured in one
#: alternated run (14:33 UTC): speed-up 1.54/1.70 with Dask's defaults, 1.75/1.72 with
#: these; the tables are bit-identical either way.
DASK_CONFIG = {
    TRIM_KEY: TRIM_VALUE,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "2s",
}


def _warm():
    from casflex.modal.tables import compute_modes
    from casflex.robot import load

    compute_modes(load(ROOT / "problems/arm2link.toml"), [[0.0, 0.0, 0.1]], 2, processes=1)
    return os.getpid()


def bench_table(repeat):
    from casflex.modal.tables import build_table
    from casflex.robot import load

    robot = load(ROOT / "problems/arm2link.toml")
    grid = np.radians(np.arange(-180.0, 180.0 + 0.75, 1.5))
    best = np.inf
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as cache:
            t0 = time.perf_counter()
            table = build_table(robot, grid, 5, cache_dir=cache)
            best = min(best, time.perf_counter() - t0)
    return best, table


def bench_dask(repeat):
    """Best time of ``repeat`` builds on a 1-worker and on a 2-worker ``LocalCluster``.

    Both clusters stay up and the runs alternate (1, 2, 1, 2, ...): the machine is
    shared, and a change of load between two blocks of runs would bias the ratio."""
    import contextlib

    import dask
    from distributed import Client, LocalCluster

    from casflex.modal.tables import build_table
    from casflex.robot import load

    robot = load(ROOT / "problems/testbed.toml")
    grid = [np.linspace(-np.pi / 2, np.pi / 2, 10), np.linspace(-np.pi, np.pi, 12)]
    times, tables, clients = {1: np.inf, 2: np.inf}, {}, {}
    with contextlib.ExitStack() as stack:
        stack.enter_context(dask.config.set(DASK_CONFIG))
        for n in (1, 2):
            cluster = stack.enter_context(LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None))
            clients[n] = stack.enter_context(Client(cluster))
            clients[n].wait_for_workers(n)
            clients[n].run(_warm)
        for _ in range(repeat):
            for n in (1, 2):
                t0 = time.perf_counter()
                tables[n] = build_table(robot, grid, 4, cache_dir=False, client=clients[n])
                times[n] = min(times[n], time.perf_counter() - t0)
    same = all(np.array_equal(tables[1].values[k], tables[2].values[k])
               for k in tables[1].values)
    return times, same, tables[2]


def _burn(n):
    x = 0.0
    for i in range(n):
        x += i * 0.5
    return x


def cpu_capacity(n=4_000_000):
    """Speed-up of a pure-Python loop on 2 processes over 1: the parallelism the machine
    really offers at the time of the run (other jobs on the same cores lower it)."""
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    for _ in range(2):
        _burn(n)
    serial = time.perf_counter() - t0
    with ProcessPoolExecutor(2) as ex:
        list(ex.map(_burn, [10, 10]))
        t0 = time.perf_counter()
        list(ex.map(_burn, [n, n]))
        parallel = time.perf_counter() - t0
    return serial / parallel


def bench_sweep(repeat):
    from casflex.cli import main

    argv = ["sweep", str(ROOT / "problems/arm2link.toml"), "--joint", "3", "--from",
            "-180deg", "--to", "180deg", "--step", "1.5deg", "--track", "--json"]
    best = np.inf
    for _ in range(repeat):
        out, err = io.StringIO(), io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
        best = min(best, time.perf_counter() - t0)
        if rc != 0:
            raise SystemExit(f"sweep failed: {err.getvalue()}")
    return best


def _cpu_model():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=1)
    args = parser.parse_args(argv)

    capacity_before = cpu_capacity()
    tables_s, table = bench_table(args.repeat)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the coarse 2-D grid: low MAC
        dask_times, same, table2d = bench_dask(args.repeat)
    sweep_s = bench_sweep(args.repeat)
    capacity_after = cpu_capacity()
    result = {
        "tables_s": tables_s,
        "dask_1_worker_s": dask_times[1],
        "dask_2_workers_s": dask_times[2],
        "dask_speedup_2_workers": dask_times[1] / dask_times[2],
        "sweep_s": sweep_s,
        "dask_tables_identical": bool(same),
        "table_points": int(table.omega.shape[0]),
        "table_quantities": sorted(table.values),
        "table_min_mac": table.info.get("min_mac"),
        "grid_2d_points": int(np.prod(table2d.omega.shape[:2])),
        "cpu_capacity_2_processes": [capacity_before, capacity_after],
        "nproc": os.cpu_count(),
        "cpu": _cpu_model(),
        "python": platform.python_version(),
    }
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:26s} {v}", file=sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
