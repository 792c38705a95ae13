"""Model updating: robot parameters fitted to measured natural frequencies.

The fit is a bounded weighted least squares (:func:`scipy.optimize.least_squares`,
trust-region reflective) of the TMM natural frequencies against the measurements,
measured and modelled modes matched by frequency order (column ``fj`` is the j-th lowest
mode). Residuals are ``(f_model - f_measured) / f_std``, or in Hz when the file gives no
standard deviations. The Jacobian is a forward difference (relative step 1e-6, far above
the TMM's 1e-12 root tolerance), its evaluations run in parallel
(:func:`casflex._parallel.parallel_map`).

Uncertainty and identifiability
-------------------------------
The covariance is ``(JᵀJ)⁻¹`` times the reduced chi-square when that exceeds 1 (or when
no standard deviations are given, when it is the residual variance); it gives the
standard deviations and the correlation matrix. The Jacobian, with each column scaled to
unit norm, is decomposed (SVD); a singular value below ``1e-3`` of the largest
(condition above 1000) marks a direction the data cannot resolve, and every parameter
with a weight of at least 0.2 in it is *not identifiable* ("only a combination of ... is
determined"). A parameter the frequencies do not depend on, one whose standard deviation
exceeds half its value, and one that ends on a bound are not identifiable either; each
comes with its reason, and its standard deviation is reported as infinite, never as a
confident number.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from casflex._parallel import parallel_map, progress_bar, worker_pool
from casflex._problemfile import TableReader, read_toml
from casflex.errors import ModelError, ProblemFileError, SolverError
from casflex.identification.logs import SEGMENT_MIN_DURATION, SEGMENT_TOLERANCE
from casflex.identification.matching import (
    EXTRA_MODES,
    MAC_MIN,
    Channel,
    match_modes,
    model_channel_shapes,
)
from casflex.identification.parameters import (
    ParameterPath,
    parameter_value,
    parse_parameter_path,
    with_parameters,
)
from casflex.robot import Robot

__all__ = ["Measurements", "FitParameter", "read_measurements", "read_fit", "model_frequencies",
           "CalibrationResult", "calibrate"]

#: relative singular value below which a parameter direction is not resolved
COLLINEARITY = 1e-3
#: weight of a parameter in an unresolved direction that makes it not identifiable
DIRECTION_WEIGHT = 0.2
#: relative standard deviation above which a parameter is not identifiable
MAX_RELATIVE_STD = 0.5
#: relative finite-difference step of the Jacobian
STEP = 1e-6
#: TMM solutions per Jacobian from which the default runs them on a process pool
POOL_THRESHOLD = 64
#: most fits with re-matched modes
MAX_REMATCH = 4


@dataclass(frozen=True)
class Measurements:
    """Measured natural frequencies at several configurations.

    Attributes
    ----------
    q : numpy.ndarray
        (R, n_joints) configurations [rad].
    frequency_hz : numpy.ndarray
        (R, m) the m lowest natural frequencies per row [Hz], NaN where not seen.
    std_hz : numpy.ndarray or None
        (R, m) their standard deviations [Hz], or ``None`` (unweighted fit).
    source : str or None
        File they were read from.
    channels : tuple of str
        Accelerometer channels at which mode shapes were identified (may be empty).
    shapes : numpy.ndarray or None
        (R, m, C) identified mode shapes at the channels (signed amplitudes, any unit),
        NaN where not given; used to match measured and modelled modes by MAC
        (:mod:`casflex.identification.matching`).

    Examples
    --------
    >>> m = Measurements(np.zeros((1, 3)), np.array([[1.0, np.nan]]), None, None)
    >>> m.n_modes, m.n_values
    (2, 1)
    """

    q: np.ndarray
    frequency_hz: np.ndarray
    std_hz: np.ndarray | None
    source: str | None = None
    channels: tuple[str, ...] = ()
    shapes: np.ndarray | None = None

    @property
    def n_modes(self) -> int:
        """Number of frequency columns m."""
        return self.frequency_hz.shape[1]

    @property
    def n_values(self) -> int:
        """Number of measured (non-empty) frequencies."""
        return int(np.isfinite(self.frequency_hz).sum())


@dataclass(frozen=True)
class FitParameter:
    """One free parameter of a fit.

    Attributes
    ----------
    path : ParameterPath
        What it is.
    low, high : float
        Bounds, in the parameter's unit.
    initial : float
        Start value (the robot file's value inside the bounds, else the fit file's
        ``initial``, else the middle of the bounds).

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> p = FitParameter(parse_parameter_path("link2.material.E", robot), 30e9, 120e9, 69e9)
    >>> p.name
    'link2.material.E'
    """

    path: ParameterPath
    low: float
    high: float
    initial: float

    @property
    def name(self) -> str:
        """The path as written."""
        return self.path.text


_F = re.compile(r"^f([1-9][0-9]*)$")
_FSTD = re.compile(r"^f([1-9][0-9]*)_std$")
_FSHAPE = re.compile(r"^f([1-9][0-9]*)_([A-Za-z][A-Za-z0-9_]*)$")
_Q = re.compile(r"^q([1-9][0-9]*)$")


def read_measurements(path: str | os.PathLike, n_joints: int) -> Measurements:
    """Read a measurement file (CSV: ``q1..qn``, ``f1..fm``, optional ``f1_std..fm_std``
    and mode-shape columns ``f<j>_<channel>``).

    Parameters
    ----------
    path : str or os.PathLike
        CSV file, one header row, one row per configuration (``#`` lines are comments);
        angles in rad, frequencies in Hz, an empty cell where a mode was not seen.
        ``f<j>_<channel>`` (e.g. ``f2_tip2_y``) is the identified shape of mode j at an
        accelerometer channel (signed amplitude, any unit common to the row and mode; an
        empty cell where not identified); the channels are named as in a sensor file
        (``<sensor>_<axis>``; ``std`` is reserved).
    n_joints : int
        Joints of the robot (the number of ``q`` columns required).

    Returns
    -------
    Measurements

    Raises
    ------
    ProblemFileError
        Naming the file, the row or column, the value and the rule.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "m.csv"
    >>> _ = f.write_text("q1,q2,q3,f1,f2\\n0,0,0.5,1.66,\\n0,0,1.0,1.5,2.3\\n")
    >>> m = read_measurements(f, 3)
    >>> m.frequency_hz.tolist()
    [[1.66, nan], [1.5, 2.3]]
    """
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines()
                 if ln.strip() and not ln.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc
    if len(lines) < 2:
        raise ProblemFileError(path, "<rows>", len(lines) - 1 if lines else 0,
                               "needs a header row and at least one configuration")
    header = [h.strip() for h in lines[0].split(",")]
    qcols = {int(_Q.match(h).group(1)): i for i, h in enumerate(header) if _Q.match(h)}
    fcols = {int(_F.match(h).group(1)): i for i, h in enumerate(header) if _F.match(h)}
    scols = {int(_FSTD.match(h).group(1)): i for i, h in enumerate(header) if _FSTD.match(h)}
    shape_cols = {(int(_FSHAPE.match(h).group(1)), _FSHAPE.match(h).group(2)): i
                  for i, h in enumerate(header) if _FSHAPE.match(h) and not _FSTD.match(h)}
    unknown = [h for h in header if not (_Q.match(h) or _F.match(h) or _FSTD.match(h)
                                         or _FSHAPE.match(h))]
    if unknown or len(set(header)) != len(header):
        raise ProblemFileError(path, "<header>", lines[0],
                               "columns are q1..qn, f1..fm, optional f1_std..fm_std and "
                               "shape columns f<j>_<channel>, each once")
    if sorted(qcols) != list(range(1, n_joints + 1)):
        raise ProblemFileError(path, "<header>", sorted(qcols),
                               f"the robot has {n_joints} joints: give q1..q{n_joints}")
    m = len(fcols)
    if m == 0 or sorted(fcols) != list(range(1, m + 1)):
        raise ProblemFileError(path, "<header>", sorted(fcols), "give f1..fm without gaps")
    if scols and sorted(scols) != list(range(1, m + 1)):
        raise ProblemFileError(path, "<header>", sorted(scols),
                               f"give a standard deviation for every mode: f1_std..f{m}_std")
    bad = sorted(j for j, _ in shape_cols if j not in fcols)
    if bad:
        raise ProblemFileError(path, "<header>", f"f{bad[0]}_...",
                               f"a shape column of mode {bad[0]}, which has no f{bad[0]} column")
    channels = tuple(sorted({c for _, c in shape_cols}))
    shapes = (np.full((len(lines) - 1, m, len(channels)), np.nan) if channels else None)
    q = np.empty((len(lines) - 1, n_joints))
    f = np.full((len(lines) - 1, m), np.nan)
    s = np.full((len(lines) - 1, m), np.nan) if scols else None

    def cell(row, line_no, cells, col, name, empty_ok):
        text = cells[col].strip()
        if not text:
            if empty_ok:
                return math.nan
            raise ProblemFileError(path, f"row {line_no}.{name}", "", "must not be empty")
        try:
            v = float(text)
        except ValueError as exc:
            raise ProblemFileError(path, f"row {line_no}.{name}", text, "must be a number"
                                   ) from exc
        if not math.isfinite(v):
            raise ProblemFileError(path, f"row {line_no}.{name}", text, "must be finite")
        return v

    for r, line in enumerate(lines[1:]):
        line_no = r + 2
        cells = line.split(",")
        if len(cells) != len(header):
            raise ProblemFileError(path, f"row {line_no}", line[:60],
                                   f"has {len(cells)} cells; the header has {len(header)}")
        for j in range(n_joints):
            q[r, j] = cell(r, line_no, cells, qcols[j + 1], f"q{j + 1}", False)
        for j in range(m):
            v = cell(r, line_no, cells, fcols[j + 1], f"f{j + 1}", True)
            if v <= 0.0:
                raise ProblemFileError(path, f"row {line_no}.f{j + 1}", v, "must be > 0 Hz")
            f[r, j] = v
            if s is not None:
                sd = cell(r, line_no, cells, scols[j + 1], f"f{j + 1}_std", not math.isfinite(v))
                if math.isfinite(v) and sd <= 0.0:
                    raise ProblemFileError(path, f"row {line_no}.f{j + 1}_std", sd, "must be > 0")
                s[r, j] = sd
        for (j, c), col in shape_cols.items():
            v = cell(r, line_no, cells, col, f"f{j}_{c}", True)
            if math.isfinite(v) and not math.isfinite(f[r, j - 1]):
                raise ProblemFileError(path, f"row {line_no}.f{j}_{c}", v,
                                       f"a shape of mode {j}, which this row does not measure")
            shapes[r, j - 1, channels.index(c)] = v
        seen = f[r][np.isfinite(f[r])]
        if np.any(np.diff(seen) < 0.0):
            raise ProblemFileError(path, f"row {line_no}", seen.tolist(),
                                   "frequencies must ascend (f1 is the lowest mode)")
    if not np.isfinite(f).any():
        raise ProblemFileError(path, "<rows>", None, "holds no measured frequency")
    return Measurements(q, f, s, str(path), channels, shapes)


def read_fit(path: str | os.PathLike, robot: Robot, raw: dict | None = None
             ) -> list[FitParameter]:
    """Read a fit file: ``[[parameter]]`` tables with ``path``, ``min``, ``max`` and an
    optional ``initial``.

    Parameters
    ----------
    path : str or os.PathLike
        TOML fit file.
    robot : casflex.robot.Robot
        The robot the paths refer to.
    raw : dict, optional
        The robot file as parsed TOML (for section dimensions).

    Returns
    -------
    list of FitParameter

    Raises
    ------
    ProblemFileError
        Naming the file, the field (``parameter[i].min`` ...), the value and the rule.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from casflex.robot import load
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "fit.toml"
    >>> _ = f.write_text('[[parameter]]\\npath = "link2.tip.mass"\\nmin = 0.0\\nmax = 1.0\\n')
    >>> [(p.name, p.initial) for p in read_fit(f, load("problems/arm2link.toml"))]
    [('link2.tip.mass', 0.0)]
    """
    data = read_toml(path)
    top = TableReader(path, data, "")
    top.used.add("parameter")
    top.finish()
    tables = data.get("parameter")
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict)
                                                             for t in tables):
        raise ProblemFileError(path, "parameter", tables,
                               "give at least one [[parameter]] table")
    out, seen = [], set()
    for i, table in enumerate(tables):
        r = TableReader(path, table, f"parameter[{i}]")
        text = r.string("path")
        if text is None:
            raise r.error("path", None, "is required")
        p = parse_parameter_path(text, robot, raw=raw, source=path,
                                 field=f"parameter[{i}].path")
        if text in seen:
            raise r.error("path", text, "names a parameter twice")
        seen.add(text)
        low = r.number("min", required=True)
        high = r.number("max", required=True)
        if p.nonnegative and low < 0.0:
            raise r.error("min", low, "must be >= 0 for this parameter")
        if not p.nonnegative and low <= 0.0:
            raise r.error("min", low, "must be > 0 for this parameter")
        if high <= low:
            raise r.error("max", high, f"must be greater than min = {low}")
        current = parameter_value(robot, p)
        initial = r.number("initial", None)
        if initial is None:
            initial = (current if current is not None and low <= current <= high
                       else 0.5 * (low + high))
        elif not low <= initial <= high:
            raise r.error("initial", initial, f"must lie in [{low}, {high}]")
        r.finish()
        out.append(FitParameter(p, low, high, float(initial)))
    return out


def model_frequencies(robot: Robot, q: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` lowest natural frequencies at every configuration [Hz] (one TMM sweep;
    module level so that it pickles for the process pool).

    Parameters
    ----------
    robot : casflex.robot.Robot
        The robot.
    q : numpy.ndarray
        (R, n_joints) configurations [rad].
    count : int
        Modes per configuration.

    Returns
    -------
    numpy.ndarray
        (R, count) frequencies [Hz].

    Examples
    --------
    >>> from casflex.robot import load
    >>> model_frequencies(load("problems/arm2link.toml"), np.zeros((1, 3)), 2).round(3)
    array([[1.322, 1.905]])
    """
    from casflex.tmm import sweep_frequencies

    return sweep_frequencies(robot, q, count) / (2.0 * np.pi)


@dataclass(frozen=True)
class CalibrationResult:
    """The outcome of :func:`calibrate`.

    Attributes
    ----------
    names : list of str
        Parameter paths.
    initial, values, std : numpy.ndarray
        (p,) start values, fitted values and standard deviations (infinite for a
        parameter that is not identifiable), in the parameters' units.
    correlation : numpy.ndarray
        (p, p) correlation matrix of the estimates.
    identifiable : list of bool
        Per parameter.
    reasons : list of str
        Per parameter: why it is not identifiable ("" when it is).
    measured_hz, before_hz, after_hz : numpy.ndarray
        (R, m) measured and modelled frequencies before and after the fit [Hz].
    singular_values : numpy.ndarray
        Singular values of the column-normalised Jacobian.
    chi2_reduced : float
        Sum of squared weighted residuals over the degrees of freedom (NaN without any).
    tmm_evaluations : int
        TMM natural-frequency solutions (configurations × parameter sets).
    robot : casflex.robot.Robot
        The robot with the fitted values.
    pairing : numpy.ndarray or None
        (R, m) the modelled mode (0-based, in ascending frequency) paired with each
        measured one at the fitted values (-1: not measured).
    mac : numpy.ndarray or None
        (R, m) MAC of each pair at the fitted values (NaN: matched by frequency order).

    Examples
    --------
    >>> r = CalibrationResult(["a"], np.ones(1), np.ones(1), np.zeros(1), np.eye(1),
    ...                       [True], [""], np.ones((1, 1)), np.full((1, 1), 1.1),
    ...                       np.ones((1, 1)), np.ones(1), 0.0, 3, None)
    >>> round(r.rms_before_hz, 3), r.rms_after_hz
    (0.1, 0.0)
    """

    names: list[str]
    initial: np.ndarray
    values: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    identifiable: list[bool]
    reasons: list[str]
    measured_hz: np.ndarray
    before_hz: np.ndarray
    after_hz: np.ndarray
    singular_values: np.ndarray
    chi2_reduced: float
    tmm_evaluations: int
    robot: Robot | None = field(repr=False, default=None)
    pairing: np.ndarray | None = None
    mac: np.ndarray | None = None

    @property
    def residual_before_hz(self) -> np.ndarray:
        """(R, m) model minus measurement before the fit [Hz] (NaN: not measured)."""
        return self.before_hz - self.measured_hz

    @property
    def residual_hz(self) -> np.ndarray:
        """(R, m) model minus measurement after the fit [Hz] (NaN: not measured)."""
        return self.after_hz - self.measured_hz

    @property
    def rms_before_hz(self) -> float:
        """RMS of the residuals before the fit [Hz]."""
        r = self.residual_before_hz
        return float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2)))

    @property
    def rms_after_hz(self) -> float:
        """RMS of the residuals after the fit [Hz]."""
        r = self.residual_hz
        return float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2)))

    def as_dict(self) -> dict:
        """The result as plain values (the JSON of ``casflex calibrate``).

        Returns
        -------
        dict
            ``parameters``, ``initial``, ``std`` (path -> value), ``identifiable`` (path ->
            bool), ``reasons``, ``correlation``, ``rms_before_hz``, ``rms_after_hz``,
            ``residual_hz`` and ``residual_before_hz`` (per row and mode, null where not
            measured), ``chi2_reduced``, ``tmm_evaluations``, ``modelled_mode`` (per row
            and mode, the 1-based modelled partner, null where not measured) and ``mac``
            (its MAC, null where matched by frequency order).

        Examples
        --------
        >>> r = CalibrationResult(["a"], np.ones(1), np.ones(1), np.zeros(1), np.eye(1),
        ...                       [True], [""], np.ones((1, 1)), np.ones((1, 1)),
        ...                       np.ones((1, 1)), np.ones(1), 0.0, 3, None)
        >>> sorted(r.as_dict())[:4]
        ['chi2_reduced', 'correlation', 'identifiable', 'initial']
        """
        return {
            "parameters": dict(zip(self.names, self.values.tolist(), strict=True)),
            "initial": dict(zip(self.names, self.initial.tolist(), strict=True)),
            "std": dict(zip(self.names, self.std.tolist(), strict=True)),
            "identifiable": dict(zip(self.names, self.identifiable, strict=True)),
            "reasons": {n: r for n, r in zip(self.names, self.reasons, strict=True) if r},
            "correlation": self.correlation,
            "rms_before_hz": self.rms_before_hz, "rms_after_hz": self.rms_after_hz,
            "residual_hz": self.residual_hz, "residual_before_hz": self.residual_before_hz,
            "chi2_reduced": self.chi2_reduced, "tmm_evaluations": self.tmm_evaluations,
            "modelled_mode": None if self.pairing is None else [
                [int(k) + 1 if k >= 0 else None for k in row] for row in self.pairing],
            "mac": self.mac,
        }


