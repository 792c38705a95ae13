"""Mass normalisation of transfer-matrix mode shapes (dissertation eq. 113–115).

The transfer-matrix method returns the natural modes of the whole structure at one
configuration with the joints locked at the motors, scaled to unit peak displacement
(:func:`casflex.tmm.modes`). The low-order model (:mod:`casflex.model`) needs them
*mass-normalised*, ``M_δδ = I``, so that ``K_δδ = Ω²`` (eq. 114–115) and the model varies
smoothly with the configuration.

Modal mass
----------
The kinetic energy of the structure moving in mode ``j`` with amplitude rate ``δ̇_j`` is
``½ δ̇_j² M_jj``; the modal mass matrix counts exactly the inertia the TMM field equations
carry (:mod:`casflex.tmm.elements`), so that modes of different frequencies are
orthogonal in it:

``M_jk = Σ_beams ∫_0^L (ρA u_j·u_k + ρI_p θ_zj θ_zk) ds + Σ_bodies x_jᵀ M_b x_k``

with ``u`` the displacement and ``θ_z`` the torsion of the beam's centre line (local
components; the dot product does not depend on the frame), ``x = [u, θ]`` the motion
of a tip body's attachment point and ``M_b`` its 6 × 6 mass matrix about that point
(mass, principal inertia about the centre of mass and the centre-of-mass offset, the
parallel-axis terms included). The rotary inertia of bending (``ρI_x``, ``ρI_y``) is
absent, as in the Euler–Bernoulli field equations of the TMM.

Motor inertias do not appear: the TMM locks the joints at the motors (a joint spring, if
present, sits between the motor and the outboard structure), so a rotor does not move in
any mode. The motors enter only ``M_qq`` of the rigid–flexible model.

Quadrature
----------
The integrands are evaluated *exactly* at any point of a beam by propagating the beam's
start state ``z(0) = [u, θ, M, F]`` (a sample of the shapes) with the beam's field
transfer matrix ``z(s) = U(s, ω) z(0)`` (:func:`local_state`), and integrated with
Gauss–Legendre quadrature (48 points per beam by default: the error is at round-off level
for the modes a low-order model keeps, λL ≲ 30). ``method="simpson"`` integrates the
stored samples instead (composite Simpson; with 51 samples the relative error of the
first modes is ~1e-7).

Double roots
------------
At a k-fold root the TMM returns an arbitrary basis of the null space. Within each such
group :func:`mass_normalize` applies Gram–Schmidt in the mass inner product
(``L⁻¹`` with ``G = L Lᵀ`` the group's block of the modal mass), which keeps the first
basis vector's direction and makes the group mass-orthonormal.
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.tmm import elements as el
from casflex.tmm.solve import MODE_FIELDS

if TYPE_CHECKING:
    from casflex.robot import Robot
    from casflex.tmm.solve import ModeShapes

__all__ = [
    "gauss_legendre",
    "local_state",
    "modal_mass_matrix",
    "modal_stiffness_matrix",
    "mass_normalize",
    "SHAPE_FIELDS",
]

#: ModeShapes fields indexed by mode first; mass_normalize transforms all of them
#: (the same tuple as :data:`casflex.tmm.solve.MODE_FIELDS`).
SHAPE_FIELDS = MODE_FIELDS

#: id of every live ModeShapes that :func:`mass_normalize` returned -> (weak reference,
#: quadrature): given one of them again with the same quadrature it returns it as it is
#: (normalising twice cost 4.4 ms a point on the 6-joint arm and moved nothing but the
#: last digits)
_NORMALIZED: dict[int, tuple] = {}


def _beam_link(robot, shapes, beam):
    nb = len(shapes.rows)
    if not 0 <= beam < nb:
        raise ModelError(f"beam index {beam} out of range: the shapes have {nb} beams")
    row = shapes.rows[beam]
    if row >= len(robot.links) or not robot.links[row].flexible:
        raise ModelError(f"shapes beam {beam} sits on row {row}, which is not a flexible row "
                         f"of robot '{robot.name}'")
    return robot.links[row]


def local_state(robot: Robot, shapes: ModeShapes, beam: int, s: ArrayLike) -> np.ndarray:
    """Exact local state ``[u, θ, M, F]`` of every mode at arc lengths ``s`` of one beam.

    The beam's start state (the first sample of the shapes) is propagated with the
    beam's field transfer matrix at each mode's frequency, so the result is exact (to
    round-off) at any ``s``, not an interpolation of the samples.

    Parameters
    ----------
    robot : casflex.robot.Robot
    shapes : casflex.tmm.ModeShapes
    beam : int
        Beam index into ``shapes.rows``.
    s : array_like
        Arc lengths from the beam's start [m], within ``[0, L]``.

    Returns
    -------
    numpy.ndarray
        (m, len(s), 12): ``u`` [m], ``θ`` [rad], ``M`` [N m], ``F`` [N] in the local beam
        frame, in the scaling of ``shapes``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> shapes = modes(robot, [0.0, 0.0, 0.5], count=2)
    >>> z = local_state(robot, shapes, 1, [0.0, 1.0])
    >>> bool(np.allclose(z[:, 1, :3], shapes.displacement[:, 1, -1]))
    True
    """
    link = _beam_link(robot, shapes, beam)
    s = np.atleast_1d(np.asarray(s, dtype=float))
    L = link.length
    if np.any(s < -1e-12 * L) or np.any(s > L * (1 + 1e-12)):
        raise ModelError(f"arc length s must lie in [0, {L}] m on row {shapes.rows[beam]}; "
                         f"got {s.min()}..{s.max()}")
    sec, mat = link.section, link.material
    z0 = np.concatenate([shapes.displacement[:, beam, 0], shapes.rotation[:, beam, 0],
                         shapes.moment[:, beam, 0], shapes.force[:, beam, 0]], axis=-1)
    omega = np.asarray(shapes.omega, dtype=float)
    U = el.beam_field(s[None, :], omega[:, None], mat.E * sec.A, mat.E * sec.Ix,
                      mat.E * sec.Iy, mat.G * sec.J, mat.rho * sec.A, mat.rho * sec.Ip)
    return np.einsum("mpij,mj->mpi", U, z0)


@functools.lru_cache(maxsize=32)
def _gauss_legendre(points):
    x, w = np.polynomial.legendre.leggauss(points)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def gauss_legendre(points: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [−1, 1], computed once per point count.

    ``numpy.polynomial.legendre.leggauss`` solves an eigenvalue problem on every call,
    which tabulations would repeat at every grid point; the arrays
    returned here are cached and read-only.

    Parameters
    ----------
    points : int
        Number of nodes (>= 1).

    Returns
    -------
    x, w : numpy.ndarray
        Nodes and weights.

    Examples
    --------
    >>> x, w = gauss_legendre(3)
    >>> x.round(6).tolist(), round(float(w.sum()), 12)
    ([-0.774597, 0.0, 0.774597], 2.0)
    """
    return _gauss_legendre(int(points))


