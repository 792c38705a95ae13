"""Per-iteration cost of the planner's NLP solvers (Ipopt + MUMPS, Fatrop) on the one-link arm.

The time-optimal rest-to-rest move of ``problems/onelink.toml`` (1 rad, |τ| <= 0.1 N m,
|q̇| <= 1 rad/s, one mode, no gravity; :func:`casflex.planning.plan_move` with CasADi's
derivatives) for every ``--intervals`` and both solvers, alternated. Per run:

``iterations``, ``solve_cpu_s``
    the solver's iterations and the CPU seconds of the solve (with building its functions);
``functions_cpu_s``
    CPU seconds in the NLP's functions (CasADi's ``t_proc_nlp_*``: f, g, their
    derivatives, the Hessian of the Lagrangian);
``solver_cpu_s``
    the rest: the solver's own linear algebra and bookkeeping (and the functions' build);
``per_iteration_functions_s`` / ``per_iteration_solver_s``
    both per iteration;
``duration``
    the planned duration [s].

Usage::

    python benchmarks/bench_planning_solvers.py [--json] [--intervals N [N ...]]
        [--repeat K] [--solver-timing]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--intervals", type=int, nargs="+", default=[20, 80, 320],
                        metavar="N")
    parser.add_argument("--repeat", type=int, default=2, metavar="K",
                        help="runs of every case, the solvers alternated")
    parser.add_argument("--solver-timing", action="store_true",
                        help="the solvers print their own timing tables (Ipopt's "
                        "print_timing_statistics, Fatrop's at print_level 10)")
    args = parser.parse_args(argv)

    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.planning import plan_move
    from casflex.robot import load

    os.chdir(ROOT)
    robot = load("problems/onelink.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    rows = []
    for N in args.intervals:
        for repeat in range(args.repeat):
            for solver in ("ipopt", "fatrop"):
                options = {}
                if args.solver_timing:
                    options = {"print_level": 10} if solver == "fatrop" else \
                        {"print_level": 5, "print_timing_statistics": "yes"}
                p = plan_move(model, [0.0], [1.0], torque_limit=0.1, velocity_limit=1.0,
                              intervals=N, solver=solver, progress_stop=False,
                              ipopt_options=options)
                t = p.stats["timings"]
                functions = sum(v for k, v in t.items() if k.startswith("t_proc_nlp_"))
                it = max(p.stats["iterations"], 1)
                rows.append({
                    "intervals": N, "solver": solver, "repeat": repeat,
                    "iterations": p.stats["iterations"], "status": p.stats["status"],
                    "duration": p.duration, "solve_cpu_s": p.stats["solve_cpu_s"],
                    "functions_cpu_s": functions,
                    "solver_cpu_s": p.stats["solve_cpu_s"] - functions,
                    "per_iteration_functions_s": functions / it,
                    "per_iteration_solver_s": (p.stats["solve_cpu_s"] - functions) / it,
                    "load": os.getloadavg()[0]})
    if args.json:
        print(json.dumps(rows))
    else:
        for r in rows:
            print(f"N {r['intervals']:4d} {r['solver']:>6}: {r['iterations']:3d} it, "
                  f"T {r['duration']:.9f} s, CPU {r['solve_cpu_s']:.3f} s, per iteration "
                  f"functions {1e3 * r['per_iteration_functions_s']:.2f} ms, solver "
                  f"{1e3 * r['per_iteration_solver_s']:.2f} ms", file=sys.stdout)
    return rows


if __name__ == "__main__":
    main()
