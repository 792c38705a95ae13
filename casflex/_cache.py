"""The one on-disk cache of casflex: where it lives, how keys are made, how files are
written and read.

Everything casflex keeps between runs — modal tables (:mod:`casflex.modal.tables`), the
tabulated estimator plant, gain schedules and JIT-compiled libraries — goes through this
module, so every cache has the same guarantees:

* **keys** are SHA-256 digests of everything the result depends on (:func:`digest` of a
  JSON-able description, plus :func:`source_digest` of the code that computes it), and
  every file stores its key;
* **writes are atomic**: a temporary file (or staging directory) in the same directory,
  flushed and then renamed into place, so a build that is killed or races another process
  never leaves a truncated file under a final name;
* **reads are verified**: a file whose stored key or content digest (SHA-256 of every
  array's dtype, shape and bytes) differs (stale, foreign, altered) or that cannot be read
  (truncated, corrupt) is treated as missing, so it is recomputed and overwritten and a
  stale cache is never used;
* **leftovers are cleaned**: temporary files and staging directories that an interrupted
  build left behind are removed by the next build (:func:`remove_stale_files`);
* **work is shared**: processes building the same per-point cache claim points with
  exclusive-create claim files and use each other's results (:func:`build_shared`);
* **libraries are private**: a cached file that is loaded as code must be owned by the
  current user and not writable by others (:func:`unsafe_reason`).

The root is ``$CASFLEX_CACHE`` if set, else ``~/.cache/casflex`` (:func:`default_cache_dir`);
every function that caches takes ``cache_dir`` (a path, ``None`` for the default, ``False``
for no cache; see :func:`cache_root`).
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import os
import re
import shutil
import socket
import stat
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path

import numpy as np

from casflex.errors import CasflexError

__all__ = [
    "CacheError",
    "default_cache_dir",
    "cache_root",
    "make_cache_directory",
    "digest",
    "source_digest",
    "atomic_savez",
    "atomic_write_text",
    "load_verified",
    "save_verified",
    "staged_directory",
    "content_digest",
    "remove_stale_files",
    "unsafe_reason",
    "build_shared",
]

#: name of the array that holds a file's key in :func:`save_verified` files
KEY_FIELD = "__key__"
#: name of the array that holds the content digest in :func:`save_verified` files
DIGEST_FIELD = "__digest__"
#: age [s] after which a leftover ``*.tmp`` file or ``.build-*`` directory is removed
STALE_AGE = 3600.0
#: age [s] after which a claim whose owner cannot be checked is taken over
CLAIM_TIMEOUT = 600.0


class CacheError(CasflexError, OSError):
    """The cache directory cannot be created or written (a file in its place, no
    permission, disk full): the message names the path and how to choose another cache.

    Parameters
    ----------
    path : str or os.PathLike
        The file or directory that could not be written.
    exc : OSError
        The underlying error.

    Examples
    --------
    >>> err = CacheError("/proc/cache/x.npz", PermissionError(13, "Permission denied"))
    >>> print(err)  # doctest: +NORMALIZE_WHITESPACE
    cache path '/proc/cache/x.npz': cannot be written (Permission denied); choose a writable
    cache directory with cache_dir= (--cache-dir on the command line) or $CASFLEX_CACHE
    """

    def __init__(self, path: str | os.PathLike, exc: OSError) -> None:
        self.path = str(path)
        reason = exc.strerror or str(exc)
        super().__init__(f"cache path {self.path!r}: cannot be written ({reason}); choose a "
                         "writable cache directory with cache_dir= (--cache-dir on the "
                         "command line) or $CASFLEX_CACHE")


def make_cache_directory(directory: str | os.PathLike) -> Path:
    """Create ``directory`` (and its parents) for cache files, or raise
    :class:`CacheError` naming it.

    Parameters
    ----------
    directory : str or os.PathLike
        A directory under the cache root.

    Examples
    --------
    >>> import tempfile
    >>> tmp = Path(tempfile.mkdtemp())
    >>> make_cache_directory(tmp / "a" / "b").is_dir()
    True
    >>> _ = (tmp / "file").write_text("")
    >>> make_cache_directory(tmp / "file" / "b")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex._cache.CacheError: cache path '.../file/b': cannot be written (Not a directory); ...
    """
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CacheError(directory, exc) from exc
    return directory


def default_cache_dir() -> Path:
    """``$CASFLEX_CACHE`` if set, else ``~/.cache/casflex``.

    Examples
    --------
    >>> isinstance(default_cache_dir(), Path)
    True
    """
    env = os.environ.get("CASFLEX_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "casflex"


def cache_root(cache_dir: str | os.PathLike | bool | None) -> Path | None:
    """The cache directory a ``cache_dir`` argument asks for: ``None`` gives
    :func:`default_cache_dir`, ``False`` gives ``None`` (caching off), a path gives itself.

    Parameters
    ----------
    cache_dir : str or os.PathLike or bool or None
        A function's ``cache_dir`` argument.

    Examples
    --------
    >>> cache_root(False) is None, cache_root("/tmp/x") == Path("/tmp/x")
    (True, True)
    """
    if cache_dir is False:
        return None
    return default_cache_dir() if cache_dir is None else Path(cache_dir)


def digest(obj: object) -> str:
    """SHA-256 (hex) of the canonical JSON text of ``obj`` (keys sorted).

    Parameters
    ----------
    obj : object
        JSON-serialisable description of what a cached result depends on.

    Examples
    --------
    >>> digest({"b": 1, "a": [1.5]}) == digest({"a": [1.5], "b": 1})
    True
    """
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


_SOURCE_MEMO: dict = {}


def _source_of(obj) -> str:
    """``inspect.getsource(obj)`` (or a name when there is none), memoised on the object,
    its code object and its file's modification time: a cache key's source digest is
    recomputed on every call, and reading sources costs ~0.1 s."""
    path = (getattr(obj, "__file__", None)
            or getattr(getattr(obj, "__code__", None), "co_filename", None)
            or getattr(sys.modules.get(getattr(obj, "__module__", None) or ""), "__file__",
                       None))
    try:
        stamp = os.stat(path).st_mtime_ns if path else None
    except OSError:
        stamp = None
    try:
        key = (obj, getattr(obj, "__code__", None), path, stamp)
        hash(key)
    except TypeError:
        key = None
    if key is not None and key in _SOURCE_MEMO:
        return _SOURCE_MEMO[key]
    try:
        src = inspect.getsource(obj)
    except (OSError, TypeError):
        src = getattr(obj, "__qualname__", repr(type(obj)))
    if key is not None:
        _SOURCE_MEMO[key] = src
    return src


def source_digest(*objects) -> str:
    """SHA-256 (hex) of the source code of modules, classes or functions, in order: part
    of a cache key, so that a change to the code that computes a cached result
    invalidates it.

    Parameters
    ----------
    *objects : module, class or function
        The code a cached result is computed by.

    Examples
    --------
    >>> source_digest(digest) == source_digest(digest)
    True
    >>> source_digest(digest) == source_digest(source_digest)
    False
    """
    h = hashlib.sha256()
    for obj in objects:
        h.update(_source_of(obj).encode())
    return h.hexdigest()


# Temporary files carry their writer, ``<name>.<host hash>-<pid>-<random>.tmp``, so that
# the next build can remove what a killed process left at once (remove_stale_files).
_HOST = hashlib.sha256(socket.gethostname().encode()).hexdigest()[:8]
_WRITER_PATTERN = re.compile(r"\.([0-9a-f]{8})-(\d+)-[^.]*\.tmp$")


def writer_tag(pid: int | None = None) -> str:
    """``<host hash>-<pid>``: the writer named in this process's temporary file names.

    Parameters
    ----------
    pid : int, optional
        Another process of this host (default this one).

    Examples
    --------
    >>> writer_tag(123).endswith("-123")
    True
    """
    return f"{_HOST}-{os.getpid() if pid is None else pid}"


def _replace_atomically(path: Path, write) -> None:
    """Write through ``write(binary file)`` to a temporary file beside ``path``, flush it
    to disk and rename it over ``path``; the temporary file is removed on any failure."""
    path = Path(path)
    make_cache_directory(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{path.name}.{writer_tag()}-",
                                   suffix=".tmp")
    except OSError as exc:
        raise CacheError(path, exc) from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise CacheError(path, exc) from exc
        raise


def atomic_savez(path: str | os.PathLike, **arrays) -> None:
    """``numpy.savez(path, **arrays)``, atomically (temporary file, fsync, rename).

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.npz`` file (its directory is created).
    **arrays : numpy.ndarray
        Arrays to store under their keyword names.

    Examples
    --------
    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "a.npz"
    >>> atomic_savez(p, x=np.arange(3))
    >>> np.load(p)["x"].tolist()
    [0, 1, 2]
    """
    _replace_atomically(Path(path), lambda fh: np.savez(fh, **arrays))


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (temporary file, fsync, rename).

    Parameters
    ----------
    path : str or os.PathLike
        Destination file (its directory is created).
    text : str
        Content.

    Examples
    --------
    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "a.txt"
    >>> atomic_write_text(p, "done")
    >>> p.read_text()
    'done'
    """
    _replace_atomically(Path(path), lambda fh: fh.write(text.encode("utf-8")))


