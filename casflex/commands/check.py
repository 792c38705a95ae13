"""``casflex check``: stability of a controller along a planned move (§6.2.2.1, §6.2.3.1).

``casflex check ROBOT.toml --move FILE:NAME --controller inversion|composite [--modes N]
[--step S] [--dt S] [--kp KP] [--kd KD] [--alpha A] [--q-weight W] [--r-weight W]
[--schedule] [--cache-dir DIR | --no-cache] [--json]``

Every condition the stability argument needs gets its own verdict, printed one per line
and in the JSON's ``conditions`` (name -> ``{"holds", "value", "unit", "rule"}``); the
headline ``stable`` is true only when all of them hold. Inversion: ``zero_dynamics_margin``
(eq. 226) and ``modal_damping`` (eq. 225, ``D - alpha I`` positive definite); composite:
``slow_loop`` (the rigid loop under ``Kp``, ``Kd``) and ``fast_loop_hurwitz``
(§6.2.3.1). A line and the JSON's ``mass_matrix_box`` say whether the model's mass
matrix ``M(q, 0)`` is positive definite over the joint box (grid points and cell centres):
a diagnosis of the model's tabulated terms, outside the headline.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from casflex.commands.common import (
    add_cache_arguments,
    add_model_arguments,
    add_robot_argument,
    cache_dir_of,
    parse_angle,
)
from casflex.errors import ModelError
from casflex.robot import load

HELP = ("check the stability of the inversion (eq. 225-226) or composite (slow and fast "
        "loops) controller along a move")


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
    add_robot_argument(parser)
    parser.add_argument("--move", required=True, metavar="FILE:NAME",
                        help="planned move, e.g. problems/moves.toml:move1")
    parser.add_argument("--controller", required=True, choices=("inversion", "composite"),
                        help="the tracking law checked")
    add_model_arguments(parser, modes=3, step="6deg")
    parser.add_argument("--dt", type=float, default=1e-2, metavar="S",
                        help="time step of the check along the move, s (default 0.01)")
    parser.add_argument("--kp", type=float, default=1.0, metavar="KP",
                        help="slow gain K_p, 1/s^2 (default 1)")
    parser.add_argument("--kd", type=float, default=2.0, metavar="KD",
                        help="slow gain K_d, 1/s (composite; default 2)")
    parser.add_argument("--alpha", type=float, default=None, metavar="A",
                        help="alpha of eq. 216, 1/s (inversion; default zeta*omega_min, "
                             "or sqrt(Kp) without damping)")
    parser.add_argument("--q-weight", type=float, default=1.0, metavar="W",
                        help="LQR Q = w I (composite; default 1)")
    parser.add_argument("--r-weight", type=float, default=10.0, metavar="W",
                        help="LQR R = w I (composite; default 10)")
    parser.add_argument("--schedule", action="store_true",
                        help="composite: gains scheduled over the configuration grid "
                             "(default fixed gains at the end of the move)")
    add_cache_arguments(parser)

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
        As :func:`casflex.control.check_stability`: ``stable`` (every condition holds),
        ``conditions`` (one verdict per condition); inversion ``worst_margin``
        [1/s³], ``worst_time`` [s], ``worst_q`` [rad], ``alpha``, ``gamma`` [1/s],
        ``damping_condition``, ``time_scale_max``; composite ``worst_margin``,
        ``worst_real`` [1/s], ``worst_time`` [s], ``worst_q`` [rad], ``epsilon`` [s],
        ``gains`` (``"scheduled"`` or ``"end of move"``); both ``mass_matrix_box``
        (:func:`casflex.control.mass_matrix_over_box`: ``M(q, 0)`` positive definite
        over the joint box, reported beside the verdict).

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
    for flag, value in (("--kp", args.kp), ("--kd", getattr(args, "kd", 2.0))):
        if not (value > 0 and np.isfinite(value)):
            raise ModelError(f"{flag}: must be a finite gain > 0; got {value}")
    step = parse_angle(args.step, "--step")
    if not step > 0:
        raise ModelError(f"--step: must be > 0; got {args.step}")
    log(f"building the model of {robot.name} ({args.modes} modes, table step "
        f"{np.degrees(step):g} deg)")
    r = check_stability(robot, move, args.controller, n_modes=args.modes, step=step,
                        dt=args.dt, Kp=args.kp, Kd=getattr(args, "kd", 2.0),
                        alpha=args.alpha, Q=args.q_weight, R=args.r_weight,
                        schedule=args.schedule, cache_dir=cache_dir_of(args))
    if args.controller == "inversion":
        log(f"eq. 226 along {move.name}: worst margin {r['worst_margin']:.6g} 1/s^3 at "
            f"t = {r['worst_time']:.3f} s; alpha = {r['alpha']:.4g} 1/s; "
            f"gamma = {r['gamma']:.4g} 1/s; move may run {r['time_scale_max']:.4g}x faster")
    else:
        log(f"fast closed loop along {move.name}: largest real part {r['worst_real']:.6g} "
            f"1/s at t = {r['worst_time']:.3f} s, q = "
            f"{np.round(r['worst_q'], 4).tolist()} rad (epsilon = {r['epsilon']:.4g} s)")
    for name, c in r["conditions"].items():
        log(f"  {'holds' if c['holds'] else 'FAILS'}: {name}: {c['value']:.6g} {c['unit']} "
            f"({c['rule']})")
    box = r["mass_matrix_box"]
    log(f"mass matrix over the joint box ({box['points']} configurations): "
        f"{'holds' if box['holds'] else 'FAILS'}: smallest residual joint inertia "
        f"{box['value']:.6g} {box['unit']} at q = {np.round(box['q'], 4).tolist()} rad")
    if not box["holds"]:
        log("note: M(q, 0) is not positive definite somewhere in the box: the model's "
            "interpolated terms are wrong there (e.g. across swapping modes); a finer or "
            "linear table, or the smooth basis, avoids it")
    failed = [name for name, c in r["conditions"].items() if not c["holds"]]
    log(f"stable: {'yes' if not failed else 'no'} ({len(r['conditions']) - len(failed)} of "
        f"{len(r['conditions'])} conditions hold)")
    if args.controller == "inversion" and not r["conditions"]["modal_damping"]["holds"]:
        log("note: without modal damping D - alpha I is not positive definite: eq. 225 "
            "fails and the zero dynamics are not exponentially stable, whatever eq. 226 "
            "says")
    if (args.controller == "composite" and not r["conditions"]["fast_loop_hurwitz"]["holds"]
            and not args.schedule):
        log("note: with gains fixed at the end of the move the fast loop of this model is "
            "not Hurwitz along the move (a property of the model: small residual joint "
            "inertia, see casflex.control.composite_stability); try --schedule")
    return r
