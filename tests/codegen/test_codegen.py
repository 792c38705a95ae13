"""Tests of casflex.codegen: generated C compiled with the system compiler vs CasADi in Python.

Every comparison evaluates the original :class:`casadi.Function` in Python (CasADi's virtual
machine) and the compiled C code (through :func:`casflex.codegen.load` or the C harness),
on random inputs, to 1e-10 relative.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from casflex import codegen
from casflex.codegen import BuildError, CodegenError, run_compiler
from casflex.errors import CasflexError
from casflex.simulate.integrators import rk4_step

FLAGS = ("-O1",)
RTOL = 1e-10

pytestmark = pytest.mark.skipif(
    shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler"
)


def _rel_err(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def _dense(v):
    return np.array(ca.DM(v).full())


def _compare(f, g, args):
    ref = f.call([ca.DM(a) for a in args])
    out = g.call([ca.DM(a) for a in args])
    assert len(ref) == len(out)
    for r, o in zip(ref, out, strict=True):
        assert _rel_err(_dense(o), _dense(r)) <= RTOL


# --------------------------------------------------------------------------------------
# toy EKF: pendulum with one flexible mode whose squared frequency depends on the angle
# --------------------------------------------------------------------------------------
DT = 1e-3
THETA_GRID = np.linspace(-np.pi, np.pi, 25)
W2_TABLE = (2 * np.pi * 3.0) ** 2 * (1.0 + 0.3 * np.cos(THETA_GRID))
Q = np.diag([1e-8, 1e-6, 1e-8, 1e-6])
R = np.diag([1e-6, 1e-4])


def _toy_ekf(kind):
    """x⁺, P⁺ from x, P, u, y: RK4 prediction, Jacobian-linearised covariance, Joseph update.

    ``kind`` "SX": ω²(θ) in closed form; "MX": ω²(θ) from a B-spline table (an interpolant
    node and its derivative inside the MX graph, as the real EKF has).
    """
    sym = ca.SX.sym if kind == "SX" else ca.MX.sym
    if kind == "SX":
        def w2(th):
            return (2 * np.pi * 3.0) ** 2 * (1.0 + 0.3 * ca.cos(th))
    else:
        w2 = ca.interpolant("w2", "bspline", [THETA_GRID], W2_TABLE)

    def ode(x, u):
        th, thd, d, dd = x[0], x[1], x[2], x[3]
        thdd = -9.81 * ca.sin(th) - 0.5 * thd + u - 0.1 * d
        ddd = -w2(th) * d - 2 * 0.02 * ca.sqrt(w2(th)) * dd - thdd
        return ca.vertcat(thd, thdd, dd, ddd)

    def meas(x):
        return ca.vertcat(x[0], ca.sin(x[0]) + 0.5 * x[2])

    x, P, u, y = sym("x", 4), sym("P", 4, 4), sym("u"), sym("y", 2)
    xp = rk4_step(ode, x, DT, u)
    F = ca.jacobian(xp, x)
    Pp = F @ P @ F.T + Q
    xs = sym("xs", 4)
    H = ca.Function("H", [xs], [ca.jacobian(meas(xs), xs)])(xp)
    S = H @ Pp @ H.T + R
    K = ca.solve(S, H @ Pp).T
    xn = xp + K @ (y - meas(xp))
    IKH = ca.DM.eye(4) - K @ H
    Pn = IKH @ Pp @ IKH.T + K @ R @ K.T
    Pn = 0.5 * (Pn + Pn.T)
    return ca.Function("ekf_step", [x, P, u, y], [xn, Pn], ["x", "P", "u", "y"],
                       ["x_next", "P_next"])


def _ekf_data(n_steps, seed=0):
    """Inputs u and noisy measurements y of a simulated true trajectory."""
    rng = np.random.default_rng(seed)
    u = 0.5 * np.sin(np.arange(n_steps) * DT * 2 * np.pi) + 0.1 * rng.standard_normal(n_steps)
    th = 0.3 * np.sin(np.arange(n_steps) * DT * 3.0)
    d = 1e-3 * np.cos(np.arange(n_steps) * DT * 19.0)
    y = np.column_stack([th, np.sin(th) + 0.5 * d])
    y += rng.standard_normal(y.shape) * np.sqrt(np.diag(R))
    return u, y


X0 = np.array([0.05, 0.0, 0.0, 0.0])
P0 = np.diag([1e-2, 1e-1, 1e-4, 1e-2])


# --------------------------------------------------------------------------------------
# (a) SX, several inputs and outputs with matrices
# --------------------------------------------------------------------------------------
def _sx_function():
    A, b = ca.SX.sym("A", 3, 3), ca.SX.sym("b", 3)
    s, M = ca.SX.sym("s"), ca.SX.sym("M", 2, 4)
    outs = [s * (A @ b), M.T @ M + ca.sin(s), ca.det(A) + ca.exp(-s * s), M.T @ ca.tanh(A[:2, :2]),
            ca.jacobian(ca.sin(A @ b) * s, b)]
    return ca.Function("mixed", [A, b, s, M], outs, ["A", "b", "s", "M"],
                       ["Ab", "MtM", "det", "AMt", "J"])


@pytest.mark.needs_cc
def test_sx_several_inputs_outputs(tmp_path):
    f = _sx_function()
    units = {"mixed": {"A": "N/m", "s": "s", "J": "1"}}
    bundle = codegen.generate([f], tmp_path, name="mixed_bundle", units=units)
    g = codegen.load(codegen.build(bundle, flags=FLAGS), "mixed")
    rng = np.random.default_rng(1)
    for _ in range(5):
        args = [rng.standard_normal((3, 3)), rng.standard_normal(3), rng.standard_normal(),
                rng.standard_normal((2, 4))]
        _compare(f, g, args)
    # the header macros are CasADi's work sizes; the README documents them and the units
    # the header macros are what the compiled mixed_work() reports at run time (SX code
    # keeps its scalars in locals, so they differ from the virtual machine's f.sz_w())
    info = bundle.function("mixed")
    lib = ctypes.CDLL(str(bundle.library))
    sizes = [ctypes.c_longlong(-1) for _ in range(4)]
    assert lib.mixed_work(*[ctypes.byref(v) for v in sizes]) == 0
    assert [v.value for v in sizes] == [info.sz_arg, info.sz_res, info.sz_iw, info.sz_w]
    header = bundle.header.read_text()
    assert f"#define mixed_SZ_W {info.sz_w}" in header
    readme = bundle.readme.read_text()
    assert f"`mixed_SZ_W` = {info.sz_w}" in readme
    assert "| in | arg[0] | `A` | 3 x 3 | 9 | dense | N/m |" in readme
    assert "reentrant" in readme
    assert bundle.reentrant
    manifest = json.loads(bundle.manifest.read_text())
    assert [p["name"] for p in manifest["functions"][0]["outputs"]] == list(f.name_out())


@pytest.mark.needs_cc
def test_dense_false_keeps_sparse_outputs(tmp_path):
    x = ca.SX.sym("x", 4)
    f = ca.Function("jacx", [x], [ca.jacobian(ca.sin(x) * x[0], x)], ["x"], ["J"])
    assert not f.sparsity_out(0).is_dense()
    sparse = codegen.generate([f], tmp_path / "s", name="sp", dense=False)
    dense = codegen.generate([f], tmp_path / "d", name="de")
    assert sparse.functions[0].outputs[0].nnz == f.nnz_out(0) < 16
    assert dense.functions[0].outputs[0].nnz == 16
    xv = np.random.default_rng(2).standard_normal(4)
    for b in (sparse, dense):
        g = codegen.load(codegen.build(b, flags=FLAGS), "jacx")
        assert _rel_err(_dense(g(xv)), _dense(f(xv))) <= RTOL


# --------------------------------------------------------------------------------------
# (b) interpolants (1-D and 2-D, bspline and linear) and their Jacobian, in MX
# --------------------------------------------------------------------------------------
def _interp_function():
    rng = np.random.default_rng(3)
    g1 = np.linspace(0.0, 2.0, 11)
    g2 = np.linspace(-1.0, 1.0, 7)
    table2 = rng.standard_normal(g1.size * g2.size)
    bs1 = ca.interpolant("bs1", "bspline", [g1], np.sin(3 * g1))
    ln1 = ca.interpolant("ln1", "linear", [g1], np.cos(2 * g1))
    bs2 = ca.interpolant("bs2", "bspline", [g1, g2], table2)
    ln2 = ca.interpolant("ln2", "linear", [g1, g2], table2)
    q, p = ca.MX.sym("q", 2), ca.MX.sym("p")
    y = ca.vertcat(bs1(q[0]) * p, ln1(q[0]), bs2(q), ln2(q) + p * p)
    return ca.Function("lookup", [q, p], [y, ca.jacobian(y, q), ca.jacobian(y, p)],
                       ["q", "p"], ["y", "dy_dq", "dy_dp"])


@pytest.mark.needs_cc
def test_interpolants_and_jacobian(tmp_path):
    f = _interp_function()
    assert f.is_a("MXFunction")
    bundle = codegen.generate([f], tmp_path, name="interp")
    source = bundle.source.read_text()
    assert "nd_boor_eval" in source and "interpn" in source  # generated, not expanded
    g = codegen.load(codegen.build(bundle, flags=FLAGS), "lookup")
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = np.array([rng.uniform(0.01, 1.99), rng.uniform(-0.99, 0.99)])
        _compare(codegen.densified(f), g, [q, rng.standard_normal()])
    assert bundle.reentrant


@pytest.mark.needs_cc
def test_bare_interpolant_function(tmp_path):
    grid = np.linspace(0.0, 1.0, 9)
    f = ca.interpolant("table", "bspline", [grid], grid**3)
    g = codegen.load(codegen.build(codegen.generate([f], tmp_path, name="bare"), flags=FLAGS),
                     "table")
    for v in np.linspace(0.05, 0.95, 7):
        assert _rel_err(float(g(v)), float(f(v))) <= RTOL


# --------------------------------------------------------------------------------------
# (c) toy EKF step, SX and MX with an interpolant
# --------------------------------------------------------------------------------------
@pytest.mark.needs_cc
@pytest.mark.parametrize("kind", ["SX", "MX"])
def test_toy_ekf_step(tmp_path, kind):
    f = _toy_ekf(kind)
    bundle = codegen.generate([f], tmp_path, name=f"ekf_{kind.lower()}",
                              units={"ekf_step": {"x": "rad, rad/s, m, m/s", "u": "N m"}})
    g = codegen.load(codegen.build(bundle, flags=FLAGS), "ekf_step")
    rng = np.random.default_rng(5)
    for _ in range(10):
        L = rng.standard_normal((4, 4)) * 0.1
        P = L @ L.T + 1e-3 * np.eye(4)
        args = [X0 + 0.1 * rng.standard_normal(4), P, rng.standard_normal(),
                rng.standard_normal(2) * 0.1]
        _compare(f, g, args)
        Pn = _dense(g(*args)[1])
        assert np.array_equal(Pn, Pn.T)


# --------------------------------------------------------------------------------------
# (d) the C harness runs the EKF 1000 steps with feedback and matches the Python loop
# --------------------------------------------------------------------------------------
@pytest.mark.needs_cc
@pytest.mark.parametrize("kind", ["SX", "MX"])
def test_harness_ekf_feedback(tmp_path, kind):
    f = _toy_ekf(kind)
    n = 1000
    u, y = _ekf_data(n)
    x, P = ca.DM(X0), ca.DM(P0)
    xs, Ps = np.empty((n, 4)), np.empty((n, 4, 4))
    for k in range(n):
        x, P = f(x, P, u[k], y[k])
        xs[k], Ps[k] = x.full().ravel(), P.full()
    bundle = codegen.generate([f], tmp_path, name="ekf_h")
    res = codegen.run_harness(bundle, "ekf_step", {"u": u, "y": y}, {"x": X0, "P": P0},
                              feedback={"x_next": "x", "P_next": "P"}, flags=FLAGS)
    assert res.outputs["x_next"].shape == (n, 4)
    assert res.outputs["P_next"].shape == (n, 4, 4)
    assert _rel_err(res.outputs["x_next"], xs) <= RTOL
    assert _rel_err(res.outputs["P_next"], Ps) <= RTOL
    for k in (0, n // 2, n - 1):  # every state component, not only the largest
        assert np.allclose(res.outputs["x_next"][k], xs[k], rtol=RTOL, atol=0)
    assert np.array_equal(res.outputs["P_next"], res.outputs["P_next"].transpose(0, 2, 1))
    t = res.timing
    assert t["steps"] == n and t["clock"] == "CLOCK_MONOTONIC"
    assert 0 < t["min_step_ns"] <= t["median_step_ns"] <= t["max_step_ns"]


@pytest.mark.needs_cc
def test_harness_feedback_by_index_and_no_timing(tmp_path):
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    f = ca.Function("acc", [u, x], [ca.vertcat(x[1], x[0] + u), x[0] * u], ["u", "x"],
                    ["x_next", "z"])
    bundle = codegen.generate([f], tmp_path, name="acc", with_header=False)
    assert bundle.header is None
    res = codegen.run_harness(bundle, "acc", {"u": [1.0, 2.0, 3.0]}, {"x": [0.5, -1.0]},
                              feedback={0: 1}, timing=False, flags=FLAGS)
    assert res.timing is None
    np.testing.assert_array_equal(res.outputs["x_next"], [[-1.0, 1.5], [1.5, 1.0], [1.0, 4.5]])
    np.testing.assert_array_equal(res.outputs["z"], [0.5, -2.0, 4.5])


@pytest.mark.needs_cc
def test_harness_sparse_port(tmp_path):
    """With dense=False the harness still takes and returns dense numpy arrays."""
    x = ca.SX.sym("x", 3)
    f = ca.Function("jd", [x], [ca.jacobian(x * x, x)], ["x"], ["J"])
    bundle = codegen.generate([f], tmp_path, name="jd", dense=False)
    xs = np.arange(6.0).reshape(2, 3)
    res = codegen.run_harness(bundle, "jd", {"x": xs}, flags=FLAGS)
    np.testing.assert_array_equal(res.outputs["J"], [np.diag(2 * v) for v in xs])


@pytest.mark.needs_cc
def test_readme_build_command_and_makefile(tmp_path):
    f = _toy_ekf("SX")
    bundle = codegen.generate([f], tmp_path, name="cmd")
    lib_cmd = next(line.split("    #")[0] for line in bundle.readme.read_text().splitlines()
                   if line.startswith("cc ") and "-shared" in line)
    subprocess.run(lib_cmd, shell=True, cwd=tmp_path, check=True, capture_output=True)
    assert bundle.library.is_file()
    g = codegen.load(bundle.library, "ekf_step")
    args = [X0, P0, 0.3, [0.05, 0.05]]
    _compare(f, g, args)
    if shutil.which("make"):
        codegen.harness(bundle, "ekf_step", feedback={"x_next": "x", "P_next": "P"})
        subprocess.run(["make", "-s", "harness_ekf_step", "CFLAGS=-O1"], cwd=tmp_path,
                       check=True, capture_output=True)
        assert (tmp_path / "harness_ekf_step").is_file()


@pytest.mark.needs_cc
def test_two_bundles_link_together(tmp_path):
    x = ca.SX.sym("x")
    a = codegen.generate([ca.Function("fa", [x], [x + 1])], tmp_path, name="bundle_a")
    b = codegen.generate([ca.Function("fb", [x], [x + 2])], tmp_path, name="bundle_b")
    lib = tmp_path / "libab.so"
    cmd = [*codegen.find_compiler(None), "-O1", "-fPIC", "-shared", str(a.source), str(b.source),
           "-o", str(lib), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True)
    assert float(codegen.load(lib, "fa")(1.0)) == 2.0
    assert float(codegen.load(lib, "fb")(1.0)) == 3.0


def test_static_state_detected(tmp_path):
    """A function with internal memory (sqpmethod) is reported as not reentrant."""
    x, p = ca.MX.sym("x", 2), ca.MX.sym("p")
    opts = {"qpsol": "qrqp", "print_header": False, "print_iteration": False,
            "print_time": False, "qpsol_options": {"print_iter": False, "print_header": False}}
    solver = ca.nlpsol("s", "sqpmethod", {"x": x, "p": p, "f": (x[0] - p) ** 2 + x[1] ** 2},
                       opts)
    f = ca.Function("opt", [p], [solver(x0=0, p=p)["x"]])
    bundle = codegen.generate([f], tmp_path, name="stateful")
    assert not bundle.reentrant
    assert any("mem" in s for s in bundle.static_state)
    assert "Not reentrant" in bundle.readme.read_text()


# --------------------------------------------------------------------------------------
# (e) errors
# --------------------------------------------------------------------------------------
def test_missing_compiler(tmp_path, monkeypatch):
    x = ca.SX.sym("x")
    bundle = codegen.generate([ca.Function("sq", [x], [x * x], ["x"], ["y"])], tmp_path,
                              name="nocc")
    monkeypatch.setenv("CC", str(tmp_path / "no" / "such" / "cc"))
    with pytest.raises(BuildError, match="no C compiler.*no/such/cc"):
        codegen.build(bundle)
    with pytest.raises(BuildError, match="no C compiler"):
        codegen.run_harness(bundle, "sq", {"x": [1.0]})
    with pytest.raises(CasflexError):
        codegen.build(bundle, compiler="definitely-not-a-compiler-xyz")


@pytest.mark.needs_cc
def test_compiler_failure_reports_stderr(tmp_path):
    x = ca.SX.sym("x")
    bundle = codegen.generate([ca.Function("sq", [x], [x * x])], tmp_path, name="badflag")
    with pytest.raises(BuildError, match="compilation failed") as info:
        codegen.build(bundle, flags=("-fno-such-flag-casflex",))
    assert "no-such-flag-casflex" in str(info.value)


@pytest.mark.needs_cc
def test_unknown_function_name(tmp_path):
    x = ca.SX.sym("x")
    bundle = codegen.generate([ca.Function("sq", [x], [x * x], ["x"], ["y"])], tmp_path,
                              name="names")
    lib = codegen.build(bundle, flags=FLAGS)
    with pytest.raises(CodegenError, match="no function 'cube'.*sq"):
        codegen.load(lib, "cube")
    with pytest.raises(CodegenError, match="no function 'cube'"):
        codegen.harness(bundle, "cube")
    with pytest.raises(CodegenError, match="no function 'cube'"):
        codegen.run_harness(bundle, "cube", {"x": [1.0]})
    with pytest.raises(CodegenError, match="no output 'z'"):
        codegen.harness(bundle, "sq", feedback={"z": "x"})
    with pytest.raises(CodegenError, match="no shared library"):
        codegen.load(tmp_path / "libmissing.so", "sq")
    # without the manifest next to it, the symbol check still catches the name
    lonely = tmp_path / "lonely"
    lonely.mkdir()
    shutil.copy(lib, lonely / "libother.so")
    with pytest.raises(CodegenError, match="no CasADi function 'cube'"):
        codegen.load(lonely / "libother.so", "cube")


def test_generate_rejects_bad_requests(tmp_path):
    x, z = ca.SX.sym("x"), ca.SX.sym("z")
    f = ca.Function("f", [x], [x + 1], ["x"], ["y"])
    with pytest.raises(CodegenError, match="empty"):
        codegen.generate([], tmp_path)
    with pytest.raises(CodegenError, match="two functions are called 'f'"):
        codegen.generate([f, f], tmp_path)
    with pytest.raises(CodegenError, match="not a valid C identifier"):
        codegen.generate([f], tmp_path, name="my-bundle")
    with pytest.raises(CodegenError, match="unknown function 'g'"):
        codegen.generate([f], tmp_path, units={"g": {"x": "m"}})
    with pytest.raises(CodegenError, match="names 'q'"):
        codegen.generate([f], tmp_path, units={"f": {"q": "m"}})
    with pytest.raises(CodegenError, match="not a casadi.Function"):
        codegen.generate([f, "g"], tmp_path)
    free = ca.Function("free", [x], [x + z], {"allow_free": True})
    with pytest.raises(CodegenError, match="free symbols"):
        codegen.generate([free], tmp_path)


@pytest.mark.needs_cc
def test_load_rejects_foreign_int_type(tmp_path):
    x = ca.SX.sym("x", 3)
    f = ca.Function("jac32", [x], [ca.jacobian(ca.sin(x), x)], ["x"], ["J"])
    bundle = codegen.generate([f], tmp_path, name="int32", casadi_int="int")
    with pytest.raises(CodegenError, match="casadi_int"):
        codegen.load(codegen.build(bundle, flags=FLAGS), "jac32")
    # the harness does not go through casadi.external: it works with 32-bit ints
    res = codegen.run_harness(bundle, "jac32", {"x": [[0.0, 1.0, 2.0]]}, flags=FLAGS)
    np.testing.assert_allclose(res.outputs["J"], [np.diag(np.cos([0.0, 1.0, 2.0]))], rtol=1e-15)


def test_run_harness_input_errors(tmp_path):
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    f = ca.Function("st", [x, u], [x * u], ["x", "u"], ["x_next"])
    bundle = codegen.generate([f], tmp_path, name="inerr")
    fb = {"x_next": "x"}
    with pytest.raises(CodegenError, match=r"no data for input\(s\) \['x'\]"):
        codegen.run_harness(bundle, "st", {"u": [1.0]}, feedback=fb)
    with pytest.raises(CodegenError, match="is fed back"):
        codegen.run_harness(bundle, "st", {"u": [1.0], "x": [[1.0, 2.0]]}, {"x": [1, 2]},
                            feedback=fb)
    with pytest.raises(CodegenError, match="must hold 2 x 2 x 1"):
        codegen.run_harness(bundle, "st", {"u": [1.0, 2.0], "x": np.ones((2, 3))})
    g = ca.Function("sc", [x, u], [u], ["x", "u"], ["y"])
    b2 = codegen.generate([g], tmp_path / "b2", name="sc")
    with pytest.raises(CodegenError, match="sparsity patterns differ"):
        codegen.harness(b2, "sc", feedback={"y": "x"})


THREAD_MAIN = r"""
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include "ekf_mt.h"
#define NT 4
#define NSTEP 2000
#define MAX1(n) ((n) > 0 ? (n) : 1)
typedef struct { double x[4], P[16]; } result_t;

