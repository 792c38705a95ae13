"""The one family of argument checks of casflex.

Each check returns the value converted (float, int, array) or raises a
:class:`~casflex.errors.CasflexError` whose message names the field, the value and the
rule it broke:

* a value read from a problem file raises :class:`~casflex.errors.ProblemFileError` with
  the file (pass ``path``);
* a value passed to a function raises :class:`~casflex.errors.ModelError` (the default
  without ``path``), or the ``error`` class the caller names.

Tables of problem files are read with :class:`casflex._problemfile.TableReader`, which
adds known-key checking and units on top of the same rules.

:data:`BOUNDS` is the one table of plausibility bounds of physical quantities (a Young's
modulus, a tip mass, a move duration ...), each with its reason; :func:`plausible` checks
a value against it. The problem-file loaders and the Python constructors both use it, and
``problems/README.md`` lists it.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from casflex.errors import CasflexError, ModelError, ProblemFileError

__all__ = ["fail", "to_float", "number", "choice", "vector", "square_matrix", "identifier",
           "output_file", "output_directory", "Bound", "BOUNDS", "plausible"]


def fail(field: str, value: object, rule: str, *, path: str | os.PathLike | None = None,
         error: type[CasflexError] | None = None) -> CasflexError:
    """The exception for ``field = value`` breaking ``rule`` (to be raised by the caller).

    Parameters
    ----------
    field : str
        Argument name or dotted problem-file field.
    value : object
        The offending value.
    rule : str
        The rule it broke, in words.
    path : str or os.PathLike, optional
        Problem file the value came from.
    error : type, optional
        Exception class (default: ProblemFileError with ``path``, else ModelError).

    Examples
    --------
    >>> str(fail("dt", -1.0, "must be > 0"))
    'dt = -1.0: must be > 0'
    >>> str(fail("move.duration", 0, "must be > 0", path="moves.toml"))
    "moves.toml: field 'move.duration' = 0: must be > 0"
    """
    if error is None:
        error = ProblemFileError if path is not None else ModelError
    if issubclass(error, ProblemFileError):
        return error(path, field, value, rule)
    return error(f"{field} = {value!r}: {rule}")


def to_float(value: int | float) -> float:
    """``float(value)``, with an integer beyond the float range giving ``±inf`` instead of
    raising :class:`OverflowError`, so that the caller's finiteness check rejects it.

    TOML and JSON integers have no size limit; ``float(10**400)`` raises.

    Parameters
    ----------
    value : int or float
        A real number (the caller has checked the type).

    Examples
    --------
    >>> to_float(3), to_float(10**400), to_float(-10**400)
    (3.0, inf, -inf)
    """
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def number(value: object, field: str, *, low: float | None = None, high: float | None = None,
           low_open: bool = False, high_open: bool = False, integer: bool = False,
           path: str | os.PathLike | None = None,
           error: type[CasflexError] | None = None) -> float | int:
    """``value`` as a finite float (or int with ``integer``) within the given bounds.

    Parameters
    ----------
    value : object
        A real number (``bool`` is not one).
    field : str
        Name of the argument or dotted problem-file field.
    low, high : float, optional
        Bounds; inclusive unless ``low_open`` / ``high_open``.
    integer : bool
        Require a whole number and return an ``int``.
    path, error
        See :func:`fail`.

    Examples
    --------
    >>> number(0.5, "vtol", low=0.0, low_open=True, high=1.0)
    0.5
    >>> number(3.0, "count", low=1, integer=True)
    3
    >>> number(float("nan"), "dt")
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: dt = nan: must be finite (no NaN or inf)
    >>> number(0.0, "dt", low=0.0, low_open=True)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: dt = 0.0: must be > 0.0
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)):
        raise fail(field, value, "must be a real number", path=path, error=error)
    v = to_float(value)
    if not math.isfinite(v):
        raise fail(field, value, "must be finite (no NaN or inf)", path=path, error=error)
    if integer and not v.is_integer():
        raise fail(field, value, "must be a whole number", path=path, error=error)
    if low is not None and (v <= low if low_open else v < low):
        raise fail(field, value, f"must be {'>' if low_open else '>='} {low}", path=path,
                   error=error)
    if high is not None and (v >= high if high_open else v > high):
        raise fail(field, value, f"must be {'<' if high_open else '<='} {high}", path=path,
                   error=error)
    return int(v) if integer else v


