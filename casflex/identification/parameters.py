"""Robot parameters named by a path, read and changed without touching the robot file.

A path is ``<link name>.<key>`` or ``<link name>.<table>.<key>`` with the link named as
in its ``[[link]]`` table (``name``, default ``row<i>``):

============================================  ===========  ================
path                                          unit         rule
============================================  ===========  ================
``<link>.joint_stiffness``                    N m/rad      > 0
``<link>.motor_inertia``                      kg m²        >= 0
``<link>.material.E`` / ``.G`` / ``.rho``     Pa, kg/m³    > 0
``<link>.tip.mass``                           kg           >= 0
``<link>.section.a`` / ``.b`` (rectangle)     m            > 0
``<link>.section.outer_diameter`` / ``.wall`` m            > 0 (tube)
``<link>.section.A`` / ``Ix`` / ``Iy`` / ``J`` / ``Ip``  m², m⁴  > 0 (explicit)
============================================  ===========  ================

A key the robot file leaves at its default (a tip mass on a link without ``[link.tip]``,
a joint stiffness on a rigid joint) may be named; its current value is the default
(0, or ``None`` for a rigid joint).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

from casflex.errors import ProblemFileError
from casflex.robot import Robot, Section

__all__ = ["ParameterPath", "parse_parameter_path", "parameter_value", "with_parameters"]

_SECTION_KEYS = {"rectangle": ("a", "b"), "tube": ("outer_diameter", "wall"),
                 "explicit": ("A", "Ix", "Iy", "J", "Ip")}
_TOP_KEYS = {"joint_stiffness": 0.0, "motor_inertia": 0.0}  # value: lowest allowed
_NONNEGATIVE = {"motor_inertia", "tip.mass"}


@dataclass(frozen=True)
class ParameterPath:
    """A parsed parameter path.

    Attributes
    ----------
    text : str
        The path as written.
    row : int
        0-based DH row of the link.
    table : str or None
        ``"material"``, ``"section"``, ``"tip"`` or ``None`` for a key of the link table.
    key : str
        Key in that table.
    section_shape : str or None
        Shape of the link's section (for section keys).
    section_dims : dict
        The section table's numbers as written in the robot file (for section keys).

    Examples
    --------
    >>> from casflex.robot import load
    >>> p = parse_parameter_path("link2.material.E", load("problems/arm2link.toml"))
    >>> p.row, p.table, p.key, p.nonnegative
    (3, 'material', 'E', False)
    """

    text: str
    row: int
    table: str | None
    key: str
    section_shape: str | None = None
    section_dims: tuple = ()

    @property
    def nonnegative(self) -> bool:
        """True when 0 is an allowed value (a mass or inertia), else the value must be > 0."""
        return (self.key if self.table is None else f"{self.table}.{self.key}") in _NONNEGATIVE


def _section_dims(robot, row, raw):
    """(shape, dims) of a link's section: from the raw TOML table when given (the numbers
    as written), else recovered from the Section's properties."""
    sec = robot.links[row].section
    if raw is not None:
        links = raw.get("link", [])
        table = links[row].get("section", {}) if row < len(links) else {}
        shape = table.get("shape", "explicit")
        dims = {k: float(table[k]) for k in _SECTION_KEYS.get(shape, ()) if k in table}
        if shape == "explicit" and "Ip" not in dims:
            dims["Ip"] = None  # Ix + Iy
        return shape, tuple(dims.items())
    if sec.kind == "rectangle":  # A = a b, Ix = b a³ / 12
        a = math.sqrt(12.0 * sec.Ix / sec.A)
        return "rectangle", (("a", a), ("b", sec.A / a))
    if sec.kind == "tube":  # A = π (ro² − ri²), Ix = A (ro² + ri²) / 4
        s2, d2 = 4.0 * sec.Ix / sec.A, sec.A / math.pi
        ro, ri = math.sqrt((s2 + d2) / 2.0), math.sqrt(max((s2 - d2) / 2.0, 0.0))
        return "tube", (("outer_diameter", 2.0 * ro), ("wall", ro - ri))
    return "explicit", tuple((k, getattr(sec, k)) for k in _SECTION_KEYS["explicit"])