def _quadrature(robot, shapes, beam, method, points):
    """Nodes [m], weights [m] and the local state (m, n, 12) for one beam."""
    link = _beam_link(robot, shapes, beam)
    L = link.length
    if method == "gauss":
        if points < 2:
            raise ModelError(f"Gauss quadrature needs at least 2 points; got {points}")
        x, w = gauss_legendre(int(points))
        s = 0.5 * L * (x + 1.0)
        return s, 0.5 * L * w, local_state(robot, shapes, beam, s)
    if method == "simpson":
        s = np.asarray(shapes.s[beam], dtype=float)
        if s.size < 3:
            raise ModelError(f"Simpson quadrature needs at least 3 samples; got {s.size}")
        # Simpson weights from integrating the unit vectors
        from scipy.integrate import simpson  # here: scipy.integrate costs an import ~0.5 s

        w = simpson(np.eye(s.size), x=s, axis=1)
        z = np.concatenate([shapes.displacement[:, beam], shapes.rotation[:, beam],
                            shapes.moment[:, beam], shapes.force[:, beam]], axis=-1)
        return s, w, z
    raise ModelError(f"quadrature method must be 'gauss' or 'simpson'; got {method!r}")


def _body_mass(robot, shapes):
    out = []
    for row in shapes.body_rows:
        tip = robot.links[row].tip
        out.append(el.body_mass_matrix(tip.mass, tip.inertia, tip.com_offset))
    return out


