"""``casflex identify``: natural frequencies and damping ratios from a test log.

``casflex identify LOG.csv [--config Q1,Q2,...] [--modes N] [--fmax HZ] [--start S]
[--plot FILE.png] [--json]``

The log (CSV or NPZ: a time column ``t``, optional joint columns ``q1..qn``, every other
column an accelerometer channel; :mod:`casflex.identification.logs`) holds one impulse or
free-decay test. Welch spectra give the peak list; ERA over model orders with a
stabilisation check and a damped-sinusoid least-squares fit give the modes
(:func:`casflex.identification.identify_modes`). ``--config`` states the configuration
(rad, or with a ``deg`` suffix) when the log has no joint columns, or overrides them.

JSON: ``{"log", "q", "frequency_hz", "frequency_std_hz", "damping", "damping_std",
"seen_by", "shape", "sample_rate_hz", "peaks_hz", "rejected_hz"}`` (Hz, rad; ``q`` null
when unknown; ``shape``: per mode, channel -> amplitude signed by its phase, the values
of the ``f<j>_<channel>`` columns of a measurement file).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from casflex.commands.common import parse_angle, plot_path
from casflex.errors import ModelError

HELP = ("identify natural frequencies and damping from an impulse-test log (Welch, ERA, "
        "least squares)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``casflex identify``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> a = p.parse_args(["log.csv", "--config", "0,0,300deg", "--modes", "4"])
    >>> a.config, a.modes
    ('0,0,300deg', 4)
    """
    parser.add_argument("log", metavar="LOG.csv", help="test log (CSV or NPZ)")
    parser.add_argument("--config", default=None, metavar="Q1,Q2,...",
                        help="configuration of the test, comma-separated, rad or with a "
                             "'deg' suffix (default the median of the log's q columns)")
    parser.add_argument("--modes", type=int, default=None, metavar="N",
                        help="report at most N modes (the most significant)")
    parser.add_argument("--fmax", type=float, default=None, metavar="HZ",
                        help="top of the band searched, Hz (default twice the highest peak)")
    parser.add_argument("--start", type=float, default=None, metavar="S",
                        help="start of the free decay after the first sample, s (default "
                             "where the record first reaches 30 %% of its largest excursion)")
    parser.add_argument("--plot", metavar="FILE.png", default=None,
                        help="write the spectrum and the stabilisation diagram")


def run(args: argparse.Namespace, log: Callable[[str], None]) -> dict:
    """Identify the modes of the log; return them as a dict (see the module docstring).

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
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> t = np.arange(4000) / 400.0
    >>> wn = 2 * np.pi * 3.0
    >>> y = np.exp(-0.01 * wn * t) * np.cos(wn * np.sqrt(1 - 1e-4) * t)
    >>> np.savez(f"{d}/a.npz", t=t, acc=y + 1e-4 * np.sin(977 * t))
    >>> a = argparse.Namespace(log=f"{d}/a.npz", config="0.5", modes=None, fmax=None,
    ...                        start=None, plot=None)
    >>> out = run(a, lambda m: None)
    >>> out["q"].tolist(), np.round(out["frequency_hz"], 4).tolist()
    ([0.5], [3.0])
    """
    from casflex.identification import identify_modes, read_log

    plot_path(args.plot)  # before any heavy work
    record = read_log(args.log)
    q = record.configuration
    if args.config is not None:
        q = np.array([parse_angle(v, "--config") for v in args.config.split(",")])
        if record.q is not None and q.size != record.q.shape[1]:
            raise ModelError(f"--config: {q.size} values; the log has {record.q.shape[1]} "
                             "joint columns")
    if args.modes is not None and args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    est = identify_modes(record.t, record.channels, channels=record.names,
                         n_modes=args.modes, fmax_hz=args.fmax, start=args.start)
    log(f"{args.log}: {record.t.size} samples at {est.sample_rate:.6g} Hz, channels "
        f"{', '.join(record.names)}; fitted at {est.fit_rate:.4g} Hz from t = {est.start:.3g} s")
    for i in range(est.frequency_hz.size):
        log(f"  mode {i + 1}: {est.frequency_hz[i]:10.5f} ± {est.frequency_std_hz[i]:.2g} Hz, "
            f"ζ = {est.damping[i]:.4f} ± {est.damping_std[i]:.2g}, seen by "
            f"{', '.join(est.seen_by[i]) or '-'}")
    if est.rejected_hz:
        log("  rejected as spurious: " + ", ".join(f"{f:.4g} Hz" for f in est.rejected_hz))
    if args.plot:
        from casflex.plotting import plot_identification

        plot_identification(est, title=str(args.log)).savefig(args.plot, dpi=120)
        log(f"wrote {args.plot}")
    out = {"log": str(args.log), "q": None if q is None else q}
    out.update(est.as_dict())
    return out
