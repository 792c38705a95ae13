"""Independent 3-D Euler-Bernoulli frame finite-element reference model.

This module is a test oracle for casflex.  It is written from scratch and does
not import casflex; it only uses numpy and scipy.

Model
-----
* Each :class:`Segment` is a straight prismatic beam discretised into
  ``n_elements`` two-node, 12-DOF frame elements (axial, St-Venant torsion and
  Euler-Bernoulli bending in two planes) with consistent mass matrices.  The
  rotary inertia of torsion (``rho * Ip``) is included, the rotary inertia of
  bending and shear deformation are neglected.
* Section frame: local z is the beam axis (start -> end), local x is
  ``Segment.local_x`` orthogonalised against z, local y = z x x.
  ``Ix`` (second moment about local x) resists the deflection ``w_y`` (bending in
  the local y-z plane); ``Iy`` resists the deflection ``w_x``.
* Segment end points closer than ``NODE_TOL`` are merged into one node and are
  rigidly connected, unless a :class:`JointSpring` is located there.  In that
  case two nodes are created: the *inboard* node (segments ending there, or the
  ground if the spring sits at the clamp point) and the *outboard* node
  (segments starting there).  The outboard node is a slave of the inboard node:
  equal translations, ``theta_out = theta_in + axis * phi``, where ``phi`` is an
  extra generalised coordinate with potential energy ``k phi^2 / 2``
  (exact elimination, no penalty).
* Nodes at the clamp point are fully fixed.
* :class:`PointBody` adds the rigid-body mass matrix of a body referred to its
  node: with node translation u, rotation theta and centre-of-mass offset c,
  ``v_com = u' + theta' x c = u' - [c]x theta'`` so that

  ``M = [[m I, -m [c]x], [m [c]x, I_com + m [c]x^T [c]x]]``.

* DOF ordering of each node (global frame): ``ux, uy, uz, rx, ry, rz``.

The generalised eigenproblem ``K q = omega^2 M q`` on the free DOFs is solved
with :func:`scipy.linalg.eigh` in the inverse form ``M q = omega^-2 K q`` (which
gives the lowest frequencies to ~1e-12 relative accuracy; falls back to the direct
form if K is singular); modes are mass-normalised.  The remaining round-off floor
comes from the large ratio of axial to bending stiffness in skew elements and is
~1e-9 (40 elements) to ~1e-8 (80 elements) relative on frame frequencies, well
below the discretisation error (cantilever, 40 elements: bending modes 1-4
2e-9 .. 4e-6, first torsion/axial mode 6.4e-5, always from above).

Usage::

    omega, shapes = modes(segments, bodies, springs, clamp=[0, 0, 0], n_modes=6)
    shapes.sample(i, s)          # (n_modes, len(s), 3) global translations
    shapes.sample(i, s, "both")  # (n_modes, len(s), 6) translations + rotations
    shapes.nodes(i)              # (n_elements + 1, 3) node coordinates of segment i
    shapes.node_values(i)        # (n_modes, n_elements + 1, 6)
    shapes.at(point, side)       # (n_modes, 6) at a node
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

NODE_TOL = 1e-9

__all__ = [
    "NODE_TOL",
    "JointSpring",
    "ModeShapes",
    "PointBody",
    "Segment",
    "angle_value",
    "dh_frames",
    "element_matrices",
    "modes",
    "prandtl_torsion_constant",
    "rectangle_torsion_constant",
    "robot_model",
    "robot_modes",
    "section_constants",
    "section_frame",
]


def _vec3(v) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(3)
    return a


def _skew(c: np.ndarray) -> np.ndarray:
    """Cross-product matrix: ``_skew(c) @ v == np.cross(c, v)``."""
    return np.array(
        [
            [0.0, -c[2], c[1]],
            [c[2], 0.0, -c[0]],
            [-c[1], c[0], 0.0],
        ]
    )


@dataclass
class Segment:
    """Straight prismatic beam segment (see the module docstring for the frame)."""

    start: np.ndarray
    end: np.ndarray
    local_x: np.ndarray
    E: float
    G: float
    rho: float
    A: float
    Ix: float
    Iy: float
    J: float
    Ip: float
    n_elements: int = 40

    def __post_init__(self) -> None:
        self.start = _vec3(self.start)
        self.end = _vec3(self.end)
        self.local_x = _vec3(self.local_x)
        if self.n_elements < 1:
            raise ValueError("n_elements must be >= 1")
        if np.linalg.norm(self.end - self.start) <= NODE_TOL:
            raise ValueError("segment has zero length")

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))


@dataclass
class PointBody:
    """Rigid body attached to a node.

    ``side`` only matters when the body sits at a :class:`JointSpring`:
    ``"outboard"`` (default) attaches it to the node of the segments starting
    there, ``"inboard"`` to the node of the segments ending there.
    """

    position: np.ndarray
    mass: float
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    com_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    side: str = "outboard"

    def __post_init__(self) -> None:
        self.position = _vec3(self.position)
        self.com_offset = _vec3(self.com_offset)
        self.inertia = np.asarray(self.inertia, dtype=float).reshape(3, 3)
        if self.side not in ("inboard", "outboard"):
            raise ValueError("side must be 'inboard' or 'outboard'")

    def mass_matrix(self) -> np.ndarray:
        """6x6 mass matrix referred to the node (DOFs u, theta)."""
        m = float(self.mass)
        C = _skew(self.com_offset)
        M = np.zeros((6, 6))
        M[:3, :3] = m * np.eye(3)
        M[:3, 3:] = -m * C
        M[3:, :3] = m * C
        M[3:, 3:] = self.inertia + m * (C.T @ C)
        return 0.5 * (M + M.T)


@dataclass
class JointSpring:
    """Rotational spring about ``axis`` between two coincident nodes at ``position``."""

    position: np.ndarray
    axis: np.ndarray
    stiffness: float

    def __post_init__(self) -> None:
        self.position = _vec3(self.position)
        a = _vec3(self.axis)
        n = np.linalg.norm(a)
        if n == 0.0:
            raise ValueError("spring axis must be non-zero")
        self.axis = a / n


def section_frame(seg: Segment) -> np.ndarray:
    """Rotation matrix whose columns are the local x, y, z axes in global coordinates."""
    ez = (seg.end - seg.start) / seg.length
    ex = seg.local_x - np.dot(seg.local_x, ez) * ez
    nx = np.linalg.norm(ex)
    if nx < 1e-12:
        raise ValueError("local_x is parallel to the beam axis")
    ex = ex / nx
    ey = np.cross(ez, ex)
    return np.column_stack([ex, ey, ez])


def _bending_k(EI: float, L: float) -> np.ndarray:
    """Stiffness for DOFs (w1, w1', w2, w2')."""
    return (EI / L**3) * np.array(
        [
            [12.0, 6 * L, -12.0, 6 * L],
            [6 * L, 4 * L**2, -6 * L, 2 * L**2],
            [-12.0, -6 * L, 12.0, -6 * L],
            [6 * L, 2 * L**2, -6 * L, 4 * L**2],
        ]
    )


def _bending_m(mu: float, L: float) -> np.ndarray:
    """Consistent translational mass for DOFs (w1, w1', w2, w2'); mu = rho A."""
    return (mu * L / 420.0) * np.array(
        [
            [156.0, 22 * L, 54.0, -13 * L],
            [22 * L, 4 * L**2, 13 * L, -3 * L**2],
            [54.0, 13 * L, 156.0, -22 * L],
            [-13 * L, -3 * L**2, -22 * L, 4 * L**2],
        ]
    )


# Local DOF numbering of an element: node a -> 0..5, node b -> 6..11, each
# (ux, uy, uz, rx, ry, rz) in the section frame.
# Deflection w_x: slope w_x' = +ry.  Deflection w_y: slope w_y' = -rx.
_WX_DOFS = (0, 4, 6, 10)
_WX_SIGN = np.array([1.0, 1.0, 1.0, 1.0])
_WY_DOFS = (1, 3, 7, 9)
_WY_SIGN = np.array([1.0, -1.0, 1.0, -1.0])


def _place(target: np.ndarray, block: np.ndarray, dofs, sign=None) -> None:
    if sign is not None:
        block = block * np.outer(sign, sign)
    idx = np.asarray(dofs)
    target[np.ix_(idx, idx)] += block


def element_matrices(seg: Segment, Le: float) -> tuple[np.ndarray, np.ndarray]:
    """Local 12x12 stiffness and consistent mass of one element of ``seg``."""
    K = np.zeros((12, 12))
    M = np.zeros((12, 12))
    bar = np.array([[1.0, -1.0], [-1.0, 1.0]])
    lin_m = np.array([[2.0, 1.0], [1.0, 2.0]]) / 6.0
    # axial (local z)
    _place(K, seg.E * seg.A / Le * bar, (2, 8))
    _place(M, seg.rho * seg.A * Le * lin_m, (2, 8))
    # torsion (about local z)
    _place(K, seg.G * seg.J / Le * bar, (5, 11))
    _place(M, seg.rho * seg.Ip * Le * lin_m, (5, 11))
    # bending, deflection w_x, resisted by Iy
    _place(K, _bending_k(seg.E * seg.Iy, Le), _WX_DOFS, _WX_SIGN)
    _place(M, _bending_m(seg.rho * seg.A, Le), _WX_DOFS, _WX_SIGN)
    # bending, deflection w_y, resisted by Ix
    _place(K, _bending_k(seg.E * seg.Ix, Le), _WY_DOFS, _WY_SIGN)
    _place(M, _bending_m(seg.rho * seg.A, Le), _WY_DOFS, _WY_SIGN)
    return K, M


def _hermite(xi: np.ndarray, L: float) -> np.ndarray:
    """Cubic Hermite shape functions for (w1, w1', w2, w2'), shape (n, 4)."""
    return np.column_stack(
        [
            1 - 3 * xi**2 + 2 * xi**3,
            L * (xi - 2 * xi**2 + xi**3),
            3 * xi**2 - 2 * xi**3,
            L * (-(xi**2) + xi**3),
        ]
    )


def _hermite_d(xi: np.ndarray, L: float) -> np.ndarray:
    """d/ds of the cubic Hermite shape functions, shape (n, 4)."""
    return np.column_stack(
        [
            (-6 * xi + 6 * xi**2) / L,
            1 - 4 * xi + 3 * xi**2,
            (6 * xi - 6 * xi**2) / L,
            -2 * xi + 3 * xi**2,
        ]
    )


class ModeShapes:
    """Mass-normalised mode shapes of the assembled model.

    Attributes
    ----------
    omega : (n_modes,) natural angular frequencies [rad/s]
    node_xyz : (n_nodes, 3) coordinates of all nodes (joint nodes appear twice)
    u : (n_modes, n_nodes, 6) nodal translations and rotations (global frame)
    segment_nodes : list of (n_elements + 1,) node indices along each segment
    """

    def __init__(self, omega, node_xyz, u, segments, segment_nodes, node_lookup):
        self.omega = omega
        self.node_xyz = node_xyz
        self.u = u
        self.segments = list(segments)
        self.segment_nodes = segment_nodes
        self._node_lookup = node_lookup

    @property
    def n_modes(self) -> int:
        return len(self.omega)

    def nodes(self, segment_index: int) -> np.ndarray:
        """Node coordinates along a segment, shape (n_elements + 1, 3)."""
        return self.node_xyz[self.segment_nodes[segment_index]]

    def node_values(self, segment_index: int) -> np.ndarray:
        """Translations and rotations at the segment nodes, shape (n_modes, n_nodes, 6)."""
        return self.u[:, self.segment_nodes[segment_index], :]

    def at(self, position, side: str = "outboard") -> np.ndarray:
        """Translation+rotation (n_modes, 6) at the node located at ``position``.

        At a joint spring ``side`` selects the inboard or the outboard node.
        """
        return self.u[:, self._node_lookup(_vec3(position), side), :]

    def sample(self, segment_index: int, s_fraction, what: str = "translation") -> np.ndarray:
        """Interpolate a segment's mode shapes at fractions ``s`` in [0, 1] of its length.

        Uses the element shape functions (linear for axial displacement and
        torsion, cubic Hermite for bending).  ``what`` is ``"translation"``
        (returns (n_modes, n_points, 3)), ``"rotation"`` ((n_modes, n_points, 3);
        bending rotations from the slope of the Hermite interpolant) or
        ``"both"`` ((n_modes, n_points, 6)).  All results in global coordinates.
        """
        seg = self.segments[segment_index]
        s = np.atleast_1d(np.asarray(s_fraction, dtype=float))
        if np.any(s < -1e-12) or np.any(s > 1 + 1e-12):
            raise ValueError("s_fraction must lie in [0, 1]")
        s = np.clip(s, 0.0, 1.0)
        ne = seg.n_elements
        Le = seg.length / ne
        R = section_frame(seg)
        el = np.minimum((s * ne).astype(int), ne - 1)
        xi = s * ne - el
        nodes = self.segment_nodes[segment_index]
        ua = self.u[:, nodes[el], :]  # (modes, pts, 6)
        ub = self.u[:, nodes[el + 1], :]
        # to local frame
        ta, ra = ua[..., :3] @ R, ua[..., 3:] @ R
        tb, rb = ub[..., :3] @ R, ub[..., 3:] @ R
        N = _hermite(xi, Le)  # (pts, 4)
        dN = _hermite_d(xi, Le)
        # w_x: (ux_a, ry_a, ux_b, ry_b)
        qx = np.stack([ta[..., 0], ra[..., 1], tb[..., 0], rb[..., 1]], axis=-1)
        # w_y: (uy_a, -rx_a, uy_b, -rx_b)
        qy = np.stack([ta[..., 1], -ra[..., 0], tb[..., 1], -rb[..., 0]], axis=-1)
        wx = np.einsum("mpk,pk->mp", qx, N)
        wy = np.einsum("mpk,pk->mp", qy, N)
        wz = (1 - xi) * ta[..., 2] + xi * tb[..., 2]
        trans = np.stack([wx, wy, wz], axis=-1) @ R.T
        rx = -np.einsum("mpk,pk->mp", qy, dN)
        ry = np.einsum("mpk,pk->mp", qx, dN)
        rz = (1 - xi) * ra[..., 2] + xi * rb[..., 2]
        rot = np.stack([rx, ry, rz], axis=-1) @ R.T
        if what == "translation":
            return trans
        if what == "rotation":
            return rot
        if what == "both":
            return np.concatenate([trans, rot], axis=-1)
        raise ValueError("what must be 'translation', 'rotation' or 'both'")


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.linalg.norm(a - b) <= NODE_TOL)


def assemble(
    segments: Sequence[Segment],
    bodies: Sequence[PointBody] = (),
    springs: Sequence[JointSpring] = (),
    clamp=None,
):
    """Assemble reduced stiffness/mass matrices.

    Returns ``(K, M, T, node_xyz, segment_nodes, node_lookup)`` where ``T`` maps
    the reduced coordinates to the full nodal DOF vector (6 per node).
    """
    if clamp is None:
        raise ValueError("a clamp point is required")
    clamp = _vec3(clamp)
    segments = list(segments)
    springs = list(springs)
    for i, sp in enumerate(springs):
        for other in springs[i + 1 :]:
            if _close(sp.position, other.position):
                raise ValueError("at most one joint spring per location")

    node_xyz: list[np.ndarray] = []
    # shared (end-point) nodes: list of (position, side, index); side is None
    # for rigid nodes and "inboard"/"outboard" at springs
    shared: list[tuple[np.ndarray, str | None, int]] = []

    def spring_at(p):
        for sp in springs:
            if _close(sp.position, p):
                return sp
        return None

    def shared_node(p, side):
        if spring_at(p) is None:
            side = None
        for q, sd, idx in shared:
            if sd == side and _close(q, p):
                return idx
        node_xyz.append(p.copy())
        shared.append((p.copy(), side, len(node_xyz) - 1))
        return len(node_xyz) - 1

    segment_nodes = []
    for seg in segments:
        ids = [shared_node(seg.start, "outboard")]
        for k in range(1, seg.n_elements):
            node_xyz.append(seg.start + (seg.end - seg.start) * k / seg.n_elements)
            ids.append(len(node_xyz) - 1)
        ids.append(shared_node(seg.end, "inboard"))
        segment_nodes.append(np.array(ids))

    # a spring at the clamp: the inboard node is the ground
    for sp in springs:
        if _close(sp.position, clamp):
            shared_node(sp.position, "inboard")

    node_xyz_arr = np.array(node_xyz)
    n_nodes = len(node_xyz_arr)
    nfull = 6 * n_nodes

    # --- full K, M
    K = np.zeros((nfull, nfull))
    M = np.zeros((nfull, nfull))
    for seg, ids in zip(segments, segment_nodes, strict=True):
        Le = seg.length / seg.n_elements
        Kl, Ml = element_matrices(seg, Le)
        R = section_frame(seg)
        Tl = np.kron(np.eye(4), R.T)  # global -> local
        Kg = Tl.T @ Kl @ Tl
        Mg = Tl.T @ Ml @ Tl
        for e in range(seg.n_elements):
            dofs = np.r_[6 * ids[e] : 6 * ids[e] + 6, 6 * ids[e + 1] : 6 * ids[e + 1] + 6]
            K[np.ix_(dofs, dofs)] += Kg
            M[np.ix_(dofs, dofs)] += Mg

    def node_lookup(p, side="outboard"):
        p = _vec3(p)
        for q, sd, idx in shared:
            if _close(q, p) and (sd is None or sd == side):
                return idx
        d = np.linalg.norm(node_xyz_arr - p, axis=1)
        i = int(np.argmin(d))
        if d[i] > NODE_TOL:
            raise ValueError(f"no node at {p}")
        return i

    for body in bodies:
        i = node_lookup(body.position, body.side)
        dofs = np.arange(6 * i, 6 * i + 6)
        M[np.ix_(dofs, dofs)] += body.mass_matrix()

    # --- reduction: clamp, spring master-slave
    fixed = np.zeros(n_nodes, dtype=bool)
    for q, sd, idx in shared:
        if _close(q, clamp) and sd in (None, "inboard"):
            fixed[idx] = True
    if not fixed.any():
        raise ValueError("no node at the clamp point")

    slave = {}  # outboard node -> (inboard node, spring)
    for sp in springs:
        ids = {sd: idx for q, sd, idx in shared if _close(q, sp.position)}
        if "inboard" not in ids or "outboard" not in ids:
            raise ValueError(f"joint spring at {sp.position} needs segments on both sides")
        slave[ids["outboard"]] = (ids["inboard"], sp)

    # column index of each independent DOF
    col = {}
    ncol = 0
    for i in range(n_nodes):
        if fixed[i] or i in slave:
            continue
        for d in range(6):
            col[(i, d)] = ncol
            ncol += 1
    phi_col = {}
    for i in slave:
        phi_col[i] = ncol
        ncol += 1

    T = np.zeros((nfull, ncol))
    for (i, d), c in col.items():
        T[6 * i + d, c] = 1.0
    for i, (master, sp) in slave.items():
        if not fixed[master]:
            for d in range(6):
                T[6 * i + d, col[(master, d)]] = 1.0
        T[6 * i + 3 : 6 * i + 6, phi_col[i]] = sp.axis

    Kr = T.T @ K @ T
    Mr = T.T @ M @ T
    for i, (_master, sp) in slave.items():
        Kr[phi_col[i], phi_col[i]] += sp.stiffness
    Kr = 0.5 * (Kr + Kr.T)
    Mr = 0.5 * (Mr + Mr.T)
    return Kr, Mr, T, node_xyz_arr, segment_nodes, node_lookup


def modes(
    segments: Sequence[Segment],
    bodies: Sequence[PointBody] = (),
    springs: Sequence[JointSpring] = (),
    clamp=None,
    n_modes: int = 6,
) -> tuple[np.ndarray, ModeShapes]:
    """Lowest ``n_modes`` natural angular frequencies [rad/s] and mode shapes."""
    Kr, Mr, T, node_xyz, segment_nodes, node_lookup = assemble(segments, bodies, springs, clamp)
    n = Kr.shape[0]
    n_modes = min(n_modes, n)
    try:
        # Inverse formulation M q = mu K q, mu = 1 / omega^2: the lowest modes are
        # the largest mu and are obtained to near machine precision, whereas
        # eigh(K, M) loses accuracy ~ eps * omega_max^2 / omega^2 (stiff
        # rotational DOFs with tiny rotary inertia make omega_max huge).
        mu, q = scipy.linalg.eigh(Mr, Kr, subset_by_index=[n - n_modes, n - 1])
        mu, q = mu[::-1], q[:, ::-1]
        if np.any(mu <= 0.0):
            raise np.linalg.LinAlgError("non-positive mu")
        lam = 1.0 / mu
    except np.linalg.LinAlgError:
        # K singular (e.g. a zero-stiffness spring): direct formulation
        lam, q = scipy.linalg.eigh(Kr, Mr, subset_by_index=[0, n_modes - 1])
    # mass-normalise
    q = q / np.sqrt(np.einsum("ik,ij,jk->k", q, Mr, q))
    omega = np.sqrt(np.clip(lam, 0.0, None))
    full = (T @ q).T.reshape(n_modes, -1, 6)
    shapes = ModeShapes(omega, node_xyz, full, segments, segment_nodes, node_lookup)
    return omega, shapes


# ----------------------------------------------------------------------------- robots
# The FE model of a robot problem file, built from the file's own numbers (read here with
# tomllib) and the conventions documented in problems/README.md: modified DH rows
# Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i); a beam spans a (local z along
# x_{i-1}, local y along the axis of joint i) or d (local frame = DH frame i); the section
# is turned by ``section_angle`` about the beam axis; side ``a`` of a rectangle lies along
# local y, side ``b`` along local x; a tip body sits at the end of its row's beam (for an
# ``a`` beam: inboard of joint i), its principal axes along the beam's local axes, or at
# the origin of DH frame i for a row without a beam. Nothing of casflex is used.


def rectangle_torsion_constant(a: float, b: float, terms: int = 200) -> float:
    """St-Venant J of a solid a × b rectangle [m^4], Saint-Venant's series.

    Written as Timoshenko & Goodier (Theory of Elasticity, 3rd ed., §109, eq. 167):
    ``J = (1/3) (2t)^3 (2h) [1 - (192/pi^5) (t/h) sum_{n=1,3,5..} tanh(n pi h / (2 t)) / n^5]
    / 8`` with 2h >= 2t the sides; validated against the published k1 table and a 2-D
    Prandtl stress-function solution in tests/tmm/test_reference_fem.py.
    """
    long_side, short_side = max(a, b), min(a, b)
    beta = long_side / short_side
    total = 0.0
    for k in range(terms):
        n = 2 * k + 1
        total += math.tanh(n * math.pi * beta / 2.0) / n**5
    k1 = (1.0 - 192.0 / (math.pi**5 * beta) * total) / 3.0
    return k1 * long_side * short_side**3


def prandtl_torsion_constant(a: float, b: float, n: int) -> float:
    """J of an a × b rectangle [m^4] from the Prandtl stress function, n cells across the
    short side.

    Solves ∇²φ = −2 on the rectangle, φ = 0 on its edge, with the 5-point finite
    difference scheme (second order), and returns J = 2 ∫ φ dA (trapezoidal rule, exact for
    the piecewise-bilinear interpolant and second-order accurate). Richardson-extrapolate
    two grids for ~1e-7 relative accuracy.
    """
    import scipy.sparse
    import scipy.sparse.linalg

    long_side, short_side = max(a, b), min(a, b)
    m = int(round(n * long_side / short_side))
    hx, hy = short_side / n, long_side / m
    nx, ny = n - 1, m - 1

    def lap1d(k, h):
        return scipy.sparse.diags([np.ones(k - 1), -2 * np.ones(k), np.ones(k - 1)],
                                  [-1, 0, 1]) / h**2

    L = scipy.sparse.kronsum(lap1d(ny, hy), lap1d(nx, hx), format="csc")
    phi = scipy.sparse.linalg.spsolve(L, -2.0 * np.ones(nx * ny))
    return float(2.0 * phi.sum() * hx * hy)


def section_constants(section: dict) -> dict:
    """A, Ix, Iy, J, Ip of a problem file's ``[link.section]`` table."""
    shape = section["shape"]
    if shape == "rectangle":
        a, b = float(section["a"]), float(section["b"])  # a along local y, b along local x
        return dict(A=a * b, Ix=b * a**3 / 12.0, Iy=a * b**3 / 12.0,
                    J=rectangle_torsion_constant(a, b), Ip=a * b * (a * a + b * b) / 12.0)
    if shape == "tube":
        ro = float(section["outer_diameter"]) / 2.0
        ri = ro - float(section["wall"])
        i = math.pi * (ro**4 - ri**4) / 4.0
        return dict(A=math.pi * (ro**2 - ri**2), Ix=i, Iy=i, J=2.0 * i, Ip=2.0 * i)
    if shape == "explicit":
        out = {k: float(section[k]) for k in ("A", "Ix", "Iy", "J")}
        out["Ip"] = float(section.get("Ip", out["Ix"] + out["Iy"]))
        return out
    raise ValueError(f"unknown section shape {shape!r}")


