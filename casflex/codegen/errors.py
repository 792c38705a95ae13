"""The two exceptions of :mod:`casflex.codegen`.

Both are documented, raised and caught under their public names
``casflex.codegen.CodegenError`` and ``casflex.codegen.BuildError``.
"""

from __future__ import annotations

from casflex.errors import CasflexError

__all__ = ["CodegenError", "BuildError"]


class CodegenError(CasflexError, ValueError):
    """A code-generation request that cannot be honoured (unknown function, wrong sizes...).

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> from casflex.codegen import generate
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("sq", [x], [x * x])], tempfile.mkdtemp(), name="demo_e")
    >>> b.function("cube")
    Traceback (most recent call last):
        ...
    casflex.codegen.CodegenError: bundle 'demo_e' has no function 'cube' (it has: sq)
    """


class BuildError(CasflexError, RuntimeError):
    """The C compiler is missing or failed, or a compiled program failed to run.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> from casflex.codegen import build, generate
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("sq", [x], [x * x])], tempfile.mkdtemp(), name="demo_be")
    >>> try:
    ...     build(b, compiler="no-such-cc")
    ... except BuildError as exc:
    ...     print(str(exc).split(";")[0])
    no C compiler: 'no-such-cc' (from argument 'compiler') is not an executable on this system
    """


# The public path of both classes (tracebacks, pickles, documentation) is the package's.
CodegenError.__module__ = BuildError.__module__ = "casflex.codegen"
