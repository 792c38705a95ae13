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
refined on ``det subU`` by batched subdivision and inverse cubic interpolation; a bracket that still
holds k ≥ 2 roots when narrower than ``double_tol`` is returned as a k-fold root, whose
mode shapes span the null space (orthonormal in base-reaction space, from an SVD).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError, SolverError
from casflex.tmm import elements as el
from casflex.tmm import fast, kernels, one_call
from casflex.tmm.chain import Chain, body_mass_global, build_chain
from casflex.tmm.conditioning import (
    check_chain,
    describe,
    format_q,
    stiffness_spread,
)

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = [
    "system_matrix",
    "frequency_determinant",
    "count_below",
    "natural_frequencies",
    "sweep_frequencies",
    "ModeShapes",
    "MODE_FIELDS",
    "mode_shapes",
    "modes",
]


def _as_chain(chain_or_robot, q):
    if isinstance(chain_or_robot, Chain):
        return chain_or_robot
    return build_chain(chain_or_robot, q)


class _Stack:
    """The elements of one robot at C configurations, stacked for batched evaluation.

    Every chain of a robot has the same element sequence (kinds and parameters); only
    the poses change with q. Points are evaluated in batches ``(cfg, omega)`` where
    ``cfg`` picks the configuration of each point, so that a whole sweep costs about as
    many numpy calls as one configuration.
    """

    def __init__(self, chains):
        first = chains[0]
        signature = [(e.kind, e.row) for e in first.elements]
        for chain in chains[1:]:
            if [(e.kind, e.row) for e in chain.elements] != signature:
                raise ValueError("chains of different structures cannot be stacked")
        self.size = len(chains)
        self.chains = chains
        check_chain(first)
        self.cap, self.reference_frequency, self.lowest_beam_frequency = fast.search_scales(
            first)
        self.items = []
        for j, e in enumerate(first.elements):
            same = [chain.elements[j] for chain in chains]
            data = {"element": e, "R3": np.array([x.R for x in same])}
            if e.kind == "beam":
                R = np.array([x.R for x in same])
                data["R12"] = np.array([x.rotation12 for x in same])
                data["R6"] = np.einsum("ab,cij->caibj", np.eye(2), R).reshape(-1, 6, 6)
            elif e.kind == "body":
                data["M"] = np.array([body_mass_global(x) for x in same])
            elif e.kind == "offset":
                data["T"] = np.array([el.offset_matrix(x.params["r"]) for x in same])
                G = np.broadcast_to(np.eye(6), (len(same), 6, 6)).copy()
                G[:, 0:3, 3:6] = -np.array([el.skew(x.params["r"]) for x in same])
                data["G"] = G
            else:  # spring
                k = e.params["stiffness"]
                data["T"] = np.array([el.joint_spring_matrix(k, x.params["axis"])
                                      for x in same])
                data["axis"] = np.array([x.params["axis"] for x in same])
            self.items.append(data)
        self.kernel = kernels.pack(self.items, self.size) if kernels.AVAILABLE else None

    def require_finite(self, values, cfg, omega, quantity):
        """Raise the breakdown error at the first point whose ``values`` are not finite."""
        if not np.isfinite(values).all():
            bad = int(np.flatnonzero(~np.isfinite(values.reshape(omega.size, -1)).all(1))[0])
            self.breakdown(int(cfg[bad]), float(omega[bad]), f"{quantity} is not finite")

    def breakdown(self, c, omega, what):
        """Raise a ModelError: configuration ``c``, the element where it broke, the quantity."""
        chain = self.chains[c]
        cfg, w = np.array([c]), np.array([omega])
        where, quantity = None, None
        forward, backward = [], []
        with np.errstate(all="ignore"):
            try:
                self.system(cfg, w, trace=forward)
            except (np.linalg.LinAlgError, ValueError):
                pass
            for e, element_ok, product_ok in forward:
                if not element_ok:
                    where, quantity = e, "its transfer matrix is not finite"
                    break
                if not product_ok:
                    where, quantity = e, "the chain product overflows at it"
                    break
            if where is None:
                try:
                    self.count(cfg, w, trace=backward)
                except (np.linalg.LinAlgError, ModelError):
                    pass
                for e, added, finite in backward:
                    if not finite:
                        where, quantity = e, "its condensed dynamic stiffness is not finite"
                        break
                    if what.startswith("the Wittrick") and added[0] > 0:
                        where, quantity = e, "its condensation adds the spurious count"
                        break
        message = f"TMM breakdown at q = {format_q(chain.q)} rad, ω = {omega:.6g} rad/s: {what}"
        if where is not None:
            message += f"; at the {where.label}, {quantity} ({describe(where)})"
        message += f"; {stiffness_spread(chain)[1]}"
        raise ModelError(message)

    def transfer(self, data, cfg, omega):
        """Base-frame transfer matrices of a body, offset or spring at the points (P, 12, 12)."""
        e = data["element"]
        if e.kind == "body":
            return el.point_body_matrix(omega, data["M"][cfg])
        return data["T"][cfg]

    def system(self, cfg, omega, columns=slice(6, 12), trace=None):
        """Columns of the system matrix (eq. 59), (P, 12, k).

        By default columns 6–11, the ones that multiply the base reactions of a clamped
        base; ``columns=slice(None)`` gives the whole 12 × 12 matrix. A list ``trace``
        receives ``(element, transfer matrix finite, product finite)`` per element.
        """
        if self.kernel is not None and trace is None and columns == slice(6, 12):
            k = self.kernel
            try:
                return kernels.system_points(
                    np.ascontiguousarray(cfg, dtype=np.int64),
                    np.ascontiguousarray(omega, dtype=float), k["kind"], k["beam"],
                    k["flat"], k["gather"], k["ratio"], k["R3"], k["M"], k["T"])
            except ZeroDivisionError:
                pass  # the numpy path below
        start = np.eye(12)[:, columns]
        U = np.broadcast_to(start, (omega.size,) + start.shape).copy()
        for data in self.items:
            e = data["element"]
            if e.kind == "beam":  # rotate the 12 x 6 block, not the 12 x 12 matrix
                P = e.params
                Rb = data["R12"][cfg]
                B = el.beam_matrix(P["length"], omega, P["section"], P["material"])
                U = Rb @ (B @ (np.swapaxes(Rb, 1, 2) @ U))
            else:
                B = self.transfer(data, cfg, omega)
                U = B @ U
            if trace is not None:
                trace.append((e, bool(np.isfinite(B).all()), bool(np.isfinite(U).all())))
        return U

    def det(self, cfg, omega):
        """Row-scaled ``det subU``: same zeros and sign, no overflow (eq. 60)."""
        sub = self.system(cfg, omega)[:, 6:12, :]
        scale = np.max(np.abs(sub), axis=2, keepdims=True)
        return np.linalg.det(sub / np.where(scale > 0.0, scale, 1.0))

    def slogdet(self, cfg, omega):
        """Sign and log-magnitude of ``det subU`` at the points."""
        return np.linalg.slogdet(self.system(cfg, omega)[:, 6:12, :])

    def count(self, cfg, omega, trace=None):
        """Wittrick–Williams count of natural frequencies below each point's ω.

        A list ``trace`` receives ``(element, negative pivots added, condensed stiffness
        finite)`` per element, tip first (for the breakdown diagnosis).
        """
        if self.kernel is not None and trace is None:
            k = self.kernel
            try:
                counts, finite = kernels.count_points(
                    np.ascontiguousarray(cfg, dtype=np.int64),
                    np.ascontiguousarray(omega, dtype=float), k["kind"], k["beam"],
                    k["flat"], k["gather"], k["ratio"], k["R3"], k["M"], k["G"], k["axis"],
                    k["stiffness"])
                if finite.all():
                    return counts.astype(int)
            except (np.linalg.LinAlgError, ZeroDivisionError):
                pass  # a singular matrix at one point: the numpy path's branches below
        n = omega.size
        Z = np.zeros((n, 6, 6))
        count = np.zeros(n)
        w2 = omega**2
        for data in reversed(self.items):
            e = data["element"]
            before = count.copy() if trace is not None else None
            if e.kind == "body":
                Z = Z - w2[:, None, None] * data["M"][cfg]
            elif e.kind == "offset":
                G = data["G"][cfg]
                Z = np.swapaxes(G, 1, 2) @ Z @ G
            elif e.kind == "spring":
                ev = np.zeros((n, 6))
                ev[:, 3:6] = data["axis"][cfg]
                Ze = np.einsum("pij,pj->pi", Z, ev)
                p = np.einsum("pi,pi->p", Ze, ev) + e.params["stiffness"]
                count += p < 0.0
                Z = Z - Ze[:, :, None] * Ze[:, None, :] / p[:, None, None]
            else:  # condense the beam's distal node in the beam's local frame
                R6 = data["R6"][cfg]
                R6t = np.swapaxes(R6, 1, 2)
                K00, K01, K10, K11 = _beam_stiffness(e, omega)
                pivot = K11 + R6t @ Z @ R6
                if trace is None:
                    self.require_finite(pivot, cfg, omega, "the condensed dynamic stiffness")
                count += _negatives(pivot)
                Z = R6 @ (K00 - K01 @ _solve(pivot, K10)) @ R6t
                count += _beam_j0(e, omega)
            if trace is not None:
                trace.append((e, count - before, bool(np.isfinite(Z).all())))
        if trace is None:  # comparisons with NaN are False: NaN would undercount
            self.require_finite(Z, cfg, omega, "the condensed dynamic stiffness")
        return count.astype(int)


