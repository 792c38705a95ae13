"""``casflex modes``: natural frequencies and mode shapes at one configuration."""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from casflex.commands.common import (
    add_deprecated_alias,
    add_modes_argument,
    add_plot_argument,
    add_robot_argument,
    parse_angle,
    plot_path,
)
from casflex.errors import ModelError
from casflex.robot import load

HELP = "compute the natural frequencies and mode shapes of a robot at one configuration (TMM)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex modes``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["problems/arm2link.toml", "--q", "0", "0", "90deg"])
    >>> a.q, a.modes, a.plot
    (['0', '0', '90deg'], 5, None)
    """
    add_robot_argument(parser)
    parser.add_argument("--q", nargs="+", default=None, metavar="Q",
                        help="joint values, rad or with a 'deg' suffix (default zeros)")
    add_modes_argument(parser, 5)
    add_deprecated_alias(parser, "--count", "--modes", "modes", type=int)
    add_plot_argument(parser, "draw the arm and its first modes")


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Compute the modes; return ``{"q", "omega", "frequency_hz"}`` (rad, rad/s, Hz).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"q": (n_joints,) rad, "omega": (modes,) rad/s, "frequency_hz": (modes,) Hz}``.

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> args = p.parse_args(["problems/arm2link.toml", "--modes", "2"])
    >>> out = run(args, lambda message: None)
    >>> out["q"].tolist(), out["omega"].round(3).tolist(), out["frequency_hz"].round(3).tolist()
    ([0.0, 0.0, 0.0], [8.307, 11.97], [1.322, 1.905])
    """
    from casflex.tmm import modes

    plot_path(args.plot)  # before any heavy work
    robot = load(args.robot)
    if args.q is None:
        q = np.zeros(robot.n_joints)
    else:
        q = np.array([parse_angle(v, "--q") for v in args.q])
    if q.size != robot.n_joints:
        raise ModelError(f"--q: robot '{robot.name}' has {robot.n_joints} joints; "
                         f"got {q.size} values")
    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    shapes = modes(robot, q, count=args.modes)
    hz = shapes.omega / (2.0 * np.pi)
    log(f"{robot.name} at q = {np.round(q, 6).tolist()} rad")
    for j, (w, f) in enumerate(zip(shapes.omega, hz, strict=True), start=1):
        log(f"  mode {j}: {w:12.5f} rad/s  {f:10.5f} Hz")
    if args.plot:
        from casflex.plotting import plot_modes

        plot_modes(robot, q, shapes).savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return {"q": q, "omega": shapes.omega, "frequency_hz": hz}
