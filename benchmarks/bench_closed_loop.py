"""Benchmark of the design job's closed loop with the EKF (issue 17, target 4).

The closed loop of ``casflex design problems/studies/arm2link_move1.toml`` (3 modes, 3°
grid, scheduled composite law, EKF on two accelerometers with q̈ from the difference of
q̇, 1 ms samples over the shaped move 1 plus 3 s), built through the public API with the
study's settings, and run by :func:`casflex.simulate.simulate_closed_loop` three ways,
alternated in one process:

``closed_loop_python_s``
    ``loop="python"``: the loop over the samples in Python calling the measurement model,
    the EKF step and the plant step through CasADi's VM (the path before issue 17).
``closed_loop_vm_s``
    ``loop="mapaccum"``: one SX Function per sample under ``mapaccum``, CasADi's VM.
``closed_loop_s``
    ``loop="mapaccum", jit=True``: the sample Function compiled to C, its library in the
    on-disk cache (the design job's path on a second run). ``closed_loop_first_s``: the
    first call in this process (compiles when the cache lacks the library).
``tracking_vm_s``, ``tracking_s``
    the design job's two loops with the true state fed back (``_tracking_sources``: the
    whole law and its slow part, ``sampled=True, method="rk4"``), in CasADi's VM and
    with their steps compiled (``jit=True``, the job's path since issue 17 part 4).
``*_cpu_s``
    the process's CPU time of the same runs (medians): the figure to compare on a
    shared machine.
``*_runs``
    every repetition; the figures above are medians. ``max_difference``: largest
    difference of ``x``, ``tau``, ``x_hat`` between the Python loop and the compiled one.
``design_second_run_s``, ``design_second_run_old_s``
    wall time of a second ``casflex design ... --json`` process (the first fills the
    caches), with the new path and with the closed loop forced to the Python loop (a
    wrapper around ``simulate_closed_loop``); ``design_timings_s`` and
    ``design_timings_old_s`` hold the ``timings_s`` of those runs. Alternated, ``--design``
    repetitions each.

Usage::

    python benchmarks/bench_closed_loop.py [--json] [--repeat 3] [--design 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"

#: run the design CLI (as the ``casflex`` entry point does)
NEW_DESIGN = """
import sys
from casflex.cli import main
sys.exit(main(sys.argv[1:]))
"""

#: run the design CLI with the closed loop forced to the Python loop
OLD_DESIGN = """
import sys, casflex.simulate as s
from casflex.cli import main
f = s.simulate_closed_loop
def python_loop(*a, **k):
    k.update(loop="python", jit=False)
    return f(*a, **k)
s.simulate_closed_loop = python_loop
sys.exit(main(sys.argv[1:]))
"""


def design_loop():
    """``(model, controller, slow law, shaped move, keywords)`` of the study's closed
    loop."""
    from casflex import control, shaping
    from casflex.design import load_study
    from casflex.estimation import ekf_step_function, tabulate_plant
    from casflex.model import build_model
    from casflex.moves import Move, ShapedMove

    study = load_study(STUDY)
    move = study.move
    move = Move(move.q0, move.qf, move.duration, study.simulation["settle"], move.name)
    dt = study.simulation["dt"]
    model, table = build_model(study.robot, study.model["modes"],
                               step=study.model["grid_step"], points=study.sensors.points,
                               gravity=None, delta_order=study.model["delta_order"])
    design = shaping.shaper_for_move(model, move, vtol=study.shaper["vtol"],
                                     margin=study.shaper["margin"],
                                     n_samples=study.shaper["n_samples"])
    shaped = ShapedMove(move, design.shaper)
    c = study.controller
    eps = control.perturbation_parameter(model, table=table)
    axis = -np.pi + 2.0 * np.pi * np.arange(c["schedule_points"]) / c["schedule_points"]
    gain = control.cached_gain_schedule(model, c["Q"], c["R"], eps, table, axis)
    slow = study.slow_gains(float(np.min(design.omega_min)), shaped.duration)
    ctrl = control.composite_controller(model, Kp=slow.Kp, Kd=slow.Kd, gain=gain,
                                        epsilon=eps)
    slow_law = control.composite_controller(model, Kp=slow.Kp, Kd=slow.Kd, fast=False)
    e = study.estimator
    ekf = ekf_step_function(tabulate_plant(model), study.sensors, e["Q"], e["R"], dt)
    m = model.m
    est = {"step": ekf, "sensors": study.sensors, "P0": np.eye(2 * m) * e["P0"],
           "x0": np.zeros(2 * m), "R": np.diag(e["R"]), "seed": e["seed"],
           "ddq": "difference"}
    return model, ctrl, slow_law, shaped, {"t_end": shaped.t_end, "dt": dt, "estimator": est,
                                 "sampled": True}


def _tracking(model, ctrl, slow, shaped, kw, jit):
    """The design job's two loops with the true state fed back."""
    from casflex.simulate import simulate_closed_loop

    return [simulate_closed_loop(model, law, shaped, t_end=kw["t_end"], dt=kw["dt"],
                                 sampled=True, method="rk4", jit=jit) for law in (ctrl, slow)]


