"""The one reader of casflex problem files (TOML): robots, moves, sensors, shapers, studies;
and of the NumPy archives users give (saved plans, measurement logs).

:func:`read_toml` and :func:`parse_toml` turn a file or a text into a dict, with a
:class:`~casflex.errors.ProblemFileError` for an unreadable file or invalid TOML;
:class:`TableReader` checks one table of it (known keys, types, finiteness, angle units);
:func:`read_npz` reads a ``.npz`` archive's arrays, with the same error for a file that is
not one.
"""

from __future__ import annotations

import math
import os
import tomllib
import zipfile
from collections.abc import Collection, Sequence
from pathlib import Path

import numpy as np

from casflex._validate import BOUNDS, to_float
from casflex.errors import ProblemFileError

__all__ = ["ANGLE_UNITS", "TableReader", "parse_toml", "read_npz", "read_toml"]

#: angle units a problem file may name, and their factor to radians
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}


def parse_toml(text: str, path: str | os.PathLike | None = None) -> dict:
    """The TOML ``text`` as a dict; invalid TOML is a :class:`ProblemFileError` naming
    ``path`` (the file the text came from, if any).

    Parameters
    ----------
    text : str
        TOML text.
    path : str or os.PathLike, optional
        File the text came from, named in errors.

    Examples
    --------
    >>> parse_toml("a = 1")
    {'a': 1}
    >>> parse_toml("a = ", "x.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: x.toml: field '<toml>' = None: is not valid TOML: ...
    """
    try:
        return tomllib.loads(text)
    except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise ProblemFileError(path, "<toml>", None, f"is not valid TOML: {exc}") from exc


