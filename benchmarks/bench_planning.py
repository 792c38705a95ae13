"""Benchmark of the planner (casflex.planning) on move 1 of the design study.

The model of ``problems/studies/arm2link_move1.toml`` (Table 8 arm with the testbed's
actuator inertias, 3 modes, 3° grid, ``delta_order`` 0, no gravity); move 1 of
``problems/moves.toml`` shaped by its SI shaper (±20 %, Vtol 5 %). Measures

``solve_s``
    one cold plan as ``casflex plan`` makes it (:func:`casflex.planning.plan_robot_move`:
    guess = the shaped move, limits = its peak torques and velocities, end bound = its
    residual tip deflection), wall time of Ipopt (with building its functions);
``solve_warm_s``
    the same plan with the end bound 5 % tighter, warm-started from the first solution
    (a neighbouring problem: its iterate and multipliers, ``warm_start_duals``);
``duration`` / ``shaped_duration``
    planned and shaped durations, s (the plan ``casflex plan`` returns: after its
    ``bound_corrections``);
``residual`` / ``shaped_residual``
    residual tip deflections with the joints on the move, simulated at ``--dt`` (0.1 ms), m;
``bound_corrections`` / ``bound_corrections_s``
    the re-solves with a tighter end bound when the verified residual passed it
    (:func:`casflex.planning.hold_verified_bounds`) and their solver seconds (not in
    ``solve_s``, the cold solve's);
``intervals``
    intervals of the OCP;
``solve_cpu_s`` / ``solve_warm_cpu_s``
    the process's CPU time of the two solves (the machine is shared: the CPU time is the
    figure that does not depend on the load);
``iterations`` / ``iterations_warm``, ``status`` / ``status_warm``, ``transcription``,
``hessian`` / ``hessian_warm`` (exact or limited-memory, of each solve), ``dynamics``,
``residual_torque_driven``, ``residual_ocp``, ``robust``,
``shortening``, ``run_cpu_s`` (model, shaper, plan and verification), ``max_rss_mb``,
``load``, ``dt`` (of the verification; 0.1 ms by default), ``progress_stop``,
``ocp_fit``, ``ocp_modes``, ``trace`` / ``trace_warm`` (T and the constraint violation
at every Ipopt iterate of the cold and the warm solve), ``derivatives``, ``compiled``
(seconds of each ``compile_cached`` call and whether it built), ``solver``, ``timings`` /
``timings_warm`` (CasADi's CPU seconds and calls per NLP function: ``t_proc_nlp_jac_g``,
``t_proc_nlp_hess_l``...), ``perturb`` (``--perturb``'s seed or None).

The cold solve's path changes with rounding-level differences (another compiler, BLAS or
machine: 110 to 489 iterations on move 1, README_planning.md), so one run is one draw.
``--perturb SEED`` multiplies the compiled point derivatives by ``1 + 1e-9 sin(0.7 k +
SEED)``; ``--draws K`` runs the first ``K`` of :data:`DRAW_SEEDS` and adds ``draws`` (each
draw's figures), ``solve_s_range`` and ``solve_warm_s_range`` ([min, max] over the draws
with a plan) and ``failed_draws`` to the unperturbed draw's record.

Usage::

    python benchmarks/bench_planning.py [--json] [--intervals N] [--lbfgs]
        [--warm-hessian exact|limited-memory] [--transcription collocation|shooting]
        [--dynamics implicit|explicit]
        [--max-iter K] [--move NAME] [--robust R] [--dt DT] [--ocp-fit chebyshev]
        [--ocp-modes N] [--no-progress-stop] [--derivatives casadi|blocks|blocks-jacobian|points]
        [--compile [--compile-flags FLAGS]] [--solver ipopt|fatrop] [--restarts K]
        [--ipopt-option KEY=VALUE ...] [--degree K] [--perturb SEED] [--draws K]

The cold plan is ``casflex plan``'s, with its second start from the rigid move when the
first ends less than 10 % shorter than the shaped move (``starts``: each start's record,
None when not needed; the totals count both). With ``--restarts K`` the cold plan is
re-solved warm from itself up to ``K`` times (:func:`casflex.planning.plan_move`'s
``restarts``): ``solve_s``, ``solve_cpu_s`` and
``iterations`` are then the totals over the passes, ``passes`` each pass's duration,
iterations, status and times, ``restarts`` the restarts made; ``converged`` /
``converged_warm``: Ipopt's own convergence (False at a limit or the progress rule).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the perturbations of ``--draws`` (``--perturb SEED``; None: none), those of the
#: spread tables in benchmarks/README_planning.md since session 25
DRAW_SEEDS = (None, 0.5, 1.1, 1.9, 2.7, 3.3)
#: the figures of each draw kept in the record of ``--draws``
DRAW_KEYS = ("perturb", "solve_s", "solve_warm_s", "iterations", "iterations_warm",
             "duration", "residual", "status", "status_warm", "passes", "bound_corrections",
             "failed")



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
    parser.add_argument("--warm-hessian", choices=("exact", "limited-memory"),
                        default=None,
                        help="Hessian of the warm solve (default: as the cold solve's)")
    parser.add_argument("--dynamics", choices=("implicit", "explicit"), default="implicit",
                        help="form of the collocated dynamics (default implicit)")
    parser.add_argument("--move", default="move1", help="move of problems/moves.toml")
    parser.add_argument("--robust", type=float, default=0.0,
                        help="relative frequency error of the robust plan (default 0)")
    parser.add_argument("--dt", type=float, default=1e-4,
                        help="step of the verification by simulation [s] (default 1e-4: "
                             "1 ms straddles the plan's acceleration jumps)")
    parser.add_argument("--ocp-fit", choices=("chebyshev",), default=None,
                        help="the OCP's model from Chebyshev fits (verified on the tables)")
    parser.add_argument("--ocp-modes", type=int, default=None,
                        help="modes of the OCP's model (verified on the study's 3)")
    parser.add_argument("--no-progress-stop", action="store_true",
                        help="only Ipopt's own stopping tests (no ProgressStop)")
    parser.add_argument("--derivatives",
                        choices=("casadi", "blocks", "blocks-jacobian", "points"),
                        default="casadi",
                        help="the NLP's derivatives: CasADi's sweeps (default) or "
                             "per-interval blocks (casflex.planning.block_derivatives)")
    parser.add_argument("--solver", choices=("ipopt", "fatrop"), default="ipopt",
                        help="the NLP solver (fatrop: the stage-ordered OCP)")
    parser.add_argument("--compile-flags", default="-Os", metavar="FLAGS",
                        help="compiler flags of --compile (default -Os: the optimised "
                             "build casflex plan uses once it is cached; sessions 15-20 "
                             "measured with -O1)")
    parser.add_argument("--compile", action="store_true",
                        help="with --derivatives blocks: the interval blocks in C "
                             "(casflex.codegen.compile_cached; built once, cached)")
    parser.add_argument("--degree", type=int, default=3, metavar="K",
                        help="collocation points per interval (default 3)")
    parser.add_argument("--restarts", type=int, default=0, metavar="K",
                        help="warm re-solves of the cold plan (plan_move's restarts; "
                             "default 0: one solve)")
    parser.add_argument("--perturb", type=float, default=None, metavar="SEED",
                        help="with --compile: every nonzero of the compiled point Jacobian "
                             "and Hessian times 1 + 1e-9 sin(0.7 k + SEED), a draw of the "
                             "rounding-level differences between machines and builds "
                             "(default: none)")
    parser.add_argument("--draws", type=int, default=1, metavar="K",
                        help="with --compile: the run repeated for the first K of "
                             f"{DRAW_SEEDS} as --perturb SEED (None: unperturbed), one "
                             "process each; the unperturbed draw's record with the draws' "
                             "figures and ranges added (default 1: one run)")
    parser.add_argument("--ipopt-option", action="append", default=[],
                        metavar="KEY=VALUE", help="an Ipopt option (repeatable)")
    args = parser.parse_args(argv)
    if args.perturb is not None and not args.compile:
        parser.error("--perturb needs --compile (it perturbs the compiled derivatives)")
    if not 1 <= args.draws <= len(DRAW_SEEDS):
        parser.error(f"--draws {args.draws}: must be 1 to {len(DRAW_SEEDS)}")
    if args.draws > 1:
        if not args.compile or args.perturb is not None:
            parser.error("--draws needs --compile and no --perturb (it sets the draws')")
        return _draws(list(sys.argv[1:] if argv is None else argv), args.draws, args.json)

    from casflex.design.study import load_study
    from casflex.errors import SolverError
    from casflex.moves import load_move
    from casflex.planning import plan_move, plan_robot_move

    os.chdir(ROOT)
    study = load_study("problems/studies/arm2link_move1.toml")
    move = load_move(f"problems/moves.toml:{args.move}")
    # plan_move's own stopping rule (session 7's copy of it here, with 3 acceptable
    # iterates, overrode the fix of the acceptable stop)
    options = dict(_ipopt_option(o) for o in args.ipopt_option)
    if args.lbfgs:
        options["hessian_approximation"] = "limited-memory"
    kw = {"intervals": args.intervals, "ipopt_options": options,
          "transcription": args.transcription, "max_iter": args.max_iter,
          "dynamics": args.dynamics, "progress_stop": not args.no_progress_stop,
          "derivatives": args.derivatives, "solver": args.solver, "degree": args.degree}
    compiled = {}
    if args.compile:
        from casflex.codegen import compile_cached

        def compile_blocks(functions):
            # cse: as casflex plan's builds (casflex.planning.point_compiler)
            lib, info = compile_cached(functions, "plan_blocks",
                                       flags=tuple(args.compile_flags.split()), cse=True)
            compiled.setdefault("compile_s", []).append(info["seconds"])
            compiled.setdefault("built", []).append(info["built"])
            built = [lib[f.name()] for f in functions]
            if args.perturb is None:
                return built
            return [_perturbed(g, args.perturb) if any(k in f.name() for k in ("jac", "hess"))
                    else g for f, g in zip(functions, built, strict=True)]

        kw["compile_function"] = compile_blocks
    usage = resource.getrusage(resource.RUSAGE_SELF)
    # what `casflex plan` runs: the model (study's options), the SI-shaped move, its
    # limits (held joints: no torque limit), the plan, the 1 ms verification
    # load_study gives the grid step in rad (before session 25 it was converted again:
    # the bench ran on a 0.052° grid, 57 times finer than the study's 3°)
    try:
        c = plan_robot_move(study.robot, move, 3, step=study.model["grid_step"],
                            delta_order=study.model["delta_order"], processes=1,
                            robust=args.robust, dt=args.dt, ocp_fit=args.ocp_fit,
                            ocp_modes=args.ocp_modes, restarts=args.restarts, **kw)
    except SolverError as exc:  # no plan: the record of the failure (exit status 1)
        spent = getattr(exc, "solve", None) or {}
        _report({"failed": str(exc), "solve_s": spent.get("solve_s"),
                 "solve_cpu_s": spent.get("solve_cpu_s"), "iterations": spent.get("iterations"),
                 "solve_warm_s": None, "duration": None, "shaped_duration": None,
                 "residual": None, "shaped_residual": None, "intervals": args.intervals,
                 "move": args.move, "derivatives": args.derivatives, "solver": args.solver,
                 "load": os.getloadavg()[0]}, args.json)
        raise SystemExit(1) from exc
    after = resource.getrusage(resource.RUSAGE_SELF)
    plan, s = c.plan, c.summary()
    end = plan.stats["end"]
    # a neighbouring problem: the end bound 5 % tighter, warm-started from the plan
    kw_warm = dict(kw)
    if args.warm_hessian is not None:
        kw_warm["ipopt_options"] = {**options, "hessian_approximation": args.warm_hessian}
    warm = plan_move(c.ocp_model or c.model, move, end=0.95 * end, guess=plan, robust=args.robust,
                     torque_limit=c.limits["torque"], velocity_limit=c.limits["velocity"],
                     **kw_warm)
    # the solve's figures: the first plan's (plan_robot_move may have solved it again
    # with a tighter end bound when the verified residual passed it: bound_corrections)
    first = plan.stats.get("first_solve", plan.stats)
    corrections = s["bound_corrections"] or []
    passes = first.get("passes")
    # totals over the restarts and, when the first start stalled, both starts
    out = {"solve_s": first.get("solve_s_total", first["solve_s"]),
           "solve_warm_s": warm.stats["solve_s"],
           "restarts": first.get("restarts", 0), "passes": passes,
           "bound_corrections": corrections,
           "bound_corrections_s": sum(r["solve_s"] or 0.0 for r in corrections),
           "converged": first["converged"], "converged_warm": warm.stats["converged"],
           "duration": plan.duration, "shaped_duration": s["shaped"]["duration"],
           "residual": s["residual_tip_deflection"],
           "shaped_residual": s["shaped"]["residual_tip_deflection"],
           "intervals": plan.stats["intervals"], "degree": args.degree,
           "solve_cpu_s": first.get("solve_cpu_s_total", first["solve_cpu_s"]),
           "solve_warm_cpu_s": warm.stats["solve_cpu_s"],
           "residual_torque_driven": s["residual_torque_driven"],
           "residual_ocp": s["residual_ocp"], "robust": s["robust"],
           "shortening": s["shortening"], "torque_peak": s["torque_peak"],
           "shaped_torque_peak": s["shaped"]["torque_peak"], "limits": s["limits"],
           "duration_warm": warm.duration, "transcription": args.transcription,
           "dynamics": args.dynamics, "move": args.move,
           "hessian": plan.stats["hessian"], "hessian_warm": warm.stats["hessian"],
           "iterations": first.get("iterations_total", first["iterations"]),
           "starts": first.get("starts"),
           "iterations_warm": warm.stats["iterations"], "status": first["status"],
           "warm_start_duals": warm.stats.get("warm_start_duals"),
           "status_warm": warm.stats["status"],
           "run_cpu_s": (after.ru_utime + after.ru_stime) - (usage.ru_utime + usage.ru_stime),
           "max_rss_mb": after.ru_maxrss / 1024.0, "load": os.getloadavg()[0],
           "dt": args.dt, "grid_step_rad": study.model["grid_step"],
           "progress_stop": not args.no_progress_stop,
           "ocp_fit": args.ocp_fit, "ocp_modes": args.ocp_modes or 3,
           "derivatives": args.derivatives, "compiled": compiled or None,
           "solver": args.solver, "perturb": args.perturb,
           "timings": first.get("timings"),
           "timings_warm": warm.stats.get("timings"),
           "trace": [[round(f, 5), float(f"{v:.1e}")]
                     for f, v in first.get("objective_trace", [])],
           "trace_warm": [[round(f, 7), float(f"{v:.1e}")]
                          for f, v in warm.stats.get("objective_trace", [])]}
    _report(out, args.json)
    return out


def _draws(argv, count, as_json):
    """The run once per draw of :data:`DRAW_SEEDS` (a process each, ``--json``): the
    unperturbed draw's record plus ``draws`` (each draw's :data:`DRAW_KEYS`) and the
    ranges ``solve_s_range`` / ``solve_warm_s_range`` ([min, max] over the draws that
    found a plan; ``failed_draws`` counts the others)."""
    import subprocess

    drop = {i for i, a in enumerate(argv) if a == "--draws"}
    argv = [a for i, a in enumerate(argv)
            if i not in drop and i - 1 not in drop and not a.startswith("--draws=")]
    argv = argv + ["--json"] if "--json" not in argv else argv
    records = []
    for seed in DRAW_SEEDS[:count]:
        extra = [] if seed is None else ["--perturb", str(seed)]
        run = subprocess.run([sys.executable, __file__, *argv, *extra], capture_output=True,
                             text=True, check=False)
        lines = [line for line in run.stdout.splitlines() if line.startswith("{")]
        if not lines:  # neither a record nor a failure's record: the run itself broke
            raise SystemExit(f"bench_planning.py draw {seed}: no record "
                             f"(exit {run.returncode}):\n{run.stderr[-2000:]}")
        record = json.loads(lines[-1])
        record["perturb"] = seed
        records.append(record)
    out = dict(records[0])
    out["draws"] = [{k: r.get(k) for k in DRAW_KEYS} for r in records]
    found = [r for r in records if r.get("duration") is not None]
    for key in ("solve_s", "solve_warm_s"):
        values = [r[key] for r in found if r.get(key) is not None]
        out[key + "_range"] = [min(values), max(values)] if values else None
    out["failed_draws"] = len(records) - len(found)
    _report(out, as_json)
    return out


def _perturbed(function, seed):
    """``function`` with every nonzero ``k`` of its outputs times ``1 + 1e-9 sin(0.7 k +
    seed)``: the cold solve's path changes with differences of this size (another
    compiler, BLAS or machine), so one seed is one draw of its spread
    (benchmarks/README_planning.md, sessions 25-32)."""
    import casadi as ca
    import numpy as np

    inputs = [ca.MX.sym(function.name_in(i), function.sparsity_in(i))
              for i in range(function.n_in())]
    outputs = function.call(inputs)
    factors = [ca.DM(o.sparsity(), 1 + 1e-9 * np.sin(0.7 * np.arange(o.nnz()) + seed))
               for o in outputs]
    return ca.Function(function.name() + "_perturbed", inputs,
                       [o * f for o, f in zip(outputs, factors, strict=True)],
                       function.name_in(),
                       function.name_out())


def _report(out, as_json):
    """The record on stdout: one JSON object, or one ``key: value`` line per key."""
    if as_json:
        print(json.dumps(out))
    else:
        for key, value in out.items():
            print(f"{key:>18}: {value}", file=sys.stdout)


def _ipopt_option(text):
    """``KEY=VALUE`` as ``(key, value)``, the value an int, a float or a string."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise SystemExit(f"--ipopt-option {text!r}: must be KEY=VALUE")
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, value


if __name__ == "__main__":
    main()
