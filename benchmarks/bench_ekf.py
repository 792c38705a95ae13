"""Time one EKF step for the Table 8 arm (3 modes, two three-axis accelerometers).

Three implementations of the same step (casflex.estimation.ekf_step_function):

* ``c_step_us``: the generated C code in the casflex.codegen harness, timed inside C
  (median over all steps of all repetitions, fed-back x and P), run ``--runs`` times
  (default 7): the median of the runs' medians, each run's figure in
  ``c_step_us_runs`` (on this shared machine whole runs land in quiet or busy spells);
* ``python_step_us``: the CasADi function called from Python (median per call);
* ``numpy_step_us``: a plain numpy EKF step with the same equations and no CasADi call
  in it (``numpy_step_factory``): the plant coefficients and the measurement with its
  Jacobian are translated once from their SX operation lists into Python code on floats,
  their B-spline tables into numpy piecewise cubics; the filter is numpy matrix algebra.
  Its estimates are asserted equal to the CasADi step's within ``NUMPY_RTOL``;
  ``numpy_vs_c_ratio = numpy_step_us / c_step_us``.

The step is that of the second-order plant (``tabulate_plant(order=2)``, Fourier
coefficients pruned with the default ``prune=1e-6``) with ``jacobians="first_order"``,
the sequential scalar updates (``update="auto"``: R is diagonal; standard form ``P − k
bᵀ``, ``joseph=False``), the RK4 transition matrix in closed form and the sensor-entry
tables of the measurement (``lean=True``), the plant's table and the sensor entries with
their rates in one lookup function (``shared=True``, :mod:`casflex.estimation.lookup`), the
accelerometers by the recursive pass over their pose's factors (``recursive=True``),
compiled with ``-O3 -march=native
-ffp-contract=off`` (no FMA contraction: within 1e-10 of Python,
tests/codegen/test_codegen_ekf.py; options below). ``--compare`` also times, in the same run, the
configurations listed in ``VARIANTS`` (the step before these changes among them): key
``variants``.

Usage: ``python benchmarks/bench_ekf.py [--json] [--steps 2000] [--repeat 5] [--step-deg 7.5]
[--runs 7] [--order 2] [--jacobians first_order] [--update auto]
[--flags "-O3 -march=native -ffp-contract=off"] [--compare [--rounds 3]] [--guarded] [--lookups]
[--forms] [--recursive] [--shared] [--peak]
[--callgrind [--callgrind-flags "-O3 -march=x86-64-v3 -ffp-contract=off"]]``

``--callgrind`` also counts the machine instructions of one step (valgrind's callgrind,
``--toggle-collect=ekf_step``, one pass over the data): ``instructions_per_step``, a
figure the machine's load does not change, ``instruction_limit_us``, that count at
``ISSUE_WIDTH`` (4) instructions per cycle of the clock, the best any schedule reaches,
and ``implied_ipc``, the instructions per cycle the timed median implies. Valgrind does
not run AVX-512 code, so the counted build uses ``--callgrind-flags`` (AVX2);
``CASFLEX_CALLGRIND_KEEP=PATH`` keeps callgrind's output for ``callgrind_annotate``.

``--lookups`` also times (and with ``--callgrind`` counts) the step with the plant's
spline table and the measurement's sensor-entry tables evaluated by ``casadi.interpolant``
(CasADi's de Boor routine, the code before) and locally
(:mod:`casflex.modal.table_functions`, the default), interleaved over ``--rounds``: key
``lookups`` (and ``max_rel_dev``, the estimates' largest difference).

``--forms`` the same for the scalar covariance updates in Joseph form (``joseph=True``,
the step of session 8) and in standard form (the default): key ``forms``.

``--peak`` also measures this machine's scalar double-precision peak in a tight loop (16
independent multiply-add chains, unfused, in CPU time, best of 5 runs: ``peak_ops_per_ns``),
its running clock (a chain of dependent integer adds, one cycle each:
``clock_ghz_measured``) and the step's operations at that peak
(``flop_limit_measured_us``), the measured counterpart of ``flop_limit_us`` (two operations
per cycle at the nominal clock of /proc/cpuinfo).

``--recursive`` the same for the accelerometer signals as time derivatives of the whole
sensor pose (``recursive=False``, the step of session 9) and by the recursive pass over
the pose's factors (the default, ``casflex.sensors.kinematic_measurement``): key
``recursive``.

``--shared`` the same for the step's tables looked up one by one, the sensor entries'
rates by differentiation (``shared=False``, the step of session 10) and in one lookup
function (the default, :mod:`casflex.estimation.lookup`): key ``shared``.

``--guarded`` also times the guarded step (``casflex.estimation.Guard``: non-finite checks,
innovation gate, covariance bounds) against the plain one, interleaved over ``--rounds``
rounds in the same run: key ``guarded`` (``c_step_us`` of both, ``cost_ratio``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from casflex.simulate.integrators import rk4_step

ROOT = Path(__file__).resolve().parents[1]

#: largest relative deviation of the numpy baseline's estimates from the CasADi step's
#: (round-off of ~10⁴ operations per step, amplified by the update; measured ≤ 1e-14)
NUMPY_RTOL = 1e-10
NATIVE = "-O3 -march=native -ffp-contract=off"
#: instructions per cycle a recent x86 core sustains at best (4-wide issue): with the
#: instruction count, the ``instruction_limit_us`` of the step
ISSUE_WIDTH = 4
#: the build counted by ``--callgrind``: NATIVE for AVX2 machines (valgrind has no AVX-512)
CALLGRIND_FLAGS = "-O3 -march=x86-64-v3 -ffp-contract=off"
FIRST = {"jacobians": "first_order"}
BEFORE = {"jacobians": "first_order", "update": "batch", "lean": False, "recursive": False}
POSE = {"jacobians": "first_order", "recursive": False}  # the step of session 9
# (label, plant order, pruned plant, ekf_step_function options, compiler flags)
VARIANTS = [
    ("first-order plant, exact, no cse, batch, full tables, -O2", 1, False,
     {"jacobians": "exact", "cse": False, "update": "batch", "lean": False,
      "recursive": False}, "-O2"),
    ("before: order 2, first_order, batch, full tables", 2, False, BEFORE, NATIVE),
    ("+ pruned plant", 2, True, BEFORE, NATIVE),
    ("+ sensor-entry tables", 2, True, {**POSE, "update": "batch"}, NATIVE),
    ("+ sequential update", 2, True, POSE, NATIVE),
    ("+ recursive accelerometers (default)", 2, True, FIRST, NATIVE),
    ("default, jacobians=linearized", 2, True, {"jacobians": "linearized"}, NATIVE),
    ("default, jacobians=exact", 2, True, {"jacobians": "exact"}, NATIVE),
    ("default, -O2", 2, True, FIRST, "-O2"),
    ("default, -O3 -march=native -fno-math-errno -fno-trapping-math", 2, True, FIRST,
     NATIVE + " -fno-math-errno -fno-trapping-math"),
    # FMA contraction: faster still, but far from Python on random inputs (not 1e-10)
    ("default, -O3 -march=native (FMA)", 2, True, FIRST, "-O3 -march=native"),
]


# ------------------------------------------------------------------ plain numpy baseline
# CasADi is used once, when the step is built: the plant coefficients and the measurement
# with its Jacobian are translated from their (expanded) SX operation lists into straight
# Python code on floats, and the B-spline tables they call into numpy piecewise cubics
# (Taylor coefficients at each grid interval's midpoint). The step itself makes no CasADi
# call: numpy matrix algebra for the filter, Python floats for the model functions.

_UNARY = {ca.OP_NEG: "-{0}", ca.OP_SQ: "{0}*{0}", ca.OP_TWICE: "2.0*{0}",
          ca.OP_SIN: "_m.sin({0})", ca.OP_COS: "_m.cos({0})", ca.OP_TAN: "_m.tan({0})",
          ca.OP_EXP: "_m.exp({0})", ca.OP_LOG: "_m.log({0})", ca.OP_SQRT: "_m.sqrt({0})",
          ca.OP_FLOOR: "float(_m.floor({0}))", ca.OP_CEIL: "float(_m.ceil({0}))",
          ca.OP_FABS: "abs({0})", ca.OP_INV: "1.0/{0}", ca.OP_NOT: "float(not {0})",
          ca.OP_ASSIGN: "{0}"}
_BINARY = {ca.OP_ADD: "{0}+{1}", ca.OP_SUB: "{0}-{1}", ca.OP_MUL: "{0}*{1}",
           ca.OP_DIV: "{0}/{1}", ca.OP_POW: "{0}**{1}", ca.OP_CONSTPOW: "{0}**{1}",
           ca.OP_LT: "float({0}<{1})", ca.OP_LE: "float({0}<={1})",
           ca.OP_EQ: "float({0}=={1})", ca.OP_NE: "float({0}!={1})",
           ca.OP_AND: "float(bool({0}) and bool({1}))",
           ca.OP_OR: "float(bool({0}) or bool({1}))",
           ca.OP_IF_ELSE_ZERO: "({1} if {0} else 0.0)", ca.OP_FMIN: "min({0},{1})",
           ca.OP_FMAX: "max({0},{1})", ca.OP_ATAN2: "_m.atan2({0},{1})"}


class PiecewiseCubic:
    """A 1-D cubic B-spline interpolant of CasADi (one input, a vector out) as numpy
    piecewise cubics on ``breaks``: value and first/second derivative at a point."""

    def __init__(self, spline: ca.Function, breaks: np.ndarray):
        x = ca.MX.sym("x")
        f = spline(x)
        d1 = ca.jacobian(f, x)
        d2 = ca.jacobian(d1, x)
        d3 = ca.jacobian(d2, x)
        taylor = ca.Function("taylor", [x], [f, d1, d2, d3])
        self.breaks = np.asarray(breaks, dtype=float)
        self.mid = 0.5 * (self.breaks[1:] + self.breaks[:-1])
        c = [np.asarray(v) for v in taylor.map(self.mid.size)(self.mid)]
        # rows: intervals; columns: outputs; p(x) = c0 + c1 d + c2 d² + c3 d³, d = x - mid
        self.c = [c[0].T, c[1].T, c[2].T / 2.0, c[3].T / 6.0]

    def _piece(self, x):
        i = min(max(int(np.searchsorted(self.breaks, x, side="right")) - 1, 0),
                self.mid.size - 1)
        return i, x - self.mid[i]

    def value(self, x):
        i, d = self._piece(x)
        c0, c1, c2, c3 = (c[i] for c in self.c)
        return c0 + d * (c1 + d * (c2 + d * c3))

    def derivative(self, x):
        i, d = self._piece(x)
        _, c1, c2, c3 = (c[i] for c in self.c)
        return c1 + d * (2.0 * c2 + d * 3.0 * c3)

    def second_derivative(self, x):
        i, d = self._piece(x)
        return 2.0 * self.c[2][i] + 6.0 * d * self.c[3][i]


def numpy_call(fun: ca.Function, breaks: np.ndarray, splines: dict):
    """A numpy evaluation of a call node of the step: a B-spline interpolant, its first
    forward derivative ``f'(x) s`` or its second ``f''(x) s s₂ + f'(x) s₂'`` (the forms
    CasADi's forward mode produces; checked against CasADi where the step is built)."""
    base = fun.name()
    for prefix in ("fwd1_fwd1_", "fwd1_"):
        base = base.removeprefix(prefix)
    if base not in splines:
        raise ValueError(f"no numpy form for the call node {fun.name()!r}")
    sp = splines[base]
    if fun.name().startswith("fwd1_fwd1_"):
        def call(x, s, s2, s2d):
            return sp.second_derivative(x) * (s * s2) + sp.derivative(x) * s2d
    elif fun.name().startswith("fwd1_"):
        def call(x, s):
            return sp.derivative(x) * s
    else:
        def call(x):
            return sp.value(x)
    return call


