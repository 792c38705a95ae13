"""``casflex plan``: optimal point-to-point motion of a robot on its flexible model.

``casflex plan ROBOT.toml --move FILE:NAME [--objective time|energy] [--duration T]
[--robust R [--robust-steps K] [--robust-path frequency|bounds]] [--modes N] [--intervals N]
[--transcription collocation|shooting]
[--end rest|free|TOL] [--dt S] [--guess PLAN.npz] [--fallback-guess rigid|none] [--out DIR]
[--plot FILE.png] [--json]``

runs :func:`casflex.planning.plan_robot_move`: the gravity-free modal model of the robot
(tables cached), the SI-shaped version of the move (as ``casflex shaper`` designs it),
the optimal control problem at the shaped move's peak torques and velocities (so that
the comparison is fair; a joint the move holds gets no torque limit and a velocity limit
of 1e-3 of the moving joints'; ``--torque-limit`` / ``--velocity-limit`` override them;
the position limits are the robot file's joint limits) with
the shaped move's residual tip deflection as the end tolerance (``--end``), and the
verification of the plan by simulation at ``--dt`` (0.1 ms by default): the planned
joint motion with the prescribed-motion simulator and the planned torques with the
torque-driven simulator.
``--robust R`` makes the plan meet the end condition with the frequencies off by ±R too
(by default each scenario's bound is the shaped move's residual at that frequency error),
and evaluates both moves there; the robust plan is reached from the nominal plan through
``--robust-steps`` problems (4 by default: ``casflex.planning.solve_by_continuation``),
along ``--robust-path``: by default, with end bounds, every problem at ±R with the
scenarios' bounds tightened from 10 times theirs, the first started from the nominal plan
lifted into the robust problem (``bounds``); with ``--end rest|free`` R and the bounds
moved together (``frequency``).
A minimum-time plan from the shaped move that is not 10 % shorter than it (a solve that
stalled near its start; Ipopt's path here hinges on the last digits) is solved again from
the rigid bang-bang move, and the shorter plan kept (``--fallback-guess none``: one
start; :func:`casflex.planning.solve_with_fallback`).
``--guess PLAN.npz`` starts from a plan an earlier run wrote (``--out``): a warm start
from its iterate and multipliers, and with ``--robust`` the continuation starts there
instead of solving the nominal problem again (the nominal plan of move 1 of the design
study takes minutes; its robust path starts at once).

JSON: ``duration`` (s), ``torque_peak`` (N m, joints on the plan), ``velocity_peak``
(rad/s), ``residual_tip_deflection`` (verified with the joints on the plan, m),
``residual_torque_driven`` and ``residual_ocp`` (m), ``robust`` (residuals at ±R),
``shaped`` {``duration``, ``residual_tip_deflection``, ``torque_peak``,
``velocity_peak``}, ``shortening`` (1 − planned / shaped duration), ``limits``,
``limit_excess`` (per joint, how far the verified torque and velocity peaks pass the
limits between the OCP's points, relative), ``end_bound_excess`` (how far the verified
residual passes the end bound asked for, relative), ``bound_corrections`` (the re-solves
with a tighter bound when the verified residual passed it, ``--bound-corrections``),
``solve_s`` and ``iterations`` (over the restarts, starts and re-solves), ``passes``, ``starts``
(each start's, when the second was needed), ``status``, ``intervals``, ``substeps``, ``objective``,
``timings``. ``--out DIR`` writes ``trajectory.csv`` (t, q, q̇, q̈, τ), ``plan.npz``
(the whole plan, :meth:`casflex.planning.PlannedMove.save`, for ``--guess``) and
``plan.png``; ``--plot FILE.png`` the same figure. Interrupted (Ctrl-C) with ``--out``, it
writes the plan reached so far to ``DIR/plan.npz`` (the solve's last feasible iterate, the
best finished pass or the last finished problem of the robust path), and ``--guess
DIR/plan.npz`` continues from there. A robust path that finds no plan at some problem
writes its last plan there too; from a robust plan at ``±r`` the path resumes after
``r`` (:func:`casflex.planning.plan_robustness`), on the bound path after that plan's
bounds.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from casflex._validate import choice, fail, number, output_directory
from casflex.commands.common import (
    add_cache_arguments,
    add_modes_argument,
    add_processes_argument,
    add_robot_argument,
    cache_dir_of,
    parse_angle,
    plot_path,
)
from casflex.errors import SolverError

#: default step of the verification and of the shaped move's peaks [s]. A plan's joint
#: acceleration jumps at every one of its ~150 interval boundaries; a step that straddles
#: one integrates it to first order (move 2: 5.96 mm at 1 ms, 4.30 mm at 0.1 ms). Since
#: session 32 :func:`casflex.planning.verify_plan` puts its steps on the nodes (move 1:
#: the same residual to 5 digits from 0.1 to 0.02 ms), but the shaped move's ~15 switches
#: are still straddled: at 0.1 ms its residual is within 3e-4 of 0.05 ms's
DEFAULT_DT = 1e-4

HELP = ("plan the optimal (minimum-time or minimum-energy) motion of a move on the flexible "
        "model, at the limits of its SI-shaped version, and verify it by simulation")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``plan`` arguments to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["r.toml", "--move", "m.toml:a", "--robust", "0.1"])
    >>> a.robust, a.objective, a.intervals, a.transcription, a.dt
    (0.1, 'time', None, 'collocation', 0.0001)
    """
    add_robot_argument(parser)
    parser.add_argument("--move", metavar="FILE:NAME", required=True,
                        help="planned move, e.g. problems/moves.toml:move1")
    parser.add_argument("--objective", choices=("time", "energy"), default="time",
                        help="minimum time (default) or minimum energy ∫τᵀτ dt for "
                        "--duration")
    parser.add_argument("--duration", type=float, default=None, metavar="T",
                        help="duration of an energy plan, s (default the shaped move's)")
    parser.add_argument("--robust", type=float, default=0.0, metavar="R",
                        help="relative frequency error the end condition must withstand "
                        "(e.g. 0.1 = ±10 %%; default 0)")
    # the default is casflex.planning.ROBUST_STEPS, read when the command runs (the
    # parser does not import the planner); tests/planning/test_plan_cli.py checks the help
    parser.add_argument("--robust-steps", type=int, default=None, metavar="K",
                        help="with --robust: reach the robust plan from the nominal plan "
                        "through K problems, R and the bounds moved together (default 4; "
                        "1: the robust problem directly from the shaped move)")
    parser.add_argument("--robust-path", default=None, metavar="KIND",
                        help="with --robust: the path of those problems, 'frequency' (the "
                        "frequency error and the bounds moved together) or 'bounds' (the "
                        "bounds tightened at the full error) (default bounds with end "
                        "bounds, frequency with --end rest|free)")
    add_modes_argument(parser, 3, help="number of modes of the model (default 3)")
    parser.add_argument("--intervals", type=int, default=None, metavar="N",
                        help="intervals of the OCP (default 40 for shooting; for "
                        "collocation enough that ω_max T / N <= 1)")
    parser.add_argument("--transcription", choices=("collocation", "shooting"),
                        default="collocation",
                        help="Gauss-Legendre collocation, 3 points per interval (default), "
                        "or multiple shooting with RK4 substeps")
    parser.add_argument("--derivatives", default=None, metavar="KIND",
                        help="the NLP's derivatives: points (both from one collocation "
                        "point's, compiled to C once and cached; the default with "
                        "collocation and Ipopt), casadi (CasADi's sweeps; the default "
                        "otherwise), or with collocation blocks-jacobian (the interval's "
                        "own Jacobian scattered per interval) or blocks (its Hessian too)")
    parser.add_argument("--solver", default="ipopt", metavar="SOLVER",
                        help="the NLP solver: ipopt (MUMPS, the default) or fatrop (Riccati "
                        "over the stages; collocation with implicit dynamics, derivatives "
                        "casadi)")
    parser.add_argument("--hessian", choices=("exact", "limited-memory"), default="exact",
                        help="second derivatives of the Ipopt solves: exact (default) or "
                        "limited-memory (Ipopt's quasi-Newton L-BFGS: no Hessian to build or "
                        "compile)")
    parser.add_argument("--end", default=None, metavar="rest|free|TOL",
                        help="end condition of the modes: at rest, free, or a residual tip "
                        "deflection bound in m (default the shaped move's residual)")
    parser.add_argument("--torque-limit", type=float, nargs="+", default=None, metavar="N_M",
                        help="torque limit per joint (or one for all), N m (default the "
                        "shaped move's peaks)")
    parser.add_argument("--velocity-limit", type=float, nargs="+", default=None,
                        metavar="RAD_S", help="velocity limit per joint (or one for all), "
                        "rad/s (default the shaped move's peaks)")
    parser.add_argument("--step", default=None, metavar="S",
                        help="grid step of the modal tables, rad or with a 'deg' suffix")
    parser.add_argument("--delta-order", type=int, choices=(0, 1), default=1,
                        help="order in δ of the mass matrix (default 1)")
    parser.add_argument("--dt", type=float, default=DEFAULT_DT, metavar="S",
                        help="simulation step of the verification, s (default 1e-4: at "
                        "1e-3 the steps that straddle the plan's acceleration jumps move "
                        "its residual by up to 43 %%)")
    parser.add_argument("--max-iter", type=int, default=500, metavar="K",
                        help="iteration limit of Ipopt (default 500)")
    parser.add_argument("--restarts", type=int, default=2, metavar="K",
                        help="warm re-solves from the plan at most, while each shortens it "
                        "by at least 0.1 %% (default 2; 0: one solve)")
    # the default is casflex.planning.BOUND_CORRECTIONS, read when the command runs
    parser.add_argument("--bound-corrections", type=int, default=None, metavar="K",
                        help="when the verified residual passes the end bound (the OCP's "
                        "discretisation), solve again with the bound tightened by "
                        "bound / verified, at most K times (default 2; 0: the plan as "
                        "solved)")
    parser.add_argument("--fallback-guess", choices=("rigid", "none"), default="rigid",
                        help="minimum time from the shaped move: when its plan is not "
                        "10 %% shorter than the shaped move (or there is none), solve "
                        "again from the rigid bang-bang move and keep the shorter plan "
                        "(default rigid; none: one start)")
    parser.add_argument("--guess", default=None, metavar="PLAN.npz",
                        help="start from this plan of an earlier run (its --out's "
                        "plan.npz; the same move): a warm start, and with --robust the "
                        "continuation starts there")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="write trajectory.csv, plan.npz and plan.png to DIR (on "
                        "Ctrl-C, plan.npz: the plan reached so far)")
    parser.add_argument("--plot", default=None, metavar="FILE.png",
                        help="figure: shaped vs planned joint motion, torques and tip "
                        "deflection")
    add_processes_argument(parser, help="worker processes for the tables (default all CPUs)")
    add_cache_arguments(parser)


