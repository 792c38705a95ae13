"""Planned against SI-shaped moves 1-3 of the design study, nominal and at a frequency error.

For every move of ``--moves`` (Table 9 moves of ``problems/moves.toml``) on the model of
``problems/studies/arm2link_move1.toml`` (Table 8 arm with the testbed's actuators, 3
modes, 3° grid, ``delta_order`` 0, no gravity):

1. the SI-shaped move (±20 %, Vtol 5 %, as the design study shapes it) and the nominal
   minimum-time plan at its peak torques and velocities, with its residual tip
   deflection as the end bound (:func:`casflex.planning.plan_robot_move`, what ``casflex
   plan`` runs; cold, from the shaped move);
2. for the moves of ``--robust-moves``: the robust plan (``robust = r``: the end bound
   must hold on the models whose frequencies are off by ±r too; each scenario's bound is
   the shaped move's residual at that error, as ``casflex plan --robust`` takes it),
   warm-started node by node from the nominal plan, or (``--robust-guess shaped``) cold
   from the SI-shaped move, which meets every scenario's bound and the limits already;
   with ``--robust-steps K`` through K problems from the nominal one along
   ``--robust-path`` (default :func:`casflex.planning.robust_path_for`: the bound path,
   every problem at ±r with the scenarios' bounds tightened from 10 times theirs; or r
   and the bounds moved together; :func:`casflex.planning.solve_by_continuation`);
3. each of them evaluated at the frequency errors −r, 0, +r
   (:func:`casflex.planning.frequency_shifted_model`) by the verification simulators at
   ``--dt`` (0.1 ms): the joints on the move (prescribed motion) and the move's torques
   open loop (torque-driven; for the shaped move, the torques of its nominal
   prescribed-motion run). Residual = largest ‖tip deflection‖ after the move ends.

4. for the moves of ``--tradeoff-moves``: the duration-vs-end-bound curve, nominal plans
   at ``--tolerances`` times the nominal plan's bound, each warm from the previous one
   and verified with the joints on it.

The plans' derivatives are ``--derivatives`` (default ``points``: the dynamics' Jacobian
and Hessian at one collocation point, compiled to C with ``--compile-flags``, default
``-O0``, through :func:`casflex.codegen.compile_cached`: seconds to build, cached; ``-O1``
solves faster but its first build costs ~170 s of CPU per model). A plan whose solve fails
(:class:`casflex.errors.SolverError`) is stored with its message (``failed``), not dropped.

Every finished step is written at once to ``--out`` (a JSON file, merged with what it
holds under a file lock: a run that is stopped keeps the moves it finished, and two runs
may fill one file side by side). A move (or the one-link cases) the file already holds is
skipped unless ``--redo``. Each run records in ``meta.runs`` the commit, the command, its
CPU seconds, the load and the script's ``FORMAT``. The file's SHA-256 is printed at the
end; ``notebooks/07_planning.py`` and ``tests/planning/test_plan_moves_data.py`` read the
stored ``benchmarks/data/planning_moves.json`` and check that hash.

``--plans DIR`` keeps the plans themselves (:meth:`casflex.planning.PlannedMove.save`):
``<move>_nominal.npz`` and ``<move>_robust.npz``. A nominal plan already in DIR is the
guess of the nominal solve (a warm re-solve, no restarts), so a robust run skips the
minutes of the nominal one.

``--onelink`` adds the one-link arm's cases of the notebook (cheap, seconds): the robust
and nominal plans of a 1 rad swing at ±10 % and the duration-vs-residual-tolerance
curve.

Usage::

    nice -n 10 python benchmarks/bench_planning_moves.py [--moves move1 move2 move3]
        [--robust-moves move1] [--robust 0.1] [--tradeoff-moves move1]
        [--tolerances 2 0.5 0.25] [--dt 1e-4] [--onelink]
        [--derivatives casadi|blocks|blocks-jacobian|points] [--compile-flags FLAGS]
        [--guess shaped|rigid] [--robust-guess nominal|shaped] [--robust-steps K]
        [--robust-path frequency|bounds]
        [--restarts K] [--plans DIR] [--redo]
        [--out benchmarks/data/planning_moves.json] [--json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "benchmarks" / "data" / "planning_moves.json"
#: sampling of the stored curves (joint motion, tip deflection) [s]
CURVE_DT = 5e-3
#: version of what the script stores (raised with every change of a record's meaning;
#: each run writes it into ``meta.runs``, tests/planning/test_plan_moves_data.py compares;
#: 4: plans evaluated on steps that divide their intervals, casflex.planning.node_step)
FORMAT = 4


def log(message: str) -> None:
    """One line on stderr with the wall clock, the process's CPU seconds and the load.

    Parameters
    ----------
    message : str
        What happened.
    """
    print(f"[{time.strftime('%H:%M:%S')} cpu {time.process_time():7.1f} s load "
          f"{os.getloadavg()[0]:4.1f}] {message}", file=sys.stderr, flush=True)


def _sig(x, digits=7):
    """Round to ``digits`` significant digits (JSON size; far below every tolerance)."""
    return [float(f"{v:.{digits}g}") for v in np.asarray(x, dtype=float).ravel()]


def residual_after(t, deflection, t_from):
    """Largest ‖tip deflection‖ at and after ``t_from`` [m]."""
    sel = t >= t_from - 1e-12
    return float(np.max(np.linalg.norm(deflection[sel], axis=1)))


def shaped_torque_law(model, run, duration):
    """The shaped move's torques of its nominal prescribed-motion run, open loop: read at
    the middle of each step (second order in the step), the holding torque after the
    move (zero without gravity)."""
    from casflex.planning import static_deflection

    qf = run.q[-1]
    hold = model.functions()["potential_forces"](
        qf, static_deflection(model, qf)).full().ravel()[:model.n]
    t, tau = run.t, run.tau
    dt = float(t[1] - t[0])

    def law(s, x):
        if s >= duration - 1e-9:
            return hold
        return np.array([np.interp(s + 0.5 * dt, t, tau[:, j]) for j in range(model.n)])

    return law


def evaluate(model, reference, torque_law, errors, dt):
    """Residuals of ``reference`` at each frequency error: joints on it, torques open loop.

    Returns the record of one move: ``errors``, ``prescribed`` and ``torque`` residuals
    [m] per error, the joint end error of the torque runs [rad], the nominal run's
    torque and velocity peaks, and its curves every ``CURVE_DT``."""
    from casflex.planning import PlannedMove, frequency_shifted_model, node_step, static_deflection
    from casflex.simulate import simulate_prescribed, simulate_torque

    if isinstance(reference, PlannedMove):  # steps on its nodes, as verify_plan's
        dt = node_step(reference, dt)
    T, t_end = float(reference.duration), float(reference.t_end)
    out = {"errors": [float(r) for r in errors], "prescribed": [], "torque": [],
           "torque_end_error": []}
    nominal = None
    for r in errors:
        mod = frequency_shifted_model(model, float(r))
        d0 = static_deflection(mod, reference.q0)
        pres = simulate_prescribed(mod, reference, dt=dt, t_end=t_end)
        out["prescribed"].append(residual_after(pres.t, pres.tip_deflection, T))
        x0 = np.r_[reference.q0, d0, np.zeros(mod.n + mod.m)]
        tr = simulate_torque(mod, torque_law, x0, t_end=t_end, dt=dt)
        out["torque"].append(residual_after(tr.t, tr.tip_deflection, T))
        k = min(int(np.searchsorted(tr.t, T - 1e-12)), tr.t.size - 1)
        out["torque_end_error"].append(float(np.linalg.norm(tr.q[k] - reference.qf)))
        log(f"  error {r:+.2f}: residual prescribed {1e3 * out['prescribed'][-1]:.4f} mm, "
            f"torque-driven {1e3 * out['torque'][-1]:.4f} mm")
        if r == 0.0:
            nominal = pres
    if nominal is None:
        nominal = simulate_prescribed(model, reference, dt=dt, t_end=t_end)
    out["torque_peak"] = nominal.torque_peak.tolist()
    out["velocity_peak"] = np.max(np.abs(nominal.dq), axis=0).tolist()
    stride = max(1, int(round(CURVE_DT / dt)))
    out["curves"] = {"t": _sig(nominal.t[::stride], 6),
                     "q": [_sig(c, 6) for c in nominal.q[::stride].T],
                     "tip_deflection": _sig(np.linalg.norm(
                         nominal.tip_deflection[::stride], axis=1), 5)}
    return out, nominal


def plan_record(plan, limits, evaluation, model):
    """The stored record of a plan: its statistics, limits, limit excess and evaluation."""
    from casflex.planning import asked_bounds, limit_excess

    st = plan.stats
    rec = {"duration": plan.duration, "status": st.get("status"),
           "iterations": st.get("iterations"), "solve_s": st.get("solve_s"),
           "solve_cpu_s": st.get("solve_cpu_s"), "intervals": st.get("intervals"),
           # the bounds asked for; the OCP's own when it was solved again tighter for
           # its verified residual (bound_corrections)
           "end_bound": (asked_bounds(st) or [st.get("end")])[0],
           "end_bounds": asked_bounds(st),
           "ocp_end_bounds": st.get("end_bounds"),
           "bound_corrections": st.get("bound_corrections"),
           "scenarios": st.get("scenarios"),
           "ocp_residual": st.get("ocp_residual"),
           "residual_bound": st.get("residual_bound"),
           "warm_start": st.get("warm_start"),
           "limits": {k: [float(v) for v in val] for k, val in limits.items()}}
    rec.update(evaluation)
    rec["limit_excess"] = {k: limit_excess(evaluation[f"{k}_peak"], limits[k])
                           for k in ("torque", "velocity")}
    return rec


def store(path: Path, key: str, value) -> None:
    """Merge ``{key: value}`` into the JSON file at ``path`` (atomically)."""
    import fcntl

    from casflex._cache import atomic_write_text

    path.parent.mkdir(parents=True, exist_ok=True)
    # two runs (e.g. move 1 and moves 2-3 on the two cores) may fill the same file: the
    # read-merge-write is done under an exclusive lock so that neither loses the other's
    with open(path.with_suffix(path.suffix + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        data = json.loads(path.read_text()) if path.exists() else {}
        if key == "meta":
            runs = {**data.get("meta", {}).get("runs", {}), **value.get("runs", {})}
            value = {**data.get("meta", {}), **value, "runs": runs}
        data[key] = value
        data.setdefault("meta", {})
        atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def derivative_options(args):
    """``plan_move``'s ``derivatives`` (and ``compile_function``: the point functions in C
    through :func:`casflex.codegen.compile_cached`, built once per model and flags)."""
    options = {"derivatives": args.derivatives}
    if args.derivatives in ("blocks", "points") and args.compile_flags != "none":
        from casflex.codegen import compile_cached

        def compile_function(functions):
            lib, info = compile_cached(functions, f"plan_{args.derivatives}",
                                       flags=tuple(args.compile_flags.split()), cse=True)
            log(f"  compiled ({args.compile_flags}): built {info['built']}, "
                f"{info['seconds']:.1f} s")
            return [lib[f.name()] for f in functions]

        options["compile_function"] = compile_function
    return options


def _done(out_path, name, robust):
    """Whether ``out_path`` already holds the move (with its robust plan if asked for)."""
    if not out_path.exists():
        return False
    rec = json.loads(out_path.read_text()).get(name)
    return bool(rec) and "planned" in rec and (not robust or "robust" in rec)


def _failure(error, cpu):
    """The stored record of a plan that failed: the error's message, never dropped."""
    return {"failed": f"{type(error).__name__}: {error}", "case_cpu_s": cpu}


