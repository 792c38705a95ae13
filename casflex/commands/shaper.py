"""``casflex shaper``: design a specified-insensitivity input shaper.

Two forms:

``casflex shaper PROBLEM.toml [--plot FILE.png] [--json]``
    reads a shaper problem (a TOML file with ``[[range]]`` tables, see
    ``problems/shapers/README.md``), designs the SI shaper with
    :func:`casflex.shaping.si_shaper` and returns the impulses and the verified maximum
    residual vibration of every range (times in s, frequencies in rad/s).

``casflex shaper ROBOT.toml --move FILE:NAME [--modes 3] [--margin 0.2] [--vtol 0.05]
[--plot FILE.png] [--json]``
    designs the shaper of a planned move of a robot (dissertation §6.1.4–6.1.5): the
    modal model is built with :func:`casflex.model.build_model` (tables cached), the
    modal contributions to the tip deflection give the tolerances (eq. 196–198), the
    frequency spans along the move widened by ``±margin`` give the ranges, and
    :func:`casflex.shaping.shaper_for_move` designs the shaper. The move is then
    simulated with the modal model (:func:`casflex.simulate.simulate_prescribed`), unshaped
    and shaped, and the residual tip deflection (largest ‖tip deflection‖ after the move —
    the shaped one — ends, m) of both is reported. Gravity is left out of the model, as in
    the dissertation's moves, so that the deflection is vibration only. ``--no-simulate``
    skips the simulations (the residual keys are then ``null``).

JSON of the robot form: the keys of the problem form plus ``"move"``, ``"margin"``,
``"contributions"`` (normalised ``r``, eq. 196), ``"raw_contributions"`` (m/s),
``"tolerances"`` (eq. 198), ``"omega_min"``/``"omega_max"`` (span of every mode along the
move without the margin, rad/s), ``"residual_tip_deflection_unshaped"``,
``"residual_tip_deflection_shaped"`` (m) and ``"residual_reduction"`` (fraction, 1 - shaped
/ unshaped).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from casflex.commands.common import parse_angle
from casflex.errors import ModelError, ProblemFileError
from casflex.shaping import (
    ranges_from_mapping,
    residual_vibration,
    si_shaper,
)

HELP = ("Design a specified-insensitivity input shaper from a shaper problem file, or for a "
        "planned move of a robot (ROBOT.toml --move FILE:NAME).")


def add_arguments(parser):
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
    robot = parser.add_argument_group("robot form (ROBOT.toml --move FILE:NAME)")
    robot.add_argument("--move", metavar="FILE:NAME", default=None,
                       help="planned move, e.g. problems/moves.toml:move1")
    robot.add_argument("--modes", type=int, default=3, metavar="M",
                       help="number of modes of the model (default 3)")
    robot.add_argument("--margin", type=float, default=0.2,
                       help="relative widening of every frequency span (default 0.2 = ±20 %%)")
    robot.add_argument("--vtol", type=float, default=0.05,
                       help="tolerable residual vibration of the dominant mode (default 0.05)")
    robot.add_argument("--step", default=None, metavar="S",
                       help="grid step of the modal tables, rad or with a 'deg' suffix "
                       "(default: 1.5deg for one shape joint, 6deg for more)")
    robot.add_argument("--processes", type=int, default=None, metavar="P",
                       help="worker processes for the tables (default: all CPUs; 1 = no pool)")
    robot.add_argument("--cache-dir", default=None, metavar="DIR",
                       help="cache directory of the modal tables (default: casflex's cache)")
    robot.add_argument("--dt", type=float, default=1e-3,
                       help="simulation and reference sample step, s (default 1e-3)")
    robot.add_argument("--no-simulate", action="store_true",
                       help="design only; do not simulate the unshaped and shaped moves")


def _read(path):
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(path, "<file>", str(path), f"is not valid TOML: {exc}") from exc


def _plot(result, filename):
    """Write the PRV curve of ``result`` over all ranges (Agg canvas, no global backend)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ranges = result.ranges
    lo = min(r.omega_min for r in ranges)
    hi = max(r.omega_max for r in ranges)
    span = hi - lo if hi > lo else hi
    w = np.linspace(max(lo - 0.25 * span, 1e-3 * hi), hi + 0.25 * span, 3000)
    fig = Figure(figsize=(7.0, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    zetas = sorted({r.zeta for r in ranges})
    for z in zetas:
        label = "V(ω)" if len(zetas) == 1 else f"V(ω), ζ = {z:g}"
        ax.plot(w / (2 * math.pi), 100.0 * residual_vibration(result.shaper, w, z), label=label)
    for i, r in enumerate(ranges):
        x = [r.omega_min / (2 * math.pi), r.omega_max / (2 * math.pi)]
        if x[0] == x[1]:
            ax.plot(x[:1], [100.0 * r.vtol], "rv", label="Vtol" if i == 0 else None)
        else:
            ax.plot(x, [100.0 * r.vtol] * 2, "r-", lw=3, label="Vtol" if i == 0 else None)
    ax.set_xlabel("natural frequency (Hz)")
    ax.set_ylabel("residual vibration (%)")
    ax.set_title(f"SI shaper: {len(result.shaper)} impulses, {result.duration:.4f} s")
    ax.set_ylim(0.0, 105.0)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(filename, dpi=120)


def run(args, log):
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
        ``{"times": [...], "amplitudes": [...], "duration": s, "ranges": [{"omega_min",
        "omega_max", "zeta", "vtol", "max_prv"}, ...]}`` (s, rad/s, fractions).

    Examples
    --------
    >>> import argparse, pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "one.toml"
    >>> _ = p.write_text("[[range]]\\nomega_min = 5.0\\nomega_max = 6.0\\nvtol = 0.05\\n")
    >>> out = run(argparse.Namespace(problem=str(p), plot=None), lambda m: None)
    >>> sorted(out)
    ['amplitudes', 'duration', 'ranges', 'times']
    """
    path = Path(args.problem)
    data = _read(path)
    move = getattr(args, "move", None)
    if not isinstance(data, dict) or "range" not in data:
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
    result = si_shaper(ranges)
    log(
        f"{len(result.shaper)} impulses, duration {result.duration:.6f} s, "
        f"{result.iterations} NLP solve(s)"
    )
    for t, a in zip(result.shaper.times, result.shaper.amplitudes, strict=True):
        log(f"  t = {t:.6f} s   A = {a:.6f}")
    out_ranges = []
    for r, v in zip(ranges, result.max_prv, strict=True):
        log(
            f"  range {r.omega_min:.4f}-{r.omega_max:.4f} rad/s, zeta {r.zeta:g}: "
            f"max V = {100 * v:.3f} % (Vtol {100 * r.vtol:.3f} %)"
        )
        out_ranges.append(
            {
                "omega_min": r.omega_min,
                "omega_max": r.omega_max,
                "zeta": r.zeta,
                "vtol": r.vtol,
                "max_prv": float(v),
            }
        )
    if getattr(args, "plot", None):
        _plot(result, args.plot)
        log(f"wrote {args.plot}")
    return {
        "times": result.shaper.times.tolist(),
        "amplitudes": result.shaper.amplitudes.tolist(),
        "duration": result.duration,
        "ranges": out_ranges,
    }


def _ranges_json(result):
    return [
        {
            "omega_min": r.omega_min,
            "omega_max": r.omega_max,
            "zeta": r.zeta,
            "vtol": r.vtol,
            "max_prv": float(v),
        }
        for r, v in zip(result.ranges, result.max_prv, strict=True)
    ]


def _check_option(value, name, lo, hi, lo_open=False, hi_open=False):
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and (
        value < hi if hi_open else value <= hi)
    if not ok:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        raise ModelError(f"{name}: {value!r} must lie in {left}{lo}, {hi}{right}")


def _simulate(model, move, shaper, dt, log):
    """Simulate the move unshaped and shaped; return a dict of residuals and the traces."""
    try:
        from casflex.simulate import simulate_prescribed
    except ImportError:
        log("casflex.simulate is not available: residual tip deflections not computed")
        return None
    from casflex.shaping import residual_amplitude, shaped_reference

    log(f"simulating {move.name} unshaped (dt = {dt:g} s, {move.t_end:g} s)")
    plain = simulate_prescribed(model, move, dt=dt, t_end=move.t_end)
    ref = shaped_reference(shaper, move, dt=dt)
    t_end = move.t_end + shaper.duration
    log(f"simulating {move.name} shaped ({t_end:g} s)")
    shaped = simulate_prescribed(model, ref, dt=dt, t_end=t_end)
    res_plain = residual_amplitude(plain.t, plain.tip_deflection, move.duration)
    res_shaped = residual_amplitude(shaped.t, shaped.tip_deflection,
                                    move.duration + shaper.duration)
    return {
        "unshaped": res_plain,
        "shaped": res_shaped,
        "plain": plain,
        "shaped_result": shaped,
    }


def _plot_robot(result, sims, move, filename):
    """PRV curve with the design ranges and, if simulated, the tip deflection."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 7.0 if sims else 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(2 if sims else 1, 1, 1)
    hi = max(r.omega_max for r in result.ranges)
    w = np.linspace(1e-3 * hi, 1.25 * hi, 3000)
    ax.plot(w, 100.0 * residual_vibration(result.shaper, w, result.ranges[0].zeta), label="V(ω)")
    for i, r in enumerate(result.ranges):
        x = [r.omega_min, r.omega_max]
        style = "rv" if x[0] == x[1] else "r-"
        ax.plot(x if x[0] != x[1] else x[:1], [100.0 * r.vtol] * (2 if x[0] != x[1] else 1),
                style, lw=3, label="Vtol" if i == 0 else None)
    ax.set_xlabel("natural frequency (rad/s)")
    ax.set_ylabel("residual vibration (%)")
    ax.set_ylim(0.0, 105.0)
    ax.set_title(f"{move.name}: r = {np.round(result.contributions, 3).tolist()}, "
                 f"{len(result.shaper)} impulses, {result.duration:.3f} s")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right")
    if sims:
        ax2 = fig.add_subplot(2, 1, 2)
        for key, label in (("plain", "unshaped"), ("shaped_result", "shaped")):
            sim = sims[key]
            d = np.asarray(sim.tip_deflection, dtype=float).reshape(len(sim.t), -1)
            ax2.plot(sim.t, 1e3 * np.linalg.norm(d, axis=1), label=label)
        ax2.set_xlabel("time (s)")
        ax2.set_ylabel("|tip deflection| (mm)")
        ax2.grid(True, alpha=0.3)
        ax2.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(filename, dpi=120)


def _run_robot(args, path, log):
    """The robot form: design the shaper of ``args.move`` for the robot at ``path``."""
    from casflex.model import build_model
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.shaping import shaper_for_move

    robot = load(path)
    move = load_move(args.move)
    modes = getattr(args, "modes", 3)
    if isinstance(modes, bool) or not isinstance(modes, int) or modes < 1:
        raise ModelError(f"--modes: {modes!r} must be an integer >= 1")
    margin = float(getattr(args, "margin", 0.2))
    vtol = float(getattr(args, "vtol", 0.05))
    dt = float(getattr(args, "dt", 1e-3))
    _check_option(margin, "--margin", 0.0, 1.0, hi_open=True)
    _check_option(vtol, "--vtol", 0.0, 1.0, lo_open=True)
    _check_option(dt, "--dt", 0.0, 0.1, lo_open=True)
    if move.n_joints != robot.n_joints:
        raise ModelError(f"--move: move '{move.name}' has {move.n_joints} joint(s) but robot "
                         f"'{robot.name}' has {robot.n_joints}")
    step = getattr(args, "step", None)
    step = None if step is None else parse_angle(step, "--step")
    log(f"building the {modes}-mode model of '{robot.name}' (tables cached)")
    model, _ = build_model(robot, n_modes=modes, step=step, gravity=None,
                           cache_dir=getattr(args, "cache_dir", None),
                           processes=getattr(args, "processes", None), progress=True)
    log(f"designing the shaper for {move.name} (margin ±{100 * margin:g} %, "
        f"Vtol {100 * vtol:g} %)")
    result = shaper_for_move(model, move, vtol=vtol, margin=margin)
    for j, (r, v, lo, hi) in enumerate(zip(result.contributions, result.tolerances,
                                           result.omega_min, result.omega_max, strict=True)):
        log(f"  mode {j + 1}: omega {lo:.3f}-{hi:.3f} rad/s, r = {r:.3f}, Vtol = {v:.3f}")
    log(f"{len(result.shaper)} impulses, duration {result.duration:.6f} s")
    for t, a in zip(result.shaper.times, result.shaper.amplitudes, strict=True):
        log(f"  t = {t:.6f} s   A = {a:.6f}")
    sims = None if getattr(args, "no_simulate", False) else _simulate(
        model, move, result.shaper, dt, log)
    unshaped = shaped = reduction = None
    if sims:
        unshaped, shaped = sims["unshaped"], sims["shaped"]
        reduction = 1.0 - shaped / unshaped if unshaped > 0.0 else None
        log(f"residual tip deflection: unshaped {1e3 * unshaped:.3f} mm, shaped "
            f"{1e3 * shaped:.3f} mm" + (f" ({100 * reduction:.1f} % less)"
                                         if reduction is not None else ""))
    if getattr(args, "plot", None):
        _plot_robot(result, sims, move, args.plot)
        log(f"wrote {args.plot}")
    return {
        "times": result.shaper.times.tolist(),
        "amplitudes": result.shaper.amplitudes.tolist(),
        "duration": result.duration,
        "ranges": _ranges_json(result.si),
        "move": move.name,
        "margin": margin,
        "contributions": result.contributions.tolist(),
        "raw_contributions": result.raw_contributions.tolist(),
        "tolerances": result.tolerances.tolist(),
        "omega_min": result.omega_min.tolist(),
        "omega_max": result.omega_max.tolist(),
        "residual_tip_deflection_unshaped": unshaped,
        "residual_tip_deflection_shaped": shaped,
        "residual_reduction": reduction,
    }
