"""Just-in-time C: compile CasADi functions once, keep the shared library in the on-disk
cache of casflex (:mod:`casflex._cache`), load it back in this and later processes.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import casadi as ca

from casflex._cache import (
    cache_root,
    pid_alive,
    remove_stale_files,
    staged_directory,
    unsafe_reason,
)
from casflex._validate import identifier
from casflex.codegen.compiler import find_compiler, run_compiler, shared_library_suffix
from casflex.codegen.errors import BuildError, CodegenError
from casflex.codegen.templates import BOOR_ROUTINE_DIGEST, fused_bspline_source

__all__ = ["BACKGROUND_BUILDS_ENV", "cached_library", "compile_cached",
           "compile_in_background", "jit_flags", "tiered_compiler", "without_repeats",
           "write_source"]

_COMPILER_IDENT: dict[tuple[str, ...], str] = {}


def jit_flags(jit: bool | str | Sequence[str], default: Sequence[str]) -> tuple[str, ...]:
    """The compiler flags a simulator's ``jit`` argument asks for.

    Parameters
    ----------
    jit : True or str or sequence of str
        ``True``: ``default``; a string: its whitespace-separated words; else each item.
    default : sequence of str
        The flags of ``jit=True``.

    Returns
    -------
    tuple of str

    Raises
    ------
    casflex.errors.ModelError
        ``jit`` none of these.

    Examples
    --------
    >>> jit_flags(True, ("-O1",)), jit_flags("-O2 -march=native", ("-O1",))
    (('-O1',), ('-O2', '-march=native'))
    >>> jit_flags(3, ("-O1",))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: jit must be True, False, a flags string or a sequence ...
    """
    from casflex.errors import ModelError

    if jit is True:
        return tuple(default)
    if isinstance(jit, str):
        return tuple(jit.split())
    try:
        return tuple(str(x) for x in jit)
    except TypeError:
        raise ModelError(f"jit must be True, False, a flags string or a sequence of "
                         f"compiler flags; got {jit!r}") from None


def _compiler_ident(cmd):
    """``<compiler> --version`` (first line), cached per process: part of the cache key."""
    key = tuple(cmd)
    if key not in _COMPILER_IDENT:
        try:
            out = subprocess.run([*cmd, "--version"], capture_output=True, text=True,
                                 timeout=60).stdout
        except (OSError, subprocess.TimeoutExpired):
            out = ""
        _COMPILER_IDENT[key] = (out.splitlines() or [""])[0]
    return _COMPILER_IDENT[key]


def _check_private(path):
    """Refuse to load code from ``path`` unless it is the user's and private."""
    reason = unsafe_reason(path)
    if reason is not None:
        raise BuildError(f"compile_cached: refusing to load from the library cache: "
                         f"'{path}' {reason} (fix it with chown/chmod go-w, or pass another "
                         "cache_dir)")


def write_source(functions: Sequence[ca.Function], name: str,
                 directory: str | os.PathLike) -> Path:
    """Write the C that :func:`compile_cached` compiles: ``<directory>/<name>.c`` (no
    header) generated from ``functions``, CasADi's B-spline node calls through casflex's
    fused routine (bit for bit CasADi's values, as the bundles' C:
    :func:`casflex.codegen.templates.fused_bspline_source`).

    Parameters
    ----------
    functions : sequence of casadi.Function
    name : str
        Name of the C file (without ``.c``).
    directory : str or os.PathLike
        An existing directory.

    Returns
    -------
    pathlib.Path
        The source file.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.MX.sym("x")
    >>> spline = ca.interpolant("s", "bspline", [[0.0, 1.0, 2.0, 3.0, 4.0]],
    ...                         [0.0, 1.0, 4.0, 9.0, 16.0, 0.0, 1.0, 8.0, 27.0, 64.0])
    >>> f = ca.Function("f", [x], [spline(x)])
    >>> "casflex_boor_eval(" in write_source([f], "demo", tempfile.mkdtemp()).read_text()
    True
    """
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": False})
    for f in functions:
        cg.add(f)
    cg.generate(str(directory) + os.sep)
    path = Path(directory) / f"{name}.c"
    path.write_text(fused_bspline_source(path.read_text()))
    return path