def choice(value: object, field: str, choices: Collection, *,
           path: str | os.PathLike | None = None,
           error: type[CasflexError] | None = None) -> object:
    """``value`` if it is one of ``choices``.

    Parameters
    ----------
    value : object
        The value to check.
    field : str
        Argument name or dotted problem-file field.
    choices : collection
        Allowed values.
    path, error
        See :func:`fail`.

    Examples
    --------
    >>> choice("rk4", "method", ("rk4", "cvodes"))
    'rk4'
    >>> choice("euler", "method", ("rk4", "cvodes"))
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: method = 'euler': must be one of 'rk4', 'cvodes'
    """
    try:
        ok = value in choices
    except TypeError:  # unhashable value against a set
        ok = False
    if not ok:
        raise fail(field, value, "must be one of " + ", ".join(repr(c) for c in choices),
                   path=path, error=error)
    return value


def vector(value: object, size: int | None, field: str, *, unit: str = "",
           error: type[CasflexError] | None = None) -> np.ndarray:
    """``value`` as a 1-D array of ``size`` finite floats (any size when ``None``).

    Parameters
    ----------
    value : array_like
        The values.
    size : int or None
        Required number of values (any when ``None``).
    field : str
        Argument name.
    unit : str
        Unit named in the error message.
    error : type, optional
        See :func:`fail`.

    Examples
    --------
    >>> vector([0, 0.5], 2, "q").tolist()
    [0.0, 0.5]
    >>> vector([0, 0.5], 3, "q", unit="rad")
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: q = [0, 0.5]: must be 3 finite values [rad]
    """
    try:
        a = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        a = None
    if a is None or (size is not None and a.size != size) or not np.all(np.isfinite(a)):
        what = f"{size} finite values" if size is not None else "finite values"
        raise fail(field, value, f"must be {what}" + (f" [{unit}]" if unit else ""),
                   error=error)
    return a


def square_matrix(value: object, size: int, field: str, *, psd: bool = False,
                  error: type[CasflexError] | None = None) -> np.ndarray:
    """``value`` as a finite ``size`` × ``size`` matrix: a scalar means that multiple of the
    identity, a vector the diagonal. With ``psd`` the matrix must be symmetric positive
    semi-definite (weights, covariances).

    Parameters
    ----------
    value : float or array_like
        Scalar, diagonal or full matrix.
    size : int
        Rows and columns.
    field : str
        Argument name.
    psd : bool
        Require a symmetric positive semi-definite matrix.
    error : type, optional
        See :func:`fail`.

    Examples
    --------
    >>> square_matrix(2.0, 2, "Q").tolist()
    [[2.0, 0.0], [0.0, 2.0]]
    >>> square_matrix([1.0, -1.0], 2, "R", psd=True)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: R = [1.0, -1.0]: must be symmetric positive semi-definite
    """
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        a = np.full((0,), np.nan)
    if a.ndim == 0:
        a = a * np.eye(size)
    elif a.ndim == 1 and a.size == size:
        a = np.diag(a)
    if a.shape != (size, size) or not np.all(np.isfinite(a)):
        raise fail(field, value, f"must be a finite scalar, {size}-vector (diagonal) or "
                                 f"{size} x {size} matrix", error=error)
    if psd and (not np.allclose(a, a.T) or np.min(np.linalg.eigvalsh(0.5 * (a + a.T))) < 0):
        raise fail(field, value, "must be symmetric positive semi-definite", error=error)
    return a


_C_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*", re.ASCII)


def identifier(value: object, field: str, *, path: str | os.PathLike | None = None,
               error: type[CasflexError] | None = None) -> str:
    """``value`` if it is a C identifier (the whole string matches ``[A-Za-z_][A-Za-z0-9_]*``,
    ASCII only: no trailing newline, no ``é``): a name that becomes a C symbol or file
    stem of generated code.

    Parameters
    ----------
    value : object
        The name to check.
    field : str
        Argument name or dotted problem-file field.
    path, error
        See :func:`fail`.

    Examples
    --------
    >>> identifier("arm_ekf", "bundle name")
    'arm_ekf'
    >>> identifier("my-bundle", "bundle name")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: bundle name = 'my-bundle': not a valid C identifier (...)
    >>> identifier("arm\\n", "bundle name")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: bundle name = 'arm\\n': not a valid C identifier (...)
    """
    if not isinstance(value, str) or not _C_IDENTIFIER.fullmatch(value):
        raise fail(field, value, "not a valid C identifier ([A-Za-z_][A-Za-z0-9_]*)",
                   path=path, error=error)
    return value


