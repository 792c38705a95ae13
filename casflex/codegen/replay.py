"""Replay recorded data through one generated function, in C: the harness program.

:func:`harness` writes a small C program that calls one function of a bundle in a loop
over recorded data, with state feedback (output ``k`` of step ``n`` becomes input ``j``
of step ``n + 1``, e.g. an EKF's ``x⁺, P⁺``), and times each call inside C;
:func:`run_harness` compiles and runs it on numpy arrays and returns a
:class:`HarnessResult`. The data file format is described in :mod:`casflex.codegen`.
"""

from __future__ import annotations

import json
import os
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import number
from casflex.codegen.bundle import Bundle
from casflex.codegen.compiler import find_compiler, run_compiler
from casflex.codegen.errors import BuildError, CodegenError
from casflex.codegen.templates import (
    HARNESS_INPUT_MAGIC,
    HARNESS_OUTPUT_MAGIC,
    harness_source,
)

__all__ = ["HarnessResult", "harness", "run_harness"]


@dataclass(frozen=True)
class HarnessResult:
    """Result of :func:`run_harness`.

    Attributes
    ----------
    outputs : dict of str to numpy.ndarray
        Every output over the steps, shape ``(n_steps,) + port.numpy_shape``.
    timing : dict or None
        The JSON object printed by the harness (``median_step_ns``, ``mean_step_ns``,
        ``min_step_ns``, ``max_step_ns``, ``timer_overhead_ns``, ``steps``, ``repeat``);
        ``None`` with ``timing=False``.
    executable : pathlib.Path
        The compiled harness.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> from casflex.codegen import generate
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("sq", [x], [x * x], ["x"], ["y"])], tempfile.mkdtemp(),
    ...              name="demo_hr")
    >>> r = run_harness(b, "sq", {"x": [1.0, 2.0]}, timing=False, flags=("-O1",))
    >>> r.outputs["y"].tolist(), r.timing, r.executable.name
    ([1.0, 4.0], None, 'harness_sq')
    """

    outputs: dict[str, np.ndarray]
    timing: dict | None
    executable: Path


def _feedback_pairs(info, feedback):
    """Validate ``feedback`` and return ``[(out_index, in_index), ...]``."""
    pairs = []
    if not feedback:
        return pairs
    items = feedback.items() if isinstance(feedback, dict) else feedback
    used_in = set()
    for out, inp in items:
        k, po = info.port(out, "output")
        j, pi = info.port(inp, "input")
        if j in used_in:
            raise CodegenError(f"harness: input '{pi.name}' of '{info.name}' is fed back twice")
        used_in.add(j)
        if po.sparsity != pi.sparsity:
            raise CodegenError(
                f"harness: output '{po.name}' ({po.rows}x{po.cols}, {po.nnz} nonzeros) of "
                f"'{info.name}' cannot feed input '{pi.name}' ({pi.rows}x{pi.cols}, "
                f"{pi.nnz} nonzeros): the sparsity patterns differ"
            )
        pairs.append((k, j))
    return pairs


def harness(bundle: Bundle, function_name: str,
            feedback: Mapping | Sequence[tuple[str | int, str | int]] | None = None, *,
            timing: bool = True) -> Path:
    """Write a C program that runs one function of a bundle over recorded data.

    The program (``<out_dir>/harness_<function>.c``) reads a data file (format in
    :mod:`casflex.codegen`), calls the function once per step with fixed-size static
    workspaces sized by the generated ``<f>_SZ_*`` macros, copies output ``k`` into input
    ``j`` after each step for every feedback pair, writes every output of every step, and,
    with ``timing``, measures each call with ``clock_gettime(CLOCK_MONOTONIC)`` and prints
    one JSON object: ``median_step_ns``, ``mean_step_ns``, ``min_step_ns``,
    ``max_step_ns`` (over all steps of all repetitions) and ``timer_overhead_ns`` (median
    of an empty timing pair, not subtracted). Input buffers are read once before the
    loop; nothing is allocated or written to a file inside it.

    Parameters
    ----------
    bundle : casflex.codegen.Bundle
        From :func:`casflex.codegen.generate`.
    function_name : str
        Function to run.
    feedback : dict, optional
        ``{output: input}`` (names or indices): output ``k`` of step ``n`` becomes input
        ``j`` of step ``n + 1``; their sparsity patterns must be equal. Fed-back inputs take
        their step-0 value from the data file's initial values.
    timing : bool, optional
        Time each call inside C.

    Returns
    -------
    pathlib.Path
        The C file. Compile it with the bundle's source:
        ``cc -O3 -ffp-contract=off -o harness_<f> harness_<f>.c <name>.c -lm`` (the
        bundle's ``BUNDLE_CFLAGS``; or ``make harness_<f>``).

    Raises
    ------
    CodegenError
        Unknown function, input or output, or incompatible feedback pair.

    Examples
    --------
    >>> import tempfile, casadi as ca
    >>> from casflex.codegen import generate
    >>> x, u = ca.SX.sym("x"), ca.SX.sym("u")
    >>> f = ca.Function("acc", [x, u], [x + u], ["x", "u"], ["x_next"])
    >>> b = generate([f], tempfile.mkdtemp(), name="demo_h")
    >>> harness(b, "acc", feedback={"x_next": "x"}).name
    'harness_acc.c'
    """
    info = bundle.function(function_name)
    pairs = _feedback_pairs(info, feedback)
    path = bundle.out_dir / f"harness_{info.name}.c"
    path.write_text(harness_source(bundle, info, pairs, timing))
    return path


