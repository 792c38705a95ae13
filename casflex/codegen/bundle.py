"""A generated C bundle: one C source and header from a list of CasADi functions, with
its README, Makefile and manifest.

:func:`generate` writes the bundle and returns a :class:`Bundle`, which describes every
function (:class:`FunctionInfo`) and every input and output (:class:`Port`): shapes,
nonzeros, units and the workspace sizes of the generated ``<f>_SZ_*`` macros.
:func:`densified` is the wrapper ``generate`` puts around functions with sparse ports.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from casflex._validate import identifier
from casflex.codegen.compiler import shared_library_suffix
from casflex.codegen.errors import CodegenError
from casflex.codegen.templates import fused_bspline_source, makefile_text, readme_text

__all__ = ["Port", "FunctionInfo", "Bundle", "generate", "densified"]

#: suffixes CasADi appends to a function name for its helper entry points
_HELPER_SUFFIXES = (
    "_checkout", "_release", "_incref", "_decref", "_n_in", "_n_out", "_default_in",
    "_name_in", "_name_out", "_sparsity_in", "_sparsity_out", "_work", "_work_bytes",
)


@dataclass(frozen=True)
class Port:
    """One input or output of a generated function.

    Attributes
    ----------
    name : str
        Name (from the :class:`casadi.Function`).
    rows, cols : int
        Matrix shape.
    nnz : int
        Number of structural nonzeros: the length of the C array.
    sparsity : tuple of int
        CasADi's compressed pattern ``(rows, cols, colind..., row...)``.
    unit : str or None
        Unit given to :func:`generate` through ``units``.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.SX.sym("x", 3)
    >>> f = ca.Function("scale", [x], [0.5 * x], ["x"], ["y"])
    >>> b = generate([f], tempfile.mkdtemp(), name="demo_p", units={"scale": {"y": "m"}})
    >>> port = b.functions[0].outputs[0]
    >>> port.name, port.rows, port.cols, port.nnz, port.unit, port.numpy_shape
    ('y', 3, 1, 3, 'm', (3,))
    """

    name: str
    rows: int
    cols: int
    nnz: int
    sparsity: tuple[int, ...] = field(repr=False)
    unit: str | None = None

    @property
    def dense(self) -> bool:
        """``True`` when the C array holds the full column-major matrix."""
        return self.nnz == self.rows * self.cols

    @property
    def numpy_shape(self) -> tuple[int, ...]:
        """Shape on the numpy side: ``()`` for a scalar, ``(rows,)`` for a column vector, else
        ``(rows, cols)``."""
        if self.rows == 1 and self.cols == 1:
            return ()
        return (self.rows,) if self.cols == 1 else (self.rows, self.cols)

    def nonzero_index(self) -> np.ndarray:
        """Column-major linear indices (into ``rows * cols``) of the nonzeros, as an array.

        Examples
        --------
        >>> import casadi as ca
        >>> sp = ca.Sparsity.diag(2)   # 2x2 with nonzeros at (0, 0) and (1, 1)
        >>> p = Port("D", 2, 2, sp.nnz(), tuple(int(v) for v in sp.compress()))
        >>> p.nonzero_index().tolist(), p.dense
        ([0, 3], False)
        """
        nrow, ncol = self.sparsity[0], self.sparsity[1]
        colind = self.sparsity[2 : 3 + ncol]
        row = np.asarray(self.sparsity[3 + ncol :], dtype=np.int64)
        col = np.repeat(np.arange(ncol), np.diff(colind))
        return row + nrow * col


@dataclass(frozen=True)
class FunctionInfo:
    """A generated function: its ports and the workspace sizes of its C implementation.

    ``sz_arg``, ``sz_res``, ``sz_iw``, ``sz_w`` are the values of the ``<name>_SZ_ARG``,
    ``<name>_SZ_RES``, ``<name>_SZ_IW`` and ``<name>_SZ_W`` macros of the header.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x, u = ca.SX.sym("x"), ca.SX.sym("u")
    >>> f = ca.Function("acc", [x, u], [x + u], ["x", "u"], ["x_next"])
    >>> info = generate([f], tempfile.mkdtemp(), name="demo_fi").functions[0]
    >>> info.name, [p.name for p in info.inputs], [p.name for p in info.outputs]
    ('acc', ['x', 'u'], ['x_next'])
    >>> info.sz_arg, info.sz_res
    (2, 1)
    """

    name: str
    inputs: tuple[Port, ...]
    outputs: tuple[Port, ...]
    sz_arg: int
    sz_res: int
    sz_iw: int
    sz_w: int

    def port(self, which: str | int, kind: str = "input") -> tuple[int, Port]:
        """Return ``(index, Port)`` of an input (``kind="input"``) or output by name or index.

        Parameters
        ----------
        which : str or int
            Port name, or its 0-based index.
        kind : {"input", "output"}, optional
            Which side to look on.

        Returns
        -------
        tuple of (int, Port)

        Raises
        ------
        CodegenError
            No such port.

        Examples
        --------
        >>> import tempfile, casadi as ca
        >>> x, u = ca.SX.sym("x"), ca.SX.sym("u")
        >>> f = ca.Function("acc", [x, u], [x + u], ["x", "u"], ["x_next"])
        >>> info = generate([f], tempfile.mkdtemp(), name="demo_port").functions[0]
        >>> index, port = info.port("u")
        >>> index, port.name
        (1, 'u')
        >>> info.port(0, kind="output")[1].name
        'x_next'
        """
        ports = self.inputs if kind == "input" else self.outputs
        if isinstance(which, (int, np.integer)) and not isinstance(which, bool):
            if not 0 <= which < len(ports):
                raise CodegenError(
                    f"function '{self.name}' has {len(ports)} {kind}s; {kind} index {which} "
                    "is out of range"
                )
            return int(which), ports[which]
        for i, p in enumerate(ports):
            if p.name == which:
                return i, p
        names = ", ".join(p.name for p in ports)
        raise CodegenError(f"function '{self.name}' has no {kind} '{which}' (its {kind}s: {names})")


@dataclass(frozen=True)
class Bundle:
    """A generated C bundle (returned by :func:`generate`).

    Attributes
    ----------
    name : str
        Bundle name: base name of the files and prefix of CasADi's internal symbols.
    out_dir : pathlib.Path
        Directory holding the files.
    source, header, readme, makefile, manifest : pathlib.Path or None
        The files written (``header`` is ``None`` with ``with_header=False``).
    casadi_real, casadi_int : str
        C types of reals and integers in the generated code.
    functions : tuple of FunctionInfo
        The functions, in the order given.
    static_state : tuple of str
        Declarations of mutable ``static`` data found in the generated source (empty for
        stateless functions).

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("sq", [x], [x * x])], tempfile.mkdtemp(), name="demo_bd")
    >>> b.name, b.source.name, b.library.stem, b.reentrant
    ('demo_bd', 'demo_bd.c', 'libdemo_bd', True)
    """

    name: str
    out_dir: Path
    source: Path
    header: Path | None
    readme: Path
    makefile: Path
    manifest: Path
    casadi_real: str
    casadi_int: str
    functions: tuple[FunctionInfo, ...]
    static_state: tuple[str, ...] = field(default=())

    @property
    def reentrant(self) -> bool:
        """``True`` when no mutable static data exists: per-thread workspaces suffice."""
        return not self.static_state

    @property
    def library(self) -> Path:
        """Path :func:`casflex.codegen.build` writes the shared library to by default."""
        return self.out_dir / f"lib{self.name}{shared_library_suffix()}"

    def function(self, name: str) -> FunctionInfo:
        """Return the :class:`FunctionInfo` called ``name`` or raise :class:`CodegenError`.

        Parameters
        ----------
        name : str
            Function name.

        Returns
        -------
        FunctionInfo

        Examples
        --------
        >>> import tempfile, casadi as ca
        >>> x = ca.SX.sym("x", 2)
        >>> b = generate([ca.Function("sq", [x], [x * x])], tempfile.mkdtemp(), name="demo_fn")
        >>> b.function("sq").inputs[0].rows
        2
        """
        for info in self.functions:
            if info.name == name:
                return info
        names = ", ".join(f.name for f in self.functions)
        raise CodegenError(f"bundle '{self.name}' has no function '{name}' (it has: {names})")



def densified(f: ca.Function) -> ca.Function:
    """``f`` itself, or a wrapper of the same name and ports whose inputs and outputs are
    all dense (what :func:`generate` generates with ``dense=True``).

    Parameters
    ----------
    f : casadi.Function
        SX or MX function.

    Returns
    -------
    casadi.Function
        ``f`` when all its ports are dense, else a function of the same kind (SX or MX)
        whose structurally sparse ports are stored as full matrices.

    Examples
    --------
    >>> import casadi as ca
    >>> x = ca.SX.sym("x", 3)
    >>> jac = ca.Function("jacx", [x], [ca.jacobian(x * x, x)], ["x"], ["J"])
    >>> jac.nnz_out(0), densified(jac).nnz_out(0), densified(jac).name()
    (3, 9, 'jacx')
    >>> sq = ca.Function("sq", [x], [x * x])
    >>> densified(sq) is sq   # dense already: returned as is
    True
    """
    sparse_in = any(not f.sparsity_in(i).is_dense() for i in range(f.n_in()))
    sparse_out = any(not f.sparsity_out(i).is_dense() for i in range(f.n_out()))
    if not (sparse_in or sparse_out):
        return f
    sym = ca.SX.sym if f.is_a("SXFunction") else ca.MX.sym
    args = [sym(f.name_in(i), f.size1_in(i), f.size2_in(i)) for i in range(f.n_in())]
    outs = f.call(args)
    outs = [ca.densify(o) for o in outs]
    return ca.Function(f.name(), args, outs, f.name_in(), f.name_out())


def _ports(f, kind, units):
    """The :class:`Port` of every input (``kind="input"``) or output of ``f``."""
    n = f.n_in() if kind == "input" else f.n_out()
    ports = []
    for i in range(n):
        if kind == "input":
            name, sp = f.name_in(i), f.sparsity_in(i)
        else:
            name, sp = f.name_out(i), f.sparsity_out(i)
        ports.append(
            Port(name, sp.size1(), sp.size2(), sp.nnz(), tuple(int(v) for v in sp.compress()),
                 units.get(name))
        )
    return tuple(ports)


def _read_sizes(header_text, name):
    """``{"ARG", "RES", "IW", "W"}`` from the header's ``<name>_SZ_*`` macros (or ``None``)."""
    sizes = {}
    for key in ("ARG", "RES", "IW", "W"):
        m = re.search(rf"^#define {re.escape(name)}_SZ_{key} (\d+)\s*$", header_text, re.M)
        if m is None:
            return None
        sizes[key] = int(m.group(1))
    return sizes