def _single(chain, omega):
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    return _Stack([chain]), np.zeros(omega.size, dtype=int), omega


def system_matrix(chain: Chain, omega: ArrayLike) -> np.ndarray:
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
    stack, cfg, omega = _single(chain, omega)
    return stack.system(cfg, omega, columns=slice(None))


def frequency_determinant(chain: Chain, omega: ArrayLike) -> np.ndarray:
    """``det subU(ω)`` with rows scaled to unit peak: zero exactly at the natural frequencies.

    Parameters
    ----------
    chain : Chain
        From :func:`casflex.tmm.chain.build_chain`.
    omega : array_like, shape (N,)
        Frequencies [rad/s].

    Returns
    -------
    numpy.ndarray, shape (N,)
        Scaled determinants (dimensionless).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm.chain import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0, 0, 0])
    >>> frequency_determinant(chain, [1.0]).shape
    (1,)
    >>> w1 = natural_frequencies(chain, count=1)[0]           # a root of the determinant
    >>> d = frequency_determinant(chain, [0.9 * w1, 1.1 * w1])
    >>> bool(d[0] * d[1] < 0)
    True
    """
    stack, cfg, omega = _single(chain, omega)
    return stack.det(cfg, omega)


# ------------------------------------------------------------------ Wittrick–Williams