def _generated_source(functions, name, root):
    """The C source CasADi generates for ``functions`` (bytes), via a scratch directory."""
    with tempfile.TemporaryDirectory(dir=root, prefix=".gen-") as tmp:
        return write_source(functions, name, tmp).read_bytes()


def without_repeats(functions: Sequence[ca.Function]) -> list[ca.Function]:
    """``functions`` with the SX ones rebuilt with CasADi's common-subexpression
    elimination (``cse``): the same operations on the same operands, so the same values
    to the last bit, in fewer instructions — much fewer for derivatives, where automatic
    differentiation repeats work (move 1's planner point Jacobian: 74 387 → 33 067). The
    elimination itself takes seconds on such graphs, which is why :func:`compile_cached`
    applies it (``cse=True``) only when it builds a library, not on every lookup.

    Parameters
    ----------
    functions : sequence of casadi.Function

    Returns
    -------
    list of casadi.Function
        The SX functions rebuilt (same name, inputs and outputs), the others as given.

    Examples
    --------
    >>> import casadi as ca
    >>> x = ca.SX.sym("x")
    >>> f = ca.Function("f", [x], [ca.sin(x) * ca.cos(x) + ca.sin(x) * ca.cos(x)])
    >>> g, = without_repeats([f])
    >>> f.n_instructions(), g.n_instructions(), float(g(0.5)) == float(f(0.5))
    (9, 6, True)
    """
    out = []
    for f in functions:
        if f.is_a("SXFunction"):
            ins = f.sx_in()
            f = ca.Function(f.name(), ins, f.call(ins), f.name_in(), f.name_out(),
                            {"cse": True})
        out.append(f)
    return out


def _library_target(functions, name, cache_dir, flags, compiler, cse=False):
    """The compiler command and the cache directory of the library of ``functions``
    built with ``flags`` (created private if missing; the library may not exist yet)."""
    identifier(name, "library name", error=CodegenError)
    cmd = find_compiler(compiler)
    base = cache_root(cache_dir)
    if base is None:
        raise CodegenError("compile_cached: cache_dir=False; the compiled library must live "
                           "in a directory (give a path, or None for the default cache)")
    root = base / "jit"
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
        root.mkdir(mode=0o700, exist_ok=True)
    except OSError as exc:
        raise BuildError(f"compile_cached: cannot create the library cache '{root}': "
                         f"{exc.strerror or exc}; pass another cache_dir") from exc
    _check_private(root)
    # Hashed incrementally: the serialised graphs can be large. The graphs and CasADi's
    # version fix CasADi's C; the digest of casflex's B-spline routine, what we make of it.
    h = hashlib.sha256(json.dumps([name, list(flags), _compiler_ident(cmd),
                                   ca.__version__, BOOR_ROUTINE_DIGEST]
                                  + (["cse"] if cse else [])).encode())
    try:  # the serialised graphs determine the generated C (and are quicker to get)
        for f in functions:
            h.update(f.serialize().encode())
    except RuntimeError:  # not serialisable: hash the generated source instead
        h.update(_generated_source(functions, name, root))
    return cmd, root / f"{name}-{h.hexdigest()[:24]}"


def build_library(functions, name, target, cmd, flags, cse=False):
    """Generate and compile ``functions`` (``cse``: :func:`without_repeats` first) into
    the cache entry ``target`` (renamed into place when complete: a concurrent or
    interrupted build never leaves a broken library). The builder of
    :func:`compile_in_background` calls it too."""
    lib = f"lib{name}{shared_library_suffix()}"
    remove_stale_files(target.parent)
    with staged_directory(target) as staging:
        source = write_source(without_repeats(functions) if cse else functions, name,
                              staging)
        run_compiler([*cmd, *flags, "-fPIC", "-shared", source.name, "-o", lib, "-lm"],
                     staging)
        source.unlink()  # 2-3x the library's size; regenerable
        built_lib = staging / lib  # private whatever the umask
        os.chmod(built_lib, os.stat(built_lib).st_mode & ~0o022)


def _load(functions, target, lib):
    _check_private(target)
    _check_private(lib)
    return {f.name(): ca.external(f.name(), str(lib)) for f in functions}


