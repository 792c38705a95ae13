"""Accelerometer and strain-gauge models of a flexible arm (dissertation §5.3, §5.4.2–5.4.3).

A sensor sits at arc length ``s`` [m] from the start of a flexible link (DH row ``row``).
The measurement model is a :class:`casadi.Function` ``h(x, u)`` of the flexible state
``x = [δ; δ̇]`` and the measured joint motion ``u = [q; q̇; q̈]`` (eq. 168–169, 174), with
one named output per sensor (and ``y``, all of them stacked in declaration order).

Accelerometers (eq. 145–153, 163–169)
-------------------------------------
The sensor point is ``p = T_b(q, δ) [s e_z + Σ_j δ_j w_j(s) + (I + [ϑ(s)δ ×]) o; 1]``
with ``T_b`` the pose of the link's base frame (local beam frame at ``s = 0``: ``z``
along the neutral axis, ``x``, ``y`` the section's principal axes, see
:mod:`casflex.robot`), ``w_j``, ``ϑ_j`` the link-local deflection and rotation of mode
``j`` (:mod:`casflex.modal.integrals`) and ``o`` an optional offset of the sensing
element from the neutral axis, in the local beam frame [m]. The acceleration is the
exact second time derivative of this position for the model's kinematics,

``p̈ = J_X(p) Ẍ + (d/dt J_X(p)) Ẋ``,   ``X = [q; δ]``,

which is eq. 148 (``T̈ r + 2 Ṫ ṙ + T r̈``) with the deflection of the inboard links in
``T_b`` included, and with ``δ̈`` eliminated through the flexible rows of the equations of
motion (eq. 157–158, :attr:`casflex.model.FlexibleModel.prescribed_dddelta`).

On a model with ``kinematics="exact"`` the point rides the exact rod instead
(:mod:`casflex.model.strain_kinematics`): the model's walk from the link's base through
its nodes, continued to ``s`` with the tabulated ``w(s)``, ``ϑ(s)`` of the sensor point
(:func:`~casflex.model.strain_kinematics.rod_point`), gives the section's rotation
``R_s`` and centre ``r_s``, and ``p = T_b [r_s + R_s o; 1]``, ``R = R_b R_s``; to first
order in δ this is the point above.

* ``frame = "sensor"`` (default): components along the axes of the deflected link at the
  sensor, ``R = R_b (I + [ϑ(s)δ ×])`` (eq. 153); ``"inertial"``: base-frame components.
* ``gravity = True`` (default, MEMS and other DC-coupled sensors): the sensor measures the
  specific force ``p̈ − g`` (g the model's gravity vector); ``False``: ``p̈``.
* ``rigid = True`` (default): the full signal; ``False``: the signal minus the one the same
  sensor would give on the rigid arm (``δ = δ̇ = δ̈ = 0``), the adjusted acceleration of
  eq. 163 (with gravity and frame applied consistently).

Strain-gauge pairs (eq. 170–174)
--------------------------------
Bending strain at the surface of the link, ``ε = −c κ``, with ``κ_x = w_x''``,
``κ_y = w_y''`` the curvatures of the link-local deflection (``w'' = d²w/ds²``,
:mod:`casflex.modal.integrals` key ``point_curvature``) and ``c`` the distance [m] of the
gauge from the neutral axis. Sign convention: ``ε_x`` is the axial strain of the gauge on
the **+x face** of the section (tension positive): a deflection curving toward +x
(``w_x'' > 0``) compresses that face. A half-bridge pair (gauges on the +x and −x faces)
reports this value. The dissertation's eq. 170 writes ``ε = a_x w_x''``, the strain of the
−x face; the sign does not matter to the estimator. ``ε_y`` likewise for the +y face.
Axial and torsional strains are not modelled (eq. 170: insignificant for serial arms).
The default ``c`` is the half depth of the section along that axis (rectangle and tube).

Sensor files
------------
``[[sensor]]`` tables, in a sensor file or in the robot file; format in
``problems/sensors/README.md`` (:func:`load_sensors`).

Examples
--------
>>> import casadi as ca
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> robot = load("problems/arm2link.toml")
>>> sensors = SensorSet([Accelerometer(3, 1.0, name="tip")])
>>> provider = PointwiseProvider(robot, [0, 0, 0], count=2, points=sensors.points)
>>> model = FlexibleModel(robot, provider, gravity=None)
>>> h = measurement_function(model, sensors)
>>> h.name_out()
['tip', 'y']
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex._problemfile import TableReader, read_toml
from casflex._validate import choice, fail, identifier, plausible, to_float
from casflex.errors import ModelError, ProblemFileError
from casflex.modal.integrals import RATE_KEYS
from casflex.model.pose_factors import pose_factors
from casflex.model.strain_kinematics import rod_nodes, rod_point
from casflex.sensor_tables import (
    entry_columns,
    fill_entries,
    lean_applicable,
    placeholder_kinematics,
)

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.robot import Robot, Section

__all__ = [
    "Accelerometer",
    "StrainPair",
    "SensorSet",
    "load_sensors",
    "sensors_from_tables",
    "measurement_function",
    "kinematic_measurement",
    "measurement_with_entries",
    "point_position_function",
    "default_strain_distance",
]

_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Accelerometer:
    """A (up to) three-axis accelerometer on a flexible link.

    Parameters
    ----------
    row : int
        DH row (0-based) of the flexible link.
    s : float
        Arc length from the link's start [m], ``0 <= s <= L``.
    name : str
        Output name (a C identifier); default ``acc<row>_<s>``.
    offset : tuple of 3 float
        Sensing element relative to the neutral axis at ``s``, local beam frame [m].
    frame : {"sensor", "inertial"}
        Components along the deflected link's axes or the base frame.
    gravity : bool
        Measure the specific force ``p̈ − g`` (MEMS) instead of ``p̈``.
    rigid : bool
        Keep the rigid-motion part (``False``: eq. 163, adjusted acceleration).
    axes : str
        Measured axes, a subset of ``"xyz"`` in order.
    noise : float or None
        Standard deviation of one sample [m/s²] (for the filter's ``R``).

    Examples
    --------
    >>> Accelerometer(2, 1.0).outputs
    ('acc2_1_x', 'acc2_1_y', 'acc2_1_z')
    """

    row: int
    s: float
    name: str = ""
    offset: tuple = (0.0, 0.0, 0.0)
    frame: str = "sensor"
    gravity: bool = True
    rigid: bool = True
    axes: str = "xyz"
    noise: float | None = None
    kind: str = field(default="accelerometer", init=False)

    def __post_init__(self):
        if not self.name:
            object.__setattr__(self, "name", _default_name("acc", self.row, self.s))
        choice(self.frame, f"{self.name}.frame", ("sensor", "inertial"))
        _check_axes(self.axes, "xyz", f"{self.name}.axes")
        object.__setattr__(self, "offset", tuple(float(v) for v in self.offset))
        for k, v in enumerate(self.offset):
            plausible(v, "offset", f"{self.name}.offset[{k}]")
        if self.noise is not None:
            plausible(self.noise, "noise_acceleration", f"{self.name}.noise")

    @property
    def outputs(self) -> tuple[str, ...]:
        """Names of the scalar signals, ``<name>_<axis>``."""
        return tuple(f"{self.name}_{a}" for a in self.axes)


@dataclass(frozen=True)
class StrainPair:
    """Bending strain-gauge pairs at one section of a flexible link.

    Parameters
    ----------
    row : int
        DH row (0-based) of the flexible link.
    s : float
        Arc length from the link's start [m].
    distance : tuple of 2 float
        Distance of the gauges from the neutral axis along local x and y [m] (the gauges
        on the ±x faces measure bending ``w_x``, those on ±y bending ``w_y``).
    name : str
        Output name; default ``sg<row>_<s>``.
    axes : str
        Bending planes measured, a subset of ``"xy"``.
    noise : float or None
        Standard deviation of one sample [-].

    Examples
    --------
    >>> StrainPair(2, 0.05, distance=(0.0035, 0.0025)).outputs
    ('sg2_0p05_x', 'sg2_0p05_y')
    """

    row: int
    s: float
    distance: tuple = (0.0, 0.0)
    name: str = ""
    axes: str = "xy"
    noise: float | None = None
    kind: str = field(default="strain", init=False)

    def __post_init__(self):
        if not self.name:
            object.__setattr__(self, "name", _default_name("sg", self.row, self.s))
        _check_axes(self.axes, "xy", f"{self.name}.axes")
        object.__setattr__(self, "distance", tuple(float(v) for v in self.distance))
        for k, v in enumerate(self.distance):
            if v != 0.0:  # 0: not given (no strain on that axis)
                plausible(v, "section_dimension", f"{self.name}.distance[{k}]")
        if self.noise is not None:
            plausible(self.noise, "noise_strain", f"{self.name}.noise")

    @property
    def outputs(self) -> tuple[str, ...]:
        """Names of the scalar signals, ``<name>_<axis>``."""
        return tuple(f"{self.name}_{a}" for a in self.axes)


def _default_name(prefix, row, s):
    text = f"{float(s):g}".replace(".", "p").replace("-", "m")
    return f"{prefix}{int(row)}_{text}"


def _check_axes(axes, allowed, field_, path=None, error=None):
    """``axes`` if it is a non-empty, ordered subset of the letters ``allowed``."""
    if not isinstance(axes, str) or not axes or any(a not in allowed for a in axes) or \
            "".join(sorted(set(axes))) != axes:
        raise fail(field_, axes, f"must be a non-empty, ordered subset of {allowed!r}",
                   path=path, error=error)
    return axes


class SensorSet:
    """An ordered set of sensors; the measurement vector stacks their axes in this order.

    Parameters
    ----------
    sensors : sequence of Accelerometer or StrainPair
    source : str, optional
        File the sensors were read from.
    points : sequence of (int, float), optional
        The points the model tabulates, when they are more than (or ordered differently
        from) the sensors' own points, e.g. one model for several sensor sets.

    Attributes
    ----------
    sensors : tuple
    points : list of (int, float)
        The distinct sensor points ``(row, s)``, to pass as ``points`` to
        :func:`casflex.model.build_model` / :class:`~casflex.model.PointwiseProvider`.

    Examples
    --------
    >>> ss = SensorSet([Accelerometer(2, 1.0, name="a"), StrainPair(2, 0.05, (1e-3, 1e-3),
    ...                                                             name="b")])
    >>> ss.n_outputs, ss.points
    (5, [(2, 1.0), (2, 0.05)])
    """

    def __init__(self, sensors: Iterable[Accelerometer | StrainPair], source: str | None = None,
                 points: Iterable[tuple[int, float]] | None = None) -> None:
        self.sensors = tuple(sensors)
        self.source = source
        names = set()
        for k, sen in enumerate(self.sensors):
            if not isinstance(sen, (Accelerometer, StrainPair)):
                raise ModelError(f"sensors[{k}] is a {type(sen).__name__}, not an "
                                 "Accelerometer or StrainPair")
            if sen.name in names or sen.name == "y":
                raise ModelError(f"sensor name {sen.name!r} is used twice (or is the "
                                 "reserved output 'y')")
            names.add(sen.name)
        self.points = [] if points is None else [(int(r), float(s)) for r, s in points]
        given = points is not None
        for sen in self.sensors:
            key = (int(sen.row), float(sen.s))
            if key not in self.points:
                if given:
                    raise ModelError(f"sensor '{sen.name}' at (row {key[0]}, s = {key[1]} m) "
                                     f"is not among the given points {self.points}")
                self.points.append(key)

    def __len__(self) -> int:
        return len(self.sensors)

    def __iter__(self) -> Iterator[Accelerometer | StrainPair]:
        return iter(self.sensors)

    @property
    def n_outputs(self) -> int:
        """Length of the stacked measurement vector."""
        return sum(len(s.axes) for s in self.sensors)

    @property
    def output_names(self) -> tuple[str, ...]:
        """Names of the scalar signals in stacking order."""
        return tuple(n for s in self.sensors for n in s.outputs)

    @property
    def noise_std(self) -> np.ndarray:
        """Per-signal standard deviations (NaN where a sensor gives none)."""
        out = []
        for s in self.sensors:
            out += [np.nan if s.noise is None else float(s.noise)] * len(s.axes)
        return np.array(out)

    def point_index(self, sensor: Accelerometer | StrainPair) -> int:
        """Index of ``sensor``'s point in :attr:`points`.

        Parameters
        ----------
        sensor : Accelerometer or StrainPair
            A sensor whose point ``(row, s)`` is among :attr:`points` (not necessarily
            one of this set's sensors).

        Returns
        -------
        int
            Sensors at the same point share the index.

        Examples
        --------
        >>> ss = SensorSet([Accelerometer(2, 1.0, name="a"), StrainPair(3, 0.05, name="b"),
        ...                 Accelerometer(2, 1.0, name="c", axes="z")])
        >>> ss.points
        [(2, 1.0), (3, 0.05)]
        >>> [ss.point_index(sen) for sen in ss]
        [0, 1, 0]
        """
        return self.points.index((int(sensor.row), float(sensor.s)))

    def with_options(self, **changes) -> SensorSet:
        """A copy with the given fields changed on every accelerometer (e.g. ``rigid``).

        Parameters
        ----------
        **changes
            Field values, e.g. ``rigid=False``, ``gravity=False``, ``frame="inertial"``.
            Each is applied to every sensor that has that field (so ``noise`` or
            ``axes`` reach the strain pairs too) and ignored for the others. The copy
            keeps :attr:`points` and ``source``.

        Returns
        -------
        SensorSet

        Examples
        --------
        >>> ss = SensorSet([Accelerometer(2, 1.0)]).with_options(rigid=False)
        >>> ss.sensors[0].rigid
        False
        """
        from dataclasses import replace

        out = []
        for s in self.sensors:
            ok = {k: v for k, v in changes.items() if hasattr(s, k)}
            out.append(replace(s, **ok) if ok else s)
        return SensorSet(out, self.source, self.points)


def default_strain_distance(section: Section) -> tuple[float, float]:
    """Half depths ``(c_x, c_y)`` [m] of a rectangle or tube section (NaN otherwise).

    The default ``distance`` of a :class:`StrainPair`: ``c_x`` is the distance of the
    ±x faces from the neutral axis, ``c_y`` that of the ±y faces.

    Parameters
    ----------
    section : casflex.robot.Section
        Its ``kind`` decides: ``"rectangle"`` and ``"tube"`` are recovered from the area
        and second moments, any other kind gives NaN.

    Returns
    -------
    tuple of 2 float

    Examples
    --------
    >>> from casflex.robot import Section
    >>> [round(v, 6) for v in default_strain_distance(Section.rectangle(0.005, 0.007))]
    [0.0035, 0.0025]
    """
    if section.kind == "rectangle":
        return (math.sqrt(3.0 * section.Iy / section.A), math.sqrt(3.0 * section.Ix / section.A))
    if section.kind == "tube":
        ro = math.sqrt(0.5 * (4.0 * section.Ix / section.A + section.A / math.pi))
        return (ro, ro)
    return (float("nan"), float("nan"))


# ------------------------------------------------------------------ file reading


def _resolve_row(reader, robot, value):
    """The DH row of the flexible link named by ``value`` (link name or row index)."""
    if isinstance(value, bool):
        raise reader.error("link", value, "must be a link name or a 0-based DH row index")
    if isinstance(value, int):
        if not 0 <= value < len(robot.links):
            raise reader.error("link", value, f"row index out of range: robot '{robot.name}' "
                                              f"has rows 0..{len(robot.links) - 1}")
        row = value
    elif isinstance(value, str):
        names = [link.name for link in robot.links]
        if value not in names:
            raise reader.error("link", value, f"unknown link; robot '{robot.name}' has links "
                                              f"{names}")
        row = names.index(value)
    else:
        raise reader.error("link", value, "must be a link name or a 0-based DH row index")
    if not robot.links[row].flexible:
        flex = [link.name for link in robot.links if link.flexible]
        raise reader.error("link", value, f"link '{robot.links[row].name}' is rigid; sensors "
                                          f"sit on flexible links {flex}")
    return row


_ACC_KEYS = {"name", "type", "link", "s", "offset", "frame", "gravity", "rigid", "axes",
             "noise"}
_SG_KEYS = {"name", "type", "link", "s", "distance", "axes", "noise"}


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(to_float(v))


def _sensor_from_table(reader, robot, kind):
    """One sensor from its ``[[sensor]]`` table (``type`` already checked)."""
    if not reader.has("link"):
        raise reader.error("link", None, "is required: a link name or row index")
    row = _resolve_row(reader, robot, reader.table["link"])
    link = robot.links[row]
    s = reader.number("s", required=True)
    if not 0.0 <= s <= link.length * (1 + 1e-12):
        raise reader.error("s", s, f"must lie on the link: 0 <= s <= {link.length} m "
                                   f"(length of '{link.name}')")
    name = reader.string("name", "")
    if name:
        identifier(name, f"{reader.prefix}.name", path=reader.path)
    axes = reader.table.get("axes", "xyz" if kind == "accelerometer" else "xy")
    _check_axes(axes, "xyz" if kind == "accelerometer" else "xy", f"{reader.prefix}.axes",
                path=reader.path, error=ProblemFileError)
    noise = reader.number("noise")
    if noise is not None and noise <= 0:
        raise reader.error("noise", noise, "must be > 0 (a standard deviation)")
    if noise is not None:
        reader.check_bound("noise", noise, noise, "noise_acceleration" if kind ==
                           "accelerometer" else "noise_strain")
    if kind == "accelerometer":
        offset = reader.vector("offset", 3, (0.0, 0.0, 0.0), quantity="offset")
        if math.hypot(*offset) > link.length:
            raise reader.error("offset", list(offset), "must lie within the link's length "
                               f"({link.length} m of '{link.name}') from its neutral axis: "
                               "a sensing element farther away is not on the link")
        flags = {}
        for key in ("gravity", "rigid"):
            v = reader.table.get(key, True)
            if not isinstance(v, bool):
                raise reader.error(key, v, "must be true or false")
            flags[key] = v
        frame = reader.string("frame", "sensor", choices=("sensor", "inertial"))
        return Accelerometer(row, s, name=name, offset=offset, frame=frame, axes=axes,
                             noise=noise, **flags)
    dist = reader.table.get("distance")
    if dist is None:
        dist = default_strain_distance(link.section)
        if not all(math.isfinite(c) for c in dist):
            raise reader.error("distance", None,
                               "is required for an 'explicit' section (no depth known)")
    elif _is_number(dist):
        dist = (float(dist), float(dist))
    if not (isinstance(dist, (list, tuple)) and len(dist) == 2
            and all(_is_number(v) and v > 0 for v in dist)):
        raise reader.error("distance", dist, "must be a positive number or [c_x, c_y] in m")
    _check_gauge_distance(reader, link, [float(v) for v in dist])
    return StrainPair(row, s, distance=tuple(dist), name=name, axes=axes, noise=noise)


def _check_gauge_distance(reader, link, dist):
    """Gauges sit on the section: no farther from the neutral axis than its faces."""
    faces = default_strain_distance(link.section)
    if all(math.isfinite(c) for c in faces):
        why = "half the section's depth along that axis: the gauges sit on its faces"
    else:  # explicit section: the extreme fibre is at ~1-2 radii of gyration
        faces = tuple(10.0 * math.sqrt(i / link.section.A)
                      for i in (link.section.Iy, link.section.Ix))
        why = ("ten radii of gyration sqrt(I/A) of the explicit section (a rectangle's "
               "face is at 1.7)")
    for axis, c, face in zip("xy", dist, faces, strict=True):
        reader.check_bound("distance", dist, c, "section_dimension")
        if c > face * (1 + 1e-9):
            raise reader.error("distance", dist, f"c_{axis} = {c} m is beyond {face:.4g} m, "
                                                 f"{why}")


def sensors_from_tables(tables: list[dict], robot: Robot,
                        path: str | os.PathLike | None = None) -> SensorSet:
    """Build a :class:`SensorSet` from parsed ``[[sensor]]`` tables.

    Parameters
    ----------
    tables : list of dict
        The ``sensor`` array of a TOML file (format in ``problems/sensors/README.md``).
    robot : casflex.robot.Robot
        The robot the sensors are mounted on (links, lengths and sections are checked).
    path : str, optional
        File name for error messages.

    Returns
    -------
    SensorSet

    Raises
    ------
    ProblemFileError
        Unknown keys, links or types; a point beyond the link length; bad values.

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> ss = sensors_from_tables([{"type": "strain", "link": "link1", "s": 0.05}], robot)
    >>> [round(c, 4) for c in ss.sensors[0].distance]
    [0.0035, 0.0025]
    """
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise fail("sensor", tables, "must be an array of tables ([[sensor]])", path=path,
                   error=ProblemFileError)
    if not tables:
        raise fail("sensor", tables, "declare at least one [[sensor]]", path=path,
                   error=ProblemFileError)
    out = []
    for i, raw in enumerate(tables):
        reader = TableReader(path, raw, f"sensor[{i}]")
        kind = raw.get("type")
        if kind not in ("accelerometer", "strain"):
            raise reader.error("type", kind, "must be 'accelerometer' or 'strain'")
        allowed = _ACC_KEYS if kind == "accelerometer" else _SG_KEYS
        unknown = sorted(set(raw) - allowed)
        if unknown:
            raise reader.error(unknown[0], raw[unknown[0]],
                               f"unknown key for a {kind}; known keys are {sorted(allowed)}")
        out.append(_sensor_from_table(reader, robot, kind))
    try:
        return SensorSet(out, source=None if path is None else str(path))
    except ModelError as exc:
        raise fail("sensor", [s.name for s in out], str(exc), path=path,
                   error=ProblemFileError) from exc


def load_sensors(path: str | os.PathLike, robot: Robot) -> SensorSet:
    """Read the ``[[sensor]]`` tables of a sensor file (or of a robot file).

    Parameters
    ----------
    path : str or pathlib.Path
        TOML file; other top-level keys allowed: ``description``, ``robot`` (path of the
        robot file, relative to this file; informative) and, in a robot file, the robot's
        own keys.
    robot : casflex.robot.Robot

    Returns
    -------
    SensorSet

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> load_sensors("problems/sensors/arm2link_accel.toml", robot).output_names[:3]
    ('tip1_x', 'tip1_y', 'tip1_z')
    """
    data = read_toml(path)
    if "sensor" not in data:
        raise fail("sensor", None, "is required: at least one [[sensor]] table", path=path,
                   error=ProblemFileError)
    if "link" not in data:  # a sensor file: nothing else allowed
        unknown = sorted(set(data) - {"sensor", "description", "robot"})
        if unknown:
            raise fail(unknown[0], data[unknown[0]], "unknown key; a sensor file has "
                       "'description', 'robot' and [[sensor]] tables", path=path,
                       error=ProblemFileError)
    return sensors_from_tables(data["sensor"], robot, path)


# ------------------------------------------------------------------ symbolic models


def _beam_body(model, row):
    for body in model.bodies:
        if body["kind"] == "beam" and body["row"] == row:
            return body
    flex = [b["row"] for b in model.bodies if b["kind"] == "beam"]
    raise ModelError(f"row {row} carries no flexible link in the model; flexible rows are "
                     f"{flex}")


def _point_data(model, sensors):
    """Provider's point quantities as SX of q (filled), checked against the sensor points."""
    P = len(sensors.points)
    m = model.m
    data = {}
    for key, width in (("point_u", 3), ("point_theta", 3), ("point_curvature", 2)):
        try:
            f = model.provider.function(key)
        except Exception as exc:  # noqa: BLE001  (provider-specific error types)
            raise ModelError(f"the model's provider has no {key!r}: build it with "
                             f"points={sensors.points} (e.g. build_model(..., points=...))"
                             ) from exc
        if f.numel_out(0) != P * m * width:
            raise ModelError(f"the provider tabulates {f.numel_out(0) // max(m * width, 1)} "
                             f"sensor points; the sensors need {P}: {sensors.points} (build "
                             "the model with points=sensors.points)")
        shared = getattr(model, "table_values", None)  # the model's one interpolant call
        if not P * m:
            data[key] = ca.SX.zeros(P * m * width)
        elif shared is not None and key in shared:
            data[key] = shared[key]
        else:
            data[key] = ca.SX(f(model.q_shape))
    if getattr(model, "kinematics", "truncated") == "exact":
        # the exact rods are walked through the shapes sampled inside the links
        for key in RATE_KEYS:
            data[key] = (shared[key] if shared is not None and key in shared
                         else ca.SX(model.provider.function(key)(model.q_shape)))
    return data


def _point_pose(model, sensors, data, sensor):
    """Position (3,) and rotation (3 × 3) of a sensor, SX in (q, δ) (:func:`_point_local`)."""
    T = _beam_body(model, sensor.row)["T"]
    Rl, local = _point_local(model, sensors, data, sensor)
    return T[:3, :3] @ local + T[:3, 3], T[:3, :3] @ Rl


def _point_local(model, sensors, data, sensor):
    """Rotation ``R_l`` and position of the sensing element in the link's base frame: on
    the link-local deflection to first order (default kinematics), or on the exact rod."""
    m, i, d = model.m, sensors.point_index(sensor), model.delta
    w, th = ca.SX.zeros(3), ca.SX.zeros(3)
    for j in range(m):
        k = (i * m + j) * 3
        w, th = w + d[j] * data["point_u"][k:k + 3], th + d[j] * data["point_theta"][k:k + 3]
    off = ca.DM(list(getattr(sensor, "offset", (0.0, 0.0, 0.0))))
    if getattr(model, "kinematics", "truncated") == "exact":
        # the rod walked from the link's base through the model's nodes to s (one rod per
        # link and call, shared by the link's sensors)
        rods = data.setdefault("rods", {})
        if sensor.row not in rods:
            rods[sensor.row] = rod_nodes(model.robot.links[sensor.row],
                                         _beam_body(model, sensor.row)["beam"],
                                         data["sample_u"], data["sample_theta"], d)
        Rl, centre = rod_point(rods[sensor.row], sensor.s, w, th)
        return Rl, centre + Rl @ off
    Rl = ca.SX.eye(3) + ca.skew(th)
    return Rl, ca.vertcat(0, 0, sensor.s) + w + Rl @ off


def point_position_function(model: FlexibleModel, sensors: SensorSet) -> ca.Function:
    """``casadi.Function`` ``(q, delta) -> (p_<name>, ...)``: sensor positions [m] in the base
    frame, the model's kinematics (for independent checks of the accelerometer model).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Built with ``points=sensors.points``.
    sensors : SensorSet
        One output per sensor, the position of its sensing element (offset included).

    Returns
    -------
    casadi.Function
        ``sensor_positions (q, delta) -> (p_<name>, ...)``, each 3 × 1 [m].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> point_position_function(model, ss)([0, 0, 0], [0]).full().ravel().round(6).tolist()
    [1.0, 0.0, -1.0]
    """
    data = _point_data(model, sensors)
    outs = [_point_pose(model, sensors, data, s)[0] for s in sensors]
    return ca.Function("sensor_positions", [model.q, model.delta], outs, ["q", "delta"],
                       [f"p_{s.name}" for s in sensors])


def _rigid_substitute(expr, model, extra=None):
    v = ca.vertcat(model.delta, model.ddelta, *([extra] if extra is not None else []))
    return ca.substitute(expr, v, ca.DM.zeros(v.numel()))


def measurement_function(model: FlexibleModel, sensors: SensorSet,
                         name: str = "h") -> ca.Function:
    """The measurement model ``h(x, u)`` of a sensor set (eq. 169, 174), exact for the model.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Built with ``points=sensors.points`` (the provider must tabulate the sensor points).
    sensors : SensorSet
    name : str
        Function name.

    Returns
    -------
    casadi.Function
        Inputs ``x = [δ; δ̇]`` (2m) and ``u = [q; q̇; q̈]`` (3n); one output per sensor
        (its axes, in m/s² or strain) and ``y``, all stacked.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip", axes="z")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> h = measurement_function(model, ss)
    >>> float(h(np.zeros(2), np.zeros(9))[0])   # at rest: g along the link's z (downward)
    -9.81
    """
    dddelta = model.prescribed_dddelta
    outs = _exact_signals(model, sensors, dddelta)
    return _wrap(model, sensors, outs, name)


def _exact_signals(model, sensors, dddelta):
    acc = ca.SX.sym("acc_dd", model.m)
    outs = _kin_signals(model, sensors, acc)
    return [ca.substitute(o, acc, dddelta) for o in outs]


def _kin_signals(model, sensors, acc, lean=False, lookup="interpolant", recursive=False):
    """Signals with δ̈ a free symbol ``acc``; the rigid part removed where asked;
    ``recursive``: the accelerometers by :func:`_recursive_acceleration`.

    ``lean``: with a table provider, the table entries the signals need (and their
    derivatives along the shape joints) come from one small spline of just those entries
    instead of the model's spline of every quantity (:func:`casflex.sensor_tables.
    fill_entries`); the same expressions to rounding; ``lookup`` as
    :meth:`casflex.modal.tables.ModalTable.function`, or None: the entries are left as
    symbols, returned as ``(outs, (V, V̇, V̈, their columns on the grid))``."""
    q, dq, ddq, d, dd = model.q, model.dq, model.ddq, model.delta, model.ddelta
    X, dX, ddX = ca.vertcat(q, d), ca.vertcat(dq, dd), ca.vertcat(ddq, acc)
    lean = lean and lean_applicable(model)
    if lean:
        # table entries as placeholders V(q_shape), with their rates as symbols: the time
        # derivatives below differentiate them as extra coordinates
        body_model, data, V = placeholder_kinematics(model, _point_data(model, sensors))
        Vd, Vdd = ca.SX.sym("Vd", V.numel()), ca.SX.sym("Vdd", V.numel())
        X, dX, ddX = ca.vertcat(X, V), ca.vertcat(dX, Vd), ca.vertcat(ddX, Vdd)
    else:
        body_model, data = model, _point_data(model, sensors)
    g = ca.DM(model.gravity)
    outs = []
    for sen in sensors:
        i = sensors.point_index(sen)
        if sen.kind == "strain":
            kap = ca.SX.zeros(2)
            for j in range(model.m):
                k = (i * model.m + j) * 2
                kap += d[j] * data["point_curvature"][k:k + 2]
            eps = ca.vertcat(-sen.distance[0] * kap[0], -sen.distance[1] * kap[1])
            outs.append(ca.vertcat(*[eps[_AXES[a]] for a in sen.axes]))
            continue
        y = (_recursive_acceleration(body_model, sensors, data, sen, X, dX, ddX, g, lean)
             if recursive else None)
        if y is None:
            p, R = _point_pose(body_model, sensors, data, sen)
            v = ca.jtimes(p, X, dX)
            a = ca.jtimes(v, X, dX) + ca.jtimes(p, X, ddX)
            if sen.gravity:
                a = a - g
            y = R.T @ a if sen.frame == "sensor" else a
        if not sen.rigid:
            y = y - _rigid_substitute(y, model, acc)
        outs.append(ca.vertcat(*[y[_AXES[c]] for c in sen.axes]))
    if lean and lookup is None:
        need, cols = entry_columns(model, outs, V, Vd, Vdd)
        return outs, (V[need], Vd[need], Vdd[need], cols)
    return fill_entries(model, outs, V, Vd, Vdd, lookup) if lean else outs


def _recursive_acceleration(model, sensors, data, sen, X, dX, ddX, g, lean):
    """An accelerometer's signal by a recursive pass over the factors of its pose (None if
    they are not known): the point carried inward through each flexible factor ``F``
    (``p ← F p``, ``ṗ ← Ḟ p + F ṗ``, ``p̈ ← F̈ p + 2 Ḟ ṗ + F p̈``), the rigid leading ones
    ``L`` as the body-frame rates ``Lᵀ L̇``, ``Lᵀ L̈`` (``Lᵀ L = I``). The whole pose's
    time derivatives to rounding, on a much smaller graph (and Jacobian)."""
    base = pose_factors(model, sen.row, placeholders=lean)
    if base is None:
        return None
    factors, k = base
    Rl, p = _point_local(model, sensors, data, sen)
    pd = ca.jtimes(p, X, dX)
    pdd = ca.jtimes(pd, X, dX) + ca.jtimes(p, X, ddX)
    for F in reversed(factors[k:]):
        Fd = ca.jtimes(F, X, dX)
        Fdd = ca.jtimes(Fd, X, dX) + ca.jtimes(F, X, ddX)
        R, Rd, Rdd = F[:3, :3], Fd[:3, :3], Fdd[:3, :3]
        p, pd, pdd = (R @ p + F[:3, 3], Rd @ p + R @ pd + Fd[:3, 3],
                      Rdd @ p + 2 * (Rd @ pd) + R @ pdd + Fdd[:3, 3])
    L = ca.SX.eye(4)
    for F in factors[:k]:
        L = L @ F
    Ld = ca.jtimes(L, X, dX)
    Ldd = ca.jtimes(Ld, X, dX) + ca.jtimes(L, X, ddX)
    RL = L[:3, :3]
    a = (RL.T @ Ldd[:3, :3]) @ p + 2 * ((RL.T @ Ld[:3, :3]) @ pd) + pdd + RL.T @ Ldd[:3, 3]
    if sen.gravity:
        a = a - RL.T @ g
    if sen.frame != "sensor":
        return RL @ a
    for F in factors[k:]:
        a = F[:3, :3].T @ a
    return Rl.T @ a


def _wrap(model, sensors, outs, name):
    x = ca.vertcat(model.delta, model.ddelta)
    u = ca.vertcat(model.q, model.dq, model.ddq)
    y = ca.vertcat(*outs) if outs else ca.SX(0, 1)
    return ca.Function(name, [x, u], [*outs, y], ["x", "u"],
                       [s.name for s in sensors] + ["y"])


def kinematic_measurement(model: FlexibleModel, sensors: SensorSet, name: str = "h_kin",
                          rigid_part: bool = False, lean: bool = False,
                          lookup: str = "interpolant", recursive: bool = False) -> ca.Function:
    """The measurement with ``δ̈`` as an input: ``(x, u, dddelta) -> y``.

    The estimator substitutes its own (lean) model of the flexible accelerations; with
    ``δ̈`` from eq. 158 it equals :func:`measurement_function`.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    sensors : SensorSet
    name : str
    rigid_part : bool
        Return instead ``u -> y_rigid``: the signals of the same sensors on the rigid arm
        (``δ = δ̇ = δ̈ = 0``), i.e. what ``rigid = False`` subtracts.
    lean : bool
        With a table provider (:class:`casflex.model.TableProvider`): the modal-table
        entries the signals use and their derivatives along the shape joints come from
        one B-spline of just those entries (the model's grid, periodicity and method)
        instead of the model's B-spline of every quantity and its derivatives (fewer and
        smaller spline evaluations). The same expressions to rounding. Ignored for
        other providers and with ``rigid_part``.
    lookup : {"interpolant", "local"}
        With ``lean``: how that B-spline is evaluated
        (:meth:`casflex.modal.tables.ModalTable.function`); ``"local"`` is the same spline
        with leaner generated C (:func:`casflex.modal.local_bspline_function`), the
        default of the estimator (:func:`casflex.estimation.ekf_step_function`).
    recursive : bool
        The accelerometers by a recursive pass over the factors of their pose instead of
        the whole pose's time derivatives: the same signals to rounding, a much smaller
        graph and Jacobian (the estimator's default). Ignored with ``rigid_part``.

    Returns
    -------
    casadi.Function

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> kinematic_measurement(model, ss).name_in()
    ['x', 'u', 'dddelta']
    >>> kinematic_measurement(model, ss, lean=True).name_out()   # pointwise: the same
    ['y']
    """
    acc = ca.SX.sym("dddelta", model.m)
    x = ca.vertcat(model.delta, model.ddelta)
    u = ca.vertcat(model.q, model.dq, model.ddq)
    if rigid_part:
        full = sensors.with_options(rigid=True)
        outs = _kin_signals(model, full, acc)
        keep = []
        for sen, o in zip(sensors, outs, strict=True):
            if sen.kind == "accelerometer" and sen.rigid:
                keep.append(_rigid_substitute(o, model, acc))
            else:
                keep.append(ca.DM.zeros(o.numel()))
        return ca.Function(name, [u], [ca.vertcat(*keep)], ["u"], ["y_rigid"])
    y = ca.vertcat(*_kin_signals(model, sensors, acc, lean, lookup, recursive))
    return ca.Function(name, [x, u, acc], [y], ["x", "u", "dddelta"], ["y"])


def measurement_with_entries(model: FlexibleModel, sensors: SensorSet, name: str = "h_kin",
                             recursive: bool = False) -> tuple[ca.Function, np.ndarray] | None:
    """The lean measurement with its modal-table entries as inputs, for a caller that looks
    them up itself (together with its own tables at the same point:
    :mod:`casflex.estimation.lookup`).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        With a table provider (:class:`casflex.model.TableProvider`).
    sensors : SensorSet
    name : str
    recursive : bool
        As :func:`kinematic_measurement`.

    Returns
    -------
    (casadi.Function, numpy.ndarray) or None
        ``(x, u, dddelta, v, v_dot, v_ddot) -> y``: :func:`kinematic_measurement` with
        ``lean=True``, except that the ``k`` table entries the signals use come in as
        ``v`` with their first and second time derivatives (along the shape joints'
        motion in ``u``); and those entries' values on the table's grid, ``grid shape +
        (k,)`` (interpolated as the model's table is, they give that measurement). None
        for a model without a table over shape joints.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, name="tip")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> measurement_with_entries(model, ss) is None   # pointwise: no table
    True
    """
    if not lean_applicable(model):
        return None
    acc = ca.SX.sym("dddelta", model.m)
    outs, (v, vd, vdd, cols) = _kin_signals(model, sensors, acc, True, None, recursive)
    x = ca.vertcat(model.delta, model.ddelta)
    u = ca.vertcat(model.q, model.dq, model.ddq)
    return ca.Function(name, [x, u, acc, v, vd, vdd], [ca.vertcat(*outs)],
                       ["x", "u", "dddelta", "v", "v_dot", "v_ddot"], ["y"]), cols
