"""Benchmark of generated C (casflex.codegen) against CasADi called from Python.

The workload is a toy EKF step (4 states: pendulum angle and rate, one flexible mode whose
squared frequency ω²(θ) comes from a 25-point B-spline table; 2 measurements; RK4
prediction with dt = 1 ms, Jacobian-linearised covariance propagation, Kalman gain by a
linear solve, Joseph-form update, symmetrised P). It is an MX graph holding a B-spline
interpolant and its derivative, the shape the real EKF will have. A second variant with
ω²(θ) in closed form is an SX graph (``*_sx`` keys).

Figures (µs per step, medians over ``--steps`` steps × ``--repeat`` loops):

``c_step_us``
    the generated C called by the C harness (``-O2``), timed inside C with
    ``clock_gettime(CLOCK_MONOTONIC)`` around each call;
``python_step_us``
    the same Function evaluated by CasADi from Python (``f(x, P, u, y)`` with the state fed
    back as ``DM``), timed with ``time.perf_counter`` around each call;
``external_step_us``
    the compiled C loaded back with ``casadi.external`` and called from Python the same way
    (Python call overhead plus C);
``timer_overhead_ns``
    median cost of an empty ``clock_gettime`` pair in the harness (not subtracted).

The README tour command (``--tour``)::

    casflex codegen problems/arm2link.toml --sensors problems/sensors/arm2link_accel.toml \
        [--controller composite] --out DIR

run in a subprocess, timed from outside (wall clock and the child's CPU time):

``cold_s`` / ``cold_cpu_s``
    from an empty cache directory (``$CASFLEX_CACHE`` set to a fresh one): modal tables,
    plant, gain schedule, code generation (``--no-cold`` skips it);
``warm_s`` / ``warm_cpu_s``
    the same command again with that cache warm;
``c_bytes``
    size of each bundle's C source (``{"casflex_ekf": ..., "casflex_model": ...}``);
``compile_s`` / ``compile_cpu_s``
    ``cc -O2 -fPIC -c`` of each bundle's source (wall clock, the compiler's CPU time).

``--variants plain`` or ``--variants composite`` runs one of the two commands only.
``--kinematics exact`` adds ``--kinematics exact`` to the command (the forward-dynamics
bundle of the exact model, issue 19).

Keys are prefixed ``composite_`` for the run with ``--controller composite``. ``--code DIR``
puts ``DIR`` first on ``PYTHONPATH`` of the subprocess (old vs new side by side).

Usage::

    python benchmarks/bench_codegen.py [--json] [--steps N] [--repeat R]
    python benchmarks/bench_codegen.py --tour [--json] [--no-cold] [--code DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from casflex import codegen
from casflex.simulate.integrators import rk4_step

ROOT = Path(__file__).resolve().parents[1]
DT = 1e-3
THETA_GRID = np.linspace(-np.pi, np.pi, 25)
W2_TABLE = (2 * np.pi * 3.0) ** 2 * (1.0 + 0.3 * np.cos(THETA_GRID))
Q = np.diag([1e-8, 1e-6, 1e-8, 1e-6])
R = np.diag([1e-6, 1e-4])
X0 = np.array([0.05, 0.0, 0.0, 0.0])
P0 = np.diag([1e-2, 1e-1, 1e-4, 1e-2])


def toy_ekf(kind="MX"):
    """Return the toy EKF step ``(x, P, u, y) -> (x_next, P_next)`` as a casadi.Function."""
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


def data(n_steps, seed=0):
    """Inputs u and noisy measurements y along a smooth trajectory."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_steps) * DT
    u = 0.5 * np.sin(2 * np.pi * t) + 0.1 * rng.standard_normal(n_steps)
    th = 0.3 * np.sin(3.0 * t)
    y = np.column_stack([th, np.sin(th) + 0.5e-3 * np.cos(19.0 * t)])
    y += rng.standard_normal(y.shape) * np.sqrt(np.diag(R))
    return u, y


def _python_loop(f, u, y, repeat):
    times = []
    for _ in range(repeat):
        x, P = ca.DM(X0), ca.DM(P0)
        for k in range(u.size):
            t0 = time.perf_counter()
            x, P = f(x, P, u[k], y[k])
            times.append(time.perf_counter() - t0)
    return statistics.median(times), x.full().ravel()


def run_variant(kind, steps, repeat, workdir):
    """Time one variant; return a dict of figures (µs) and the max relative deviation."""
    f = toy_ekf(kind)
    u, y = data(steps)
    bundle = codegen.generate([f], f"{workdir}/{kind}", name=f"ekf_{kind.lower()}")
    res = codegen.run_harness(bundle, "ekf_step", {"u": u, "y": y}, {"x": X0, "P": P0},
                              feedback={"x_next": "x", "P_next": "P"}, repeat=repeat,
                              flags=("-O2",))
    py_s, x_py = _python_loop(f, u, y, repeat)
    ext = codegen.load(codegen.build(bundle, flags=("-O2",)), "ekf_step")
    ext_s, x_ext = _python_loop(ext, u, y, repeat)
    x_c = res.outputs["x_next"][-1]
    dev = float(max(np.max(np.abs(x_c - x_py)), np.max(np.abs(x_ext - x_py)))
                / np.max(np.abs(x_py)))
    return {
        "c_step_us": res.timing["median_step_ns"] / 1e3,
        "c_mean_step_us": res.timing["mean_step_ns"] / 1e3,
        "python_step_us": py_s * 1e6,
        "external_step_us": ext_s * 1e6,
        "timer_overhead_ns": res.timing["timer_overhead_ns"],
        "max_rel_deviation": dev,
        "sz_w": bundle.functions[0].sz_w,
        "sz_iw": bundle.functions[0].sz_iw,
    }


