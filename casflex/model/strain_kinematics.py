"""Geometrically exact kinematics of the flexible links in strain coordinates (issue 19).

``FlexibleModel(kinematics="exact")`` keeps the modal amplitudes δ and the modal stiffness
``K = diag(ω²)`` of the default model, but rebuilds every flexible link from the modes'
strains instead of adding the modes' displacements to the undeformed line. A mode's
link-local rotation ``ϑ_j(s)`` has the derivative ``κ_j(s)``, the section's material
curvature (bending about the local x and y axes and the twist rate), and its axial
deflection the axial strain ``ε_j(s) = w_j,z'``. The amplitudes scale these strains,
``κ(s) = Σ δ_j κ_j(s)``, ``ε(s) = Σ δ_j ε_j(s)``, and the rod is the exact solution of
``Λ' = Λ [κ]×``, ``r' = (1 + ε) Λ e_z`` from the link's base frame. The strain energy of
a Kirchhoff rod is ``½ ∫ κᵀ D κ + EA ε² ds``, exactly ``½ δᵀ K δ`` for mass-normalised
eigenmodes: every nonlinearity of large deflections sits in the positions, none is
dropped. To first order in δ the rod is the default model's (``r = s e_z + Σ δ_j w_j``,
``Λ = I + [Σ δ_j ϑ_j]×``). The idea and its independent check against a 3-D
geometrically exact beam model are in ``tests/exact_ritz.py`` (session 8, issue 19).

Strains from the tabulated shapes
---------------------------------
No new table is needed. The tables already hold ``w_j`` and ``ϑ_j`` at the 16
Gauss–Legendre points of each link and at its end (``sample_u``, ``sample_theta``,
:func:`casflex.modal.integrals.rate_samples`), and both vanish at the link's base. The
polynomial through these 18 values (degree 17, nodes clustered at the ends as
Gauss–Legendre's are, so the interpolation is well conditioned) is a fixed linear map of
the tabulated values; it gives ``w_j`` and ``ϑ_j`` at any arc length, with an error that
falls faster than any power of the degree for the smooth (trigonometric and hyperbolic)
mode shapes of a uniform beam (:func:`node_interpolation`; measured in the tests against
the TMM's own local state).

The rod at the quadrature nodes
-------------------------------
The rod is walked through the nodes ``0 = s_0 < s_1 < … < s_K = L``: the
``ROD_POINTS`` Gauss–Legendre points of the link and its two ends. By default these are
the tables' own 16 sample points, so the polynomial is only a check (``P`` is the
identity; other counts interpolate). Why 16 suffice: Gauss–Legendre with 16 points
integrates polynomials of degree 31 exactly, and the mass matrix at δ = 0 equals the
default model's (48-point integrals ``C1``, ``C2``) to 5e-14 with five modes; the rod's
nonlinear part (below, error O(h²)) moves the static tip 254 mm across the plane of the
Table 8 arm by 0.001 % of the deflection between 16 and 48 points (+0.064 % and +0.063 %
against the 3-D reference, ``tests/model/test_spatial_static.py``). A step from ``s_k``
to ``s_{k+1}`` turns the section by the increment ``Δϑ = ϑ(s_{k+1}) − ϑ(s_k)`` (``∫ κ
ds`` over the step, exact to first order) in two Cayley half-turns, and advances it by
the step's local displacement read in the mid-step frame::

    R_mid = R_k cay(½Δϑ),   r_{k+1} = r_k + R_mid (h e_z + Δw − ϑ_mid × h e_z),
    R_{k+1} = R_mid cay(½Δϑ)

(``Δw = w(s_{k+1}) − w(s_k)``, ``ϑ_mid = ½(ϑ(s_k) + ϑ(s_{k+1}))``). To first order in δ
every node lands exactly on ``s_k e_z + w(s_k)`` with rotation ``I + [ϑ(s_k)]×``: the
default model's kinematics are reproduced exactly. The nonlinear part is a second-order
(midpoint) integrator of the rod, error O(h²).

Mass and the tip body
---------------------
A node carries the section's mass ``ρA w_k`` and torsional inertia ``ρI_p w_k`` (``w_k``
the Gauss–Legendre weight; the sections have no rotary inertia of bending, as in the TMM
field equations and :func:`~casflex.modal.integrals.section_pseudo_inertia`). The tip
body is a rigid body on the end frame ``(R_K, r_K)``, which is also the link's end
transform, so the outboard links and the tool point ride on the exact end. Mass matrix,
bias forces and gravity follow from these point masses exactly in δ, without
truncation (:func:`point_mass_terms`); ``K`` is the default model's.

The modal block
---------------
With these kinematics the model's modal mass at δ = 0 is what the rods compute from
the interpolated tables: the identity at the grid points (5e-14), 1e-4 off between the
points of the Table 8 arm's 1.5° table (the cubic splines' error on the shapes). The
default model forces it to the identity (``modal_mass="first_order"``); here the
default is ``"kinematic"``, the rods' own block, because the correction would double the
cost of the bias forces (it needs the Christoffel symbols of ``M_δδ(q, 0)``), for a
frequency error of 5e-5. ``modal_mass="first_order"`` is accepted and applies the
correction.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.errors import ModelError
from casflex.modal.integrals import RATE_SAMPLES, pseudo_inertia, rate_samples
from casflex.modal.normalize import gauss_legendre

if TYPE_CHECKING:
    from casflex.robot import Link

__all__ = ["KINEMATICS", "ROD_POINTS", "node_interpolation", "point_mass_terms", "rod_nodes",
           "rod_point"]

#: The kinematics a :class:`~casflex.model.equations.FlexibleModel` can use: the modal
#: displacements added to the undeformed links (default) or the rods rebuilt from the
#: modal strains.
KINEMATICS = ("truncated", "exact")
#: Gauss–Legendre points per flexible link that carry its mass in the exact kinematics
#: (the tabulated samples' own points: module docstring).
ROD_POINTS = RATE_SAMPLES


def _barycentric(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Lagrange interpolation matrix ``P[i, k] = ℓ_k(x_i)`` through ``nodes``."""
    diff = nodes[:, None] - nodes[None, :]
    np.fill_diagonal(diff, 1.0)
    weights = 1.0 / np.prod(diff, axis=1)
    P = np.zeros((x.size, nodes.size))
    for i, xi in enumerate(x):
        d = xi - nodes
        hit = np.flatnonzero(np.abs(d) < 1e-14 * max(1.0, abs(xi)))
        if hit.size:
            P[i, hit[0]] = 1.0
        else:
            c = weights / d
            P[i] = c / c.sum()
    return P