def sx_to_python(fun: ca.Function, breaks: np.ndarray):
    """Translate an SX function into Python code on floats (its B-spline call nodes into
    :class:`PiecewiseCubic`): ``f(*inputs) -> list of dense numpy outputs``."""
    fun = fun.expand() if not fun.is_a("SXFunction") else fun
    sx = fun.instructions_sx()
    calls = {}
    # the B-spline interpolants called (their derivatives' call nodes name them)
    splines = {}
    for k in range(fun.n_instructions()):
        if fun.instruction_id(k) == ca.OP_CALL:
            g = sx[k].which_function()
            # casadi.interpolant's B-splines and the same splines evaluated locally
            # (casflex.modal.table_functions, named "<table>_local")
            spline = g.class_name() == "BSplineInterpolant" or g.name().endswith("_local")
            if spline and g.name() not in splines:
                splines[g.name()] = PiecewiseCubic(g, breaks)
    lines = [f"o{i} = [0.0] * {fun.nnz_out(i)}" for i in range(fun.n_out())]
    for k in range(fun.n_instructions()):
        op, ins, res = fun.instruction_id(k), fun.instruction_input(k), \
            fun.instruction_output(k)
        w = [f"w{i}" for i in ins]
        if op == ca.OP_INPUT:
            lines.append(f"w{res[0]} = a{ins[0]}[{ins[1]}]")
        elif op == ca.OP_OUTPUT:
            # now: CasADi reuses the work slot afterwards
            lines.append(f"o{res[0]}[{res[1]}] = w{ins[0]}")
        elif op == ca.OP_CONST:
            lines.append(f"w{res[0]} = {float(fun.instruction_constant(k))!r}")
        elif op == ca.OP_CALL:
            g = sx[k].which_function()
            calls[k] = numpy_call(g, breaks, splines)
            _check_call(g, calls[k])
            targets = ", ".join(f"w{r}" if r >= 0 else "_" for r in res)
            lines.append(f"{targets}, = c{k}({', '.join(w)})")
        elif op in _UNARY:
            lines.append(f"w{res[0]} = " + _UNARY[op].format(*w))
        elif op in _BINARY:
            lines.append(f"w{res[0]} = " + _BINARY[op].format(*w))
        else:
            raise ValueError(f"operation {op} of {fun.name()} has no Python form")
    ret = [f"o{i}" for i in range(fun.n_out())]
    args = ", ".join(f"a{i}" for i in range(fun.n_in()))
    src = f"def f({args}):\n    " + "\n    ".join(lines) + \
        f"\n    return [{', '.join(ret)}]\n"
    scope = {"_m": __import__("math"), **{f"c{k}": c for k, c in calls.items()}}
    exec(compile(src, f"<numpy {fun.name()}>", "exec"), scope)
    flat = scope["f"]
    shapes, scatter = [], []
    for i in range(fun.n_out()):
        sp = fun.sparsity_out(i)
        rows, cols = (np.asarray(v, dtype=int) for v in sp.get_triplet())
        shapes.append((sp.size1(), sp.size2()))
        scatter.append((rows, cols))

    def evaluate(*inputs):
        vals = flat(*[np.asarray(a, dtype=float).ravel(order="F").tolist() for a in inputs])
        out = []
        for v, shape, (rows, cols) in zip(vals, shapes, scatter, strict=True):
            dense = np.zeros(shape)
            dense[rows, cols] = v
            out.append(dense)
        return out

    return evaluate