def _end(text):
    if text is None or text in ("rest", "free"):
        return text
    try:
        value = float(text)
    except ValueError:
        value = None
    return number(value if value is not None else text, "--end", low=0.0, low_open=True)


def _limit(values, n, option):
    if values is None:
        return {}
    if len(values) not in (1, n):
        from casflex._validate import fail

        raise fail(option, values, f"give one value or one per joint ({n})")
    for v in values:
        number(v, option, low=0.0, low_open=True)
    return {"torque_limit" if "torque" in option else "velocity_limit":
            values * n if len(values) == 1 else list(values)}


def _saved_plan(path, move):
    """The plan of ``--guess``: a file of ``PlannedMove.save`` for the move's end points."""
    import numpy as np

    from casflex._validate import fail
    from casflex.planning import PlannedMove

    plan = PlannedMove.load(path)
    for name, ours, theirs in (("start", plan.q0, move.q0), ("goal", plan.qf, move.qf)):
        if ours.shape != np.shape(theirs) or not np.allclose(ours, theirs, rtol=0.0,
                                                             atol=1e-9):
            raise fail("--guess", str(path), f"its {name} {np.round(ours, 6).tolist()} rad "
                       f"is not the move's {np.round(theirs, 6).tolist()} rad")
    return plan


def _keep(plan, why, reached, then, out, log):
    """Write ``plan``, what a run stopped by ``why`` had reached, to ``out/plan.npz`` for
    ``--guess`` (``then``: what ``--guess`` does with it), and say so."""
    if out is None:
        log(f"{why}: the {reached} is lost; with --out DIR it is kept for --guess")
        return
    out.mkdir(parents=True, exist_ok=True)
    plan.save(out / "plan.npz")
    log(f"{why}: the {reached} is in {out / 'plan.npz'}; --guess {out / 'plan.npz'} {then}")


