"""A geometrically exact Ritz model of a flexible arm in its own TMM modes (issue 19).

Why: under large deflections casflex's modal model (elastic potential ``½ δᵀKδ``,
kinematics to δ² with ``foreshortening``) deflects too far: +2.5 % at 254 mm across the
joints' plane against the 3-D geometrically exact reference (test_spatial_static.py).
This module answers whether the missing terms are geometric, and of which order, with a
second Ritz model in **the same modes** whose kinematics are exact.

The model (a Kirchhoff rod Ritz model in strain space): each mode's material curvatures
``κ = (M_x/EI_x, M_y/EI_y, M_z/GJ)`` and axial strain ``ε = F_z/EA`` along every beam
(:func:`casflex.modal.normalize.local_state`, exact at any arc length, mass-normalised
modes at the frozen joint angles) are superposed with the amplitudes δ, and the rod is
rebuilt from them exactly: ``Λ' = Λ [κ]×``, ``r' = (1 + ε) Λ e_z``, integrated with
``n_steps`` Cayley half-steps per beam (error O(h²)); link 2's first section is clamped
to link 1's last (the joints frozen). The strain energy of a Kirchhoff rod is exactly
``½ ∫ κᵀ D κ + EA ε²``, i.e. ``½ δᵀ K δ`` with the same ``K = diag(ω²)`` as casflex's; all
the nonlinearity is in the positions. A uniform body-force field ``a`` [m/s²] has the
potential ``−∫ ρA a·r ds``. To first order in δ the positions equal the modes'
displacements (the tip Jacobian equals casflex's ``tip`` Jacobian,
test_elastica_stiffening.py); ``load_order`` truncates the field's potential to a Taylor
polynomial in δ of that order, to see which order the static answer needs.

:func:`quartic_terms` writes the quartic potential terms a displacement-based modal model
(casflex's ``δ``) lacks, from the same shapes: the inextensible beam's nonlinear curvature
(``κ² ≈ w''²(1 + w'²)`` per bending direction), the rotation of the bending plane
against the section's principal axes by the section's rotation about the beam axis
(``½ (EI_y − EI_x) θ_z² (κ_x² − κ_y²)``), and the third-order rigid rotation of link 2
about the elbow (``(1/6)[Θ]×³ d``, in the field's potential).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from casflex.modal.normalize import local_state, mass_normalize
from casflex.tmm import modes


def _skew(v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]),
                      ca.horzcat(-v[1], v[0], 0))


def _cayley(w):
    """Rotation matrix of the Cayley map of ``w`` (a rotation by ``2 atan(|w|/2)``)."""
    a = _skew(0.5 * w)
    return ca.SX.eye(3) + 2.0 / (1.0 + 0.25 * ca.dot(w, w)) * (a + a @ a)


def beam_fields(robot, shapes, beam: int, s: np.ndarray) -> dict:
    """Mode fields of one beam at arc lengths ``s`` [m]: ``u``, ``theta`` (m, p, 3) [m,
    rad], material curvatures ``kappa`` (m, p, 3) [1/m] (bending about local x, y, and
    the twist rate), axial strain ``eps`` (m, p), and the section's ``EI_x``, ``EI_y``,
    ``GJ``, ``EA``, ``rhoA``."""
    link = robot.links[shapes.rows[beam]]
    sec, mat = link.section, link.material
    D = np.array([mat.E * sec.Ix, mat.E * sec.Iy, mat.G * sec.J])
    z = local_state(robot, shapes, beam, s)
    return {"u": z[..., 0:3], "theta": z[..., 3:6], "kappa": z[..., 6:9] / D,
            "eps": z[..., 11] / (mat.E * sec.A), "EI_x": D[0], "EI_y": D[1], "GJ": D[2],
            "EA": mat.E * sec.A, "rhoA": mat.rho * sec.A}


class ExactRitz:
    """The arm at frozen joint angles ``q`` [rad] as an exact-kinematics Ritz model in its
    first ``n_modes`` mass-normalised TMM modes (module docstring).

    Attributes: ``delta`` (the SX amplitudes), ``K`` (modal stiffness by midpoint
    quadrature), ``load`` (``∫ ρA r ds``, SX (3,) [kg m]), ``tip`` (tip displacement from
    the undeformed tip, SX (3,) [m]), ``midpoints`` and ``midpoint_masses`` (the steps'
    midpoints, SX (3,) each [m], and their ``ρA h`` [kg]: :func:`turning_run`),
    ``shapes``.
    """

    def __init__(self, robot, q=(0.0, 0.0, 0.0), n_modes: int = 5, n_steps: int = 100):
        self.robot = robot
        self.shapes = sh = mass_normalize(robot, modes(robot, q, count=n_modes))
        if len(sh.rows) != 2 or not np.allclose(sh.position[1, 0], sh.position[0, -1]):
            raise ValueError("two beams, the second starting at the first one's end")
        self.delta = d = ca.SX.sym("delta", n_modes)
        self.K = np.zeros((n_modes, n_modes))
        load, r, frame = ca.SX.zeros(3), ca.SX(sh.position[0, 0]), ca.SX(sh.R[0])
        ez = ca.SX([0.0, 0.0, 1.0])
        self.midpoints, masses = [], []
        for b in range(2):
            length = float(sh.s[b, -1])
            h = length / n_steps
            f = beam_fields(robot, sh, b, (np.arange(n_steps) + 0.5) * h)
            self.K += h * (np.einsum("mpi,npi,i->mn", f["kappa"], f["kappa"],
                                     [f["EI_x"], f["EI_y"], f["GJ"]])
                           + f["EA"] * np.einsum("mp,np->mn", f["eps"], f["eps"]))
            if b == 1:  # link 2 clamped to link 1's end section
                frame = frame @ ca.SX(sh.R[0].T @ sh.R[1])
            points = [r]
            for k in range(n_steps):
                half = _cayley(0.5 * h * (ca.SX(f["kappa"][:, k, :].T) @ d))
                step = h * (1.0 + ca.dot(ca.SX(f["eps"][:, k]), d)) * (frame @ half @ ez)
                self.midpoints.append(r + 0.5 * step)
                masses.append(h * f["rhoA"])
                r = r + step
                frame = frame @ half @ half
                points.append(r)
            w = np.full(n_steps + 1, h * f["rhoA"])
            w[[0, -1]] *= 0.5
            load = load + ca.horzcat(*points) @ ca.SX(w)
        self.load = load
        self.tip = r - ca.SX(sh.position[1, -1])
        self.midpoint_masses = np.array(masses)

    def static(self, field, load_order: int | None = None, tol: float = 1e-12) -> dict:
        """Static equilibrium under the uniform field ``field`` [m/s², base frame]:
        ``{"tip": tip displacement [m], "delta": amplitudes}``; ``load_order`` truncates
        the field's potential to its Taylor polynomial in δ of that order (None: exact)."""
        d, z = self.delta, np.zeros(self.delta.shape[0])
        Y = ca.dot(ca.SX(np.asarray(field, dtype=float)), self.load)
        if load_order is not None:
            Y = taylor(Y, d, load_order)
        Pi = 0.5 * ca.bilin(ca.SX(self.K), d, d) - Y
        newton = ca.Function("newton", [d], [ca.gradient(Pi, d), ca.hessian(Pi, d)[0],
                                             self.tip])
        x = z.copy()
        for _ in range(60):
            g, H, _ = newton(x)
            g = g.full().ravel()
            if np.abs(g).max() < tol:
                break
            x -= np.linalg.solve(H.full(), g)
        else:
            raise AssertionError("the Ritz model's Newton did not converge")
        return {"tip": newton(x)[2].full().ravel(), "delta": x}