class _Evaluator:
    """Modelled frequencies at sets of parameter values, in parallel, counted."""

    def __init__(self, robot, params, data, pool, bar):
        self.robot, self.params, self.data = robot, params, data
        self.paths = [p.path for p in params]
        self.pool, self.bar = pool, bar
        self.evaluations = 0
        self.count = data.n_modes  # modelled modes per configuration
        # on a pool, each parameter set's configurations go out in one block per worker,
        # so that even the single-set residual evaluations use every worker
        blocks = 1 if pool is None else min(pool.processes, len(data.q))
        self.blocks = np.array_split(np.arange(len(data.q)), blocks)

    def frequencies(self, value_sets):
        q, m = self.data.q, self.count
        jobs = [((i, b), (with_parameters(self.robot, self.paths, v), q[rows], m))
                for i, v in enumerate(value_sets) for b, rows in enumerate(self.blocks)]
        out = [np.empty((len(q), m)) for _ in value_sets]
        try:
            for (i, b), f in parallel_map(model_frequencies, jobs, processes=1,
                                          pool=self.pool, chunksize=1):
                out[i][self.blocks[b]] = f
        except SolverError as exc:
            at = "; ".join(", ".join(f"{p.text} = {v:.6g}" for p, v in zip(self.paths, vs,
                                                                          strict=True))
                           for vs in value_sets)
            raise SolverError(f"TMM at {at}: {exc}") from exc
        n = len(value_sets) * len(q)
        self.evaluations += n
        self.bar.update(n)
        return out