def run_move(name, args, study, out_path, robust_moves):
    """Shaped, nominal plan and (for ``robust_moves``) robust plan of one move."""
    from casflex.errors import SolverError
    from casflex.moves import load_move
    from casflex.planning import (
        ProgressStop,
        continuation_ceiling,
        hold_verified_bounds,
        plan_move,
        plan_robot_move,
        robust_path_for,
        verify_plan,
    )

    move = load_move(f"problems/moves.toml:{name}")
    r = args.robust
    errors = [-r, 0.0, r]
    options = derivative_options(args)
    log(f"{name}: nominal plan (cold, from the {args.guess} move)")
    # the cold solve's guess only (the restarts and the robust plan start from a plan).
    # The cold solve stops on the progress of T along a path-dependent descent
    # (README_planning.md, sessions 9-11); plan_move's restarts solve the same problem
    # again from where it stopped (iterate and multipliers) and keep the shortest pass.
    first = {"guess": "rigid"} if args.guess == "rigid" else {}
    restarts = args.restarts
    saved = args.plans / f"{name}_nominal.npz" if args.plans else None
    if saved is not None and saved.exists():
        from casflex.planning import PlannedMove

        first, restarts = {"guess": PlannedMove.load(saved)}, 0
        log(f"{name}: the nominal plan of {saved} as the guess (no restarts)")
    c0 = time.process_time()
    # the grid step of load_study is in rad already (sessions before 25 converted it again:
    # the stored plans are of a 0.052° grid, 57 times finer than the study's 3°)
    c = plan_robot_move(study.robot, move, args.modes, step=study.model["grid_step"],
                        delta_order=study.model["delta_order"], processes=1, dt=args.dt,
                        vtol=study.shaper["vtol"], margin=study.shaper["margin"],
                        max_iter=args.max_iter, log=log, restarts=restarts, **options,
                        **first)
    model, shaped, plan = c.model, c.shaped, c.plan
    if saved is not None and not saved.exists():
        args.plans.mkdir(parents=True, exist_ok=True)
        plan.save(saved)
    limits = {k: np.asarray(v, dtype=float) for k, v in c.limits.items()}
    # the solve's figures are the first plan's (plan_robot_move may have solved it again
    # with a tighter bound: bound_corrections in the record)
    solved = plan.stats.get("first_solve", plan.stats)
    passes = solved.get("passes") or [{"duration": plan.duration,
                                       "status": solved["status"],
                                       "iterations": solved["iterations"],
                                       "solve_cpu_s": solved["solve_cpu_s"]}]
    restarts, best = [], passes[0]["duration"]
    for again in passes[1:]:
        restarts.append({"from": best, **{k: again[k] for k in (
            "duration", "status", "iterations", "solve_cpu_s")}})
        if again["duration"] is not None:
            best = min(best, again["duration"])
    for k, again in enumerate(passes):
        log(f"{name}: pass {k}: " + (f"{again['duration']:.4f} s ({again['status']}, "
                                     f"{again['iterations']} iterations)"
                                     if again["duration"] is not None else again["status"]))
    log(f"{name}: planned {plan.duration:.4f} s; shaped {shaped.duration:.4f} s; "
        f"run CPU {time.process_time() - c0:.0f} s")
    nominal_cpu = time.process_time() - c0
    log(f"{name}: evaluating the shaped move at {errors}")
    shaped_run = c.shaped_verification["run"]
    shaped_eval, _ = evaluate(model, shaped, shaped_torque_law(model, shaped_run,
                                                               shaped.duration), errors,
                              args.dt)
    record = {"move": name, "description": move.description,
              "q0": move.q0.tolist(), "qf": move.qf.tolist(),
              "shaped": {"duration": float(shaped.duration),
                         "shaper": {"times": _sig(shaped.shaper.times, 10),
                                    "amplitudes": _sig(shaped.shaper.amplitudes, 10)},
                         **shaped_eval}}
    # an earlier attempt at this move (another --guess, say) is kept in the record
    previous = json.loads(out_path.read_text()).get(name, {}) if out_path.exists() else {}
    record["attempts"] = previous.get("attempts", [])
    if "planned" in previous:
        old = previous["planned"]
        record["attempts"].append({k: old.get(k) for k in (
            "duration", "status", "iterations", "solve_cpu_s", "guess", "prescribed",
            "torque", "errors")})
    log(f"{name}: evaluating the nominal plan at {errors}")
    ev, _ = evaluate(model, plan, plan.torque_function(), errors, args.dt)
    record["planned"] = plan_record(plan, limits, ev, model)
    # starts: both cold starts' records when the first stalled (None if not needed); the
    # passes and "cold" are then the kept start's
    record["planned"].update(case_cpu_s=nominal_cpu, restarts=restarts, guess=args.guess,
                             starts=solved.get("starts"),
                             cold={k: passes[0][k] for k in (
                                 "duration", "status", "iterations", "solve_cpu_s")})
    store(out_path, name, record)
    log(f"{name}: nominal stored")
    if name in robust_moves:
        # one bound per scenario (0, -r, +r): the shaped move's residual at that error
        res = dict(zip(errors, shaped_eval["prescribed"], strict=True))
        end = [res[0.0], res[-r], res[r]]
        start = {"nominal": plan, "shaped": shaped}[args.robust_guess]
        path = robust_path_for(end, args.robust_path)
        log(f"{name}: robust ±{r:g} plan, end bounds {[round(1e3 * b, 4) for b in end]} mm "
            f"(the shaped move's at 0, -r, +r), from the {args.robust_guess} move, "
            f"{path} path")
        c0 = time.process_time()
        try:
            # as casflex plan --robust (plan_robot_move): a problem of the continuation
            # that rises above the shaped move's duration has lost its way and is retried
            # with a shorter step (without it, move 1's first problem went to 3.84 s)
            robust = plan_move(model, move, end=end, robust=r, guess=start,
                               robust_steps=args.robust_steps, robust_path=path, log=log,
                               restarts=args.restarts,
                               duration_ceiling=continuation_ceiling(
                                   "time", r, args.robust_steps, shaped.duration, path),
                               torque_limit=limits["torque"],
                               velocity_limit=limits["velocity"], max_iter=args.max_iter,
                               progress_stop=ProgressStop(leave=0.0), **options)
            # as casflex plan: a verified residual past its scenario's bound is solved
            # again with the bounds tightened (hold_verified_bounds)
            robust, _, _ = hold_verified_bounds(
                lambda bounds, last: plan_move(
                    model, move, end=bounds, robust=r, guess=last,
                    elastic=last.stats.get("elastic"),
                    intervals=robust.stats["intervals"], torque_limit=limits["torque"],
                    velocity_limit=limits["velocity"], max_iter=args.max_iter, log=log,
                    progress_stop=ProgressStop(leave=0.0), **options),
                lambda p: verify_plan(model, p, dt=args.dt, errors=[-r, r]), robust,
                verify_plan(model, robust, dt=args.dt, errors=[-r, r]), log=log)
        except SolverError as error:
            record["robust"] = {**_failure(error, time.process_time() - c0), "robust": r,
                                "end_bounds": end, "guess": args.robust_guess,
                                "robust_steps": args.robust_steps, "robust_path": path,
                                "continuation": getattr(error, "continuation", None)}
            log(f"{name}: robust plan failed: {error}")
        else:
            cpu = time.process_time() - c0
            log(f"{name}: robust {robust.duration:.4f} s ({robust.stats['status']}, "
                f"{robust.stats['iterations']} iterations, "
                f"{robust.stats['solve_cpu_s']:.0f} s CPU)")
            if args.plans:
                robust.save(args.plans / f"{name}_robust.npz")
            ev, _ = evaluate(model, robust, robust.torque_function(), errors, args.dt)
            record["robust"] = plan_record(robust, limits, ev, model)
            solved = robust.stats.get("first_solve", robust.stats)  # before a re-solve
            record["robust"].update(robust=r, case_cpu_s=cpu, guess=args.robust_guess,
                                    robust_steps=args.robust_steps, robust_path=path,
                                    continuation=solved.get("continuation"),
                                    passes=solved.get("passes"))
        store(out_path, name, record)
        log(f"{name}: robust stored")
    if name in args.tradeoff_moves:
        record["tradeoff"] = tradeoff(model, move, plan, limits, args, options)
        store(out_path, name, record)
        log(f"{name}: trade-off curve stored")
    return record


