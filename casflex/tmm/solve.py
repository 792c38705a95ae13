"""Natural frequencies and mode shapes of a chain (eq. 59–62).

Root search
-----------
The natural frequencies are the ω at which the block ``subU`` of the system transfer
matrix that maps the base reactions to the tip forces is singular (clamped base, free
tip, eq. 60). A sign-change scan of ``det subU`` misses double roots (a straight tube
bends at the same frequency in two planes) and near-double roots closer than the scan
step, so casflex first *counts* the natural frequencies below any ω with the
Wittrick–Williams algorithm and only then refines:

``N(ω) = J0(ω) + s{K(ω)}``

where ``J0`` sums the clamped–clamped natural frequencies of every beam below ω (known in
closed form) and ``s{K}`` is the number of negative eigenvalues of the structure's dynamic
stiffness matrix, obtained by condensing the chain from the free tip to the clamped base
(a block LDLᵀ factorisation; Sylvester's law of inertia makes the count exact). Bisection
on ``N`` isolates every root with its multiplicity; a bracket holding one simple root is
refined with Ridders' method on ``det subU``; a bracket that still
holds k ≥ 2 roots when narrower than ``double_tol`` is returned as a k-fold root, whose
mode shapes span the null space (orthonormal in base-reaction space, from an SVD).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from casflex.errors import SolverError
from casflex.tmm import elements as el
from casflex.tmm.chain import Chain, body_mass_global, build_chain, element_transfer

__all__ = [
    "system_matrix",
    "frequency_determinant",
    "count_below",
    "natural_frequencies",
    "ModeShapes",
    "mode_shapes",
    "modes",
]


def _as_chain(chain_or_robot, q):
    if isinstance(chain_or_robot, Chain):
        return chain_or_robot
    return build_chain(chain_or_robot, q)


def system_matrix(chain, omega):
    """System transfer matrix from the clamped base to the free tip (eq. 59), (N, 12, 12).

    Parameters
    ----------
    chain : Chain
    omega : array_like
        [rad/s].

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm.chain import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0, 0, 0])
    >>> system_matrix(chain, [1.0, 2.0]).shape
    (2, 12, 12)
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    U = np.broadcast_to(np.eye(12), (omega.size, 12, 12))
    for element in chain.elements:
        U = element_transfer(element, omega) @ U
    return U


def frequency_determinant(chain, omega):
    """``det subU(ω)``: zero exactly at the natural frequencies (eq. 60).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm.chain import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0, 0, 0])
    >>> frequency_determinant(chain, [1.0]).shape
    (1,)
    """
    sub = system_matrix(chain, omega)[:, 6:12, 6:12]
    # rows scaled to unit peak: same zeros and sign, no overflow at high frequency
    scale = np.max(np.abs(sub), axis=2, keepdims=True)
    return np.linalg.det(sub / np.where(scale > 0.0, scale, 1.0))


# ------------------------------------------------------------------ Wittrick–Williams


def _clamped_bending_count(beta):
    """Clamped–clamped Euler–Bernoulli frequencies with λL below ``beta``."""
    i = np.floor(beta / np.pi)
    sgn = np.sign(1.0 - np.cosh(beta) * np.cos(beta))
    return i - (1.0 - (-1.0) ** i * sgn) / 2.0


def _beam_j0(element, omega):
    P = element.params
    sec, mat, L = P["section"], P["material"], P["length"]
    axial = np.floor(omega * L * np.sqrt(mat.rho / mat.E) / np.pi)
    torsion = np.floor(omega * L * np.sqrt(mat.rho * sec.Ip / (mat.G * sec.J)) / np.pi)
    mu = mat.rho * sec.A
    bx = L * np.sqrt(omega) * (mu / (mat.E * sec.Iy)) ** 0.25
    by = L * np.sqrt(omega) * (mu / (mat.E * sec.Ix)) ** 0.25
    return axial + torsion + _clamped_bending_count(bx) + _clamped_bending_count(by)


def _negatives(A):
    A = 0.5 * (A + np.swapaxes(A, -1, -2))
    return np.sum(np.linalg.eigvalsh(A) < 0.0, axis=-1)


