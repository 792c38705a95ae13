"""``casflex shaper``: design a specified-insensitivity input shaper.

Two forms:

``casflex shaper PROBLEM.toml [--dt S] [--plot FILE.png] [--time-limit S] [--json]``
    reads a shaper problem (a TOML file with ``[[range]]`` tables, see
    ``problems/shapers/README.md``), designs the SI shaper with
    :func:`casflex.shaping.si_shaper` and returns the impulses and the verified maximum
    residual vibration of every range (times in s, frequencies in rad/s), at the same
    instant (the constrained definition) and by eq. 187, with the grid LP's optimum, lower
    bound and gap. ``--dt S`` puts the impulses on the sample grid of a loop of period S
    (a digital shaper).

``casflex shaper ROBOT.toml --move FILE:NAME [--modes 3] [--margin 0.2] [--vtol 0.05]
[--plot FILE.png] [--json]``
    designs the shaper of a planned move of a robot (dissertation §6.1.4–6.1.5) with
    :func:`casflex.shaping.shaper_for_robot_move`: the modal model is built (tables
    cached), the modal contributions to the tip deflection give the tolerances
    (eq. 196–198), the frequency spans along the move widened by ``±margin`` give the
    ranges, and :func:`casflex.shaping.shaper_for_move` designs the shaper. The move is then
    simulated with the modal model (:func:`casflex.simulate.simulate_prescribed`), unshaped
    and shaped, and the residual tip deflection (largest ‖tip deflection‖ after the move —
    the shaped one — ends, m) of both is reported. Gravity is left out of the model, as in
    the dissertation's moves, so that the deflection is vibration only. ``--no-simulate``
    skips the simulations (the residual keys are then ``null``).

``--time-limit S`` bounds the wall-clock time of the design (default 60 s, 0 = no
limit; the ``time_limit`` of :func:`casflex.shaping.si_shaper`): beyond it the command fails
with a one-line error naming the option.

``--plot`` draws :func:`casflex.plotting.plot_prv` (problem form) or
:func:`casflex.plotting.plot_move_shaper` (robot form).

JSON of the robot form: the keys of the problem form plus ``"move"``, ``"margin"``,
``"contributions"`` (normalised ``r``, eq. 196), ``"raw_contributions"`` (m/s),
``"tolerances"`` (eq. 198), ``"omega_min"``/``"omega_max"`` (span of every mode along the
move without the margin, rad/s), ``"residual_tip_deflection_unshaped"``,
``"residual_tip_deflection_shaped"`` (m) and ``"residual_reduction"`` (fraction, 1 - shaped
/ unshaped).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from casflex._problemfile import read_toml
from casflex._validate import number
from casflex.commands.common import (
    add_cache_arguments,
    add_processes_argument,
    cache_dir_of,
    parse_angle,
)
from casflex.errors import ProblemFileError
from casflex.shaping import DEFAULT_TIME_LIMIT, ranges_from_mapping, si_shaper

HELP = ("design a specified-insensitivity input shaper from a shaper problem file, or for a "
        "planned move of a robot (ROBOT.toml --move FILE:NAME)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``shaper`` arguments to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["a.toml", "--plot", "x.png"]).plot
    'x.png'
    """
    parser.add_argument(
        "problem",
        metavar="PROBLEM.toml",
        help="shaper problem file with [[range]] tables (frequencies in rad/s or Hz), or a "
        "robot description together with --move",
    )
    parser.add_argument(
        "--plot",
        metavar="FILE.png",
        default=None,
        help="write the residual vibration curve over all ranges with the tolerances "
        "(robot form: and the simulated tip deflection, unshaped and shaped)",
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=DEFAULT_TIME_LIMIT,
        metavar="S",
        help=f"wall-clock limit of the shaper design, s (default {DEFAULT_TIME_LIMIT:g}; "
        "0 = no limit)",
    )
    robot = parser.add_argument_group("robot form (ROBOT.toml --move FILE:NAME)")
    robot.add_argument("--move", metavar="FILE:NAME", default=None,
                       help="planned move, e.g. problems/moves.toml:move1")
    robot.add_argument("--modes", type=int, default=3, metavar="N",
                       help="number of modes of the model (default 3)")
    robot.add_argument("--margin", type=float, default=0.2,
                       help="relative widening of every frequency span (default 0.2 = ±20 %%)")
    robot.add_argument("--vtol", type=float, default=0.05,
                       help="tolerable residual vibration of the dominant mode (default 0.05)")
    robot.add_argument("--step", default=None, metavar="S",
                       help="grid step of the modal tables, rad or with a 'deg' suffix "
                       "(default 1.5deg for one shape joint, 6deg for more)")
    add_processes_argument(robot)
    add_cache_arguments(robot)
    parser.add_argument("--dt", type=float, default=None, metavar="S",
                        help="shaper problem: sample time of the loop that runs the shaper, "
                        "s; the impulses are put on its grid (a digital shaper; default "
                        "none); robot form: simulation and reference sample step, s "
                        "(default 1e-3)")
    robot.add_argument("--no-simulate", action="store_true",
                       help="design only; do not simulate the unshaped and shaped moves")


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Design the shaper of ``args.problem``; return impulses and per-range checks.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"times": [...], "amplitudes": [...], "duration": s, "dt": s or None, "start",
        "lp_duration", "lp_lower_bound", "lp_gap", "ranges": [{"omega_min", "omega_max",
        "zeta", "vtol", "max_prv", "max_prv_eq187"}, ...]}`` (s, rad/s, fractions;
        ``max_prv`` is the vibration left at the same instant, the constrained one).

    Examples
    --------
    >>> import argparse, pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "one.toml"
    >>> _ = p.write_text("[[range]]\\nomega_min = 5.0\\nomega_max = 6.0\\nvtol = 0.05\\n")
    >>> out = run(argparse.Namespace(problem=str(p), plot=None), lambda m: None)
    >>> sorted(out)[:5]
    ['amplitudes', 'dt', 'duration', 'lp_duration', 'lp_gap']
    """
    path = Path(args.problem)
    data = read_toml(path)
    move = getattr(args, "move", None)
    if "range" not in data:
        if move is None:
            raise ProblemFileError(
                path,
                "range",
                None,
                "no [[range]] tables: this is not a shaper problem; for a robot description "
                "give the planned move with --move FILE:NAME",
            )
        return _run_robot(args, path, log)
    if move is not None:
        raise ProblemFileError(
            path, "--move", move, "a shaper problem file ([[range]] tables) takes no --move; "
            "--move goes with a robot description"
        )
    ranges = ranges_from_mapping(data, str(path))
    log(f"designing an SI shaper for {len(ranges)} frequency range(s) from {path}")
    dt = getattr(args, "dt", None)
    if dt is not None:
        dt = number(float(dt), "--dt", low=0.0, low_open=True, high=0.1)
    result = si_shaper(ranges, time_limit=_time_limit(args), dt=dt)
    log(
        f"{len(result.shaper)} impulses, duration {result.duration:.6f} s, "
        f"{result.iterations} NLP solve(s), start: {result.start}"
        + ("" if dt is None else f", on the {dt:g} s sample grid")
    )
    if result.lp_gap is not None:
        log(f"grid LP: optimum {result.lp_duration:.6f} s on a {result.lp_step:.3g} s grid, "
            f"lower bound {result.lp_lower_bound:.6f} s (gap {100 * result.lp_gap:.2f} %)")
    _log_impulses(result.shaper, log)
    for r, v, v187 in zip(result.ranges, result.max_prv, result.max_prv_eq187, strict=True):
        log(
            f"  range {r.omega_min:.4f}-{r.omega_max:.4f} rad/s, zeta {r.zeta:g}: "
            f"max V = {100 * v:.3f} % (Vtol {100 * r.vtol:.3f} %; eq. 187: {100 * v187:.3f} %)"
        )
    if getattr(args, "plot", None):
        from casflex.plotting import plot_prv

        plot_prv(result.shaper, result.ranges).savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return _shaper_json(result)


def _log_impulses(shaper, log):
    for t, a in zip(shaper.times, shaper.amplitudes, strict=True):
        log(f"  t = {t:.6f} s   A = {a:.6f}")


def _shaper_json(result):
    """Impulses and per-range checks of an SI design (s, rad/s, fractions)."""
    return {
        "times": result.shaper.times.tolist(),
        "amplitudes": result.shaper.amplitudes.tolist(),
        "duration": result.duration,
        "dt": result.lp_step if result.start == "digital" else None,
        "start": result.start,
        "lp_duration": result.lp_duration,
        "lp_lower_bound": result.lp_lower_bound,
        "lp_gap": result.lp_gap,
        "ranges": [
            {
                "omega_min": r.omega_min,
                "omega_max": r.omega_max,
                "zeta": r.zeta,
                "vtol": r.vtol,
                "max_prv": float(v),
                "max_prv_eq187": float(v187),
            }
            for r, v, v187 in zip(result.ranges, result.max_prv, result.max_prv_eq187,
                                  strict=True)
        ],
    }


def _residuals(model, move, shaper, dt, log):
    """Simulate the move unshaped and shaped; the residual tip deflections (m) and traces.

    Composed from library calls: :func:`casflex.simulate.simulate_prescribed` on the move
    and on :func:`casflex.shaping.shaped_reference`, and
    :func:`casflex.shaping.residual_amplitude` after the end of each move.
    """
    from casflex.shaping import residual_amplitude, shaped_reference
    from casflex.simulate import simulate_prescribed

    log(f"simulating {move.name} unshaped (dt = {dt:g} s, {move.t_end:g} s)")
    plain = simulate_prescribed(model, move, dt=dt, t_end=move.t_end)
    t_end = move.t_end + shaper.duration
    log(f"simulating {move.name} shaped ({t_end:g} s)")
    shaped = simulate_prescribed(model, shaped_reference(shaper, move, dt=dt), dt=dt,
                                 t_end=t_end)
    residual = {
        "unshaped": residual_amplitude(plain.t, plain.tip_deflection, move.duration),
        "shaped": residual_amplitude(shaped.t, shaped.tip_deflection,
                                     move.duration + shaper.duration),
    }
    traces = {"unshaped": (plain.t, plain.tip_deflection),
              "shaped": (shaped.t, shaped.tip_deflection)}
    return residual, traces


def _time_limit(args):
    """``--time-limit`` in s, None for 0 (no limit)."""
    limit = number(float(getattr(args, "time_limit", DEFAULT_TIME_LIMIT)), "--time-limit",
                   low=0.0)
    return limit if limit > 0.0 else None


def _run_robot(args, path, log):
    """The robot form: design the shaper of ``args.move`` for the robot at ``path``."""
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.shaping import shaper_for_robot_move

    robot = load(path)
    move = load_move(args.move)
    modes = number(getattr(args, "modes", 3), "--modes", low=1, integer=True)
    margin = number(float(getattr(args, "margin", 0.2)), "--margin", low=0.0, high=1.0,
                    high_open=True)
    vtol = number(float(getattr(args, "vtol", 0.05)), "--vtol", low=0.0, low_open=True,
                  high=1.0)
    dt = getattr(args, "dt", None)
    dt = number(float(1e-3 if dt is None else dt), "--dt", low=0.0, low_open=True, high=0.1)
    step = getattr(args, "step", None)
    step = None if step is None else parse_angle(step, "--step")
    model, result = shaper_for_robot_move(
        robot, move, modes, vtol=vtol, margin=margin, step=step,
        cache_dir=cache_dir_of(args), processes=getattr(args, "processes", None),
        progress=True, log=log, time_limit=_time_limit(args))
    for j, (r, v, lo, hi) in enumerate(zip(result.contributions, result.tolerances,
                                           result.omega_min, result.omega_max, strict=True)):
        log(f"  mode {j + 1}: omega {lo:.3f}-{hi:.3f} rad/s, r = {r:.3f}, Vtol = {v:.3f}")
    log(f"{len(result.shaper)} impulses, duration {result.duration:.6f} s")
    _log_impulses(result.shaper, log)
    residual, traces = {"unshaped": None, "shaped": None}, None
    reduction = None
    if not getattr(args, "no_simulate", False):
        residual, traces = _residuals(model, move, result.shaper, dt, log)
        unshaped, shaped = residual["unshaped"], residual["shaped"]
        reduction = 1.0 - shaped / unshaped if unshaped > 0.0 else None
        log(f"residual tip deflection: unshaped {1e3 * unshaped:.3f} mm, shaped "
            f"{1e3 * shaped:.3f} mm" + (f" ({100 * reduction:.1f} % less)"
                                         if reduction is not None else ""))
    if getattr(args, "plot", None):
        from casflex.plotting import plot_move_shaper

        plot_move_shaper(result, move.name, traces).savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return {
        **_shaper_json(result.si),
        "move": move.name,
        "margin": margin,
        "contributions": result.contributions.tolist(),
        "raw_contributions": result.raw_contributions.tolist(),
        "tolerances": result.tolerances.tolist(),
        "omega_min": result.omega_min.tolist(),
        "omega_max": result.omega_max.tolist(),
        "residual_tip_deflection_unshaped": residual["unshaped"],
        "residual_tip_deflection_shaped": residual["shaped"],
        "residual_reduction": reduction,
    }
