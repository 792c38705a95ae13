"""Benchmark of the model pipeline: tables, CasADi model, simulation of move 1, Dask grid.

``tables_s``
    :func:`casflex.modal.tables.build_table` of the Table 8 arm (``problems/arm2link.toml``):
    q3 over [-π, π) every 1.5° (240 points, the default grid of
    :func:`casflex.model.default_grid`), 5 modes, default quantities, empty cache, local
    process pool over all CPUs.
``model_build_s``
    :func:`casflex.model.build_model` on the table just built (read from the cache):
    B-spline interpolants + symbolic model + ``functions()``; gravity neglected.
``simulate_move1_s``
    :func:`casflex.simulate.simulate_prescribed` of Table 9 move 1 (5 modes, 5 s, 1 ms
    steps) by the fastest route: ``method="poly", jit=True`` with its compiled library in
    the on-disk cache, median of three calls after the first (what every simulation of
    a study costs once the model is compiled). ``simulate_move1_first_call_s``: the first
    call in a process that finds the library on disk (builds ``F``, regenerates and
    hashes the C source, loads it). ``jit_compile_s``: the one-off compilation with an
    empty cache (``-O1``), ``jit_compile_call_s`` that whole first call.
``simulate_move1_rk4_s``, ``simulate_move1_rk4_warm_s``
    the same move with the plain RK4 path: first call on the model (builds the RK4 step
    and ``mapaccum`` Functions) and a second call. Nothing is compiled: CasADi's VM
    evaluates the step.
``simulate_move1_poly_s``, ``simulate_move1_poly_warm_s``
    ``method="poly"`` without compilation (exact polynomial form of the modal rows,
    coefficients interpolated in time, CasADi's VM), first and second call;
    ``move1_poly_info`` holds its breakdown (pieces, F evaluations, achieved interpolation
    error, stage timings), ``move1_poly_jit_info`` that of a compiled call, and
    ``move1_poly_vs_rk4``/``move1_jit_vs_rk4`` the largest differences from the RK4
    result (modal amplitudes relative to each mode's range, torques relative to the peak).
``dask_1_worker_s``, ``dask_2_workers_s``, ``dask_speedup_2_workers``
    the testbed 10 × 12 grid of ``bench_tables.py`` (same settings, reused from there;
    1- and 2-worker runs alternated, best of three each).
``cpu_capacity_2_processes``
    speed-up of a pure-Python loop on 2 processes over 1, before and after (what the shared
    machine offered at the time).

``--kinematics``: instead of the above, ``FlexibleModel(kinematics="exact")`` against the
default kinematics, side by side in one process (5 modes, the 1.5° table, no gravity):
SX instructions of ``mass``, ``forward``, ``ode``, ``dddelta``; the model's build (with
``functions()``); the median time of one evaluation of ``forward``, ``ode`` and
``dddelta`` in CasADi's VM (rounds alternated); and move 1 with ``method="rk4"`` (the
exact model's route: ``poly`` refuses it), the warm call of each, alternated. Keys
``kinematics_<variant>_<figure>`` and the ratios ``kinematics_ratio_<figure>``;
``casflex_path`` names the package measured, so that two versions of the exact model
are compared by running this script under each (``PYTHONPATH``) in turn.

Usage::

    python benchmarks/bench_model.py [--json] [--skip-dask] [--kinematics]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_tables import _cpu_model, bench_dask, cpu_capacity  # noqa: E402


def bench(skip_dask=False):
    from casflex.modal.tables import build_table
    from casflex.model import build_model, default_grid
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.simulate import simulate_prescribed

    robot = load(ROOT / "problems/arm2link.toml")
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        grid = default_grid(robot, (2,))[0]
        t0 = time.perf_counter()
        table = build_table(robot, grid, 5, cache_dir=cache)
        out["tables_s"] = time.perf_counter() - t0
        out["table_points"] = int(table.omega.shape[0])
        t0 = time.perf_counter()
        model, _ = build_model(robot, 5, cache_dir=cache, gravity=None)
        f = model.functions()
        out["model_build_s"] = time.perf_counter() - t0
    out["sx_instructions"] = {k: int(f[k].n_instructions())
                              for k in ("mass", "ode", "prescribed", "tip")}
    move = load_move(ROOT / "problems/moves.toml:move1")
    t0 = time.perf_counter()
    r = simulate_prescribed(model, move, dt=1e-3)
    out["simulate_move1_rk4_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = simulate_prescribed(model, move, dt=1e-3)
    out["simulate_move1_rk4_warm_s"] = time.perf_counter() - t0
    out["move1_steps"] = int(r.info["steps"])
    out["move1_max_tip_deflection"] = r.max_tip_deflection
    out["move1_residual_tip_deflection"] = r.residual_tip_deflection
    out["move1_torque_peak"] = r.torque_peak.tolist()
    out["loadavg_before_poly"] = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = simulate_prescribed(model, move, dt=1e-3, method="poly")
    out["simulate_move1_poly_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    p = simulate_prescribed(model, move, dt=1e-3, method="poly")
    out["simulate_move1_poly_warm_s"] = time.perf_counter() - t0
    out["move1_poly_info"] = {k: v for k, v in p.info.items() if k.startswith("poly_")}

    def deviation(a):
        span = np.ptp(r.delta, axis=0)
        return {"delta_rel_range": float(np.max(np.abs(a.delta - r.delta).max(axis=0) / span)),
                "tau_rel_peak": float(np.abs(a.tau - r.tau).max() / np.abs(r.tau).max())}

    out["move1_poly_vs_rk4"] = deviation(p)
    # compiled: once with an empty library cache, then as a new process would (the
    # in-memory functions forgotten), then warm
    from casflex.simulate.integrators import STEP_CACHE

    with tempfile.TemporaryDirectory() as jit_cache:
        t0 = time.perf_counter()
        c = simulate_prescribed(model, move, dt=1e-3, method="poly", jit=True,
                                cache_dir=jit_cache)
        out["jit_compile_call_s"] = time.perf_counter() - t0
        out["jit_compile_s"] = c.info["poly_jit_s"]
        STEP_CACHE.clear()
        t0 = time.perf_counter()
        c = simulate_prescribed(model, move, dt=1e-3, method="poly", jit=True,
                                cache_dir=jit_cache)
        out["simulate_move1_first_call_s"] = time.perf_counter() - t0
        warm = []
        for _ in range(3):
            t0 = time.perf_counter()
            c = simulate_prescribed(model, move, dt=1e-3, method="poly", jit=True,
                                    cache_dir=jit_cache)
            warm.append(time.perf_counter() - t0)
    out["simulate_move1_s"] = float(np.median(warm))
    out["simulate_move1_warm_runs_s"] = warm
    out["move1_poly_jit_info"] = {k: v for k, v in c.info.items() if k.startswith("poly_")}
    out["move1_jit_vs_rk4"] = deviation(c)
    if not skip_dask:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # coarse 2-D grid: low MAC
            times, same, _ = bench_dask(3)
        out["dask_1_worker_s"] = times[1]
        out["dask_2_workers_s"] = times[2]
        out["dask_speedup_2_workers"] = times[1] / times[2]
        out["dask_tables_identical"] = bool(same)
    return out


def bench_kinematics(rounds=3):
    """The exact kinematics against the default, side by side (module docstring)."""
    from casflex.model import build_model
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.simulate import simulate_prescribed

    robot = load(ROOT / "problems/arm2link.toml")
    move = load_move(ROOT / "problems/moves.toml:move1")
    out, models = {}, {}
    with tempfile.TemporaryDirectory() as cache:
        for variant in ("truncated", "exact"):
            build_model(robot, 5, cache_dir=cache, gravity=None)  # the table, once
            t0 = time.perf_counter()
            model, _ = build_model(robot, 5, cache_dir=cache, gravity=None,
                                   kinematics=variant)
            f = model.functions()
            out[f"kinematics_{variant}_build_s"] = time.perf_counter() - t0
            out[f"kinematics_{variant}_sx_instructions"] = {
                k: int(f[k].n_instructions()) for k in ("mass", "forward", "ode", "dddelta")}
            models[variant] = model
            simulate_prescribed(model, move, dt=1e-3)  # builds the RK4 step
    rng = np.random.default_rng(0)
    q, dq, ddq = (rng.normal(0.0, 0.3, 3) for _ in range(3))
    d, dd = rng.normal(0.0, 0.01, 5), rng.normal(0.0, 0.1, 5)
    args = {"dddelta": (q, dq, ddq, d, dd), "forward": (q, dq, d, dd, ddq),
            "ode": (np.r_[q, d, dq, dd], ddq)}
    calls = {(v, k): [] for v in models for k in args}
    sims = {v: [] for v in models}
    for _ in range(rounds):
        for variant, model in models.items():
            for key, a in args.items():
                f = model.functions()[key]
                t0 = time.perf_counter()
                for _ in range(200):
                    f(*a)
                calls[variant, key].append((time.perf_counter() - t0) / 200)
            t0 = time.perf_counter()
            simulate_prescribed(model, move, dt=1e-3)
            sims[variant].append(time.perf_counter() - t0)
    for variant in models:
        for key in args:
            out[f"kinematics_{variant}_{key}_call_s"] = float(np.median(calls[variant, key]))
        out[f"kinematics_{variant}_move1_rk4_s"] = float(np.median(sims[variant]))
        out[f"kinematics_{variant}_move1_rk4_runs_s"] = sims[variant]
    for figure in ("build_s", "forward_call_s", "ode_call_s", "dddelta_call_s", "move1_rk4_s"):
        out[f"kinematics_ratio_{figure}"] = (out[f"kinematics_exact_{figure}"]
                                             / out[f"kinematics_truncated_{figure}"])
    import casflex

    out["casflex_path"] = str(Path(casflex.__file__).parent)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--skip-dask", action="store_true", help="leave the Dask part out")
    parser.add_argument("--kinematics", action="store_true",
                        help="the exact kinematics against the default, side by side")
    args = parser.parse_args(argv)
    before = cpu_capacity()
    result = bench_kinematics() if args.kinematics else bench(args.skip_dask)
    result["cpu_capacity_2_processes"] = [before, cpu_capacity()]
    result.update({"nproc": os.cpu_count(), "cpu": _cpu_model(),
                   "python": platform.python_version(),
                   "loadavg_1min": os.getloadavg()[0]})
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:32s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
