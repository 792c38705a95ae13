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
* **reads are verified**: a file whose stored key differs (stale, foreign) or that cannot
  be read (truncated, corrupt) is treated as missing, so it is recomputed and overwritten
  and a stale cache is never used.

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
import shutil
import sys
import tempfile
from collections.abc import Iterator
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
]

#: name of the array that holds a file's key in :func:`save_verified` files
KEY_FIELD = "__key__"


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


def _replace_atomically(path: Path, write) -> None:
    """Write through ``write(binary file)`` to a temporary file beside ``path``, flush it
    to disk and rename it over ``path``; the temporary file is removed on any failure."""
    path = Path(path)
    make_cache_directory(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
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


def save_verified(path: str | os.PathLike, key: str, **arrays) -> None:
    """Store ``arrays`` with their ``key`` atomically, for :func:`load_verified`.

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
    atomic_savez(path, **{KEY_FIELD: np.array(key)}, **arrays)


def load_verified(path: str | os.PathLike, key: str) -> dict | None:
    """The arrays stored at ``path`` if the file exists, reads and carries ``key``; else
    ``None`` (missing, truncated, corrupt or stale: the caller recomputes).

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
            if str(data[KEY_FIELD]) != key:
                return None
            return {k: data[k] for k in data.files if k != KEY_FIELD}
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