def compile_cached(functions: Sequence[ca.Function], name: str, *,
                   cache_dir: str | os.PathLike | None = None,
                   flags: Sequence[str] = ("-O1",),
                   compiler: str | Sequence[str] | None = None, cse: bool = False
                   ) -> tuple[dict[str, ca.Function], dict]:
    """Compile CasADi functions to C once, keep the shared library on disk, load them back.

    The functions' serialised graphs (or, for functions CasADi cannot serialise, the C
    source :class:`casadi.CodeGenerator` generates from them) are hashed (SHA-256) with
    the flags, the compiler's ``--version`` line and the CasADi version; the library lives
    in ``<cache_dir>/jit/<name>-<hash>/``, so a later call — in this or another process —
    with the same functions loads it without compiling, and a changed function, flag or
    compiler never reads a stale library. The build goes to a private directory that is
    renamed into place (:func:`casflex._cache.staged_directory`), so an interrupted or
    concurrent build never leaves a broken library behind; leftovers of a killed build
    are removed by a later one (:func:`casflex._cache.remove_stale_files`).

    A shared library runs as code when it is loaded: the ``jit`` directory is created
    private (mode ``0o700``), and a cached library is loaded only if it, its directory
    and the ``jit`` directory are owned by the current user and not writable by group or
    others (:func:`casflex._cache.unsafe_reason`); otherwise :class:`BuildError` names
    the path and the rule.

    Parameters
    ----------
    functions : sequence of casadi.Function
        Functions to compile (their names become the C symbols).
    name : str
        Name of the C file and library (a C identifier).
    cache_dir : str or pathlib.Path, optional
        Cache root; default :func:`casflex._cache.default_cache_dir`
        (``$CASFLEX_CACHE`` or ``~/.cache/casflex``). ``False`` (no cache) is refused: a
        loaded library must stay on disk.
    flags : sequence of str
        Compiler flags (``-fPIC -shared`` and ``-lm`` are added). ``-O0``/``-O1`` keep the
        compile time of large expression graphs low; ``-O2`` and above take much longer.
    compiler : str, optional
        Compiler command; default ``$CC``, else ``cc``.
    cse : bool
        Compile the SX functions without their repeated subexpressions
        (:func:`without_repeats`: the same values, fewer instructions), eliminated only
        when the library is built; part of the cache key.

    Returns
    -------
    functions : dict
        ``name -> casadi.Function`` evaluating the compiled code (:func:`casadi.external`).
    info : dict
        ``library`` (path), ``built`` (``True`` if compiled by this call), ``seconds``
        (time spent generating, hashing and, when built, compiling).

    Raises
    ------
    casflex.codegen.BuildError
        No C compiler, it failed, the cache directory cannot be created, or a cached
        library or its directory is not the current user's or is writable by others.
    casflex.codegen.CodegenError
        ``name`` is not a C identifier, or ``cache_dir`` is ``False``.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.SX.sym("x")
    >>> f = ca.Function("cube", [x], [x**3])
    >>> cache = tempfile.mkdtemp()
    >>> funs, info = compile_cached([f], "demo_jit", cache_dir=cache)
    >>> float(funs["cube"](2.0)), info["built"]
    (8.0, True)
    >>> compile_cached([f], "demo_jit", cache_dir=cache)[1]["built"]   # from the cache
    False
    """
    start = time.perf_counter()
    cmd, target = _library_target(functions, name, cache_dir, flags, compiler, cse)
    lib = target / f"lib{name}{shared_library_suffix()}"
    built = False
    if not lib.is_file():
        build_library(functions, name, target, cmd, flags, cse)
        built = True
    loaded = _load(functions, target, lib)
    return loaded, {"library": str(lib), "built": built,
                    "seconds": time.perf_counter() - start}


def cached_library(functions: Sequence[ca.Function], name: str, *,
                   cache_dir: str | os.PathLike | None = None,
                   flags: Sequence[str] = ("-O1",),
                   compiler: str | Sequence[str] | None = None, cse: bool = False
                   ) -> dict[str, ca.Function] | None:
    """The compiled ``functions`` if :func:`compile_cached` (or
    :func:`compile_in_background`) already built them with ``flags``, else ``None``;
    never compiles.

    Parameters
    ----------
    functions, name, cache_dir, flags, compiler, cse
        As :func:`compile_cached`.

    Returns
    -------
    dict or None
        ``name -> casadi.Function`` evaluating the cached library, or ``None``.

    Raises
    ------
    casflex.codegen.BuildError, casflex.codegen.CodegenError
        As :func:`compile_cached`.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.SX.sym("x")
    >>> f = ca.Function("square", [x], [x**2])
    >>> cache = tempfile.mkdtemp()
    >>> cached_library([f], "demo_lookup", cache_dir=cache) is None
    True
    >>> _ = compile_cached([f], "demo_lookup", cache_dir=cache)
    >>> float(cached_library([f], "demo_lookup", cache_dir=cache)["square"](3.0))
    9.0
    """
    _, target = _library_target(functions, name, cache_dir, flags, compiler, cse)
    lib = target / f"lib{name}{shared_library_suffix()}"
    return _load(functions, target, lib) if lib.is_file() else None