class _Pairer:
    """The modelled partner of every measured mode (by MAC where shapes were identified,
    by frequency order elsewhere) at given parameter values."""

    def __init__(self, robot, params, data, channels, mac_min):
        self.robot, self.paths, self.data = robot, [p.path for p in params], data
        self.mac_min, self.evaluations = mac_min, 0
        self.rows = []
        if channels is not None and data.shapes is not None and data.channels:
            known = {c.name: c for c in channels}
            missing = [c for c in data.channels if c not in known]
            if missing:
                raise ModelError(f"measurements: shape channel {missing[0]} is not in the "
                                 "sensor file's channels: " + ", ".join(known))
            self.channels = [known[c] for c in data.channels]
            self.rows = [r for r in range(len(data.q))
                         if np.isfinite(data.shapes[r]).any()]
        self.active = bool(self.rows)

    def __call__(self, values):
        m = self.data.n_modes
        pairing = np.tile(np.arange(m), (len(self.data.q), 1))
        mac = np.full(pairing.shape, np.nan)
        if not self.active:
            return pairing, mac
        robot = with_parameters(self.robot, self.paths, values)
        for r in self.rows:
            f, phi = model_channel_shapes(robot, self.data.q[r], self.channels,
                                          m + EXTRA_MODES)
            self.evaluations += f.size
            pair, mac[r] = match_modes(self.data.frequency_hz[r], self.data.shapes[r], f, phi,
                                       mac_min=self.mac_min, where=f"row {r + 1}: ")
            pairing[r] = np.where(pair >= 0, pair, 0)
        return pairing, mac