def tradeoff(model, move, nominal, limits, args, options):
    """Duration against the end bound: nominal plans at ``--tolerances`` (fractions of
    the nominal plan's bound, each warm-started from the previous one), each verified
    with the joints on it (prescribed motion, nominal model)."""
    from casflex.planning import ProgressStop, plan_move
    from casflex.planning.restarts import solve_from_plan
    from casflex.simulate import simulate_prescribed

    base = float(nominal.stats["end"])
    curve, previous = [], nominal
    for f in sorted(args.tolerances, reverse=True):
        c0 = time.process_time()
        # from the previous plan (its iterate and multipliers, or its iterate alone if
        # the multipliers lead Ipopt astray)
        p, failures = solve_from_plan(plan_move, dict(
            model=model, start=move, end=f * base, torque_limit=limits["torque"],
            velocity_limit=limits["velocity"], max_iter=args.max_iter,
            progress_stop=ProgressStop(leave=0.0), **options), previous)
        for error in failures:
            log(f"  trade-off {f:g}: failed: {error}")
        if p is None:
            curve.append({"fraction": f, "bound": f * base,
                          **_failure(failures[-1], time.process_time() - c0)})
            continue
        run = simulate_prescribed(model, p, dt=args.dt, t_end=p.t_end)
        curve.append({"fraction": f, "bound": f * base, "duration": p.duration,
                      "failed_first": [f"SolverError: {e}" for e in failures],
                      "prescribed": residual_after(run.t, run.tip_deflection, p.duration),
                      "status": p.stats["status"], "iterations": p.stats["iterations"],
                      "case_cpu_s": time.process_time() - c0})
        log(f"  trade-off {f:g}: {p.duration:.4f} s, residual "
            f"{1e3 * curve[-1]['prescribed']:.4f} mm ({p.stats['status']})")
        previous = p
    return {"base_bound": base, "curve": curve}