def _check_counts(robot, shapes):
    m = np.asarray(shapes.omega).size
    if shapes.displacement.shape[0] != m:
        raise ModelError(f"shapes hold {shapes.displacement.shape[0]} modes but "
                         f"{m} frequencies")
    if len(shapes.body_rows) != shapes.body_state_local.shape[1]:
        raise ModelError("shapes.body_rows does not match shapes.body_state_local")
    return m


def modal_mass_matrix(robot: Robot, shapes: ModeShapes, method: str = "gauss",
                      points: int = 48) -> np.ndarray:
    """Modal mass matrix of the sampled modes (see the module docstring).

    Parameters
    ----------
    robot : casflex.robot.Robot
        The robot the shapes were computed for (sections, materials, tip bodies).
    shapes : casflex.tmm.ModeShapes
    method : {"gauss", "simpson"}
        Gauss–Legendre on the exact fields (default) or Simpson on the stored samples.
    points : int
        Gauss points per beam (ignored by Simpson).

    Returns
    -------
    numpy.ndarray
        (m, m) symmetric modal mass matrix, in [kg] times the square of the shapes'
        unit (identity for mass-normalised shapes).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> shapes = mass_normalize(robot, modes(robot, [0.0, 0.0, 0.5], count=3))
    >>> bool(np.allclose(modal_mass_matrix(robot, shapes), np.eye(3), atol=1e-10))
    True
    """
    m = _check_counts(robot, shapes)
    M = np.zeros((m, m))
    for b in range(len(shapes.rows)):
        link = _beam_link(robot, shapes, b)
        mat, sec = link.material, link.section
        _, w, z = _quadrature(robot, shapes, b, method, points)
        u, tz = z[..., 0:3], z[..., 5]
        M += mat.rho * sec.A * np.einsum("p,jpa,kpa->jk", w, u, u)
        M += mat.rho * sec.Ip * np.einsum("p,jp,kp->jk", w, tz, tz)
    for i, Mb in enumerate(_body_mass(robot, shapes)):
        x = shapes.body_state_local[:, i]
        M += x @ Mb @ x.T
    return 0.5 * (M + M.T)


def modal_stiffness_matrix(robot: Robot, shapes: ModeShapes, method: str = "gauss",
                           points: int = 48) -> np.ndarray:
    """Modal stiffness matrix from the strain energy of the modes (eq. 98–99, 109).

    ``K_jk = Σ_beams ∫ (E I_y w_x,j'' w_x,k'' + E I_x w_y,j'' w_y,k'' + G J θ_z,j' θ_z,k'
    + E A ε_j ε_k) ds + Σ_springs k φ_j φ_k``, written with the internal resultants
    (``M_x²/EI_x + M_y²/EI_y + M_z²/GJ + F_z²/EA``). For mass-normalised modes it equals
    ``diag(ω²)`` — a check of the TMM's shapes against its frequencies.

    Parameters
    ----------
    robot, shapes, method, points
        As in :func:`modal_mass_matrix`.

    Returns
    -------
    numpy.ndarray
        (m, m) symmetric [N m times the square of the shapes' unit] (rad²/s² for
        mass-normalised shapes).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> shapes = mass_normalize(robot, modes(robot, [0.0, 0.0, 0.5], count=2))
    >>> K = modal_stiffness_matrix(robot, shapes)
    >>> bool(np.allclose(np.diag(K), shapes.omega**2, rtol=1e-8))
    True
    """
    m = _check_counts(robot, shapes)
    K = np.zeros((m, m))
    for b in range(len(shapes.rows)):
        link = _beam_link(robot, shapes, b)
        mat, sec = link.material, link.section
        flex = np.array([1.0 / (mat.E * sec.Ix), 1.0 / (mat.E * sec.Iy), 1.0 / (mat.G * sec.J)])
        _, w, z = _quadrature(robot, shapes, b, method, points)
        Mres, Fz = z[..., 6:9], z[..., 11]
        K += np.einsum("p,jpa,kpa,a->jk", w, Mres, Mres, flex)
        K += np.einsum("p,jp,kp->jk", w, Fz, Fz) / (mat.E * sec.A)
    for i, row in enumerate(shapes.spring_rows):
        phi = shapes.spring_rotation[:, i]
        K += robot.links[row].joint_stiffness * np.outer(phi, phi)
    return 0.5 * (K + K.T)