def content_digest(arrays: Mapping[str, object]) -> str:
    """SHA-256 (hex) of named arrays: name, dtype, shape and bytes of each, in name order.

    Parameters
    ----------
    arrays : mapping of str to array_like
        The arrays (converted with :func:`numpy.asarray`).

    Examples
    --------
    >>> a = content_digest({"x": np.arange(3.0), "y": np.ones(2)})
    >>> a == content_digest({"y": np.ones(2), "x": np.arange(3.0)})
    True
    >>> a == content_digest({"x": np.arange(3), "y": np.ones(2)})   # int, not float
    False
    """
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(np.asarray(arrays[name]))
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save_verified(path: str | os.PathLike, key: str, **arrays) -> None:
    """Store ``arrays`` with their ``key`` and :func:`content_digest` atomically, for
    :func:`load_verified`.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.npz`` file.
    key : str
        Digest of everything the arrays depend on.
    **arrays : numpy.ndarray
        Arrays to store.

    Examples
    --------
    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "g.npz"
    >>> save_verified(p, "k1", gains=np.ones(2))
    >>> load_verified(p, "k1")["gains"].tolist(), load_verified(p, "other")
    ([1.0, 1.0], None)
    """
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    atomic_savez(path, **{KEY_FIELD: np.array(key),
                          DIGEST_FIELD: np.array(content_digest(arrays))}, **arrays)


