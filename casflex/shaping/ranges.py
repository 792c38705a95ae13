"""Frequency ranges of input-shaping problems and the shaper problem files.

A :class:`FrequencyRange` is a band of natural frequencies [rad/s] with a damping ratio
and a tolerable residual vibration; a shaper problem file is TOML with ``[[range]]``
tables (``omega_min``, ``omega_max``, ``zeta``, ``vtol``, ``unit = "rad/s" | "Hz"``), read
by :func:`load_shaper_problem` (see ``problems/shapers/README.md``). The SI design
(:mod:`casflex.shaping.si`) takes ranges in any of the forms :func:`as_ranges` accepts.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from casflex._problemfile import read_toml
from casflex._validate import fail, number
from casflex.errors import ProblemFileError
from casflex.shaping.shapers import check_vtol, check_zeta

__all__ = ["FrequencyRange", "ranges_from_mapping", "load_shaper_problem", "as_ranges"]


def _validate_range_values(omega_min, omega_max, zeta, vtol, path=None, prefix=""):
    """The four numbers of a range, checked in the order of the fields' rules."""
    omega_min, omega_max, zeta, vtol = (
        number(value, prefix + name, path=path, error=ProblemFileError)
        for name, value in (("omega_min", omega_min), ("omega_max", omega_max),
                            ("zeta", zeta), ("vtol", vtol))
    )
    number(omega_min, prefix + "omega_min", low=0.0, low_open=True, path=path,
           error=ProblemFileError)
    if omega_min > omega_max:
        raise fail(prefix + "omega_max", omega_max, f"must be >= omega_min ({omega_min})",
                   path=path, error=ProblemFileError)
    check_zeta(zeta, prefix + "zeta", path)
    check_vtol(vtol, prefix + "vtol", path)
    return omega_min, omega_max, zeta, vtol


@dataclass(frozen=True)
class FrequencyRange:
    """A band of natural frequencies whose residual vibration must stay below ``vtol``.

    Parameters
    ----------
    omega_min, omega_max : float
        Band limits, rad/s (``0 < omega_min <= omega_max``; equal for a single frequency).
    zeta : float
        Damping ratio of the mode in the band, 0 <= zeta < 1.
    vtol : float
        Tolerable residual vibration fraction, 0 < vtol <= 1 (1 = unconstrained).

    Raises
    ------
    ProblemFileError
        Naming the offending field.

    Examples
    --------
    >>> r = FrequencyRange(10.0, 12.0, 0.0, 0.05)
    >>> r.omega_mid
    11.0
    """

    omega_min: float
    omega_max: float
    zeta: float = 0.0
    vtol: float = 0.05

    def __post_init__(self):
        values = _validate_range_values(self.omega_min, self.omega_max, self.zeta, self.vtol)
        for name, v in zip(("omega_min", "omega_max", "zeta", "vtol"), values, strict=True):
            object.__setattr__(self, name, v)

    @property
    def omega_mid(self) -> float:
        """Midpoint of the band, rad/s."""
        return 0.5 * (self.omega_min + self.omega_max)


_RANGE_KEYS = {"omega_min", "omega_max", "zeta", "vtol", "unit"}
_RANGE_REQUIRED = ("omega_min", "omega_max", "vtol")
_TOP_KEYS = {"range", "description"}
_UNITS = {"rad/s": 1.0, "hz": 2.0 * math.pi}


