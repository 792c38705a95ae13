"""``casflex modes``: natural frequencies and mode shapes at one configuration."""

from __future__ import annotations

import numpy as np

from casflex.commands.common import parse_angle
from casflex.errors import ModelError
from casflex.robot import load

HELP = "natural frequencies and mode shapes of a robot at one configuration (TMM)"


def add_arguments(parser):
    """Arguments of ``casflex modes``."""
    parser.add_argument("robot", help="robot description (TOML)")
    parser.add_argument("--q", nargs="+", default=None, metavar="Q",
                        help="joint values, rad (or with a 'deg' suffix); zeros if omitted")
    parser.add_argument("--count", type=int, default=5, help="number of modes (default 5)")
    parser.add_argument("--plot", metavar="FILE.png", help="draw the arm and its first modes")


def run(args, log):
    """Compute the modes; return ``{"q", "omega", "frequency_hz"}`` (rad, rad/s, Hz)."""
    from casflex.tmm import modes

    robot = load(args.robot)
    if args.q is None:
        q = np.zeros(robot.n_joints)
    else:
        q = np.array([parse_angle(v, "--q") for v in args.q])
    if q.size != robot.n_joints:
        raise ModelError(f"--q: robot '{robot.name}' has {robot.n_joints} joints; "
                         f"got {q.size} values")
    if args.count < 1:
        raise ModelError(f"--count: must be >= 1; got {args.count}")
    shapes = modes(robot, q, count=args.count)
    hz = shapes.omega / (2.0 * np.pi)
    log(f"{robot.name} at q = {np.round(q, 6).tolist()} rad")
    for j, (w, f) in enumerate(zip(shapes.omega, hz, strict=True), start=1):
        log(f"  mode {j}: {w:12.5f} rad/s  {f:10.5f} Hz")
    if args.plot:
        from casflex.plotting import plot_modes

        plot_modes(robot, q, shapes).savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return {"q": q, "omega": shapes.omega, "frequency_hz": hz}
