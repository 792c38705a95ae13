"""``casflex simulate``: prescribed joint motion of a flexible arm (dissertation §3.3.7.1).

``casflex simulate ROBOT.toml --move FILE:NAME [--modes 5] [--dt 0.001] [--step 1.5deg]
[--gravity | --no-gravity] [--method poly|rk4|cvodes|idas] [--jit] [--shape-rates]
[--foreshortening] [--kinematics truncated|exact] [--cache-dir DIR | --no-cache]
[--plot FILE.png] [--json]``

``--method poly`` (the default) takes the same RK4 steps as ``--method rk4`` on the exact
polynomial form of the modal rows: the same result (to rounding) several times faster
(``benchmarks/README.md``); ``--method rk4`` steps the CasADi model directly, ``cvodes``
and ``idas`` are variable-step integrators. ``--jit`` also compiles the polynomial form to
C once per model (kept in the cache directory), after which a move runs outside CasADi's
virtual machine.

The modal tables are built (or read from the cache) with a progress bar on stderr, the
CasADi model is built on them and the joints follow the move exactly; the modal row of
eq. 118 gives the deflections, the joint row the torques. Gravity is neglected by default,
as in the dissertation's simulations (``--gravity`` uses the robot's).

JSON: ``{"t_end", "max_tip_deflection", "residual_tip_deflection", "torque_peak"}``
(s, m, m, N m per joint).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from casflex.commands.common import (
    add_cache_arguments,
    add_gravity_argument,
    add_model_arguments,
    add_plot_argument,
    add_robot_argument,
    cache_dir_of,
    disk_cache,
    parse_angle,
    plot_path,
)
from casflex.errors import ModelError
from casflex.robot import load

HELP = "simulate a planned move with perfect joint tracking (tip deflection, torques)"

#: the fastest exact method: the same RK4 steps as "rk4" on the polynomial form
DEFAULT_METHOD = "poly"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex simulate``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["r.toml", "--move", "m.toml:move1"])
    >>> a.modes, a.dt, a.method, a.gravity
    (5, 0.001, 'poly', False)
    """
    add_robot_argument(parser)
    parser.add_argument("--move", required=True, metavar="FILE:NAME",
                        help="planned move, e.g. problems/moves.toml:move1")
    add_model_arguments(parser, modes=5)
    parser.add_argument("--dt", type=float, default=1e-3, metavar="S",
                        help="time step, s (default 0.001)")
    add_gravity_argument(parser)
    parser.add_argument("--method", default=DEFAULT_METHOD,
                        choices=["poly", "rk4", "cvodes", "idas"],
                        help="integration method (default poly: the RK4 steps of rk4 on "
                             "the exact polynomial form of the modal rows, same result, "
                             "faster)")
    parser.add_argument("--jit", action="store_true",
                        help="with --method poly: compile the model's arrays and the RK4 "
                             "steps to C (system compiler; cached on disk, the first run "
                             "compiles for ~30 s)")
    parser.add_argument("--shape-rates", action="store_true",
                        help="model option: velocity terms of mode shapes that change with "
                             "the configuration (fast moves; costs time)")
    parser.add_argument("--foreshortening", action="store_true",
                        help="model option: the beams' shortening (geometric stiffening on "
                             "fast moves; costs time)")
    parser.add_argument("--kinematics", choices=("truncated", "exact"), default="truncated",
                        help="model option: 'exact' rebuilds the links from the modal "
                             "strains (large deflections; ~8x the cost of a step; needs "
                             "--method rk4, cvodes or idas)")
    add_cache_arguments(parser)
    add_plot_argument(parser, "joint angles, torques, modal amplitudes and tip deflection")

