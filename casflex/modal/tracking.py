"""Mode identity and sign across configurations: the modified MAC (§3.3.6.1, eq. 119–121).

The natural frequencies returned by the TMM are sorted, so the *k*-th frequency at one
configuration need not belong to the same physical mode as the *k*-th at the next: modes
cross (dissertation Fig. 25). Mode shapes also come with an arbitrary sign and, at a
multiple root, as an arbitrary basis of the degenerate subspace. This module follows every
mode from one configuration to the next so that frequencies and shapes vary smoothly
(Fig. 26).

The modified MAC
----------------
For a one-dimensional shape the MAC of two modes is
``MAC = (φ1ᵀφ2)² / ((φ1ᵀφ1)(φ2ᵀφ2))``. For 3-D shapes over several links the
dissertation sums the products of all components over all sample points of all links
(eq. 119–120): ``w_x, w_y, w_z`` and the torsion ``θ_z`` of every link, in the *local*
link frames (which move with the joints, so that the same physical mode has the same
components in neighbouring configurations). casflex reads this as an inner product

``<φ1, φ2> = Σ_links Σ_points c_p (w1·w2 + r² θ1z θ2z) + Σ_bodies u1ᵀ M_b u2``

with two weightings:

``"uniform"``
    the literal sum of eq. 119–120: ``c_p = 1``, ``r = 1`` (θ_z in rad added to
    displacements in m, as printed), no tip bodies.
``"mass"`` (default when the robot is known)
    the discrete kinetic-energy inner product: ``c_p = ρA Δs`` (trapezoidal weights of the
    sample points), ``r² = I_p/A`` (torsional inertia ρI_p), and every tip body's 6 × 6
    mass matrix acting on its local ``[u, θ]``. It is dimensionally consistent and makes
    distinct modes of one configuration nearly orthogonal (exactly, up to quadrature), so
    the MAC separates them as well as possible; bodies matter for arms whose joint-spring
    modes mostly move lumped masses (the testbed).

The MAC is ``<φ1,φ2>² / (<φ1,φ1><φ2,φ2>)`` and the sign rule of eq. 121 uses the sign of
the same inner product (eq. 121 sums the displacement products only; with the weighting
above it is the same rule with the torsion and bodies included).

Tracking
--------
Along a path of configurations every tracked mode is matched to the mode of the next
configuration that maximises the total MAC (a linear assignment, so two tracked modes can
never claim the same mode), and its sign is chosen so that the signed correlation with
its predecessor is positive. At a configuration with a multiple root (e.g. the Table 8 arm
folded at q3 = 90°, link 2 on link 1) any orthogonal combination of the degenerate shapes
is a mode; following §3.3.6.1 ("approximated based on the ones in the direct vicinity")
the combination is taken from the neighbours: the next non-degenerate configuration is
matched directly to the previous one, the two neighbours' tracked shapes are blended
(linearly in the path position) and projected onto the degenerate subspace, and the
orthogonal combination closest to the projections is kept (orthogonal Procrustes). The
TMM should be asked for a few more modes than needed (``count + 2``) so that a mode
crossing in from above is in the set and can be followed.

Grids of several shape joints are tracked along a spanning tree: along axis 0 with every
other index at 0 (the spine), then from each spine point along axis 1, and so on (a
"comb"). Neighbours joined by grid edges that are not in the tree are checked afterwards
(``GridTracking.edge_correlation``). Around a conical intersection of two modes in a 2-D
parameter space no continuous choice of sign exists at all; those edges show up there.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.tmm.solve import MODE_FIELDS  # the per-mode fields combine() transforms

if TYPE_CHECKING:
    from casflex.robot import Robot
    from casflex.tmm.solve import ModeShapes

__all__ = [
    "shape_features",
    "mac",
    "correlation",
    "combine",
    "Tracking",
    "track",
    "GridTracking",
    "track_grid",
    "track_grid_features",
    "point_tracking_data",
    "track_path_features",
    "tracked_unit_features",
]


def _trapezoid_weights(s):
    """Trapezoidal quadrature weights of the sample points ``s`` (n_points,)."""
    s = np.asarray(s, dtype=float)
    w = np.zeros_like(s)
    if s.size > 1:
        ds = np.diff(s)
        w[:-1] += 0.5 * ds
        w[1:] += 0.5 * ds
    else:
        w[:] = 1.0
    return w


def _sqrt_psd(M):
    """A factor ``L`` with ``L Lᵀ = M`` for a symmetric positive semi-definite ``M``."""
    e, V = np.linalg.eigh(0.5 * (M + M.T))
    return V * np.sqrt(np.clip(e, 0.0, None))


def shape_features(shapes: ModeShapes, robot: Robot | None = None,
                   weighting: str | None = None) -> np.ndarray:
    """Feature vectors whose dot products are the modified-MAC inner product.

    Parameters
    ----------
    shapes : casflex.tmm.ModeShapes
        Mode shapes of one configuration.
    robot : casflex.robot.Robot, optional
        Needed for the ``"mass"`` weighting (sections, materials, tip bodies).
    weighting : {"mass", "uniform"}, optional
        ``"mass"`` (default with a robot) or ``"uniform"`` (default without), see the
        module notes.

    Returns
    -------
    numpy.ndarray
        (n_modes, n_features); ``F @ F.T`` is the matrix of inner products ``<φi, φj>``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> F = shape_features(modes(robot, [0, 0, 0.3], count=3), robot)
    >>> G = F @ F.T   # mass-weighted: distinct modes are (nearly) orthogonal
    >>> bool(abs(G[0, 1]) < 1e-3 * np.sqrt(G[0, 0] * G[1, 1]))
    True
    """
    if weighting is None:
        weighting = "uniform" if robot is None else "mass"
    if weighting not in ("mass", "uniform"):
        raise ModelError(f"weighting must be 'mass' or 'uniform'; got {weighting!r}")
    if weighting == "mass" and robot is None:
        raise ModelError("the 'mass' weighting needs the robot (sections, materials, bodies)")
    disp = np.asarray(shapes.displacement, dtype=float)  # (m, nb, np, 3)
    tors = np.asarray(shapes.rotation, dtype=float)[..., 2]  # (m, nb, np)
    m = disp.shape[0]
    parts = []
    if weighting == "uniform":
        parts.append(disp.reshape(m, -1))
        parts.append(tors.reshape(m, -1))
        return np.concatenate(parts, axis=1)
    for ib, row in enumerate(shapes.rows):
        link = robot.links[row]
        c = _trapezoid_weights(shapes.s[ib])
        rho_a = link.material.rho * link.section.A
        rho_ip = link.material.rho * link.section.Ip
        parts.append((disp[:, ib] * np.sqrt(rho_a * c)[None, :, None]).reshape(m, -1))
        parts.append(tors[:, ib] * np.sqrt(rho_ip * c)[None, :])
    state = np.asarray(shapes.body_state_local, dtype=float)
    for jb, row in enumerate(shapes.body_rows):
        tip = robot.links[row].tip
        parts.append(state[:, jb] @ _body_factor(tip.mass, tip.inertia, tip.com_offset))
    return np.concatenate(parts, axis=1)


_BODY_FACTORS: dict[tuple[float, bytes, bytes], np.ndarray] = {}


def _body_factor(mass, inertia, com_offset):
    """``L`` with ``L Lᵀ`` = the tip body's 6 × 6 mass matrix (memoised: a grid's tracking
    asks for the same few bodies at every point)."""
    from casflex.tmm.elements import body_mass_matrix

    key = (float(mass), np.asarray(inertia, dtype=float).tobytes(),
           np.asarray(com_offset, dtype=float).tobytes())
    L = _BODY_FACTORS.get(key)
    if L is None:
        L = _sqrt_psd(body_mass_matrix(mass, inertia, com_offset))
        L.setflags(write=False)
        _BODY_FACTORS[key] = L
    return L


def _as_features(x, robot, weighting):
    if isinstance(x, np.ndarray):
        return np.atleast_2d(x)
    return shape_features(x, robot, weighting)


def correlation(a: ModeShapes | np.ndarray, b: ModeShapes | np.ndarray,
                robot: Robot | None = None, weighting: str | None = None) -> np.ndarray:
    """Signed normalised correlation ``<φa, φb> / (|φa| |φb|)`` of every pair of modes.

    Parameters
    ----------
    a, b : ModeShapes or numpy.ndarray
        Mode shapes, or feature arrays from :func:`shape_features`.
    robot, weighting
        As in :func:`shape_features`.

    Returns
    -------
    numpy.ndarray
        (n_a, n_b) values in [-1, 1]; ``correlation**2`` is the MAC, the sign is the sign
        test of eq. 121.

    Examples
    --------
    >>> c = correlation(np.array([[1.0, 0.0], [1.0, 1.0]]), np.array([[-2.0, 0.0]]))
    >>> c.round(3).tolist()
    [[-1.0], [-0.707]]
    """
    fa = _as_features(a, robot, weighting)
    fb = _as_features(b, robot, weighting)
    na = _row_norms(fa)
    nb = _row_norms(fb)
    na[na == 0.0] = 1.0
    nb[nb == 0.0] = 1.0
    return (fa @ fb.T) / np.outer(na, nb)


def mac(a: ModeShapes | np.ndarray, b: ModeShapes | np.ndarray, robot: Robot | None = None,
        weighting: str | None = None) -> np.ndarray:
    """Modified modal assurance criterion of every pair of modes (eq. 119–120).

    Parameters
    ----------
    a, b : ModeShapes or numpy.ndarray
        Mode shapes, or feature arrays from :func:`shape_features`.
    robot, weighting
        As in :func:`shape_features`.

    Returns
    -------
    numpy.ndarray
        (n_a, n_b) values in [0, 1]; 1 means the same shape up to scale and sign.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> m = mac(modes(robot, [0, 0, 0.30], count=3), modes(robot, [0, 0, 0.32], count=3), robot)
    >>> bool(np.all(np.diag(m) > 0.99))
    True
    """
    return correlation(a, b, robot, weighting) ** 2


def combine(shapes: ModeShapes, transform: ArrayLike,
            order: ArrayLike | None = None) -> ModeShapes:
    """Apply a linear recombination of the modes to every per-mode field of ``shapes``.

    Parameters
    ----------
    shapes : ModeShapes
        Raw modes (m of them).
    transform : numpy.ndarray
        (n, m): tracked mode ``j`` is ``Σ_i transform[j, i] · raw mode i``.
    order : array_like of int, optional
        (n,) raw mode whose frequency and multiplicity each tracked mode takes (default:
        the largest entry of each row).

    Returns
    -------
    ModeShapes
        n modes; the non-modal fields (geometry) are shared with ``shapes``. Every
        multiplicity is 1: a combined mode is one definite mode (a degenerate subspace
        has been resolved), and modes of one root need not be adjacent any more.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> raw = modes(load("problems/arm2link.toml"), [0, 0, 0], count=3)
    >>> swapped = combine(raw, np.array([[0, -1.0, 0], [1.0, 0, 0]]))
    >>> bool(swapped.omega[0] == raw.omega[1]), bool(np.all(swapped.displacement[0]
    ...     == -raw.displacement[1]))
    (True, True)
    """
    T = np.asarray(transform, dtype=float)
    if order is None:
        order = np.argmax(np.abs(T), axis=1)
    order = np.asarray(order, dtype=int)
    changes = {"omega": np.asarray(shapes.omega)[order],
               "multiplicity": np.ones(order.size, dtype=int)}
    for name in MODE_FIELDS:
        a = np.asarray(getattr(shapes, name))
        changes[name] = np.tensordot(T, a, axes=(1, 0))
    return dataclasses.replace(shapes, **changes)


# ------------------------------------------------------------------ one path


def _groups(shapes, rel_tol):
    """Index arrays of the (numerically) equal-frequency groups of one configuration."""
    w = np.asarray(shapes.omega, dtype=float)
    mult = np.asarray(shapes.multiplicity, dtype=int)
    groups, i = [], 0
    while i < w.size:
        j = i + 1
        while j < w.size and (mult[i] > 1 and j < i + mult[i]
                              or abs(w[j] - w[i]) <= rel_tol * max(abs(w[i]), 1e-300)):
            j += 1
        groups.append(np.arange(i, j))
        i = j
    return groups


def _row_norms(F, keepdims=False):
    """``np.linalg.norm(F, axis=1)``, the same arithmetic without its call overhead (a
    grid's tracking makes hundreds of these on a few rows)."""
    return np.sqrt(np.add.reduce(F * F, axis=1, keepdims=keepdims))


def _unit_rows(F):
    n = _row_norms(F, keepdims=True)
    n[n == 0.0] = 1.0
    return F / n


def _match(ref, F):
    """Signed assignment of the tracked reference rows to the modes ``F`` (no degeneracy)."""
    C = correlation(ref, F)
    C2 = C**2
    rows, cols = np.arange(C.shape[0]), np.argmax(C2, axis=1)
    # each row's strict maximum in a column of its own is the unique best assignment:
    # the one linear_sum_assignment returns (it is called otherwise)
    if (np.unique(cols).size < cols.size
            or (C2 == C2[rows, cols][:, None]).sum(axis=1).max() > 1):
        from scipy.optimize import linear_sum_assignment  # lazy: a warm model needs none

        rows, cols = linear_sum_assignment(-C2)
    T = np.zeros((ref.shape[0], F.shape[0]))
    sgn = np.where(C[rows, cols] < 0.0, -1.0, 1.0)
    T[rows, cols] = sgn
    return T, C[rows, cols] ** 2


def _fit_subspaces(ref, F, groups):
    """Combinations of the degenerate groups of ``F`` closest to the reference rows.

    Returns the (n, m) transform and the MAC of every tracked row with its reference.
    """
    n, m = ref.shape[0], F.shape[0]
    R = _unit_rows(ref)
    bases, coefs = [], []
    score = np.zeros((n, m))
    for g in groups:
        Fg = F[g]
        Gm = Fg @ Fg.T
        e, V = np.linalg.eigh(0.5 * (Gm + Gm.T))
        keep = e > 1e-14 * max(e.max(), 1e-300)
        C = (V[:, keep] / np.sqrt(e[keep])).T  # rows: coefficients of an orthonormal basis
        B = C @ Fg
        bases.append(B)
        coefs.append(C)
        frac = np.sum((R @ B.T) ** 2, axis=1)  # subspace MAC of every reference row
        score[:, g] = frac[:, None]
    from scipy.optimize import linear_sum_assignment  # lazy: a warm model needs none

    rows, cols = linear_sum_assignment(-score)
    T = np.zeros((n, m))
    quality = np.zeros(n)
    owner = np.empty(m, dtype=int)
    for k, g in enumerate(groups):
        owner[g] = k
    assigned = {}
    for r, c in zip(rows, cols, strict=True):
        assigned.setdefault(owner[c], []).append(r)
    for k, js in assigned.items():
        g, B, C = groups[k], bases[k], coefs[k]
        js = np.array(sorted(js))
        A = R[js] @ B.T  # projections of the references on the orthonormal basis
        U, _, Vt = np.linalg.svd(A, full_matrices=False)
        Q = U @ Vt  # orthonormal rows closest to A (orthogonal Procrustes)
        T[np.ix_(js, g)] = Q @ C
        quality[js] = np.sum(Q * A, axis=1) ** 2
    return T, quality


def _rescale_peak(T, shapes):
    """Scale each row of ``T`` positively so the combined shape has unit peak displacement."""
    disp = np.asarray(shapes.displacement).reshape(len(shapes.omega), -1)
    peak = np.max(np.abs(T @ disp), axis=1)
    peak[peak == 0.0] = 1.0
    return T / peak[:, None]


@dataclass(frozen=True)
class Tracking:
    """Result of :func:`track` along one path of configurations.

    Attributes
    ----------
    transform : tuple of numpy.ndarray
        Per step an (n, m) matrix: tracked mode ``j`` = ``Σ_i transform[j, i]`` · raw mode
        ``i`` (a signed permutation, except in degenerate subspaces).
    order : numpy.ndarray
        (n_steps, n) raw mode each tracked mode follows (its frequency is
        ``raw.omega[order]``).
    sign : numpy.ndarray
        (n_steps, n) ±1, the sign applied to that raw mode (eq. 121).
    mac : numpy.ndarray
        (n_steps, n) MAC of each tracked mode with its tracked predecessor along the path
        (1 at the anchor); for steps fitted in a degenerate subspace, with the blended
        neighbour reference.
    degenerate : numpy.ndarray
        (n_steps,) True where the step had a multiple root and was fitted from its
        neighbours.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> seq = [modes(robot, [0, 0, x], count=4) for x in np.radians([50.0, 55.0])]
    >>> tr = track(seq, count=3, robot=robot)
    >>> tr.order.tolist(), tr.degenerate.tolist()
    ([[0, 1, 2], [0, 2, 1]], [False, False])
    """

    transform: tuple[np.ndarray, ...]
    order: np.ndarray
    sign: np.ndarray
    mac: np.ndarray
    degenerate: np.ndarray

    def apply(self, sequence: Sequence[ModeShapes]) -> list[ModeShapes]:
        """The tracked, sign-corrected ModeShapes of every step of ``sequence``.

        Parameters
        ----------
        sequence : sequence of ModeShapes
            The raw modes that were passed to :func:`track`.

        Returns
        -------
        list of ModeShapes
            Modes in tracked order and sign, ``count`` per step.

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.tmm import modes
        >>> robot = load("problems/arm2link.toml")
        >>> seq = [modes(robot, [0, 0, x], count=4) for x in np.radians([50.0, 55.0])]
        >>> tracked = track(seq, count=3, robot=robot).apply(seq)
        >>> seq[1].omega[:3].round(2), tracked[1].omega.round(2)   # modes 2, 3 swapped
        (array([13.79, 18.61, 19.82]), array([13.79, 19.82, 18.61]))
        """
        return [combine(s, T, o) for s, T, o in
                zip(sequence, self.transform, self.order, strict=True)]

    def omega(self, sequence: Sequence[ModeShapes]) -> np.ndarray:
        """(n_steps, n) tracked natural frequencies [rad/s].

        Parameters
        ----------
        sequence : sequence of ModeShapes
            The raw modes that were passed to :func:`track`.

        Returns
        -------
        numpy.ndarray, shape (n_steps, n)

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.tmm import modes
        >>> robot = load("problems/arm2link.toml")
        >>> seq = [modes(robot, [0, 0, x], count=4) for x in np.radians([50.0, 55.0])]
        >>> track(seq, count=3, robot=robot).omega(seq).round(2)
        array([[13.04, 18.79, 18.8 ],
               [13.79, 19.82, 18.61]])
        """
        return np.array([np.asarray(s.omega)[o] for s, o in
                         zip(sequence, self.order, strict=True)])


def _track_features(feats, groups, shapes, ref=None, count=None):
    """Core of :func:`track` on precomputed features; see there."""
    N = len(feats)
    degenerate = np.array([any(g.size > 1 for g in gs) for gs in groups])
    T = [None] * N
    if ref is None:
        plain = np.flatnonzero(~degenerate)
        anchor = int(plain[0]) if plain.size else 0
        n = feats[anchor].shape[0] if count is None else int(count)
        if n > feats[anchor].shape[0]:
            raise ModelError(f"cannot track {n} modes: only {feats[anchor].shape[0]} computed")
        T[anchor] = np.eye(feats[anchor].shape[0])[:n]
        quality = np.full((N, n), np.nan)
        quality[anchor] = 1.0
        if degenerate[anchor]:  # every step degenerate: keep the solver's basis
            for k in range(N):
                T[k] = np.eye(feats[k].shape[0])[:n]
                quality[k] = 1.0
        else:
            _follow(feats, groups, shapes, degenerate, T, quality, anchor,
                    range(anchor + 1, N))
            _follow(feats, groups, shapes, degenerate, T, quality, anchor,
                    range(anchor - 1, -1, -1))
    else:
        n = ref.shape[0]
        quality = np.full((N, n), np.nan)
        _follow(feats, groups, shapes, degenerate, T, quality, None, range(N), ref=ref)
    order = np.array([np.argmax(np.abs(t), axis=1) for t in T])
    sign = np.array([np.sign(t[np.arange(t.shape[0]), o]) for t, o in
                     zip(T, order, strict=True)])
    sign[sign == 0] = 1.0
    return Tracking(transform=tuple(T), order=order, sign=sign, mac=quality,
                    degenerate=degenerate)


def _follow(feats, groups, shapes, degenerate, T, quality, start, steps, ref=None):
    """Track from ``start`` (already in ``T``) or from ``ref`` through ``steps``."""
    if ref is None:
        last, last_pos = T[start] @ feats[start], start
    else:
        last, last_pos = ref, None
    pending = []
    for k in steps:
        if degenerate[k]:
            pending.append(k)
            continue
        Tk, qk = _match(last, feats[k])
        T[k], quality[k] = Tk, qk
        cur = Tk @ feats[k]
        _fill(pending, feats, groups, shapes, T, quality, last, cur, last_pos, k)
        pending = []
        last, last_pos = cur, k
    _fill(pending, feats, groups, shapes, T, quality, last, None, last_pos, None)


def _fill(pending, feats, groups, shapes, T, quality, before, after, pos_before, pos_after):
    """Fit the degenerate steps ``pending`` from the tracked neighbours on each side."""
    if not pending:
        return
    b = _unit_rows(before)
    a = None if after is None else _unit_rows(after)
    for k in pending:
        if a is None:
            ref = b
        else:
            if pos_before is None:  # reference given from outside the path
                t = (pending.index(k) + 1) / (len(pending) + 1)
            else:
                t = (k - pos_before) / (pos_after - pos_before)
            ref = (1.0 - t) * b + t * a
        Tk, qk = _fit_subspaces(ref, feats[k], groups[k])
        T[k] = _rescale_peak(Tk, shapes[k])
        quality[k] = qk


def track(sequence: Iterable[ModeShapes], count: int | None = None, robot: Robot | None = None,
          weighting: str | None = None, reference: ModeShapes | None = None,
          rel_tol: float = 1e-9) -> Tracking:
    """Follow the modes along a path of configurations (identity and sign).

    Parameters
    ----------
    sequence : sequence of ModeShapes
        Raw TMM modes at consecutive configurations of a path (e.g. a sweep of one
        joint), each with the same number m of modes; compute a few more than you need.
    count : int, optional
        Number of modes to follow (default: all m). Tracked mode ``j`` is the ``j``-th
        lowest at the first configuration without a multiple root (the anchor).
    robot : casflex.robot.Robot, optional
        Enables the ``"mass"`` weighting of the MAC (recommended).
    weighting : {"mass", "uniform"}, optional
        See :func:`shape_features`.
    reference : ModeShapes, optional
        Already tracked modes (count of them) of the configuration just before
        ``sequence[0]``; the path then continues their identity and sign (used for grids).
    rel_tol : float
        Relative frequency difference below which two roots count as one multiple root
        (besides the multiplicity reported by the TMM).

    Returns
    -------
    Tracking
        ``order``/``sign`` per step (the permutation and sign of eq. 121) and the full
        ``transform`` (which also carries the combinations chosen at multiple roots).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> q3 = np.radians([45.0, 50.0, 55.0])
    >>> seq = [modes(robot, [0, 0, x], count=5) for x in q3]
    >>> tr = track(seq, count=3, robot=robot)
    >>> tr.order.tolist()   # modes 2 and 3 cross between 50° and 55°
    [[0, 1, 2], [0, 1, 2], [0, 2, 1]]
    >>> bool(tr.mac[1:].min() > 0.9)
    True
    """
    sequence = list(sequence)
    if not sequence:
        raise ModelError("track needs at least one configuration")
    feats = [shape_features(s, robot, weighting) for s in sequence]
    groups = [_groups(s, rel_tol) for s in sequence]
    ref = None
    if reference is not None:
        ref = shape_features(reference, robot, weighting)
        if count is not None and count != ref.shape[0]:
            raise ModelError(f"count = {count} but the reference holds {ref.shape[0]} modes")
    return _track_features(feats, groups, sequence, ref=ref, count=count)


# ------------------------------------------------------------------ grids


@dataclass(frozen=True)
class GridTracking:
    """Result of :func:`track_grid` over an N-D grid of configurations.

    Attributes
    ----------
    transform : numpy.ndarray
        Object array of the grid's shape; each entry an (n, m) matrix as in
        :class:`Tracking`.
    order, sign, mac : numpy.ndarray
        grid_shape + (n,), as in :class:`Tracking` (``mac`` along the tree edge that
        reached the point).
    degenerate : numpy.ndarray
        grid_shape booleans.
    edge_correlation : numpy.ndarray
        grid_shape + (ndim, n): signed correlation of each tracked mode with the tracked
        mode at the previous index along each axis (NaN at index 0), for *every* grid edge
        including those outside the spanning tree; a value near +1 is a consistent edge, a
        negative one a sign inconsistency, a small one an identity jump.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> grid = [[modes(robot, [0, a, b], count=3) for b in (0.2, 0.3)] for a in (0.0, 0.5)]
    >>> gt = track_grid(grid, count=2, robot=robot)
    >>> gt.order.shape, gt.edge_correlation.shape, bool(gt.degenerate.any())
    ((2, 2, 2), (2, 2, 2, 2), False)
    """

    transform: np.ndarray
    order: np.ndarray
    sign: np.ndarray
    mac: np.ndarray
    degenerate: np.ndarray
    edge_correlation: np.ndarray

    def apply(self, shapes: np.ndarray) -> np.ndarray:
        """Object array of tracked ModeShapes for a grid of raw ModeShapes.

        Parameters
        ----------
        shapes : numpy.ndarray of ModeShapes
            Object array of the grid's shape (the raw modes given to :func:`track_grid`).

        Returns
        -------
        numpy.ndarray of ModeShapes
            Object array of the grid's shape, ``count`` tracked modes per point.

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.tmm import modes
        >>> robot = load("problems/arm2link.toml")
        >>> raw = np.empty((2, 2), dtype=object)
        >>> for i, a in enumerate((0.0, 0.5)):
        ...     for j, b in enumerate((0.2, 0.3)):
        ...         raw[i, j] = modes(robot, [0, a, b], count=3)
        >>> tracked = track_grid(raw, count=2, robot=robot).apply(raw)
        >>> tracked.shape, tracked[1, 1].omega.shape
        ((2, 2), (2,))
        """
        out = np.empty(self.transform.shape, dtype=object)
        for idx in np.ndindex(self.transform.shape):
            out[idx] = combine(shapes[idx], self.transform[idx], self.order[idx])
        return out


def track_grid(shapes: np.ndarray | Sequence[Any], count: int | None = None,
               robot: Robot | None = None, weighting: str | None = None,
               rel_tol: float = 1e-9) -> GridTracking:
    """Track modes over an N-D grid along a comb-shaped spanning tree.

    Parameters
    ----------
    shapes : numpy.ndarray of ModeShapes
        Object array (or nested lists) of the grid's shape with the raw modes of every
        grid point (axes = shape joints, in the order of the grid).
    count, robot, weighting, rel_tol
        As in :func:`track`.

    Returns
    -------
    GridTracking

    Notes
    -----
    The tree is: axis 0 with all other indices 0 (the spine), then from every point of
    the tracked part along axis 1, and so on. The tracked mode identities are those of
    the first point of the spine (or of the first spine point without a multiple root).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> grid = [[modes(robot, [0, a, b], count=4) for b in (0.2, 0.3)] for a in (0.0, 0.5)]
    >>> gt = track_grid(grid, count=3, robot=robot)
    >>> gt.order.shape, bool(np.nanmin(gt.edge_correlation) > 0.9)
    ((2, 2, 3), True)
    """
    arr = np.empty(_grid_shape(shapes), dtype=object)
    for idx in np.ndindex(arr.shape):
        item = shapes
        for i in idx:
            item = item[i]
        arr[idx] = item
    feats = np.empty(arr.shape, dtype=object)
    grps = np.empty(arr.shape, dtype=object)
    for idx in np.ndindex(arr.shape):
        feats[idx] = shape_features(arr[idx], robot, weighting)
        grps[idx] = _groups(arr[idx], rel_tol)
    return _track_grid(feats, grps, arr, count)


def point_tracking_data(shapes: ModeShapes, robot: Robot | None = None,
                        weighting: str | None = None, rel_tol: float = 1e-9) -> dict:
    """What :func:`track_grid_features` needs of one grid point (its per-point work, which
    can run where the shapes are).

    Parameters
    ----------
    shapes : ModeShapes
        Raw modes of the point.
    robot, weighting, rel_tol
        As in :func:`track`.

    Returns
    -------
    dict
        ``features`` (:func:`shape_features`), ``groups`` (index arrays of the
        equal-frequency groups), ``omega`` [rad/s] and ``displacement``: the raw
        displacement field where a group holds more than one mode (its tracked
        combinations are rescaled to unit peak), else None.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> data = point_tracking_data(modes(robot, [0, 0, 0.3], count=3), robot)
    >>> data["features"].shape[0], len(data["groups"]), data["displacement"] is None
    (3, 3, True)
    """
    groups = _groups(shapes, rel_tol)
    degenerate = any(g.size > 1 for g in groups)
    return {"features": shape_features(shapes, robot, weighting), "groups": groups,
            "omega": np.asarray(shapes.omega),
            "displacement": np.asarray(shapes.displacement) if degenerate else None}


def track_grid_features(points: np.ndarray, count: int | None = None) -> GridTracking:
    """:func:`track_grid` from each point's :func:`point_tracking_data` (the same result,
    bit for bit, without the mode shapes at hand).

    Parameters
    ----------
    points : numpy.ndarray of dict
        Object array of the grid's shape.
    count : int, optional
        As in :func:`track`.

    Returns
    -------
    GridTracking

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> raw = np.empty((2, 2), dtype=object)
    >>> for i, a in enumerate((0.0, 0.5)):
    ...     for j, b in enumerate((0.2, 0.3)):
    ...         raw[i, j] = modes(robot, [0, a, b], count=3)
    >>> data = np.empty((2, 2), dtype=object)
    >>> for idx in np.ndindex(2, 2):
    ...     data[idx] = point_tracking_data(raw[idx], robot)
    >>> a, b = track_grid_features(data, count=2), track_grid(raw, count=2, robot=robot)
    >>> bool(np.array_equal(a.edge_correlation, b.edge_correlation, equal_nan=True))
    True
    """
    feats = np.empty(points.shape, dtype=object)
    grps = np.empty(points.shape, dtype=object)
    peaks = np.empty(points.shape, dtype=object)  # what _rescale_peak reads
    for idx in np.ndindex(points.shape):
        data = points[idx]
        feats[idx], grps[idx] = data["features"], data["groups"]
        peaks[idx] = _peak_data(data)
    return _track_grid(feats, grps, peaks, count)


def track_path_features(points: Sequence[dict], reference: ArrayLike) -> Tracking:
    """:func:`track` along a path from each point's :func:`point_tracking_data`, continuing
    already tracked modes: the work of one path of :func:`track_grid`'s spanning tree off
    its first axis, which can run where the path's data is.

    Parameters
    ----------
    points : sequence of dict
        :func:`point_tracking_data` of the path's points (after the tracked point).
    reference : numpy.ndarray
        (n, n_features) tracked feature rows of the point just before the path: its
        transform times its features.

    Returns
    -------
    Tracking
        As :func:`track` with ``reference``; bit for bit what :func:`track_grid` computes
        for the same path.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> raw = [[modes(robot, [0, a, b], count=4) for b in (0.2, 0.3, 0.4)] for a in (0.0, 0.5)]
    >>> gt = track_grid(raw, count=3, robot=robot)
    >>> data = [point_tracking_data(s, robot) for s in raw[1]]
    >>> ref = gt.transform[1, 0] @ data[0]["features"]
    >>> tr = track_path_features(data[1:], ref)
    >>> bool(np.array_equal(tr.order, gt.order[1, 1:]))
    True
    """
    return _track_features([p["features"] for p in points], [p["groups"] for p in points],
                           [_peak_data(p) for p in points], ref=np.asarray(reference))


def tracked_unit_features(transform: ArrayLike, features: np.ndarray) -> np.ndarray:
    """Unit-norm feature rows of the tracked modes: their dot products across a grid edge
    are :attr:`GridTracking.edge_correlation`.

    Parameters
    ----------
    transform : numpy.ndarray
        (n, m) tracking transform of the point.
    features : numpy.ndarray
        (m, n_features) features of its raw modes (:func:`shape_features`).

    Returns
    -------
    numpy.ndarray
        (n, n_features), each nonzero row scaled to unit length.

    Examples
    --------
    >>> u = tracked_unit_features(np.eye(2), np.array([[3.0, 4.0], [0.0, 0.0]]))
    >>> u.tolist()
    [[0.6, 0.8], [0.0, 0.0]]
    """
    return _unit_rows(np.asarray(transform) @ features)


def _peak_data(data):
    """What :func:`_rescale_peak` reads of a point, from its tracking data."""
    return SimpleNamespace(omega=data["omega"], displacement=data["displacement"])


def _track_grid(feats, grps, arr, count):
    """Core of :func:`track_grid` on per-point features and groups; ``arr`` holds what
    :func:`_rescale_peak` reads at degenerate points."""
    gshape = arr.shape
    ndim = len(gshape)
    T = np.empty(gshape, dtype=object)
    deg = np.zeros(gshape, dtype=bool)
    qual = None

    def line(axis, base):
        idxs = []
        for i in range(gshape[axis]):
            j = list(base)
            j[axis] = i
            idxs.append(tuple(j))
        return idxs

    # spine along axis 0
    spine = line(0, (0,) * ndim)
    tr = _track_features([feats[i] for i in spine], [grps[i] for i in spine],
                         [arr[i] for i in spine], count=count)
    n = tr.order.shape[1]
    qual = np.full(gshape + (n,), np.nan)
    for k, idx in enumerate(spine):
        T[idx], qual[idx], deg[idx] = tr.transform[k], tr.mac[k], tr.degenerate[k]
    for axis in range(1, ndim):
        sub_shape = gshape[:axis]
        for head in np.ndindex(sub_shape):
            base = head + (0,) * (ndim - axis)
            path = line(axis, base)
            if len(path) < 2:
                continue
            ref = T[base] @ feats[base]
            rest = path[1:]
            tr = _track_features([feats[i] for i in rest], [grps[i] for i in rest],
                                 [arr[i] for i in rest], ref=ref)
            for k, idx in enumerate(rest):
                T[idx], qual[idx], deg[idx] = tr.transform[k], tr.mac[k], tr.degenerate[k]
    order = np.empty(gshape + (n,), dtype=int)
    sign = np.empty(gshape + (n,))
    unit = np.empty(gshape, dtype=object)  # unit rows of the tracked features
    for idx in np.ndindex(gshape):
        t = T[idx]
        order[idx] = np.argmax(np.abs(t), axis=1)
        s = np.sign(t[np.arange(n), order[idx]])
        s[s == 0] = 1.0
        sign[idx] = s
        unit[idx] = tracked_unit_features(t, feats[idx])
    edge = np.full(gshape + (ndim, n), np.nan)
    for idx in np.ndindex(gshape):
        for axis in range(ndim):
            if idx[axis] == 0:
                continue
            prev = list(idx)
            prev[axis] -= 1
            edge[idx + (axis,)] = np.sum(unit[tuple(prev)] * unit[idx], axis=1)
    return GridTracking(transform=T, order=order, sign=sign, mac=qual, degenerate=deg,
                        edge_correlation=edge)


def _grid_shape(shapes):
    """Shape of the nesting of ``shapes`` above the ModeShapes."""
    if isinstance(shapes, np.ndarray) and shapes.dtype == object:
        return shapes.shape
    shape, item = [], shapes
    while isinstance(item, (list, tuple)):
        shape.append(len(item))
        item = item[0]
    return tuple(shape)
