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
``dask_overhead_cpu_fraction``
    CPU of the client process (the Dask client, the scheduler and the nannies of a
    ``LocalCluster`` all run in it: building the tasks, pickling and unpickling their
    data, the scheduler's bookkeeping, the cluster's background work; since session 24
    the tracking of the grid's base plane is a worker's task, :mod:`casflex.modal.gridlines`)
    over the CPU of the workers,
    in the 2-worker runs (one value per run): the issue's metric, gross.
    ``dask_client_cpu_s`` splits the client's CPU into its main thread (build_table's
    own work) and the others (scheduler, comms, nannies), ``dask_workers_cpu_s`` the
    workers' CPU, ``dask_wall_s_2_workers`` the wall time of those builds.
``dask_overhead_cpu_fraction_net``, ``dask_idle_cpu_s``
    after each of those builds the cluster is left idle for the same wall time; its CPU
    then (client process, workers) is the background a build pays per second of wall
    whatever it does (heartbeats, monitors; a wall time stretched by a loaded machine
    stretches it). The net fraction takes it from both sides:
    (client − idle client) / (workers − idle workers).
``dask_overhead_cpu_fraction_old``, ``..._net_old``, ``dask_client_cpu_s_old``,
``dask_workers_cpu_s_old``, ``dask_idle_cpu_s_old``
    the same for the path before (session 9: ``casflex.modal.tables.TRACK_ON_WORKERS =
    False``: the raw modes kept on the workers, every point's tracking data through the
    client, which tracks the whole grid), on the same cluster, old and new alternated
    (which comes first changes every repeat); the tables compared
    (``dask_tables_identical`` covers 1 worker, 2 workers and both paths).
``dask_task``
    the per-task cost of the Dask path, from ``--tasks`` no-op chunks run through
    :func:`casflex._parallel.parallel_map` on the 2-worker cluster: the client process's
    CPU per task, the same less the idle cluster's background CPU over that time
    (``client_cpu_net_ms``, the figure the projection uses) and the wall time per task [ms].
``dask_task_old``
    the same per-task figures for the path before issue 17 part 6 (a ``client.submit``
    and a ``result()`` per task, written out here), measured alternately with
    ``dask_task`` on the same cluster.
