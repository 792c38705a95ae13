"""Configuration-dependent quantities of the rigid–flexible model (dissertation eq. 63–95).

:func:`configuration_quantities` turns the mass-normalised TMM modes of one configuration
into every quantity :mod:`casflex.model` needs, as a dict of numpy arrays whose shapes
depend only on the robot, the mode count and the sensor points
(:func:`quantity_shapes`), so that a tabulation engine can evaluate it at every grid
point, stack the results and fit splines. It is a pure function of plain data (picklable,
importable in subprocesses).

Book-style link-local deflections
---------------------------------
The TMM modes give the *absolute* small displacement ``u(s)`` and rotation ``θ(s)`` of
every section of the locked structure. The model (like Book's recursive formulation)
writes the position of a point of flexible link ``b`` as

``p(s) = T_b(q, δ) · [s e_z + Σ_j δ_j w_j(s); 1]``

where ``T_b`` is the pose of the link's *base frame* (its local beam frame at ``s = 0``),
which moves with the joints and with the deflection of every link inboard of ``b``
through the end transforms ``E(δ)`` and the joint springs. Linearising the pose of the
base frame, ``T_b ≈ T_b0 (I + [[θ(0)×], u(0)]) `` (local components), the absolute
displacement of the point is, to first order,

``u(s) = u(0) + θ(0) × (s e_z) + w(s)``,

so the link-local deflection and rotation of mode ``j`` are

``w_j(s) = u_j(s) − u_j(0) − θ_j(0) × (s e_z)``,   ``ϑ_j(s) = θ_j(s) − θ_j(0)``

(local beam components; the general form is ``u(s) − u(0) − θ(0) × (r(s) − r(0))``).
The end values ``w_j(L)``, ``ϑ_j(L)`` define the end transform of the link,

``E_b(δ) = [[I + [Σ δ_j ϑ_j(L) ×], L e_z + Σ δ_j w_j(L)], [0, 1]]``,

and a joint spring adds the relative rotation ``φ = Σ δ_j φ_j`` about its joint axis
(``spring_rotation`` of the TMM). Composing these transforms reproduces the TMM's
absolute modes exactly to first order in δ, because the TMM propagates the state with
the same rules (``u_B = u_A + θ × r`` across rigid offsets, ``θ`` continuous except for
the spring rotation). This is checked by the tests: the kinetic energy of the model at
δ = 0 gives ``M_δδ = I``.

Pseudo-inertia integrals (eq. 73–82, 94)
----------------------------------------
A section of a beam at ``s`` (and a tip body at ``s = L``) is a small rigid body whose
frame in the link's base frame is ``L(s; δ) = L0(s) + Σ δ_j L_j(s)`` with

``L0(s) = [[I, s e_z], [0, 1]]``,   ``L_j(s) = [[[ϑ_j(s) ×], w_j(s)], [0, 0]]``,

and whose 4 × 4 pseudo-inertia about its frame origin is
``J = [[½ tr(I_c) 1 − I_c + m c cᵀ, m c], [m cᵀ, m]]`` (``I_c`` about the centre of mass,
``c`` the centre-of-mass offset). With ``F = T_b L`` the kinetic energy of the link is
``½ ∫ Tr(Ḟ J Ḟᵀ)`` (eq. 68–72), which needs the integrals

* ``C0 = ∫ L0 J L0ᵀ`` — constant, the rigid pseudo-inertia (eq. 81–82; here
  :func:`rigid_pseudo_inertias`);
* ``C1_j = ∫ L0 J L_jᵀ`` — eq. 78–79 (``C1 = 2 (C_ij + C*_ij)`` in the dissertation's
  notation, which carries a factor ½);
* ``C2_jk = ∫ L_j J L_kᵀ`` — eq. 75–76 (``2 (C_ijk + C*_ijk)``) with the torsional
  inertia P_ijk of eq. 73 and the rotary inertia of the tip body folded in through the
  rotational part of ``J``.

Per unit length a beam section has ``m = ρA``, ``c = 0`` and ``I_c = diag(0, 0, ρI_p)``:
translational mass and torsional inertia, exactly the inertia of the TMM field
equations (Euler–Bernoulli, no rotary inertia of bending), so that the model's modal
mass is the TMM's. The same convention makes a rigid link a slender rod with the
torsional inertia ``ρI_p L`` about its axis.

Keys of the returned dict
-------------------------
``m`` modes, ``nb`` flexible rows (beams, base first, the order of ``ModeShapes.rows``),
``ns`` joint springs (rows with ``joint_stiffness``), ``P`` sensor points. Shapes are
mass-normalised, so a mode shape has units kg^-1/2 (displacement m/√kg) and δ has √kg·m.

======================  ===============  ====================================================
key                     shape            meaning [unit]
======================  ===============  ====================================================
``omega``               (m,)             natural frequencies [rad/s]
``C1``                  (nb, m, 4, 4)    ``∫ L0 J L_jᵀ`` [kg^1/2 m]
``C2``                  (nb, m, m, 4, 4) ``∫ L_j J L_kᵀ`` [-]
``N``                   (nb, m, m)       ``tr C2[:3, :3]``: link-local part of the modal
                                         mass, eq. 94 [-]
``eps``                 (nb, m, 3)       ``ε_ij = ∫ (w_j + ϑ_j × c) dm``, eq. 97 [kg^1/2]
``end_u``               (nb, m, 3)       ``w_j(L)``, local end deflection [kg^-1/2 m]
``end_theta``           (nb, m, 3)       ``ϑ_j(L)``, local end rotation [kg^-1/2 rad]
``spring_phi``          (ns, m)          rotation of each joint spring [kg^-1/2 rad]
``sample_u``            (nb, S, m, 3)    ``w_j(s)`` at the rate samples of
                                         :func:`rate_samples` [kg^-1/2 m]
``sample_theta``        (nb, S, m, 3)    ``ϑ_j(s)`` there [kg^-1/2 rad]
``point_u``             (P, m, 3)        ``w_j(s)`` at the sensor points [kg^-1/2 m]
``point_theta``         (P, m, 3)        ``ϑ_j(s)`` at the sensor points [kg^-1/2 rad]
``point_curvature``     (P, m, 2)        ``w_x'', w_y''`` [kg^-1/2 / m]
``point_twist_rate``    (P, m)           ``θ_z'`` [kg^-1/2 rad/m]
``point_axial_strain``  (P, m)           ``w_z'`` [kg^-1/2]
======================  ===============  ====================================================

The ``sample_*`` keys (``S = RATE_SAMPLES + 1``: Gauss–Legendre points and the beam's
end) let the model differentiate the shapes inside a link along the shape joints
(``FlexibleModel(shape_rates=True)``: ``∫ Tr(L_j J ∂L_kᵀ/∂q)``).

All vectors are in the local beam frame of the link (``z`` along the beam, see
:mod:`casflex.robot`). The ``point_*`` keys are present only when ``points`` is given.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.normalize import gauss_legendre, local_state
from casflex.tmm.chain import build_chain

if TYPE_CHECKING:
    from casflex.robot import Link, Robot
    from casflex.tmm.solve import ModeShapes

__all__ = [
    "QUANTITY_KEYS",
    "POINT_KEYS",
    "configuration_quantities",
    "quantity_shapes",
    "RATE_KEYS",
    "RATE_SAMPLES",
    "rate_samples",
    "pseudo_inertia",
    "rigid_pseudo_inertias",
    "section_pseudo_inertia",
]

#: Keys of :func:`configuration_quantities` without sensor points.
QUANTITY_KEYS = ("omega", "C1", "C2", "N", "eps", "end_u", "end_theta", "spring_phi")
#: Keys of the shapes sampled inside each link (always computed; the model reads them only
#: with ``shape_rates=True``).
RATE_KEYS = ("sample_u", "sample_theta")
#: Gauss–Legendre points per beam of the ``sample_*`` keys (the end point comes on top).
RATE_SAMPLES = 16
#: Keys added when sensor points are requested.
POINT_KEYS = ("point_u", "point_theta", "point_curvature", "point_twist_rate",
              "point_axial_strain")


def _skew(v):
    """Cross-product matrices of the last axis (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def pseudo_inertia(mass: float, inertia: ArrayLike = (0.0, 0.0, 0.0),
                   com_offset: ArrayLike = (0.0, 0.0, 0.0)) -> np.ndarray:
    """4 × 4 pseudo-inertia ``∫ h hᵀ dm`` of a rigid body about a frame origin.

    Parameters
    ----------
    mass : float
        [kg].
    inertia : array_like
        Principal moments (3,) or tensor (3, 3) about the centre of mass, in the frame's
        axes [kg m²].
    com_offset : array_like
        Centre of mass in the frame [m].

    Returns
    -------
    numpy.ndarray
        ``[[½ tr(I_c) 1 − I_c + m c cᵀ, m c], [m cᵀ, m]]`` so that
        ``Tr(Ṫ J Ṫᵀ)`` is twice the kinetic energy of the body moving with the frame T.

    Examples
    --------
    >>> J = pseudo_inertia(2.0, (0.1, 0.2, 0.3), (0.0, 0.0, 1.0))
    >>> J[3, 3].item(), J[2, 3].item(), J[2, 2].item()
    (2.0, 2.0, 2.0)
    """
    I = np.asarray(inertia, dtype=float)
    I = np.diag(I) if I.shape == (3,) else I
    c = np.asarray(com_offset, dtype=float)
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(I) * np.eye(3) - I + mass * np.outer(c, c)
    J[:3, 3] = J[3, :3] = mass * c
    J[3, 3] = mass
    return J


def section_pseudo_inertia(link: Link) -> np.ndarray:
    """Pseudo-inertia per unit length of a beam section, ``diag(½ρI_p, ½ρI_p, −½ρI_p, ρA)``.

    Translational mass and torsional inertia only (module docstring) [kg/m, kg m].

    Parameters
    ----------
    link : casflex.robot.Link
        A flexible row.

    Returns
    -------
    numpy.ndarray, shape (4, 4)

    Raises
    ------
    ModelError
        The row is rigid.

    Examples
    --------
    >>> from casflex.robot import load
    >>> link = load("problems/arm2link.toml").links[2]
    >>> round(section_pseudo_inertia(link)[3, 3].item(), 5)   # ρA [kg/m]
    0.0945
    """
    if not link.flexible:
        raise ModelError(f"row '{link.name}' is not flexible: it has no section")
    rIp = link.material.rho * link.section.Ip
    return np.diag([0.5 * rIp, 0.5 * rIp, -0.5 * rIp, link.mass_per_length])


def rigid_pseudo_inertias(robot: Robot) -> list[tuple[str, int, np.ndarray]]:
    """Constant pseudo-inertias ``C0`` of every rigid piece of the robot (eq. 81–82).

    Parameters
    ----------
    robot : casflex.robot.Robot

    Returns
    -------
    list of (str, int, numpy.ndarray)
        ``(kind, row, J)``: ``kind = "beam"`` for a flexible row (its beam and tip body
        about the beam's base, in the local beam frame), ``"body"`` for the tip body of a
        rigid row (about the origin of DH frame ``row``, in that frame). Rows with neither
        are left out.

    Examples
    --------
    >>> from casflex.robot import load
    >>> [(k, r) for k, r, _ in rigid_pseudo_inertias(load("problems/arm2link.toml"))]
    [('beam', 2), ('beam', 3)]
    """
    out = []
    for row, link in enumerate(robot.links):
        if link.flexible:
            L = link.length
            Js = section_pseudo_inertia(link)
            rA = Js[3, 3]
            J = Js * L
            J[2, 2] += rA * L**3 / 3.0
            J[2, 3] = J[3, 2] = rA * L**2 / 2.0
            if not link.tip.is_empty:
                L0 = np.eye(4)
                L0[2, 3] = L
                J = J + L0 @ pseudo_inertia(link.tip.mass, link.tip.inertia,
                                            link.tip.com_offset) @ L0.T
            out.append(("beam", row, J))
        elif not link.tip.is_empty:
            out.append(("body", row, pseudo_inertia(link.tip.mass, link.tip.inertia,
                                                    link.tip.com_offset)))
    return out


def rate_samples(link: Link) -> tuple[np.ndarray, np.ndarray]:
    """Sample points of a beam and their pseudo-inertia weights (the ``sample_*`` keys).

    ``RATE_SAMPLES`` Gauss–Legendre points along the beam and its end, with the section's
    pseudo-inertia times the quadrature weight, and the tip body's at the end, so that
    ``Σ_p L_j(s_p) J_p L_k(s_p)ᵀ`` approximates ``C2_jk`` (module docstring).

    Parameters
    ----------
    link : casflex.robot.Link
        A flexible row.

    Returns
    -------
    s : numpy.ndarray, shape (RATE_SAMPLES + 1,)
        Arc lengths [m].
    J : numpy.ndarray, shape (RATE_SAMPLES + 1, 4, 4)
        Pseudo-inertia of each sample [kg, kg m, kg m²].

    Examples
    --------
    >>> from casflex.robot import load
    >>> link = load("problems/arm2link.toml").links[2]
    >>> s, J = rate_samples(link)
    >>> s.shape, bool(np.isclose(J[:, 3, 3].sum(), link.mass_per_length * link.length
    ...                          + link.tip.mass))
    ((17,), True)
    """
    L = link.length
    xg, wg = gauss_legendre(RATE_SAMPLES)
    s = np.r_[0.5 * L * (xg + 1.0), L]
    J = np.einsum("p,ab->pab", np.r_[0.5 * L * wg, 0.0], section_pseudo_inertia(link))
    if not link.tip.is_empty:
        J[-1] += pseudo_inertia(link.tip.mass, link.tip.inertia, link.tip.com_offset)
    return s, J


def quantity_shapes(robot: Robot, n_modes: int, n_points: int = 0) -> dict[str, tuple[int, ...]]:
    """Array shape of every key of :func:`configuration_quantities`.

    Parameters
    ----------
    robot : casflex.robot.Robot
    n_modes : int
    n_points : int
        Number of sensor points (0: no ``point_*`` keys).

    Returns
    -------
    dict of str to tuple

    Examples
    --------
    >>> from casflex.robot import load
    >>> quantity_shapes(load("problems/arm2link.toml"), 3)["C2"]
    (2, 3, 3, 4, 4)
    """
    m = int(n_modes)
    nb = sum(1 for link in robot.links if link.flexible)
    ns = sum(1 for link in robot.links if link.joint_stiffness is not None)
    out = {"omega": (m,), "C1": (nb, m, 4, 4), "C2": (nb, m, m, 4, 4), "N": (nb, m, m),
           "eps": (nb, m, 3), "end_u": (nb, m, 3), "end_theta": (nb, m, 3),
           "spring_phi": (ns, m), "sample_u": (nb, RATE_SAMPLES + 1, m, 3),
           "sample_theta": (nb, RATE_SAMPLES + 1, m, 3)}
    if n_points:
        P = int(n_points)
        out.update({"point_u": (P, m, 3), "point_theta": (P, m, 3),
                    "point_curvature": (P, m, 2), "point_twist_rate": (P, m),
                    "point_axial_strain": (P, m)})
    return out


def _check_shapes(robot, q, shapes):
    chain = build_chain(robot, robot.check_q(q))
    rows = tuple(chain.beam_rows)
    if tuple(shapes.rows) != rows:
        raise ModelError(f"shapes hold beams on rows {tuple(shapes.rows)}, robot "
                         f"'{robot.name}' has beams on rows {rows}")
    R = np.array([b.R for b in chain.beams]).reshape(-1, 3, 3)
    if not np.allclose(R, shapes.R, atol=1e-9):
        raise ModelError(f"shapes were not computed at q = {np.asarray(q).tolist()}: the "
                         "beam orientations differ")
    springs = tuple(e.row for e in chain.elements if e.kind == "spring")
    if tuple(shapes.spring_rows) != springs:
        raise ModelError(f"shapes hold springs on rows {tuple(shapes.spring_rows)}, robot "
                         f"has {springs}")


def _relative(z, s):
    """Link-local deflection and rotation (module docstring) from local states (m, p, 12)."""
    u0, th0 = z[:, :1, 0:3], z[:, :1, 3:6]
    r = np.zeros((s.size, 3))
    r[:, 2] = s
    w = z[..., 0:3] - u0 - np.cross(th0, r[None])
    th = z[..., 3:6] - th0
    return w, th


def configuration_quantities(robot: Robot, q: ArrayLike, shapes_normalized: ModeShapes,
                             points: Sequence[tuple[int, float]] | None = None,
                             quadrature_points: int = 48) -> dict[str, np.ndarray]:
    """Every configuration-dependent quantity of the model at one configuration.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        The joint variables the shapes were computed at [rad] (checked against the
        shapes' beam orientations).
    shapes_normalized : casflex.tmm.ModeShapes
        Mass-normalised modes (:func:`casflex.modal.normalize.mass_normalize`).
    points : sequence of (int, float), optional
        Sensor points ``(row, s)``: DH row of a flexible link and arc length from the
        beam's start [m].
    quadrature_points : int
        Gauss–Legendre points per beam for the integrals.

    Returns
    -------
    dict of str to numpy.ndarray
        Keys, shapes and units in the module docstring (:func:`quantity_shapes`).

    Raises
    ------
    ModelError
        Shapes not matching the robot or ``q``, a point on a rigid row or off the beam.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> from casflex.modal.normalize import mass_normalize
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, 0.5]
    >>> shapes = mass_normalize(robot, modes(robot, q, count=3))
    >>> Q = configuration_quantities(robot, q, shapes, points=[(3, 0.5)])
    >>> Q["C2"].shape, Q["point_curvature"].shape
    ((2, 3, 3, 4, 4), (1, 3, 2))
    """
    shapes = shapes_normalized
    _check_shapes(robot, q, shapes)
    omega = np.asarray(shapes.omega, dtype=float)
    m = omega.size
    nb = len(shapes.rows)
    xg, wg = gauss_legendre(int(quadrature_points))
    C1 = np.zeros((nb, m, 4, 4))
    C2 = np.zeros((nb, m, m, 4, 4))
    eps = np.zeros((nb, m, 3))
    end_u = np.zeros((nb, m, 3))
    end_th = np.zeros((nb, m, 3))
    sample_u = np.zeros((nb, RATE_SAMPLES + 1, m, 3))
    sample_th = np.zeros((nb, RATE_SAMPLES + 1, m, 3))
    for b, row in enumerate(shapes.rows):
        link = robot.links[row]
        L = link.length
        s = np.concatenate([0.5 * L * (xg + 1.0), [0.0, L]])
        wq = np.concatenate([0.5 * L * wg, [0.0, 0.0]])
        # the start point must come first for _relative
        order = np.r_[s.size - 2, np.arange(s.size - 2), s.size - 1]
        s, wq = s[order], wq[order]
        z = local_state(robot, shapes, b, s)
        w, th = _relative(z, s)
        Lj = np.zeros((m, s.size, 4, 4))
        Lj[..., :3, :3] = _skew(th)
        Lj[..., :3, 3] = w
        L0 = np.broadcast_to(np.eye(4), (s.size, 4, 4)).copy()
        L0[:, 2, 3] = s
        Jw = np.einsum("p,ab->pab", wq, section_pseudo_inertia(link))
        if not link.tip.is_empty:
            Jw[-1] += pseudo_inertia(link.tip.mass, link.tip.inertia, link.tip.com_offset)
        C1[b] = np.einsum("pab,pbc,jpdc->jad", L0, Jw, Lj)
        C2[b] = np.einsum("jpab,pbc,kpdc->jkad", Lj, Jw, Lj)
        eps[b] = C1[b][:, 3, :3]
        end_u[b], end_th[b] = w[:, -1], th[:, -1]
        sr = np.r_[0.0, rate_samples(link)[0]]
        w, th = _relative(local_state(robot, shapes, b, sr), sr)
        sample_u[b], sample_th[b] = np.swapaxes(w[:, 1:], 0, 1), np.swapaxes(th[:, 1:], 0, 1)
    out = {
        "omega": omega.copy(),
        "C1": C1,
        "C2": 0.5 * (C2 + np.swapaxes(np.swapaxes(C2, 1, 2), 3, 4)),
        "N": np.trace(C2[..., :3, :3], axis1=-2, axis2=-1),
        "eps": eps,
        "end_u": end_u,
        "end_theta": end_th,
        "spring_phi": np.asarray(shapes.spring_rotation, dtype=float).T.reshape(-1, m).copy(),
        "sample_u": sample_u,
        "sample_theta": sample_th,
    }
    if points:
        out.update(_point_values(robot, shapes, points))
    return out


def _point_values(robot, shapes, points):
    m = np.asarray(shapes.omega).size
    P = len(points)
    res = {"point_u": np.zeros((P, m, 3)), "point_theta": np.zeros((P, m, 3)),
           "point_curvature": np.zeros((P, m, 2)), "point_twist_rate": np.zeros((P, m)),
           "point_axial_strain": np.zeros((P, m))}
    for i, point in enumerate(points):
        try:
            row, s = int(point[0]), float(point[1])
        except (TypeError, ValueError, IndexError) as exc:
            raise ModelError(f"sensor point {i} must be (row, s); got {point!r}") from exc
        if row not in shapes.rows:
            raise ModelError(f"sensor point {i}: row {row} carries no flexible link; flexible "
                             f"rows are {tuple(shapes.rows)}")
        b = shapes.rows.index(row)
        link = robot.links[row]
        z = local_state(robot, shapes, b, [0.0, s])
        w, th = _relative(z, np.array([0.0, s]))
        sec, mat = link.section, link.material
        res["point_u"][i] = w[:, 1]
        res["point_theta"][i] = th[:, 1]
        res["point_curvature"][i, :, 0] = z[:, 1, 7] / (mat.E * sec.Iy)
        res["point_curvature"][i, :, 1] = -z[:, 1, 6] / (mat.E * sec.Ix)
        res["point_twist_rate"][i] = z[:, 1, 8] / (mat.G * sec.J)
        res["point_axial_strain"][i] = z[:, 1, 11] / (mat.E * sec.A)
    return res