def bench_loop(repeat):
    from casflex.simulate import simulate_closed_loop

    model, ctrl, slow, shaped, kw = design_loop()
    out = {"loadavg_before": os.getloadavg()[0]}
    t0 = time.perf_counter()
    compiled = simulate_closed_loop(model, ctrl, shaped, loop="mapaccum", jit=True, **kw)
    out["closed_loop_first_s"] = time.perf_counter() - t0
    paths = {"closed_loop_python_s": {"loop": "python"},
             "closed_loop_vm_s": {"loop": "mapaccum"},
             "closed_loop_s": {"loop": "mapaccum", "jit": True}}
    _tracking(model, ctrl, slow, shaped, kw, True)  # compiles when the cache lacks it
    runs = {k: [] for k in [*paths, "tracking_vm_s", "tracking_s"]}
    cpu = {k: [] for k in runs}
    results = {}
    for _ in range(repeat):
        for key, opts in paths.items():
            t0, c0 = time.perf_counter(), time.process_time()
            results[key] = simulate_closed_loop(model, ctrl, shaped, **opts, **kw)
            runs[key].append(time.perf_counter() - t0)
            cpu[key].append(time.process_time() - c0)
        for key, jit in (("tracking_vm_s", False), ("tracking_s", True)):
            t0, c0 = time.perf_counter(), time.process_time()
            results[key] = _tracking(model, ctrl, slow, shaped, kw, jit)
            runs[key].append(time.perf_counter() - t0)
            cpu[key].append(time.process_time() - c0)
    for key, values in runs.items():
        out[key] = float(np.median(values))
        out[key.replace("_s", "_runs")] = values
        out[key.replace("_s", "_cpu_s")] = float(np.median(cpu[key]))
    out["tracking_max_difference"] = max(
        float(np.max(np.abs(a.x - b.x))) for a, b in zip(results["tracking_vm_s"],
                                                         results["tracking_s"], strict=True))
    old = results["closed_loop_python_s"]
    out["samples"] = int(old.t.size)
    out["max_difference"] = max(float(np.max(np.abs(getattr(old, f) - getattr(compiled, f))))
                                for f in ("x", "tau", "x_hat"))
    out["loadavg_after"] = os.getloadavg()[0]
    return out


TIMINGS_KEY = {"design_second_run_s": "design_timings_s",
               "design_second_run_old_s": "design_timings_old_s"}


def bench_design(repeat):
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    out = {"design_second_run_s": [], "design_second_run_old_s": [],
           "loadavg_before_design": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        commands = {
            "design_second_run_s": [sys.executable, "-c", NEW_DESIGN],
            "design_second_run_old_s": [sys.executable, "-c", OLD_DESIGN],
        }
        for key, cmd in commands.items():  # first runs: fill the caches
            subprocess.run([*cmd, "design", str(STUDY), "--out", f"{tmp}/{key}", "--json"],
                           env=env, cwd=ROOT, check=True, capture_output=True)
        for _ in range(repeat):
            for key, cmd in commands.items():
                t0 = time.perf_counter()
                proc = subprocess.run([*cmd, "design", str(STUDY), "--out", f"{tmp}/{key}",
                                       "--json"], env=env, cwd=ROOT, check=True,
                                      capture_output=True, text=True)
                out[key].append(time.perf_counter() - t0)
                summary = json.loads(proc.stdout)
                timings = summary.get("timings_s") or summary["summary"]["timings_s"]
                out[TIMINGS_KEY[key]] = timings
    out["loadavg_after_design"] = os.getloadavg()[0]
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=3, help="closed-loop repetitions")
    parser.add_argument("--design", type=int, default=2,
                        help="design second-run repetitions (0: skip)")
    args = parser.parse_args(argv)
    result = bench_loop(args.repeat)
    if args.design:
        result.update(bench_design(args.design))
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:28s} {value}")


if __name__ == "__main__":
    main()