``dask_worker_blas_threads``
    the BLAS threads of each Dask worker after a task (:func:`casflex._parallel.blas_threads`:
    1, by Dask's nanny environment and by :func:`casflex._parallel.single_threaded_blas`).
``pool_blas``
    the testbed grid through a local 2-process pool (:func:`casflex.modal.build_table`,
    ``processes=2``) in fresh subprocesses whose environment sets no BLAS thread variable,
    with the workers' BLAS left at OpenBLAS's default (``old``: one thread per core, the
    path before issue 17 part 6) and set to one thread (``new``), alternated ``--repeat``
    times: wall [s] and CPU of the process and its workers [s] of each run.
``projection``, ``projection_old``
    the speed-up on 4–64 workers predicted from those measurements (see
    :func:`projection_lines` for the new path and :func:`projection` for the old) for the
    testbed grid and for ``problems/arm3_spatial.toml`` (three shape joints, 12 × 12 × 12
    points over its joint limits, 4 modes), whose per-point CPU in the workers and in the
    client (``arm3_per_point_ms``, both paths) is measured on a 4 × 4 × 4 grid on the
    same cluster.
``cpu_capacity_2_processes``
    speed-up of a pure-Python loop on 2 processes over 1, before and after: what the
    machine offers at the time (other jobs on the same cores lower it); read the Dask
    speed-up against it.
``sweep_s``
    ``casflex sweep problems/arm2link.toml --joint 3 --from -180deg --to 180deg
    --step 1.5deg --track`` (in-process call of :func:`casflex.cli.main`).

Usage::

    python benchmarks/bench_tables.py [--json] [--repeat N] [--tasks N] [--dask-only]
                                      [--no-pool-blas]

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
#: are tens of ms of numpy). The other keys slow down the cluster's periodic background
#: work, which on 2 cores competes with the workers and is charged to the client and the
#: workers in proportion to the wall time: the event loops' 20 ms health tick, the
#: workers' 100 ms memory monitor, the 0.5 s system monitor (with its GIL and disk
#: probes), work stealing and the active memory manager (no use on a table's equal
#: tasks). Measured on an idle 2-worker cluster (02:53 UTC, load 13): 0.040 CPU-s per s in
#: the client process and 0.023 in each worker with Dask's defaults (+ the profiler and
#: system-monitor keys), 0.010 and 0.0045 with these. The tables are bit-identical.
DASK_CONFIG = {
    TRIM_KEY: TRIM_VALUE,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "10s",
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.admin.system-monitor.disk": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.scheduler.work-stealing": False,
    "distributed.scheduler.active-memory-manager.start": False,
}
ARM3 = ROOT / "problems/arm3_spatial.toml"
#: the 3-link arm's projected grid: 12 points per shape joint over its limits
ARM3_AXIS_POINTS = 12


def _cpu():
    """CPU seconds (user + system) of this process."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _thread_cpu():
    """CPU seconds of this process: (main thread, all other threads). From the kernel's
    per-thread and per-process clocks (``time.thread_time``, ``getrusage``), not the
    10 ms ticks of ``/proc``: the client's share of a build is a few tens of ms. Call it
    from the main thread."""
    main = time.thread_time()
    return main, _cpu() - main


def _noop(x):
    return x


#: the Dask paths of ``build_table`` measured: ``tables.KEEP_ON_WORKERS`` and
#: ``tables.TRACK_ON_WORKERS`` of each ("lines": session 10, the tracking on the workers
#: by grid lines; "kept": session 9, raw modes kept on the workers, tracking in the
#: client; "client": before, every point's raw modes through the client)
PATHS = {"lines": (True, True), "kept": (True, False), "client": (False, False)}


def measure_build(client, robot, grid, n_modes, path="lines", idle=False):
    """Build a table on ``client`` by ``path`` (:data:`PATHS`); wall, client CPU (main,
    other threads), workers' CPU. ``idle``: then leave the cluster idle for the same wall
    time and record its background CPU over it (``idle_client_s``, ``idle_workers_s``)."""
    from casflex.modal import tables

    w0, c0 = client.run(_cpu), _thread_cpu()
    t0 = time.perf_counter()
    before = tables.KEEP_ON_WORKERS, tables.TRACK_ON_WORKERS
    tables.KEEP_ON_WORKERS, tables.TRACK_ON_WORKERS = PATHS[path]
    try:
        table = tables.build_table(robot, grid, n_modes, cache_dir=False, client=client)
    finally:
        tables.KEEP_ON_WORKERS, tables.TRACK_ON_WORKERS = before
    wall = time.perf_counter() - t0
    c1, w1 = _thread_cpu(), client.run(_cpu)
    got = {"wall_s": wall, "client_main_s": c1[0] - c0[0],
           "client_other_s": c1[1] - c0[1], "workers_s": sum(w1[k] - w0[k] for k in w1)}
    if idle:  # the client's window: from after that client.run to before the next
        c1 = _thread_cpu()
        time.sleep(wall)
        c2, w2 = _thread_cpu(), client.run(_cpu)
        got.update(idle_client_s=sum(c2) - sum(c1), idle_workers_s=sum(w2[k] - w1[k]
                                                                        for k in w2))
    return table, got


def measure_tasks(client, n_tasks, idle_s=3.0):
    """Client CPU and wall per task of ``n_tasks`` no-op chunks through parallel_map.

    The cluster's background work (heartbeats, monitors) costs the client CPU in
    proportion to the wall time, which on a loaded machine is long: its rate, measured
    over ``idle_s`` of an idle cluster, is subtracted for ``client_cpu_net_ms``."""
    from casflex._parallel import parallel_map

    list(parallel_map(_noop, [(i, (i,)) for i in range(8)], client=client, chunksize=1))
    c0, t0 = _cpu(), time.perf_counter()
    time.sleep(idle_s)
    idle_rate = (_cpu() - c0) / (time.perf_counter() - t0)
    c0, t0 = _cpu(), time.perf_counter()
    list(parallel_map(_noop, [(i, (i,)) for i in range(n_tasks)], client=client,
                      chunksize=1))
    cpu, wall = _cpu() - c0, time.perf_counter() - t0
    return {"client_cpu_ms": 1e3 * cpu / n_tasks, "wall_ms": 1e3 * wall / n_tasks,
            "idle_client_cpu_per_s": idle_rate,
            "client_cpu_net_ms": 1e3 * max(cpu - idle_rate * wall, 0.0) / n_tasks}


def _task_submit_old(client, n_tasks):
    """The Dask path of ``parallel_map`` before issue 17 part 6, for no-op chunks: one
    ``client.submit`` and one ``result()`` per task."""
    import pickle

    from distributed import as_completed

    futures = [client.submit(_noop_packed, pickle.dumps([(i,)],
                                                        protocol=pickle.HIGHEST_PROTOCOL),
                             pure=False) for i in range(n_tasks)]
    return [pickle.loads(f.result()) for f in as_completed(futures)]


def _noop_packed(packed):
    """A chunk of no-op calls, its arguments and results pickled (as ``parallel_map``'s
    Dask tasks)."""
    import pickle

    return pickle.dumps([_noop(*args) for args in pickle.loads(packed)],
                        protocol=pickle.HIGHEST_PROTOCOL)


def measure_tasks_old_new(client, n_tasks, rounds=2):
    """Client CPU and wall per no-op task, old path (``_task_submit_old``) and new
    (``parallel_map``), alternated; the lowest of ``rounds`` each."""
    from casflex._parallel import parallel_map

    def new(c, n):
        return list(parallel_map(_noop, [(i, (i,)) for i in range(n)], client=c,
                                 chunksize=1))

    best = {"old": None, "new": None}
    for _ in range(rounds):
        for key, run in (("old", _task_submit_old), ("new", new)):
            c0, t0 = _cpu(), time.perf_counter()
            run(client, n_tasks)
            cpu, wall = _cpu() - c0, time.perf_counter() - t0
            got = {"client_cpu_ms": 1e3 * cpu / n_tasks, "wall_ms": 1e3 * wall / n_tasks}
            if best[key] is None or got["client_cpu_ms"] < best[key]["client_cpu_ms"]:
                best[key] = got
    return best


#: a local 2-process build of the testbed grid in a fresh process (``pool_blas``); argv[1]
#: "old" leaves the workers' BLAS threads at OpenBLAS's default
POOL_SCRIPT = """
import json, resource, sys, time
import numpy as np
from casflex import _parallel
from casflex.modal.tables import build_table
from casflex.robot import load
if sys.argv[1] == "old":
    _parallel.single_threaded_blas = lambda: False
robot = load(sys.argv[2])
grid = [np.linspace(-np.pi / 2, np.pi / 2, 10), np.linspace(-np.pi, np.pi, 12)]
t0 = time.perf_counter()
build_table(robot, grid, 4, cache_dir=False, processes=2)
wall = time.perf_counter() - t0
cpu = sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                            resource.getrusage(resource.RUSAGE_CHILDREN)))
print(json.dumps({"wall_s": wall, "cpu_s": cpu}))
"""


def bench_pool_blas(repeat):
    """``pool_blas``: old and new workers' BLAS threads, alternated in fresh processes
    whose environment sets none of the thread variables."""
    import subprocess

    from casflex._parallel import THREAD_VARIABLES

    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    runs = {"old": [], "new": []}
    for _ in range(repeat):
        for key in runs:
            out = subprocess.run([sys.executable, "-c", POOL_SCRIPT, key,
                                  str(ROOT / "problems/testbed.toml")], env=env, check=True,
                                 capture_output=True, text=True)
            runs[key].append(json.loads(out.stdout.strip().splitlines()[-1]))
    return runs


def projection(workers, n_points, worker_s_per_point, client_s_per_point, task_s):
    """Predicted speed-up of a table build on ``workers`` workers over one worker, by the
    path of session 9 (``"kept"``: tasks of points, the tracking in the client).

    Wall(W) = N c + T(W) o + max(N w / W, one chunk of w) where N points cost ``w``
    [s] each in the workers and ``c`` each in the client (unpickling, tracking: serial),
    and the T(W) tasks (two stages of ``parallel_map``'s default chunks) cost ``o``
    each in the client and the scheduler (serial too). It assumes a free core per worker
    and one for the client, and no network time (a local cluster)."""
    def wall(w):
        chunk = max(1, min(16, -(-n_points // (4 * w))))
        tasks = 2 * -(-n_points // chunk)
        return (n_points * client_s_per_point + tasks * task_s
                + max(n_points * worker_s_per_point / w, chunk * worker_s_per_point))

    return {str(w): wall(1) / wall(w) for w in workers}


def projection_lines(workers, grid_shape, worker_s_per_point, client_s_per_point, task_s):
    """:func:`projection` for the path by grid lines (``"lines"``, session 10; one graph
    since session 24).

    The L lines along the last axis (n points each) go in B(W) = min(L, k W) blocks
    (:func:`casflex.modal.line_blocks`, k = ``BLOCKS_PER_WORKER``, more for blocks of at
    most ``MAX_BLOCK_POINTS`` points), two tasks each and one for the base plane's
    tracking; the worker with the most lines (blocks dealt in turn) sets the pace:
    Wall(W) = N c + (2 B(W) + 1) o + (its lines) n w. Past W = L the workers beyond L
    idle. The base plane's tracking (one point per line, between the two stages on one
    worker) is counted in w as if it were spread: ~1 ms of the testbed grid's ~0.45 s."""
    from casflex.modal import line_blocks

    n_lines, n_last = int(np.prod(grid_shape[:-1])), int(grid_shape[-1])
    n_points = n_lines * n_last

    def wall(w):
        blocks = line_blocks(n_lines, w, line_points=n_last)
        most = max(sum(b.size for b in blocks[i::w]) for i in range(min(w, len(blocks))))
        return (n_points * client_s_per_point + (2 * len(blocks) + 1) * task_s
                + most * n_last * worker_s_per_point)

    return {str(w): wall(1) / wall(w) for w in workers}


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