def parse_parameter_path(text: str, robot: Robot, *, raw: dict | None = None,
                         source: str | os.PathLike | None = None,
                         field: str = "path") -> ParameterPath:
    """Parse ``text`` as a parameter of ``robot`` (table in the module docstring).

    Parameters
    ----------
    text : str
        ``<link name>.<key>`` or ``<link name>.<table>.<key>``.
    robot : casflex.robot.Robot
        The robot the path refers to.
    raw : dict, optional
        The robot file as parsed TOML: rectangle and tube dimensions are then taken as
        written (else recovered from the section's area and second moment).
    source : str or os.PathLike, optional
        File the path was read from (named in errors).
    field : str
        Field named in errors.

    Returns
    -------
    ParameterPath

    Raises
    ------
    ProblemFileError
        Unknown link, table or key.

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/testbed.toml")
    >>> parse_parameter_path("link2.tip.mass", robot).row
    3
    >>> parse_parameter_path("link9.tip.mass", robot)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ProblemFileError: ...: field 'path' = 'link9.tip.mass': names no link ...
    """
    if not isinstance(text, str):
        raise ProblemFileError(source, field, text, "must be a string")
    parts = text.split(".")
    names = [link.name for link in robot.links]
    if len(parts) not in (2, 3) or parts[0] not in names:
        raise ProblemFileError(source, field, text,
                               f"names no link of robot '{robot.name}': write "
                               f"<link>.<key> or <link>.<table>.<key> with <link> one of "
                               f"{names}")
    if names.count(parts[0]) > 1:
        raise ProblemFileError(source, field, text,
                               f"link name '{parts[0]}' is not unique in the robot file")
    row = names.index(parts[0])
    link = robot.links[row]
    if len(parts) == 2:
        key = parts[1]
        if key not in _TOP_KEYS:
            raise ProblemFileError(source, field, text,
                                   f"<link>.<key> takes one of {sorted(_TOP_KEYS)}")
        if link.joint != "revolute":
            raise ProblemFileError(source, field, text,
                                   f"{key} needs a revolute joint; row '{link.name}' is fixed")
        return ParameterPath(text, row, None, key)
    table, key = parts[1], parts[2]
    if table == "material":
        if key not in ("E", "G", "rho"):
            raise ProblemFileError(source, field, text, "material keys are E, G and rho")
        if not link.flexible:
            raise ProblemFileError(source, field, text, f"link '{link.name}' is rigid")
        return ParameterPath(text, row, table, key)
    if table == "tip":
        if key != "mass":
            raise ProblemFileError(source, field, text, "the tip key that can be fitted is mass")
        return ParameterPath(text, row, table, key)
    if table == "section":
        if not link.flexible:
            raise ProblemFileError(source, field, text, f"link '{link.name}' is rigid")
        shape, dims = _section_dims(robot, row, raw)
        if key not in _SECTION_KEYS[shape]:
            raise ProblemFileError(source, field, text,
                                   f"a {shape} section has the keys {list(_SECTION_KEYS[shape])}")
        return ParameterPath(text, row, table, key, shape, dims)
    raise ProblemFileError(source, field, text, "tables are material, section and tip")


def parameter_value(robot: Robot, path: ParameterPath) -> float | None:
    """The current value of a parameter (``None`` for the stiffness of a rigid joint).

    Parameters
    ----------
    robot : casflex.robot.Robot
        The robot.
    path : ParameterPath
        From :func:`parse_parameter_path`.

    Returns
    -------
    float or None
        In the unit of the path's key (see the module docstring).

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/testbed.toml")
    >>> parameter_value(robot, parse_parameter_path("link1.joint_stiffness", robot))
    90.0
    """
    link = robot.links[path.row]
    if path.table is None:
        return getattr(link, path.key)
    if path.table == "material":
        return getattr(link.material, path.key)
    if path.table == "tip":
        return link.tip.mass
    if path.section_shape == "explicit" and path.key in ("A", "Ix", "Iy", "J", "Ip"):
        return getattr(link.section, path.key)
    return dict(path.section_dims)[path.key]


def with_parameters(robot: Robot, paths: list[ParameterPath], values: list[float]) -> Robot:
    """A copy of ``robot`` with the parameters set to ``values``.

    Parameters
    ----------
    robot : casflex.robot.Robot
        The robot.
    paths : list of ParameterPath
        Parameters to set.
    values : list of float
        Their new values, in the units of the module docstring.

    Returns
    -------
    casflex.robot.Robot

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> p = parse_parameter_path("link2.tip.mass", robot)
    >>> with_parameters(robot, [p], [0.2]).links[3].tip.mass
    0.2
    """
    links = list(robot.links)
    sections = {}
    for path, value in zip(paths, values, strict=True):
        value = float(value)
        link = links[path.row]
        if path.table is None:
            links[path.row] = replace(link, **{path.key: value})
        elif path.table == "material":
            links[path.row] = replace(link, material=replace(link.material, **{path.key: value}))
        elif path.table == "tip":
            links[path.row] = replace(link, tip=replace(link.tip, mass=value))
        else:
            dims = sections.setdefault(path.row, (path.section_shape,
                                                  dict(path.section_dims)))[1]
            dims[path.key] = value
    for row, (shape, dims) in sections.items():
        if shape == "rectangle":
            section = Section.rectangle(dims["a"], dims["b"])
        elif shape == "tube":
            section = Section.tube(dims["outer_diameter"], dims["wall"])
        else:
            ip = dims["Ip"] if dims.get("Ip") is not None else dims["Ix"] + dims["Iy"]
            section = Section(A=dims["A"], Ix=dims["Ix"], Iy=dims["Iy"], J=dims["J"], Ip=ip)
        links[row] = replace(links[row], section=section)
    return replace(robot, links=tuple(links))