#: prefix of the job directory of a background build, after ``.gen-<library directory>``
_BACKGROUND = "-bg-"
#: the intermediate process: start ``argv[1:]`` in a new session, output nowhere, and exit
_DETACH = ("import subprocess, sys; subprocess.Popen(sys.argv[1:], stdin=subprocess.DEVNULL, "
           "stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)")


def compile_in_background(functions: Sequence[ca.Function], name: str, *,
                          cache_dir: str | os.PathLike | None = None,
                          flags: Sequence[str] = ("-O2",),
                          compiler: str | Sequence[str] | None = None,
                          cse: bool = False) -> Path | None:
    """Start building the library :func:`compile_cached` would build, in a detached
    process, and return at once.

    For code that is worth optimising but slow to compile: a caller runs a quickly
    compiled build now and picks up this one with :func:`cached_library` when it is
    there — later in the same run or in a later process. The functions are saved
    (CasADi's serialisation) into a private job directory in the cache; a separate
    Python process, in its own session (so neither Ctrl-C nor the caller's exit stops
    it), compiles them into the cache entry of ``compile_cached(functions, name,
    flags=flags)``, renamed into place when complete, and removes the job directory. A
    failed build leaves nothing but the missing library (the caller keeps its quick
    build).

    Parameters
    ----------
    functions, name, cache_dir, flags, compiler, cse
        As :func:`compile_cached` (the repeated subexpressions, with ``cse``, eliminated
        by the builder process).

    Returns
    -------
    pathlib.Path or None
        The library that will appear; ``None`` if nothing was started: it is already
        built, a live process is building it, or the functions cannot be serialised.

    Raises
    ------
    casflex.codegen.BuildError, casflex.codegen.CodegenError
        As :func:`compile_cached` (no compiler, an unusable cache).

    Examples
    --------
    >>> import tempfile, time, casadi as ca
    >>> x = ca.SX.sym("x")
    >>> f = ca.Function("halve", [x], [x / 2])
    >>> cache = tempfile.mkdtemp()
    >>> lib = compile_in_background([f], "demo_bg", cache_dir=cache, flags=("-O2",))
    >>> for _ in range(600):  # the caller goes on; here we wait for the library
    ...     if cached_library([f], "demo_bg", cache_dir=cache, flags=("-O2",)):
    ...         break
    ...     time.sleep(0.1)
    >>> float(cached_library([f], "demo_bg", cache_dir=cache, flags=("-O2",))["halve"](3.0))
    1.5
    >>> compile_in_background([f], "demo_bg", cache_dir=cache, flags=("-O2",)) is None
    True
    """
    cmd, target = _library_target(functions, name, cache_dir, flags, compiler, cse)
    return _start_background(functions, name, flags, cmd, target, cse)


def _start_background(functions, name, flags, cmd, target, cse=False):
    """:func:`compile_in_background` for the cache entry ``target`` already found."""
    lib = target / f"lib{name}{shared_library_suffix()}"
    if lib.is_file() or _background_build_running(target):
        return None
    job = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".gen-{target.name}{_BACKGROUND}"))
    try:
        for i, f in enumerate(functions):
            f.save(str(job / f"{i}.casadi"))
    except RuntimeError:  # not serialisable (e.g. an external): no background build
        shutil.rmtree(job, ignore_errors=True)
        return None
    (job / "job.json").write_text(json.dumps({
        "name": name, "target": str(target), "cmd": list(cmd), "flags": list(flags),
        "functions": len(functions), "cse": bool(cse)}))
    # an intermediate process starts the builder and exits: the builder is nobody's child
    # here (no zombie, no ResourceWarning for a Popen still running at exit)
    subprocess.run([sys.executable, "-c", _DETACH, sys.executable, "-m",
                    "casflex.codegen._background", str(job)],
                   stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, check=False, timeout=60)
    return lib