def _static_state(source_text):
    """Mutable static declarations in generated C (static data that is not ``const``)."""
    found = []
    for line in source_text.splitlines():
        s = line.strip()
        if s.startswith("static ") and not s.startswith("static const") and "(" not in s:
            found.append(s)
    return tuple(found)


_TABLE = re.compile(r"(static const casadi_real casadi_c\d+\[\d+\] = )\s*\{([^}]*)\};")


def _compact_tables(source_text):
    """The source with every constant table written in the shortest decimal form that
    reads back to the same double (``repr``), 16 numbers a line: CasADi writes ``%.16e``,
    e.g. ``-3.1415926535897931e+00``; the values, hence the compiled code, are unchanged.
    Tables with a non-finite entry are left as CasADi wrote them."""

    def shorter(match):
        values = [float(v) for v in match.group(2).split(",") if v.strip()]
        if not all(math.isfinite(v) for v in values):
            return match.group(0)
        text = [repr(v) for v in values]
        lines = [", ".join(text[i:i + 16]) for i in range(0, len(text), 16)]
        return match.group(1) + "{\n  " + ",\n  ".join(lines) + "};"

    return _TABLE.sub(shorter, source_text)


def generate(functions: ca.Function | Sequence[ca.Function], out_dir: str | os.PathLike,
             name: str = "casflex_rt", with_header: bool = True, *,
             casadi_real: str = "double", casadi_int: str = "long long int",
             dense: bool = True,
             units: Mapping[str, Mapping[str, str]] | None = None) -> Bundle:
    """Generate one C bundle (source, header, README, Makefile, manifest) from functions.

    Parameters
    ----------
    functions : sequence of casadi.Function
        Functions to generate (SX or MX; interpolants and Jacobians of B-splines are generated
        directly, without ``expand``). Names must be distinct C identifiers; they become the
        exported C symbols, so bundles linked into one program need distinct function names.
    out_dir : str or pathlib.Path
        Directory to write to (created if missing). Existing files of the same name are
        overwritten.
    name : str, optional
        Bundle name: files ``<name>.c``, ``<name>.h``, ``<name>.json`` and the prefix of
        CasADi's internal symbols (``<name>_casadi_version`` ...), so several bundles coexist.
    with_header : bool, optional
        Write ``<name>.h`` with the prototypes and the ``<f>_SZ_*`` workspace macros.
    casadi_real, casadi_int : str, optional
        C types of reals and integers. :func:`casflex.codegen.load` needs the defaults (``double``,
        ``long long int``), which are what CasADi's own loader expects.
    dense : bool, optional
        Wrap functions with structurally sparse inputs/outputs so that every C array holds a
        full column-major matrix (default). With ``False`` arrays hold the nonzeros only.
    units : dict, optional
        ``{function name: {input or output name: unit string}}`` documented in the README.

    Returns
    -------
    Bundle

    Raises
    ------
    CodegenError
        Empty list, non-Function item, duplicate or invalid names, unknown names in
        ``units``, a function with free symbols, or a CasADi code-generation failure.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> x = ca.SX.sym("x", 2)
    >>> f = ca.Function("twice", [x], [2 * x], ["x"], ["y"])
    >>> b = generate([f], tempfile.mkdtemp(), name="demo", units={"twice": {"x": "m"}})
    >>> b.source.name, b.header.name, b.functions[0].inputs[0].unit
    ('demo.c', 'demo.h', 'm')
    >>> b.reentrant
    True
    """
    if isinstance(functions, ca.Function):
        functions = [functions]
    functions = list(functions)
    if not functions:
        raise CodegenError("generate: 'functions' is empty; give at least one casadi.Function")
    identifier(name, "bundle name", error=CodegenError)
    units = {} if units is None else dict(units)
    seen = set()
    for k, f in enumerate(functions):
        if not isinstance(f, ca.Function):
            raise CodegenError(
                f"generate: functions[{k}] is a {type(f).__name__}, not a casadi.Function"
            )
        identifier(f.name(), f"function name (functions[{k}])", error=CodegenError)
        if f.name() in seen:
            raise CodegenError(f"generate: two functions are called '{f.name()}'")
        seen.add(f.name())
        if f.has_free():
            free = f.get_free()
            raise CodegenError(
                f"generate: function '{f.name()}' has free symbols {free}; "
                "make them inputs before generating C"
            )
    for f in functions:
        for suffix in _HELPER_SUFFIXES:
            if f.name() + suffix in seen:
                raise CodegenError(
                    f"generate: function name '{f.name() + suffix}' clashes with the helper "
                    f"'{suffix}' CasADi generates for '{f.name()}'"
                )
    for fname, table in units.items():
        if fname not in seen:
            raise CodegenError(f"generate: units given for unknown function '{fname}'")
        f = next(g for g in functions if g.name() == fname)
        known = set(f.name_in()) | set(f.name_out())
        for port in table:
            if port not in known:
                raise CodegenError(
                    f"generate: units['{fname}'] names '{port}', which is no input or output "
                    f"of '{fname}' ({', '.join(sorted(known))})"
                )
    if dense:
        functions = [densified(f) for f in functions]

    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    opts = {
        "with_header": bool(with_header),
        "casadi_real": casadi_real,
        "casadi_int": casadi_int,
        "main": False,
        "mex": False,
        "prefix": name,
        "verbose": True,
    }
    try:
        cg = ca.CodeGenerator(name, opts)
        for f in functions:
            cg.add(f)
        cg.generate(str(out_dir) + os.sep)
    except RuntimeError as exc:
        raise CodegenError(
            f"generate: CasADi code generation of bundle '{name}' failed: {exc}"
        ) from exc

    source = out_dir / f"{name}.c"
    header = out_dir / f"{name}.h" if with_header else None
    source_text = fused_bspline_source(_compact_tables(source.read_text()))
    source.write_text(source_text)
    header_text = header.read_text() if header is not None else ""
    infos = []
    for f in functions:
        sizes = _read_sizes(header_text, f.name()) if header is not None else None
        if sizes is None:
            sizes = {"ARG": f.sz_arg(), "RES": f.sz_res(), "IW": f.sz_iw(), "W": f.sz_w()}
        table = units.get(f.name(), {})
        infos.append(
            FunctionInfo(f.name(), _ports(f, "input", table), _ports(f, "output", table),
                         sizes["ARG"], sizes["RES"], sizes["IW"], sizes["W"])
        )
    bundle = Bundle(
        name=name,
        out_dir=out_dir,
        source=source,
        header=header,
        readme=out_dir / "README.md",
        makefile=out_dir / "Makefile",
        manifest=out_dir / f"{name}.json",
        casadi_real=casadi_real,
        casadi_int=casadi_int,
        functions=tuple(infos),
        static_state=_static_state(source_text),
    )
    bundle.readme.write_text(readme_text(bundle))
    bundle.makefile.write_text(makefile_text(bundle))
    bundle.manifest.write_text(json.dumps(_manifest(bundle), indent=2) + "\n")
    return bundle



def _manifest(bundle):
    """The machine-readable description written to ``<name>.json``."""
    return {
        "bundle": bundle.name,
        "prefix": bundle.name,
        "casadi_version": ca.__version__,
        "casadi_real": bundle.casadi_real,
        "casadi_int": bundle.casadi_int,
        "reentrant": bundle.reentrant,
        "static_state": list(bundle.static_state),
        "functions": [
            {
                "name": f.name,
                "sz_arg": f.sz_arg, "sz_res": f.sz_res, "sz_iw": f.sz_iw, "sz_w": f.sz_w,
                "inputs": [_port_dict(p) for p in f.inputs],
                "outputs": [_port_dict(p) for p in f.outputs],
            }
            for f in bundle.functions
        ],
    }


def _port_dict(p):
    return {"name": p.name, "rows": p.rows, "cols": p.cols, "nnz": p.nnz, "unit": p.unit}