def load_verified(path: str | os.PathLike, key: str) -> dict | None:
    """The arrays stored at ``path`` if the file exists, reads, carries ``key`` and its
    content matches the stored digest; else ``None`` (missing, truncated, corrupt, altered,
    stale or written without a digest: the caller recomputes).

    Parameters
    ----------
    path : str or os.PathLike
        A file written by :func:`save_verified`.
    key : str
        The key the caller expects.

    Examples
    --------
    >>> load_verified("/nonexistent/file.npz", "k") is None
    True
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            if DIGEST_FIELD not in data.files or str(data[KEY_FIELD]) != key:
                return None
            arrays = {k: data[k] for k in data.files if k not in (KEY_FIELD, DIGEST_FIELD)}
            if content_digest(arrays) != str(data[DIGEST_FIELD]):
                return None
            return arrays
    except Exception:  # missing, truncated, foreign, corrupt: recompute
        return None


@contextlib.contextmanager
def staged_directory(target: str | os.PathLike) -> Iterator[Path]:
    """Build a directory under a private name beside ``target`` and rename it into place
    when the block succeeds, so ``target`` is either absent or complete.

    If another process put ``target`` in place first, its copy is kept and this one is
    discarded (both were built from the same key). The staging directory is removed
    whatever happens.

    Parameters
    ----------
    target : str or os.PathLike
        Final directory.

    Examples
    --------
    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "lib-abc"
    >>> with staged_directory(target) as tmp:
    ...     _ = (tmp / "lib.so").write_text("built")
    >>> (target / "lib.so").read_text()
    'built'
    """
    target = Path(target)
    make_cache_directory(target.parent)
    try:
        staging = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".build-{target.name}-"))
    except OSError as exc:
        raise CacheError(target, exc) from exc
    try:
        yield staging
        try:
            os.replace(staging, target)
        except OSError:  # a non-empty target exists: another process finished first
            if not target.is_dir():
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def remove_stale_files(directory: str | os.PathLike, max_age: float = STALE_AGE) -> int:
    """Remove the ``*.tmp`` files and ``.build-*`` / ``.gen-*`` directories in
    ``directory`` (not below it) last modified more than ``max_age`` seconds ago, and at
    once the temporary files whose writing process (named in the file name) has ended on
    this host: what a killed build left behind. Call it when a build starts; younger ones
    of a live process may belong to a build that is still running and are kept.

    Parameters
    ----------
    directory : str or os.PathLike
        A cache directory (a missing one is fine).
    max_age : float
        Age [s] beyond which a leftover is removed.

    Returns
    -------
    int
        Number of files and directories removed.

    Examples
    --------
    >>> import tempfile
    >>> tmp = Path(tempfile.mkdtemp())
    >>> old, new = tmp / "p0000000.npz.x1.tmp", tmp / "p0000001.npz.x2.tmp"
    >>> _ = old.write_text(""); _ = new.write_text("")
    >>> os.utime(old, (time.time() - 7200, time.time() - 7200))
    >>> remove_stale_files(tmp), old.exists(), new.exists()
    (1, False, True)
    """
    removed = 0
    limit = time.time() - max_age
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return 0
    for entry in entries:
        name = entry.name
        writer = _WRITER_PATTERN.search(name)
        orphan = (writer is not None and writer.group(1) == _HOST
                  and int(writer.group(2)) != os.getpid()
                  and not pid_alive(int(writer.group(2))))
        try:
            if entry.stat(follow_symlinks=False).st_mtime >= limit and not orphan:
                continue
            if name.endswith(".tmp") and entry.is_file(follow_symlinks=False):
                os.unlink(entry.path)
            elif (name.startswith((".build-", ".gen-"))
                  and entry.is_dir(follow_symlinks=False)):
                shutil.rmtree(entry.path)
            else:
                continue
        except OSError:  # gone meanwhile, or not ours to remove: leave it
            continue
        removed += 1
    return removed


def unsafe_reason(path: str | os.PathLike) -> str | None:
    """Why ``path`` must not be trusted as code to load, or ``None`` if it may be: it must
    be owned by the current user and not writable by group or others (checked where
    ``os.getuid`` exists).

    Parameters
    ----------
    path : str or os.PathLike
        A cached file or directory.

    Examples
    --------
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> unsafe_reason(d) is None
    True
    >>> os.chmod(d, 0o777)
    >>> unsafe_reason(d)
    'is writable by group or others (mode 0o777); it must be writable only by its owner'
    """
    st = os.stat(path)
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return (f"is owned by uid {st.st_uid}, not by the current user (uid {os.getuid()}); "
                "it must be the current user's")
    if hasattr(os, "getuid") and st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return (f"is writable by group or others (mode {oct(stat.S_IMODE(st.st_mode))}); "
                "it must be writable only by its owner")
    return None


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host may still be running (``True`` when that
    cannot be checked)."""
    if sys.platform == "win32":
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, belongs to someone else
        return True
    return True