def angle_value(v) -> float:
    """An angle of a problem file [rad]: a number (rad) or ``{value, unit}``."""
    if isinstance(v, dict):
        value = float(v["value"])
        return math.radians(value) if v.get("unit", "rad") == "deg" else value
    return float(v)


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def dh_frames(rows: Sequence[dict], q) -> list[np.ndarray]:
    """Base-frame 4 × 4 poses of the DH frames of the problem file's ``[[link]]`` rows."""
    q = list(np.asarray(q, dtype=float).ravel())
    T = np.eye(4)
    out = []
    for row in rows:
        theta = angle_value(row.get("theta", 0.0))
        if row.get("joint", "fixed") == "revolute":
            theta += q.pop(0)
        step = np.eye(4)
        step[:3, :3] = _rot_x(angle_value(row.get("alpha", 0.0))) @ _rot_z(theta)
        # Rx(α) Tx(a) Rz(θ) Tz(d): origin at Rx(α)·(a, 0, 0) + R·(0, 0, d)
        step[:3, 3] = np.array([float(row.get("a", 0.0)), 0.0, 0.0]) + step[:3, :3] @ [
            0.0, 0.0, float(row.get("d", 0.0))]
        T = T @ step
        out.append(T.copy())
    if q:
        raise ValueError("more joint variables than revolute rows")
    return out


