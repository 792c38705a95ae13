"""``casflex codegen``: C code of the real-time estimator (EKF) and of the model.

Writes two bundles (:func:`casflex.codegen.realtime_bundles`), each in its own directory
with its header, README and Makefile: ``DIR/<name>_ekf`` with ``ekf_step``, ``plant``,
``measurement``, ``rigid_signals`` and, unless ``--no-model``, ``DIR/<name>_model`` with
the model's ``forward`` dynamics.

The EKF step is the one ``benchmarks/bench_ekf.py`` times: ``--jacobians first_order``
(default; ``exact`` and ``linearized`` are the alternatives of
:func:`casflex.estimation.ekf_step_function`), sequential scalar updates when ``R`` is
diagonal.

With ``--controller composite|inversion`` the EKF bundle also gets ``rt_step``
(:func:`casflex.codegen.rt_step_function`): encoder readings, reference and accelerometer
sample to the joint torques and the updated estimator state in one call; the composite law
uses fast gains scheduled on a 30-point axis per shape joint, cached on disk.

The estimator is the same with and without ``--controller``: its plant comes from the
model built as in the control studies and the design job (``delta_order=0``, the
dissertation's ``M(q)``). The forward-dynamics bundle keeps ``M`` to first order in ``δ``
(``delta_order=1``) without a controller and is the controller's ``M(q)`` model with one
(:mod:`casflex.codegen.robot_bundles`).

``--kinematics exact`` makes the forward-dynamics bundle the model with exact kinematics
(the links rebuilt from the modal strains, as ``casflex simulate --kinematics exact``;
``delta_order=1`` with or without ``--controller``); the estimator is unchanged. It needs
the model bundle (not with ``--no-model``).

``--fit chebyshev`` fits every model term as a Chebyshev series over the joint box
instead of interpolating a grid (no ``--step``); ``--basis smooth`` uses the smooth basis
of clusters of close modes (:func:`casflex.model.build_model`, the design studies'
``model.fit`` and ``model.basis``).

Gravity follows the convention of every verb, ``--gravity/--no-gravity``. For one
release, a command that gives neither keeps the old default of this verb (the robot's
gravity) and says so on stderr; give the flag to choose.

JSON: ``{"files": [source, header, README, Makefile, manifest of each bundle],
"functions": [C function names]}``.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable

import numpy as np

from casflex._validate import output_directory
from casflex.commands.common import (
    add_cache_arguments,
    add_gravity_argument,
    add_modes_argument,
    add_robot_argument,
    cache_dir_of,
    deprecation_note,
    parse_angle,
)
from casflex.errors import ModelError

HELP = "generate C code of the EKF (and the forward dynamics) for a robot and its sensors"

#: a --step without a unit, read in degrees for one release (the old convention)
_BARE_NUMBER = re.compile(r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex codegen``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["r.toml", "--sensors", "s.toml", "--out", "d"]).modes
    3
    """
    add_robot_argument(parser)
    parser.add_argument("--sensors", required=True, metavar="SENSORS.toml",
                        help="sensor file with [[sensor]] tables (or a robot file with them)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    add_modes_argument(parser, 3)
    parser.add_argument("--name", default="casflex", help="bundle name prefix (default "
                        "casflex)")
    parser.add_argument("--dt", type=float, default=1e-3, metavar="S",
                        help="sample time, s (default 0.001)")
    parser.add_argument("--Q", type=float, default=5e-6,
                        help="process-noise intensity on [delta; ddelta] (default 5e-6)")
    parser.add_argument("--R", type=float, default=None,
                        help="signal variance (default the sensors' noise^2)")
    parser.add_argument("--step", default=None, metavar="S",
                        help="grid step of the modal tables, rad or with a 'deg' suffix "
                        "(default 1.5deg for one shape joint, 6deg for more; a number "
                        "without unit is read in deg for one release, deprecated)")
    parser.add_argument("--prefilter", action="store_true",
                        help="high-pass prefilter one decade below the lowest frequency")
    parser.add_argument("--sqrt", action="store_true", help="square-root covariance form")
    parser.add_argument("--jacobians", choices=("first_order", "exact", "linearized"),
                        default="first_order",
                        help="the EKF step's Jacobians (default first_order: those of the "
                             "plant's first-order part, the benchmarked real-time step, "
                             "same accuracy as exact on the studies; exact: through the "
                             "full plant; linearized: also the measurement's at zero "
                             "deflection, leanest)")
    parser.add_argument("--fit", choices=("grid", "chebyshev"), default="grid",
                        help="the model's terms interpolated over a grid of the shape "
                             "joints (default) or Chebyshev series over the joint box "
                             "(no grid: not with --step)")
    parser.add_argument("--basis", choices=("eigen", "smooth"), default="eigen",
                        help="tracked eigenmodes (default) or the smooth basis of clusters "
                             "of close modes")
    parser.add_argument("--no-model", action="store_true",
                        help="skip the forward-dynamics bundle")
    add_gravity_argument(parser, default=None,
                         help="include the robot's gravity (the convention's default is "
                         "--no-gravity; without either flag this verb keeps the robot's "
                         "gravity for one release, with a note)")
    parser.add_argument("--controller", choices=("composite", "inversion"), default=None,
                        help="add rt_step: EKF and this controller in one call")
    parser.add_argument("--kp", type=float, default=1.0, metavar="KP",
                        help="slow gain K_p, 1/s^2 (default 1)")
    parser.add_argument("--kd", type=float, default=2.0, metavar="KD",
                        help="slow gain K_d, 1/s (default 2)")
    parser.add_argument("--q-weight", type=float, default=1.0, metavar="W",
                        help="LQR Q = w I (composite; default 1)")
    parser.add_argument("--r-weight", type=float, default=10.0, metavar="W",
                        help="LQR R = w I (composite; default 10)")
    parser.add_argument("--guard", action="store_true",
                        help="guarded ekf_step/rt_step: NaN/inf inputs skipped or held, "
                             "innovation gate, covariance bounds, status word")
    parser.add_argument("--P0", type=float, default=1e-4,
                        help="--guard: reset covariance P0 I (default 1e-4)")
    parser.add_argument("--gate", type=float, default=None,
                        help="--guard: threshold of nu^2/S per channel (default the "
                             "chi-square(1) quantile of 1 - 1e-9, 37.3)")
    parser.add_argument("--torque-limit", type=float, nargs="+", default=None,
                        metavar="N_M", help="--guard with --controller: torque limit of "
                        "each joint (one value for all, or one per joint 1..n), N m")
    parser.add_argument("--kinematics", choices=("truncated", "exact"), default="truncated",
                        help="kinematics of the forward-dynamics bundle: 'exact' rebuilds the "
                             "links from the modal strains (large deflections; a C file "
                             "several times larger)")
    add_cache_arguments(parser)


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Generate the bundles; return ``{"files": [...], "functions": [...]}``.

    Building the model tabulates modes over a grid (seconds to minutes), so the example
    below only shows an argument check; see the module docstring for what is written.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"files": [paths of source, header, README, Makefile, manifest per bundle],
        "functions": [C function names]}``.

    Raises
    ------
    casflex.errors.ModelError
        ``--modes < 1``, ``--dt <= 0``, ``--R`` missing for sensors without noise,
        ``--step`` with ``--fit chebyshev``, or ``--kinematics exact`` with ``--no-model``.

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> args = p.parse_args(["problems/arm2link.toml", "--sensors",
    ...                      "problems/sensors/arm2link_strain.toml", "--out", "d",
    ...                      "--modes", "0"])
    >>> run(args, print)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --modes: must be >= 1; got 0
    """
    from casflex.codegen import realtime_bundles

    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    if not (args.dt > 0 and math.isfinite(args.dt)):
        raise ModelError(f"--dt: must be > 0 s; got {args.dt}")
    output_directory(args.out, "--out")  # before any heavy work
    guard = None
    if args.guard:
        from casflex.estimation import DEFAULT_GATE, Guard

        if args.sqrt:
            raise ModelError("--guard: not with --sqrt")
        if args.controller and args.torque_limit is None:
            raise ModelError("--guard with --controller: --torque-limit must be given")
        if not (args.P0 > 0 and math.isfinite(args.P0)):
            raise ModelError(f"--P0: must be > 0; got {args.P0}")
        gate = DEFAULT_GATE if args.gate is None else args.gate
        if not gate > 0:
            raise ModelError(f"--gate: must be > 0; got {gate}")
        guard = Guard(P_reset=args.P0 * np.eye(2 * args.modes), gate=gate)
    elif args.torque_limit is not None or args.gate is not None:
        raise ModelError("--torque-limit and --gate need --guard")
    limits = args.torque_limit
    if limits is not None and not all(v > 0 and math.isfinite(v) for v in limits):
        raise ModelError(f"--torque-limit: must be > 0 N m; got {limits}")
    if limits is not None and len(limits) == 1:
        limits = limits[0]
    if args.kinematics == "exact" and args.no_model:
        raise ModelError("--kinematics exact: applies to the forward-dynamics bundle, which "
                         "--no-model leaves out")
    if args.fit == "chebyshev" and args.step is not None:
        raise ModelError(f"--step {args.step}: the grid step of the modal tables; --fit "
                         "chebyshev has no grid (leave --step out)")
    cache_dir = cache_dir_of(args)
    notes = []  # deprecation notes, written after the work so that an error stays one line
    step = _step(args.step, notes)
    gravity = args.gravity
    if gravity is None:  # the old default of this verb, for one release
        notes.append(("codegen without --gravity/--no-gravity (modelled the robot's "
                      "gravity, as before)", "--gravity to keep it, --no-gravity for the "
                      "convention's default"))
        gravity = True
    bundles = realtime_bundles(
        args.robot, args.sensors, args.out, n_modes=args.modes, name=args.name,
        step=step, gravity=gravity, model=not args.no_model, Q=args.Q, R=args.R,
        dt=args.dt, sqrt=args.sqrt, prefilter=args.prefilter, jacobians=args.jacobians,
        controller=args.controller, kp=args.kp, kd=args.kd, q_weight=args.q_weight,
        r_weight=args.r_weight, guard=guard, torque_limits=limits, fit=args.fit,
        basis=args.basis, kinematics=args.kinematics, log=log,
        progress=True, cache_dir=cache_dir)
    files, functions = [], []
    for b in bundles:
        files += [str(p) for p in (b.source, b.header, b.readme, b.makefile, b.manifest)
                  if p is not None]
        functions += [f.name for f in b.functions]
        log(f"wrote {b.source} and {b.header}")
    for old, new in notes:
        deprecation_note(old, new)
    return {"files": files, "functions": functions}


def _step(text, notes):
    """``--step`` in rad; a bare number is the old convention (deg), with a note."""
    if text is None:
        return None
    if _BARE_NUMBER.match(str(text)):
        notes.append((f"codegen --step {str(text).strip()} (a number read in deg)",
                      f"--step {str(text).strip()}deg"))
        text = f"{str(text).strip()}deg"
    step = parse_angle(text, "--step")
    if not step > 0:
        raise ModelError(f"--step: must be > 0; got {text}")
    return step