def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Build the model, simulate the move, return the JSON summary (SI units).

    Building the model is costly, so the example below only shows the argument
    checks; see the module docstring for a full command line and the JSON keys.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"t_end": s, "max_tip_deflection": m, "residual_tip_deflection": m,
        "torque_peak": [N m per joint]}``.

    Raises
    ------
    ModelError
        A move for another number of joints or outside the robot's joint limits,
        ``--modes < 1``, a bad ``--dt``,
        or ``--jit`` without ``--method poly``.

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> args = p.parse_args(["problems/arm2link.toml", "--move", "problems/moves.toml:move1",
    ...                      "--dt", "-0.01"])
    >>> run(args, print)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --dt: must be a positive step in s; got -0.01
    >>> run(p.parse_args(["problems/arm2link.toml", "--move", "problems/moves.toml:move1",
    ...                   "--jit", "--method", "rk4"]), print)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --jit: needs --method poly; got --method rk4
    """
    from casflex.moves import load_move
    from casflex.simulate import simulate_move

    plot_path(args.plot)  # before any heavy work
    robot = load(args.robot)
    move = load_move(args.move)
    if move.n_joints != robot.n_joints:
        raise ModelError(f"--move {args.move}: the move has {move.n_joints} joint values; "
                         f"robot '{robot.name}' ({args.robot}) has {robot.n_joints} joints")
    robot.within_limits(move.q0, f"--move {args.move}: start q0")
    robot.within_limits(move.qf, f"--move {args.move}: target qf")
    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    if not (math.isfinite(args.dt) and args.dt > 0.0):
        raise ModelError(f"--dt: must be a positive step in s; got {args.dt}")
    step = None if args.step is None else parse_angle(args.step, "--step")
    jit = getattr(args, "jit", False)
    if jit and args.method != "poly":
        raise ModelError(f"--jit: needs --method poly; got --method {args.method}")
    options = {"shape_rates": getattr(args, "shape_rates", False),
               "foreshortening": getattr(args, "foreshortening", False),
               "kinematics": getattr(args, "kinematics", "truncated")}
    if options["kinematics"] == "exact" and args.method == "poly":
        # not a budget: --method poly promises rk4's result to rounding, and the exact
        # model's poly form is its degree-2 truncation (and at 5 modes 2-6x rk4's CPU)
        raise ModelError("--kinematics exact: needs --method rk4, cvodes or idas (--method "
                         "poly gives rk4's result only for a model polynomial in delta; the "
                         "exact model's poly form is its truncation at degree 2 in delta, "
                         "0.1 % of the peak on Table 9 move 3, and slower than rk4 at 5 "
                         "modes: casflex.simulate.simulate_prescribed(method='poly'))")
    cache_dir = cache_dir_of(args)
    if jit:  # the compiled library must live on disk: --no-cache gives a temporary one
        with disk_cache(cache_dir) as tmp:
            result, model, table = simulate_move(robot, move, args.modes, dt=args.dt,
                                                 step=step, gravity=args.gravity,
                                                 method=args.method, jit=jit, cache_dir=tmp,
                                                 **options)
    else:
        result, model, table = simulate_move(robot, move, args.modes, dt=args.dt, step=step,
                                             gravity=args.gravity, method=args.method,
                                             cache_dir=cache_dir, **options)
    sizes = table.omega.shape[:-1]  # one axis per shape joint
    points = " × ".join(str(s) for s in sizes) + (f" = {math.prod(sizes)}" if len(sizes) > 1
                                                   else "")
    log(f"model of '{robot.name}': {model.m} modes over {points} grid points of "
        f"joint(s) {[j + 1 for j in table.shape_joints]} ({result.info['model_s']:.1f} s)")
    log(f"{move.name}: {result.t[-1]:.3f} s simulated in {result.info['wall_s']:.2f} s "
        f"({args.method}, dt = {args.dt} s)")
    log(f"  max tip deflection      {1e3 * result.max_tip_deflection:10.3f} mm")
    log(f"  residual tip deflection {1e3 * result.residual_tip_deflection:10.3f} mm "
        f"(after t = {result.t_move_end:g} s)")
    log(f"  torque peak             {[round(float(v), 4) for v in result.torque_peak]} N m")
    if args.plot:
        from casflex.plotting import plot_result

        plot_result(result, title=f"{robot.name}: {move.description or move.name}").savefig(
            args.plot, dpi=110)
        log(f"wrote {args.plot}")
    return {"t_end": float(result.t[-1]),
            "max_tip_deflection": result.max_tip_deflection,
            "residual_tip_deflection": result.residual_tip_deflection,
            "torque_peak": result.torque_peak.tolist()}