def _keep_interrupted(exc, out, log):
    """Ctrl-C during the plan: write the plan it had reached to ``out/plan.npz``."""
    if exc.plan is None:
        log("interrupted before a feasible plan was reached: nothing to keep")
        return
    _keep(exc.plan, "interrupted", f"{exc.plan.duration:.4f} s plan reached ({exc.note})",
          "continues from it", out, log)


def _keep_reached(exc, out, log):
    """A robust path that found no plan at some problem: write the last plan it reached
    (``exc.plan``, its frequency error in its scenarios) to ``out/plan.npz``, from which
    ``--guess`` resumes the path."""
    from casflex.planning import plan_robustness

    plan = getattr(exc, "plan", None)
    if plan is None or getattr(exc, "continuation", None) is None:
        return
    _keep(plan, "no robust plan", f"{plan.duration:.4f} s plan of the last problem the path "
          f"finished (frequency error ±{plan_robustness(plan):g})",
          "resumes the path there (more --robust-steps make its steps shorter)", out, log)


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Plan ``args.move`` for ``args.robot``; return the comparison with the shaped move.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        See the module docstring (SI units).

    Examples
    --------
    >>> import argparse
    >>> try:
    ...     run(argparse.Namespace(robot="problems/onelink.toml", move="x.toml:a",
    ...                            robust=2.0), lambda m: None)
    ... except Exception as exc:
    ...     print(type(exc).__name__)
    ModelError
    """
    from casflex.moves import load_move
    from casflex.planning import (
        BOUND_CORRECTIONS,
        DERIVATIVES,
        ROBUST_PATHS,
        ROBUST_STEPS,
        SOLVERS,
        PlanInterrupted,
        default_derivatives,
        plan_robot_move,
        point_compiler,
    )
    from casflex.robot import load

    robust = number(float(getattr(args, "robust", 0.0)), "--robust", low=0.0, high=1.0,
                    high_open=True)
    modes = number(getattr(args, "modes", 3), "--modes", low=1, integer=True)
    intervals = getattr(args, "intervals", None)
    if intervals is not None:
        intervals = number(intervals, "--intervals", low=2, integer=True)
    dt = number(float(getattr(args, "dt", DEFAULT_DT)), "--dt", low=0.0, low_open=True, high=0.1)
    max_iter = number(getattr(args, "max_iter", 500), "--max-iter", low=1, integer=True)
    restarts = number(getattr(args, "restarts", 2), "--restarts", low=0, integer=True)
    corrections = getattr(args, "bound_corrections", None)
    corrections = BOUND_CORRECTIONS if corrections is None else \
        number(corrections, "--bound-corrections", low=0, integer=True)
    robust_steps = getattr(args, "robust_steps", None)
    robust_steps = ROBUST_STEPS if robust_steps is None else \
        number(robust_steps, "--robust-steps", low=1, integer=True)
    duration = getattr(args, "duration", None)
    if duration is not None:
        duration = number(float(duration), "--duration", low=0.0, low_open=True)
    end = _end(getattr(args, "end", None))
    robust_path = getattr(args, "robust_path", None)
    if robust_path is not None:
        robust_path = choice(robust_path, "--robust-path", ROBUST_PATHS)
    if robust and robust_path == "bounds" and isinstance(end, str):
        raise fail("--robust-path", robust_path, f"needs end bounds to tighten (--end TOL, "
                   f"or the shaped move's residuals by default), not --end {end}")
    solver = choice(getattr(args, "solver", "ipopt"), "--solver", SOLVERS)
    transcription = getattr(args, "transcription", "collocation")
    derivatives = getattr(args, "derivatives", None)
    if derivatives is None:  # the fastest that the transcription and the solver take
        derivatives = default_derivatives(transcription, solver)
    derivatives = choice(derivatives, "--derivatives", DERIVATIVES)
    out = getattr(args, "out", None)
    out = output_directory(out, "--out") if out else None
    plot = plot_path(getattr(args, "plot", None))
    step = getattr(args, "step", None)
    step = None if step is None else parse_angle(step, "--step")
    robot = load(args.robot)
    move = load_move(args.move)
    options = {**_limit(getattr(args, "torque_limit", None), robot.n_joints, "--torque-limit"),
               **_limit(getattr(args, "velocity_limit", None), robot.n_joints,
                        "--velocity-limit")}
    objective = getattr(args, "objective", "time")
    guess = getattr(args, "guess", None)
    if guess is not None:
        options["guess"] = _saved_plan(guess, move)
    if getattr(args, "fallback_guess", "rigid") == "none":
        options["fallback_guess"] = None
    hessian = choice(getattr(args, "hessian", "exact"), "--hessian",
                     ("exact", "limited-memory"))
    if hessian != "exact":
        options["ipopt_options"] = {"hessian_approximation": hessian}
    try:
        comparison = plan_robot_move(
            robot, move, modes, objective=objective, duration=duration, robust=robust,
            intervals=intervals, end=end, step=step,
            delta_order=getattr(args, "delta_order", 1), dt=dt,
            cache_dir=cache_dir_of(args),
            processes=getattr(args, "processes", None), progress=True, log=log,
            max_iter=max_iter, transcription=transcription, derivatives=derivatives,
            compile_function=point_compiler(derivatives, cache_dir_of(args), log),
            solver=solver, restarts=restarts, robust_steps=robust_steps,
            robust_path=robust_path,
            bound_corrections=corrections, **options)
    except PlanInterrupted as exc:  # keep what the solve had reached, for --guess
        _keep_interrupted(exc, out, log)
        raise
    except SolverError as exc:  # a robust path's last plan, for --guess
        _keep_reached(exc, out, log)
        raise
    summary = comparison.summary()
    log(f"planned {summary['duration']:.4f} s vs shaped {summary['shaped']['duration']:.4f} s "
        f"({100 * summary['shortening']:.1f} % shorter); residual tip deflection planned "
        f"{1e3 * summary['residual_tip_deflection']:.3f} mm (torque-driven "
        f"{1e3 * summary['residual_torque_driven']:.3f} mm, OCP "
        f"{1e3 * summary['residual_ocp']:.3f} mm), shaped "
        f"{1e3 * summary['shaped']['residual_tip_deflection']:.3f} mm")
    if objective == "time" and summary["shortening"] <= 0.0:
        # Ipopt may end near its start (an acceptable plateau) or on a longer path
        log(f"warning: the plan is not shorter than the shaped move ({summary['duration']:.4f}"
            f" s against {summary['shaped']['duration']:.4f} s, Ipopt status "
            f"{summary['status']}): the shaped move is the better motion at these limits")
    over = {k: max((e for e in excess if e is not None), default=0.0)
            for k, excess in summary["limit_excess"].items()}
    if any(e > 0.0 for e in over.values()):
        log("between the OCP's points the verified motion passes its limits by up to "
            + ", ".join(f"{100 * e:.2f} % ({k})" for k, e in over.items()))
    if summary["end_bound_excess"]:
        log(f"the verified residual passes the plan's end bound by "
            f"{100 * summary['end_bound_excess']:.2f} % (the OCP's discretisation; "
            f"Ipopt status {summary['status']})")
    for r in summary["robust"]:
        log(f"  frequency error {100 * r['error']:+g} %: planned "
            f"{1e3 * r['residual_tip_deflection']:.3f} mm, shaped "
            f"{1e3 * r['shaped_residual_tip_deflection']:.3f} mm")
    figure = None
    if plot or out:
        from casflex.plotting import plot_plan

        figure = plot_plan(comparison)
    if out:
        out.mkdir(parents=True, exist_ok=True)
        comparison.plan.to_csv(out / "trajectory.csv")
        comparison.plan.save(out / "plan.npz")
        figure.savefig(out / "plan.png", dpi=120)
        log(f"wrote {out / 'trajectory.csv'}, {out / 'plan.npz'} and {out / 'plan.png'}")
    if plot:
        figure.savefig(plot, dpi=120)
        log(f"wrote {plot}")
    return summary