#: state permutation [u, θ, M, F] -> [u, θ, F, M]
_CONJUGATE = np.array([0, 1, 2, 3, 4, 5, 9, 10, 11, 6, 7, 8])


def _solve(A, B):
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:  # exactly singular at one ω (measure zero): least squares
        return np.linalg.pinv(A) @ B


def _beam_stiffness(element, omega):
    """Dynamic stiffness blocks of a beam, base-frame components, DOFs ``[u, θ]`` per end.

    Built from the local transfer matrix (whose blocks do not mix the large bending
    entries into the axial and torsional ones) and rotated afterwards.
    """
    P = element.params
    T = el.beam_matrix(P["length"], omega, P["section"], P["material"])
    T = T[:, _CONJUGATE][:, :, _CONJUGATE]  # forces as [F, M], work-conjugate to [u, θ]
    Tdd, Tdf, Tfd, Tff = T[:, :6, :6], T[:, :6, 6:], T[:, 6:, :6], T[:, 6:, 6:]
    Tdf_inv = np.linalg.pinv(Tdf) if np.any(np.linalg.det(Tdf) == 0.0) else np.linalg.inv(Tdf)
    K00 = Tdf_inv @ Tdd
    K01 = -Tdf_inv
    K10 = Tfd - Tff @ K00
    K11 = Tff @ Tdf_inv
    R6 = np.kron(np.eye(2), element.R)
    return (R6 @ K00 @ R6.T, R6 @ K01 @ R6.T, R6 @ K10 @ R6.T, R6 @ K11 @ R6.T)


