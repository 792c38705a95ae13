"""Benchmark: what a ``poly`` form of ``kinematics="exact"`` would cost and how far it is off.

``--budget`` (the error budget of the degree in δ)
    The exact model's modal rows with every ``(q, δ)``-coefficient cut at degree ``p`` in
    δ (:func:`casflex.simulate.taylor_modal_rows`), simulated by the RK4 steps of
    ``method="rk4"`` (:func:`casflex.simulate.simulate_taylor`), against RK4 on the exact
    rows themselves (same model, same step), for ``p = 1, 2, 3``: Table 9 move 3 (q1 by
    π in 2 s, ``kinematics="exact"``) and the planar elbow move (q2 → −0.8, q3 → +1.2 rad
    in 1 s, ``kinematics="exact"`` with ``shape_rates=True``, the variant that meets the
    ANCF reference); 5 modes, the 1.5° table, gravity off, 3 s settle, RK4 at 5 ms (the
    step of the exact fidelity tests). Figures per move and degree: ``peak`` and
    ``residual`` (max |tip deflection| during / after the move, % difference from the
    exact run) and ``gap`` (max over time of |d_p − d_exact| in % of the exact peak);
    wall time of each run [s].
``--coefficients`` (the cost of configuration-only coefficients)
    SX instructions of the exact model's mass matrix ``M(q, δ)`` (upper triangle) and of
    its Taylor coefficients at δ = 0 of degree 1 and 2 in δ by nested CasADi Jacobians
    (what ``F(q)`` of :func:`casflex.simulate.poly.configuration_function` would hold),
    and the build time of each; 5 modes frozen at one configuration
    (``PointwiseProvider``, so that no table lookup is counted).

``--build`` (the coefficient function's build, session 13)
    Per mode count of ``--modes-list`` (default 3,5,8), in a fresh subprocess each:
    the exact model on frozen modes (``PointwiseProvider`` at q = (0.1, 0.3, -0.8),
    gravity off, so that no table is built), SX instructions of its ``M`` and ``h``,
    :func:`casflex.simulate.exact_poly.configuration_function`'s build (CPU s, peak RSS
    of the process [GB], the baseline after the model's construction), the SX
    instructions of one evaluation (:func:`casflex.simulate.exact_poly.instructions`) and
    the CPU time of one evaluation (min of 3).

``--cost`` (``method="poly"`` on the exact model, against RK4 on it and poly on the
    truncated model)
    Table 9 move 1 (all joints −1 rad in 2 s, the default grid, 1 ms: the move of
    ``bench_model.py``) and Table 9 move 3 (the 1.5° grid, 5 ms, 3 s settle: the move of
    ``--budget``), ``--modes`` modes (default 3), gravity off. Per move: SX
    instructions of poly's coefficient function (``exact_poly_G`` of
    :mod:`casflex.simulate.exact_poly`, ``truncated_F`` of
    :func:`casflex.simulate.poly.configuration_function`) and of the exact model's
    ``dddelta``; the first call of each method (graph build included) and then
    ``--repeat`` warm calls of the three in alternation (wall and CPU seconds, min/max);
    poly's breakdown (pieces, coefficient evaluations, stage timings); the gap of
    poly-exact to RK4 on the exact rows (the truncation, % of the exact peak tip
    deflection) and, on move 3, to :func:`casflex.simulate.simulate_taylor` at degree 2
    (the same truncation by another path; relative to the peak). ``--cases elbow2_1s``
    adds the planar elbow move of ``--budget`` (``shape_rates=True``, 5 ms).

Usage::

    python benchmarks/bench_exact_poly.py [--budget] [--coefficients] [--build] [--cost]
        [--modes-list M,M] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _figures(run, exact, t_move_end):
    d = np.linalg.norm(run["tip_deflection"], axis=1)
    e = np.linalg.norm(exact["tip_deflection"], axis=1)
    after = run["t"] > t_move_end
    peak, residual = np.abs(e).max(), np.abs(e[after]).max()
    return {"peak_pct": 100.0 * (np.abs(d).max() - peak) / peak,
            "residual_pct": 100.0 * (np.abs(d[after]).max() - residual) / residual,
            "gap_pct": 100.0 * float(np.abs(run["tip_deflection"]
                                            - exact["tip_deflection"]).max()) / peak,
            "exact_peak_m": float(peak), "exact_residual_m": float(residual),
            "delta_max": float(np.abs(exact["delta"]).max())}


def budget(degrees=(1, 2, 3), dt=5e-3):
    """Degree-p rows against the exact rows (module docstring)."""
    from casflex.model import build_model
    from casflex.moves import Move
    from casflex.robot import load
    from casflex.simulate import simulate_prescribed, simulate_taylor

    robot = load(ROOT / "problems/arm2link.toml")
    moves = {"move3": (Move(np.zeros(3), [-np.pi, 0.0, 0.0], 2.0, settle=3.0), {}),
             "elbow2_1s": (Move(np.zeros(3), [0.0, -0.8, 1.2], 1.0, settle=3.0),
                           {"shape_rates": True})}
    out = {}
    cache = os.environ.get("CASFLEX_CACHE") or tempfile.mkdtemp()
    for name, (move, options) in moves.items():
        model, _ = build_model(robot, 5, step=np.radians(1.5), cache_dir=cache,
                               gravity=None, kinematics="exact", progress=False, **options)
        t0 = time.perf_counter()
        ref = simulate_prescribed(model, move, dt=dt)
        exact = {"t": ref.t, "delta": ref.delta, "tip_deflection": ref.tip_deflection}
        out[f"{name}_exact_rk4_s"] = time.perf_counter() - t0
        for p in degrees:
            t0 = time.perf_counter()
            run = simulate_taylor(model, move, p, dt=dt)
            out[f"{name}_p{p}"] = {**_figures(run, exact, move.duration),
                                   "seconds": time.perf_counter() - t0,
                                   "integrate_s": run["wall_s"]}
            print(name, p, out[f"{name}_p{p}"], file=sys.stderr, flush=True)
    return out


def coefficients(orders=(1, 2)):
    """Instructions of nested-Jacobian Taylor coefficients of the exact M (docstring)."""
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load

    robot = load(ROOT / "problems/arm2link.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.1, 0.3, -0.8], count=5),
                          gravity=None, kinematics="exact")
    q, d = model.q, model.delta
    N = model.n + model.m
    iu = np.triu_indices(N)
    D = ca.vertcat(*[model.M[int(i), int(k)] for i, k in zip(*iu, strict=True)])
    out = {"mass_instructions": int(ca.Function("M", [q, d], [D]).n_instructions())}
    for k in orders:
        t0 = time.perf_counter()
        D = ca.vec(ca.jacobian(D, d))
        at_zero = ca.Function("D", [q, d], [D])(q, ca.DM.zeros(model.m))
        out[f"taylor_degree{k}_instructions"] = int(
            ca.Function("F", [q], [at_zero]).n_instructions())
        out[f"taylor_degree{k}_build_s"] = time.perf_counter() - t0
    return out


def build_one(modes):
    """One mode count of ``--build`` (module docstring), in this process."""
    import resource

    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load
    from casflex.simulate import exact_poly

    def rss_gb():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # KB on Linux

    robot = load(ROOT / "problems/arm2link.toml")
    q = np.array([0.1, 0.3, -0.8])
    model = FlexibleModel(robot, PointwiseProvider(robot, q, count=modes), gravity=None,
                          kinematics="exact")
    out = {"modes": modes, "rss_before_gb": rss_gb()}
    out["model_M_h_instructions"] = int(ca.Function(
        "rows", [model.q, model.dq, model.delta, model.ddelta],
        [ca.vec(model.M), model.h]).n_instructions())
    c = time.process_time()
    G = exact_poly.configuration_function(model)
    out["build_cpu_s"] = time.process_time() - c
    out["peak_rss_gb"] = rss_gb()
    out["evaluation_instructions"] = exact_poly.instructions(model)
    dq = np.array([0.2, -0.1, 0.4])
    times = []
    for _ in range(3):
        c = time.process_time()
        G(q, dq)
        times.append(time.process_time() - c)
    out["evaluation_cpu_s"] = min(times)
    return out


def build(modes_list):
    """``--build``: :func:`build_one` per mode count, each in a fresh process."""
    import subprocess

    out = {}
    for m in modes_list:
        run = subprocess.run([sys.executable, __file__, "--build-one", str(m)],
                             capture_output=True, text=True, check=True)
        out[f"build_m{m}"] = json.loads(run.stdout)
        print(out[f"build_m{m}"], file=sys.stderr, flush=True)
    return out


def _timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def cost(repeat=3, names=("move1", "move3"), modes=3):
    """poly-exact against RK4-exact and poly-truncated (module docstring)."""
    from casflex.model import build_model
    from casflex.moves import Move, load_move
    from casflex.robot import load
    from casflex.simulate import simulate_prescribed, simulate_taylor
    from casflex.simulate.poly import configuration_function

    robot = load(ROOT / "problems/arm2link.toml")
    cases = {"move1": (load_move(ROOT / "problems/moves.toml:move1"), None, 1e-3, {}),
             "move3": (Move(np.zeros(3), [-np.pi, 0.0, 0.0], 2.0, settle=3.0),
                       np.radians(1.5), 5e-3, {}),
             "elbow2_1s": (Move(np.zeros(3), [0.0, -0.8, 1.2], 1.0, settle=3.0),
                           np.radians(1.5), 5e-3, {"shape_rates": True})}
    out = {}
    for name in names:
        move, step, dt, options = cases[name]
        models = {k: build_model(robot, modes, step=step, gravity=None, kinematics=k,
                                 progress=False, **options)[0]
                  for k in ("exact", "truncated")}
        plan = {"poly_exact": ("exact", "poly"), "rk4_exact": ("exact", "rk4"),
                "poly_truncated": ("truncated", "poly")}
        runs = {k: partial(simulate_prescribed, models[kind], move, dt=dt, method=method)
                for k, (kind, method) in plan.items()}
        res, first, warm = {}, {}, {k: [] for k in runs}
        for k, f in runs.items():
            res[k], w, c = _timed(f)
            first[k] = {"wall_s": w, "cpu_s": c}
            print(name, k, "first", first[k], file=sys.stderr, flush=True)
        for _ in range(repeat):
            for k, f in runs.items():
                _, w, c = _timed(f)
                warm[k].append((w, c))
        e, p = res["rk4_exact"], res["poly_exact"]
        peak = float(np.linalg.norm(e.tip_deflection, axis=1).max())
        out[name] = {
            "loadavg": list(os.getloadavg()), "modes": modes, "dt": dt,
            "steps": int(e.t.size - 1),
            "instructions": {
                "exact_poly_G": int(p.info["poly_F_instructions"]),
                "truncated_F": int(configuration_function(models["truncated"])
                                   .n_instructions()),
                "exact_dddelta": int(models["exact"].functions()["dddelta"]
                                     .n_instructions())},
            "first_call": first,
            "warm": {k: {"wall_s": [min(x[0] for x in v), max(x[0] for x in v)],
                         "cpu_s": [min(x[1] for x in v), max(x[1] for x in v)]}
                     for k, v in warm.items()},
            "poly_exact_info": {k: v for k, v in p.info.items() if k.startswith("poly_")},
            "poly_exact_vs_rk4_exact_gap_pct": 100.0 * float(
                np.abs(p.tip_deflection - e.tip_deflection).max()) / peak,
            "poly_exact_vs_rk4_exact_tau_rel": float(np.abs(p.tau - e.tau).max()
                                                     / np.abs(e.tau).max()),
            "exact_peak_m": peak}
        if name != "move1":
            r = simulate_taylor(models["exact"], move, 2, dt=dt)
            out[name]["poly_exact_vs_taylor2_rel"] = float(
                np.abs(p.tip_deflection - r["tip_deflection"]).max()) / peak
        print(name, out[name], file=sys.stderr, flush=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", action="store_true", help="error of degree p in delta")
    parser.add_argument("--coefficients", action="store_true",
                        help="instructions of the Taylor coefficients of the exact M")
    parser.add_argument("--cost", action="store_true",
                        help="poly on the exact model against RK4 and poly-truncated")
    parser.add_argument("--repeat", type=int, default=3, metavar="N",
                        help="warm calls per method with --cost (default 3)")
    parser.add_argument("--cases", default="move1,move3", metavar="NAMES",
                        help="moves of --cost, comma-separated from move1, move3, "
                             "elbow2_1s (default move1,move3)")
    parser.add_argument("--modes", type=int, default=3, metavar="M",
                        help="modes of --cost (default 3)")
    parser.add_argument("--build", action="store_true",
                        help="build time, memory and evaluation cost of the coefficients")
    parser.add_argument("--modes-list", default="3,5,8", metavar="M,M",
                        help="mode counts of --build (default 3,5,8)")
    parser.add_argument("--build-one", type=int, default=None, metavar="M",
                        help=argparse.SUPPRESS)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.build_one is not None:  # the subprocess of --build
        print(json.dumps(build_one(args.build_one)))
        return 0
    result = {"loadavg_start": list(os.getloadavg())}
    if args.coefficients:
        result.update(coefficients())
    if args.budget:
        result.update(budget())
    if args.build:
        result.update(build([int(x) for x in args.modes_list.split(",")]))
    if args.cost:
        result.update(cost(args.repeat, tuple(args.cases.split(",")), args.modes))
    result["loadavg_end"] = list(os.getloadavg())
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:32s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
