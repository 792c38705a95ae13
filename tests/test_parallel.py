"""casflex._parallel: the workers' BLAS threads (issue 17 part 6), and workers that end
with their parent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: a script that reports OpenBLAS's own thread count (asked through its C API here, not
#: through casflex) in the parent and in the workers of a 2-process parallel_map
SCRIPT = r'''
import ctypes, json, os
import numpy as np
from casflex._parallel import parallel_map

def openblas_threads(_):
    np.ones((50, 50)) @ np.ones((50, 50))  # BLAS used
    counts = []
    for line in open("/proc/self/maps"):
        path = line.split()[-1]
        if "openblas" in os.path.basename(path) and ".so" in path:
            lib = ctypes.CDLL(path)
            for name in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                         "openblas_get_num_threads64_", "openblas_get_num_threads"):
                if hasattr(lib, name):
                    counts.append(getattr(lib, name)())
                    break
    return sorted(set(counts)), os.environ.get("OPENBLAS_NUM_THREADS")

if __name__ == "__main__":
    parent = openblas_threads(0)
    workers = [r for _, r in parallel_map(openblas_threads, [(i, (i,)) for i in range(4)],
                                          processes=2, chunksize=1)]
    print(json.dumps({"parent": parent, "workers": workers, "after": openblas_threads(0)}))
'''


def _run(tmp_path, **env):
    script = tmp_path / "blas_threads.py"
    script.write_text(SCRIPT)
    environ = {k: v for k, v in os.environ.items()
               if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                            "BLIS_NUM_THREADS")}
    environ.update(env, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, str(script)], env=environ, capture_output=True,
                         text=True, timeout=120, check=True)
    return json.loads(out.stdout)


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="lists loaded libraries "
                    "through /proc (Linux)")
def test_pool_workers_run_single_threaded_blas(tmp_path):
    r = _run(tmp_path)
    if not r["parent"][0]:
        pytest.skip("numpy's BLAS is not OpenBLAS here")
    # OpenBLAS starts with one thread per core: the workers must say 1, the parent (the
    # user's process) is left alone
    assert r["parent"][0] == [os.cpu_count()] or os.cpu_count() == 1
    assert all(counts == [1] and env == "1" for counts, env in r["workers"])
    assert r["after"] == r["parent"]


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="lists loaded libraries "
                    "through /proc (Linux)")
def test_a_users_thread_setting_is_kept(tmp_path):
    r = _run(tmp_path, OPENBLAS_NUM_THREADS="2")
    if not r["parent"][0]:
        pytest.skip("numpy's BLAS is not OpenBLAS here")
    assert all(counts == [2] and env == "2" for counts, env in r["workers"])


#: a parent holding a worker_pool: one worker busy (a long sleep), one idle; it prints
#: the workers' pids once both run, then waits to be killed
HOLDER = r"""
import multiprocessing, os, sys, time
from casflex._parallel import worker_pool

with worker_pool(2) as pool:
    busy = pool.executor.submit(time.sleep, 120)
    pool.executor.submit(os.getpid).result()  # both workers started (fork: at once)
    print(" ".join(str(p.pid) for p in multiprocessing.active_children()), flush=True)
    time.sleep(120)
