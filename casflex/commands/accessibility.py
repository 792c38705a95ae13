"""``casflex accessibility``: maps of the modal accessibility indexes (eq. 204).

``casflex accessibility ROBOT.toml [--joints J1 J2] [--step S] [--q Q1 Q2 ...]
[--modes N] [--plot FILE.png] [--cache-dir DIR | --no-cache] [--json]``

The two joints (1-based, default 2 3) take a full turn ``[-pi, pi)`` at ``--step``
(default 10deg: 36 x 36 points); the other joints stay at 0 or at ``--q``.

JSON: ``{"joints": [J1, J2], "grid": [axis1, axis2] (rad), "index": (modes, N, N)
(sqrt(kg) m)}``. Its size grows with the square of the number of points: about 80 KB
with 3 modes at the default 10deg, 21 KB at 20deg, 325 KB at 5deg (the resolution of the
dissertation's Fig. 108-110).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

import numpy as np

from casflex.commands.common import (
    add_cache_arguments,
    add_modes_argument,
    add_plot_argument,
    add_robot_argument,
    cache_dir_of,
    parse_angle,
    plot_path,
)
from casflex.errors import ModelError
from casflex.robot import load

#: default grid step: 36 x 36 points, a JSON of about 80 KB with 3 modes
DEFAULT_STEP = "10deg"

HELP = "map the accessibility indexes of the modes over a grid of two joints (eq. 204)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex accessibility``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["problems/arm2link.toml", "--step", "45deg", "--modes", "1"])
    >>> a.joints, a.step, a.modes, a.no_cache, p.parse_args(["r.toml"]).step
    ([2, 3], '45deg', 1, False, '10deg')
    """
    add_robot_argument(parser)
    parser.add_argument("--joints", nargs=2, type=int, default=[2, 3], metavar="J",
                        help="the two joints varied, 1-based (default 2 3)")
    parser.add_argument("--step", default=DEFAULT_STEP, metavar="S",
                        help="grid step, rad or with a 'deg' suffix (default "
                        f"{DEFAULT_STEP}; the JSON grows as 1/step^2)")
    parser.add_argument("--q", nargs="+", default=None, metavar="Q",
                        help="values of the other joints, rad or with a 'deg' suffix "
                        "(default zeros)")
    add_modes_argument(parser, 3)
    add_plot_argument(parser, "draw the maps")
    add_cache_arguments(parser)

def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Compute the maps; return ``{"joints", "grid", "index"}`` (1-based joints, rad).

    Checks the options, then calls :func:`casflex.control.robot_accessibility_map`, which
    tabulates the modes over the two joints, so the example below only shows the argument
    checks; ``casflex accessibility
    problems/arm2link.toml --step 45deg --modes 1 --json`` gives an ``index`` of shape
    (1, 8, 8).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"joints": [j1, j2] (1-based), "grid": [axis1, axis2] (rad), "index": (modes,
        n1, n2) accessibility indexes (sqrt(kg) m)}``.

    Raises
    ------
    ModelError
        Invalid joints, step, ``--q`` or ``--modes``.

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> run(p.parse_args(["problems/arm2link.toml", "--joints", "1", "4"]), print)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --joints: 4 is not a joint of 'arm2link' (1..3)
    """
    from casflex.control import robot_accessibility_map
    from casflex.plotting import plot_accessibility

    plot_path(args.plot)  # before any heavy work
    robot = load(args.robot)
    n = robot.n_joints
    joints = [int(j) for j in args.joints]
    for j in joints:
        if not 1 <= j <= n:
            raise ModelError(f"--joints: {j} is not a joint of '{robot.name}' (1..{n})")
    if joints[0] == joints[1]:
        raise ModelError(f"--joints: two different joints are needed; got {joints}")
    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    step = parse_angle(args.step, "--step")
    count = int(round(2 * math.pi / step)) if step > 0 else 0
    if count < 8:
        raise ModelError(f"--step: {args.step} must be > 0 and give at least 8 points per "
                         "turn")
    q = None
    if args.q is not None:
        q = np.array([parse_angle(v, "--q") for v in args.q])
        if q.size != n:
            raise ModelError(f"--q: robot '{robot.name}' has {n} joints; got {q.size} values")
    axes, index = robot_accessibility_map(robot, (joints[0] - 1, joints[1] - 1), step, q=q,
                                          n_modes=args.modes,
                                          cache_dir=cache_dir_of(args), log=log)
    for k in range(index.shape[0]):
        log(f"  mode {k + 1}: a in [{index[k].min():.4g}, {index[k].max():.4g}] sqrt(kg) m")
    if args.plot:
        fig = plot_accessibility(axes, index, joints=(joints[0] - 1, joints[1] - 1))
        fig.savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return {"joints": joints, "grid": [a for a in axes], "index": index}