def node_interpolation(link: Link, points: int = ROD_POINTS
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rod's nodes along a flexible link and the map from the tabulated samples.

    Parameters
    ----------
    link : casflex.robot.Link
        A flexible row.
    points : int
        Gauss–Legendre points that carry the link's mass.

    Returns
    -------
    s : numpy.ndarray, shape (points + 2,)
        Arc lengths of the nodes: the base, the Gauss–Legendre points, the end [m].
    weights : numpy.ndarray, shape (points + 2,)
        Quadrature weights [m] (zero at the two ends).
    P : numpy.ndarray, shape (points + 2, RATE_SAMPLES + 1)
        ``f(s) = P @ f(s_samples)`` for ``f`` vanishing at the base (``w_j``, ``ϑ_j``),
        ``s_samples`` the points of :func:`~casflex.modal.integrals.rate_samples`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> link = load("problems/arm2link.toml").links[2]
    >>> s, w, P = node_interpolation(link)
    >>> s.shape, P.shape, bool(np.isclose(w.sum(), link.length))
    ((18,), (18, 17), True)
    >>> samples = rate_samples(link)[0]
    >>> bool(np.allclose(P @ np.sin(samples), np.sin(s)))   # sin vanishes at the base
    True
    """
    if not link.flexible:
        raise ModelError(f"row '{link.name}' is not flexible: it has no rod")
    if points < 2:
        raise ModelError(f"the exact kinematics need >= 2 rod points; got {points}")
    L = link.length
    xg, wg = gauss_legendre(int(points))
    s = np.r_[0.0, 0.5 * L * (xg + 1.0), L]
    weights = np.r_[0.0, 0.5 * L * wg, 0.0]
    samples = np.r_[0.0, rate_samples(link)[0]]
    P = _barycentric(samples / L, s / L)[:, 1:]  # the base value is zero
    return s, weights, P


def _skew(v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]),
                      ca.horzcat(-v[1], v[0], 0))


def _cayley(v):
    """Rotation matrix of the Cayley map of ``v`` (a turn by ``2 atan(|v|/2)`` about v)."""
    a = _skew(0.5 * v)
    return ca.SX.eye(3) + 2.0 / (1.0 + 0.25 * ca.dot(v, v)) * (a + a @ a)


def _sampled(values, beam, m, delta):
    """``Σ_j δ_j f_j(s_p)`` at the sample points of ``beam``, (S, 3) SX, from the flat
    C-order quantity ``values`` of shape (nb, S, m, 3)."""
    S = RATE_SAMPLES + 1
    rows = []
    for p in range(S):
        out = ca.SX.zeros(3)
        for j in range(m):
            k = ((beam * S + p) * m + j) * 3
            out += delta[j] * values[k:k + 3]
        rows.append(out.T)
    return ca.vertcat(*rows)


def rod_nodes(link: Link, beam: int, sample_u: ca.SX, sample_theta: ca.SX, delta: ca.SX,
              points: int | None = None) -> dict:
    """The exact rod of one flexible link in its local beam frame (module docstring).

    Parameters
    ----------
    link : casflex.robot.Link
        The flexible row.
    beam : int
        Its index among the flexible rows (base first).
    sample_u, sample_theta : casadi.SX
        The tabulated ``sample_u``/``sample_theta`` quantities, flattened in C order
        ([kg^-1/2 m], [kg^-1/2 rad]).
    delta : casadi.SX
        Modal amplitudes [√kg m].
    points : int, optional
        Gauss–Legendre points that carry the link's mass (default ``ROD_POINTS``).

    Returns
    -------
    dict
        ``R`` and ``r``: per node the section's rotation (3 × 3) and position (3,) [m]
        in the link's base frame, base first, end last; ``s`` and ``weights`` as
        :func:`node_interpolation`; ``w`` and ``theta``: per node the superposed
        link-local deflection [m] and rotation [rad] of the modes (3,) the walk used;
        ``end``: the 4 × 4 end transform; ``tip``: the tip body's pseudo-inertia
        about the end frame (None without a tip body); ``rhoA`` [kg/m] and ``rhoIp``
        [kg m].

    Examples
    --------
    >>> import casadi as ca
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> values = PointwiseProvider(robot, [0, 0, 0.5], count=2)
    >>> d = ca.SX.sym("d", 2)
    >>> u, th = (values.function(k)([]) for k in ("sample_u", "sample_theta"))
    >>> rod = rod_nodes(robot.links[2], 0, ca.SX(u), ca.SX(th), d)
    >>> end = ca.Function("end", [d], [rod["end"]])
    >>> end([0, 0]).full()[2, 3].item() == robot.links[2].length
    True
    """
    m = delta.numel()
    s, weights, P = node_interpolation(link, ROD_POINTS if points is None else points)
    W = ca.DM(P) @ _sampled(sample_u, beam, m, delta)  # (K+1, 3): w(s_k)
    TH = ca.DM(P) @ _sampled(sample_theta, beam, m, delta)  # ϑ(s_k)
    R, r = ca.SX.eye(3), ca.SX.zeros(3)
    Rs, rs = [R], [r]
    ws, ths = [W[0, :].T], [TH[0, :].T]
    for k in range(s.size - 1):
        ws.append(W[k + 1, :].T)
        ths.append(TH[k + 1, :].T)
        R, r = _rod_step(R, r, float(s[k + 1] - s[k]), ws[k + 1] - ws[k], ths[k], ths[k + 1])
        Rs.append(R)
        rs.append(r)
    end = ca.SX.eye(4)
    end[:3, :3], end[:3, 3] = R, r
    tip = None if link.tip.is_empty else pseudo_inertia(
        link.tip.mass, link.tip.inertia, link.tip.com_offset)
    return {"R": Rs, "r": rs, "s": s, "w": ws, "theta": ths, "weights": weights,
            "end": end, "tip": tip,
            "rhoA": link.mass_per_length,
            "rhoIp": link.material.rho * link.section.Ip}


def _rod_step(R, r, h, dw, th0, th1):
    """One step of the rod walk (module docstring): from the section ``(R, r)`` at ``s``
    to ``s + h``, with the modes' deflection increment ``dw`` and rotations ``th0``,
    ``th1`` at the two ends of the step."""
    ez = ca.DM([0.0, 0.0, 1.0])
    half = _cayley(0.5 * (th1 - th0))
    R_mid = R @ half
    local = h * ez + dw - ca.cross(0.5 * (th0 + th1), h * ez)
    return R_mid @ half, r + R_mid @ local


def rod_point(rod: dict, s: float, w: ca.SX, theta: ca.SX) -> tuple[ca.SX, ca.SX]:
    """The section of an exact rod at arc length ``s``, between its nodes.

    The walk of :func:`rod_nodes` continued from the last node at or before ``s`` by one
    step of the same rule to ``s``, with the modes' deflection ``w(s)`` and rotation
    ``ϑ(s)`` given there (a sensor point's tabulated ``point_u``, ``point_theta``
    superposed with δ). To first order in δ the section is the default model's, ``(I +
    [ϑ(s)]×, s e_z + w(s))``, exactly; beyond, the error of the walk is O(h²) as at the
    nodes.

    Parameters
    ----------
    rod : dict
        A rod of :func:`rod_nodes`.
    s : float
        Arc length from the link's base, ``0 <= s <= L`` [m].
    w, theta : casadi.SX
        ``Σ_j δ_j w_j(s)`` [m] and ``Σ_j δ_j ϑ_j(s)`` [rad], (3,) each, link-local.

    Returns
    -------
    R : casadi.SX
        (3, 3) rotation of the section in the link's base frame.
    r : casadi.SX
        (3,) position of its centre line [m] in the link's base frame.

    Examples
    --------
    >>> import casadi as ca
    >>> from casflex.robot import load
    >>> link = load("problems/arm2link.toml").links[2]
    >>> d = ca.SX.sym("d", 1)
    >>> zero = ca.SX.zeros((ROD_POINTS + 1) * 3)
    >>> rod = rod_nodes(link, 0, zero, zero, d)
    >>> R, r = rod_point(rod, 0.3, ca.SX.zeros(3), ca.SX.zeros(3))
    >>> ca.evalf(r).full().ravel().tolist()   # the undeformed link: s along z
    [0.0, 0.0, 0.3]
    """
    nodes = rod["s"]
    if not -1e-12 <= s <= nodes[-1] * (1.0 + 1e-12):
        raise ModelError(f"arc length {s} m is outside the rod [0, {nodes[-1]}] m")
    k = int(np.searchsorted(nodes, s, side="right")) - 1
    k = min(max(k, 0), nodes.size - 1)
    return _rod_step(rod["R"][k], rod["r"][k], float(s - nodes[k]), w - rod["w"][k],
                     rod["theta"][k], theta)


def _local_points(body: dict) -> tuple[list, list]:
    """A flexible link's inertia as weighted 4-vectors ``ṽ`` in its base frame: its
    kinetic energy is ``½ Σ w |d/dt(T ṽ)|²`` over the top three rows (module docstring of
    :func:`point_mass_terms`)."""
    rod = body["rod"]
    points, weights = [], []
    for k, w in enumerate(rod["weights"]):
        if w == 0.0:
            continue
        points.append(ca.vertcat(rod["r"][k], 1.0))
        weights.append(rod["rhoA"] * w)
        c = 0.5 * rod["rhoIp"] * w
        if c:
            R = rod["R"][k]
            points += [ca.vertcat(R[:, 0], 0.0), ca.vertcat(R[:, 1], 0.0),
                       ca.vertcat(R[:, 2], 0.0)]
            weights += [c, c, -c]
    if rod["tip"] is not None:
        # Tr(Ṗ Ψ Ṗᵀ) = Σ λ_i |Ṗ u_i|² with Ψ = Σ λ_i u_i u_iᵀ and P = T E: the tip body
        # is the points E u_i of weights λ_i (the rows' last entries are constant)
        lam, U = np.linalg.eigh(np.asarray(rod["tip"], dtype=float))
        for i in np.flatnonzero(np.abs(lam) > 0.0):
            points.append(rod["end"] @ ca.DM(U[:, i]))
            weights.append(float(lam[i]))
    return points, weights


def point_mass_terms(bodies: list[dict], X: ca.SX, dX: ca.SX, gravity: np.ndarray,
                     fill: Callable[[ca.SX], ca.SX] | None = None,
                     invariant: ca.SX | None = None) -> tuple[ca.SX, ca.SX, ca.SX]:
    """Mass matrix, bias forces and gravity potential of the exact kinematics.

    Every inertial term is a weighted sum of squared rates of points ``T ṽ`` (top three
    rows), ``T(X)`` a body's base pose and ``ṽ(X)`` a homogeneous 4-vector in that frame:
    a rod node ``[r_k; 1]`` (weight ``ρA w_k``), its section's axes ``[R_k e_x; 0]``,
    ``[R_k e_y; 0]``, ``[R_k e_z; 0]`` (weights ``½, ½, −½`` times ``ρI_p w_k``: twice the
    kinetic energy of the torsion is ``ρI_p (ω·R e_z)² = Tr(Ṙ J Ṙᵀ)`` with ``J =
    ½ρI_p diag(1, 1, −1)``), the tip body ``E u_i`` on the rod's end frame ``E`` (weights
    ``λ_i``, ``Ψ = Σ λ_i u_i u_iᵀ`` its pseudo-inertia), and a rigid piece's
    pseudo-inertia ``C0`` on ``T``. With ``ṗ = Ṫ ṽ + R v̇`` (``R`` the pose's rotation,
    ``v`` the top of ``ṽ``), the body's mass matrix is assembled from the pose's
    Jacobian ``J_r = ∂T[r, :]ᵀ/∂X`` and three sums over its points, functions of the
    link's own coordinates only::

        Ψ = Σ w ṽ ṽᵀ,   Γ_c = Σ w ṽ ∂v_c/∂X,   M_loc = Σ w (∂v/∂X)ᵀ ∂v/∂X,
        M = Σ_r (J_rᵀ Ψ J_r + J_rᵀ G_r + G_rᵀ J_r) + M_loc,   G_r = Σ_c R[r, c] Γ_c

    (``|R v̇| = |v̇|``): the nodes are differentiated once, in the link's frame, and the
    chain only through the poses, instead of every node through the whole chain (the
    same ``M = Jᵀ W J`` to round-off; tests/model/test_exact_kinematics.py compares the
    two). The bias forces are the Christoffel form ``d/dt(M Ẋ) − ∂T/∂X`` at ``Ẍ = 0``;
    for point masses this is ``Jᵀ W (∂²y/∂X²)[Ẋ, Ẋ]``, and the Coriolis matrix
    ``C = Jᵀ W J̇`` of the points is ``½ ∂(C Ẋ)/∂Ẋ`` (``J̇ Ẋ`` is quadratic in Ẋ), so
    ``Ṁ − 2C`` is skew.

    Parameters
    ----------
    bodies : list of dict
        The model's inertial pieces (:attr:`FlexibleModel.bodies`): a flexible link
        carries ``rod`` (:func:`rod_nodes`) on its base pose ``T``, a rigid piece its
        pseudo-inertia ``C0`` on ``T``.
    X, dX : casadi.SX
        The generalised coordinates ``[q; δ]`` and their rates.
    gravity : numpy.ndarray
        Gravity in the base frame [m/s²].
    fill : callable, optional
        Applied to the poses and points before they are differentiated: the model's
        substitution of the tabulated values for their placeholders, so that the
        derivatives also see the shapes change along the shape joints
        (``shape_rates=True``). None: the shapes are frozen in the velocities.
    invariant : casadi.SX, optional
        Coordinates the kinetic energy does not depend on (a first joint about an axis
        fixed in the base): set to zero in ``M`` and the bias, which removes their
        trigonometric terms. The potential keeps them.

    Returns
    -------
    M : casadi.SX
        (N, N) mass matrix without the motor inertias [kg, kg m, kg m²].
    bias : casadi.SX
        (N,) ``C Ẋ`` [N, N m].
    V : casadi.SX
        Gravitational potential [J].

    Examples
    --------
    >>> import casadi as ca
    >>> X, dX = ca.SX.sym("X", 1), ca.SX.sym("dX", 1)
    >>> T = ca.SX.eye(4)
    >>> T[0, 3], T[1, 3] = ca.cos(X[0]), ca.sin(X[0])   # 2 kg on a unit circle
    >>> body = {"T": T, "C0": ca.DM(pseudo_inertia(2.0))}
    >>> M, bias, V = point_mass_terms([body], X, dX, np.array([0.0, -9.81, 0.0]))
    >>> f = ca.Function("f", [X, dX], [M, bias, V])
    >>> [round(float(v), 6) + 0.0 for v in f(0.5, 3.0)]   # 2 kg m², no bias, m g y
    [2.0, 0.0, 9.406329]
    """
    N = X.numel()
    gh = ca.DM(np.r_[gravity, 0.0])
    same = (lambda e: e) if fill is None else fill
    # every pose and every link's points in one vector, differentiated once (shared sweeps)
    poses, locals_, pieces, at = [], [], [], 0
    for body in bodies:
        T = same(body["T"])
        poses.append(T)
        entry = [at]
        at += 12
        if body.get("rod") is not None:
            points, weights = _local_points(body)
            Vt = same(ca.horzcat(*points))  # (4, P); the last row is constant
            locals_.append((Vt, ca.diag(ca.DM(weights))))
            entry.append(at)
            at += 3 * len(points)
        else:
            locals_.append(None)
        pieces.append(entry)
    Y = ca.vertcat(*[ca.vertcat(ca.vec(T[:3, :]), ca.vec(loc[0][:3, :]) if loc else ca.SX(0, 1))
                     for T, loc in zip(poses, locals_, strict=True)])
    Jac = ca.jacobian(Y, X)
    Yd = ca.jtimes(Y, X, dX)
    Ydd = ca.jtimes(Yd, X, dX)
    if invariant is not None:  # coordinates M and the bias do not depend on (zeroed)
        zero = ca.SX.zeros(invariant.numel())
        Jac, Yd, Ydd, Y = ca.substitute([Jac, Yd, Ydd, Y], [invariant], [zero])
    M, bias, Vg = ca.SX.zeros(N, N), ca.SX.zeros(N), ca.SX(0)
    for body, T, loc, entry in zip(bodies, poses, locals_, pieces, strict=True):
        a = entry[0]
        Tg = T  # gravity keeps every coordinate
        T = ca.vertcat(ca.reshape(Y[a:a + 12], 3, 4), T[3, :])
        Td, Tdd = ca.reshape(Yd[a:a + 12], 3, 4), ca.reshape(Ydd[a:a + 12], 3, 4)
        JT = [Jac[a + r:a + 12:3, :] for r in range(3)]  # ∂T[r, :]ᵀ/∂X, (4, N)
        R, Rd = T[:3, :3], Td[:, :3]
        if loc is None:
            Psi = ca.SX(body["C0"])
            A = Psi @ Tdd.T
        else:
            Vt, Wd = loc
            b, P = entry[1], Vt.shape[1]
            Vt = ca.vertcat(ca.reshape(Y[b:b + 3 * P], 3, P), Vt[3, :])
            Jc = [Jac[b + c:b + 3 * P:3, :] for c in range(3)]  # ∂v_c/∂X, (P, N)
            Vd = ca.reshape(Yd[b:b + 3 * P], 3, P)
            Vdd = ca.reshape(Ydd[b:b + 3 * P], 3, P)
            VW = Vt @ Wd
            Psi = VW @ Vt.T
            Gam = [VW @ Jc[c] for c in range(3)]  # Γ_c, (4, N)
            for c in range(3):
                M += Jc[c].T @ Wd @ Jc[c]
            for r in range(3):
                B = JT[r].T @ sum(R[r, c] * Gam[c] for c in range(3))
                M += B + B.T
            A = Psi @ Tdd.T + 2.0 * (VW @ Vd.T) @ Rd.T + (VW @ Vdd.T) @ R.T
            K = R.T @ Tdd
            Z = Wd @ (2.0 * (R.T @ Rd) @ Vd + Vdd).T  # (P, 3)
            for c in range(3):
                bias += Gam[c].T @ K[c, :].T + Jc[c].T @ Z[:, c]
        for r in range(3):
            M += JT[r].T @ Psi @ JT[r]
            bias += JT[r].T @ A[:, r]
        Vg -= gh.T @ Tg @ Psi[:, 3]
    return M, bias, Vg
