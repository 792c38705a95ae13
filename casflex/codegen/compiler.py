"""The system C compiler: find it, run it, build a bundle into a shared library, load a
function of that library back into Python.

* :func:`find_compiler` resolves the compiler command (``compiler`` argument, else
  ``$CC``, else ``cc``) and raises :class:`~casflex.codegen.BuildError` when it is missing;
* :func:`run_compiler` runs one compiler command and turns a failure into a
  :class:`~casflex.codegen.BuildError` carrying the compiler's stderr;
* :func:`build` compiles a :class:`~casflex.codegen.Bundle` into ``lib<name>.so``;
* :func:`load` wraps one function of such a library as a :class:`casadi.Function`
  (:func:`casadi.external`), checking it against the bundle's manifest.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca

from casflex.codegen.errors import BuildError, CodegenError

if TYPE_CHECKING:
    from casflex.codegen.bundle import Bundle

__all__ = ["find_compiler", "run_compiler", "shared_library_suffix", "build", "load"]


def shared_library_suffix() -> str:
    """File suffix of a shared library on this platform (``.so``, ``.dylib`` or ``.dll``).

    Examples
    --------
    >>> shared_library_suffix() in (".so", ".dylib", ".dll")
    True
    """
    if sys.platform == "darwin":
        return ".dylib"
    if sys.platform.startswith("win"):
        return ".dll"
    return ".so"


def find_compiler(compiler: str | Sequence[str] | None = None) -> list[str]:
    """The C compiler command as a list, its executable resolved on ``$PATH``.

    Parameters
    ----------
    compiler : str or sequence of str, optional
        Compiler command, possibly with arguments (``"gcc -m64"``); default ``$CC``, else
        ``cc``.

    Returns
    -------
    list of str
        ``[absolute path of the executable, *arguments]``.

    Raises
    ------
    casflex.codegen.BuildError
        The command is empty or its executable is not found.

    Examples
    --------
    >>> cmd = find_compiler("cc -O1")
    >>> Path(cmd[0]).is_absolute(), cmd[1:]
    (True, ['-O1'])
    >>> find_compiler("no-such-cc")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.codegen.BuildError: no C compiler: 'no-such-cc' (from argument 'compiler') ...
    """
    spec = compiler if compiler is not None else os.environ.get("CC") or "cc"
    cmd = shlex.split(spec) if isinstance(spec, str) else list(spec)
    if not cmd:
        raise BuildError("no C compiler: the compiler command is empty (set $CC or 'compiler')")
    exe = cmd[0]
    found = shutil.which(exe)
    if found is None:
        origin = "argument 'compiler'" if compiler is not None else (
            "$CC" if os.environ.get("CC") else "default 'cc'")
        raise BuildError(
            f"no C compiler: '{exe}' (from {origin}) is not an executable on this system; "
            "install gcc/clang or set $CC"
        )
    return [found, *cmd[1:]]


def run_compiler(cmd: Sequence[str], cwd: str | os.PathLike, timeout_s: float = 600.0) -> None:
    """Run one compiler command in ``cwd``; a failure raises with the compiler's stderr.

    The command runs in its own process group, so a timeout or an interrupt (Ctrl-C) stops
    the compiler driver's children (``cc1``, ``as``, ``ld``) too, not only the driver.

    Parameters
    ----------
    cmd : sequence of str
        The full command, e.g. ``[*find_compiler(), "-O2", "-o", "prog", "prog.c", "-lm"]``.
    cwd : str or os.PathLike
        Working directory (relative paths in ``cmd`` are relative to it).
    timeout_s : float, optional
        Wall-clock limit [s]; past it the command's whole process group is killed.

    Raises
    ------
    casflex.codegen.BuildError
        The compiler cannot be run, runs longer than ``timeout_s``, or exits with an error
        (the message holds the command and the end of its stderr).

    Examples
    --------
    >>> import tempfile
    >>> work = Path(tempfile.mkdtemp())
    >>> _ = (work / "one.c").write_text("int one(void) { return 1; }\\n")
    >>> run_compiler([*find_compiler(), "-c", "one.c"], work)
    >>> (work / "one.o").is_file()
    True
    >>> run_compiler([*find_compiler(), "-c", "none.c"], work)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.codegen.BuildError: compilation failed (exit status 1): ...
    """
    cmd = [str(c) for c in cmd]
    posix = os.name == "posix"
    try:
        proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=posix)
    except OSError as exc:
        raise BuildError(f"could not run the C compiler {cmd[0]!r}: {exc}") from exc
    try:
        _, stderr = proc.communicate(timeout=timeout_s)
    except BaseException as exc:  # the timeout, or KeyboardInterrupt: stop the whole group
        if posix:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        else:
            proc.kill()
        proc.communicate()
        if isinstance(exc, subprocess.TimeoutExpired):
            raise BuildError(f"the C compiler timed out after {timeout_s:g} s: "
                             f"{shlex.join(cmd)}") from exc
        raise
    if proc.returncode != 0:
        raise BuildError(
            f"compilation failed (exit status {proc.returncode}): {shlex.join(cmd)}\n"
            f"{stderr.strip()[-4000:]}"
        )


def build(bundle: Bundle, compiler: str | Sequence[str] | None = None,
          flags: Sequence[str] = ("-O2",), output: str | os.PathLike | None = None) -> Path:
    """Compile a bundle into a shared library with the system C compiler.

    Parameters
    ----------
    bundle : casflex.codegen.Bundle
        From :func:`casflex.codegen.generate`.
    compiler : str, optional
        Compiler command (may include arguments, e.g. ``"gcc -m64"``); default ``$CC``, else
        ``cc``.
    flags : sequence of str, optional
        Compiler flags; ``-fPIC -shared`` and ``-lm`` are added.
    output : str or pathlib.Path, optional
        Library path; default ``bundle.library`` (``<out_dir>/lib<name>.so``). A process that
        has already loaded a library keeps the old code for that path: build rebuilt code to
        a new path (or directory) before loading it again.

    Returns
    -------
    pathlib.Path
        The shared library.

    Raises
    ------
    BuildError
        No compiler found, or the compiler failed (message with its stderr).

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> from casflex.codegen import generate
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("sq", [x], [x * x])], tempfile.mkdtemp(), name="demo_b")
    >>> build(b, flags=("-O1",)).stem
    'libdemo_b'
    """
    cmd = find_compiler(compiler)
    lib = Path(output).resolve() if output is not None else bundle.library
    lib.parent.mkdir(parents=True, exist_ok=True)
    run_compiler(
        [*cmd, *flags, "-fPIC", "-shared", str(bundle.source), "-o", str(lib), "-lm"],
        bundle.out_dir,
    )
    return lib


def _find_manifest(lib):
    """The manifest ``<name>.json`` beside ``lib<name>.so``, or ``None``."""
    stem = lib.name
    for suffix in (".so", ".dylib", ".dll"):
        if stem.endswith(suffix):
            stem = stem[: -len(suffix)]
    if stem.startswith("lib"):
        stem = stem[3:]
    path = lib.parent / f"{stem}.json"
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def load(library: str | os.PathLike, name: str) -> ca.Function:
    """Load function ``name`` of a compiled bundle as a :class:`casadi.Function`.

    Parameters
    ----------
    library : str or pathlib.Path
        Shared library from :func:`build`.
    name : str
        Function name.

    Returns
    -------
    casadi.Function
        Evaluates the compiled C code (through :func:`casadi.external`).

    Raises
    ------
    CodegenError
        The library does not exist, has no function ``name``, or was generated with
        ``casadi_real``/``casadi_int`` types other than CasADi's (``double``,
        ``long long int``), which :func:`casadi.external` cannot call.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> from casflex.codegen import generate
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("sq", [x], [x * x])], tempfile.mkdtemp(), name="demo_l")
    >>> g = load(build(b, flags=("-O1",)), "sq")
    >>> float(g(3.0))
    9.0
    """
    lib = Path(library).resolve()
    if not lib.is_file():
        raise CodegenError(f"load: no shared library at '{lib}' (build the bundle first)")
    manifest = _find_manifest(lib)
    known = [f["name"] for f in manifest["functions"]] if manifest else None
    try:
        handle = ctypes.CDLL(str(lib))
    except OSError as exc:
        raise CodegenError(f"load: '{lib}' is not a loadable shared library: {exc}") from exc
    if known is not None and name not in known:
        raise CodegenError(
            f"load: '{lib}' has no function '{name}' (it has: {', '.join(known)})"
        )
    if not (hasattr(handle, name) and hasattr(handle, f"{name}_work")):
        raise CodegenError(f"load: '{lib}' exports no CasADi function '{name}'")
    if manifest is not None:
        for kind, ctype in (("int", ctypes.c_longlong), ("real", ctypes.c_double)):
            sym = f"{manifest['prefix']}_casadi_{kind}_size"
            if hasattr(handle, sym):
                getattr(handle, sym).restype = ctypes.c_int
                size = getattr(handle, sym)()
                if size != ctypes.sizeof(ctype):
                    raise CodegenError(
                        f"load: '{lib}' was generated with casadi_{kind} = "
                        f"'{manifest['casadi_' + kind]}' ({size} bytes); casadi.external "
                        f"needs {ctypes.sizeof(ctype)} bytes (generate with the defaults)"
                    )
    try:
        return ca.external(name, str(lib))
    except RuntimeError as exc:
        raise CodegenError(f"load: casadi.external('{name}', '{lib}') failed: {exc}") from exc