def _writable(directory: Path) -> bool:
    return os.access(directory, os.W_OK | os.X_OK)


def output_file(value: str | os.PathLike, field: str, *,
                error: type[CasflexError] | None = None) -> Path:
    """``value`` as the path of a file to be written: its directory must exist and be
    writable, and the path must not be a directory. Check it before the work whose result
    it is to receive.

    Parameters
    ----------
    value : str or os.PathLike
        The file to be written (an existing file is overwritten).
    field : str
        Argument or option name, e.g. ``"--plot"``.
    error : type, optional
        See :func:`fail`.

    Examples
    --------
    >>> import tempfile
    >>> tmp = Path(tempfile.mkdtemp())
    >>> output_file(tmp / "plot.png", "--plot") == tmp / "plot.png"
    True
    >>> output_file(tmp / "missing" / "plot.png", "--plot")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --plot = '.../plot.png': the directory ... does not exist; ...
    """
    path = Path(value)
    parent = path.parent
    if path.is_dir():
        raise fail(field, str(value), "is a directory; give a file name", error=error)
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise fail(field, str(value), f"the directory {str(parent)!r} {what}; create it "
                                      "first", error=error)
    if not _writable(parent):
        raise fail(field, str(value), f"the directory {str(parent)!r} is not writable",
                   error=error)
    return path


def output_directory(value: str | os.PathLike, field: str, *,
                     error: type[CasflexError] | None = None) -> Path:
    """``value`` as a directory to be created (with its parents) or written into: it must
    not be an existing file, and the nearest existing directory above it must be
    writable. Check it before the work whose results it is to receive.

    Parameters
    ----------
    value : str or os.PathLike
        The output directory.
    field : str
        Argument or option name, e.g. ``"--out"``.
    error : type, optional
        See :func:`fail`.

    Examples
    --------
    >>> import tempfile
    >>> tmp = Path(tempfile.mkdtemp())
    >>> output_directory(tmp / "new" / "out", "--out") == tmp / "new" / "out"
    True
    >>> _ = (tmp / "notes.txt").write_text("")
    >>> output_directory(tmp / "notes.txt", "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --out = '.../notes.txt': is an existing file, not a directory
    """
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise fail(field, str(value), "is an existing file, not a directory", error=error)
    existing = path
    while not existing.exists():  # the nearest existing ancestor is where mkdir starts
        if existing.parent == existing:
            break
        existing = existing.parent
    if existing != path and existing.exists() and not existing.is_dir():
        raise fail(field, str(value), f"{str(existing)!r} is an existing file, not a "
                                      "directory", error=error)
    if existing.is_dir() and not _writable(existing):
        raise fail(field, str(value), f"the directory {str(existing)!r} is not writable",
                   error=error)
    return path


# ------------------------------------------------------------------ plausibility bounds


@dataclass(frozen=True)
class Bound:
    """The plausible range ``low <= value <= high`` of one physical quantity, and why.

    Attributes
    ----------
    low, high : float
        Inclusive bounds, in ``unit``.
    unit : str
        SI unit of the quantity (``"-"`` for a pure number).
    reason : str
        Why a value outside is not physical (or not computable), in words.

    Examples
    --------
    >>> BOUNDS["E"].rule
    'must lie in [100000, 1.5e+12] Pa: from soft elastomers (~0.1 MPa) to diamond (~1.2 TPa)'
    """

    low: float
    high: float
    unit: str
    reason: str

    @property
    def rule(self) -> str:
        """The rule as an error message states it."""
        return f"must lie in [{self.low:g}, {self.high:g}] {self.unit}: {self.reason}"