def ranges_from_mapping(data: Mapping, path: str | os.PathLike | None = None
                        ) -> list[FrequencyRange]:
    """Build the frequency ranges of a parsed shaper problem (a TOML document as a dict).

    Parameters
    ----------
    data : dict
        ``{"range": [{"omega_min": ..., "omega_max": ..., "vtol": ..., "zeta": ...,
        "unit": "rad/s" | "Hz"}, ...], "description": "..."}``.
    path : str or None, optional
        File name used in error messages.

    Returns
    -------
    list of FrequencyRange
        Frequencies converted to rad/s.

    Raises
    ------
    ProblemFileError
        Unknown or missing key, non-finite value, omega_min > omega_max, vtol outside
        (0, 1], damping outside [0, 1), unknown unit, no ranges.

    Examples
    --------
    >>> r = ranges_from_mapping({"range": [{"omega_min": 1, "omega_max": 2, "vtol": 0.05,
    ...                                      "unit": "Hz"}]})
    >>> round(r[0].omega_max, 4)
    12.5664
    """
    if not isinstance(data, dict):
        raise ProblemFileError(path, "<document>", type(data).__name__, "must be a table")
    for key in data:
        if key not in _TOP_KEYS:
            raise ProblemFileError(
                path, key, data[key], f"unknown key; allowed top-level keys: {sorted(_TOP_KEYS)}"
            )
    if "description" in data and not isinstance(data["description"], str):
        raise ProblemFileError(path, "description", data["description"], "must be a string")
    tables = data.get("range")
    if tables is None:
        raise ProblemFileError(path, "range", None, "missing: at least one [[range]] is needed")
    if not isinstance(tables, list) or not tables:
        raise ProblemFileError(path, "range", tables, "must be a non-empty array of [[range]]")
    out = []
    for i, tab in enumerate(tables):
        prefix = f"range[{i}]."
        if not isinstance(tab, dict):
            raise ProblemFileError(path, f"range[{i}]", tab, "must be a table")
        for key in tab:
            if key not in _RANGE_KEYS:
                raise ProblemFileError(
                    path, prefix + key, tab[key], f"unknown key; allowed: {sorted(_RANGE_KEYS)}"
                )
        for key in _RANGE_REQUIRED:
            if key not in tab:
                raise ProblemFileError(path, prefix + key, None, "missing required key")
        unit = tab.get("unit", "rad/s")
        if not isinstance(unit, str) or unit.strip().lower() not in _UNITS:
            raise ProblemFileError(path, prefix + "unit", unit, "unit must be 'rad/s' or 'Hz'")
        scale = _UNITS[unit.strip().lower()]
        wmin, wmax, zeta, vtol = _validate_range_values(
            tab["omega_min"], tab["omega_max"], tab.get("zeta", 0.0), tab["vtol"], path, prefix
        )
        out.append(FrequencyRange(wmin * scale, wmax * scale, zeta, vtol))
    return out


def load_shaper_problem(path: str | os.PathLike) -> list[FrequencyRange]:
    """Read a shaper problem file (TOML with ``[[range]]`` tables).

    See ``problems/shapers/README.md`` for the keys. Frequencies are given in rad/s or, with
    ``unit = "Hz"``, in Hz, and returned in rad/s.

    Parameters
    ----------
    path : str or pathlib.Path
        The TOML file.

    Returns
    -------
    list of FrequencyRange

    Raises
    ------
    ProblemFileError
        Unreadable file, invalid TOML, or any rule of :func:`ranges_from_mapping`.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "p.toml"
    >>> _ = p.write_text('[[range]]\\nomega_min = 3.0\\nomega_max = 4.0\\nunit = "Hz"\\n'
    ...                  'zeta = 0.0\\nvtol = 0.05\\n')
    >>> r = load_shaper_problem(p)
    >>> len(r), round(r[0].omega_min, 4)
    (1, 18.8496)
    """
    return ranges_from_mapping(_read_problem(path), str(path))


def _read_problem(path):
    """The TOML document of a shaper problem file.

    Invalid TOML is reported on the field ``'<file>'`` with the file name as the value, as
    for an unreadable file (the shaper problems' convention).
    """
    try:
        return read_toml(path)
    except ProblemFileError as exc:
        if exc.field == "<file>":
            raise
        raise ProblemFileError(path, "<file>", str(path), exc.rule) from exc.__cause__


def as_ranges(ranges: FrequencyRange | Iterable) -> list[FrequencyRange]:
    """``ranges`` as a list of :class:`FrequencyRange`: one range, or ranges given as
    ranges, dicts of their fields or tuples of them.

    Parameters
    ----------
    ranges : FrequencyRange or iterable
        The ranges.

    Returns
    -------
    list of FrequencyRange

    Examples
    --------
    >>> [r.omega_max for r in as_ranges([(1.0, 2.0, 0.0, 0.05)])]
    [2.0]
    """
    if isinstance(ranges, FrequencyRange):
        ranges = [ranges]
    out = []
    for i, r in enumerate(ranges):
        if isinstance(r, FrequencyRange):
            out.append(r)
        elif isinstance(r, dict):
            out.append(FrequencyRange(**r))
        else:
            try:
                out.append(FrequencyRange(*r))
            except TypeError as exc:
                raise ProblemFileError(None, f"range[{i}]", r, "not a frequency range") from exc
    if not out:
        raise ProblemFileError(None, "range", [], "at least one frequency range is needed")
    return out
