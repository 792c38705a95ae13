"""``casflex check``: stability of a controller along a planned move (§6.2.2.1, §6.2.3.1)."""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from casflex.commands.common import parse_angle
from casflex.errors import ModelError
from casflex.robot import load

HELP = ("stability of the inversion (eq. 226) or composite (fast loop Hurwitz) controller "
        "along a move")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex check``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["problems/arm2link.toml", "--move",
    ...                   "problems/moves.toml:control_move1", "--controller", "composite",
    ...                   "--schedule"])
    >>> a.controller, a.modes, a.step, a.dt, a.schedule
    ('composite', 3, '6deg', 0.01, True)
    """
    parser.add_argument("robot", help="robot description (TOML)")
    parser.add_argument("--move", required=True, metavar="FILE:NAME",
                        help="planned move, e.g. problems/moves.toml:move1")
    parser.add_argument("--controller", required=True, choices=("inversion", "composite"))
    parser.add_argument("--modes", type=int, default=3, help="number of modes (default 3)")
    parser.add_argument("--step", default="6deg",
                        help="grid step of the modal tables (default 6deg)")
    parser.add_argument("--dt", type=float, default=1e-2,
                        help="time step of the check along the move [s] (default 0.01)")
    parser.add_argument("--kp", type=float, default=1.0, help="K_p (default 1)")
    parser.add_argument("--alpha", type=float, default=None,
                        help="alpha of eq. 216 [1/s] (inversion; default zeta*omega_min, "
                             "or sqrt(Kp) without damping)")
    parser.add_argument("--q-weight", type=float, default=1.0, help="LQR Q = w I (default 1)")
    parser.add_argument("--r-weight", type=float, default=10.0,
                        help="LQR R = w I (default 10)")
    parser.add_argument("--schedule", action="store_true",
                        help="composite: gains scheduled over the configuration grid "
                             "(default: fixed gains at the end of the move)")
    parser.add_argument("--no-cache", action="store_true", help="do not cache the tables")


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Run the check; return ``{"stable", "worst_margin", "worst_time", ...}`` (SI).

    Checks the options, then calls :func:`casflex.control.check_stability`. Building the
    model tabulates modes over a grid, so the example below only shows an argument check.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        As :func:`casflex.control.check_stability`: inversion (eq. 226) ``stable``,
        ``worst_margin`` [1/s³], ``worst_time`` [s], ``worst_q`` [rad], ``alpha``,
        ``gamma`` [1/s], ``damping_condition``, ``time_scale_max``; composite (fast loop)
        ``stable``, ``worst_margin``, ``worst_real`` [1/s], ``worst_time`` [s],
        ``worst_q`` [rad], ``epsilon`` [s], ``gains`` (``"scheduled"`` or ``"end of
        move"``).

    Raises
    ------
    casflex.errors.ModelError
        A move for another number of joints, ``--modes < 1``, a bad ``--dt`` or
        ``--step``.

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> args = p.parse_args(["problems/arm2link.toml", "--move",
    ...                      "problems/moves.toml:control_move1", "--controller",
    ...                      "inversion", "--dt", "0"])
    >>> run(args, print)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --dt: must be > 0 [s]; got 0.0
    """
    from casflex.control import check_stability
    from casflex.moves import load_move

    robot = load(args.robot)
    move = load_move(args.move)
    if move.n_joints != robot.n_joints:
        raise ModelError(f"--move: {args.move} has {move.n_joints} joints; robot "
                         f"'{robot.name}' has {robot.n_joints}")
    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    if not args.dt > 0:
        raise ModelError(f"--dt: must be > 0 [s]; got {args.dt}")
    step = parse_angle(args.step, "--step")
    if not step > 0:
        raise ModelError(f"--step: must be > 0; got {args.step}")
    log(f"building the model of {robot.name} ({args.modes} modes, table step "
        f"{np.degrees(step):g} deg)")
    r = check_stability(robot, move, args.controller, n_modes=args.modes, step=step,
                        dt=args.dt, Kp=args.kp, alpha=args.alpha, Q=args.q_weight,
                        R=args.r_weight, schedule=args.schedule,
                        cache_dir=False if args.no_cache else None)
    if args.controller == "inversion":
        log(f"eq. 226 along {move.name}: worst margin {r['worst_margin']:.6g} 1/s^3 at "
            f"t = {r['worst_time']:.3f} s; alpha = {r['alpha']:.4g} 1/s; "
            f"gamma = {r['gamma']:.4g} 1/s; move may run {r['time_scale_max']:.4g}x faster")
        if not r["damping_condition"]:
            log("note: D - alpha I is not positive definite (no modal damping): eq. 225 "
                "does not hold, the zero dynamics are not exponentially stable")
        return r
    log(f"fast closed loop along {move.name}: largest real part {r['worst_real']:.6g} 1/s "
        f"at t = {r['worst_time']:.3f} s, q = {np.round(r['worst_q'], 4).tolist()} rad "
        f"(epsilon = {r['epsilon']:.4g} s)")
    if not r["stable"] and not args.schedule:
        log("note: with gains fixed at the end of the move the fast loop of this model is "
            "not Hurwitz along the move (a property of the model: small residual joint "
            "inertia, see casflex.control.composite_stability); try --schedule")
    return r