def bench_dask(repeat, n_tasks):
    """Best time of ``repeat`` builds on a 1-worker and on a 2-worker ``LocalCluster``,
    the CPU split of the 2-worker runs, the per-task cost and the 3-link arm's per-point
    costs.

    Both clusters stay up and the runs alternate (1, 2, 1, 2, ...): the machine is
    shared, and a change of load between two blocks of runs would bias the ratio."""
    import contextlib

    import dask
    from distributed import Client, LocalCluster

    from casflex.robot import load

    robot = load(ROOT / "problems/testbed.toml")
    grid = [np.linspace(-np.pi / 2, np.pi / 2, 10), np.linspace(-np.pi, np.pi, 12)]
    times, tables, clients, cpu, cpu_old = {1: np.inf, 2: np.inf}, {}, {}, [], []
    with contextlib.ExitStack() as stack:
        stack.enter_context(dask.config.set(DASK_CONFIG))
        for n in (1, 2):
            cluster = stack.enter_context(LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None))
            clients[n] = stack.enter_context(Client(cluster))
            clients[n].wait_for_workers(n)
            # as tasks, not client.run: a first TMM call may compile the numba kernels for
            # a while, which in the worker's event loop would stop its heartbeats
            clients[n].gather([clients[n].submit(_warm, workers=[w], pure=False)
                               for w in clients[n].scheduler_info()["workers"]])
        # untimed: the client's first calls of each path import and warm what they use
        for n, path in ((1, "lines"), (2, "lines"), (2, "kept")):
            measure_build(clients[n], robot, grid, 4, path)
        for r in range(repeat):
            for n in (1, 2):
                tables[n], used = measure_build(clients[n], robot, grid, 4)
                times[n] = min(times[n], used["wall_s"])
            # the 2-worker build by the new path and the old, in turn first, each
            # followed by the idle cluster over its wall time
            for path in (("lines", "kept") if r % 2 == 0 else ("kept", "lines")):
                tables[path], used = measure_build(clients[2], robot, grid, 4, path,
                                                   idle=True)
                (cpu if path == "lines" else cpu_old).append(used)
        tasks = measure_tasks(clients[2], n_tasks)
        tasks_old_new = measure_tasks_old_new(clients[2], n_tasks)
        from casflex._parallel import blas_threads

        worker_blas = clients[2].run(blas_threads)
        arm3 = load(ARM3)
        small = [np.linspace(lo, hi, 4) for lo, hi in
                 (arm3.joint_limits[k] for k in (1, 2, 3))]
        arm3_cpu = {}
        for path in ("lines", "kept"):
            _, arm3_cpu[path] = measure_build(clients[2], arm3, small, 4, path)
            arm3_cpu[path]["points"] = 4 ** 3
    same = all(np.array_equal(tables[1].values[k], tables[m].values[k])
               and tables[1].info["periodic"] == tables[m].info["periodic"]
               for k in tables[1].values for m in (2, "lines", "kept"))
    return (times, same, tables[2], cpu, tasks, arm3_cpu, tasks_old_new, worker_blas,
            cpu_old)


