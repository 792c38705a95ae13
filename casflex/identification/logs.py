"""Recorded test logs: a time column, joint angles and accelerometer channels.

A log is one impulse or free-decay test at one configuration of the arm, as a CSV file
(one header row of column names, then one row per sample; lines starting with ``#`` are
comments) or an NPZ file (one 1-D array per column, all of the same length):

``t``
    time [s], increasing. The sample rate is taken from it (a least-squares line through
    the sample times), not from a nominal rate; the sampling must be uniform (a sample
    may jitter by at most a quarter of a period).
``q1`` … ``qn``
    joint angles [rad] (optional; 1-based as in every file). The configuration of the
    test is their median over the record.
every other column
    an accelerometer channel [m/s²], named by its column (``tip_x``, ``acc2_z`` ...).
    Offsets (gravity, bias) are allowed.

A log may hold several configurations (a test campaign recorded in one file: tap, wait,
move, tap, ...). :func:`split_configurations` cuts it into *segments of constant joint
angles*: maximal runs of samples over which every joint stays within ``tolerance`` rad
(default 0.005 rad, 0.29°) of its value at the run's first sample and which last at least
``min_duration`` seconds (default 2 s); two adjacent runs whose median angles lie within
half the tolerance of each other are one (noise cut the first short); everything else
(the moves between) is dropped.
Each segment is then one free-decay record at one configuration (the ends of the moves
that stay within the band belong to it; the identification starts at the impulse).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from casflex._problemfile import read_npz
from casflex.errors import ProblemFileError

__all__ = ["VibrationLog", "read_log", "uniform_sample_rate", "split_configurations"]

_JOINT = re.compile(r"^q([1-9][0-9]*)$")
#: smallest number of samples a log must hold
MIN_SAMPLES = 64
#: default joint-angle band of a segment of constant configuration [rad]
SEGMENT_TOLERANCE = 0.005
#: default shortest segment kept [s]
SEGMENT_MIN_DURATION = 2.0


@dataclass(frozen=True)
class VibrationLog:
    """One recorded test.

    Attributes
    ----------
    t : numpy.ndarray
        (N,) sample times [s].
    channels : numpy.ndarray
        (N, C) accelerometer signals [m/s²].
    names : tuple of str
        The C channel names.
    q : numpy.ndarray or None
        (N, n) joint angles [rad], or ``None`` when the log has no ``q`` columns.
    source : str or None
        File the log was read from.

    Examples
    --------
    >>> t = np.arange(100) / 100.0
    >>> log = VibrationLog(t, np.zeros((100, 1)), ("tip_z",), None, None)
    >>> log.sample_rate, log.configuration
    (100.0, None)
    """

    t: np.ndarray
    channels: np.ndarray
    names: tuple[str, ...]
    q: np.ndarray | None
    source: str | None

    @property
    def sample_rate(self) -> float:
        """Sample rate [Hz] from the time column."""
        return uniform_sample_rate(self.t, self.source)

    @property
    def configuration(self) -> np.ndarray | None:
        """Median joint angles over the record [rad] (``None`` without ``q`` columns)."""
        return None if self.q is None else np.median(self.q, axis=0)


def uniform_sample_rate(t: ArrayLike, source: str | os.PathLike | None = None) -> float:
    """Sample rate [Hz] of uniformly sampled times: the slope of a line through them.

    Parameters
    ----------
    t : array_like
        (N,) sample times [s], increasing, N >= 2.
    source : str, optional
        File named in errors.

    Returns
    -------
    float
        Samples per second [Hz].

    Raises
    ------
    ProblemFileError
        Times not increasing, or a sample further than a quarter period from the line.

    Examples
    --------
    >>> uniform_sample_rate(np.arange(10) / 4987.0)
    4987.0
    """
    t = np.asarray(t, dtype=float)
    if t.size < 2 or not np.all(np.diff(t) > 0.0):
        raise ProblemFileError(source, "t", None, "must increase from sample to sample")
    k = np.arange(t.size, dtype=float)
    slope, intercept = np.polyfit(k, t, 1)
    jitter = np.max(np.abs(t - (intercept + slope * k)))
    if jitter > 0.25 * slope:
        i = int(np.argmax(np.abs(t - (intercept + slope * k))))
        raise ProblemFileError(
            source, "t", float(t[i]),
            f"sampling is not uniform: sample {i + 1} lies {jitter / slope:.2f} periods off a "
            f"uniform grid of {1.0 / slope:.6g} Hz (at most 0.25); resample the log")
    return float(round(1.0 / slope, 9))


def _read_columns(path):
    if path.suffix.lower() == ".npz":
        return read_npz(path, "a log is a CSV file or an archive of numpy.savez")
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines()
                 if ln.strip() and not ln.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc
    if not lines:
        raise ProblemFileError(path, "<header>", None, "the file holds no header row")
    header = [h.strip() for h in lines[0].split(",")]
    if len(set(header)) != len(header) or not all(header):
        raise ProblemFileError(path, "<header>", lines[0],
                               "column names must be non-empty and distinct")
    rows = []
    for i, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        if len(cells) != len(header):
            raise ProblemFileError(path, f"row {i}", line[:60],
                                   f"has {len(cells)} cells; the header has {len(header)}")
        try:
            rows.append([float(c) for c in cells])
        except ValueError as exc:
            raise ProblemFileError(path, f"row {i}", line[:60], "every cell must be a number"
                                   ) from exc
    data = np.array(rows, dtype=float).reshape(-1, len(header))
    return {h: data[:, j] for j, h in enumerate(header)}


def read_log(path: str | os.PathLike) -> VibrationLog:
    """Read a test log (CSV or NPZ, format in the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        ``.csv`` or ``.npz`` file.

    Returns
    -------
    VibrationLog

    Raises
    ------
    ProblemFileError
        Unreadable file, no ``t`` column, no channel, a non-finite value, fewer than 64
        samples, non-uniform sampling; the message names the file and the column.

    Examples
    --------
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> t = np.arange(200) / 500.0
    >>> q = {f"q{j}": np.full(200, 0.5 * j) for j in (1, 2, 3)}
    >>> np.savez(f"{d}/log.npz", t=t, tip_z=np.sin(20 * t), **q)
    >>> log = read_log(f"{d}/log.npz")
    >>> log.names, log.sample_rate, log.configuration.tolist()
    (('tip_z',), 500.0, [0.5, 1.0, 1.5])
    """
    path = Path(path)
    columns = _read_columns(path)
    if "t" not in columns:
        raise ProblemFileError(path, "t", None, "a log needs a time column named 't' [s]")
    n = None
    for name, values in columns.items():
        if values.ndim != 1:
            raise ProblemFileError(path, name, values.shape, "must be a 1-D column")
        if n is None:
            n = values.size
        elif values.size != n:
            raise ProblemFileError(path, name, values.size,
                                   f"has a different length from the other columns ({n})")
        if not np.issubdtype(values.dtype, np.number) or not np.all(
                np.isfinite(values.astype(float))):
            raise ProblemFileError(path, name, None, "must hold finite numbers only")
    if n < MIN_SAMPLES:
        raise ProblemFileError(path, "t", n, f"a log needs at least {MIN_SAMPLES} samples")
    joints = {}
    for name in columns:
        m = _JOINT.match(name)
        if m:
            joints[int(m.group(1))] = name
    if joints and sorted(joints) != list(range(1, len(joints) + 1)):
        raise ProblemFileError(path, "q", sorted(joints),
                               "joint columns must be q1 .. qn without gaps")
    names = tuple(k for k in columns if k != "t" and not _JOINT.match(k))
    if not names:
        raise ProblemFileError(path, "<header>", list(columns),
                               "a log needs at least one accelerometer channel")
    t = columns["t"].astype(float)
    uniform_sample_rate(t, path)
    q = (np.column_stack([columns[joints[j]].astype(float) for j in sorted(joints)])
         if joints else None)
    channels = np.column_stack([columns[k].astype(float) for k in names])
    if not math.isfinite(float(np.sum(channels))):
        raise ProblemFileError(path, "<channels>", None, "values overflow the float range")
    return VibrationLog(t, channels, names, q, str(path))


def _run_end(q, start, tolerance):
    """First index after ``start`` where a joint leaves ``q[start] ± tolerance`` (or the
    end): searched in doubling blocks, so the cost stays linear over many short runs."""
    n, block, i = len(q), 64, start + 1
    while i < n:
        stop = min(n, i + block)
        out = np.flatnonzero(np.any(np.abs(q[i:stop] - q[start]) > tolerance, axis=1))
        if out.size:
            return i + int(out[0])
        i, block = stop, 2 * block
    return n


def split_configurations(log: VibrationLog, tolerance: float = SEGMENT_TOLERANCE,
                         min_duration: float = SEGMENT_MIN_DURATION) -> list[VibrationLog]:
    """Cut a log into its segments of constant joint angles (rule in the module docstring).

    Parameters
    ----------
    log : VibrationLog
        A log with joint columns.
    tolerance : float
        Largest deviation of any joint from its value at the segment's first sample [rad].
    min_duration : float
        Shortest segment kept [s] (shorter runs are motion and are dropped).

    Returns
    -------
    list of VibrationLog
        The segments in time order, each with its own ``t``, ``channels`` and ``q``
        (``source`` names the file and the time span).

    Raises
    ------
    ProblemFileError
        A log without joint columns, or without any segment of ``min_duration``.

    Examples
    --------
    >>> t = np.arange(1000) / 100.0
    >>> q = np.where(t < 4.0, 0.0, np.where(t < 5.0, t - 4.0, 1.0))[:, None]
    >>> parts = split_configurations(VibrationLog(t, np.zeros((1000, 1)), ("a",), q, None))
    >>> [(float(p.t[0]), float(p.t[-1]), float(p.configuration[0])) for p in parts]
    [(0.0, 4.0, 0.0), (5.0, 9.99, 1.0)]
    """
    tolerance = float(tolerance)
    min_duration = float(min_duration)
    if not (tolerance > 0.0 and math.isfinite(tolerance)):
        raise ProblemFileError(log.source, "tolerance", tolerance, "must be a finite number > 0")
    if not (min_duration > 0.0 and math.isfinite(min_duration)):
        raise ProblemFileError(log.source, "min_duration", min_duration,
                               "must be a finite number > 0")
    if log.q is None:
        raise ProblemFileError(log.source, "q", None,
                               "splitting by configuration needs the joint columns q1..qn")
    dt = 1.0 / log.sample_rate
    runs, start = [], 0
    while start < len(log.t):
        end = _run_end(log.q, start, tolerance)
        # a run cut by encoder noise right after it began (at the end of a move) is
        # continued by the next one: adjacent runs whose medians lie within half the band
        # are one (the runs of a slow move lie a whole band apart)
        if runs and runs[-1][1] == start and np.all(np.abs(
                np.median(log.q[runs[-1][0]:runs[-1][1]], axis=0)
                - np.median(log.q[start:end], axis=0)) <= 0.5 * tolerance):
            runs[-1] = (runs[-1][0], end)
        else:
            runs.append((start, end))
        start = end
    segments = []
    for start, end in runs:
        if (end - start) * dt >= min_duration and end - start >= MIN_SAMPLES:
            span = f"t = {log.t[start]:.6g} .. {log.t[end - 1]:.6g} s"
            segments.append(VibrationLog(log.t[start:end], log.channels[start:end],
                                         log.names, log.q[start:end],
                                         f"{log.source}, {span}" if log.source else span))
    if not segments:
        raise ProblemFileError(log.source, "q", None,
                               f"no segment of constant joint angles (within {tolerance:g} rad) "
                               f"lasts {min_duration:g} s")
    return segments