def _check_call(fun: ca.Function, call, trials=5):
    """The numpy form of a call node equals CasADi's evaluation (random inputs)."""
    rng = np.random.default_rng(0)
    lo, hi = -np.pi, np.pi
    for _ in range(trials):
        x = rng.uniform(lo, hi)
        seeds = rng.standard_normal(3)
        args, nargs = [], []
        for i in range(fun.n_in()):
            if fun.nnz_in(i) == 0:
                args.append(ca.DM.zeros(fun.sparsity_in(i)))
                continue
            v = x if not nargs else seeds[len(nargs) - 1]
            args.append(v)
            nargs.append(v)
        ref = np.asarray(fun(*args)).ravel()
        got = np.asarray(call(*nargs)).ravel()
        scale = max(np.max(np.abs(ref)), 1e-300)
        if np.max(np.abs(got - ref)) > 1e-11 * scale:
            raise AssertionError(f"numpy form of {fun.name()} differs from CasADi by "
                                 f"{np.max(np.abs(got - ref)) / scale:.1e}")


def numpy_step_factory(plant, sensors, Q, R, dt):
    """A plain numpy EKF step ``(x, P, u, y, mask) -> (x_next, P_next, x_post)``: the
    equations of ``ekf_step_function(..., jacobians="first_order", update="batch")``
    (the default sequential update is the same to rounding), with no CasADi call in it."""
    from casflex.sensors import kinematic_measurement

    m = plant.m
    nx = 2 * m
    table = plant.model.provider.table
    grid = np.asarray(table.grid[0], dtype=float)
    h_grid = float(np.median(np.diff(grid)))
    # every knot of the (periodically padded) splines is on the uniform grid's lattice
    breaks = grid[0] + h_grid * np.arange(-4, round((grid[-1] - grid[0]) / h_grid) + 6)
    coef = sx_to_python(plant.function(), breaks)
    pairs = plant.pairs
    hk = kinematic_measurement(plant.model, sensors, lean=True, recursive=True)
    xs, us, acs = ca.SX.sym("x", nx), ca.SX.sym("u", 3 * plant.n), ca.SX.sym("a", m)
    hs = hk(xs, us, acs)
    hjac = sx_to_python(ca.Function("hjac", [xs, us, acs],
                                    [hs, ca.jtimes(hs, ca.vertcat(xs, acs),
                                                   ca.SX.eye(hs.numel()), True).T]),
                        breaks)
    Qd = Q * dt * np.eye(nx)
    Rm = np.asarray(R, dtype=float) * np.eye(sensors.n_outputs) if np.ndim(R) == 0 else R
    eye = np.eye(nx)

    def step(x, P, u, y, mask):
        c = coef(u)
        r0, Jd, Jv = c[0].ravel(), c[1], c[2]
        W = c[3] if pairs else np.zeros((m, 0))

        def accel(z):
            quad = np.array([z[a] * z[b] for a, b in pairs])
            return r0 + Jd @ z[:m] + Jv @ z[m:] + (W @ quad if pairs else 0.0)

        def rhs(z):
            return np.r_[z[m:], accel(z)]

        F = np.zeros((nx, nx))  # first-order part (jacobians="first_order")
        F[:m, m:] = np.eye(m)
        F[m:, :m], F[m:, m:] = Jd, Jv
        acc = accel(x)
        h, Jxa = hjac(x, u, acc)
        h = h.ravel()
        H = Jxa[:, :nx] + Jxa[:, nx:] @ np.hstack([Jd, Jv])
        valid = mask > 0.5
        e = np.where(valid, y - h, 0.0)
        Hm = H * valid[:, None]
        Rv = Rm * np.outer(valid, valid) + np.diag(~valid)
        S = Hm @ P @ Hm.T + Rv
        L = np.linalg.cholesky(S)
        K = np.linalg.solve(L.T, np.linalg.solve(L, Hm @ P)).T
        xp = x + K @ e
        IKH = eye - K @ Hm
        Pp = IKH @ P @ IKH.T + K @ Rv @ K.T
        Pp = 0.5 * (Pp + Pp.T)
        hF = dt * F
        Phi = eye + hF @ (eye + hF / 2 @ (eye + hF / 3 @ (eye + hF / 4)))
        xn = rk4_step(rhs, xp, dt)
        Pn = Phi @ Pp @ Phi.T + Qd
        return xn, 0.5 * (Pn + Pn.T), xp

    return step