static void* run(void* out) {
  /* every thread: its own workspaces and buffers, on its stack */
  const casadi_real* arg[ekf_step_SZ_ARG];
  casadi_real* res[ekf_step_SZ_RES];
  casadi_int iw[MAX1(ekf_step_SZ_IW)];
  casadi_real w[MAX1(ekf_step_SZ_W)];
  double x[4] = {0.05, 0, 0, 0}, P[16] = {0}, xn[4], Pn[16], u, y[2];
  int n, mem = ekf_step_checkout();
  P[0] = 1e-2; P[5] = 1e-1; P[10] = 1e-4; P[15] = 1e-2;
  for (n = 0; n < NSTEP; ++n) {
    u = 0.5 * (n % 7) - 1.0; y[0] = 0.01 * (n % 5); y[1] = 0.01 * (n % 3);
    arg[0] = x; arg[1] = P; arg[2] = &u; arg[3] = y; res[0] = xn; res[1] = Pn;
    if (ekf_step(arg, res, iw, w, mem)) return 0;
    memcpy(x, xn, sizeof x); memcpy(P, Pn, sizeof P);
  }
  ekf_step_release(mem);
  memcpy(((result_t*) out)->x, x, sizeof x); memcpy(((result_t*) out)->P, P, sizeof P);
  return out;
}