def _background_build_running(target: Path) -> bool:
    """Whether a live process is building ``target`` in the background (its job
    directory names the builder's pid once it has started; a job directory younger than
    a minute without one is being set up)."""
    for job in target.parent.glob(f".gen-{target.name}{_BACKGROUND}*"):
        try:
            pid = int((job / "pid").read_text())
        except (OSError, ValueError):
            try:
                if time.time() - job.stat().st_mtime < 60.0:
                    return True
            except OSError:
                pass
            continue
        if pid_alive(pid):
            return True
    return False


#: environment variable that switches the background builds of :func:`tiered_compiler`
#: off when ``"0"`` (a shared batch machine, a test suite); other values leave them on
BACKGROUND_BUILDS_ENV = "CASFLEX_BACKGROUND_BUILDS"


def tiered_compiler(name: str, *, quick_flags: Sequence[str], optimised_flags: Sequence[str],
                    cache_dir: str | os.PathLike | None = None,
                    log: Callable[[str], None] | None = None,
                    background: bool | None = None, what: str = "the functions",
                    cse: bool = False
                    ) -> Callable[[Sequence[ca.Function]], list[ca.Function]] | None:
    """A ``compile_function(functions) -> compiled functions`` that never waits long for
    the compiler: the optimised library when it is in the cache, else the quick one at
    once (:func:`compile_cached`) and, with ``background``, the optimised one started in
    a detached process (:func:`compile_in_background`) for the next call, in this or a
    later process, to find.

    Parameters
    ----------
    name : str
        Library name (a C identifier).
    quick_flags, optimised_flags : sequence of str
        Compiler flags of the two builds.
    cache_dir : str or pathlib.Path, optional
        Cache root (default: casflex's cache).
    log : callable, optional
        ``log(message)``: told when there is no C compiler and when an optimised build
        starts.
    background : bool, optional
        Start the optimised build when it is missing; default: yes, unless the
        environment variable ``CASFLEX_BACKGROUND_BUILDS`` is ``"0"``
        (:data:`BACKGROUND_BUILDS_ENV`).
    what : str
        What is compiled, for the messages.
    cse : bool
        Both builds without the functions' repeated subexpressions (as
        :func:`compile_cached`).

    Returns
    -------
    callable or None
        ``None`` when there is no C compiler (``log`` says so); else the function, whose
        ``builds`` list records the flags each call used.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.SX.sym("x")
    >>> compile_function = tiered_compiler("demo_tiers", quick_flags=("-O0",),
    ...                                    optimised_flags=("-O1",),
    ...                                    cache_dir=tempfile.mkdtemp(), background=False)
    >>> [f] = compile_function([ca.Function("twice", [x], [2 * x])])
    >>> float(f(1.5)), compile_function.builds
    (3.0, [('-O0',)])
    """
    say = log or (lambda message: None)
    try:
        find_compiler()
    except BuildError as exc:
        say(f"{exc}: {what} are evaluated by CasADi's virtual machine (slower)")
        return None
    quick, optimised = tuple(quick_flags), tuple(optimised_flags)
    if background is None:
        background = os.environ.get(BACKGROUND_BUILDS_ENV, "1").strip() != "0"

    def compile_function(functions):
        # the optimised entry found once: looked up, else built from the background
        cmd, target = _library_target(functions, name, cache_dir, optimised, None, cse)
        library = target / f"lib{name}{shared_library_suffix()}"
        flags = optimised
        if library.is_file():
            lib = _load(functions, target, library)
        else:
            flags = quick
            lib, _ = compile_cached(functions, name, cache_dir=cache_dir, flags=quick,
                                    cse=cse)
            if background and _start_background(functions, name, optimised, cmd, target,
                                                 cse):
                names = ", ".join(f.name() for f in functions)
                say(f"{what} ({names}): compiled with {' '.join(quick)}; a faster build "
                    f"({' '.join(optimised)}) is compiling in the background for the next "
                    "solves")
        compile_function.builds.append(flags)
        return [lib[f.name()] for f in functions]

    compile_function.builds = []
    return compile_function