def _groups(shapes):
    """Index ranges of the frequency groups (a k-fold root is one group of k modes)."""
    omega = np.asarray(shapes.omega, dtype=float)
    mult = np.asarray(shapes.multiplicity, dtype=int)
    groups, j = [], 0
    while j < omega.size:
        k = max(1, int(mult[j]))
        k = min(k, omega.size - j)
        groups.append(range(j, j + k))
        j += k
    return groups


def mass_normalize(robot: Robot, shapes: ModeShapes, method: str = "gauss",
                   points: int = 48) -> ModeShapes:
    """Scale the modes so that the modal mass matrix is the identity (eq. 114).

    A simple mode is divided by the square root of its modal mass (its sign is kept);
    the modes of a k-fold root are mass-orthonormalised by Gram–Schmidt (module
    docstring). Every shape field (:data:`SHAPE_FIELDS`) is transformed alike, so
    moments, forces, slopes, curvatures, tip-body motions and spring rotations stay
    consistent with the displacements. Modes this function returned are given back as
    they are (same quadrature): normalising them again would only move the last digits.

    Parameters
    ----------
    robot : casflex.robot.Robot
    shapes : casflex.tmm.ModeShapes
        Modes of one configuration as returned by :func:`casflex.tmm.modes`.
    method, points
        Quadrature of the modal mass (see :func:`modal_mass_matrix`).

    Returns
    -------
    casflex.tmm.ModeShapes
        A copy whose shapes are in units of kg^-1/2 (displacements [m/√kg]): a modal
        amplitude δ_j then has units √kg·m and ``½ δ̇ᵀ δ̇`` is the kinetic energy.

    Raises
    ------
    ModelError
        If a mode has a non-positive modal mass.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> raw = modes(robot, [0.0, 0.0, 0.0], count=2)
    >>> normalized = mass_normalize(robot, raw)
    >>> bool(np.all(np.sign(normalized.displacement[:, 1, -1, :]) ==
    ...             np.sign(raw.displacement[:, 1, -1, :])))
    True
    """
    seen = _NORMALIZED.get(id(shapes))
    if seen is not None and seen[0]() is shapes and seen[1:] == (method, points):
        return shapes
    M = modal_mass_matrix(robot, shapes, method=method, points=points)
    m = M.shape[0]
    S = np.zeros((m, m))
    for g in _groups(shapes):
        idx = np.array(g)
        G = M[np.ix_(idx, idx)]
        try:
            Lc = np.linalg.cholesky(G)
        except np.linalg.LinAlgError as exc:
            raise ModelError(f"modal mass of modes {idx.tolist()} (ω = "
                             f"{np.asarray(shapes.omega)[idx].tolist()} rad/s) is not "
                             f"positive definite: {np.diag(G).tolist()}") from exc
        S[np.ix_(idx, idx)] = np.linalg.inv(Lc)
    new = {}
    for name in SHAPE_FIELDS:
        a = np.asarray(getattr(shapes, name))
        new[name] = np.tensordot(S, a, axes=(1, 0)) if a.shape[0] == m else a
    out = replace(shapes, **new)
    key = id(out)
    _NORMALIZED[key] = (weakref.ref(out, lambda _, key=key: _NORMALIZED.pop(key, None)),
                        method, points)
    return out
