"""``casflex calibrate``: fit robot parameters to measured natural frequencies.

``casflex calibrate ROBOT.toml (--data MEAS.csv | --logs LOG ...) --fit FIT.toml
[--sensors SENSORS.toml] [--mac-min M] [--modes N] [--q-tolerance RAD] [--min-segment S]
[--out CALIBRATED.toml] [--plot FILE.png] [--processes P] [--json]``

``--data`` is a measurement file (``q1..qn`` [rad], ``f1..fm`` [Hz], optional
``f1_std..``); ``--logs`` identifies every log first and fits to the frequencies found:
a log is cut into segments of constant joint angles (every ``q`` column within
``--q-tolerance`` rad of its value at the segment's start for at least ``--min-segment``
seconds; the moves between are dropped), so one log may hold one configuration or a
whole test campaign.

With ``--sensors`` (a sensor file giving the accelerometer channels' positions), measured
modes that carry shapes (``f<j>_<channel>`` columns of the measurement file, or the
identified shapes of the logs) are paired with modelled modes by MAC, the others by
frequency order; a pair with MAC below ``--mac-min`` (default 0.7) is refused. The fit
file names the free parameters
(``[[parameter]]`` with ``path``, ``min``, ``max``); formats in ``problems/README.md``.
``--out`` writes the robot file with the fitted values and a comment saying where they
came from; a parameter that is not identifiable keeps the robot file's value and is named
in the header comment with the reason.

JSON: ``{"parameters", "initial", "std", "identifiable", "reasons", "correlation",
"rms_before_hz", "rms_after_hz", "residual_hz", "residual_before_hz", "chi2_reduced",
"tmm_evaluations", "modelled_mode", "mac", "out"}`` (paths -> values in the parameters'
units; residuals per row and mode, model minus measurement, null where not measured;
``modelled_mode`` the 1-based modelled partner of each measured mode, ``mac`` its MAC or
null where matched by frequency order).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from casflex._problemfile import read_toml
from casflex._validate import output_file
from casflex.commands.common import add_robot_argument, plot_path
from casflex.errors import ModelError
from casflex.identification.logs import SEGMENT_MIN_DURATION, SEGMENT_TOLERANCE
from casflex.identification.matching import MAC_MIN
from casflex.robot import load

HELP = "fit robot parameters (E, masses, joint stiffness ...) to measured frequencies"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex calibrate``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["r.toml", "--data", "m.csv", "--fit", "f.toml"])
    >>> a.data, a.logs, a.fit
    ('m.csv', None, 'f.toml')
    """
    add_robot_argument(parser)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--data", metavar="MEAS.csv", default=None,
                        help="measured frequencies (columns q1..qn in rad, f1..fm in Hz, "
                        "optional f1_std..fm_std)")
    source.add_argument("--logs", nargs="+", metavar="LOG", default=None,
                        help="test logs (CSV or NPZ), one configuration each: identified "
                             "first")
    parser.add_argument("--fit", required=True, metavar="FIT.toml",
                        help="free parameters: [[parameter]] path, min, max")
    parser.add_argument("--sensors", default=None, metavar="SENSORS.toml",
                        help="accelerometer positions of the shape channels: match modes "
                             "by MAC")
    parser.add_argument("--mac-min", type=float, default=MAC_MIN, metavar="M",
                        help=f"lowest MAC accepted for a pair (default {MAC_MIN})")
    parser.add_argument("--modes", type=int, default=None, metavar="N",
                        help="with --logs: modes kept per log (the most significant)")
    parser.add_argument("--q-tolerance", type=float, default=SEGMENT_TOLERANCE, metavar="RAD",
                        help="with --logs: joint-angle band of a segment of constant "
                             f"configuration (default {SEGMENT_TOLERANCE} rad)")
    parser.add_argument("--min-segment", type=float, default=SEGMENT_MIN_DURATION,
                        metavar="S", help="with --logs: shortest segment identified "
                                          f"(default {SEGMENT_MIN_DURATION} s)")
    parser.add_argument("--out", default=None, metavar="CALIBRATED.toml",
                        help="write the robot file with the fitted values")
    parser.add_argument("--plot", default=None, metavar="FILE.png",
                        help="measured vs modelled frequencies before and after")
    parser.add_argument("--processes", type=int, default=None, metavar="P",
                        help="worker processes of the TMM evaluations (default a pool "
                             "when the Jacobian is large enough; 1 = no pool)")


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Fit the parameters; return the result dict (see the module docstring).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / "m.csv").write_text("q1,q2,q3,f1,f2\\n"
    ...                              "0,0,0,1.3136,1.8973\\n0,0,1,2.2102,2.9330\\n")
    >>> _ = (d / "fit.toml").write_text('[[parameter]]\\npath = "link2.material.E"\\n'
    ...                                 'min = 30e9\\nmax = 120e9\\n')
    >>> a = argparse.Namespace(robot="problems/arm2link.toml", data=str(d / "m.csv"),
    ...                        logs=None, fit=str(d / "fit.toml"), modes=None,
    ...                        q_tolerance=0.005, min_segment=2.0, sensors=None,
    ...                        mac_min=0.7,
    ...                        out=str(d / "cal.toml"), plot=None, processes=1)
    >>> out = run(a, lambda m: None)
    >>> out["identifiable"], out["rms_after_hz"] < out["rms_before_hz"]
    ({'link2.material.E': True}, True)
    """
    from casflex.identification import (
        calibrate,
        calibrated_text,
        measurements_from_logs,
        read_channels,
        read_fit,
        read_measurements,
    )

    plot_path(args.plot)  # output paths before any heavy work
    if args.out is not None:
        output_file(args.out, "--out")
    if args.processes is not None and args.processes < 1:
        raise ModelError(f"--processes: must be >= 1; got {args.processes}")
    if args.modes is not None and args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    for flag, value in (("--q-tolerance", args.q_tolerance), ("--min-segment", args.min_segment)):
        if not value > 0.0 or value == float("inf"):
            raise ModelError(f"{flag}: must be a finite number > 0; got {value}")
    robot = load(args.robot)
    raw = read_toml(args.robot)
    params = read_fit(args.fit, robot, raw)
    if not 0.0 < args.mac_min <= 1.0:
        raise ModelError(f"--mac-min: must lie in (0, 1]; got {args.mac_min}")
    channels = None if args.sensors is None else read_channels(args.sensors, robot)
    progress = sys.stderr.isatty()
    if args.data is not None:
        data = read_measurements(args.data, robot.n_joints)
        source = args.data
    else:
        data, estimates = measurements_from_logs(
            args.logs, robot.n_joints, n_modes=args.modes, progress=progress,
            tolerance=args.q_tolerance, min_duration=args.min_segment)
        source = f"{len(args.logs)} logs ({len(estimates)} configurations)"
        log(f"segments of constant joint angles: {data.source}")
        for i, (q, est) in enumerate(zip(data.q, estimates, strict=True)):
            log(f"  row {i + 1}: q = " + ", ".join(f"{v:.4f}" for v in q) + " rad: "
                + ", ".join(f"{f:.4f}" for f in est.frequency_hz) + " Hz")
    log(f"{robot.name}: fitting {len(params)} parameters to {data.n_values} frequencies at "
        f"{len(data.q)} configurations")
    result = calibrate(robot, data, params, processes=args.processes, progress=progress,
                       channels=channels, mac_min=args.mac_min)
    if result.mac is not None and np.isfinite(result.mac).any():
        for r, c in zip(*np.nonzero(np.isfinite(result.mac)), strict=True):
            log(f"  row {r + 1} f{c + 1} <-> modelled mode {result.pairing[r, c] + 1}: "
                f"MAC {result.mac[r, c]:.3f}")
    for j, name in enumerate(result.names):
        if result.identifiable[j]:
            log(f"  {name} = {result.values[j]:.6g} ± {result.std[j]:.2g} "
                f"(from {result.initial[j]:.6g})")
        else:
            log(f"  {name} = {result.values[j]:.6g}: NOT identifiable: {result.reasons[j]}")
    log(f"  rms residual {result.rms_before_hz:.4g} Hz -> {result.rms_after_hz:.4g} Hz "
        f"({result.tmm_evaluations} TMM solutions)")
    out = result.as_dict()
    out["out"] = None
    if args.out is not None:
        text = Path(args.robot).read_text(encoding="utf-8")
        # only identifiable values go into the file; the others keep the robot file's
        # value and are named in the header
        keep = [j for j in range(len(params)) if result.identifiable[j]]
        new = calibrated_text(text, [params[j].path for j in keep],
                              [result.values[j] for j in keep],
                              f"casflex calibrate: fitted to {source}")
        new = (f"# Calibrated by casflex calibrate from {args.robot} and {source} "
               f"(fit file {args.fit}).\n"
               + "".join(f"# NOT identifiable, left as in {args.robot}: {n}: {r}\n"
                         for n, r in zip(result.names, result.reasons, strict=True) if r)
               + new)
        Path(args.out).write_text(new, encoding="utf-8")
        out["out"] = str(args.out)
        log(f"wrote {args.out}")
    if args.plot:
        from casflex.plotting import plot_calibration

        plot_calibration(result, title=f"{robot.name}: calibration").savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    return out