def taylor(expr, x, order: int, step: float = 1e-4):
    """Taylor polynomial of the scalar SX ``expr`` in ``x`` about 0, to ``order`` (≤ 3);
    the third-order coefficients by central differences of the exact Hessian (error
    ``step²`` relative, ~1e-8)."""
    if order > 3:
        raise ValueError("order ≤ 3")
    n = x.shape[0]
    z = np.zeros(n)
    H = ca.hessian(expr, x)[0]
    coefficients = ca.Function("c", [x], [expr, ca.gradient(expr, x), H])
    value, grad, hess = (v.full() for v in coefficients(z))
    out = float(value.item()) + ca.dot(ca.DM(grad), x)
    if order >= 2:
        out = out + 0.5 * ca.bilin(ca.DM(hess), x, x)
    if order >= 3:
        for k in range(n):
            e = np.zeros(n)
            e[k] = step
            Tk = (coefficients(e)[2].full() - coefficients(-e)[2].full()) / (2 * step)
            out = out + x[k] * ca.bilin(ca.DM(Tk), x, x) / 6.0
    return out


def quartic_terms(robot, delta, field_per_unit, q=(0.0, 0.0, 0.0), n_steps: int = 400
                  ) -> dict:
    """The quartic potential terms a displacement-based modal model lacks, as SX of
    ``delta`` (the model's amplitudes: the mass-normalised TMM modes at ``q``, signs as
    :func:`casflex.tmm.modes` gives them): ``"curvature"`` ``½ Σ ∫ EI w''² w'²`` per
    bending direction (``w'`` the total slope in the beam's undeformed frame);
    ``"twist"`` ``½ Σ ∫ (EI_y − EI_x) θ_z² (κ_x² − κ_y²)``; ``"rigid3"`` the field's
    potential of link 2's third-order rotation about the elbow, per unit field
    ``field_per_unit`` [m/s²] (multiply by the field's strength)."""
    sh = mass_normalize(robot, modes(robot, q, count=delta.shape[0]))
    out = {"curvature": 0, "twist": 0}
    for b in range(2):
        h = float(sh.s[b, -1]) / n_steps
        f = beam_fields(robot, sh, b, (np.arange(n_steps) + 0.5) * h)
        th, kap = f["theta"], f["kappa"]
        slope_x = ca.SX(th[..., 1].T) @ delta  # w_x' = θ_y
        slope_y = -ca.SX(th[..., 0].T) @ delta  # w_y' = −θ_x
        twist = ca.SX(th[..., 2].T) @ delta
        kx, ky = ca.SX(kap[..., 0].T) @ delta, ca.SX(kap[..., 1].T) @ delta
        out["curvature"] += 0.5 * h * ca.sum1(f["EI_x"] * kx**2 * slope_y**2
                                              + f["EI_y"] * ky**2 * slope_x**2)
        out["twist"] += 0.5 * h * ca.sum1((f["EI_y"] - f["EI_x"]) * twist**2
                                          * (kx**2 - ky**2))
    # link 2 turned about the elbow by link 1's end rotation Θ: exp([Θ]×) d keeps
    # (1/6)[Θ]×³ d = −(1/6)|Θ|² Θ × d beyond the model's second order
    rot_end = beam_fields(robot, sh, 0, [float(sh.s[0, -1])])["theta"][:, 0, :]
    theta = ca.SX(sh.R[0] @ rot_end.T) @ delta
    arm = sh.position[1] - sh.position[0, -1]
    w = np.full(len(arm), float(sh.s[1, 1] - sh.s[1, 0]))
    w[[0, -1]] *= 0.5
    rhoA = beam_fields(robot, sh, 1, [0.0])["rhoA"]
    g = ca.SX(np.asarray(field_per_unit, dtype=float))
    third = sum(w[i] * ca.dot(g, -ca.dot(theta, theta) * ca.cross(theta, ca.SX(arm[i])))
                for i in range(len(arm))) / 6.0
    out["rigid3"] = -rhoA * third
    return out