int main(void) {
  pthread_t th[NT];
  result_t ref, r[NT];
  int i;
  ekf_step_incref();
  run(&ref);
  for (i = 0; i < NT; ++i) pthread_create(&th[i], 0, run, &r[i]);
  for (i = 0; i < NT; ++i) pthread_join(th[i], 0);
  ekf_step_decref();
  for (i = 0; i < NT; ++i)
    if (memcmp(&r[i], &ref, sizeof ref)) { printf("thread %d differs\n", i); return 1; }
  printf("ok %.17g\n", ref.x[0]);
  return 0;
}
"""


@pytest.mark.needs_cc
def test_reentrant_concurrent_threads(tmp_path):
    """The README's thread-safety claim: per-thread workspaces give identical results."""
    bundle = codegen.generate([_toy_ekf("MX")], tmp_path, name="ekf_mt")
    assert bundle.reentrant
    (tmp_path / "mt.c").write_text(THREAD_MAIN)
    cmd = [*codegen.find_compiler(None), "-O1", "-pthread", "-I", str(tmp_path), "-o",
           str(tmp_path / "mt"), str(tmp_path / "mt.c"), str(bundle.source), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True)
    out = subprocess.run([str(tmp_path / "mt")], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("ok ")


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
def test_run_compiler_timeout_stops_the_children(tmp_path):
    """A compiler driver killed on its timeout must not leave its children (``cc1``)
    running: a shell standing in for the driver starts a child and waits on it."""
    script = "sleep 60 >/dev/null 2>&1 & echo $! > child.pid; wait"
    with pytest.raises(BuildError, match="timed out after 0.5 s"):
        run_compiler(["sh", "-c", script], tmp_path, timeout_s=0.5)
    child = int((tmp_path / "child.pid").read_text())
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:   # gone, or a zombie waiting for init to reap it
        stat = Path(f"/proc/{child}/stat")
        if not stat.exists() or stat.read_text().split(") ")[1].startswith("Z"):
            return
        time.sleep(0.05)
    os.kill(child, 9)
    pytest.fail(f"the compiler's child {child} was still running after the timeout")