def read_toml(path: str | os.PathLike) -> dict:
    """The TOML file at ``path`` as a dict; a missing or unreadable file or invalid TOML
    is a :class:`ProblemFileError` naming the file.

    Parameters
    ----------
    path : str or os.PathLike
        TOML file.

    Examples
    --------
    >>> read_toml("no/such/file.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: no/such/file.toml: field '<file>' = ...: cannot be read: ...
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc
    return parse_toml(text, path)


def read_npz(path: str | os.PathLike, what: str) -> dict:
    """The arrays of the NumPy archive at ``path`` (``numpy.savez``), never unpickling;
    a missing file, another kind of file, a damaged archive or an array of Python objects
    is a :class:`ProblemFileError` naming the file.

    (numpy itself takes any file that is not an archive for a pickle and suggests
    ``allow_pickle=True``, and a damaged archive raises ``zipfile.BadZipFile``.)

    Parameters
    ----------
    path : str or os.PathLike
        ``.npz`` file.
    what : str
        What the archive should be, for the error (e.g. "a plan is the plan.npz that
        PlannedMove.save writes").

    Returns
    -------
    dict of str to numpy.ndarray

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     path = Path(d) / "a.npz"
    ...     np.savez(path, x=[1.0, 2.0])
    ...     read_npz(path, "test")["x"].tolist()
    [1.0, 2.0]
    >>> read_npz("README.md", "a log")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: README.md: field '<file>' = ...: is not a NumPy .npz ...
    """
    path = Path(path)
    if path.is_file() and not zipfile.is_zipfile(path):
        raise ProblemFileError(path, "<file>", str(path),
                               f"is not a NumPy .npz archive ({what})")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc


class TableReader:
    """Reads one table of a problem file: known keys, types, finiteness, units.

    Every getter marks its key as known; :meth:`finish` rejects the keys no getter asked
    for. Every error is a :class:`~casflex.errors.ProblemFileError` naming the file, the
    dotted field (``prefix.key``), the value and the rule.

    Parameters
    ----------
    path : str or pathlib.Path or None
        File the table comes from (``None`` for in-memory descriptions).
    table : dict
        The parsed TOML table.
    prefix : str
        Dotted name of the table in the file, e.g. ``"link[2]"``.

    Examples
    --------
    >>> r = TableReader("arm.toml", {"E": 7e10, "theta": {"value": 90, "unit": "deg"}}, "m")
    >>> r.number("E", positive=True), round(r.number("theta", angle=True), 6)
    (70000000000.0, 1.570796)
    >>> r.finish()
    >>> TableReader("arm.toml", {"E": -1.0}, "m").number("E", positive=True)
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: arm.toml: field 'm.E' = -1.0: must be > 0
    """

    def __init__(self, path: str | os.PathLike | None, table: dict, prefix: str) -> None:
        self.path = path
        self.table = table
        self.prefix = prefix
        self.used = set()

    def _field(self, key):
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str, value: object, rule: str) -> ProblemFileError:
        """The :class:`ProblemFileError` for ``key = value`` breaking ``rule``.

        Parameters
        ----------
        key : str
            Key in this table.
        value : object
            The offending value.
        rule : str
            The rule it broke.

        Examples
        --------
        >>> str(TableReader("a.toml", {}, "link[0]").error("E", -1, "must be > 0"))
        "a.toml: field 'link[0].E' = -1: must be > 0"
        """
        return ProblemFileError(self.path, self._field(key), value, rule)

    def has(self, key: str) -> bool:
        """Whether the table gives ``key`` (does not mark it as known).

        Parameters
        ----------
        key : str
            Key in this table.

        Examples
        --------
        >>> TableReader(None, {"a": 1}, "").has("a")
        True
        """
        return key in self.table

    def number(self, key: str, default: float | None = None, *, required: bool = False,
               angle: bool = False, positive: bool = False, nonnegative: bool = False,
               quantity: str | None = None) -> float | None:
        """The number under ``key`` as a finite float, or ``default`` when absent.

        Parameters
        ----------
        key : str
            Key in this table.
        default : float, optional
            Value when the key is absent.
        required : bool
            Absence is an error.
        angle : bool
            Also accept ``{value = ..., unit = "deg"|"rad"}``; the result is in rad.
        positive, nonnegative : bool
            Require ``> 0`` / ``>= 0``.
        quantity : str, optional
            Require the plausibility bounds of this quantity
            (:data:`casflex._validate.BOUNDS`; the value in SI units, angles in rad).

        Examples
        --------
        >>> r = TableReader(None, {"q": {"value": 180, "unit": "deg"}}, "")
        >>> round(r.number("q", angle=True), 6), r.number("d", 0.5)
        (3.141593, 0.5)
        >>> TableReader("a.toml", {"E": 1e300}, "m").number("E", quantity="E")
        ...                                            # doctest: +ELLIPSIS
        Traceback (most recent call last):
            ...
        casflex.errors.ProblemFileError: a.toml: field 'm.E' = 1e+300: must lie in [...] Pa: ...
        """
        self.used.add(key)
        if key not in self.table:
            if required:
                raise self.error(key, None, "is required but missing")
            return default
        raw = self.table[key]
        value = raw
        if angle and isinstance(raw, dict):
            unknown = set(raw) - {"value", "unit"}
            if unknown or "value" not in raw:
                raise self.error(key, raw, "an angle is a number [rad] or {value = ..., "
                                           "unit = \"deg\"|\"rad\"}")
            unit = raw.get("unit", "rad")
            if not isinstance(unit, str) or unit not in ANGLE_UNITS:
                raise self.error(key, raw, f"unknown angle unit {unit!r}; use 'rad' or 'deg'")
            value = raw["value"]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise self.error(key, raw, "must be a number")
            value = to_float(value) * ANGLE_UNITS[unit]
        elif isinstance(raw, bool) or not isinstance(raw, (int, float)):
            raise self.error(key, raw, "must be a number")
        value = to_float(value)
        if not math.isfinite(value):
            raise self.error(key, raw, "must be finite (no NaN or inf)")
        if positive and value <= 0.0:
            raise self.error(key, raw, "must be > 0")
        if nonnegative and value < 0.0:
            raise self.error(key, raw, "must be >= 0")
        if quantity is not None:
            self.check_bound(key, raw, value, quantity)
        return value

    def check_bound(self, key: str, raw: object, value: float, quantity: str) -> None:
        """Raise the :class:`ProblemFileError` of ``key`` unless ``value`` lies within the
        plausibility bounds of ``quantity`` (:data:`casflex._validate.BOUNDS`).

        Parameters
        ----------
        key : str
            Key in this table.
        raw : object
            The value as the file gives it (named in the error).
        value : float
            The value in SI units (angles in rad).
        quantity : str
            Key of :data:`casflex._validate.BOUNDS`.

        Examples
        --------
        >>> TableReader("a.toml", {}, "tip").check_bound("mass", 2.0, 2.0, "tip_mass")
        """
        bound = BOUNDS[quantity]
        if not bound.low <= value <= bound.high:
            raise self.error(key, raw, bound.rule)

    def vector(self, key: str, n: int, default: Sequence[float],
               quantity: str | None = None) -> tuple[float, ...]:
        """The list of ``n`` finite numbers under ``key`` as a tuple, or ``default``.

        Parameters
        ----------
        key : str
            Key in this table.
        n : int
            Required length.
        default : sequence of float
            Value when the key is absent.
        quantity : str, optional
            Require every value within the plausibility bounds of this quantity
            (:data:`casflex._validate.BOUNDS`).

        Examples
        --------
        >>> TableReader(None, {"g": [0, 0, -9.81]}, "").vector("g", 3, (0, 0, 0))
        (0.0, 0.0, -9.81)
        """
        self.used.add(key)
        if key not in self.table:
            return tuple(default)
        raw = self.table[key]
        if not isinstance(raw, list) or len(raw) != n:
            raise self.error(key, raw, f"must be a list of {n} numbers")
        out = []
        for v in raw:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise self.error(key, raw, f"must be a list of {n} numbers")
            if not math.isfinite(to_float(v)):
                raise self.error(key, raw, "must be finite (no NaN or inf)")
            out.append(float(v))
            if quantity is not None:
                self.check_bound(key, raw, out[-1], quantity)
        return tuple(out)

    def string(self, key: str, default: str | None = None,
               choices: Collection[str] | None = None) -> str | None:
        """The string under ``key`` (one of ``choices`` if given), or ``default``.

        Parameters
        ----------
        key : str
            Key in this table.
        default : str, optional
            Value when the key is absent.
        choices : collection of str, optional
            Allowed values.

        Examples
        --------
        >>> TableReader(None, {"joint": "revolute"}, "").string("joint", choices={"revolute"})
        'revolute'
        """
        self.used.add(key)
        if key not in self.table:
            return default
        raw = self.table[key]
        if not isinstance(raw, str):
            raise self.error(key, raw, "must be a string")
        if choices is not None and raw not in choices:
            raise self.error(key, raw, f"must be one of {sorted(choices)}")
        return raw

    def table_(self, key: str) -> TableReader | None:
        """A reader of the sub-table under ``key``, or ``None`` when absent.

        Parameters
        ----------
        key : str
            Key in this table.

        Examples
        --------
        >>> sub = TableReader("a.toml", {"tip": {"mass": 1.0}}, "link[1]").table_("tip")
        >>> sub.prefix, sub.number("mass")
        ('link[1].tip', 1.0)
        """
        self.used.add(key)
        if key not in self.table:
            return None
        raw = self.table[key]
        if not isinstance(raw, dict):
            raise self.error(key, raw, "must be a table")
        return TableReader(self.path, raw, self._field(key))

    def finish(self) -> None:
        """Reject the keys of the table that no getter asked for.

        Examples
        --------
        >>> r = TableReader("a.toml", {"mass": 1.0, "colour": "red"}, "tip")
        >>> r.number("mass")
        1.0
        >>> try:
        ...     r.finish()
        ... except ProblemFileError as exc:
        ...     print(exc.field, "-", exc.rule)
        tip.colour - unknown key; known keys here are ['mass']
        """
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            key = unknown[0]
            raise self.error(key, self.table[key],
                             f"unknown key; known keys here are {sorted(self.used)}")