def _clamped_bending_count(beta):
    """Clamped–clamped Euler–Bernoulli frequencies with λL below ``beta``."""
    i = np.floor(beta / np.pi)
    sgn = np.sign(1.0 - np.cosh(beta) * np.cos(beta))
    # below the first root (λL = 4.730) the count is 0; the formula's sign rounds to 0
    # there when β⁴/6 < eps (a stiff beam at a very low ω)
    return np.where(beta < 4.0, 0.0, i - (1.0 - (-1.0) ** i * sgn) / 2.0)


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


def _solve(A, B):
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:  # exactly singular at one ω (measure zero): least squares
        return np.linalg.pinv(A) @ B


#: state permutation [u, θ, M, F] -> [u, θ, F, M]
_CONJUGATE = np.array([0, 1, 2, 3, 4, 5, 9, 10, 11, 6, 7, 8])


def _beam_stiffness(element, omega):
    """Dynamic stiffness blocks of a beam in its local frame, DOFs ``[u, θ]`` per end.

    Built from the local transfer matrix, whose blocks do not mix the large bending
    entries into the axial and torsional ones.
    """
    P = element.params
    T = el.beam_matrix(P["length"], omega, P["section"], P["material"])
    T = T[:, _CONJUGATE][:, :, _CONJUGATE]  # forces as [F, M], work-conjugate to [u, θ]
    Tdd, Tdf, Tfd, Tff = T[:, :6, :6], T[:, :6, 6:], T[:, 6:, :6], T[:, 6:, 6:]
    try:
        Tdf_inv = np.linalg.inv(Tdf)
    except np.linalg.LinAlgError:
        Tdf_inv = np.linalg.pinv(Tdf)
    K00 = Tdf_inv @ Tdd
    K10 = Tfd - Tff @ K00
    K11 = Tff @ Tdf_inv
    return K00, -Tdf_inv, K10, K11