def op_counts(f):
    """``(arithmetic operations, calls)`` among the SX instructions of ``f``: every
    instruction but inputs, outputs, constants and assignments is one floating-point
    operation (sqrt, division and the comparisons of the guard each count as one);
    calls are the B-spline lookups, counted apart."""
    import casadi as ca

    skip = {ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_ASSIGN, ca.OP_PARAMETER}
    ids = [f.instruction_id(k) for k in range(f.n_instructions())]
    calls = sum(1 for i in ids if i == ca.OP_CALL)
    return sum(1 for i in ids if i not in skip and i != ca.OP_CALL), calls


def callgrind_instructions(exe, inp, tmp, steps, function="ekf_step"):
    """Machine instructions executed per call of ``function`` (and its callees), counted by
    valgrind's callgrind over one pass of the harness: a figure the machine's load does
    not change (None without valgrind)."""
    import shutil

    if shutil.which("valgrind") is None:
        return None
    out = tmp / "callgrind.out"
    subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                    f"--toggle-collect={function}", str(exe), str(inp), str(tmp / "cg.txt"), "1"],
                   capture_output=True, text=True, check=True)
    if os.environ.get("CASFLEX_CALLGRIND_KEEP"):  # for callgrind_annotate
        shutil.copy(out, os.environ["CASFLEX_CALLGRIND_KEEP"])
    for line in out.read_text().splitlines():
        if line.startswith(("summary:", "totals:")):
            return int(line.split()[1]) / steps
    return None