def run_onelink(args, out_path):
    """The one-link arm's robust comparison and duration-vs-tolerance curve (seconds)."""
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.planning import plan_move, verify_plan
    from casflex.robot import load

    robot = load("problems/onelink.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    kw = {"torque_limit": 0.1, "intervals": 84, "settle": 1.0}
    bound, r = 2e-3, args.robust
    rec = {"case": "problems/onelink.toml, 1 mode, 0 -> 1 rad at 0.1 N m, 84 intervals",
           "bound": bound, "robust": r, "errors": [-r, 0.0, r], "plans": {}}
    for label, rb in (("nominal", 0.0), ("robust", r)):
        p = plan_move(model, [0.0], [1.0], end=bound, robust=rb, **kw)
        v = verify_plan(model, p, dt=1e-4, errors=[-r, r], torque=False)
        rec["plans"][label] = {"duration": p.duration, "status": p.stats["status"],
                               "prescribed": [v["errors"][0]["prescribed"], v["prescribed"],
                                              v["errors"][1]["prescribed"]]}
        log(f"onelink {label}: {p.duration:.4f} s, residuals "
            f"{[round(1e3 * x, 4) for x in rec['plans'][label]['prescribed']]} mm")
    bounds = [5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4]
    free = plan_move(model, [0.0], [1.0], end="free", **kw)
    previous, curve = free, []
    for b in bounds:
        p = plan_move(model, [0.0], [1.0], end=b, guess=previous, **kw)
        v = verify_plan(model, p, dt=1e-4, torque=False)
        curve.append({"bound": b, "duration": p.duration, "prescribed": v["prescribed"],
                      "status": p.stats["status"]})
        previous = p
    rest = plan_move(model, [0.0], [1.0], end="rest", guess=previous, **kw)
    J = 0.01 + 2700.0 * 0.007 * 0.005 * 1.0**3 / 3.0
    rec["tradeoff"] = {"curve": curve, "free": free.duration,
                       "free_residual": free.stats["ocp_residual"], "rest": rest.duration,
                       "rigid_minimum": 2.0 * math.sqrt(1.0 * J / 0.1)}
    store(out_path, "onelink", rec)
    log("onelink stored")
    return rec


def main(argv: list[str] | None = None) -> dict:
    """Run the comparison; print a summary or (``--json``) the stored JSON object.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments.

    Returns
    -------
    dict
        What the output file holds.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moves", nargs="*", default=["move1", "move2", "move3"])
    parser.add_argument("--robust-moves", nargs="*", default=["move1"])
    parser.add_argument("--robust", type=float, default=0.1)
    parser.add_argument("--dt", type=float, default=1e-4,
                        help="step of the verification simulators [s]")
    parser.add_argument("--max-iter", type=int, default=500)
    parser.add_argument("--modes", type=int, default=3, help="modes of the model (study: 3)")
    parser.add_argument("--derivatives", default="points",
                        choices=["casadi", "blocks", "blocks-jacobian", "points"],
                        help="the NLP's derivatives (plan_move's derivatives)")
    parser.add_argument("--compile-flags", default="-O0", metavar="FLAGS",
                        help="compile the point functions with these flags ('none': "
                             "interpreted)")
    parser.add_argument("--tradeoff-moves", nargs="*", default=[],
                        help="moves whose duration-vs-end-bound curve is stored")
    parser.add_argument("--tolerances", nargs="*", type=float,
                        default=[2.0, 0.5, 0.25],
                        help="end bounds of the trade-off curve, in units of the nominal "
                             "plan's bound")
    parser.add_argument("--guess", default="shaped", choices=["shaped", "rigid"],
                        help="initial guess of the cold solve: the SI-shaped move (what "
                             "casflex plan does) or the rigid time-optimal move")
    parser.add_argument("--robust-guess", default="nominal", choices=["nominal", "shaped"],
                        help="start of the robust plan: warm from the nominal plan, or "
                             "cold from the SI-shaped move")
    parser.add_argument("--robust-steps", type=int, default=1, metavar="K",
                        help="reach the robust plan by a continuation of K problems from "
                             "the nominal one (plan_move's robust_steps)")
    parser.add_argument("--robust-path", default=None, choices=["frequency", "bounds"],
                        help="the path of those problems (plan_move's robust_path; "
                             "default: bounds, the robust moves having end bounds)")
    parser.add_argument("--restarts", type=int, default=0, metavar="K",
                        help="solve the nominal plan again from where it stopped, up to K "
                             "times while it gets shorter")
    parser.add_argument("--plans", type=Path, default=None, metavar="DIR",
                        help="save every plan to DIR (<move>_nominal.npz, "
                        "<move>_robust.npz); a nominal plan already there is the guess "
                        "of the nominal solve (a warm re-solve of it, no restarts)")
    parser.add_argument("--redo", action="store_true",
                        help="recompute moves the output file already holds")
    parser.add_argument("--onelink", action="store_true")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    from casflex.design.study import load_study

    os.chdir(ROOT)
    out_path = args.out.resolve()
    study = load_study("problems/studies/arm2link_move1.toml")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=ROOT).stdout.strip()
    meta = {"robust": args.robust, "dt": args.dt, "study": "arm2link_move1.toml",
            "modes": args.modes, "commit": commit, "curve_dt": CURVE_DT,
            "derivatives": args.derivatives, "compile_flags": args.compile_flags,
            "format": FORMAT, "restarts": args.restarts, "guess": args.guess,
            "robust_guess": args.robust_guess, "robust_steps": args.robust_steps,
            "robust_path": args.robust_path,
            "command": "python benchmarks/bench_planning_moves.py "
                       + " ".join(sys.argv[1:] if argv is None else argv)}
    if args.onelink and (args.redo or not (out_path.exists() and "onelink"
                                           in json.loads(out_path.read_text()))):
        run_onelink(args, out_path)
        store(out_path, "meta", {"dt": args.dt, "robust": args.robust,
                                 "runs": {"onelink": {**meta, "date": time.strftime(
                                     "%Y-%m-%d %H:%M UTC", time.gmtime())}}})
    for name in args.moves:
        if not args.redo and _done(out_path, name, name in args.robust_moves):
            log(f"{name}: already in {out_path.name}, skipped (--redo to recompute)")
            continue
        c0 = time.process_time()
        run_move(name, args, study, out_path, set(args.robust_moves))
        store(out_path, "meta", {"dt": args.dt, "robust": args.robust, "runs": {name: {
            **meta, "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "load": os.getloadavg()[0], "cpu_s": time.process_time() - c0}}})
    data = json.loads(out_path.read_text())
    log(f"{out_path}: sha256 {hashlib.sha256(out_path.read_bytes()).hexdigest()}")
    if args.json:
        print(json.dumps(data))
    return data


if __name__ == "__main__":
    main()
