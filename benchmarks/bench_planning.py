"""Benchmark of the planner (casflex.planning) on move 1 of the design study.

The model of ``problems/studies/arm2link_move1.toml`` (Table 8 arm with the testbed's
actuator inertias, 3 modes, 3° grid, ``delta_order`` 0, no gravity); move 1 of
``problems/moves.toml`` shaped by its SI shaper (±20 %, Vtol 5 %). Measures

``solve_s``
    one cold plan (guess: the shaped move) at the shaped move's peak torques and
    velocities, end bound = the shaped move's residual tip deflection (problem build +
    Ipopt);
``solve_warm_s``
    the same plan with the end bound 5 % tighter, warm-started from the first solution
    (a neighbouring problem);
``duration`` / ``shaped_duration``
    planned and shaped durations, s;
``residual`` / ``shaped_residual``
    residual tip deflections with the joints on the move, simulated at 1 ms, m;
``intervals``
    intervals of the OCP;
``solve_cpu_s`` / ``solve_warm_cpu_s``
    the process's CPU time of the two solves (the machine is shared: the CPU time is the
    figure that does not depend on the load);
``iterations`` / ``iterations_warm``, ``status`` / ``status_warm``, ``transcription``,
``hessian``, ``load``.

Usage::

    python benchmarks/bench_planning.py [--json] [--intervals N] [--lbfgs]
        [--transcription collocation|shooting] [--dynamics implicit|explicit]
        [--max-iter K] [--move NAME]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark; print a table or (``--json``) one JSON object.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments.

    Returns
    -------
    dict
        The measured figures (see the module docstring).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--intervals", type=int, default=None,
                        help="intervals (default: plan_move's for the transcription)")
    parser.add_argument("--transcription", choices=("collocation", "shooting"),
                        default="collocation")
    parser.add_argument("--max-iter", type=int, default=500)
    parser.add_argument("--lbfgs", action="store_true",
                        help="limited-memory Hessian in Ipopt (default: exact)")
    parser.add_argument("--dynamics", choices=("implicit", "explicit"), default="implicit",
                        help="form of the collocated dynamics (default implicit)")
    parser.add_argument("--move", default="move1", help="move of problems/moves.toml")
    args = parser.parse_args(argv)

    from casflex.design.study import load_study
    from casflex.model import build_model
    from casflex.moves import ShapedMove, load_move
    from casflex.planning import plan_limits, plan_move, verify_plan
    from casflex.shaping import shaper_for_move
    from casflex.simulate import simulate_prescribed

    os.chdir(ROOT)
    study = load_study("problems/studies/arm2link_move1.toml")
    model, _ = build_model(study.robot, 3, step=study.model["grid_step"], gravity=None,
                           delta_order=0, processes=1)
    move = load_move(f"problems/moves.toml:{args.move}")
    shaped = ShapedMove(move, shaper_for_move(model, move, vtol=0.05, margin=0.2).shaper)
    run = simulate_prescribed(model, shaped, dt=1e-3)
    shaped_residual = run.residual_tip_deflection
    tau, vel = plan_limits(model, shaped)
    options = {"hessian_approximation": "limited-memory"} if args.lbfgs else {}
    kw = {"intervals": args.intervals, "torque_limit": tau, "velocity_limit": vel,
          "ipopt_options": options, "transcription": args.transcription,
          "max_iter": args.max_iter, "dynamics": args.dynamics}
    t0, c0 = time.perf_counter(), time.process_time()
    plan = plan_move(model, move, end=shaped_residual, guess=shaped, **kw)
    solve_s, solve_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    warm = plan_move(model, move, end=0.95 * shaped_residual, guess=plan, **kw)
    solve_warm_s, solve_warm_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    check = verify_plan(model, plan, torque=False)
    out = {"solve_s": solve_s, "solve_warm_s": solve_warm_s, "duration": plan.duration,
           "shaped_duration": shaped.duration, "residual": check["prescribed"],
           "shaped_residual": shaped_residual, "intervals": plan.stats["intervals"],
           "solve_cpu_s": solve_cpu_s, "solve_warm_cpu_s": solve_warm_cpu_s,
           "duration_warm": warm.duration, "transcription": args.transcription,
           "dynamics": args.dynamics, "move": args.move,
           "hessian": "limited-memory" if args.lbfgs else "exact",
           "substeps": plan.stats["substeps"], "iterations": plan.stats["iterations"],
           "iterations_warm": warm.stats["iterations"], "status": plan.stats["status"],
           "status_warm": warm.stats["status"], "load": os.getloadavg()[0]}
    if args.json:
        print(json.dumps(out))
    else:
        for key, value in out.items():
            print(f"{key:>18}: {value}", file=sys.stdout)
    return out


if __name__ == "__main__":
    main()