def _as_nonzeros(value, port, n_rows, what):
    """``value`` (leading dimension n_rows, then the port's shape) -> (n_rows, nnz)."""
    arr = np.asarray(value, dtype=float)
    size = port.rows * port.cols
    if arr.size != n_rows * size:
        raise CodegenError(
            f"{what} '{port.name}' must hold {n_rows} x {port.rows} x {port.cols} numbers "
            f"(shape ({n_rows}, {port.rows}, {port.cols})), got shape {arr.shape}"
        )
    mat = arr.reshape(n_rows, port.rows, port.cols).transpose(0, 2, 1).reshape(n_rows, size)
    return mat[:, port.nonzero_index()]


def _from_nonzeros(nz, port):
    """(n_rows, nnz) nonzeros -> dense arrays of shape ``(n_rows,) + port.numpy_shape``."""
    n_rows = nz.shape[0]
    full = np.zeros((n_rows, port.rows * port.cols))
    full[:, port.nonzero_index()] = nz
    full = full.reshape(n_rows, port.cols, port.rows).transpose(0, 2, 1)
    return full.reshape((n_rows,) + port.numpy_shape)


def _fmt_row(values):
    """One line of a data file: every number with 17 significant digits (``repr``)."""
    return " ".join(repr(float(v)) for v in values)


