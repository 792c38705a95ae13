"""``casflex sweep``: natural frequencies while one joint moves (dissertation Fig. 25/26).

``casflex sweep ROBOT.toml --joint K --from A --to B --step S [--track] [--modes N]
[--q Q1 Q2 ...] [--plot FILE.png] [--unit rad/s|Hz] [--json]``

Joint ``K`` (1-based) takes the values ``A, A + S, ...`` up to ``B`` (included when it
falls on the step, within 1e-9 of a step); the other joints stay at 0 or at ``--q``
(whose K-th entry is ignored). Angles are in rad, or in degrees with a ``deg`` suffix
(``--step 1.5deg``); a negative value with a suffix can also be written ``--from=-180deg``.

By default the frequencies are the sorted roots at every configuration (Fig. 25); with
``--track`` the modes are followed by the modified MAC with continuous sign
(:func:`casflex.modal.tracking.track`, Fig. 26), computing two more modes than ``--modes``
so that modes crossing in from above are followed, and ``omega[i][j]`` is then mode ``j``
(numbered by frequency at the first point) at ``q[i]``.

JSON: ``{"joint": K, "q": [...], "omega": [[...], ...]}`` (rad, rad/s). The figure is
drawn in rad/s, or in Hz with ``--unit Hz``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable

import numpy as np

from casflex.commands.common import (
    add_deprecated_alias,
    add_modes_argument,
    add_plot_argument,
    add_processes_argument,
    add_robot_argument,
    add_unit_argument,
    parse_angle,
    plot_path,
)
from casflex.errors import ModelError
from casflex.robot import load

HELP = "compute the natural frequencies while one joint sweeps a range (sorted or tracked by MAC)"

#: refuse sweeps longer than this (a typo in --step)
MAX_POINTS = 100_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``sweep`` arguments to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> from casflex.commands.common import ArgumentParser
    >>> p = ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["r.toml", "--joint", "3", "--from", "-180deg", "--to", "pi",
    ...                   "--step", "1.5deg"])
    >>> a.joint, a.start.strip(), a.stop, a.step
    (3, '-180deg', 'pi', '1.5deg')
    """
    add_robot_argument(parser)
    parser.add_argument("--joint", type=int, required=True, metavar="K",
                        help="joint to sweep, 1-based")
    parser.add_argument("--from", dest="start", required=True, metavar="A",
                        help="first value, rad or with a 'deg' suffix, or '-pi'/'pi'")
    parser.add_argument("--to", dest="stop", required=True, metavar="B",
                        help="last value, rad or with a 'deg' suffix, or '-pi'/'pi'")
    parser.add_argument("--step", required=True, metavar="S",
                        help="increment > 0, rad or with a 'deg' suffix")
    parser.add_argument("--track", action="store_true",
                        help="follow the modes by MAC with continuous sign (Fig. 26) "
                             "instead of sorting the frequencies (Fig. 25)")
    add_modes_argument(parser, 5)
    add_deprecated_alias(parser, "--count", "--modes", "modes", type=int)
    parser.add_argument("--q", nargs="+", default=None, metavar="Q",
                        help="values of the other joints, rad or with a 'deg' suffix "
                             "(default 0)")
    add_processes_argument(parser)
    add_plot_argument(parser, "write frequency vs joint angle")
    add_unit_argument(parser)


def sweep_values(start: float, stop: float, step: float) -> np.ndarray:
    """The joint values ``start, start + step, ...`` up to ``stop`` [rad].

    Parameters
    ----------
    start, stop : float
        First and last value [rad], ``start <= stop``; ``stop`` is included when it lies
        on the grid (to 1e-9 steps).
    step : float
        Increment [rad], > 0.

    Returns
    -------
    numpy.ndarray

    Raises
    ------
    ModelError
        Non-positive step, ``start > stop``, or more than ``MAX_POINTS`` values.

    Examples
    --------
    >>> np.degrees(sweep_values(0.0, np.radians(3.0), np.radians(1.5))).round(6).tolist()
    [0.0, 1.5, 3.0]
    """
    if not step > 0.0:
        raise ModelError(f"--step: must be > 0; got {step} rad")
    if start > stop:
        raise ModelError(f"--from {start} rad is greater than --to {stop} rad; the step is "
                         "positive, so give the smaller value first")
    n = int(math.floor((stop - start) / step + 1e-9)) + 1
    if n > MAX_POINTS:
        raise ModelError(f"--step: {n} points from {start} to {stop} rad; at most "
                         f"{MAX_POINTS} (check the step's unit)")
    return start + step * np.arange(n)


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Sweep the joint; return ``{"joint", "q", "omega"}`` (rad, rad/s).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"joint": K (1-based), "q": [rad, ...], "omega": [[rad/s per mode], ...]}``.

    Examples
    --------
    >>> import argparse
    >>> a = argparse.Namespace(robot="problems/arm2link.toml", joint=3, start="0",
    ...                        stop="2deg", step="1deg", track=False, modes=2, q=None,
    ...                        processes=1, plot=None, unit="rad/s")
    >>> out = run(a, lambda m: None)
    >>> len(out["q"]), len(out["omega"][0])
    (3, 2)
    """
    from casflex.modal.sweep import frequency_sweep

    plot_path(args.plot)  # before any heavy work
    robot = load(args.robot)
    k = args.joint
    if not 1 <= k <= robot.n_joints:
        raise ModelError(f"--joint: robot '{robot.name}' has joints 1..{robot.n_joints}; "
                         f"got {k}")
    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    if args.processes is not None and args.processes < 1:
        raise ModelError(f"--processes: must be >= 1; got {args.processes}")
    values = sweep_values(parse_angle(args.start, "--from"), parse_angle(args.stop, "--to"),
                          parse_angle(args.step, "--step"))
    if args.q is None:
        base = np.zeros(robot.n_joints)
    else:
        base = np.array([parse_angle(v, "--q") for v in args.q])
        if base.size != robot.n_joints:
            raise ModelError(f"--q: robot '{robot.name}' has {robot.n_joints} joints; got "
                             f"{base.size} values")
    qs = np.repeat(base[None, :], values.size, axis=0)
    qs[:, k - 1] = values
    kind = "tracked" if args.track else "sorted"
    log(f"{robot.name}: sweeping q{k} from {values[0]:.6g} to {values[-1]:.6g} rad "
        f"({values.size} points), {args.modes} modes, {kind}")
    result = frequency_sweep(robot, qs, args.modes, track=args.track, joint=k - 1,
                             processes=args.processes,
                             progress=values.size >= 20 and sys.stderr.isatty())
    omega = result.omega
    if result.tracked:
        log(f"  lowest MAC between tracked neighbours: {result.min_mac:.4f}")
        if result.min_mac < 0.9:
            log("  warning: a tracked mode changes fast between neighbours; use a smaller "
                "--step")
    for j in range(args.modes):
        col = result.omega_hz[:, j]
        log(f"  mode {j + 1}: {col.min():10.5f} .. {col.max():10.5f} Hz")
    if args.plot:
        from casflex.plotting import plot_sweep

        fig = plot_sweep(values, omega, k - 1, tracked=args.track,
                         unit=getattr(args, "unit", "rad/s"),
                         title=f"{robot.name}: natural frequencies vs q{k} ({kind})")
        fig.savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return {"joint": k, "q": values, "omega": omega}