#: Plausibility bounds of every physical quantity casflex reads, keyed by quantity name.
#: Values outside are rejected at load (ProblemFileError) and by the constructors
#: (ModelError): they are not physical, and computing with them gives overflow, underflow
#: or a silently meaningless number. Documented in ``problems/README.md``.
BOUNDS: dict[str, Bound] = {
    "E": Bound(1e5, 1.5e12, "Pa", "from soft elastomers (~0.1 MPa) to diamond (~1.2 TPa)"),
    "G": Bound(3e4, 7e11, "Pa", "shear moduli of the same materials, G = E / (2 (1 + nu)) "
                                "with -0.5 < nu <= 0.5"),
    "rho": Bound(1.0, 2.5e4, "kg/m^3", "from aerogels and foams to osmium (22 590 kg/m^3)"),
    "section_dimension": Bound(1e-5, 10.0, "m", "a side, diameter or wall of a beam "
                                                "section, from a 10 um foil to 10 m"),
    "section_area": Bound(1e-10, 100.0, "m^2", "the area of sections of 10 um to 10 m"),
    "section_moment": Bound(1e-22, 1e3, "m^4", "second moments and torsion constants of "
                                               "sections of 10 um to 10 m"),
    "offset": Bound(-100.0, 100.0, "m", "DH offsets, centre-of-mass offsets: no robot "
                                        "reaches farther than 100 m"),
    "beam_length": Bound(1e-3, 100.0, "m", "a flexible link from 1 mm to 100 m"),
    "angle": Bound(-100.0, 100.0, "rad", "constant DH angles and joint positions within 16 "
                                         "turns; beyond, no cable or encoder follows and "
                                         "cos/sin lose digits"),
    "tip_mass": Bound(0.0, 1e4, "kg", "payloads up to 10 t (the heaviest industrial robots "
                                      "carry 2.3 t)"),
    "tip_inertia": Bound(0.0, 1e4, "kg m^2", "moments of inertia of bodies up to 10 t and a "
                                             "few metres"),
    "motor_inertia": Bound(0.0, 1e3, "kg m^2", "rotor inertias reflected through gears of "
                                               "industrial drives"),
    "joint_stiffness": Bound(1e-3, 1e10, "N m/rad", "from micro-robot flexures to the stiffest "
                                                    "gearboxes; a stiffer joint is rigid: "
                                                    "leave joint_stiffness out"),
    "gravity": Bound(-1e3, 1e3, "m/s^2", "a component of gravity (or of a base "
                                         "acceleration) up to 100 g"),
    "move_duration": Bound(1e-3, 1e5, "s", "a move from 1 ms (beyond any drive's "
                                           "bandwidth below) to about a day"),
    "settle": Bound(0.0, 1e5, "s", "time simulated after a move, at most about a day"),
    "joint_velocity": Bound(-1e4, 1e4, "rad/s", "peak joint speed of a planned move, up to "
                                                "about 100 000 rpm"),
    "joint_acceleration": Bound(-1e6, 1e6, "rad/s^2", "peak joint acceleration of a planned "
                                                      "move"),
    "noise_acceleration": Bound(1e-9, 1e4, "m/s^2", "accelerometer noise from 1e-10 g "
                                                    "(seismic sensors) to 1000 g"),
    "noise_strain": Bound(1e-13, 0.1, "-", "strain-gauge noise, from below any gauge's "
                                           "resolution to a strain that breaks the gauge"),
    "natural_frequency": Bound(1e-3, 1e8, "rad/s", "flexible modes of a robot, from a "
                                                   "period of 100 min to ultrasound; outside, "
                                                   "the modal analysis broke down"),
    "vtol": Bound(1e-6, 1.0, "-", "tolerable residual vibration: below 1e-6 is under any "
                                  "model's accuracy (and 1e-300 broke the shaper), 1 is "
                                  "unconstrained"),
}


def plausible(value: object, quantity: str, field: str, *, high: float | None = None,
              reason: str | None = None, path: str | os.PathLike | None = None,
              error: type[CasflexError] | None = None) -> float:
    """``value`` as a finite float within the plausibility bounds of ``quantity``.

    Parameters
    ----------
    value : object
        A real number in the SI unit of ``quantity``.
    quantity : str
        Key of :data:`BOUNDS`.
    field : str
        Argument name or dotted problem-file field.
    high : float, optional
        A tighter upper bound that depends on other values (a gauge no farther from the
        neutral axis than the section's face, a point on the link); ``reason`` says why.
    reason : str, optional
        Reason of ``high``.
    path, error
        See :func:`fail`.

    Examples
    --------
    >>> plausible(69e9, "E", "material.E")
    69000000000.0
    >>> plausible(1e300, "E", "link[2].material.E", path="arm.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: arm.toml: field 'link[2].material.E' = 1e+300: must ...
    >>> plausible(0.01, "section_dimension", "distance", high=0.0035,
    ...           reason="the gauge sits on the section's face")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: distance = 0.01: must be <= 0.0035 m: the gauge sits on ...
    """
    bound = BOUNDS[quantity]
    v = number(value, field, path=path, error=error)
    if not bound.low <= v <= bound.high:
        raise fail(field, value, bound.rule, path=path, error=error)
    if high is not None and v > high:
        raise fail(field, value, f"must be <= {high!r} {bound.unit}: {reason}", path=path,
                   error=error)
    return v