def count_below(chain: Chain, omega: ArrayLike) -> np.ndarray:
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
    >>> count_below(chain, [1.0, 10.0, 20.0]).tolist()   # 8.31 and 11.97 rad/s lie between
    [0, 1, 2]
    """
    stack, cfg, omega = _single(chain, omega)
    return stack.count(cfg, omega)


# ------------------------------------------------------------------ root search


def _refine(stack, cfg, a, b, points=12, rounds=3):
    """Refine brackets that each hold exactly one simple root of ``det subU``.

    Every round evaluates ``det`` at ``points`` interior points of every bracket in one
    batched call and keeps the sub-interval with the sign change; after ``rounds``
    rounds (a reduction of ``(points + 1) ** rounds``) the root is found by inverse
    cubic interpolation through the four samples around the sign change, which is
    accurate to far below 1e-12 relative at that spacing. Values are ``sign · exp(log
    |det| − max)`` per bracket (from ``slogdet``): no overflow, and no kinks from a
    varying scaling. With the compiled kernels, Brent's method runs on each bracket
    instead (about 10 evaluations per root, to 5e-15 relative). Returns the roots and a
    mask of the brackets where a sign change was found.
    """
    if stack.kernel is not None:  # Brent's method per bracket, compiled
        k = stack.kernel
        root, ok, _ = kernels.refine_brackets(
            np.ascontiguousarray(cfg, dtype=np.int64), np.ascontiguousarray(a, dtype=float),
            np.ascontiguousarray(b, dtype=float), k["kind"], k["beam"], k["flat"],
            k["gather"], k["ratio"], k["R3"], k["M"], k["T"])
        return root, ok
    n = a.size
    rows = np.arange(n)
    frac = np.linspace(0.0, 1.0, points + 2)
    ok = np.ones(n, dtype=bool)
    for _ in range(rounds):
        x = a[:, None] + (b - a)[:, None] * frac[None, :]
        sign, logabs = stack.slogdet(np.repeat(cfg, frac.size), x.ravel())
        if np.isnan(logabs).any() or np.isposinf(logabs).any():
            i = int(np.flatnonzero(~(logabs < np.inf))[0])
            stack.breakdown(int(np.repeat(cfg, frac.size)[i]), float(x.ravel()[i]),
                            "det subU is not finite")
        logabs = logabs.reshape(x.shape)
        f = sign.reshape(x.shape) * np.exp(logabs - logabs.max(axis=1, keepdims=True))
        change = np.signbit(f[:, :-1]) != np.signbit(f[:, 1:])
        ok &= change.any(axis=1)
        k = np.argmax(change, axis=1)
        a, b = x[rows, k], x[rows, k + 1]
    j = np.clip(k - 1, 0, frac.size - 4)[:, None] + np.arange(4)[None, :]
    xs, fs = x[rows[:, None], j], f[rows[:, None], j]
    # inverse interpolation: x as a cubic in f, evaluated at f = 0
    root = np.zeros(n)
    with np.errstate(invalid="ignore", divide="ignore"):
        for i in range(4):
            term = xs[:, i].copy()
            for m in range(4):
                if m != i:
                    term *= (0.0 - fs[:, m]) / (fs[:, i] - fs[:, m])
            root += term
        fk, fk1 = f[rows, k], f[rows, k + 1]
        linear = a - fk * (b - a) / (fk1 - fk)
    d = np.diff(fs, axis=1)
    monotone = np.all(d > 0.0, axis=1) | np.all(d < 0.0, axis=1)
    good = monotone & np.isfinite(root) & (root >= a) & (root <= b)
    root = np.where(good, root, linear)
    root = np.where(np.isfinite(root), root, 0.5 * (a + b))
    return root, ok


def _check_counts(stack, points, counts):
    """Breakdown unless the counts are 0 at the probe and never decrease with ω."""
    spurious = counts[:, 0] > 0
    if spurious.any():
        c = int(np.flatnonzero(spurious)[0])
        stack.breakdown(c, float(points[0]), (
            f"the Wittrick–Williams count finds {counts[c, 0]} natural frequencies below "
            f"{points[0]:.3g} rad/s, 1e-6 of the lowest beam frequency, where a clamped "
            "robot of plausible proportions has none: its static stiffness came out "
            "indefinite (ill-conditioned) or a mass or spring is out of proportion"))
    falling = np.diff(counts, axis=1) < 0
    if falling.any():
        c, j = (int(v[0]) for v in np.nonzero(falling))
        stack.breakdown(c, float(points[j + 1]), (
            f"the Wittrick–Williams count falls from {counts[c, j]} at {points[j]:.6g} rad/s "
            f"to {counts[c, j + 1]} at {points[j + 1]:.6g} rad/s (it can only grow: "
            "ill-conditioned)"))


def _roots(stack, count, omega_max, double_tol, rtol):
    """Roots of every configuration of ``stack``: list of (values, multiplicities)."""
    C = stack.size
    # with the grid, a probe far below any physical natural frequency (1e-6 of the softest
    # beam's cantilever frequency): a clamped structure has a positive definite static
    # stiffness, so a count above 0 there means the condensation lost its precision
    probe, grid = fast.search_points(stack.reference_frequency, stack.lowest_beam_frequency,
                                     omega_max)
    points = np.concatenate([[probe], grid])
    if stack.kernel is not None:  # the whole search compiled; the path below diagnoses
        found = kernels.search(stack.kernel, points, stack.cap, count, omega_max, double_tol,
                               rtol)
        if found is not None:
            return found
    cfg_all = np.repeat(np.arange(C), points.size)
    counts = stack.count(cfg_all, np.tile(points, C)).reshape(C, points.size)
    _check_counts(stack, np.concatenate([[probe], grid]), counts)
    counts = counts[:, 1:]
    if omega_max is None:
        while counts[:, -1].min() < count and grid[-1] < stack.cap:
            more = np.geomspace(grid[-1] * 2.0, min(grid[-1] * 256.0, stack.cap), 8)
            extra = stack.count(np.repeat(np.arange(C), more.size), np.tile(more, C))
            grid = np.concatenate([grid, more])
            counts = np.concatenate([counts, extra.reshape(C, more.size)], axis=1)
            _check_counts(stack, grid, counts)
        if counts[:, -1].min() < count:
            c = int(np.argmin(counts[:, -1]))
            raise SolverError(
                f"configuration {c}: fewer than {count} natural frequencies below "
                f"{grid[-1]:g} rad/s, the highest frequency at which the beam transfer "
                "matrices stay accurate")
        want = np.full(C, count)
    else:
        want = counts[:, -1] if count is None else np.minimum(count, counts[:, -1])

    # brackets between consecutive grid points, per configuration
    lo = np.tile(np.concatenate([[0.0], grid[:-1]]), C)
    hi = np.tile(grid, C)
    nlo = np.concatenate([np.zeros((C, 1), int), counts[:, :-1]], axis=1).ravel()
    nhi = counts.ravel()
    cfg = np.repeat(np.arange(C), grid.size)

    simple, multiples = [], []
    while lo.size:
        keep = (nhi > nlo) & (nlo < want[cfg])
        lo, hi, nlo, nhi, cfg = lo[keep], hi[keep], nlo[keep], nhi[keep], cfg[keep]
        if not lo.size:
            break
        one = nhi - nlo == 1
        narrow = (hi - lo) <= double_tol * hi
        simple.append((lo[one], hi[one], cfg[one]))
        multi = ~one & narrow
        multiples.append((0.5 * (lo[multi] + hi[multi]), nhi[multi] - nlo[multi], cfg[multi]))
        split = ~one & ~narrow
        lo, hi, nlo, nhi, cfg = lo[split], hi[split], nlo[split], nhi[split], cfg[split]
        if not lo.size:
            break
        mid = 0.5 * (lo + hi)
        nmid = stack.count(cfg, mid)
        lo, hi = np.concatenate([lo, mid]), np.concatenate([mid, hi])
        nlo, nhi = np.concatenate([nlo, nmid]), np.concatenate([nmid, nhi])
        cfg = np.concatenate([cfg, cfg])

    a = np.concatenate([s[0] for s in simple]) if simple else np.zeros(0)
    b = np.concatenate([s[1] for s in simple]) if simple else np.zeros(0)
    scfg = np.concatenate([s[2] for s in simple]) if simple else np.zeros(0, int)
    a = np.maximum(a, 1e-12 * b)
    r = a.copy()
    if a.size:
        r, ok = _refine(stack, scfg, a, b)
        for i in np.flatnonzero(~ok):
            # no sign change seen (det underflow or a root at a bracket end): bisect on
            # the exact counts instead
            lo_i, hi_i = a[i], b[i]
            n_i = stack.count(scfg[i : i + 1], np.array([lo_i]))[0]
            while hi_i - lo_i > rtol * hi_i:
                m = 0.5 * (lo_i + hi_i)
                if stack.count(scfg[i : i + 1], np.array([m]))[0] > n_i:
                    hi_i = m
                else:
                    lo_i = m
            r[i] = 0.5 * (lo_i + hi_i)
    roots = np.concatenate([r] + [m[0] for m in multiples])
    mult = np.concatenate([np.ones(r.size, int)] + [m[1] for m in multiples]).astype(int)
    rcfg = np.concatenate([scfg] + [m[2] for m in multiples]).astype(int)
    bad = ~(roots > probe) | ~np.isfinite(roots)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        stack.breakdown(int(rcfg[i]), float(probe), f"a natural frequency of {roots[i]:.6g} "
                        f"rad/s, at or below the static probe {probe:.3g} rad/s")

    out = []
    for c in range(C):
        sel = rcfg == c
        order = np.argsort(roots[sel])
        rc, mc = roots[sel][order], mult[sel][order]
        values, multiplicity = np.repeat(rc, mc), np.repeat(mc, mc)
        if count is not None:
            values, multiplicity = values[:count], multiplicity[:count]
        if omega_max is not None:
            keep = values <= omega_max
            values, multiplicity = values[keep], multiplicity[keep]
        out.append((values, multiplicity))
    return out


def natural_frequencies(chain_or_robot: Chain | Robot, q: ArrayLike | None = None,
                        count: int | None = None, omega_max: float | None = None, *,
                        double_tol: float = 1e-9, rtol: float = 1e-12,
                        return_multiplicity: bool = False
                        ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
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
    numpy.ndarray or tuple of numpy.ndarray
        Ascending frequencies, repeated according to multiplicity; with
        ``return_multiplicity`` the pair ``(frequencies, multiplicities)``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> natural_frequencies(load("problems/arm2link.toml"), [0, 0, 0], count=3).round(2)
    array([ 8.31, 11.97, 22.75])
    """
    if count is None and omega_max is None:
        raise ValueError("give count, omega_max or both")
    found = None
    if not isinstance(chain_or_robot, Chain):
        one = one_call.single(chain_or_robot, q, count, omega_max, double_tol, rtol, 0)
        if one is not None:
            found = [one[:2]]
        else:
            found, _ = fast.roots(chain_or_robot, q, count, omega_max, double_tol, rtol)
    if found is None:
        chain = _as_chain(chain_or_robot, q)
        found = _roots(_Stack([chain]), count, omega_max, double_tol, rtol)
    values, multiplicity = found[0]
    if return_multiplicity:
        return values, multiplicity
    return values