def count_below(chain, omega):
    """Number of natural frequencies below each ω (Wittrick–Williams), counted with multiplicity.

    Parameters
    ----------
    chain : Chain
    omega : array_like
        [rad/s], > 0.

    Returns
    -------
    numpy.ndarray of int

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm.chain import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0, 0, 0])
    >>> count_below(chain, [1.0, 10.0, 20.0]).tolist()   # 8.26 and 11.9 rad/s lie between
    [0, 1, 2]
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    n = omega.size
    Z = np.zeros((n, 6, 6))
    count = np.zeros(n)
    w2 = omega**2
    for element in reversed(chain.elements):
        kind = element.kind
        if kind == "body":
            Z = Z - w2[:, None, None] * body_mass_global(element)[None]
        elif kind == "offset":
            G = np.eye(6)
            G[0:3, 3:6] = -el.skew(element.params["r"])
            Z = G.T @ Z @ G
        elif kind == "spring":
            e = np.zeros(6)
            e[3:6] = element.params["axis"]
            Ze = Z @ e
            p = Ze @ e + element.params["stiffness"]
            count += p < 0.0
            Z = Z - Ze[:, :, None] * Ze[:, None, :] / p[:, None, None]
        else:  # beam: dynamic stiffness from the transfer blocks
            K00, K01, K10, K11 = _beam_stiffness(element, omega)
            pivot = K11 + Z
            count += _negatives(pivot)
            Z = K00 - K01 @ _solve(pivot, K10)
            count += _beam_j0(element, omega)
    return count.astype(int)


# ------------------------------------------------------------------ root search


def _ridders(f, lo, hi, flo, fhi, rtol=1e-12, max_iter=60):
    """Vectorised Ridders' method on brackets with ``flo * fhi < 0``.

    Ridders fits an exponential through the bracket ends and the midpoint, which suits
    the exponentially growing determinant of beam transfer matrices; each iteration
    costs two batched evaluations and keeps a valid bracket.
    """
    lo, hi, flo, fhi = (np.array(a, dtype=float) for a in (lo, hi, flo, fhi))
    x = 0.5 * (lo + hi)
    active = np.ones(lo.size, dtype=bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        a, b, fa, fb = lo[idx], hi[idx], flo[idx], fhi[idx]
        m = 0.5 * (a + b)
        fm = f(m)
        root = np.sqrt(np.maximum(fm * fm - fa * fb, 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            xn = m + (m - a) * np.sign(fa - fb) * fm / root
        xn = np.where(np.isfinite(xn) & (xn > a) & (xn < b), xn, m)
        fx = f(xn)
        # new bracket from the four points a < (m, xn) < b with a sign change
        pts = np.stack([a, np.minimum(m, xn), np.maximum(m, xn), b], axis=1)
        fpts = np.stack([fa, np.where(m <= xn, fm, fx), np.where(m <= xn, fx, fm), fb], axis=1)
        change = np.sign(fpts[:, :-1]) != np.sign(fpts[:, 1:])
        k = np.argmax(change, axis=1)
        r = np.arange(idx.size)
        lo[idx], hi[idx] = pts[r, k], pts[r, k + 1]
        flo[idx], fhi[idx] = fpts[r, k], fpts[r, k + 1]
        step = np.abs(xn - x[idx])
        x[idx] = xn
        exact = fx == 0.0
        active[idx] = ~exact & (hi[idx] - lo[idx] > rtol * hi[idx]) & (step > rtol * xn)
    return np.where(hi - lo <= rtol * hi, 0.5 * (lo + hi), x)


def _omega_cap(chain, lambda_l=80.0):
    """Highest ω [rad/s] at which every beam keeps λL ≤ ``lambda_l`` (cosh within range)."""
    cap = np.inf
    for b in chain.beams:
        sec, mat, L = b.params["section"], b.params["material"], b.params["length"]
        ei = mat.E * min(sec.Ix, sec.Iy)
        cap = min(cap, (lambda_l / L) ** 2 * np.sqrt(ei / (mat.rho * sec.A)))
    return cap


def natural_frequencies(chain_or_robot, q=None, count=None, omega_max=None, *,
                        double_tol=1e-9, rtol=1e-12, return_multiplicity=False):
    """Natural frequencies of a chain, every root with its multiplicity [rad/s].

    Parameters
    ----------
    chain_or_robot : Chain or casflex.robot.Robot
    q : array_like, optional
        Joint variables [rad] when a robot is given.
    count : int, optional
        Number of lowest frequencies wanted (each double root counts twice).
    omega_max : float, optional
        Return every frequency below this [rad/s]. Give ``count``, ``omega_max`` or both.
    double_tol : float
        Relative width below which a bracket still holding k ≥ 2 roots is a k-fold root.
    rtol : float
        Relative tolerance of the refined simple roots.
    return_multiplicity : bool
        Also return the multiplicity of each returned value.

    Returns
    -------
    numpy.ndarray
        Ascending frequencies, repeated according to multiplicity.

    Examples
    --------
    >>> from casflex.robot import load
    >>> natural_frequencies(load("problems/arm2link.toml"), [0, 0, 0], count=3).round(2)
    array([ 8.26, 11.94, 23.36])
    """
    if count is None and omega_max is None:
        raise ValueError("give count, omega_max or both")
    chain = _as_chain(chain_or_robot, q)

    def N(w):
        return count_below(chain, w)

    cap = _omega_cap(chain)
    if omega_max is None:
        grid = np.geomspace(1e-2, 1e2, 13)
        counts = N(grid)
        while counts[-1] < count and grid[-1] < cap:
            more = np.geomspace(grid[-1] * 2.0, min(grid[-1] * 256.0, cap), 8)
            grid, counts = np.concatenate([grid, more]), np.concatenate([counts, N(more)])
        reach = np.flatnonzero(counts >= count)
        if reach.size == 0:
            raise SolverError(
                f"fewer than {count} natural frequencies below {grid[-1]:g} rad/s, the "
                "highest frequency at which the beam transfer matrices stay accurate")
        last = reach[0]
    else:
        top = float(omega_max)
        grid = np.geomspace(min(1e-2, top / 10.0), top, 24)
        counts = N(grid)
        last = grid.size - 1
    want = counts[last] if count is None else min(count, counts[last])
    lo = np.concatenate([[0.0], grid[:last]])
    hi = grid[: last + 1]
    nlo = np.concatenate([[0], counts[:last]])
    nhi = counts[: last + 1]

    simple_lo, simple_hi, multiples = [], [], []
    while lo.size:
        keep = (nhi > nlo) & (nlo < want)
        lo, hi, nlo, nhi = lo[keep], hi[keep], nlo[keep], nhi[keep]
        if not lo.size:
            break
        one = nhi - nlo == 1
        narrow = (hi - lo) <= double_tol * hi
        simple_lo.extend(lo[one])
        simple_hi.extend(hi[one])
        multi = ~one & narrow
        for a, b, k in zip(lo[multi], hi[multi], nhi[multi] - nlo[multi], strict=True):
            multiples.append((0.5 * (a + b), int(k)))
        split = ~one & ~narrow
        lo, hi, nlo, nhi = lo[split], hi[split], nlo[split], nhi[split]
        if not lo.size:
            break
        mid = 0.5 * (lo + hi)
        nmid = N(mid)
        lo, hi = np.concatenate([lo, mid]), np.concatenate([mid, hi])
        nlo, nhi = np.concatenate([nlo, nmid]), np.concatenate([nmid, nhi])

    roots, mult = [], []
    if simple_lo:
        a, b = np.array(simple_lo), np.array(simple_hi)
        a = np.maximum(a, 1e-12 * b)

        def det(w):
            return frequency_determinant(chain, w)

        fa, fb = det(a), det(b)
        bad = ~(fa * fb < 0.0)
        if bad.any():
            # a degenerate bracket end (det exactly 0 or tiny underflow): bisect on counts
            for i in np.flatnonzero(bad):
                lo_i, hi_i, n_i = a[i], b[i], N([a[i]])[0]
                for _ in range(200):
                    m = 0.5 * (lo_i + hi_i)
                    if N([m])[0] > n_i:
                        hi_i = m
                    else:
                        lo_i = m
                    if hi_i - lo_i <= rtol * hi_i:
                        break
                a[i] = b[i] = 0.5 * (lo_i + hi_i)
            fa[bad], fb[bad] = -1.0, 1.0
        good = ~bad
        r = np.where(good, 0.0, a)
        if good.any():
            r[good] = _ridders(det, a[good], b[good], fa[good], fb[good], rtol=rtol)
        roots.extend(r)
        mult.extend([1] * r.size)
    for w, k in multiples:
        roots.append(w)
        mult.append(k)
    order = np.argsort(roots)
    roots = np.asarray(roots)[order]
    mult = np.asarray(mult, dtype=int)[order]
    values = np.repeat(roots, mult)
    multiplicity = np.repeat(mult, mult)
    if count is not None:
        values, multiplicity = values[:count], multiplicity[:count]
    if omega_max is not None:
        keep = values <= omega_max
        values, multiplicity = values[keep], multiplicity[keep]
    if return_multiplicity:
        return values, multiplicity
    return values


# ------------------------------------------------------------------ mode shapes


@dataclass(frozen=True)
class ModeShapes:
    """Mode shapes of a chain sampled along every beam.

    Shapes are scaled to unit peak displacement over all sample points, with the
    largest displacement component positive (mass normalisation is done by
    :mod:`casflex.modal`). Arrays are indexed ``[mode, beam, point, ...]``.

    Attributes
    ----------
    omega : numpy.ndarray
        (m,) natural frequencies [rad/s].
    multiplicity : numpy.ndarray
        (m,) multiplicity of each frequency.
    s : numpy.ndarray
        (n_beams, n_points) arc length from each beam's start [m].
    rows : tuple of int
        DH row of each beam.
    R : numpy.ndarray
        (n_beams, 3, 3) local-to-base rotation of each beam.
    position : numpy.ndarray
        (n_beams, n_points, 3) undeformed sample points in the base frame [m].
    displacement : numpy.ndarray
        (m, n_beams, n_points, 3) ``w_x, w_y, w_z`` in the local beam frame [m].
    rotation : numpy.ndarray
        (m, n_beams, n_points, 3) ``θ_x, θ_y, θ_z`` (θ_z is the torsion) [rad].
    moment, force : numpy.ndarray
        (m, n_beams, n_points, 3) internal resultants in the local frame [N m], [N].
    slope : numpy.ndarray
        (m, n_beams, n_points, 2) ``w_x', w_y'`` [rad].
    curvature : numpy.ndarray
        (m, n_beams, n_points, 2) ``w_x'', w_y''`` [1/m].
    twist_rate : numpy.ndarray
        (m, n_beams, n_points) ``θ_z'`` [rad/m].
    axial_strain : numpy.ndarray
        (m, n_beams, n_points) ``w_z'`` [-].
    body_state : numpy.ndarray
        (m, n_bodies, 6) ``[u, θ]`` of every tip body's attachment point, base frame.
    body_state_local : numpy.ndarray
        (m, n_bodies, 6) the same in each body's local frame.
    body_position : numpy.ndarray
        (n_bodies, 3) attachment points [m].
    body_rows : tuple of int
        DH row of each tip body.
    spring_rotation : numpy.ndarray
        (m, n_springs) rotation of the outboard side relative to the inboard side of every
        joint spring [rad].
    spring_rows : tuple of int
        DH row of each joint spring.
    """

    omega: np.ndarray
    multiplicity: np.ndarray
    s: np.ndarray
    rows: tuple
    R: np.ndarray
    position: np.ndarray
    displacement: np.ndarray
    rotation: np.ndarray
    moment: np.ndarray
    force: np.ndarray
    slope: np.ndarray
    curvature: np.ndarray
    twist_rate: np.ndarray
    axial_strain: np.ndarray
    body_state: np.ndarray
    body_state_local: np.ndarray
    body_position: np.ndarray
    body_rows: tuple
    spring_rotation: np.ndarray
    spring_rows: tuple

    @property
    def displacement_global(self):
        """(m, n_beams, n_points, 3) displacements in the base frame [m]."""
        return np.einsum("bij,mbpj->mbpi", self.R, self.displacement)


def _null_basis(subU, k):
    """Orthonormal basis (6, k) of the k-dimensional (near) null space of ``subU``."""
    scale = np.max(np.abs(subU), axis=1, keepdims=True)
    scale[scale == 0.0] = 1.0
    _, _, vt = np.linalg.svd(subU / scale)
    return vt[-k:].T


def mode_shapes(chain, omega, multiplicity=None, n_points=51):
    """Mode shapes at the given natural frequencies (eq. 61–62).

    Parameters
    ----------
    chain : Chain
    omega : array_like
        Natural frequencies [rad/s], repeated for multiple roots.
    multiplicity : array_like of int, optional
        Multiplicity of each entry (1 if omitted).
    n_points : int
        Sample points per beam, ends included.

    Returns
    -------
    ModeShapes

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm.chain import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0, 0, 0])
    >>> w = natural_frequencies(chain, count=2)
    >>> mode_shapes(chain, w, n_points=11).displacement.shape
    (2, 2, 11, 3)
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    m = omega.size
    mult = np.ones(m, dtype=int) if multiplicity is None else np.asarray(multiplicity, int)
    # base reactions f0 of every mode; a k-fold root contributes k basis vectors
    f0 = np.empty((m, 6))
    subU = system_matrix(chain, omega)[:, 6:12, 6:12]
    j = 0
    while j < m:
        k = int(mult[j])
        f0[j : j + k] = _null_basis(subU[j], k).T
        j += k
    z = np.zeros((m, 12))
    z[:, 6:] = f0

    beams = chain.beams
    nb = len(beams)
    frac = np.linspace(0.0, 1.0, n_points)
    s = np.array([frac * b.params["length"] for b in beams]).reshape(nb, n_points)
    local = np.zeros((m, nb, n_points, 12))
    position = np.zeros((nb, n_points, 3))
    body_state, body_local, body_position, body_rows = [], [], [], []
    spring_rotation, spring_rows = [], []
    ib = 0
    for element in chain.elements:
        if element.kind == "beam":
            P = element.params
            sec, mat = P["section"], P["material"]
            Rt = el.rotation_matrix(element.R.T)
            z_loc = z @ Rt.T  # (m, 12) local components at the beam start
            U = el.beam_field(
                s[ib][None, :], omega[:, None], mat.E * sec.A, mat.E * sec.Ix,
                mat.E * sec.Iy, mat.G * sec.J, mat.rho * sec.A, mat.rho * sec.Ip,
            )  # (m, n_points, 12, 12)
            local[:, ib] = np.einsum("mpij,mj->mpi", U, z_loc)
            position[ib] = element.start + s[ib][:, None] * element.R[:, 2]
            z = local[:, ib, -1] @ Rt  # back to base components at the beam end
            ib += 1
        else:
            if element.kind == "body":
                body_state.append(z[:, :6].copy())
                R6t = np.kron(np.eye(2), element.R.T)
                body_local.append(z[:, :6] @ R6t.T)
                body_position.append(element.start)
                body_rows.append(element.row)
            elif element.kind == "spring":
                P = element.params
                spring_rotation.append(z[:, 6:9] @ P["axis"] / P["stiffness"])
                spring_rows.append(element.row)
            z = np.einsum("mij,mj->mi", element_transfer(element, omega), z)

    disp = local[..., 0:3]
    rot = local[..., 3:6]
    mom = local[..., 6:9]
    frc = local[..., 9:12]
    EIx = np.array([b.params["material"].E * b.params["section"].Ix for b in beams])
    EIy = np.array([b.params["material"].E * b.params["section"].Iy for b in beams])
    GJ = np.array([b.params["material"].G * b.params["section"].J for b in beams])
    EA = np.array([b.params["material"].E * b.params["section"].A for b in beams])
    slope = np.stack([rot[..., 1], -rot[..., 0]], axis=-1)
    curvature = np.stack(
        [mom[..., 1] / EIy[None, :, None], -mom[..., 0] / EIx[None, :, None]], axis=-1)
    twist_rate = mom[..., 2] / GJ[None, :, None]
    axial_strain = frc[..., 2] / EA[None, :, None]
    body_state = np.stack(body_state, axis=1) if body_state else np.zeros((m, 0, 6))
    body_local = np.stack(body_local, axis=1) if body_local else np.zeros((m, 0, 6))
    spring_rotation = (np.stack(spring_rotation, axis=1) if spring_rotation
                       else np.zeros((m, 0)))

    # scale: unit peak displacement, largest component positive
    flat = disp.reshape(m, -1)
    peak_idx = np.argmax(np.abs(flat), axis=1)
    peak = flat[np.arange(m), peak_idx]
    peak[peak == 0.0] = 1.0
    scale = 1.0 / peak

    def sc(a):
        return a * scale.reshape((m,) + (1,) * (a.ndim - 1))

    return ModeShapes(
        omega=omega, multiplicity=mult, s=s, rows=chain.beam_rows,
        R=np.array([b.R for b in beams]).reshape(nb, 3, 3), position=position,
        displacement=sc(disp), rotation=sc(rot), moment=sc(mom), force=sc(frc),
        slope=sc(slope), curvature=sc(curvature), twist_rate=sc(twist_rate),
        axial_strain=sc(axial_strain), body_state=sc(body_state),
        body_state_local=sc(body_local), body_position=np.array(body_position).reshape(-1, 3),
        body_rows=tuple(body_rows), spring_rotation=sc(spring_rotation),
        spring_rows=tuple(spring_rows),
    )


def modes(robot, q, count=5, omega_max=None, n_points=51):
    """Natural frequencies and mode shapes of ``robot`` at configuration ``q``.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Joint variables [rad].
    count : int
        Number of lowest modes (a double root counts twice).
    omega_max : float, optional
        Upper frequency limit [rad/s].
    n_points : int
        Sample points per beam.

    Returns
    -------
    ModeShapes

    Examples
    --------
    >>> from casflex.robot import load
    >>> shapes = modes(load("problems/arm2link.toml"), [0.0, 0.0, 0.0], count=3)
    >>> (shapes.omega / (2 * np.pi)).round(3)
    array([1.315, 1.9  , 3.718])
    """
    chain = build_chain(robot, q)
    w, mult = natural_frequencies(chain, count=count, omega_max=omega_max,
                                  return_multiplicity=True)
    # a k-fold root cut short by `count` keeps the entries present: that many basis vectors
    _, inverse, present = np.unique(w, return_inverse=True, return_counts=True)
    return mode_shapes(chain, w, present[inverse], n_points=n_points)
