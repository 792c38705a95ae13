"""Independent planar nonlinear beam dynamics of a two-link arm with prescribed joints.

A test oracle for the fidelity of casflex's modal model on large, fast planar moves. It
is written from scratch and imports nothing from casflex (numpy only).

Model
-----
* Each link is a straight, uniform Euler–Bernoulli beam discretised into ``n_elements``
  planar ANCF (absolute nodal coordinate) elements, gradient-deficient (Berzeri &
  Shabana 2000): every node carries its absolute position ``r`` and slope ``r' = ∂r/∂s``
  in the plane, ``e = [r_A, r'_A, r_B, r'_B]`` per element, cubic Hermite interpolation.
  Rigid motions of any size are exact; nothing is linearised in the displacements.
* Kinetic energy ``½ ∫ ρA |ṙ|² ds``: a constant consistent mass matrix (translational
  inertia only, as the Euler–Bernoulli field equations).
* Strain energy ``½ ∫ EA ε² ds + ½ ∫ EI |r''|² ds`` with the Green axial strain
  ``ε = ½(r'·r' − 1)``. ``|r''|²`` equals the squared curvature for an unstretched
  centre line (``|r'| = 1``, ``r''⊥r'``); with the axial strains of these moves
  (< 1e-5) the difference is below 1e-4 relative. The axial part is nonlinear (Gauss
  quadrature, 5 points: exact for its degree-8 integrand); the bending part is linear in
  the absolute coordinates.
* Prescribed joints: the first node of link 1 is clamped to a hub at the origin turning
  by ``θ1(t)`` (``r = 0``, ``r' = (cos θ1, sin θ1)``); the first node of link 2 sits on
  the last node of link 1 with its slope turned by the relative angle ``φ(t)``
  (``r'_2(0) = R(φ) r'_1(L)``). These are linear, time-varying constraints
  ``e = B(t) y + g(t)`` on the free coordinates ``y``, eliminated exactly:
  ``Bᵀ[M (B ÿ + 2Ḃ ẏ + B̈ y + g̈) + Q(e)] = 0``.
* Time integration: Newmark's average-acceleration rule (implicit trapezoidal,
  unconditionally stable, second order, no numerical damping) with Newton iterations on
  the exact tangent. The joint profiles may switch their acceleration at grid points:
  the step ending at a switch uses the left limit, and the acceleration is re-solved with
  the right limit before the next step.

Angles are those of the plane: ``θ1`` is the absolute angle of link 1, ``φ`` the angle of
link 2 relative to link 1 (counter-clockwise positive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAUSS_POINTS = 5


@dataclass(frozen=True)
class PlanarBeam:
    """A uniform planar beam: length [m], EA [N], EI [N m²], ρA [kg/m]."""

    length: float
    EA: float
    EI: float
    rhoA: float


@dataclass(frozen=True)
class BangBang:
    """Joint angle ``a0 -> a1`` with bang-bang acceleration over ``duration`` [rad, s]."""

    a0: float
    a1: float
    duration: float

    def __call__(self, t: float, side: int = 1) -> tuple[float, float, float]:
        """Angle, rate, acceleration at ``t``; ``side`` picks the limit at a switch."""
        T, d = self.duration, self.a1 - self.a0
        acc = 4.0 * d / T**2
        tt = t + side * 1e-12 * max(T, 1.0)
        if tt <= 0.0:
            return self.a0, 0.0, 0.0
        if tt <= 0.5 * T:
            return self.a0 + 0.5 * acc * t**2, acc * t, acc
        if tt <= T:
            r = T - t
            return self.a1 - 0.5 * acc * r**2, acc * r, -acc
        return self.a1, 0.0, 0.0

    @property
    def switches(self) -> tuple[float, ...]:
        return (0.0, 0.5 * self.duration, self.duration)


def _hermite(xi, h):
    """Shape functions and their first and second arc-length derivatives at ξ ∈ [0, 1]."""
    x = np.asarray(xi, dtype=float)
    N = np.stack([1 - 3 * x**2 + 2 * x**3, h * (x - 2 * x**2 + x**3),
                  3 * x**2 - 2 * x**3, h * (-x**2 + x**3)], axis=-1)
    dN = np.stack([-6 * x + 6 * x**2, h * (1 - 4 * x + 3 * x**2),
                   6 * x - 6 * x**2, h * (-2 * x + 3 * x**2)], axis=-1) / h
    d2N = np.stack([-6 + 12 * x, h * (-4 + 6 * x), 6 - 12 * x, h * (-2 + 6 * x)],
                   axis=-1) / h**2
    return N, dN, d2N


def _expand(N):
    """Scalar shape functions (..., 4) -> 2 × 8 interpolation matrices (..., 2, 8)."""
    S = np.zeros(N.shape[:-1] + (2, 8))
    for k in range(4):
        S[..., 0, 2 * k] = N[..., k]
        S[..., 1, 2 * k + 1] = N[..., k]
    return S


class TwoLinkArm:
    """ANCF model of two planar beams joined at prescribed joint angles.

    Parameters
    ----------
    links : (PlanarBeam, PlanarBeam)
    n_elements : int
        Elements per link.
    """

    def __init__(self, links: tuple[PlanarBeam, PlanarBeam], n_elements: int) -> None:
        self.links = links
        ne = self.ne = int(n_elements)
        nn = ne + 1
        self.n_full = 2 * nn * 4
        # element dof indices into the full vector, link by link
        dofs, props = [], []
        for b, link in enumerate(links):
            base = b * nn * 4
            for e in range(ne):
                dofs.append(base + 4 * e + np.arange(8))
                props.append((link.length / ne, link.EA, link.EI, link.rhoA))
        self.dofs = np.array(dofs)
        p = np.array(props)
        self.h, self.EA, self.EI, self.rhoA = p.T
        xg, wg = np.polynomial.legendre.leggauss(GAUSS_POINTS)
        xi, self.wg = 0.5 * (xg + 1.0), 0.5 * wg
        # element matrices (vectorised over elements): mass, bending, slope interpolation
        Me, Kb = [], []
        self.dS = []
        for h, EI, rA in zip(self.h, self.EI, self.rhoA, strict=True):
            N, dN, d2N = _hermite(xi, h)
            S, S1, S2 = _expand(N), _expand(dN), _expand(d2N)
            Me.append(rA * h * np.einsum("g,gai,gaj->ij", self.wg, S, S))
            Kb.append(EI * h * np.einsum("g,gai,gaj->ij", self.wg, S2, S2))
            self.dS.append(S1)
        self.dS = np.array(self.dS)  # (E, G, 2, 8)
        self.M = self._assemble_matrix(np.array(Me))
        self.Kb = self._assemble_matrix(np.array(Kb))
        # free coordinates: every node but the first of each link
        self.first1 = np.arange(4)
        self.first2 = nn * 4 + np.arange(4)
        self.last1 = (nn - 1) * 4 + np.arange(4)
        self.free = np.setdiff1d(np.arange(self.n_full), np.r_[self.first1, self.first2])

    def _assemble_matrix(self, Ke):
        K = np.zeros((self.n_full, self.n_full))
        rows = np.repeat(self.dofs[:, :, None], 8, axis=2)
        cols = np.repeat(self.dofs[:, None, :], 8, axis=1)
        np.add.at(K, (rows, cols), Ke)
        return K

    def elastic(self, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Generalised elastic force ∂U/∂e and its tangent, full coordinates."""
        ee = e[self.dofs]  # (E, 8)
        S1 = self.dS  # (E, G, 2, 8)
        rp = np.einsum("egai,ei->ega", S1, ee)  # r' at Gauss points
        eps = 0.5 * (np.einsum("ega,ega->eg", rp, rp) - 1.0)
        Sr = np.einsum("egai,ega->egi", S1, rp)  # S'ᵀ r'
        w = (self.EA * self.h)[:, None] * self.wg[None, :]
        Fe = np.einsum("eg,eg,egi->ei", w, eps, Sr)
        StS = np.einsum("egai,egaj->egij", S1, S1)
        Ke = np.einsum("eg,egij->eij", w * eps, StS) + \
            np.einsum("eg,egi,egj->eij", w, Sr, Sr)
        F = self.Kb @ e
        np.add.at(F, self.dofs, Fe)
        K = self.Kb + self._assemble_matrix(Ke)
        return F, K

    def constraint(self, th1: tuple[float, float, float], phi: tuple[float, float, float]):
        """``B, Ḃ, B̈`` (full × free) and ``g, ġ, g̈`` from joint angle, rate, acceleration."""
        nf = self.free.size
        col = {d: k for k, d in enumerate(self.free)}
        B = [np.zeros((self.n_full, nf)) for _ in range(3)]
        for k, d in enumerate(self.free):
            B[0][d, k] = 1.0
        a, da, dda = phi
        c, s = np.cos(a), np.sin(a)
        R = np.array([[c, -s], [s, c]])
        Rp = np.array([[-s, -c], [c, -s]])  # dR/dφ
        Rpp = -R
        # link 2's first node: position = link 1's last position, slope = R(φ) slope
        for i in range(2):
            B[0][self.first2[i], col[self.last1[i]]] = 1.0
        mats = (R, da * Rp, dda * Rp + da**2 * Rpp)
        for k, Rk in enumerate(mats):
            for i in range(2):
                for j in range(2):
                    B[k][self.first2[2 + i], col[self.last1[2 + j]]] = Rk[i, j]
        t, dt_, ddt = th1
        c1, s1 = np.cos(t), np.sin(t)
        g = [np.zeros(self.n_full) for _ in range(3)]
        g[0][self.first1[2:]] = (c1, s1)
        g[1][self.first1[2:]] = (-s1 * dt_, c1 * dt_)
        g[2][self.first1[2:]] = (-c1 * dt_**2 - s1 * ddt, -s1 * dt_**2 + c1 * ddt)
        return B, g

    def straight(self, th1: float, phi: float) -> np.ndarray:
        """Free coordinates of the undeformed arm at the given joint angles."""
        e = np.zeros(self.n_full)
        start = np.zeros(2)
        angle = th1
        nn = self.ne + 1
        for b, link in enumerate(self.links):
            if b == 1:
                angle = th1 + phi
            u = np.array([np.cos(angle), np.sin(angle)])
            for k in range(nn):
                i = b * nn * 4 + 4 * k
                e[i:i + 2] = start + u * link.length * k / self.ne
                e[i + 2:i + 4] = u
            start = start + u * link.length
        return e[self.free]

    def tip(self, y: np.ndarray) -> np.ndarray:
        """Tip position (last node of link 2) from free coordinates, (..., 2) [m]."""
        i = np.searchsorted(self.free, self.n_full - 4)
        return y[..., i:i + 2]

    def rigid_tip(self, th1: float, phi: float) -> np.ndarray:
        L1, L2 = self.links[0].length, self.links[1].length
        return np.array([L1 * np.cos(th1) + L2 * np.cos(th1 + phi),
                         L1 * np.sin(th1) + L2 * np.sin(th1 + phi)])

    def _residual(self, y, v, a, th1, phi):
        (B, dB, ddB), (g, dg, ddg) = self.constraint(th1, phi)
        e = B @ y + g
        F, K = self.elastic(e)
        inertia = self.M @ (B @ a + 2.0 * dB @ v + ddB @ y + ddg)
        return B.T @ (inertia + F), (B, dB, ddB, K)

    def _acceleration(self, y, v, th1, phi):
        (B, dB, ddB), (g, dg, ddg) = self.constraint(th1, phi)
        F, _ = self.elastic(B @ y + g)
        rhs = -B.T @ (self.M @ (2.0 * dB @ v + ddB @ y + ddg) + F)
        return np.linalg.solve(B.T @ self.M @ B, rhs)

    def simulate(self, theta1: BangBang, phi: BangBang, t_end: float, dt: float,
                 tol: float = 1e-6, max_iter: int = 20) -> dict[str, np.ndarray]:
        """Newmark average-acceleration integration from rest, undeformed.

        Returns ``t`` (N,), ``tip`` (N, 2), ``tip_rigid`` (N, 2) [s, m], ``y`` (N, nf).
        """
        n_steps = int(round(t_end / dt))
        t = np.arange(n_steps + 1) * dt
        switches = np.array(theta1.switches + phi.switches)
        y = self.straight(theta1(0.0)[0], phi(0.0)[0])
        v = np.zeros_like(y)
        a = self._acceleration(y, v, theta1(0.0, 1), phi(0.0, 1))
        ys = np.empty((n_steps + 1, y.size))
        ys[0] = y
        for k in range(1, n_steps + 1):
            tk = t[k]
            j1, j2 = theta1(tk, -1), phi(tk, -1)
            y_pred = y + dt * v + 0.25 * dt**2 * a
            v_pred = v + 0.5 * dt * a
            a_new = a.copy()
            for _ in range(max_iter):
                yn = y_pred + 0.25 * dt**2 * a_new
                vn = v_pred + 0.5 * dt * a_new
                r, (B, dB, ddB, K) = self._residual(yn, vn, a_new, j1, j2)
                J = B.T @ (self.M @ (B + dt * dB + 0.25 * dt**2 * ddB)
                           + 0.25 * dt**2 * K @ B)
                da = np.linalg.solve(J, -r)
                a_new += da
                if np.linalg.norm(da) <= tol * (1.0 + np.linalg.norm(a_new)):
                    break
            else:
                raise RuntimeError(f"Newton did not converge at t = {tk}")
            y = y_pred + 0.25 * dt**2 * a_new
            v = v_pred + 0.5 * dt * a_new
            a = a_new
            if np.any(np.abs(switches - tk) < 0.5 * dt):
                a = self._acceleration(y, v, theta1(tk, 1), phi(tk, 1))
            ys[k] = y
        tip_rigid = np.array([self.rigid_tip(theta1(tk)[0], phi(tk)[0]) for tk in t])
        return {"t": t, "tip": self.tip(ys), "tip_rigid": tip_rigid, "y": ys}

    def frequencies(self, th1: float, phi: float, count: int) -> np.ndarray:
        """Lowest natural frequencies of the arm locked at the given angles [rad/s]."""
        (B, _, _), (g, _, _) = self.constraint((th1, 0.0, 0.0), (phi, 0.0, 0.0))
        y = self.straight(th1, phi)
        _, K = self.elastic(B @ y + g)
        Kr, Mr = B.T @ K @ B, B.T @ self.M @ B
        L = np.linalg.cholesky(Mr)
        Li = np.linalg.inv(L)
        w2 = np.linalg.eigvalsh(Li @ Kr @ Li.T)
        return np.sqrt(np.abs(w2[:count]))