def sweep_frequencies(robot: Robot, qs: ArrayLike, count: int, *, double_tol: float = 1e-9,
                      rtol: float = 1e-12) -> np.ndarray:
    """The ``count`` lowest natural frequencies at many configurations at once [rad/s].

    All configurations are solved together: every numpy call of the root search works
    on the points of every configuration, so a sweep costs little more than one
    configuration.

    Parameters
    ----------
    robot : casflex.robot.Robot
    qs : array_like
        (k, n_joints) configurations [rad].
    count : int
        Frequencies per configuration (a double root counts twice).

    Returns
    -------
    numpy.ndarray
        (k, count) ascending frequencies per configuration.

    Examples
    --------
    >>> from casflex.robot import load
    >>> w = sweep_frequencies(load("problems/arm2link.toml"), [[0, 0, 0], [0, 0, -1]], 2)
    >>> w.round(2)
    array([[ 8.31, 11.97],
           [ 6.61,  9.31]])
    """
    roots, _ = fast.roots(robot, qs, count, None, double_tol, rtol)
    if roots is None:
        chains = [build_chain(robot, q) for q in np.atleast_2d(np.asarray(qs, dtype=float))]
        roots = _roots(_Stack(chains), count, None, double_tol, rtol)
    return np.array([values for values, _ in roots])


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

    Examples
    --------
    >>> from casflex.robot import load
    >>> shapes = modes(load("problems/arm2link.toml"), [0.0, 0.0, 0.0], count=2)
    >>> shapes.omega.round(3), shapes.rows
    (array([ 8.307, 11.97 ]), (2, 3))
    >>> shapes.s.shape, shapes.displacement.shape   # (beams, points), (modes, beams, points, 3)
    ((2, 51), (2, 2, 51, 3))
    >>> float(np.abs(shapes.displacement).max().round(12))   # unit peak displacement
    1.0
    """

    omega: np.ndarray
    multiplicity: np.ndarray
    s: np.ndarray
    rows: tuple[int, ...]
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
    body_rows: tuple[int, ...]
    spring_rotation: np.ndarray
    spring_rows: tuple[int, ...]

    @property
    def displacement_global(self) -> np.ndarray:
        """(m, n_beams, n_points, 3) displacements in the base frame [m]."""
        return np.einsum("bij,mbpj->mbpi", self.R, self.displacement)


#: :class:`ModeShapes` fields indexed by mode first: a change of mode basis (mass
#: normalisation, tracking) transforms all of them alike.
MODE_FIELDS = (
    "displacement", "rotation", "moment", "force", "slope", "curvature", "twist_rate",
    "axial_strain", "body_state", "body_state_local", "spring_rotation",
)


def _null_vectors(subU):
    """Right singular vectors of ``subU`` (m, 6, 6), smallest singular value last.

    Each matrix is scaled as a whole: scaling its rows separately would blow up rows that
    vanish at a multiple root (their noise becomes of unit size) and spoil the null space.
    """
    scale = np.max(np.abs(subU), axis=(1, 2), keepdims=True)
    _, _, vt = np.linalg.svd(subU / np.where(scale > 0.0, scale, 1.0))
    return vt


def mode_shapes(chain: Chain, omega: ArrayLike, multiplicity: ArrayLike | None = None,
                n_points: int = 51) -> ModeShapes:
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
    return _shapes(chain, _Stack([chain]), omega, multiplicity, n_points)


def _shapes(chain, stack, omega, multiplicity, n_points):
    """:func:`mode_shapes` with the chain's stack already built."""
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    m = omega.size
    mult = np.ones(m, dtype=int) if multiplicity is None else np.asarray(multiplicity, int)
    if stack.kernel is not None:
        arrays = dict(stack.kernel, start=np.array([[e.start for e in chain.elements]]))
        shapes = _compiled_shapes(fast.shape_layout(chain.elements, n_points), arrays,
                                  omega, mult)
        if shapes is not None:
            return shapes
    # base reactions f0 of every mode; a k-fold root contributes k basis vectors
    f0 = np.empty((m, 6))
    cfg = np.zeros(m, dtype=int)
    vt = _null_vectors(stack.system(cfg, omega)[:, 6:12, :])
    j = 0
    while j < m:
        k = int(mult[j])
        f0[j : j + k] = vt[j, -k:]  # an orthonormal basis of the k-dimensional null space
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
    for j, (element, data) in enumerate(zip(chain.elements, stack.items, strict=True)):
        if element.kind == "beam":
            P = element.params
            sec, mat = P["section"], P["material"]
            Rt = data["R12"][0].T  # blockdiag(Rᵀ): base to local components
            z_loc = z @ Rt.T  # (m, 12) local components at the beam start
            if stack.kernel is not None:
                k = stack.kernel
                local[:, ib] = kernels.field_points(
                    k["beam"][j], k["flat"][j], k["gather"][j], k["ratio"][j],
                    np.ascontiguousarray(s[ib]), omega, np.ascontiguousarray(z_loc))
            else:
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
            z = np.einsum("mij,mj->mi", stack.transfer(data, cfg, omega), z)

    # a k-fold root: the SVD basis is orthonormal in base-reaction space, but the map to
    # shapes can be far from isometric (the shapes of two basis vectors nearly parallel).
    # Recombine each group so that its sampled [u, θ] fields are orthonormal instead.
    j = 0
    while j < m:
        k = int(mult[j])
        if k > 1:
            S = local[j : j + k, ..., 0:6].reshape(k, -1)
            U_, sig, _ = np.linalg.svd(S, full_matrices=False)
            A = (U_ / sig[None, :]).T  # rows of A @ S are orthonormal
            local[j : j + k] = np.einsum("ab,b...->a...", A, local[j : j + k])
            body_state = [np.concatenate([b[:j], A @ b[j : j + k], b[j + k :]])
                          for b in body_state]
            body_local = [np.concatenate([b[:j], A @ b[j : j + k], b[j + k :]])
                          for b in body_local]
            spring_rotation = [np.concatenate([v[:j], A @ v[j : j + k], v[j + k :]])
                               for v in spring_rotation]
        j += k

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