def run_harness(bundle: Bundle, function_name: str,
                inputs: Mapping[str, ArrayLike] | None = None,
                initial: Mapping[str, ArrayLike] | None = None,
                feedback: Mapping | Sequence[tuple[str | int, str | int]] | None = None, *,
                steps: int | None = None, repeat: int = 1, timing: bool = True,
                compiler: str | Sequence[str] | None = None, flags: Sequence[str] = ("-O2",),
                workdir: str | os.PathLike | None = None) -> HarnessResult:
    """Compile and run the harness of one function on numpy data; return the outputs.

    Parameters
    ----------
    bundle : casflex.codegen.Bundle
        From :func:`casflex.codegen.generate`.
    function_name : str
        Function to run.
    inputs : dict, optional
        ``{input name: array}`` for every input that is not fed back, shape
        ``(n_steps,) + shape`` (a column vector may be ``(n_steps, rows)``, a scalar
        ``(n_steps,)``). Sparse inputs are given dense; their structural zeros are ignored.
    initial : dict, optional
        ``{input name: array}``: step-0 value of every fed-back input.
    feedback : dict, optional
        ``{output: input}``, see :func:`harness`.
    steps : int, optional
        Number of steps; needed only when every input is fed back.
    repeat : int, optional
        Run the whole loop this many times (from the same initial values) for timing.
    timing : bool, optional
        Time the calls inside C.
    compiler, flags
        As for :func:`casflex.codegen.build`.
    workdir : str or pathlib.Path, optional
        Where the data files go; default ``bundle.out_dir``.

    Returns
    -------
    HarnessResult

    Raises
    ------
    CodegenError
        Missing, unknown or wrongly-sized inputs.
    BuildError
        Compilation failed, or the harness exited with an error.

    Examples
    --------
    >>> import tempfile, casadi as ca, numpy as np
    >>> from casflex.codegen import generate
    >>> x, u = ca.SX.sym("x"), ca.SX.sym("u")
    >>> f = ca.Function("acc", [x, u], [x + u], ["x", "u"], ["x_next"])
    >>> b = generate([f], tempfile.mkdtemp(), name="demo_r")
    >>> r = run_harness(b, "acc", {"u": [1.0, 2.0, 3.0]}, {"x": 10.0},
    ...                 feedback={"x_next": "x"}, flags=("-O1",))
    >>> r.outputs["x_next"]
    array([11., 13., 16.])
    >>> r.timing["steps"]
    3
    """
    info = bundle.function(function_name)
    pairs = _feedback_pairs(info, feedback)
    fb = sorted({j for _, j in pairs})
    ext = [j for j in range(len(info.inputs)) if j not in fb]
    inputs = {} if inputs is None else dict(inputs)
    initial = {} if initial is None else dict(initial)
    ext_names = {info.inputs[j].name for j in ext}
    fb_names = {info.inputs[j].name for j in fb}
    for key in inputs:
        if key not in ext_names:
            why = "is fed back (give it in 'initial')" if key in fb_names else "is not an input"
            raise CodegenError(f"run_harness: inputs['{key}'] of '{info.name}' {why}")
    for key in initial:
        if key not in fb_names:
            raise CodegenError(
                f"run_harness: initial['{key}'] given, but '{key}' is no fed-back input of "
                f"'{info.name}' (fed back: {', '.join(sorted(fb_names)) or 'none'})"
            )
    missing = [info.inputs[j].name for j in ext if info.inputs[j].name not in inputs]
    missing += [info.inputs[j].name for j in fb if info.inputs[j].name not in initial]
    if missing:
        raise CodegenError(f"run_harness: no data for input(s) {missing} of '{info.name}'")
    if steps is None:
        if not ext:
            raise CodegenError("run_harness: every input is fed back; give 'steps'")
        first = np.asarray(inputs[info.inputs[ext[0]].name])
        steps = first.shape[0] if first.ndim else 1
    steps = number(steps, "steps", low=1, integer=True, error=CodegenError)
    repeat = number(repeat, "repeat", low=1, integer=True, error=CodegenError)

    ext_data = [_as_nonzeros(inputs[info.inputs[j].name], info.inputs[j], steps, "input")
                for j in ext]
    data = np.hstack(ext_data) if ext_data else np.zeros((steps, 0))
    init = np.concatenate(
        [_as_nonzeros(initial[info.inputs[j].name], info.inputs[j], 1, "initial value")[0]
         for j in fb]
    ) if fb else np.zeros(0)

    src = harness(bundle, function_name, feedback=feedback, timing=timing)
    exe = bundle.out_dir / f"harness_{info.name}"
    cc = find_compiler(compiler)
    run_compiler(
        [*cc, *flags, "-I", str(bundle.out_dir), "-o", str(exe), str(src), str(bundle.source),
         "-lm"],
        bundle.out_dir,
    )
    work = Path(workdir).resolve() if workdir is not None else bundle.out_dir
    work.mkdir(parents=True, exist_ok=True)
    in_path = work / f"harness_{info.name}_input.txt"
    out_path = work / f"harness_{info.name}_output.txt"
    with open(in_path, "w") as fh:
        fh.write(f"{HARNESS_INPUT_MAGIC} {steps} {data.shape[1]} {init.size}\n")
        fh.write(_fmt_row(init) + "\n")
        for row in data:
            fh.write(_fmt_row(row) + "\n")
    try:
        proc = subprocess.run([str(exe), str(in_path), str(out_path), str(int(repeat))],
                              capture_output=True, text=True, timeout=3600)
    except OSError as exc:
        raise BuildError(f"run_harness: could not run '{exe}': {exc}") from exc
    if proc.returncode != 0:
        raise BuildError(
            f"run_harness: '{exe.name}' exited with status {proc.returncode}: "
            f"{proc.stderr.strip()[-2000:]}"
        )
    tokens = out_path.read_text().split()
    if len(tokens) < 3 or tokens[0] != HARNESS_OUTPUT_MAGIC:
        raise BuildError(f"run_harness: '{out_path}' is not a harness output file")
    n_steps, n_cols = int(tokens[1]), int(tokens[2])
    values = np.array([float(t) for t in tokens[3:]], dtype=float)
    if values.size != n_steps * n_cols:
        raise BuildError(f"run_harness: '{out_path}' is truncated")
    values = values.reshape(n_steps, n_cols)
    outputs, col = {}, 0
    for p in info.outputs:
        outputs[p.name] = _from_nonzeros(values[:, col : col + p.nnz], p)
        col += p.nnz
    timing_info = json.loads(proc.stdout) if timing else None
    return HarnessResult(outputs=outputs, timing=timing_info, executable=exe)