def _claim_owner_alive(text: str) -> bool:
    """Whether the process named by a claim file's ``host pid`` may still be running
    (``True`` when that cannot be checked: another host, no ``os.kill`` probe)."""
    host, _, pid = text.strip().rpartition(" ")
    if host != socket.gethostname() or not pid.isdigit():
        return True
    return pid_alive(int(pid))


def _try_claim(claim: Path, timeout: float) -> bool:
    """Create ``claim`` exclusively (``host pid`` inside); take it over when its owner
    died or it has not been refreshed for ``timeout`` seconds. ``True`` if it is ours."""
    make_cache_directory(claim.parent)
    for _ in range(2):
        try:
            fd = os.open(claim, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        except FileExistsError:
            try:
                text = claim.read_text()
                age = time.time() - claim.stat().st_mtime
            except OSError:  # released meanwhile: try again
                continue
            if _claim_owner_alive(text) and age < timeout:
                return False
            with contextlib.suppress(OSError):  # stale: the owner died or hangs
                claim.unlink()
            continue
        except OSError as exc:
            raise CacheError(claim, exc) from exc
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{socket.gethostname()} {os.getpid()}\n")
        return True
    return False


def build_shared(items: Iterable[int], path_of: Callable[[int], Path], key: str,
                 compute: Callable[[list[int]], Iterable[tuple[int, dict]]], *,
                 timeout: float = CLAIM_TIMEOUT, poll: float = 0.2
                 ) -> Iterator[tuple[int, dict, bool]]:
    """Results of ``items`` from a per-item cache that several processes may be filling
    at once, each item computed by one of them.

    An item whose file verifies (:func:`load_verified`) is read. Otherwise this process
    claims it by creating ``<file>.claim`` exclusively (``O_CREAT | O_EXCL``), computes
    the items it claimed through ``compute`` and stores each with :func:`save_verified`;
    items claimed by another process are waited for and read when their file appears. A
    claim whose owner died (same host, process gone) or that was not refreshed for
    ``timeout`` seconds is taken over; an owner refreshes its claims while it computes.
    Results are the same whichever process computes an item.

    Parameters
    ----------
    items : iterable of int
        Item numbers (e.g. flat grid indices).
    path_of : callable
        ``path_of(item)``: the item's ``.npz`` file.
    key : str
        The cache key the files carry.
    compute : callable
        ``compute(items)`` yields ``(item, arrays)`` for each of ``items`` (any order).
    timeout : float
        Age [s] of an unrefreshed claim that is taken over.
    poll : float
        Interval [s] between looks at items another process is computing.

    Yields
    ------
    item : int
    arrays : dict
    computed : bool
        ``True`` if this process computed the item.

    Examples
    --------
    >>> import tempfile
    >>> tmp = Path(tempfile.mkdtemp())
    >>> square = lambda items: ((i, {"v": np.array(i * i)}) for i in items)
    >>> sorted((i, int(a["v"]), c) for i, a, c in
    ...        build_shared([2, 3], lambda i: tmp / f"p{i}.npz", "k", square))
    [(2, 4, True), (3, 9, True)]
    >>> [c for _, _, c in build_shared([3], lambda i: tmp / f"p{i}.npz", "k", square)]
    [False]
    """
    pending = list(items)
    while pending:
        mine, others = [], []
        for item in pending:
            path = Path(path_of(item))
            got = load_verified(path, key)
            if got is None and _try_claim(path.with_name(path.name + ".claim"), timeout):
                got = load_verified(path, key)  # finished between the look and the claim
                if got is None:
                    mine.append(item)
                    continue
                _release(path)
            if got is None:
                others.append(item)
            else:
                yield item, got, False
        if mine:
            yield from _compute_claimed(mine, path_of, key, compute, timeout)
        elif others:
            time.sleep(poll)
        pending = others


def _release(path: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path.with_name(path.name + ".claim"))


def _compute_claimed(mine, path_of, key, compute, timeout):
    """Compute and store the claimed items, refreshing the remaining claims now and then;
    release every claim still held on the way out (done, failed or interrupted)."""
    left = {item: Path(path_of(item)) for item in mine}
    refreshed = time.monotonic()
    try:
        for item, arrays in compute(list(mine)):
            save_verified(left[item], key, **arrays)
            _release(left.pop(item))
            yield item, arrays, True
            if time.monotonic() - refreshed > timeout / 4:
                for path in left.values():
                    with contextlib.suppress(OSError):
                        os.utime(path.with_name(path.name + ".claim"))
                refreshed = time.monotonic()
    finally:
        for path in left.values():
            _release(path)