def turning_run(robot, move, n_modes: int = 5, n_steps: int = 50, dt: float = 1e-3
                ) -> dict[str, np.ndarray]:
    """Tip deflection ``{"t", "d"}`` [s, m] (base frame, tip minus rigid tip) of the exact
    Ritz model when only joint 1 turns: ``move`` a :class:`reference_beam_3d.JointMove`
    with q2 and q3 held (the modes are those of the frozen q2, q3; q1 turns the whole arm
    about z0, which does not change them). No gravity, no damping.

    Equations (d'Alembert with the exact positions ``r_i(δ)`` of ``2 n_steps`` point
    masses ``ρA h`` at the steps' midpoints, in the frame turning with q1, ``ω = q̇1 z0``):
    ``Σ m_i J_iᵀ (J_i δ̈ + (∂²r_i/∂δ²)[δ̇, δ̇] + 2ω × J_i δ̇ + ω̇ × r_i + ω × (ω × r_i)) +
    K δ = 0``, ``J_i = ∂r_i/∂δ``; the sections' rotary inertia is left out (~1e-5 on the
    bending frequencies, the links' own torsional inertia ~1e-5 of link 2's about link
    1's axis). Classic RK4 with step ``dt``; the joint's acceleration switches on step
    boundaries (bang-bang moves of a whole number of steps)."""
    if not np.allclose(move.q0[1:], move.qf[1:]):
        raise ValueError("q2 and q3 must be held")
    ritz = ExactRitz(robot, (0.0,) + tuple(move.q0[1:]), n_modes, n_steps)
    d, dd = ritz.delta, ca.SX.sym("ddelta", n_modes)
    P = ca.vertcat(*ritz.midpoints)
    kin = ca.Function("kin", [d, dd], [P, ca.jacobian(P, d),
                                       ca.jtimes(ca.jtimes(P, d, dd), d, dd)])
    tip = ca.Function("tip", [d], [ritz.tip])
    mass = np.repeat(ritz.midpoint_masses, 3)
    a0, a1, duration = float(move.q0[0]), float(move.qf[0]), float(move.duration)
    peak = 4.0 * (a1 - a0) / duration**2

    def joint(t):  # q1, q̇1, q̈1 at t (the acceleration of the step starting at t)
        if t <= 0.0 or t >= duration:
            return (a0 if t <= 0.0 else a1), 0.0, 0.0
        if t < 0.5 * duration:
            return a0 + 0.5 * peak * t**2, peak * t, peak
        return a1 - 0.5 * peak * (duration - t) ** 2, peak * (duration - t), -peak

    def rhs(t, x):
        delta, rate = x[:n_modes], x[n_modes:]
        Pv, Jv, cv = (v.full() for v in kin(delta, rate))
        Pv, cv = Pv.reshape(-1, 3), cv.reshape(-1, 3)
        _, w, wd = joint(t)
        om, omd = np.array([0.0, 0.0, w]), np.array([0.0, 0.0, wd])
        acc = (cv + 2.0 * np.cross(om, (Jv @ rate).reshape(-1, 3)) + np.cross(omd, Pv)
               + np.cross(om, np.cross(om, Pv)))
        M = Jv.T @ (mass[:, None] * Jv)
        return np.concatenate([rate, np.linalg.solve(M, -Jv.T @ (mass * acc.ravel())
                                                      - ritz.K @ delta)])

    steps = int(round(move.t_end / dt))
    x, t_out, d_out = np.zeros(2 * n_modes), [], []
    eps = 1e-9 * dt  # stage times inside the step, so a switch on its boundary is seen
    for i in range(steps + 1):
        t = i * dt
        c, s = np.cos(joint(t)[0]), np.sin(joint(t)[0])
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        t_out.append(t)
        d_out.append(turn @ tip(x[:n_modes]).full().ravel())
        if i == steps:
            break
        k1 = rhs(t + eps, x)
        k2 = rhs(t + 0.5 * dt, x + 0.5 * dt * k1)
        k3 = rhs(t + 0.5 * dt, x + 0.5 * dt * k2)
        k4 = rhs(t + dt - eps, x + dt * k3)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return {"t": np.array(t_out), "d": np.array(d_out)}