def calibrate(robot: Robot, data: Measurements, params: list[FitParameter], *,
              processes: int | None = None, progress: bool = False,
              max_iterations: int = 50, channels: list[Channel] | None = None,
              mac_min: float = MAC_MIN) -> CalibrationResult:
    """Fit the parameters of ``robot`` to measured natural frequencies.

    Parameters
    ----------
    robot : casflex.robot.Robot
        The robot file's model.
    data : Measurements
        Measured frequencies [Hz] at configurations [rad].
    params : list of FitParameter
        Free parameters with bounds.
    processes : int, optional
        Local process pool size for the TMM evaluations (``1`` runs in this process).
        Default: ``os.cpu_count()`` when one Jacobian needs at least
        ``POOL_THRESHOLD`` TMM solutions, else in this process (a pool's start-up costs
        more than it saves on fewer, see ``benchmarks/README_calibration.md``).
    progress : bool
        Progress bar on stderr.
    max_iterations : int
        Most Jacobian evaluations of the least-squares solver.
    channels : list of Channel, optional
        Geometry of the channels of ``data.shapes``
        (:func:`casflex.identification.matching.read_channels`). With it, measured modes
        that carry shapes are paired with modelled ones by MAC (at the start values, and
        again at the fitted values, refitting if a pair changed); without it, or where a
        row has no shapes, column ``fj`` is the j-th lowest modelled mode.
    mac_min : float
        Lowest MAC accepted for a pair (a lower one raises ModelError).

    Returns
    -------
    CalibrationResult

    Raises
    ------
    ModelError
        Fewer measured values than parameters, configurations of the wrong size, a shape
        channel missing from ``channels``, or a measured shape that matches no modelled
        mode (MAC below ``mac_min``).

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> E = parse_parameter_path("link2.material.E", robot)
    >>> q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    >>> truth = model_frequencies(with_parameters(robot, [E], [60e9]), q, 2)
    >>> fit = calibrate(robot, Measurements(q, truth, None), [FitParameter(E, 30e9, 90e9, 69e9)],
    ...                 processes=1)
    >>> round(float(fit.values[0]) / 60e9, 6), fit.identifiable
    (1.0, [True])
    """
    from scipy.optimize import least_squares

    q = np.atleast_2d(np.asarray(data.q, dtype=float))
    if q.shape[1] != robot.n_joints:
        raise ModelError(f"measurements: {q.shape[1]} joint columns for robot '{robot.name}' "
                         f"with {robot.n_joints} joints")
    p = len(params)
    if p == 0:
        raise ModelError("params: give at least one parameter to fit")
    if data.n_values < p:
        raise ModelError(f"measurements: {data.n_values} measured frequencies cannot "
                         f"determine {p} parameters")
    seen = np.isfinite(data.frequency_hz)
    f_meas = data.frequency_hz[seen]
    sigma = np.ones_like(f_meas) if data.std_hz is None else data.std_hz[seen]
    scale = np.array([max(abs(x.initial), x.high * 1e-3) for x in params])
    low = np.array([x.low for x in params]) / scale
    high = np.array([x.high for x in params]) / scale
    x0 = np.array([x.initial for x in params]) / scale

    if processes is None and len(q) * (p + 1) < POOL_THRESHOLD:
        processes = 1
    pairer = _Pairer(robot, params, data, channels, mac_min)
    # one pool for the whole fit: a pool per Jacobian cost more than it saved
    with worker_pool(processes) as pool, progress_bar(None, "TMM", progress) as bar:
        ev = _Evaluator(robot, params, data, pool, bar)
        memo = {}

        def evaluate(xs):
            # full (R, count) modelled frequencies, then each measured mode's partner
            todo = [x for x in xs if (x.tobytes(), ev.count) not in memo]
            for x, f in zip(todo, ev.frequencies([x * scale for x in todo]), strict=True):
                memo[x.tobytes(), ev.count] = f
            return [np.take_along_axis(memo[x.tobytes(), ev.count], pairing, axis=1)
                    for x in xs]

        def residual(x):
            return (evaluate([x])[0][seen] - f_meas) / sigma

        def jacobian(x):
            steps = []
            for j in range(p):
                h = STEP * max(abs(x[j]), 1.0)
                if x[j] + h > high[j]:
                    h = -h
                xj = x.copy()
                xj[j] += h
                steps.append((xj, h))
            values = evaluate([x] + [s for s, _ in steps])
            f0 = values[0][seen]
            return np.column_stack([(v[seen] - f0) / h / sigma
                                    for v, (_, h) in zip(values[1:], steps, strict=True)])

        pairing, mac = pairer(x0 * scale)
        ev.count = int(pairing.max()) + 1
        before = evaluate([x0])[0]
        x = x0
        for _ in range(MAX_REMATCH):
            sol = least_squares(residual, x, jac=jacobian, bounds=(low, high), method="trf",
                                x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                                max_nfev=max_iterations)
            x = sol.x
            if not pairer.active:
                break
            # the pairs at the fitted values: refit if a mode changed partner
            new, mac = pairer(x * scale)
            if np.array_equal(new, pairing):
                break
            pairing = new
            ev.count = int(pairing.max()) + 1
        else:
            raise SolverError(f"mode matching did not settle in {MAX_REMATCH} refits: the "
                              "measured modes change partner with the fitted values")
        after = evaluate([x])[0]
        J = jacobian(x)
    values = x * scale
    r = (after[seen] - f_meas) / sigma
    dof = f_meas.size - p
    chi2 = float(r @ r / dof) if dof > 0 else math.nan
    factor = chi2 if data.std_hz is None else max(1.0, chi2)
    norms = np.linalg.norm(J, axis=0)
    identifiable = [True] * p
    reasons = [""] * p
    dead = norms <= 1e-9 * max(norms.max(), np.finfo(float).tiny)
    for j in np.flatnonzero(dead):
        identifiable[j] = False
        reasons[j] = "the measured frequencies do not depend on it"
    live = np.flatnonzero(~dead)
    sv = np.zeros(0)
    if live.size:
        Jn = J[:, live] / norms[live]
        _, sv, vt = np.linalg.svd(Jn, full_matrices=False)
        for k in np.flatnonzero(sv < COLLINEARITY * sv[0]):
            members = live[np.abs(vt[k]) >= DIRECTION_WEIGHT]
            together = ", ".join(params[m].name for m in members)
            for m in members:
                identifiable[m] = False
                reasons[m] = (f"only a combination of {together} is determined (relative "
                              f"singular value {sv[k] / sv[0]:.1e} < {COLLINEARITY:g})"
                              if len(members) > 1 else
                              f"badly conditioned (relative singular value "
                              f"{sv[k] / sv[0]:.1e})")
    cov = np.linalg.pinv(J.T @ J) * (factor if math.isfinite(factor) else math.inf)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(np.diag(cov))
        corr = cov / np.outer(d, d)
    for j in range(p):
        if not identifiable[j]:
            continue
        if math.isfinite(std[j]) and std[j] > MAX_RELATIVE_STD * abs(values[j]):
            identifiable[j] = False
            reasons[j] = (f"the data determine it only to ±{std[j]:.3g} "
                          f"({100 * std[j] / max(abs(values[j]), 1e-300):.0f} %)")
        elif abs(x[j] - low[j]) < 1e-9 * max(1.0, abs(low[j])) or abs(
                x[j] - high[j]) < 1e-9 * max(1.0, abs(high[j])):
            identifiable[j] = False
            bound = "min" if abs(x[j] - low[j]) < abs(x[j] - high[j]) else "max"
            reasons[j] = (f"ended on its bound {bound} = {values[j]:.6g}: the data pull it "
                          "beyond the bounds given")
    for j in range(p):
        if not identifiable[j]:
            std[j] = math.inf
    measured = data.frequency_hz
    return CalibrationResult(
        names=[x.name for x in params], initial=x0 * scale, values=values, std=std,
        correlation=corr, identifiable=identifiable, reasons=reasons, measured_hz=measured,
        before_hz=np.where(seen, before, np.nan), after_hz=np.where(seen, after, np.nan),
        singular_values=sv, chi2_reduced=chi2,
        tmm_evaluations=ev.evaluations + pairer.evaluations,
        robot=with_parameters(robot, [x.path for x in params], values),
        pairing=np.where(seen, pairing, -1), mac=np.where(seen, mac, np.nan))


