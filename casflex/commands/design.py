"""``casflex design``: the end-to-end design job of a study file (:mod:`casflex.design`).

``casflex design STUDY.toml --out DIR [--cache-dir DIR | --no-cache] [--processes N]
[--json]``

Tabulates (or reuses) the modal model with a progress bar, designs the SI shaper of the
study's move from the frequency ranges and modal contributions along it, simulates the move
unshaped, shaped, and shaped under the closed-loop controller with the EKF in the loop,
checks stability along the move, generates and compiles the C bundle, and writes
``DIR/report.md``, the PNG figures, ``DIR/summary.json`` and ``DIR/c/``. A study that names
a missing file, an unknown sensor link or an impossible tolerance fails before any heavy
work.

JSON: the summary (``summary.json``), with at least ``shaper_duration`` [s],
``frequency_ranges`` [rad/s], ``contributions``, ``residual_reduction`` (0–1), ``stable``
and ``c_files``, ``status`` (``"stable"``, ``"not stable"`` or ``"closed loop diverged"``)
and ``closed_loop_divergence`` (``None``, or the time [s] and quantity where the sampled
loop with the EKF diverged: the job writes its report and says so instead of failing).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from casflex.commands.common import (
    add_cache_arguments,
    add_processes_argument,
    cache_dir_of,
    disk_cache,
)

HELP = "run the design job of a study: shaper, simulations, stability, C bundle, report"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex design``.

    Parameters
    ----------
    parser : argparse.ArgumentParser

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["s.toml", "--out", "d"]).out
    'd'
    """
    parser.add_argument("study", metavar="STUDY.toml",
                        help="study file (e.g. problems/studies/arm2link_move1.toml)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    add_cache_arguments(parser)
    add_processes_argument(parser, "worker processes of the tabulation (default all CPUs)")


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Validate the study, run the job, return the summary (SI units).

    Parameters
    ----------
    args : argparse.Namespace
        From :func:`add_arguments`.
    log : callable
        ``log(message)`` writes one line to stderr.

    Returns
    -------
    dict
        :attr:`casflex.design.DesignResult.summary`.

    Examples
    --------
    A study with a tolerance outside ``(0, 1]`` fails before any heavy work:

    >>> import argparse, tempfile
    >>> from pathlib import Path
    >>> bad = Path(tempfile.mkdtemp()) / "bad.toml"
    >>> _ = bad.write_text(Path("problems/studies/arm2link_move1.toml").read_text()
    ...                    .replace("vtol = 0.05", "vtol = 2.0")
    ...                    .replace('"../', f'"{Path.cwd()}/problems/'))
    >>> run(argparse.Namespace(study=str(bad), out="o", cache_dir=None, processes=None),
    ...     print)
    Traceback (most recent call last):
    ...
    casflex.errors.ProblemFileError: ...shaper.vtol...must be <= 1...
    """
    from casflex._validate import output_directory
    from casflex.design import run_design
    from casflex.errors import ModelError

    if args.processes is not None and args.processes < 1:
        raise ModelError(f"--processes: must be >= 1; got {args.processes}")
    output_directory(args.out, "--out")
    start = time.perf_counter()

    def step(message):
        log(f"[{time.perf_counter() - start:6.1f} s] {message}")

    # the study is validated before any heavy work starts; --no-cache: a temporary
    # directory, since the compiled closed loop must live on disk
    with disk_cache(cache_dir_of(args)) as cache_dir:
        result = run_design(args.study, args.out, progress=True, log=step,
                            cache_dir=cache_dir, processes=args.processes)
    s = result.summary
    log(f"shaper: {len(s['shaper']['times'])} impulses, {s['shaper_duration']:.4f} s; "
        f"shaping removes {100 * s['residual_reduction']:.1f} % of the residual tip "
        f"deflection; {'stable' if s['stable'] else 'NOT stable'} along the move")
    d = s.get("closed_loop_divergence")
    if d is not None:
        where = f" at t = {d['time']:.4g} s ({d['quantity']})" if d["time"] is not None else ""
        log(f"status: the closed loop with the EKF DIVERGED{where}; the report says so")
    log(f"wrote {result.out_dir / 'report.md'} and {len(result.files) - 1} more files "
        f"in {time.perf_counter() - start:.1f} s")
    return s