def run(steps=1000, repeat=5):
    """Run the benchmark; return a flat dict (µs, ns for the timer overhead)."""
    with tempfile.TemporaryDirectory() as work:
        mx = run_variant("MX", steps, repeat, work)
        sx = run_variant("SX", steps, repeat, work)
    out = dict(mx)
    out.update({f"{k}_sx": v for k, v in sx.items()})
    out.update({"steps": steps, "repeat": repeat, "casadi_version": ca.__version__})
    return out


TOUR = ["codegen", "problems/arm2link.toml", "--sensors", "problems/sensors/arm2link_accel.toml"]


def _timed(cmd, env, cwd=None):
    """Run ``cmd`` (in ``cwd``); return (wall s, CPU s of the child)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, cwd=cwd)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_tour(controller, cold=True, code=None, cache=None, kinematics="truncated"):
    """Time the tour command (cold, warm), the size and the -O2 compile of its C."""
    env = dict(os.environ)
    # the child runs in the checkout whose code it times: ``python -m`` puts the working
    # directory first on sys.path, ahead of PYTHONPATH
    cwd = str(Path(code).resolve()) if code is not None else str(ROOT)
    if code is not None:
        env["PYTHONPATH"] = os.pathsep.join([cwd, env.get("PYTHONPATH", "")])
    out = {}
    with tempfile.TemporaryDirectory() as work:
        env["CASFLEX_CACHE"] = str(cache) if cache is not None else f"{work}/cache"
        cmd = [sys.executable, "-m", "casflex.cli", *TOUR, "--out", f"{work}/rt"]
        if controller:
            cmd += ["--controller", controller]
        if kinematics != "truncated":
            cmd += ["--kinematics", kinematics]
        if cold:
            shutil.rmtree(env["CASFLEX_CACHE"], ignore_errors=True)
            out["cold_s"], out["cold_cpu_s"] = _timed(cmd, env, cwd)
        elif cache is None:
            _timed(cmd, env, cwd)  # warm the cache, untimed
        shutil.rmtree(f"{work}/rt", ignore_errors=True)
        out["warm_s"], out["warm_cpu_s"] = _timed(cmd, env, cwd)
        out["c_bytes"], out["compile_s"], out["compile_cpu_s"] = {}, {}, {}
        for src in sorted(Path(f"{work}/rt").glob("*/*.c")):
            out["c_bytes"][src.stem] = src.stat().st_size
            out["compile_s"][src.stem], out["compile_cpu_s"][src.stem] = _timed(
                [os.environ.get("CC", "cc"), "-O2", "-fPIC", "-c", str(src), "-o",
                 str(src.with_suffix(".o"))], env)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true", help="print exactly one JSON object")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--tour", action="store_true",
                        help="time the README's casflex codegen command instead")
    parser.add_argument("--no-cold", action="store_true",
                        help="--tour: skip the run from an empty cache")
    parser.add_argument("--code", default=None,
                        help="--tour: directory put first on the subprocess's PYTHONPATH")
    parser.add_argument("--variants", default="plain,composite",
                        help="--tour: comma-separated, of plain (no --controller) and "
                             "composite")
    parser.add_argument("--kinematics", default="truncated", choices=("truncated", "exact"),
                        help="--tour: the forward-dynamics bundle's kinematics")
    parser.add_argument("--cache", default=None,
                        help="--tour: a cache directory to use (warm runs only)")
    args = parser.parse_args(argv)
    if args.tour:
        res = {"load_before": os.getloadavg()[0]}
        chosen = args.variants.split(",")
        for controller in [c for c in (None, "composite") if (c or "plain") in chosen]:
            got = run_tour(controller, cold=not args.no_cold and args.cache is None,
                           code=args.code, cache=args.cache, kinematics=args.kinematics)
            prefix = f"{controller}_" if controller else ""
            res.update({prefix + k: v for k, v in got.items()})
        res["load_after"] = os.getloadavg()[0]
        print(json.dumps(res) if args.json else json.dumps(res, indent=1))
        return 0
    res = run(args.steps, args.repeat)
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"toy EKF step, {args.steps} steps x {args.repeat} loops (medians)", file=sys.stderr)
    for variant, suffix in (("MX + B-spline", ""), ("SX closed form", "_sx")):
        print(
            f"{variant:>15}: C {res['c_step_us' + suffix]:8.3f} us | "
            f"CasADi/Python {res['python_step_us' + suffix]:8.2f} us | "
            f"external/Python {res['external_step_us' + suffix]:8.2f} us | "
            f"max rel dev {res['max_rel_deviation' + suffix]:.1e}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