def robot_model(data: dict, q, n_elements: int = 40):
    """FE ``(segments, bodies, springs, clamp)`` of a parsed robot problem file at ``q``."""
    rows = data["link"]
    frames = dh_frames(rows, q)
    segments, bodies, springs = [], [], []
    prev = np.eye(4)
    for row, T in zip(rows, frames, strict=True):
        R_alpha = prev[:3, :3] @ _rot_x(angle_value(row.get("alpha", 0.0)))
        joint_point = prev[:3, 3] + R_alpha[:, 0] * float(row.get("a", 0.0))
        section = row.get("section")
        along_a = section is not None and float(row.get("a", 0.0)) != 0.0
        if section is not None:
            turn = _rot_z(angle_value(row.get("section_angle", 0.0)))
            if along_a:
                # local x, y, z = y_{i-1}, z_{i-1} (after Rx(α)), x_{i-1}
                local = np.column_stack([R_alpha[:, 1], R_alpha[:, 2], R_alpha[:, 0]]) @ turn
                start, end = prev[:3, 3], joint_point
            else:
                local = T[:3, :3] @ turn
                start, end = joint_point, T[:3, 3]
            mat = row["material"]
            segments.append(Segment(start, end, local[:, 0], E=float(mat["E"]),
                                    G=float(mat["G"]), rho=float(mat["rho"]),
                                    n_elements=n_elements, **section_constants(section)))
            body_point, body_axes = end, local
        else:
            body_point, body_axes = T[:3, 3], T[:3, :3]
        tip = row.get("tip")
        if tip is not None and (float(tip.get("mass", 0.0)) or any(tip.get("inertia", ()))):
            inertia = np.diag(np.asarray(tip.get("inertia", (0.0, 0.0, 0.0)), dtype=float))
            bodies.append(PointBody(
                body_point, float(tip.get("mass", 0.0)), body_axes @ inertia @ body_axes.T,
                body_axes @ np.asarray(tip.get("com_offset", (0.0, 0.0, 0.0)), dtype=float),
                side="inboard" if along_a and "joint_stiffness" in row else "outboard"))
        if "joint_stiffness" in row:
            springs.append(JointSpring(joint_point, T[:3, 2], float(row["joint_stiffness"])))
        prev = T
    return segments, bodies, springs, np.zeros(3)


def robot_modes(data: dict, q, n_modes: int = 6, n_elements: int = 40):
    """Lowest ``n_modes`` frequencies [rad/s] and mode shapes of a parsed problem file."""
    segments, bodies, springs, clamp = robot_model(data, q, n_elements)
    return modes(segments, bodies, springs, clamp=clamp, n_modes=n_modes)