def measurements_from_logs(paths: list[str | os.PathLike], n_joints: int, *,
                           n_modes: int | None = None, progress: bool = False,
                           tolerance: float = SEGMENT_TOLERANCE,
                           min_duration: float = SEGMENT_MIN_DURATION,
                           ) -> tuple[Measurements, list]:
    """Identify the modes of every log and tabulate them as measurements.

    Every log is cut into its segments of constant joint angles
    (:func:`casflex.identification.logs.split_configurations`: every joint within
    ``tolerance`` of its value at the segment's start for at least ``min_duration``); a
    log of one test is one segment, a log of a test campaign gives one segment per
    configuration. Row ``i`` of the result holds the frequencies identified in segment
    ``i`` (logs in the order given, segments in time order), lowest first, with their
    standard errors, at the median joint angles of the segment, and their shapes at the
    log's channels (:attr:`ModalEstimate.shape`, for matching by MAC). Columns beyond a
    segment's modes are empty.

    Parameters
    ----------
    paths : list of str or os.PathLike
        Log files (CSV or NPZ, see :mod:`casflex.identification.logs`).
    n_joints : int
        Joints of the robot; every log needs the columns ``q1..qn``.
    n_modes : int, optional
        Modes kept per log (the most significant ones).
    progress : bool
        Progress bar on stderr.
    tolerance : float
        Joint-angle band of a segment [rad].
    min_duration : float
        Shortest segment kept [s].

    Returns
    -------
    (Measurements, list of ModalEstimate)
        The measurements and the estimate of every row (its record's ``source`` names the
        log and the time span in ``Measurements.source``).

    Raises
    ------
    ProblemFileError
        A log without joint columns, with the wrong number, or without a segment of
        constant joint angles.

    Examples
    --------
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> t = np.arange(4000) / 400.0
    >>> wn = 2 * np.pi * 3.0
    >>> y = np.exp(-0.01 * wn * t) * np.cos(wn * np.sqrt(1 - 1e-4) * t)
    >>> np.savez(f"{d}/a.npz", t=t, q1=0 * t, acc=y + 1e-4 * np.sin(977 * t))
    >>> data, _ = measurements_from_logs([f"{d}/a.npz"], 1)
    >>> data.frequency_hz.round(4).tolist()
    [[3.0]]
    """
    from casflex.identification.logs import read_log, split_configurations
    from casflex.identification.modal_fit import identify_modes

    rows, estimates, sources = [], [], []
    with progress_bar(len(paths), "identify", progress) as bar:
        for path in paths:
            log = read_log(path)
            if log.q is None or log.q.shape[1] != n_joints:
                got = 0 if log.q is None else log.q.shape[1]
                raise ProblemFileError(path, "q", got, f"the robot has {n_joints} joints: "
                                       f"the log needs the columns q1..q{n_joints}")
            for segment in split_configurations(log, tolerance, min_duration):
                est = identify_modes(segment.t, segment.channels, channels=segment.names,
                                     n_modes=n_modes)
                rows.append((segment.configuration, est.frequency_hz, est.frequency_std_hz))
                estimates.append(est)
                sources.append(segment.source)
            bar.update(1)
    m = max(r[1].size for r in rows)
    q = np.array([r[0] for r in rows])
    f = np.full((len(rows), m), np.nan)
    s = np.full((len(rows), m), np.nan)
    channels = tuple(dict.fromkeys(c for est in estimates for c in est.channels))
    shapes = np.full((len(rows), m, len(channels)), np.nan)
    for i, (_, fi, si) in enumerate(rows):
        f[i, :fi.size], s[i, :si.size] = fi, si
        est = estimates[i]
        if est.shape is not None:
            cols = [channels.index(c) for c in est.channels]
            shapes[i][:fi.size, cols] = est.shape  # a view: modes, then columns
    return Measurements(q, f, s, "; ".join(sources), channels, shapes), estimates