def cpu_ghz():
    """Clock of this machine's CPU [GHz] from /proc/cpuinfo (None where unknown)."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("cpu MHz"):
                    return float(line.split(":")[1]) / 1e3
    except OSError:
        pass
    return None


def flop_limit(step):
    """Operations per step and the time they need at the scalar limit of this machine:
    two double-precision operations per cycle (two FP ports, scalar code: ``-O2`` without
    ``-march`` neither vectorises nor fuses), at the clock of :func:`cpu_ghz`."""
    flops, calls = op_counts(step)
    ghz = cpu_ghz()
    return {"flops_per_step": flops, "calls_per_step": calls, "cpu_ghz": ghz,
            "flop_limit_us": None if ghz is None else flops / (2.0 * ghz * 1e3)}



#: tight loops of ``--peak``: 16 independent mul-add chains (scalar double, no FMA), and a
#: chain of dependent integer adds (one cycle each on any x86 core: the running clock)
PEAK_SOURCE = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
static double now(void) {
  struct timespec t; clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}
int main(int argc, char **argv) {
  long n = atol(argv[1]);
  volatile double seed = 1.0000001;
  double m = seed, a = 1e-9 * seed, x[16], s = 0.0;
  for (int i = 0; i < 16; i++) x[i] = 1.0 + i * 1e-3;
  double t0 = now();
#define S(i) x[i] = x[i] * m + a;
  for (long k = 0; k < n; k++) {  /* unrolled: the 16 chains live in registers */
    S(0) S(1) S(2) S(3) S(4) S(5) S(6) S(7) S(8) S(9) S(10) S(11) S(12) S(13) S(14) S(15)
  }
  double tf = now() - t0;
  volatile long seedi = 3; long z = seedi, c = seedi;
  t0 = now();
  for (long k = 0; k < n; k++)
    __asm__ volatile("add %1, %0\n\tadd %1, %0\n\tadd %1, %0\n\tadd %1, %0\n\t"
                     "add %1, %0\n\tadd %1, %0\n\tadd %1, %0\n\tadd %1, %0" : "+r"(z) : "r"(c));
  double ti = now() - t0;
  for (int i = 0; i < 16; i++) s += x[i];
  printf("%.6f %.6f %g %ld\n", 32.0 * n / tf / 1e9, 8.0 * n / ti / 1e9, s, z);
  return 0;
}
"""