def modes(robot: Robot, q: ArrayLike, count: int | None = 5, omega_max: float | None = None,
          n_points: int = 51) -> ModeShapes:
    """Natural frequencies and mode shapes of ``robot`` at configuration ``q``.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Joint variables [rad].
    count : int or None
        Number of lowest modes (a double root counts twice); ``None`` with ``omega_max``
        gives every mode below it.
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
    array([1.322, 1.905, 3.62 ])
    """
    if count is None and omega_max is None:
        raise ValueError("give count, omega_max or both")
    one = one_call.single(robot, q, count, omega_max, 1e-9, 1e-12, n_points)  # the defaults
    if one is not None:  # the same kernels as below, in one compiled call
        if one[2] is not None:
            return ModeShapes(**one[2])
        found = [one[:2]]
    else:
        found, posed = fast.roots(robot, q, count, omega_max, 1e-9, 1e-12)
    if one is None and found is not None:
        w, mult = found[0]
        if (mult == 1).all():  # simple roots: the compiled shapes
            shapes = _compiled_shapes(posed[0].shape_layout(n_points), posed[1], w, mult)
            if shapes is not None:
                return shapes
    chain = build_chain(robot, q)
    stack = _Stack([chain])  # one stack for the roots and the shapes
    if found is None:
        found = _roots(stack, count, omega_max, 1e-9, 1e-12)
    w = found[0][0]
    present = np.array([int(np.count_nonzero(w == v)) for v in w], dtype=int)
    return _shapes(chain, stack, w, present, n_points)


def _compiled_shapes(layout, arrays, omega, multiplicity):
    """:func:`mode_shapes` by the compiled kernel (:func:`casflex.tmm.fast.compiled_shapes`)
    or None (a multiple root, no kernels, no null vector: the numpy path)."""
    fields = fast.compiled_shapes(layout, arrays, omega, multiplicity)
    return None if fields is None else ModeShapes(**fields)
