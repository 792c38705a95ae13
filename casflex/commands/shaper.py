"""``casflex shaper``: design a specified-insensitivity input shaper.

``casflex shaper PROBLEM.toml [--plot FILE.png] [--json]`` reads a shaper problem (a TOML
file with ``[[range]]`` tables, see ``problems/shapers/README.md``), designs the SI shaper
with :func:`casflex.shaping.si_shaper` and returns the impulses and the verified maximum
residual vibration of every range (times in s, frequencies in rad/s).

A robot description (``ROBOT.toml --move``, Vtol levels from modal contributions) will be
accepted later; for now any file without ``[[range]]`` tables is rejected.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from casflex.errors import ProblemFileError
from casflex.shaping import (
    ranges_from_mapping,
    residual_vibration,
    si_shaper,
)

HELP = "Design a specified-insensitivity input shaper from a shaper problem file."


def add_arguments(parser):
    """Add the ``shaper`` arguments to ``parser``.

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
        help="shaper problem file with [[range]] tables (frequencies in rad/s or Hz)",
    )
    parser.add_argument(
        "--plot",
        metavar="FILE.png",
        default=None,
        help="write the residual vibration curve over all ranges with the tolerances",
    )


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
    if not isinstance(data, dict) or "range" not in data:
        raise ProblemFileError(
            path,
            "range",
            None,
            "no [[range]] tables: this is not a shaper problem, and the robot form "
            "(ROBOT.toml --move) is not available yet",
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