"""


def _alive(pid):
    """A process that runs (a zombie left for a reaper counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_workers_end_when_their_parent_is_killed():
    """SIGKILL leaves a parent no chance to end its pool: the workers get SIGTERM from the
    kernel (end_with_parent in the pool's initializer) instead of running on (the idle
    one would wait on its task queue for ever, the busy one finish its task first)."""
    import signal
    import time

    holder = subprocess.Popen([sys.executable, "-c", HOLDER], stdout=subprocess.PIPE,
                              text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        workers = [int(pid) for pid in holder.stdout.readline().split()]
        assert len(workers) == 2 and all(_alive(pid) for pid in workers)
    finally:
        holder.kill()
        holder.wait(timeout=30)
    deadline = time.monotonic() + 5.0
    while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [pid for pid in workers if _alive(pid)]
    for pid in left:  # do not leave them behind when the test fails
        os.kill(pid, signal.SIGKILL)
    assert not left, f"workers {left} outlived their killed parent"


def _fails_on_three(x):
    if x == 3:
        raise ValueError("three")
    return -x


def test_dask_path_returns_every_tag_with_its_result_and_raises_a_task_error(monkeypatch):
    distributed = pytest.importorskip("distributed")
    from casflex._parallel import THREAD_VARIABLES, parallel_map

    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        cancelled = []
        cancel = client.cancel
        monkeypatch.setattr(client, "cancel", lambda futures, **kw: (
            cancelled.append(len(futures)), cancel(futures, **kw)))
        jobs = [(f"t{i}", (i,)) for i in range(11)]
        got = list(parallel_map(abs, [(t, (-i,)) for t, (i,) in jobs], client=client,
                                chunksize=2))
        assert sorted(got) == sorted((t, i) for t, (i,) in jobs)
        # every task done: no cancel message (one per map cost the client's CPU)
        assert cancelled == []
        with pytest.raises(ValueError, match="three"):
            list(parallel_map(_fails_on_three, jobs, client=client, chunksize=1))
        assert all(cancelled)  # what had not finished, and nothing else
    # the workers were threads of this very process: its BLAS threads (and the variables
    # that set them) are the user's business, left alone
    assert not any(name in os.environ for name in THREAD_VARIABLES)


def _split(x):
    """A call for map_keep: the summary comes back, the list stays on the worker."""
    return -x, [x] * 3


def _use_kept(kept, y):
    return kept, y


def test_kept_parts_stay_until_used_once_and_a_missing_part_is_none():
    distributed = pytest.importorskip("distributed")
    from casflex._parallel import drop_kept, map_keep, map_kept

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = list(map_keep(_split, [(f"t{i}", (i,)) for i in range(7)], client, "tok",
                            chunksize=2))
        assert sorted((tag, s) for tag, s, _ in got) == sorted((f"t{i}", -i) for i in range(7))
        where = {tag: worker for tag, _, worker in got}
        assert set(where.values()) <= set(client.scheduler_info()["workers"])
        used = dict(map_kept(_use_kept, [(f"t{i}", (10 * i,)) for i in range(7)], client,
                             "tok", where, chunksize=3))
        assert used == {f"t{i}": ([i] * 3, 10 * i) for i in range(7)}
        # each part is given up when used: asked again, the function gets None (and
        # must recompute it, as casflex.modal.build_table's does)
        assert dict(map_kept(_use_kept, [("t0", (0,))], client, "tok", where)) == {
            "t0": (None, 0)}
        list(map_keep(_split, [("x", (1,))], client, "abandoned"))
        drop_kept(client, "abandoned")
        assert dict(map_kept(_use_kept, [("x", (1,))], client, "abandoned", {})) == {
            "x": (None, 1)}


def _where_split(x):
    """For map_keep_reduce_use: summary -x; kept: x and the worker that made it."""
    from distributed import get_worker

    return -x, (x, get_worker().address)


def _total(summaries):
    return sum(summaries.values())


def _use_where(kept, total, y):
    from distributed import get_worker

    return kept, total, y, get_worker().address


def _fails_on_three_split(x):
    if x == 3:
        raise ValueError("three")
    return -x, x


def test_keep_reduce_use_runs_each_job_where_its_part_is_kept():
    distributed = pytest.importorskip("distributed")
    from casflex._parallel import map_keep_reduce_use, map_kept

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        jobs = [(f"t{i}", (i,), (10 * i,)) for i in range(5)]
        times = {}
        got = dict(map_keep_reduce_use(_where_split, _total, _use_where, jobs, client,
                                       "tok", stage_times=times))
        assert sorted(got) == sorted(tag for tag, _, _ in jobs)
        workers = set()
        for i in range(5):
            (x, made_on), total, y, used_on = got[f"t{i}"]
            assert (x, total, y) == (i, -sum(range(5)), 10 * i)
            assert used_on == made_on  # the part was used where it was kept
            workers.add(made_on)
        assert len(workers) == 2  # the jobs went to both workers in turn
        assert times["keep"] <= times["reduce"]
        # each part is given up when used: asked again, it is gone
        assert dict(map_kept(_use_kept, [("t0", (0,))], client, "tok", {})) == {
            "t0": (None, 0)}
        with pytest.raises(ValueError, match="three"):
            list(map_keep_reduce_use(_fails_on_three_split, _total, _use_kept_last,
                                     [(i, (i,), ()) for i in range(5)], client, "bad"))


def _use_kept_last(kept, total):
    return kept, total


def test_the_benchmarks_dask_settings_are_keys_of_the_installed_distributed():
    """A misspelt or retired key in ``bench_tables.DASK_CONFIG`` would be set and ignored
    silently: every key must exist in distributed's own defaults, with a value of the
    same kind."""
    import importlib.util

    import dask
    import distributed  # noqa: F401  (registers its defaults)

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_tables.py"
    spec = importlib.util.spec_from_file_location("bench_tables_for_test", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    defaults = dask.config.merge(*dask.config.defaults)
    for key, value in bench.DASK_CONFIG.items():
        node = defaults
        for part in key.split("."):
            assert isinstance(node, dict), f"{key}: {part!r} is below a leaf"
            found = [k for k in node if k.replace("_", "-") == part.replace("_", "-")]
            assert found, f"{key}: no {part!r} in distributed's defaults"
            node = node[found[0]]
        assert isinstance(value, bool) == isinstance(node, bool), (key, value, node)
