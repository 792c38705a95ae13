"""12 × 12 transfer matrices of beams, rigid bodies, rotations and joint springs.

State vector
------------
casflex orders the state at a point of the structure by physical quantity,

    z = [u_x, u_y, u_z, θ_x, θ_y, θ_z, M_x, M_y, M_z, F_x, F_y, F_z],

displacement u [m], small rotation vector θ [rad], internal moment M [N m] and internal
force F [N], all in one frame. ``M`` and ``F`` are the resultants that the *outboard* part
of the structure exerts on the *inboard* part across the section. With this choice every
3-vector group transforms with the same 3 × 3 rotation, so a frame change is
``blockdiag(R, R, R, R)`` — the dissertation's eq. 56–58, whose state (eq. 14) groups the
same twelve quantities by axis instead (see :data:`DISSERTATION_ORDER`).

Beam field equations (local frame, z along the beam, Euler–Bernoulli, harmonic motion at
ω [rad/s])::

    u'  = θ × e_z + e_z F_z/(EA)       θ' = (M_x/(E I_x), M_y/(E I_y), M_z/(G J))
    M'  = −e_z × F − ω² ρ I_p θ_z e_z  F' = −ω² ρ A u

They split into the axial (eq. 16–23), torsional (eq. 24–26) and two bending blocks
(eq. 28–46); the closed forms below are their exact solutions.

All functions accept an array of ω and return stacked matrices of shape (N, 12, 12).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from casflex.robot import Material, Section

__all__ = [
    "DISSERTATION_ORDER",
    "beam_matrix",
    "beam_field",
    "point_body_matrix",
    "rigid_body_matrix",
    "offset_matrix",
    "rotation_matrix",
    "rotation_x",
    "rotation_y",
    "rotation_z",
    "joint_spring_matrix",
    "body_mass_matrix",
    "skew",
]

#: Indices into casflex's state that give the dissertation's eq. 14 order
#: ``[w_x, θ_x, M_x, F_x, w_y, θ_y, M_y, V_y, w_z, θ_z, M_z, F_z]``.
DISSERTATION_ORDER = np.array([0, 3, 6, 9, 1, 4, 7, 10, 2, 5, 8, 11])


def skew(v: ArrayLike) -> np.ndarray:
    """Cross-product matrix ``[v]×`` with ``[v]× w = v × w``.

    Parameters
    ----------
    v : array_like, shape (3,)
        The vector.

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        Skew-symmetric matrix.

    Examples
    --------
    >>> skew([0.0, 0.0, 1.0]) @ [1.0, 0.0, 0.0]
    array([0., 1., 0.])
    """
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _omega(omega):
    return np.atleast_1d(np.asarray(omega, dtype=float))


def beam_field(s: ArrayLike, omega: ArrayLike, EA: float, EIx: float, EIy: float, GJ: float,
               rho_A: float, rho_Ip: float) -> np.ndarray:
    """Field transfer matrix of a uniform beam over a length ``s``, in its local frame.

    Parameters
    ----------
    s : float or array_like
        Length(s) [m] from the beam's start; broadcast against ``omega``.
    omega : float or array_like
        Circular frequency [rad/s], > 0.
    EA, EIx, EIy, GJ : float
        Axial [N], bending about x and y [N m²] and torsional [N m²] stiffness.
    rho_A, rho_Ip : float
        Mass per length [kg/m] and torsional inertia per length [kg m].

    Returns
    -------
    numpy.ndarray
        Shape ``broadcast(s, omega).shape + (12, 12)``: ``z(s) = U z(0)``.

    Examples
    --------
    >>> U = beam_field(1.0, 10.0, 1e6, 1.0, 1.0, 1.0, 0.1, 1e-6)
    >>> U.shape
    (12, 12)
    """
    s, omega = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(omega, dtype=float))
    shape = s.shape
    s, omega = s.ravel(), omega.ravel()
    table = layout(float(EA), float(EIx), float(EIy), float(GJ), float(rho_A), float(rho_Ip))
    # values[j] holds quantity j for the two rows below; one gather places all 40 entries
    values = np.empty((10, 2, s.size))

    # axial (u_z' = F_z/EA, F_z' = -ω² ρA u_z) and torsion (θ_z' = M_z/GJ,
    # M_z' = -ω² ρIp θ_z), stacked as two rows
    stiff = table["stiff"]
    k = omega * table["wave"]
    np.cos(k * s, out=values[0])
    sn = np.sin(k * s)
    if np.all(k != 0.0):
        sinc = sn / k
    else:
        sinc = np.where(k == 0.0, s, sn / np.where(k == 0.0, 1.0, k))
    np.divide(sinc, stiff, out=values[1])
    np.multiply(-stiff * k, sn, out=values[2])

    # bending in the x–z (EIy) and y–z (EIx) planes, stacked as two rows: with
    # y = (w, dw, d2w, d3w), y(s) = K y(0), K_ab = λ^(a-b) F_(a-b) of the Krylov–Duncan
    # functions S, T, U, V
    lam = np.sqrt(omega) * table["bend"]  # λ⁴ = ω² ρA / EI
    x = lam * s
    ch, sh, co, si = np.cosh(x), np.sinh(x), np.cos(x), np.sin(x)
    S, T = 0.5 * (ch + co), 0.5 * (sh + si)
    U, V = 0.5 * (ch - co), 0.5 * (sh - si)
    values[3] = S
    if np.all(lam > 0.0):
        np.divide(T, lam, out=values[4])
        np.divide(U, lam**2, out=values[5])
        np.divide(V, lam**3, out=values[6])
    else:  # ω = 0: the static limits T/λ → s, U/λ² → s²/2, V/λ³ → s³/6
        small = lam == 0.0
        ls = np.where(small, 1.0, lam)
        values[4] = np.where(small, s, T / ls)
        values[5] = np.where(small, s**2 / 2.0, U / ls**2)
        values[6] = np.where(small, s**3 / 6.0, V / ls**3)
    np.multiply(lam, V, out=values[7])
    np.multiply(lam**2, U, out=values[8])
    np.multiply(lam**3, T, out=values[9])

    out = np.zeros((s.size, 144))
    out[:, table["flat"]] = (values.reshape(20, -1)[table["gather"]] * table["ratio"]).T
    return out.reshape(shape + (12, 12))


#: Krylov–Duncan block K_ab in terms of F = (S, T/λ, U/λ², V/λ³, λV, λ²U, λ³T)
_KRYLOV = np.array([0, 1, 2, 3, 4, 0, 1, 2, 5, 4, 0, 1, 6, 5, 4, 0])
#: state indices of (w, dw, d2w, d3w) and the factor mapping y to the state:
#: x–z plane: u_x = y0, θ_y = y1, M_y = EIy y2, F_x = -EIy y3
#: y–z plane: u_y = y0, θ_x = -y1, M_x = -EIx y2, F_y = -EIx y3
_BEND_XZ, _BEND_YZ = (0, 4, 7, 9), (1, 3, 6, 10)
_WAVE = ((2, 2), (2, 11), (11, 2), (11, 11), (5, 5), (5, 8), (8, 5), (8, 8))


@functools.lru_cache(maxsize=256)
def layout(EA, EIx, EIy, GJ, rho_A, rho_Ip):
    """Constants of one beam: flat indices of the 40 non-zero entries, the gather from
    the quantities computed by :func:`beam_field`, the bending sign ratios, the axial and
    torsional stiffness and wavenumber factors, the bending wavenumber factors."""
    signs = (np.array([1.0, 1.0, EIy, -EIy]), np.array([1.0, -1.0, -EIx, -EIx]))
    ratio = np.array([np.outer(sg, 1.0 / sg).ravel() for sg in signs])
    flat = [12 * r + c for r, c in _WAVE]
    for idx in (_BEND_XZ, _BEND_YZ):
        flat += [12 * idx[a] + idx[b] for a in range(4) for b in range(4)]
    # quantity j of row r sits at 2 j + r: wave rows (c, sinc/stiff, -stiff k sin, c),
    # bending rows F_KRYLOV with F = (S, T/λ, U/λ², V/λ³, λV, λ²U, λ³T) from j = 3
    gather = ([0, 2, 4, 0], [1, 3, 5, 1], 2 * (3 + _KRYLOV), 2 * (3 + _KRYLOV) + 1)
    return {
        "flat": np.array(flat),
        "gather": np.concatenate(gather),
        "ratio": np.concatenate([np.ones(8), ratio[0], ratio[1]])[:, None],
        "stiff": np.array([[EA], [GJ]]),
        "wave": np.sqrt(np.array([[rho_A / EA], [rho_Ip / GJ]])),
        "bend": (rho_A / np.array([[EIy], [EIx]])) ** 0.25,
    }


def beam_matrix(length: float, omega: ArrayLike, section: Section,
                material: Material) -> np.ndarray:
    """Transfer matrix of a uniform flexible link in its local frame (eq. 15–47).

    Parameters
    ----------
    length : float
        Beam length L [m].
    omega : float or array_like
        Circular frequency [rad/s].
    section : casflex.robot.Section
    material : casflex.robot.Material

    Returns
    -------
    numpy.ndarray
        (N, 12, 12) with N = ``len(omega)``.

    Examples
    --------
    >>> from casflex.robot import Section, Material
    >>> U = beam_matrix(1.0, [1.0, 2.0], Section.rectangle(0.005, 0.007),
    ...                 Material(69e9, 26.9e9, 2700.0))
    >>> U.shape
    (2, 12, 12)
    """
    E, G, rho = material.E, material.G, material.rho
    return beam_field(
        length, _omega(omega), E * section.A, E * section.Ix, E * section.Iy,
        G * section.J, rho * section.A, rho * section.Ip,
    )


def body_mass_matrix(mass: float, inertia: ArrayLike, com_offset: ArrayLike) -> np.ndarray:
    """6 × 6 rigid-body mass matrix about its attachment point, over ``[u, θ]``.

    Parameters
    ----------
    mass : float
        [kg].
    inertia : array_like
        3 principal moments ``(Ixx, Iyy, Izz)`` or a 3 × 3 tensor about the centre of
        mass [kg m²].
    com_offset : array_like
        Centre of mass relative to the attachment point [m].

    Examples
    --------
    >>> body_mass_matrix(2.0, [0, 0, 0], [0, 0, 0])[:3, :3].tolist()
    [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]
    """
    inertia = np.asarray(inertia, dtype=float)
    Ic = np.diag(inertia) if inertia.shape == (3,) else inertia
    C = skew(np.asarray(com_offset, dtype=float))
    # velocity of the centre of mass: u̇ + θ̇ × c = u̇ − [c]× θ̇
    return np.block([[mass * np.eye(3), -mass * C], [mass * C, Ic - mass * C @ C]])


def point_body_matrix(omega: ArrayLike, mass_matrix: ArrayLike) -> np.ndarray:
    """Transfer across a rigid body attached at a point (zero length).

    ``d`` is continuous and the internal forces jump by the inertia forces:
    ``f⁺ = f⁻ − ω² M d``.

    Parameters
    ----------
    omega : float or array_like
        [rad/s].
    mass_matrix : numpy.ndarray
        6 × 6 from :func:`body_mass_matrix`, in the frame of the state, or a stack
        (N, 6, 6) of one per frequency.

    Examples
    --------
    >>> float(point_body_matrix(1.0, body_mass_matrix(1.0, [0, 0, 0], [0, 0, 0]))[0, 9, 0])
    -1.0
    """
    w2 = _omega(omega) ** 2
    out = np.broadcast_to(np.eye(12), (w2.size, 12, 12)).copy()
    # M d gives [force; moment]; the state holds [M; F]
    M = np.broadcast_to(mass_matrix, (w2.size, 6, 6))
    out[:, 6:9, 0:6] = -w2[:, None, None] * M[:, 3:6]
    out[:, 9:12, 0:6] = -w2[:, None, None] * M[:, 0:3]
    return out


def offset_matrix(r: ArrayLike) -> np.ndarray:
    """Massless rigid connection from point A to point B = A + r (r in the state's frame [m]).

    ``u_B = u_A + θ × r``, ``θ_B = θ_A``, ``F_B = F_A``, ``M_B = M_A − r × F_A``.

    Parameters
    ----------
    r : array_like, shape (3,)
        Offset from A to B [m], in the state's frame.

    Returns
    -------
    numpy.ndarray, shape (12, 12)

    Examples
    --------
    >>> float(offset_matrix([0.0, 0.0, 1.0])[0, 4])   # u_x grows with θ_y along z
    1.0
    """
    R = skew(np.asarray(r, dtype=float))
    out = np.eye(12)
    out[0:3, 3:6] = -R
    out[6:9, 9:12] = -R
    return out


def rigid_body_matrix(omega: ArrayLike, mass: float, inertia: ArrayLike, com_offset: ArrayLike,
                      length: float) -> np.ndarray:
    """Rigid link of ``length`` along local z carrying a body (eq. 48–55, generalised).

    The body (mass, principal inertia about its centre of mass, centre of mass at
    ``com_offset`` from the link's start) rides on a massless rigid segment from z = 0 to
    z = ``length``. The dissertation's eq. 53–55 are the case ``com_offset = (0, 0, r)``.

    Parameters
    ----------
    omega : array_like, shape (N,)
        Frequencies [rad/s].
    mass : float
        Body mass [kg].
    inertia : array_like, shape (3,)
        Principal moments about the centre of mass, local axes [kg m^2].
    com_offset : array_like, shape (3,)
        Centre of mass from the link's start, local frame [m].
    length : float
        Length of the rigid segment along local z [m].

    Returns
    -------
    numpy.ndarray, shape (N, 12, 12)

    Examples
    --------
    >>> U = rigid_body_matrix([1.0], 1.0, [0, 0, 0], [0, 0, 0.5], 1.0)
    >>> U.shape
    (1, 12, 12)
    """
    M = body_mass_matrix(mass, inertia, com_offset)
    return offset_matrix([0.0, 0.0, length])[None] @ point_body_matrix(omega, M)


def rotation_matrix(R: ArrayLike) -> np.ndarray:
    """12 × 12 frame change ``blockdiag(R, R, R, R)``: components in frame A → frame B.

    ``R`` maps A-components to B-components (``v_B = R v_A``).

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation matrix.

    Returns
    -------
    numpy.ndarray, shape (12, 12)

    Examples
    --------
    >>> rotation_matrix(np.eye(3)).shape
    (12, 12)
    """
    out = np.zeros((12, 12))
    for b in range(0, 12, 3):  # the blocks set directly: np.kron costs ~20 µs here
        out[b : b + 3, b : b + 3] = R
    return out


def _rot(axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    if axis == 0:
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    if axis == 1:
        return np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])


def rotation_x(angle: float) -> np.ndarray:
    """Eq. 58: components in a frame rotated by ``angle`` [rad] about x (12 × 12).

    Parameters
    ----------
    angle : float
        Rotation of the new frame about x [rad].

    Returns
    -------
    numpy.ndarray, shape (12, 12)

    Examples
    --------
    >>> np.allclose(rotation_x(0.3) @ rotation_x(-0.3), np.eye(12))
    True
    """
    return rotation_matrix(_rot(0, angle))


def rotation_y(angle: float) -> np.ndarray:
    """Eq. 57: frame rotated by ``angle`` [rad] about y (12 × 12).

    Parameters
    ----------
    angle : float
        Rotation of the new frame about y [rad].

    Returns
    -------
    numpy.ndarray, shape (12, 12)

    Examples
    --------
    >>> np.allclose(rotation_y(0.3).T, rotation_y(-0.3))
    True
    """
    return rotation_matrix(_rot(1, angle))


def rotation_z(angle: float) -> np.ndarray:
    """Eq. 56: frame rotated by ``angle`` [rad] about z (12 × 12).

    Parameters
    ----------
    angle : float
        Rotation of the new frame about z [rad].

    Returns
    -------
    numpy.ndarray, shape (12, 12)

    Examples
    --------
    >>> float(rotation_z(np.pi / 2)[0, 1].round(12))
    1.0
    """
    return rotation_matrix(_rot(2, angle))


def joint_spring_matrix(stiffness: float, axis: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Torsional joint spring about ``axis`` (unit vector in the state's frame) [Nm/rad].

    The outboard side rotates relative to the inboard side by ``φ = (axis · M)/k``;
    every other quantity is continuous.

    Parameters
    ----------
    stiffness : float
        Spring stiffness k [Nm/rad], > 0.
    axis : array_like, shape (3,), optional
        Joint axis in the state's frame (normalised here); default z.

    Returns
    -------
    numpy.ndarray, shape (12, 12)

    Examples
    --------
    >>> float(joint_spring_matrix(100.0)[5, 8])   # θ_z jumps by M_z / k
    0.01
    """
    e = np.asarray(axis, dtype=float)
    e = e / np.linalg.norm(e)
    out = np.eye(12)
    out[3:6, 6:9] = np.outer(e, e) / stiffness
    return out
