"""Assembly of a robot at one configuration into a chain of transfer elements (§3.2.4).

The dissertation assembles the system matrix with a loop over the DH rows that inserts
12 × 12 rotations between beams (the GetSystemMatrix algorithm). casflex does the same
walk but keeps every element's pose in the base frame: each element knows the rotation
``R`` from its local frame to the base frame and its start point, and its transfer matrix
is applied to states written in base-frame components, ``blockdiag(R)·U_local·blockdiag(R)ᵀ``.
That removes the special cases of the published loop (the ±π/2 rotations that turn a DH
``x`` or ``z`` axis into the beam axis) while giving the same product.

Walk of row i (``Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i) Tz(d_i)``):

1. rotate by α_{i-1} about x;
2. translate by a_{i-1} along x — a beam if the row is flexible along ``a`` (local z = x,
   local y = the axis of joint i), else a rigid offset; an ``a`` beam's tip body sits
   here, at the beam's end, inboard of joint i;
3. rotate by θ_i about z, with the joint spring of row i (if any) about that axis;
4. translate by d_i along z — a beam if flexible along ``d`` (local frame = DH frame i),
   else a rigid offset; the tip body of any other row sits at the end of this step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from casflex.tmm import elements as el

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = ["Element", "Chain", "build_chain"]


@dataclass(frozen=True)
class Element:
    """One transfer element posed in the base frame.

    Attributes
    ----------
    kind : str
        ``"beam"``, ``"body"``, ``"offset"`` or ``"spring"``.
    R : numpy.ndarray
        3 × 3 rotation from the element's local frame to the base frame.
    start : numpy.ndarray
        Start point in the base frame [m].
    row : int
        Index of the DH row the element belongs to.
    params : dict
        Kind-specific data: beam — ``length``, ``section``, ``material``; body — ``mass``,
        ``inertia``, ``com_offset`` (local); offset — ``r`` (base frame); spring —
        ``stiffness``, ``axis`` (base frame).
    link : str
        Name of the robot link (DH row) the element belongs to.

    Examples
    --------
    >>> from casflex.robot import load
    >>> beam = build_chain(load("problems/arm2link.toml"), [0.0, 0.0, 0.0]).elements[1]
    >>> beam.kind, beam.row, beam.params["length"]
    ('beam', 3, 1.0)
    >>> beam.start.tolist(), beam.end.round(6).tolist()   # hangs down from the elbow
    ([1.0, 0.0, 0.0], [1.0, 0.0, -1.0])
    >>> beam.rotation12.shape
    (12, 12)
    """

    kind: str
    R: np.ndarray
    start: np.ndarray
    row: int
    params: dict[str, Any] = field(default_factory=dict)
    link: str = ""

    @property
    def label(self) -> str:
        """Where the element sits, for messages: kind, link name and 1-based DH row.

        Examples
        --------
        >>> from casflex.robot import load
        >>> build_chain(load("problems/arm2link.toml"), [0.0, 0.0, 0.0]).elements[0].label
        "beam of link 'link1' (DH row 3)"
        """
        name = f" of link '{self.link}'" if self.link else ""
        return f"{self.kind}{name} (DH row {self.row + 1})"

    @cached_property
    def rotation12(self) -> np.ndarray:
        """``blockdiag(R, R, R, R)``: local state components to base-frame components."""
        return el.rotation_matrix(self.R)

    @property
    def end(self) -> np.ndarray:
        """End point in the base frame [m]."""
        if self.kind == "beam":
            return self.start + self.R[:, 2] * self.params["length"]
        if self.kind == "offset":
            return self.start + self.params["r"]
        return self.start


@dataclass(frozen=True)
class Chain:
    """The structure of a robot at configuration ``q``, base (clamped) to tip (free).

    Attributes
    ----------
    elements : tuple of Element
    q : numpy.ndarray
        Joint variables [rad].
    beam_rows : tuple of int
        DH row index of each beam element, base first.

    Examples
    --------
    >>> from casflex.robot import load
    >>> chain = build_chain(load("problems/arm2link.toml"), [0.0, 0.5, 0.0])
    >>> chain.beam_rows, len(chain.beams), chain.q.tolist()
    ((2, 3), 2, [0.0, 0.5, 0.0])
    """

    elements: tuple[Element, ...]
    q: np.ndarray
    beam_rows: tuple[int, ...]

    @property
    def beams(self) -> tuple[Element, ...]:
        """The beam elements, base first."""
        return tuple(e for e in self.elements if e.kind == "beam")


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def build_chain(robot: Robot, q: ArrayLike) -> Chain:
    """Pose every element of ``robot`` at joint variables ``q``.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Joint variables [rad], one per revolute row.

    Returns
    -------
    Chain

    Examples
    --------
    >>> from casflex.robot import load
    >>> chain = build_chain(load("problems/arm2link.toml"), [0.0, 0.0, 0.0])
    >>> [e.kind for e in chain.elements]
    ['beam', 'beam']
    """
    theta = robot.joint_angles(q)
    R = np.eye(3)
    p = np.zeros(3)
    out = []

    def add_body(link, row, R_local):
        tip = link.tip
        if not tip.is_empty:
            out.append(Element("body", R_local, p.copy(), row, {
                "mass": tip.mass, "inertia": np.array(tip.inertia),
                "com_offset": np.array(tip.com_offset)}, link.name))

    for row, link in enumerate(robot.links):
        R = R @ _rx(link.alpha)
        if link.beam_along == "a":
            # local z along x_{i-1}, local y along the axis of joint i (current z)
            Rl = np.column_stack([R[:, 1], R[:, 2], R[:, 0]]) @ _rz(link.section_angle)
            out.append(Element("beam", Rl, p.copy(), row, {
                "length": link.length, "section": link.section, "material": link.material},
                link.name))
            p = p + R[:, 0] * link.a
            add_body(link, row, Rl)
        elif link.a != 0.0:
            out.append(Element("offset", R.copy(), p.copy(), row, {"r": R[:, 0] * link.a},
                               link.name))
            p = p + R[:, 0] * link.a
        R = R @ _rz(theta[row])
        if link.joint_stiffness is not None:
            out.append(Element("spring", R.copy(), p.copy(), row, {
                "stiffness": link.joint_stiffness, "axis": R[:, 2].copy()}, link.name))
        if link.beam_along == "d":
            Rl = R @ _rz(link.section_angle)
            out.append(Element("beam", Rl, p.copy(), row, {
                "length": link.length, "section": link.section, "material": link.material},
                link.name))
            p = p + R[:, 2] * link.d
            add_body(link, row, Rl)
        else:
            if link.d != 0.0:
                out.append(Element("offset", R.copy(), p.copy(), row, {"r": R[:, 2] * link.d},
                                   link.name))
                p = p + R[:, 2] * link.d
            if link.beam_along is None:
                add_body(link, row, R.copy())
    beam_rows = tuple(e.row for e in out if e.kind == "beam")
    return Chain(elements=tuple(out), q=np.asarray(q, dtype=float), beam_rows=beam_rows)


def body_mass_global(element: Element) -> np.ndarray:
    """6 × 6 mass matrix of a ``body`` element about its attachment point, base frame."""
    P = element.params
    M_local = el.body_mass_matrix(P["mass"], P["inertia"], P["com_offset"])
    Rb = np.kron(np.eye(2), element.R)
    return Rb @ M_local @ Rb.T
