"""Robot descriptions: DH rows, flexible link sections, materials, tip bodies.

A robot is a serial chain of *rows* in the modified (Craig) Denavit–Hartenberg
convention used by the dissertation (Table 8): row ``i`` carries
``(theta_i, d_i, a_{i-1}, alpha_{i-1})`` and the homogeneous transform from frame
``i-1`` to frame ``i`` is

    T_{i-1,i} = Rx(alpha_{i-1}) · Tx(a_{i-1}) · Rz(theta_i) · Tz(d_i).

A row may be *flexible*: it then carries a uniform Euler–Bernoulli beam whose length is
the row's translation, either ``a_{i-1}`` (the beam runs along ``x_{i-1}`` and ends at the
axis of joint ``i``) or ``d_i`` (the beam starts at joint ``i`` and runs along ``z_i``);
a flexible row with both ``a`` and ``d`` non-zero cannot be placed (§3.2.4).

Local beam frames (the frame the section, mode shapes and tip bodies refer to): ``z``
points along the beam; for a ``d`` beam ``x``/``y`` are the DH ``x_i``/``y_i``; for an
``a`` beam ``y`` is the axis of joint ``i`` (``z_i``) and ``x = y × z`` (= ``y_{i-1}``
after the twist), so that the section's ``a`` side lies along the joint axis as in the
dissertation's Fig. 24.  A non-zero
``section_angle`` rotates the section about the beam axis.  A rigid row's local frame is
DH frame ``i``.

Units: metres, kilograms, seconds, radians, pascals.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from casflex._problemfile import TableReader, parse_toml, read_toml
from casflex._validate import fail, number, plausible
from casflex.errors import ModelError, ProblemFileError

__all__ = [
    "Section",
    "Material",
    "TipBody",
    "Link",
    "Robot",
    "load",
    "loads",
    "rectangle_torsion_constant",
]


def rectangle_torsion_constant(a: float, b: float, terms: int = 50) -> float:
    """St-Venant torsion constant of a solid ``a × b`` rectangle [m^4].

    Uses the series solution of the Prandtl stress function,
    ``J = (1/3) h t^3 [1 - (192 t)/(pi^5 h) sum_{n odd} tanh(n pi h / (2 t)) / n^5]``
    with ``h = max(a, b)`` and ``t = min(a, b)``.

    Parameters
    ----------
    a, b : float
        Side lengths [m].
    terms : int
        Number of odd terms of the series (the n-th term falls like n⁻⁵: 50 terms leave
        about 1e-9 relative).

    Returns
    -------
    float
        Torsion constant J [m^4].

    Examples
    --------
    >>> round(rectangle_torsion_constant(1.0, 1.0), 5)  # square: 0.1406 a^4
    0.14058
    """
    h, t = max(a, b), min(a, b)
    n = np.arange(1, 2 * terms, 2, dtype=float)
    series = np.sum(np.tanh(n * np.pi * h / (2.0 * t)) / n**5)
    return float(h * t**3 / 3.0 * (1.0 - 192.0 * t / (np.pi**5 * h) * series))


@dataclass(frozen=True)
class Section:
    """Cross-section properties of a uniform beam, in the local beam frame.

    Attributes
    ----------
    A : float
        Area [m^2].
    Ix : float
        Second moment of area about local x, ``∫ y² dA`` [m^4]; resists deflection w_y.
    Iy : float
        Second moment of area about local y, ``∫ x² dA`` [m^4]; resists deflection w_x.
    J : float
        St-Venant torsion constant [m^4] (torsional stiffness G·J).
    Ip : float
        Polar moment of area ``Ix + Iy`` [m^4] (torsional inertia ρ·Ip).
    kind : str
        ``"rectangle"``, ``"tube"`` or ``"explicit"`` (informative).

    Examples
    --------
    >>> s = Section(A=1e-4, Ix=2e-9, Iy=3e-9, J=4e-9, Ip=5e-9)
    >>> s.kind, s.Ix + s.Iy == s.Ip
    ('explicit', True)
    >>> Section.rectangle(0.01, 0.02).A
    0.0002
    """

    A: float
    Ix: float
    Iy: float
    J: float
    Ip: float
    kind: str = "explicit"

    def __post_init__(self):
        if not all(isinstance(v, (int, float)) and math.isfinite(v)
                   for v in (self.A, self.Ix, self.Iy, self.J, self.Ip)):
            return  # overflowed: Section.rectangle / tube say so with their arguments
        plausible(self.A, "section_area", "Section.A")
        for name in ("Ix", "Iy", "J", "Ip"):
            plausible(getattr(self, name), "section_moment", f"Section.{name}")

    @classmethod
    def rectangle(cls, a: float, b: float) -> Section:
        """Solid rectangle, ``a`` along local y and ``b`` along local x [m].

        Parameters
        ----------
        a : float
            Side along the local y axis [m].
        b : float
            Side along the local x axis [m].

        Returns
        -------
        Section

        Examples
        --------
        >>> s = Section.rectangle(0.005, 0.007)
        >>> round(s.Ix / s.Iy, 4)   # (b a^3) / (a b^3) = (a/b)^2
        0.5102
        """
        for name, value in (("a", a), ("b", b)):
            plausible(value, "section_dimension", f"Section.rectangle {name}")
        try:
            section = cls(
                A=a * b,
                Ix=b * a**3 / 12.0,
                Iy=a * b**3 / 12.0,
                J=rectangle_torsion_constant(a, b),
                Ip=a * b * (a**2 + b**2) / 12.0,
                kind="rectangle",
            )
        except OverflowError:
            section = None
        return _finite_section(section, f"Section.rectangle(a={a!r}, b={b!r})")

    @classmethod
    def tube(cls, outer_diameter: float, wall: float) -> Section:
        """Circular tube by outer diameter and wall thickness [m]; ``J = Ip``.

        Parameters
        ----------
        outer_diameter : float
            Outer diameter [m].
        wall : float
            Wall thickness [m], smaller than the outer radius.

        Returns
        -------
        Section

        Examples
        --------
        >>> s = Section.tube(0.0127, 0.00041)
        >>> s.J == s.Ip
        True
        """
        for name, value in (("outer_diameter", outer_diameter), ("wall", wall)):
            plausible(value, "section_dimension", f"Section.tube {name}")
        ro = outer_diameter / 2.0
        ri = ro - wall
        try:
            i = math.pi / 4.0 * (ro**4 - ri**4)
            section = cls(A=math.pi * (ro**2 - ri**2), Ix=i, Iy=i, J=2 * i, Ip=2 * i,
                          kind="tube")
        except OverflowError:
            section = None
        return _finite_section(section, f"Section.tube(outer_diameter={outer_diameter!r}, "
                                        f"wall={wall!r})")


def _finite_section(section, call):
    """``section`` if its properties are finite floats (``None``: they overflowed)."""
    if section is None or not all(
            math.isfinite(v) for v in (section.A, section.Ix, section.Iy, section.J,
                                       section.Ip)):
        raise ModelError(f"{call}: the section properties overflow the float range; "
                         "give the dimensions in m")
    return section


@dataclass(frozen=True)
class Material:
    """Isotropic material: moduli ``E``, ``G`` [Pa] and density ``rho`` [kg/m^3].

    Attributes
    ----------
    E : float
        Young's modulus [Pa].
    G : float
        Shear modulus [Pa].
    rho : float
        Density [kg/m^3].

    Examples
    --------
    >>> aluminium = Material(E=69e9, G=26.9e9, rho=2700.0)
    >>> round(aluminium.E / (2 * aluminium.G) - 1, 3)   # Poisson's ratio
    0.283
    """

    E: float
    G: float
    rho: float

    def __post_init__(self):
        for name in ("E", "G", "rho"):
            plausible(getattr(self, name), name, f"Material.{name}")


@dataclass(frozen=True)
class TipBody:
    """A rigid body attached at the distal end of a row.

    Attributes
    ----------
    mass : float
        Mass [kg].
    inertia : tuple of 3 float
        Principal moments ``(Ixx, Iyy, Izz)`` about the centre of mass, along the local
        link frame axes [kg m^2].
    com_offset : tuple of 3 float
        Centre of mass relative to the row's end point, in the local link frame [m].

    Examples
    --------
    >>> TipBody().is_empty
    True
    >>> tip = TipBody(mass=0.5, inertia=(1e-4, 1e-4, 2e-4), com_offset=(0.0, 0.0, 0.02))
    >>> tip.mass, tip.is_empty
    (0.5, False)
    """

    mass: float = 0.0
    inertia: tuple[float, ...] = (0.0, 0.0, 0.0)
    com_offset: tuple[float, ...] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        plausible(self.mass, "tip_mass", "TipBody.mass")
        for name, quantity in (("inertia", "tip_inertia"), ("com_offset", "offset")):
            values = getattr(self, name)
            if not isinstance(values, (tuple, list)) or len(values) != 3:
                raise ModelError(f"TipBody.{name} = {values!r}: must be 3 numbers")
            for k, v in enumerate(values):
                plausible(v, quantity, f"TipBody.{name}[{k}]")

    @property
    def is_empty(self) -> bool:
        """True when the body has neither mass nor inertia."""
        return self.mass == 0.0 and not any(self.inertia)


@dataclass(frozen=True)
class Link:
    """One DH row and what is attached to it.

    Attributes
    ----------
    theta : float
        Constant part of the joint angle θ_i [rad] (the joint variable adds to it).
    d : float
        Joint offset d_i along z_i [m].
    a : float
        Common normal a_{i-1} along x_{i-1} [m].
    alpha : float
        Twist α_{i-1} about x_{i-1} [rad].
    joint : str
        ``"revolute"`` (θ_i = theta + q_k) or ``"fixed"``.
    name : str
        Label used in messages and plots.
    section, material : Section, Material or None
        Both given for a flexible row, both ``None`` for a rigid one.
    section_angle : float
        Rotation of the section about the beam axis from the default local frame [rad].
    tip : TipBody
        Rigid body at the row's distal end.
    motor_inertia : float
        Rotor inertia reflected through the gear to joint i [kg m^2]. It enters M_qq of the
        rigid-body dynamics only: the transfer-matrix modes lock the joints at the motors.
    joint_stiffness : float or None
        Torsional spring at joint i between motor and outboard structure [Nm/rad]; ``None``
        for a rigid joint.

    Examples
    --------
    >>> link = load("problems/arm2link.toml").links[2]
    >>> link.name, link.joint, link.flexible, link.beam_along, link.length
    ('link1', 'revolute', True, 'a', 1.0)
    >>> round(link.mass_per_length, 4)   # rho * A [kg/m]
    0.0945
    >>> Link(d=0.3, joint="revolute").flexible
    False
    """

    theta: float = 0.0
    d: float = 0.0
    a: float = 0.0
    alpha: float = 0.0
    joint: str = "fixed"
    name: str = ""
    section: Section | None = None
    material: Material | None = None
    section_angle: float = 0.0
    tip: TipBody = field(default_factory=TipBody)
    motor_inertia: float = 0.0
    joint_stiffness: float | None = None

    def __post_init__(self):
        who = f"Link {self.name!r}" if self.name else "Link"
        for key in ("theta", "alpha", "section_angle"):
            plausible(getattr(self, key), "angle", f"{who}.{key}")
        for key in ("a", "d"):
            plausible(getattr(self, key), "offset", f"{who}.{key}")
        plausible(self.motor_inertia, "motor_inertia", f"{who}.motor_inertia")
        if self.joint_stiffness is not None:
            plausible(self.joint_stiffness, "joint_stiffness", f"{who}.joint_stiffness")
        if self.flexible:
            plausible(self.length, "beam_length", f"{who}.length")

    @property
    def flexible(self) -> bool:
        """True when the row carries a beam."""
        return self.section is not None

    @property
    def beam_along(self) -> str | None:
        """``"a"`` or ``"d"`` for a flexible row (which translation the beam spans), else None."""
        if not self.flexible:
            return None
        return "a" if self.a != 0.0 else "d"

    @property
    def length(self) -> float:
        """Beam length [m] of a flexible row (0 for a rigid row)."""
        if not self.flexible:
            return 0.0
        return abs(self.a) if self.a != 0.0 else abs(self.d)

    @property
    def mass_per_length(self) -> float:
        """Distributed mass ρA [kg/m] (0 for a rigid row)."""
        return self.material.rho * self.section.A if self.flexible else 0.0


@dataclass(frozen=True)
class Robot:
    """A validated serial robot description.

    Attributes
    ----------
    links : tuple of Link
        The DH rows, base first.
    name : str
    gravity : numpy.ndarray
        Gravity vector in the base frame [m/s^2].
    damping_ratio : float
        Modal damping ratio applied to every flexible mode.
    source : str or None
        File the description was read from.
    joint_limits : tuple of (float, float) or None
        Per joint variable, in order: ``(low, high)`` of q_k [rad] with ``low < high``,
        or ``None`` for a joint that turns freely (a full turn). ``()`` (the default)
        means no joint is limited; it is normalised to one ``None`` per joint.

    Examples
    --------
    >>> robot = load("problems/arm2link.toml")
    >>> robot.n_joints, [link.name for link in robot.flexible_links]
    (3, ['link1', 'link2'])
    >>> robot.joint_limits
    (None, None, None)
    """

    links: tuple[Link, ...]
    name: str = "robot"
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    damping_ratio: float = 0.0
    source: str | None = None
    description: str = ""
    joint_limits: tuple[tuple[float, float] | None, ...] = ()

    def __post_init__(self):
        gravity = np.asarray(self.gravity, dtype=float)
        if gravity.shape != (3,):
            raise ModelError(f"Robot.gravity = {self.gravity!r}: must be 3 numbers [m/s^2]")
        for k, v in enumerate(gravity):
            plausible(float(v), "gravity", f"Robot.gravity[{k}]")
        number(self.damping_ratio, "Robot.damping_ratio", low=0.0, high=1.0, high_open=True)
        object.__setattr__(self, "joint_limits", _checked_limits(self.joint_limits,
                                                                 self.n_joints))

    @property
    def n_joints(self) -> int:
        """Number of joint variables (revolute rows)."""
        return sum(1 for link in self.links if link.joint == "revolute")

    @property
    def joint_rows(self) -> tuple[int, ...]:
        """Row index of every joint variable, in order."""
        return tuple(i for i, link in enumerate(self.links) if link.joint == "revolute")

    @property
    def flexible_links(self) -> tuple[Link, ...]:
        """The flexible rows, base first."""
        return tuple(link for link in self.links if link.flexible)

    def joint_angles(self, q: ArrayLike) -> np.ndarray:
        """DH angles θ_i of every row for joint variables ``q`` [rad].

        Parameters
        ----------
        q : array_like, shape (n_joints,)
            Joint variables [rad].

        Returns
        -------
        numpy.ndarray, shape (n_rows,)
            ``theta`` of each row plus the joint variable of the revolute rows [rad].

        Examples
        --------
        >>> robot = load("problems/arm2link.toml")
        >>> robot.joint_angles([0.1, 0.2, 0.3]).tolist()
        [0.1, 0.2, 0.3, 0.0]
        """
        q = self.check_q(q)
        theta = np.array([link.theta for link in self.links], dtype=float)
        theta[list(self.joint_rows)] += q
        return theta

    def within_limits(self, q: ArrayLike, what: str = "q") -> np.ndarray:
        """Return ``q`` (as :meth:`check_q`) or raise ModelError if a joint leaves its limits.

        Parameters
        ----------
        q : array_like, shape (n_joints,)
            Joint variables [rad].
        what : str
            What ``q`` is, for the message (e.g. ``"move 'move1' target qf"``).

        Returns
        -------
        numpy.ndarray, shape (n_joints,)

        Raises
        ------
        ModelError
            Naming the joint (1-based), its value and its limits (in degrees and rad).

        Examples
        --------
        >>> import dataclasses, math
        >>> robot = load("problems/arm2link.toml")
        >>> limited = dataclasses.replace(robot, joint_limits=(None, None, (-1.0, 1.0)))
        >>> limited.within_limits([3.0, 0.0, 0.5]).tolist()
        [3.0, 0.0, 0.5]
        >>> limited.within_limits([0.0, 0.0, 1.5], "move 'm' target qf")
        ...                                               # doctest: +ELLIPSIS
        Traceback (most recent call last):
            ...
        casflex.errors.ModelError: move 'm' target qf: q3 = 85.944 deg (1.5 rad) lies ...
        """
        q = self.check_q(q)
        for k, (value, limits) in enumerate(zip(q, self.joint_limits, strict=True)):
            if limits is not None and not limits[0] <= value <= limits[1]:
                low, high = np.degrees(limits)
                raise ModelError(
                    f"{what}: q{k + 1} = {math.degrees(value):.3f} deg ({value:.6g} rad) "
                    f"lies outside the joint limits [{low:.3f}, {high:.3f}] deg of robot "
                    f"'{self.name}'")
        return q

    def check_q(self, q: ArrayLike) -> np.ndarray:
        """Return ``q`` as a float array of length ``n_joints`` or raise ModelError.

        Parameters
        ----------
        q : array_like
            Joint variables [rad]; a scalar is accepted for a one-joint robot.

        Returns
        -------
        numpy.ndarray, shape (n_joints,)

        Raises
        ------
        ModelError
            Wrong length, or a non-finite value.

        Examples
        --------
        >>> robot = load("problems/arm2link.toml")
        >>> robot.check_q([0, 1, 2])
        array([0., 1., 2.])
        >>> robot.check_q([0.0, float("nan"), 0.0])
        Traceback (most recent call last):
            ...
        casflex.errors.ModelError: joint variables must be finite; got q = [0.0, nan, 0.0]
        """
        from casflex.errors import ModelError

        q = np.atleast_1d(np.asarray(q, dtype=float))
        if q.shape != (self.n_joints,):
            raise ModelError(
                f"robot '{self.name}' has {self.n_joints} joint variables; got q of shape "
                f"{q.shape}"
            )
        if not np.all(np.isfinite(q)):
            raise ModelError(f"joint variables must be finite; got q = {q.tolist()}")
        return q

    def frames(self, q: ArrayLike) -> np.ndarray:
        """Homogeneous transforms ``T_0i`` of every DH frame ``i = 1..n`` (n, 4, 4).

        Parameters
        ----------
        q : array_like, shape (n_joints,)
            Joint variables [rad].

        Returns
        -------
        numpy.ndarray, shape (n_rows, 4, 4)
            Base-to-frame transforms, one per DH row (positions in m).

        Examples
        --------
        >>> robot = load("problems/arm2link.toml")
        >>> robot.frames([0, 0, 0])[-1][:3, 3].round(6).tolist()   # tip of the L-shaped arm
        [1.0, 0.0, -1.0]
        """
        theta = self.joint_angles(q)
        out = np.empty((len(self.links), 4, 4))
        T = np.eye(4)
        for i, link in enumerate(self.links):
            T = T @ dh_transform(link.alpha, link.a, theta[i], link.d)
            out[i] = T
        return out

    def with_joint_stiffness(self, stiffness: Iterable[float | None]) -> Robot:
        """Return a copy with the joint stiffness of every revolute row replaced [Nm/rad].

        Parameters
        ----------
        stiffness : sequence of float or None
            One value per joint variable, in order [Nm/rad]; ``None`` makes a joint rigid.

        Returns
        -------
        Robot

        Examples
        --------
        >>> robot = load("problems/arm2link.toml")
        >>> soft = robot.with_joint_stiffness([None, 2000.0, 500.0])
        >>> [soft.links[row].joint_stiffness for row in soft.joint_rows]
        [None, 2000.0, 500.0]
        """
        stiffness = list(stiffness)
        links = list(self.links)
        for row, k in zip(self.joint_rows, stiffness, strict=True):
            links[row] = replace(links[row], joint_stiffness=k)
        return replace(self, links=tuple(links))


def _checked_limits(limits, n_joints):
    """Joint limits as one ``(low, high)`` [rad] or ``None`` per joint, validated."""
    limits = tuple(limits or ())
    if all(item is None for item in limits):
        return (None,) * n_joints  # nothing limited: fits any number of joints
    if len(limits) != n_joints:
        raise ModelError(f"Robot.joint_limits = {limits!r}: needs one (low, high) or None "
                         f"per joint variable ({n_joints})")
    out = []
    for k, item in enumerate(limits):
        if item is None:
            out.append(None)
            continue
        field_ = f"Robot.joint_limits[{k}]"
        if not isinstance(item, (tuple, list, np.ndarray)) or len(item) != 2:
            raise fail(field_, item, "must be (low, high) [rad] or None")
        low, high = (plausible(v, "angle", field_) for v in item)
        if not low < high:
            raise fail(field_, [low, high], "the lower limit must be < the upper limit")
        out.append((low, high))
    return tuple(out)


def dh_transform(alpha: float, a: float, theta: float, d: float) -> np.ndarray:
    """Modified-DH transform ``Rx(alpha) Tx(a) Rz(theta) Tz(d)`` as a 4x4 array.

    Parameters
    ----------
    alpha : float
        Twist α_{i-1} [rad].
    a : float
        Common normal a_{i-1} [m].
    theta : float
        Joint angle θ_i [rad].
    d : float
        Offset d_i [m].

    Examples
    --------
    >>> dh_transform(0.0, 1.0, 0.0, 0.0)[:3, 3].tolist()
    [1.0, 0.0, 0.0]
    """
    ca, sa = math.cos(alpha), math.sin(alpha)
    ct, st = math.cos(theta), math.sin(theta)
    return np.array(
        [
            [ct, -st, 0.0, a],
            [st * ca, ct * ca, -sa, -sa * d + 0.0],
            [st * sa, ct * sa, ca, ca * d + 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


# --------------------------------------------------------------------------- loading


def _read_section(r):
    shape = r.string("shape", choices={"rectangle", "tube", "explicit"})
    if shape is None:
        raise r.error("shape", None, "is required: 'rectangle', 'tube' or 'explicit'")
    if shape in ("rectangle", "tube"):
        keys = ("a", "b") if shape == "rectangle" else ("outer_diameter", "wall")
        dims = {k: r.number(k, required=True, positive=True, quantity="section_dimension")
                for k in keys}
        if shape == "tube" and dims["wall"] >= dims["outer_diameter"] / 2.0:
            raise r.error("wall", dims["wall"], "must be smaller than the outer radius "
                                                f"{dims['outer_diameter'] / 2.0} m")
        why = "beyond the float range; give the dimensions in m"
        try:
            section = getattr(Section, shape)(*dims.values())
        except ModelError as exc:
            section, why = None, f"outside their plausibility bounds ({exc})"
        if section is None or min(section.A, section.Ix, section.Iy, section.J,
                                  section.Ip) <= 0.0:
            # the dimension farthest from 1 m (in decades) over- or underflowed
            key = max(keys, key=lambda k: abs(math.log10(dims[k])))
            raise r.error(key, dims[key], f"gives section properties (A, I, J) {why}")
    else:
        vals = {k: r.number(k, required=True, positive=True,
                            quantity="section_area" if k == "A" else "section_moment")
                for k in ("A", "Ix", "Iy", "J")}
        ip = r.number("Ip", default=vals["Ix"] + vals["Iy"], positive=True,
                      quantity="section_moment")
        section = Section(A=vals["A"], Ix=vals["Ix"], Iy=vals["Iy"], J=vals["J"], Ip=ip)
    r.finish()
    return section


def _read_link(path, raw, index):
    r = TableReader(path, raw, f"link[{index}]")
    name = r.string("name", default=f"row{index + 1}")
    joint = r.string("joint", default="fixed", choices={"revolute", "fixed"})
    theta = r.number("theta", 0.0, angle=True, quantity="angle")
    d = r.number("d", 0.0, quantity="offset")
    a = r.number("a", 0.0, quantity="offset")
    alpha = r.number("alpha", 0.0, angle=True, quantity="angle")
    section_angle = r.number("section_angle", 0.0, angle=True, quantity="angle")
    motor_inertia = r.number("motor_inertia", 0.0, nonnegative=True, quantity="motor_inertia")
    joint_stiffness = r.number("joint_stiffness", None, positive=True,
                               quantity="joint_stiffness")
    if joint_stiffness is not None and joint != "revolute":
        raise r.error("joint_stiffness", joint_stiffness,
                      "a joint spring needs a revolute joint in this row")
    if motor_inertia and joint != "revolute":
        raise r.error("motor_inertia", motor_inertia,
                      "a motor inertia needs a revolute joint in this row")

    sec_r, mat_r = r.table_("section"), r.table_("material")
    section = material = None
    if (sec_r is None) != (mat_r is None):
        missing = "material" if mat_r is None else "section"
        raise r.error(missing, None,
                      "a flexible link needs both [link.section] and [link.material]")
    if sec_r is not None:
        section = _read_section(sec_r)
        material = Material(**{key: mat_r.number(key, required=True, positive=True,
                                                 quantity=key) for key in ("E", "G", "rho")})
        mat_r.finish()
        if a == 0.0 and d == 0.0:
            raise r.error("a", a, "a flexible link needs a non-zero length: set a or d (> 0)")
        if a != 0.0 and d != 0.0:
            raise r.error("d", d, "a flexible link must lie along a or along d, not both "
                                  f"(a = {a}); split it into two rows")
        if a < 0.0:
            raise r.error("a", a, "the length of a flexible link must be > 0")
        if d < 0.0:
            raise r.error("d", d, "the length of a flexible link must be > 0")
        key = "a" if a != 0.0 else "d"
        r.check_bound(key, r.table[key], abs(a or d), "beam_length")

    limits = None
    q_min = r.number("q_min", None, angle=True, quantity="angle")
    q_max = r.number("q_max", None, angle=True, quantity="angle")
    if (q_min is None) != (q_max is None):
        missing = "q_max" if q_max is None else "q_min"
        raise r.error(missing, None, "joint limits need both q_min and q_max")
    if q_min is not None:
        if joint != "revolute":
            raise r.error("q_min", r.table["q_min"], "joint limits need a revolute joint "
                                                     "in this row")
        if not q_min < q_max:
            raise r.error("q_max", r.table["q_max"],
                          f"must be > q_min ({q_min:.6g} rad = {math.degrees(q_min):.6g} deg)")
        limits = (q_min, q_max)

    tip = TipBody()
    tip_r = r.table_("tip")
    if tip_r is not None:
        mass = tip_r.number("mass", 0.0, nonnegative=True, quantity="tip_mass")
        inertia = tip_r.vector("inertia", 3, (0.0, 0.0, 0.0))
        if min(inertia) < 0.0:
            raise tip_r.error("inertia", list(inertia), "moments of inertia must be >= 0")
        for v in inertia:
            tip_r.check_bound("inertia", list(inertia), v, "tip_inertia")
        tip = TipBody(mass=mass, inertia=inertia,
                      com_offset=tip_r.vector("com_offset", 3, (0.0, 0.0, 0.0),
                                              quantity="offset"))
        tip_r.finish()
    r.finish()
    return Link(theta=theta, d=d, a=a, alpha=alpha, joint=joint, name=name, section=section,
                material=material, section_angle=section_angle, tip=tip,
                motor_inertia=motor_inertia, joint_stiffness=joint_stiffness), limits


def loads(text: str, path: str | os.PathLike[str] | None = None) -> Robot:
    """Read a robot description from TOML text (see :func:`load`).

    Parameters
    ----------
    text : str
        TOML text with ``[[link]]`` tables (see ``problems/README.md``).
    path : str or pathlib.Path, optional
        File name used in error messages and stored as ``Robot.source``.

    Returns
    -------
    Robot

    Raises
    ------
    ProblemFileError
        Naming file, field, value and rule for anything malformed.

    Examples
    --------
    >>> robot = loads('''
    ... name = "pendulum"
    ... [[link]]
    ... joint = "revolute"
    ... [[link]]
    ... a = 0.5
    ... tip = { mass = 1.0 }
    ... ''')
    >>> robot.name, robot.n_joints, robot.links[1].tip.mass
    ('pendulum', 1, 1.0)
    >>> try:
    ...     loads('link = [{joint = "prismatic"}]')
    ... except ProblemFileError as exc:
    ...     print(exc.field, "=", repr(exc.value), exc.rule)
    link[0].joint = 'prismatic' must be one of ['fixed', 'revolute']
    """
    data = parse_toml(text, path)
    return _from_dict(data, path)


def load(path: str | os.PathLike[str]) -> Robot:
    """Read and validate a robot description file.

    Parameters
    ----------
    path : str or pathlib.Path
        TOML file with ``[[link]]`` tables (see ``problems/README.md``).

    Returns
    -------
    Robot

    Raises
    ------
    ProblemFileError
        Naming file, field, value and rule for anything malformed.

    Examples
    --------
    >>> robot = load("problems/arm2link.toml")
    >>> robot.flexible_links[0].length
    1.0
    """
    return _from_dict(read_toml(path), path)


def _from_dict(data, path):
    r = TableReader(path, data, "")
    name = r.string("name", default=Path(path).stem if path else "robot")
    description = r.string("description", default="")
    gravity = np.array(r.vector("gravity", 3, (0.0, 0.0, -9.81), quantity="gravity"))
    damping = r.number("damping_ratio", 0.0, nonnegative=True)
    if damping >= 1.0:
        raise r.error("damping_ratio", damping, "must be < 1 (underdamped modes)")
    r.used.add("link")
    r.used.add("sensor")  # [[sensor]] tables are read and validated by casflex.sensors
    raw_links = data.get("link")
    if raw_links is None:
        raise r.error("link", None, "is required: at least one [[link]] table")
    if not isinstance(raw_links, list) or not all(isinstance(x, dict) for x in raw_links):
        raise r.error("link", raw_links, "must be an array of tables ([[link]])")
    r.finish()
    rows = [_read_link(path, raw, i) for i, raw in enumerate(raw_links)]
    links = tuple(link for link, _ in rows)
    if not any(link.joint == "revolute" for link in links):
        raise ProblemFileError(path, "link", len(links), "needs at least one revolute joint")
    limits = tuple(lim for link, lim in rows if link.joint == "revolute")
    return Robot(links=links, name=name, gravity=gravity, damping_ratio=damping,
                 source=None if path is None else str(path), description=description,
                 joint_limits=limits)
