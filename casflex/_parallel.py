"""The one way casflex runs many independent calls: in this process, on a local process
pool or on a Dask cluster, with a progress bar on stderr.

:func:`parallel_map` is used for the modal tables (:func:`casflex.modal.tables.build_table`)
and the CLI's frequency sweep, and for the Jacobians of model updating
(:func:`casflex.identification.calibrate`), which share one pool over all their calls
through :func:`worker_pool`. The per-call work there is short (tens of ms of numpy), so
calls travel in chunks and, on Dask, each chunk's arguments and results are pickled into
one buffer.

On Dask, :func:`map_keep` leaves a part of each result on the worker that made it, for
:func:`map_kept` to use there (a table build's raw mode shapes: only the tracking's data
of each point travels to the client). :func:`map_keep_reduce_use` does both and a
reduction of the summaries between them as one graph, which the client submits once and
whose summaries never reach it (a table build by grid lines:
:mod:`casflex.modal.gridlines`).

Every worker process (local pool or Dask) runs its BLAS on one thread
(:func:`single_threaded_blas`): the workers already fill the cores, and OpenBLAS's own
threads in each of them would fight for the same cores (on 2 cores, measured in the test
suite: 57 s of CPU instead of 1.6 s for one run). A user's explicit
``OMP_NUM_THREADS``/``OPENBLAS_NUM_THREADS``/``MKL_NUM_THREADS``/``BLIS_NUM_THREADS`` is
kept.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from concurrent.futures import Executor

    from distributed import Client
    from tqdm import tqdm

__all__ = ["parallel_map", "progress_bar", "worker_pool", "WorkerPool", "blas_threads",
           "single_threaded_blas", "end_with_parent", "THREAD_VARIABLES", "map_keep",
           "map_kept", "drop_kept", "map_keep_reduce_use"]

#: the environment variables through which a user sets the BLAS and OpenMP threads
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "BLIS_NUM_THREADS")
#: ``(set, get)`` thread-count functions of the BLAS builds a process may have loaded:
#: OpenBLAS (plain, 64-bit interface, and the scipy-openblas builds numpy and scipy ship)
#: and MKL's single dynamic library
_BLAS_SYMBOLS = (("openblas_set_num_threads", "openblas_get_num_threads"),
                 ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
                 ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
                 ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
                 ("MKL_Set_Num_Threads", "MKL_Get_Max_Threads"))


def progress_bar(total: int, desc: str = "", enabled: bool = True) -> tqdm:
    """A tqdm progress bar on stderr that starts no monitor thread.

    tqdm's monitor thread would outlive the bar, and a later process pool could then no
    longer fork (forkserver is slower to start, and cannot re-import a ``__main__`` read
    from stdin).

    Parameters
    ----------
    total : int
        Number of steps.
    desc : str
        Label.
    enabled : bool
        Show the bar (a disabled bar counts silently).

    Examples
    --------
    >>> with progress_bar(3, enabled=False) as bar:
    ...     bar.update(3)
    """
    # plain tqdm, text on stderr: tqdm.auto would pick the notebook widget, and warn on
    # import where ipywidgets is not installed
    from tqdm import tqdm

    return type("_Bar", (tqdm,), {"monitor_interval": 0})(
        total=total, desc=desc, file=sys.stderr, disable=not enabled, leave=False,
        dynamic_ncols=True)


def _blas_libraries():
    """``{path: (set, get)}`` of the BLAS libraries loaded in this process (Linux:
    ``/proc/self/maps``; elsewhere none are found)."""
    import ctypes

    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if line.rstrip().endswith(".so")
                     or ".so." in line}
    except OSError:
        return {}
    found = {}
    for path in sorted(paths):
        name = os.path.basename(path).lower()
        if "openblas" not in name and "mkl_rt" not in name:
            continue
        try:
            lib = ctypes.CDLL(path)  # already loaded: the same handle
        except OSError:
            continue
        for set_name, get_name in _BLAS_SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                found[path] = (getattr(lib, set_name), getattr(lib, get_name))
                break
    return found


def blas_threads() -> dict[str, int]:
    """The number of threads of every BLAS library loaded in this process.

    Returns
    -------
    dict
        Library file name to its thread count (OpenBLAS and MKL; empty where none is
        loaded or the platform does not list loaded libraries).

    Examples
    --------
    >>> import numpy
    >>> all(n >= 1 for n in blas_threads().values())
    True
    """
    return {os.path.basename(path): int(get())
            for path, (_, get) in _blas_libraries().items()}


def single_threaded_blas() -> bool:
    """Run this process's BLAS on one thread, unless the user chose the threads.

    A worker process calls it before its first task (:func:`parallel_map`'s pools and
    Dask tasks): the workers fill the cores, so BLAS threads would only fight for them.
    Where one of :data:`THREAD_VARIABLES` is set (by the user, or by Dask's nanny, which
    sets them to 1), nothing changes; otherwise the loaded OpenBLAS/MKL libraries are
    set to one thread and the variables to ``1`` (for libraries loaded later and for the
    process's children).

    Returns
    -------
    bool
        Whether the threads were set here (``False``: the user's setting is kept).

    Examples
    --------
    >>> import os
    >>> os.environ.setdefault("OPENBLAS_NUM_THREADS", "1") and single_threaded_blas()
    False
    """
    if any(name in os.environ for name in THREAD_VARIABLES):
        return False
    for name in THREAD_VARIABLES:
        os.environ[name] = "1"
    for set_threads, _ in _blas_libraries().values():
        set_threads(1)
    return True


#: ``prctl`` option: the signal a process gets when its parent ends (linux/prctl.h)
_PR_SET_PDEATHSIG = 1


def end_with_parent(parent: int | None = None) -> bool:
    """Have Linux send this process ``SIGTERM`` when its parent ends
    (``prctl(PR_SET_PDEATHSIG)``), so that a worker process does not outlive a parent that
    was killed without a chance to end it (``SIGKILL``; an orderly exit ends the pools
    itself). Elsewhere, or where ``prctl`` cannot be called, nothing changes.

    The signal follows the thread that started the process: a pool's workers are started
    by the thread of its first ``submit`` (:func:`worker_pool`'s caller), or by the
    ``forkserver`` process, which itself ends with its parent's pipe.

    Parameters
    ----------
    parent : int, optional
        The pid the parent had: if it already ended before the call (the process then has
        another parent), this process ends now (``SIGTERM``).

    Returns
    -------
    bool
        Whether the signal was set.

    Examples
    --------
    In a child process (the signal would otherwise stay set on this one):

    >>> import subprocess, sys
    >>> code = "from casflex._parallel import end_with_parent; print(end_with_parent())"
    >>> out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    >>> out.stdout.strip() == str(sys.platform.startswith("linux"))
    True
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if parent is not None and os.getppid() != parent:  # ended before prctl: no signal
        os.kill(os.getpid(), signal.SIGTERM)
    return True


def _init_worker(parent):
    """Initializer of a pool's worker processes: they end with their parent
    (:func:`end_with_parent`) and run their BLAS on one thread
    (:func:`single_threaded_blas`)."""
    end_with_parent(parent)
    single_threaded_blas()


def _executor(processes):
    """Process pool: ``fork`` while this process has a single thread (works in scripts
    without a ``__main__`` guard and starts fast), ``forkserver`` when other threads run
    (forking a threaded process can deadlock), the platform default elsewhere. Its workers
    end with the process that started them, also when that is killed (Linux)."""
    import multiprocessing
    import threading
    from concurrent.futures import ProcessPoolExecutor

    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1:
        method = "fork"
    elif "forkserver" in methods:
        method = "forkserver"
    else:
        method = None
    ctx = multiprocessing.get_context(method)
    if method == "forkserver":
        ctx.set_forkserver_preload(["casflex.modal.tables"])
    # a forked worker's parent is this process; a forkserver's is the server
    parent = os.getpid() if method == "fork" else None
    return ProcessPoolExecutor(max_workers=processes, mp_context=ctx,
                               initializer=_init_worker, initargs=(parent,))


@dataclass(frozen=True)
class WorkerPool:
    """A process pool kept open across :func:`parallel_map` calls (see :func:`worker_pool`).

    Attributes
    ----------
    executor : concurrent.futures.Executor
        The pool.
    processes : int
        Its number of worker processes.

    Examples
    --------
    >>> WorkerPool(None, 2).processes
    2
    """

    executor: Executor
    processes: int


@contextlib.contextmanager
def worker_pool(processes: int | None = None) -> Iterator[WorkerPool | None]:
    """A local process pool kept open for many :func:`parallel_map` calls.

    Starting a pool costs a fork per worker and the workers' first imports; a caller
    that maps many small batches (an iterative fit: one batch per Jacobian) pays that
    once by passing the pool to every call.

    Parameters
    ----------
    processes : int, optional
        Worker processes (default ``os.cpu_count()``); ``1`` gives ``None``, which
        :func:`parallel_map` takes as "run in this process".

    Yields
    ------
    WorkerPool or None
        The pool, shut down when the block ends.

    Examples
    --------
    >>> with worker_pool(1) as pool:
    ...     sorted(parallel_map(abs, [(i, (-i,)) for i in range(3)], pool=pool))
    [(0, 0), (1, 1), (2, 2)]
    """
    if processes is None:
        processes = os.cpu_count() or 1
    if processes <= 1:
        yield None
        return
    executor = _executor(processes)
    try:
        yield WorkerPool(executor, processes)
    finally:
        executor.shutdown(wait=True, cancel_futures=True)


def _run_chunk(func, arg_list):
    """Worker side of a chunk: ``[func(*args) for args in arg_list]``."""
    return [func(*args) for args in arg_list]


def _run_chunk_packed(func, packed_args, client_pid=None):
    """:func:`_run_chunk` with the arguments and the results pickled into one buffer
    each: a chunk's many small arrays travel as one frame instead of hundreds (Dask's
    per-object serialisation of task arguments and results costs the client and the
    scheduler more CPU than the arrays' size suggests). A worker process other than the
    client's (``client_pid``; threads of the client's own process are left alone) runs
    its BLAS on one thread."""
    import pickle

    if os.getpid() != client_pid:
        single_threaded_blas()  # once: it sets the variables
    return pickle.dumps(_run_chunk(func, pickle.loads(packed_args)),
                        protocol=pickle.HIGHEST_PROTOCOL)


def parallel_map(func: Callable, jobs: Iterable, *, client: Client | None = None,
                 processes: int | None = None, progress: bool = False, desc: str = "",
                 chunksize: int | None = None, pool: WorkerPool | None = None
                 ) -> Iterator[tuple]:
    """Run ``func(*args)`` for every ``(tag, args)`` in ``jobs``; yield ``(tag, result)``
    as results arrive.

    Parameters
    ----------
    func : callable
        A picklable (module-level) function.
    jobs : iterable of (object, tuple)
        A tag (returned with the result) and the positional arguments of each call.
    client : dask.distributed.Client, optional
        Submit to this cluster (``client.submit``, gathered as completed).
    processes : int, optional
        Size of the local process pool (default ``os.cpu_count()``); ``1`` runs the
        calls in this process.
    progress : bool
        tqdm progress bar on stderr.
    desc : str
        Label of the progress bar.
    chunksize : int, optional
        Calls per task sent to a worker. The per-point work is short (tens of ms), so
        single calls would be dominated by scheduling and transfer; by default a chunk
        is ``ceil(N / (4 workers))`` calls, at most 16 (1 when running in-process).
    pool : WorkerPool, optional
        A pool from :func:`worker_pool` to run on (it stays open for the next call);
        ``processes`` is then ignored. Without it a pool is started and shut down for
        this call alone.

    Yields
    ------
    (tag, result)
        In completion order (a chunk's results together). An exception in a call is
        raised here; the remaining tasks are cancelled.

    Examples
    --------
    >>> sorted(parallel_map(abs, [(i, (-i,)) for i in range(3)], processes=1))
    [(0, 0), (1, 1), (2, 2)]
    """
    from concurrent.futures import as_completed as cf_completed

    jobs = list(jobs)
    if not jobs:
        return
    if processes is None:
        processes = os.cpu_count() or 1
    shared = pool is not None and client is None
    if shared:
        processes, pool = pool.processes, pool.executor
    else:
        pool = None
        if client is None and processes > 1 and len(jobs) > 1:
            pool = _executor(min(processes, len(jobs)))  # before tqdm's monitor thread
    if client is not None:
        workers = max(1, sum(client.nthreads().values()))
    else:
        workers = processes if pool is not None else 0
    if chunksize is None:
        chunksize = 1 if workers == 0 else max(1, min(16, -(-len(jobs) // (4 * workers))))
    chunks = [jobs[i:i + chunksize] for i in range(0, len(jobs), chunksize)]
    bar = progress_bar(len(jobs), desc, progress)
    try:
        if client is not None:
            import pickle

            # one map (one message to the scheduler) per call, results gathered in
            # batches of completed chunks (_gather_batches)
            futures = client.map(_run_chunk_packed, [func] * len(chunks),
                                 [pickle.dumps([a for _, a in c],
                                               protocol=pickle.HIGHEST_PROTOCOL)
                                  for c in chunks], [os.getpid()] * len(chunks), pure=False)
            tags = {f.key: [t for t, _ in c] for f, c in zip(futures, chunks, strict=True)}
            for fut, packed in _gather_batches(client, futures):
                results = pickle.loads(packed)
                bar.update(len(results))
                yield from zip(tags[fut.key], results, strict=True)
        elif pool is None:
            for tag, args in jobs:
                result = func(*args)
                bar.update(1)
                yield tag, result
        else:
            futures = {pool.submit(_run_chunk, func, [a for _, a in c]): [t for t, _ in c]
                       for c in chunks}
            try:
                for fut in cf_completed(futures):
                    results = fut.result()
                    bar.update(len(results))
                    yield from zip(futures[fut], results, strict=True)
            finally:
                for fut in futures:  # a shared pool stays open: drop what is left
                    fut.cancel()
    finally:
        bar.close()
        if pool is not None and not shared:
            pool.shutdown(wait=True, cancel_futures=True)


def _gather_batches(client, futures):
    """``(future, result)`` of Dask futures as they complete, one gather per batch of
    completed ones: half the client's CPU per task of a ``result()`` each
    (benchmarks/README_tables.md). Not ``as_completed(with_results=True)``: its
    concurrent fetches broke a comm (tornado's write buffer assertion) and left the loop
    waiting. What is left is cancelled when the caller stops (an error, a break)."""
    from distributed import as_completed

    try:
        for batch in as_completed(futures).batches():
            yield from zip(batch, client.gather(batch), strict=True)
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:  # a cancel is a message to the scheduler even when empty
            client.cancel(pending)


# ------------------------------------------------------------------ results kept on workers

#: results kept in this process by :func:`map_keep` (a Dask worker), per token (newest
#: last): ``{tag: result}``; a few tokens at most (an abandoned build's entries go)
_KEPT: OrderedDict = OrderedDict()
_KEPT_TOKENS = 4
_KEPT_LOCK = threading.Lock()


def _store_kept(token, tag, kept):
    """Keep ``kept`` in this process under ``(token, tag)`` (the oldest tokens go)."""
    with _KEPT_LOCK:
        _KEPT.setdefault(token, {})[tag] = kept
        _KEPT.move_to_end(token)
        while len(_KEPT) > _KEPT_TOKENS:
            _KEPT.popitem(last=False)


def _take_kept(token, tag):
    """The part kept under ``(token, tag)``, taken out of the store (None if absent)."""
    with _KEPT_LOCK:
        store = _KEPT.get(token, {})
        kept = store.pop(tag, None)
        if not store:
            _KEPT.pop(token, None)
    return kept


def _keep_chunk(func, packed_jobs, token, client_pid):
    """Worker side of :func:`map_keep`: ``func(*args) -> (summary, kept)`` per pickled
    ``(tag, args)``; the kept parts stay here, the summaries and this worker's address go
    back."""
    import pickle

    from distributed import get_worker

    if os.getpid() != client_pid:
        single_threaded_blas()
    summaries = []
    for tag, args in pickle.loads(packed_jobs):
        summary, kept = func(*args)
        _store_kept(token, tag, kept)
        summaries.append(summary)
    return get_worker().address, pickle.dumps(summaries, protocol=pickle.HIGHEST_PROTOCOL)


def _on_kept_chunk(func, packed_jobs, token, client_pid):
    """Worker side of :func:`map_kept`: ``func(kept, *args)``, the kept result taken out
    of this worker's store (None when it is not here: the caller's func recomputes)."""
    import pickle

    if os.getpid() != client_pid:
        single_threaded_blas()
    results = []
    for tag, args in pickle.loads(packed_jobs):
        results.append(func(_take_kept(token, tag), *args))
    return pickle.dumps(results, protocol=pickle.HIGHEST_PROTOCOL)


def _drop_kept(token):
    with _KEPT_LOCK:
        _KEPT.pop(token, None)


def _chunk_size(n_jobs, client, chunksize):
    """``chunksize``, or by default ``ceil(N / (4 workers))`` calls, at most 16."""
    if chunksize is not None:
        return chunksize
    workers = max(1, sum(client.nthreads().values()))
    return max(1, min(16, -(-n_jobs // (4 * workers))))


def map_keep(func: Callable, jobs: Iterable, client: Client, token: str, *,
             progress: bool = False, desc: str = "", chunksize: int | None = None
             ) -> Iterator[tuple]:
    """:func:`parallel_map` on a Dask cluster whose calls return ``(summary, kept)``:
    only the summary comes back, the kept part stays on the worker that made it, for
    :func:`map_kept`.

    A table build's raw mode shapes are ~10× its summary (the tracking's features):
    kept on the workers they cross the network once instead of three times, and the
    client does not unpickle them.

    Parameters
    ----------
    func : callable
        A picklable (module-level) function returning ``(summary, kept)``.
    jobs : iterable of (hashable, tuple)
        A tag (unique; the key of the kept part) and the positional arguments.
    client : dask.distributed.Client
    token : str
        Names this set of kept parts on the workers (unique per use, e.g. a uuid).
    progress, desc, chunksize
        As in :func:`parallel_map`.

    Yields
    ------
    (tag, summary, worker)
        In completion order; ``worker`` is the address of the worker keeping the part.

    Examples
    --------
    On a cluster ``c`` (started once: a doctest would pay its start-up; see
    ``tests/test_parallel.py``), with ``divmod(i, 2)`` as ``(summary, kept)``::

        got = sorted(map_keep(divmod, [(i, (i, 2)) for i in range(3)], c, "doc"))
        # [(0, 0, addr), (1, 0, addr), (2, 1, addr)]: the quotients, the workers
        where = {tag: worker for tag, _, worker in got}
        sorted(map_kept(divmod, [(i, (1,)) for i in range(3)], c, "doc", where))
        # [(0, (0, 0)), (1, (1, 0)), (2, (0, 0))]: divmod(i % 2, 1) on those workers

    >>> list(map_keep(divmod, [], None, "nothing"))   # no jobs: no cluster needed
    []
    """
    import pickle

    jobs = list(jobs)
    if not jobs:
        return
    size = _chunk_size(len(jobs), client, chunksize)
    chunks = [jobs[i:i + size] for i in range(0, len(jobs), size)]
    tags = [[t for t, _ in c] for c in chunks]
    futures = client.map(_keep_chunk, [func] * len(chunks),
                         [pickle.dumps(c, protocol=pickle.HIGHEST_PROTOCOL) for c in chunks],
                         [token] * len(chunks), [os.getpid()] * len(chunks), pure=False)
    by_key = {f.key: t for f, t in zip(futures, tags, strict=True)}
    with progress_bar(len(jobs), desc, progress) as bar:
        for fut, (worker, packed) in _gather_batches(client, futures):
            summaries = pickle.loads(packed)
            bar.update(len(summaries))
            for tag, summary in zip(by_key[fut.key], summaries, strict=True):
                yield tag, summary, worker


def map_kept(func: Callable, jobs: Iterable, client: Client, token: str,
             where: dict, *, progress: bool = False, desc: str = "",
             chunksize: int | None = None) -> Iterator[tuple]:
    """``func(kept, *args)`` for every ``(tag, args)``, on the worker keeping the part of
    ``tag`` from :func:`map_keep` (which gives it up: each kept part is used once).

    Parameters
    ----------
    func : callable
        A picklable (module-level) function. ``kept`` is None where the part is gone (its
        worker left the cluster, or the call ran elsewhere): ``func`` must then recompute
        it.
    jobs : iterable of (hashable, tuple)
        Tags of :func:`map_keep` and further positional arguments.
    client : dask.distributed.Client
    token : str
        The token given to :func:`map_keep`.
    where : dict
        Tag to worker address, from :func:`map_keep`; a tag not in it runs anywhere.
    progress, desc, chunksize
        As in :func:`parallel_map`.

    Yields
    ------
    (tag, result)
        In completion order.

    Examples
    --------
    >>> list(map_kept(abs, [], None, "nothing", {}))   # see map_keep for a cluster's use
    []
    """
    import pickle

    jobs = list(jobs)
    if not jobs:
        return
    groups: dict = {}
    for job in jobs:  # one map per worker, its chunks bound to it
        groups.setdefault(where.get(job[0]), []).append(job)
    size = _chunk_size(len(jobs), client, chunksize)  # of all the jobs: as many tasks
    futures, by_key = [], {}
    for worker, group in groups.items():
        chunks = [group[i:i + size] for i in range(0, len(group), size)]
        tags = [[t for t, _ in c] for c in chunks]
        place = {} if worker is None else {"workers": [worker], "allow_other_workers": True}
        mapped = client.map(_on_kept_chunk, [func] * len(chunks),
                            [pickle.dumps(c, protocol=pickle.HIGHEST_PROTOCOL)
                             for c in chunks], [token] * len(chunks),
                            [os.getpid()] * len(chunks), pure=False, **place)
        futures += mapped
        by_key.update({f.key: t for f, t in zip(mapped, tags, strict=True)})
    with progress_bar(len(jobs), desc, progress) as bar:
        for fut, packed in _gather_batches(client, futures):
            results = pickle.loads(packed)
            bar.update(len(results))
            yield from zip(by_key[fut.key], results, strict=True)


def _keep_one(func, packed_job, token, client_pid):
    """Worker side of :func:`map_keep_reduce_use`'s first stage: ``func(*args) ->
    (summary, kept)`` of the pickled ``(tag, args)``; the kept part stays in this process,
    the summary is the task's result (for the reduction, on whichever worker runs it)."""
    import pickle

    if os.getpid() != client_pid:
        single_threaded_blas()
    tag, args = pickle.loads(packed_job)
    summary, kept = func(*args)
    _store_kept(token, tag, kept)
    return summary


def _reduce_summaries(func, tags, *summaries):
    """Worker side of the reduction: ``func({tag: summary})``."""
    return func(dict(zip(tags, summaries, strict=True)))


def _use_one(func, packed_job, token, client_pid, reduced):
    """Worker side of :func:`map_keep_reduce_use`'s last stage: ``func(kept, reduced,
    *args)`` of the pickled ``(tag, args)``, the kept part taken out of this worker's store
    (None when it is not here); the result pickled into one buffer."""
    import pickle

    if os.getpid() != client_pid:
        single_threaded_blas()
    tag, args = pickle.loads(packed_job)
    return pickle.dumps(func(_take_kept(token, tag), reduced, *args),
                        protocol=pickle.HIGHEST_PROTOCOL)


def map_keep_reduce_use(keep: Callable, reduce: Callable, use: Callable, jobs: Iterable,
                        client: Client, token: str, *, nthreads: dict | None = None,
                        progress: bool = False, descs: tuple[str, str] = ("", ""),
                        stage_times: dict | None = None) -> Iterator[tuple]:
    """Per ``(tag, keep_args, use_args)`` job, ``keep(*keep_args) -> (summary, kept)``;
    then ``reduced = reduce({tag: summary})`` once; then ``use(kept, reduced, *use_args)``
    on the worker keeping that ``kept``: :func:`map_keep` and :func:`map_kept` with the
    reduction between them, as one Dask graph.

    The client submits the graph once and gathers only the last stage's results: the
    summaries go from worker to worker to the reduction's task, ``reduced`` from there
    to the last stage's, and the client neither waits between the stages nor unpickles
    the summaries (a table build by grid lines: two round trips and about a quarter of
    the client's CPU less, ``benchmarks/README_tables.md``). Each job's two tasks are
    bound to one worker (``allow_other_workers``: where that worker has left, they run
    elsewhere and ``use`` gets ``kept = None``, so it must be able to recompute it).

    Parameters
    ----------
    keep : callable
        A picklable (module-level) function returning ``(summary, kept)``.
    reduce : callable
        A picklable function of the dict ``{tag: summary}``.
    use : callable
        A picklable function ``use(kept or None, reduced, *use_args)``.
    jobs : iterable of (hashable, tuple, tuple)
        A tag (unique), the arguments of ``keep`` and the further arguments of ``use``.
    client : dask.distributed.Client
    token : str
        Names the kept parts on the workers (unique per use); :func:`drop_kept` frees
        what is left after an error.
    nthreads : dict, optional
        ``client.nthreads()`` when the caller has it (one round trip less).
    progress : bool
        Progress bars on stderr, one per stage (jobs done).
    descs : (str, str)
        Their labels.
    stage_times : dict, optional
        Filled with ``"keep"`` and ``"reduce"``: ``time.perf_counter()`` [s] when the
        client learnt that the first stage and the reduction had finished.

    Yields
    ------
    (tag, result)
        The results of ``use``, in completion order. An exception in any stage is raised
        here; what has not finished is cancelled.

    Examples
    --------
    On a cluster ``c`` (see ``tests/test_parallel.py``), with ``divmod(i, 2)`` as
    ``(summary, kept)``, the summaries summed, and ``use(kept, total, x) = (kept, total,
    x)``::

        sorted(map_keep_reduce_use(divmod, lambda s: sum(s.values()), use,
                                   [(i, (i, 2), (10 * i,)) for i in range(3)], c, "doc"))
        # [(0, (0, 1, 0)), (1, (1, 1, 10)), (2, (0, 1, 20))]

    >>> list(map_keep_reduce_use(divmod, sum, abs, [], None, "nothing"))   # no cluster
    []
    """
    import pickle
    import time

    from dask.highlevelgraph import HighLevelGraph, MaterializedLayer
    from distributed import as_completed

    jobs = list(jobs)
    if not jobs:
        return
    if nthreads is None:
        nthreads = client.nthreads()
    # each job's tasks on one worker thread, the threads taken in turn
    slots = [w for w, n in sorted(nthreads.items()) for _ in range(max(1, n))]
    pid = os.getpid()
    # a plain graph in layers, one of each stage per worker bound there
    # (``allow_other_workers``): no collection machinery to build and optimise
    tags = [job[0] for job in jobs]
    keep_keys = [f"casflex-keep-{token}-{i}" for i in range(len(jobs))]
    use_keys = [f"casflex-use-{token}-{i}" for i in range(len(jobs))]
    reduce_key = f"casflex-reduce-{token}"
    stage = {}  # (stage, worker) -> {key: task}

    def packed(tag, args):  # tags and arguments inside bytes: not searched for keys
        return pickle.dumps((tag, args), protocol=pickle.HIGHEST_PROTOCOL)

    for i, (tag, keep_args, use_args) in enumerate(jobs):
        worker = slots[i % len(slots)]
        stage.setdefault(("keep", worker), {})[keep_keys[i]] = (
            _keep_one, keep, packed(tag, keep_args), token, pid)
        stage.setdefault(("use", worker), {})[use_keys[i]] = (
            _use_one, use, packed(tag, use_args), token, pid, reduce_key)
    # the tags inside a partial, for the same reason
    layers = {reduce_key: MaterializedLayer(
        {reduce_key: (functools.partial(_reduce_summaries, reduce, tags), *keep_keys)})}
    dependencies = {reduce_key: set()}
    for (name, worker), tasks in stage.items():
        layer = f"casflex-{name}-{token}-{worker}"
        layers[layer] = MaterializedLayer(
            tasks, annotations={"workers": [worker], "allow_other_workers": True})
        dependencies[layer] = {reduce_key} if name == "use" else set()
        if name == "keep":
            dependencies[reduce_key].add(layer)
    # the first stage's and the reduction's futures too, for the first bar and the
    # stage times (their results are not gathered)
    wanted = [*keep_keys, reduce_key, *use_keys]
    futures = client.get(HighLevelGraph(layers, dependencies), wanted, sync=False)
    first, last = futures[:len(jobs) + 1], futures[len(jobs) + 1:]
    tag_of = {f.key: t for f, t in zip(last, tags, strict=True)}
    first_keys = {f.key for f in first}
    times = {} if stage_times is None else stage_times
    left = len(jobs)
    with progress_bar(len(jobs), descs[0], progress) as bar_keep, \
            progress_bar(len(jobs), descs[1], progress) as bar_use:
        try:
            for batch in as_completed(futures).batches():
                done_first = [f for f in batch if f.key in first_keys]
                for f in done_first:
                    if f.status == "error":
                        f.result()  # raises the task's exception
                    if f.key == reduce_key:
                        times["reduce"] = time.perf_counter()
                    else:
                        left -= 1
                        bar_keep.update(1)
                if not left and "keep" not in times:
                    times["keep"] = time.perf_counter()
                finished = [f for f in batch if f.key not in first_keys]
                if finished:
                    for fut, packed in zip(finished, client.gather(finished), strict=True):
                        bar_use.update(1)
                        yield tag_of[fut.key], pickle.loads(packed)
        finally:
            pending = [f for f in futures if not f.done()]
            if pending:
                client.cancel(pending)


def drop_kept(client: Client, token: str) -> None:
    """Free what :func:`map_keep` kept under ``token`` on every worker (after an error;
    :func:`map_kept` frees each part it uses).

    Parameters
    ----------
    client : dask.distributed.Client or None
        None: nothing to free.
    token : str

    Examples
    --------
    >>> drop_kept(None, "nothing kept")
    """
    if client is not None:
        client.run(_drop_kept, token)