def measured_peak(tmp, runs=5, n=30_000_000):
    """``(scalar double operations per ns, clock in GHz)`` of this machine, the best of
    ``runs`` runs of :data:`PEAK_SOURCE` (``-O2 -march=native -fno-tree-vectorize
    -ffp-contract=off``: scalar, unfused, as the step's operations), in CPU time; None
    without a C compiler."""
    import shutil

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    src, exe = Path(tmp) / "peak.c", Path(tmp) / "peak"
    src.write_text(PEAK_SOURCE)
    subprocess.run([cc, "-O2", "-march=native", "-fno-tree-vectorize", "-ffp-contract=off",
                    str(src), "-o", str(exe)], check=True, capture_output=True)
    best = (0.0, 0.0)
    for _ in range(runs):
        ops, ghz = (float(v) for v in subprocess.run(
            [str(exe), str(n)], check=True, capture_output=True, text=True).stdout.split()[:2])
        best = (max(best[0], ops), max(best[1], ghz))
    return best


def timed_rounds(results, steps, rounds, time_c, log, prefix=""):
    """Time each compiled step of ``steps`` (label -> Function) with ``time_c(label, step)
    -> (us, deviation, _)`` in ``rounds`` interleaved rounds; ``results[label]`` gathers the
    rounds, the median (``c_step_us``), the largest C-vs-Python deviation and the load of
    each round."""
    for rnd in range(rounds):
        for label, stp in steps.items():
            us, dev, _ = time_c(label, stp)
            v = results.setdefault(label, {
                "sx_instructions": int(stp.n_instructions()), "rounds_us": [],
                "c_vs_python_max_rel_dev": 0.0, "load_avg_1min": []})
            v["rounds_us"].append(us)
            v["c_vs_python_max_rel_dev"] = max(v["c_vs_python_max_rel_dev"], dev)
            v["load_avg_1min"].append(os.getloadavg()[0])
            v["c_step_us"] = float(np.median(v["rounds_us"]))
            log(f"[{rnd}] {prefix}{label:12s} {us:7.2f} us  {stp.n_instructions()} instr  "
                f"dev {dev:.1e}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--runs", type=int, default=7,
                        help="runs of the compiled harness for c_step_us (median of the "
                             "runs' medians; every run in c_step_us_runs)")
    parser.add_argument("--step-deg", type=float, default=7.5,
                        help="grid step of the modal tables, deg")
    parser.add_argument("--order", type=int, default=2, help="plant order in Δ (1 or 2)")
    parser.add_argument("--jacobians", default="first_order",
                        choices=["exact", "first_order", "linearized"])
    parser.add_argument("--update", default="auto", choices=["auto", "batch", "sequential"])
    parser.add_argument("--flags", default=NATIVE, help="C compiler flags")
    parser.add_argument("--compare", action="store_true",
                        help="also time the configurations of VARIANTS in this run")
    parser.add_argument("--guarded", action="store_true",
                        help="also time the guarded step against the plain one")
    parser.add_argument("--callgrind", action="store_true",
                        help="also count the machine instructions of one step under "
                             "valgrind's callgrind (keys instructions_per_step, "
                             "instruction_limit_us)")
    parser.add_argument("--callgrind-flags", default=CALLGRIND_FLAGS,
                        help="C compiler flags of the build whose instructions are counted")
    parser.add_argument("--lookups", action="store_true",
                        help="also time and count the step with the plant's table through "
                        "casadi.interpolant (before) and evaluated locally (now), "
                        "interleaved over --rounds")
    parser.add_argument("--forms", action="store_true",
                        help="also time and count the step with the scalar updates in Joseph "
                        "and in standard form (the default), interleaved over --rounds")
    parser.add_argument("--peak", action="store_true",
                        help="also measure this machine's scalar floating-point peak and "
                        "clock in tight loops (keys peak_ops_per_ns, clock_ghz_measured, "
                        "flop_limit_measured_us)")
    parser.add_argument("--recursive", action="store_true",
                        help="also time and count the step with the accelerometers as the "
                        "whole pose's time derivatives (before) and by the recursive pass "
                        "(now), interleaved over --rounds")
    parser.add_argument("--shared", action="store_true",
                        help="also time and count the step with a lookup per table (before) "
                        "and with one lookup function (now), interleaved over --rounds")
    parser.add_argument("--rounds", type=int, default=3,
                        help="interleaved rounds over VARIANTS with --compare (median)")
    args = parser.parse_args(argv)

    from casflex import codegen
    from casflex.estimation import Guard, ekf_step_function, run_ekf, tabulate_plant
    from casflex.model import build_model
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.sensors import load_sensors
    from casflex.simulate.measurements import simulate_data

    def log(msg):
        if not args.json:
            print(msg, file=sys.stderr)

    robot = load(ROOT / "problems/arm2link.toml")
    sensors = load_sensors(ROOT / "problems/sensors/arm2link_accel.toml", robot)
    model, _ = build_model(robot, n_modes=3, step=np.radians(args.step_deg), cache_dir=False,
                           processes=1, points=sensors.points, gravity=None)
    t0 = time.perf_counter()
    plants = {o: tabulate_plant(model, order=o) for o in {1, 2, args.order}}
    plant = plants[args.order]
    log(f"plants tabulated in {time.perf_counter() - t0:.1f} s: {plant.info}")
    Q, R, dt = 5e-6, (250e-6 * 9.8) ** 2, 1e-3
    step = ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians,
                             update=args.update)
    move = load_move(str(ROOT / "problems/moves.toml") + ":move1")
    data = simulate_data(model, sensors, move, dt=dt, t_end=args.steps * dt - dt)
    N = data.u.shape[0]
    x0, P0 = np.zeros(6), 1e-6 * np.eye(6)
    mask = np.ones_like(data.y)

    run_medians = []
    instructions = []

    def time_c(stp, flags, runs=1):
        with tempfile.TemporaryDirectory() as tmp:
            bundle = codegen.generate([stp], tmp, name="bench_ekf")
            initial, feedback = {"x": x0, "P": P0}, {"x_next": "x", "P_next": "P"}
            if "u_last" in stp.name_in():  # guarded step
                initial["u_last"] = data.u[0]
                feedback["u_next"] = "u_last"
            res = codegen.run_harness(bundle, "ekf_step",
                                      {"u": data.u, "y": data.y, "mask": mask},
                                      initial, feedback=feedback,
                                      repeat=args.repeat, flags=tuple(flags.split()))
            ref = run_ekf(stp, data.u, data.y, x0, P0)
            dev = float(np.max(np.abs(res.outputs["x_post"] - ref.x)) / np.max(np.abs(ref.x)))
            medians = [res.timing["median_step_ns"] / 1e3]
            # the same executable again: on a shared machine a whole run can land in a
            # busy (or quiet) spell; the median over runs is reported, with every run
            exe = res.executable
            inp = Path(tmp) / "harness_ekf_step_input.txt"
            for _ in range(runs - 1):
                proc = subprocess.run([str(exe), str(inp), str(Path(tmp) / "again.txt"),
                                       str(args.repeat)], capture_output=True, text=True,
                                      check=True)
                medians.append(json.loads(proc.stdout)["median_step_ns"] / 1e3)
            run_medians[:] = medians
            if args.callgrind:  # machine instructions per step: independent of the load
                # valgrind knows no AVX-512: the count is of a build for AVX2 (x86-64-v3)
                counted = codegen.run_harness(
                    bundle, "ekf_step", {"u": data.u, "y": data.y, "mask": mask}, initial,
                    feedback=feedback, repeat=1, flags=tuple(args.callgrind_flags.split()))
                instructions[:] = [callgrind_instructions(counted.executable, inp, Path(tmp),
                                                          N)]
            return float(np.median(medians)), dev, bundle.functions[0].sz_w

    variants = {}
    if args.compare:
        steps = {}
        for label, order, pruned, opts, _flags in VARIANTS:
            pl = plants.setdefault(order, tabulate_plant(model, order=order))
            if not pruned:
                pl = dataclasses.replace(pl, keep=None)  # every Fourier coefficient
            steps[label] = ekf_step_function(pl, sensors, Q, R, dt, **opts)
        # interleaved rounds: on a shared machine one variant's median can catch a busy
        # spell; the median over the rounds is reported (and each round's figure)
        flags_of = {label: flags for label, _, _, _, flags in VARIANTS}
        timed_rounds(variants, steps, args.rounds,
                     lambda label, st: time_c(st, flags_of[label]), log)
    def side_by_side(steps, prefix):
        """Interleaved timings (and counts) of two steps, and their estimates' largest
        relative difference."""
        results, counted = {}, {}

        def timed(label, st):
            out = time_c(st, args.flags)
            if instructions:  # the count of the build just timed
                counted[label] = instructions[0]
            return out

        timed_rounds(results, steps, args.rounds, timed, log, prefix)
        for label, ins in counted.items():
            results[label]["instructions_per_step"] = ins
        ra, rb = (run_ekf(st, data.u, data.y, x0, P0).x for st in steps.values())
        results["max_rel_dev"] = float(np.max(np.abs(ra - rb)) / np.max(np.abs(ra)))
        return results

    lookups = {}
    if args.lookups:  # the spline tables: CasADi's de Boor routine vs local (fits' rounding)
        lookups = side_by_side(
            {lk: ekf_step_function(dataclasses.replace(plant, lookup=lk), sensors, Q, R, dt,
                                   jacobians=args.jacobians, update=args.update)
             for lk in ("interpolant", "local")}, "lookup ")
    forms = {}
    if args.forms:  # the scalar covariance updates: Joseph vs standard form
        forms = side_by_side(
            {form: ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians,
                                     update=args.update, joseph=form == "joseph")
             for form in ("joseph", "standard")}, "form ")
    recursive = {}
    if args.recursive:  # the accelerometers: whole-pose derivatives vs the recursive pass
        recursive = side_by_side(
            {form: ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians,
                                     update=args.update, recursive=form == "recursive")
             for form in ("pose", "recursive")}, "accelerometers ")
    shared = {}
    if args.shared:  # the tables: one lookup each vs one lookup function
        shared = side_by_side(
            {form: ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians,
                                     update=args.update, shared=form == "shared")
             for form in ("separate", "shared")}, "tables ")
    guarded = {}
    if args.guarded:
        gstep = ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians,
                                  update=args.update, guard=Guard(P0))
        timed_rounds(guarded, {"plain": step, "guarded": gstep}, args.rounds,
                     lambda _, st: time_c(st, args.flags), log)
        guarded["cost_ratio"] = guarded["guarded"]["c_step_us"] / guarded["plain"]["c_step_us"]
        guarded["rounds_ratio"] = [g / p for g, p in zip(guarded["guarded"]["rounds_us"],
                                                         guarded["plain"]["rounds_us"],
                                                         strict=True)]
    c_us, c_dev, sz_w = time_c(step, args.flags, runs=max(1, args.runs))
    c_runs = list(run_medians)
    ref = run_ekf(step, data.u, data.y, x0, P0)

    calls = min(N, 300)
    times = []
    x, P = x0, P0
    for k in range(calls):
        t = time.perf_counter()
        out = step(x, P, data.u[k], data.y[k], mask[k])
        times.append(time.perf_counter() - t)
        x, P = out[0], out[1]
    py_us = float(np.median(times)) * 1e6

    npstep = numpy_step_factory(plant, sensors, Q, R, dt)
    times = []
    x, P = x0, P0
    dev = 0.0
    for k in range(calls):
        t = time.perf_counter()
        xn, Pn, xp = npstep(x, P, data.u[k], data.y[k], mask[k])
        times.append(time.perf_counter() - t)
        dev = max(dev, float(np.max(np.abs(xp - ref.x[k])) / np.max(np.abs(ref.x))))
        x, P = xn, Pn
    np_us = float(np.median(times)) * 1e6
    # same equations, other order of operations (and batch vs sequential update, equal to
    # ≤ 2e-14): anything above round-off is a wrong baseline, not a slow one
    if dev > NUMPY_RTOL:
        raise AssertionError(f"numpy baseline differs from the CasADi step by {dev:.1e} "
                             f"(> {NUMPY_RTOL:.0e})")

    out = {
        "c_step_us": c_us,
        "c_step_us_runs": c_runs,
        "python_step_us": py_us,
        "numpy_step_us": np_us,
        "numpy_vs_c_ratio": np_us / c_us,
        "states": 6,
        "outputs": sensors.n_outputs,
        "sx_instructions": int(step.n_instructions()),
        "sz_w": sz_w,
        **flop_limit(step),
        "order": args.order,
        "jacobians": args.jacobians,
        "update": args.update,
        "flags": args.flags,
        "c_vs_python_max_rel_dev": c_dev,
        "numpy_vs_casadi_max_rel_dev": dev,
        "steps": N,
        "repeat": args.repeat,
        "nproc": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
    }
    if args.callgrind:
        ins = instructions[0] if instructions else None
        ghz = out["cpu_ghz"]
        out["instructions_per_step"] = ins
        out["callgrind_flags"] = args.callgrind_flags
        # the time of those instructions at ISSUE_WIDTH per cycle: no schedule does better
        out["instruction_limit_us"] = (None if ins is None or ghz is None
                                       else ins / (ISSUE_WIDTH * ghz * 1e3))
        # instructions per cycle that the timed median implies (the load inflates it less
        # than the time: a busy spell lowers the apparent IPC)
        out["implied_ipc"] = None if ins is None or ghz is None else ins / (c_us * ghz * 1e3)
    if args.peak:
        with tempfile.TemporaryDirectory() as tmp:
            peak = measured_peak(tmp)
        if peak is not None:
            out["peak_ops_per_ns"], out["clock_ghz_measured"] = peak
            # the step's operations at that peak: no schedule of them does better
            out["flop_limit_measured_us"] = out["flops_per_step"] / (peak[0] * 1e3)
    if lookups:
        out["lookups"] = lookups
    if forms:
        out["forms"] = forms
    if recursive:
        out["recursive"] = recursive
    if shared:
        out["shared"] = shared
    if guarded:
        out["guarded"] = guarded
    if variants:
        out["variants"] = variants
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:28s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