def _net_fraction(c):
    """The overhead fraction net of the cluster's background: the idle cluster's CPU over
    the same wall time taken from the client's and from the workers' CPU."""
    return ((c["client_main_s"] + c["client_other_s"] - c["idle_client_s"])
            / (c["workers_s"] - c["idle_workers_s"]))


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
    parser.add_argument("--tasks", type=int, default=400, help="no-op tasks timed")
    parser.add_argument("--dask-only", action="store_true",
                        help="skip tables_s and sweep_s (the Dask keys only)")
    parser.add_argument("--no-pool-blas", dest="pool_blas", action="store_false",
                        help="skip pool_blas (the old vs new workers' BLAS threads)")
    args = parser.parse_args(argv)

    capacity_before = cpu_capacity()
    tables_s, table = (None, None) if args.dask_only else bench_table(args.repeat)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the coarse 2-D grid: low MAC
        (dask_times, same, table2d, cpu, tasks, arm3, tasks_old_new, worker_blas,
         cpu_old) = bench_dask(args.repeat, args.tasks)
    pool_blas = bench_pool_blas(args.repeat) if args.pool_blas else None
    sweep_s = None if args.dask_only else bench_sweep(args.repeat)
    capacity_after = cpu_capacity()
    result = {
        "tables_s": tables_s,
        "dask_1_worker_s": dask_times[1],
        "dask_2_workers_s": dask_times[2],
        "dask_speedup_2_workers": dask_times[1] / dask_times[2],
        "dask_overhead_cpu_fraction": [(c["client_main_s"] + c["client_other_s"])
                                       / c["workers_s"] for c in cpu],
        "dask_client_cpu_s": [{"main": c["client_main_s"], "other": c["client_other_s"]}
                              for c in cpu],
        "dask_workers_cpu_s": [c["workers_s"] for c in cpu],
        "dask_overhead_cpu_fraction_net": [_net_fraction(c) for c in cpu],
        "dask_idle_cpu_s": [{"client": c["idle_client_s"], "workers": c["idle_workers_s"],
                             "over_s": c["wall_s"]} for c in cpu],
        "dask_overhead_cpu_fraction_old": [(c["client_main_s"] + c["client_other_s"])
                                           / c["workers_s"] for c in cpu_old],
        "dask_overhead_cpu_fraction_net_old": [_net_fraction(c) for c in cpu_old],
        "dask_idle_cpu_s_old": [{"client": c["idle_client_s"],
                                 "workers": c["idle_workers_s"], "over_s": c["wall_s"]}
                                for c in cpu_old],
        "dask_wall_s_2_workers": {"new": [c["wall_s"] for c in cpu],
                                  "old": [c["wall_s"] for c in cpu_old]},
        "dask_client_cpu_s_old": [{"main": c["client_main_s"],
                                   "other": c["client_other_s"]} for c in cpu_old],
        "dask_workers_cpu_s_old": [c["workers_s"] for c in cpu_old],
        "dask_task": tasks,
        "dask_task_old_new": tasks_old_new,
        "dask_worker_blas_threads": list(worker_blas.values()),
        "pool_blas": pool_blas,
        "arm3_per_point_ms": {path: {
            "workers": 1e3 * a["workers_s"] / a["points"],
            "client_main": 1e3 * a["client_main_s"] / a["points"],
            "client_other": 1e3 * a["client_other_s"] / a["points"]}
            for path, a in arm3.items()},
        "sweep_s": sweep_s,
        "dask_tables_identical": bool(same),
        "table_points": None if table is None else int(table.omega.shape[0]),
        "table_quantities": None if table is None else sorted(table.values),
        "table_min_mac": None if table is None else table.info.get("min_mac"),
        "grid_2d_points": int(np.prod(table2d.omega.shape[:2])),
        "cpu_capacity_2_processes": [capacity_before, capacity_after],
        "nproc": os.cpu_count(),
        "cpu": _cpu_model(),
        "python": platform.python_version(),
        "load": os.getloadavg(),
    }
    shape2d = table2d.omega.shape[:2]
    n2d = int(np.prod(shape2d))
    task_s = 1e-3 * tasks["client_cpu_net_ms"]
    workers = (1, 2, 4, 8, 16, 32, 64)
    result["projection"], result["projection_old"] = {}, {}
    for key, runs, a3 in (("projection", cpu, arm3["lines"]),
                          ("projection_old", cpu_old, arm3["kept"])):
        best = min(runs, key=lambda c: c["client_main_s"] + c["client_other_s"])
        project = projection_lines if key == "projection" else (
            lambda w, shape, *a: projection(w, int(np.prod(shape)), *a))
        result[key] = {
            "testbed_2d": project(workers, shape2d, best["workers_s"] / n2d,
                                  best["client_main_s"] / n2d, task_s),
            "arm3_spatial_3d": project(workers, (ARM3_AXIS_POINTS,) * 3,
                                       a3["workers_s"] / a3["points"],
                                       a3["client_main_s"] / a3["points"], task_s)}
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:26s} {v}", file=sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
