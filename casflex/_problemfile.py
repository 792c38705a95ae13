"""The one reader of casflex problem files (TOML): robots, moves, sensors, shapers, studies.

:func:`read_toml` and :func:`parse_toml` turn a file or a text into a dict, with a
:class:`~casflex.errors.ProblemFileError` for an unreadable file or invalid TOML;
:class:`TableReader` checks one table of it (known keys, types, finiteness, angle units).
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path

from casflex.errors import ProblemFileError

__all__ = ["ANGLE_UNITS", "TableReader", "parse_toml", "read_toml"]

#: angle units a problem file may name, and their factor to radians
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}


def parse_toml(text: str, path: str | os.PathLike | None = None) -> dict:
    """The TOML ``text`` as a dict; invalid TOML is a :class:`ProblemFileError` naming
    ``path`` (the file the text came from, if any).

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
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(path, "<toml>", None, f"is not valid TOML: {exc}") from exc


def read_toml(path: str | os.PathLike) -> dict:
    """The TOML file at ``path`` as a dict; a missing or unreadable file or invalid TOML
    is a :class:`ProblemFileError` naming the file.

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

    def __init__(self, path, table, prefix):
        self.path = path
        self.table = table
        self.prefix = prefix
        self.used = set()

    def _field(self, key):
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key, value, rule):
        return ProblemFileError(self.path, self._field(key), value, rule)

    def has(self, key):
        return key in self.table

    def number(self, key, default=None, *, required=False, angle=False, positive=False,
               nonnegative=False):
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
            if unit not in ANGLE_UNITS:
                raise self.error(key, raw, f"unknown angle unit {unit!r}; use 'rad' or 'deg'")
            value = raw["value"]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise self.error(key, raw, "must be a number")
            value = float(value) * ANGLE_UNITS[unit]
        elif isinstance(raw, bool) or not isinstance(raw, (int, float)):
            raise self.error(key, raw, "must be a number")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(key, raw, "must be finite (no NaN or inf)")
        if positive and value <= 0.0:
            raise self.error(key, raw, "must be > 0")
        if nonnegative and value < 0.0:
            raise self.error(key, raw, "must be >= 0")
        return value

    def vector(self, key, n, default):
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
            if not math.isfinite(float(v)):
                raise self.error(key, raw, "must be finite (no NaN or inf)")
            out.append(float(v))
        return tuple(out)

    def string(self, key, default=None, choices=None):
        self.used.add(key)
        if key not in self.table:
            return default
        raw = self.table[key]
        if not isinstance(raw, str):
            raise self.error(key, raw, "must be a string")
        if choices is not None and raw not in choices:
            raise self.error(key, raw, f"must be one of {sorted(choices)}")
        return raw

    def table_(self, key):
        self.used.add(key)
        if key not in self.table:
            return None
        raw = self.table[key]
        if not isinstance(raw, dict):
            raise self.error(key, raw, "must be a table")
        return TableReader(self.path, raw, self._field(key))

    def finish(self):
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            key = unknown[0]
            raise self.error(key, self.table[key],
                             f"unknown key; known keys here are {sorted(self.used)}")
