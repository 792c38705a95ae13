"""A smooth mode basis over a grid with close or crossing modes (issue 21).

Why eigenvectors cannot be followed on a 2-D grid
--------------------------------------------------
Along one path :func:`casflex.modal.tracking.track` follows eigenmodes by MAC and swaps
them where they cross. Over two or more shape joints that is not enough: two modes of a
real symmetric family meet at isolated points of the (q_a, q_b) plane (conical
intersections; the tubes of ``problems/arm4_spatial.toml`` have two bending directions
of nearly equal stiffness), and around such a point each eigenvector turns by up to 90°
within the pair's plane over a few grid steps and comes back with its sign flipped after
a loop. No ordering or sign choice of the eigenvectors is continuous there (the MAC
between grid neighbours of the 4-joint arm falls to 0.64 at a 30° step), and the
tabulated eigenfrequency has a cone-shaped kink that no spline follows.

What is smooth is the *subspace*: the span of a group of modes that stays apart from the
other modes over the whole grid (a cluster) varies analytically with the joints. This
module therefore treats every cluster as a subspace and picks its basis by the
dissertation's neighbourhood rule generalised to a grid: at each grid point (in C order)
the basis of the cluster is the orthonormal one closest to the already chosen bases of
its neighbours at the previous index along every axis (orthogonal Procrustes on the sum
of their projections). Clusters are found from the sorted frequencies: sorted modes k and
k + 1 belong together when their relative gap falls below ``gap`` somewhere on the grid.

What is tabulated for a rotated cluster
---------------------------------------
A rotated basis vector is not an eigenmode, so its "frequency" is not an eigenvalue. With
mass-orthonormal basis vectors ``ψ = Q φ`` (``Q`` orthogonal, ``φ`` the mass-normalised
eigenmodes of the cluster) the modal mass stays the identity and the modal stiffness
becomes ``K̃ = Q diag(ω²) Qᵀ``: block-diagonal, one full block per cluster, exactly the
strain energy of the basis vectors. This module returns ``K̃`` as ``stiffness`` and the
Rayleigh frequencies ``sqrt(K̃_jj)`` as ``omega``; the natural frequencies are the
eigenvalues of ``K̃`` (``numpy.linalg.eigvalsh``), which is how the tabulated basis is
checked against direct TMM. A model built on this basis must use the full ``K̃`` (and a
damping consistent with it); ``diag(omega²)`` alone drops the coupling
``K̃_jk = Σ_i Q_ji Q_ki ω_i²``, which is as large as the frequency split of the pair.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.robot import Robot
    from casflex.tmm.solve import ModeShapes

__all__ = ["DEFAULT_GAP", "mode_clusters", "SmoothBasis", "smooth_basis",
           "track_grid_smooth", "point_features", "track_features_smooth"]

#: relative frequency gap below which two sorted modes are one cluster somewhere on a grid
DEFAULT_GAP = 0.05


def mode_clusters(omega: ArrayLike, count: int, gap: float = DEFAULT_GAP
                  ) -> tuple[tuple[int, ...], ...]:
    """Groups of sorted modes that come close somewhere on a grid.

    Parameters
    ----------
    omega : array_like
        ``grid_shape + (m,)`` natural frequencies [rad/s], ascending at every point.
    count : int
        Modes needed (the lowest ``count``); the clusters returned cover them.
    gap : float
        Sorted modes ``k`` and ``k + 1`` are one cluster when
        ``min over the grid of (ω_{k+1} − ω_k) / ω_k < gap`` (dimensionless).

    Returns
    -------
    tuple of tuple of int
        Consecutive 0-based sorted indices, covering ``0 .. count − 1`` and possibly more
        (a cluster is never split).

    Raises
    ------
    ModelError
        When a cluster that is needed holds the highest computed mode (the next,
        uncomputed mode might belong to it: compute more modes).

    Examples
    --------
    >>> w = np.array([[1.0, 2.0, 2.01, 5.0], [1.0, 2.1, 2.3, 5.0]])
    >>> mode_clusters(w, 2)
    ((0,), (1, 2))
    """
    w = np.asarray(omega, dtype=float)
    m = w.shape[-1]
    if not 1 <= int(count) <= m:
        raise ModelError(f"count must lie in [1, {m}] (the computed modes); got {count!r}")
    if not gap >= 0.0:
        raise ModelError(f"gap must be a non-negative relative frequency gap; got {gap!r}")
    flat = w.reshape(-1, m)
    rel = np.min((flat[:, 1:] - flat[:, :-1]) / np.abs(flat[:, :-1]), axis=0)
    clusters, current = [], [0]
    for k in range(m - 1):
        if rel[k] < gap:
            current.append(k + 1)
        else:
            clusters.append(tuple(current))
            current = [k + 1]
    clusters.append(tuple(current))
    out = []
    for c in clusters:
        if c[0] >= count:
            break
        if c[-1] == m - 1:
            raise ModelError(f"the cluster of sorted modes {c[0] + 1}..{m} holds the "
                             f"highest computed mode {m}: whether the next mode comes within "
                             f"{gap:g} of it is unknown; compute more modes")
        out.append(c)
    return tuple(out)


@dataclass(frozen=True)
class SmoothBasis:
    """Result of :func:`smooth_basis`: a mode basis that varies smoothly over a grid.

    Attributes
    ----------
    transform : numpy.ndarray
        Object array of the grid's shape; each entry an (n, m) matrix: basis vector ``j``
        = ``Σ_i transform[j, i]`` · raw mode ``i`` (unit modal mass when the raw modal
        masses were given).
    stiffness : numpy.ndarray
        ``grid_shape + (n, n)`` modal stiffness ``K̃`` of the basis [rad²/s²],
        block-diagonal by cluster (module notes).
    omega : numpy.ndarray
        ``grid_shape + (n,)`` Rayleigh frequencies ``sqrt(diag K̃)`` [rad/s].
    clusters : tuple of tuple of int
        The sorted raw modes spanning each block.
    neighbour_mac : numpy.ndarray
        ``grid_shape + (ndim, n)``: MAC of each basis vector with the one at the previous
        index along each axis (NaN at index 0), over *every* grid edge.

    Examples
    --------
    >>> F = np.empty((2,), dtype=object)
    >>> F[0], F[1] = np.eye(2), np.eye(2)
    >>> sb = smooth_basis(F, np.array([[1.0, 2.0], [1.0, 2.0]]), ((0,), (1,)))
    >>> sb.min_mac, sb.eigenfrequencies()[1].tolist()
    (1.0, [1.0, 2.0])
    """

    transform: np.ndarray
    stiffness: np.ndarray
    omega: np.ndarray
    clusters: tuple[tuple[int, ...], ...]
    neighbour_mac: np.ndarray

    @property
    def mac(self) -> np.ndarray:
        """``grid_shape + (n,)`` MAC over the worst grid edge into each point (NaN at the
        first point), as ``GridTracking.mac``."""
        return np.fmin.reduce(self.neighbour_mac, axis=-2)

    @property
    def edge_correlation(self) -> np.ndarray:
        """``grid_shape + (ndim, n)`` correlation over every edge (``sqrt`` of the MAC: the
        Procrustes choice keeps each vector's sign continuous), as in ``GridTracking``."""
        return np.sqrt(self.neighbour_mac)

    @property
    def degenerate(self) -> np.ndarray:
        """``grid_shape`` booleans, all False: a cluster's basis is chosen at every point."""
        return np.zeros(self.omega.shape[:-1], dtype=bool)

    def clusters_1based(self) -> list[list[int]]:
        """The clusters as 1-based mode numbers (for messages and files).

        Returns
        -------
        list of list of int

        Examples
        --------
        >>> F = np.empty((1,), dtype=object)
        >>> F[0] = np.eye(2)
        >>> smooth_basis(F, np.array([[1.0, 1.0]]), ((0, 1),)).clusters_1based()
        [[1, 2]]
        """
        return [[k + 1 for k in c] for c in self.clusters]

    @property
    def min_mac(self) -> float:
        """Lowest MAC between grid neighbours over all edges (1.0 for a single point)."""
        m = self.neighbour_mac
        return float(np.nanmin(m)) if np.isfinite(m).any() else 1.0

    def eigenfrequencies(self) -> np.ndarray:
        """``grid_shape + (n,)`` natural frequencies [rad/s]: eigenvalues of ``K̃``.

        Returns
        -------
        numpy.ndarray
            Ascending at every point.

        Examples
        --------
        >>> F = np.empty((1,), dtype=object)
        >>> F[0] = np.array([[1.0, 1.0], [1.0, -1.0]])
        >>> sb = smooth_basis(F, np.array([[3.0, 4.0]]), ((0, 1),))
        >>> sb.eigenfrequencies().round(12).tolist()
        [[3.0, 4.0]]
        """
        return np.sqrt(np.clip(np.linalg.eigvalsh(self.stiffness), 0.0, None))

    def apply(self, shapes: np.ndarray) -> np.ndarray:
        """Object array of ModeShapes in the smooth basis (``omega`` = Rayleigh frequencies).

        Parameters
        ----------
        shapes : numpy.ndarray of ModeShapes
            The raw modes given to :func:`track_grid_smooth`.

        Returns
        -------
        numpy.ndarray of ModeShapes
            n basis vectors per point, multiplicity 1. Every field is exact at the sample
            points; but a rotated vector mixes modes of different ω, so what rebuilds a
            shape between the samples from its ω (:func:`casflex.modal.normalize.
            local_state`, hence ``mass_normalize`` and the model quantities of
            :mod:`casflex.modal.integrals`) is not valid for it: evaluate those on the
            eigenmodes and transform them with ``transform``.

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.tmm import modes
        >>> robot = load("problems/arm2link.toml")
        >>> raw = np.empty((2,), dtype=object)
        >>> raw[0], raw[1] = (modes(robot, [0, 0, x], count=4) for x in (0.9, 0.95))
        >>> out = track_grid_smooth(raw, 3, robot).apply(raw)
        >>> out[1].omega.shape
        (3,)
        """
        from casflex.modal.tracking import combine

        out = np.empty(self.transform.shape, dtype=object)
        for idx in np.ndindex(self.transform.shape):
            t = self.transform[idx]
            c = combine(shapes[idx], t, np.argmax(np.abs(t), axis=1))
            out[idx] = dataclasses.replace(c, omega=self.omega[idx].copy())
        return out


def _polar(A):
    """The orthogonal matrix closest to ``A`` (orthogonal Procrustes)."""
    U, _, Vt = np.linalg.svd(A)
    return U @ Vt


def smooth_basis(features: np.ndarray, omega: ArrayLike,
                 clusters: tuple[tuple[int, ...], ...],
                 mass: ArrayLike | None = None) -> SmoothBasis:
    """Choose every cluster's basis smoothly over a grid (neighbourhood Procrustes).

    Parameters
    ----------
    features : numpy.ndarray
        Object array of the grid's shape; each entry the (m, f) feature rows of the raw
        eigenmodes (see :func:`casflex.modal.tracking.shape_features`), sorted by
        frequency.
    omega : array_like
        ``grid_shape + (m,)`` their natural frequencies [rad/s].
    clusters : tuple of tuple of int
        From :func:`mode_clusters`.
    mass : array_like, optional
        ``grid_shape + (m, m)`` modal mass matrices of the raw modes (exact quadrature,
        :func:`casflex.modal.normalize.modal_mass_matrix`); the basis is then
        mass-orthonormal to that accuracy. Default: the feature Gram matrix.

    Returns
    -------
    SmoothBasis

    Notes
    -----
    At the first grid point the basis is the eigenbasis. At every later point (C order)
    the reference of a cluster is the sum of its basis rows at the neighbours one index
    back along each axis; the new basis is the orthonormal one maximising the total
    correlation with it (SVD of the projections). Raw modes are orthonormalised within the
    cluster with the inverse square root of their Gram matrix (a plain scaling for
    distinct eigenmodes, which are mass-orthogonal); their stiffness in that basis is
    ``diag(ω²) G`` symmetrised, exact for eigenmodes.

    Examples
    --------
    A pair whose eigenvectors turn by 90° around a conical intersection at the origin:
    the basis follows the (constant) plane instead.

    >>> F = np.empty((3,), dtype=object)
    >>> w = np.empty((3, 2))
    >>> for i, a in enumerate(np.radians([0.0, 40.0, 80.0])):
    ...     F[i] = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    ...     w[i] = [1.0, 1.01]
    >>> smooth_basis(F, w, ((0, 1),)).min_mac > 0.999
    True
    """
    gshape = features.shape
    ndim = len(gshape)
    w = np.asarray(omega, dtype=float)
    idx_all = [np.array(c, dtype=int) for c in clusters]
    n = sum(c.size for c in idx_all)
    rows = np.cumsum([0] + [c.size for c in idx_all])
    T = np.empty(gshape, dtype=object)
    tracked = np.empty(gshape, dtype=object)
    K = np.zeros(gshape + (n, n))
    for idx in np.ndindex(gshape):
        F = np.asarray(features[idx], dtype=float)
        G = F @ F.T if mass is None else np.asarray(mass[idx], dtype=float)
        Tk = np.zeros((n, F.shape[0]))
        preds = []
        for ax in range(ndim):
            if idx[ax] > 0:
                p = list(idx)
                p[ax] -= 1
                preds.append(tracked[tuple(p)])
        for ci, g in enumerate(idx_all):
            r = slice(rows[ci], rows[ci + 1])
            Gg = 0.5 * (G[np.ix_(g, g)] + G[np.ix_(g, g)].T)
            e, V = np.linalg.eigh(Gg)
            if e.min() <= 1e-14 * max(e.max(), 1e-300):
                raise ModelError(f"grid point {idx}: modes {[k + 1 for k in g]} are linearly "
                                 "dependent (zero Gram eigenvalue)")
            C = (V / np.sqrt(e)) @ V.T  # G^(-1/2): Löwdin orthonormalisation
            if preds:
                ref = sum(p[r] for p in preds)
                B = C @ F[g]
                Q = _polar(ref @ B.T)
            else:
                Q = np.eye(g.size)
            Tg = Q @ C
            Tk[r, g] = Tg
            Kraw = np.diag(w[idx][g] ** 2) @ G[np.ix_(g, g)]
            Kg = Tg @ (0.5 * (Kraw + Kraw.T)) @ Tg.T
            K[idx + (r, r)] = 0.5 * (Kg + Kg.T)
        T[idx] = Tk
        tracked[idx] = Tk @ F
    nmac = np.full(gshape + (ndim, n), np.nan)
    for idx in np.ndindex(gshape):
        a = tracked[idx]
        for ax in range(ndim):
            if idx[ax] == 0:
                continue
            p = list(idx)
            p[ax] -= 1
            b = tracked[tuple(p)]
            num = np.sum(a * b, axis=1) ** 2
            den = np.sum(a * a, axis=1) * np.sum(b * b, axis=1)
            nmac[idx + (ax,)] = num / np.where(den > 0.0, den, 1.0)
    diag = np.diagonal(K, axis1=-2, axis2=-1)
    return SmoothBasis(transform=T, stiffness=K, omega=np.sqrt(np.clip(diag, 0.0, None)),
                       clusters=tuple(tuple(int(k) for k in c) for c in clusters),
                       neighbour_mac=nmac)


def track_grid_smooth(shapes: np.ndarray, count: int, robot: Robot | None = None,
                      weighting: str | None = None, gap: float = DEFAULT_GAP,
                      exact_mass: bool = True) -> SmoothBasis:
    """A smooth mode basis of raw TMM modes over a grid (clusters found by ``gap``).

    Parameters
    ----------
    shapes : numpy.ndarray of ModeShapes
        Object array of the grid's shape with the raw, sorted modes of every point
        (compute a few more than ``count``).
    count : int
        Modes needed; the basis covers whole clusters, so it may hold more.
    robot : casflex.robot.Robot, optional
        For the ``"mass"`` weighting of the alignment and the exact modal masses.
    weighting : {"mass", "uniform"}, optional
        See :func:`casflex.modal.tracking.shape_features`.
    gap : float
        Relative frequency gap defining the clusters (:func:`mode_clusters`).
    exact_mass : bool
        Orthonormalise with :func:`casflex.modal.normalize.modal_mass_matrix` (needs
        ``robot``) instead of the feature Gram matrix.

    Returns
    -------
    SmoothBasis
        ``count`` basis vectors per point.

    Raises
    ------
    ModelError
        When ``count`` splits a cluster (the error names the count that does not).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> raw = np.empty((2,), dtype=object)
    >>> raw[0], raw[1] = (modes(robot, [0, 0, x], count=4) for x in (0.9, 0.95))
    >>> sb = track_grid_smooth(raw, 3, robot)
    >>> sb.clusters, sb.min_mac > 0.95
    (((0,), (1, 2)), True)
    """
    shapes = np.asarray(shapes, dtype=object) if not isinstance(shapes, np.ndarray) \
        else shapes
    gshape = shapes.shape
    omega = np.array([np.asarray(shapes[i].omega, dtype=float) for i in np.ndindex(gshape)])
    omega = omega.reshape(gshape + (omega.shape[-1],))
    features = np.empty(gshape, dtype=object)
    mass = None
    if exact_mass and robot is not None:
        mass = np.empty(gshape + (omega.shape[-1],) * 2)
    for idx in np.ndindex(gshape):
        features[idx], m = point_features(shapes[idx], robot, weighting, exact_mass)
        if mass is not None:
            mass[idx] = m
    return track_features_smooth(features, omega, count, mass, gap)


def point_features(shapes: ModeShapes, robot: Robot | None = None,
                   weighting: str | None = None, exact_mass: bool = True
                   ) -> tuple[np.ndarray, np.ndarray | None]:
    """What :func:`track_features_smooth` needs of one point's raw modes.

    Parameters
    ----------
    shapes : casflex.tmm.ModeShapes
        Raw modes, sorted by frequency.
    robot : casflex.robot.Robot, optional
        For the ``"mass"`` weighting and the exact modal masses.
    weighting : {"mass", "uniform"}, optional
        See :func:`casflex.modal.tracking.shape_features`.
    exact_mass : bool
        Also the exact modal mass matrix (needs ``robot``).

    Returns
    -------
    features : numpy.ndarray
        (m, f) feature rows, scaled so that their Gram diagonal is the modal mass when it
        is computed (the alignment compares unit-mass rows).
    mass : numpy.ndarray or None
        (m, m) :func:`casflex.modal.normalize.modal_mass_matrix` [kg·m² scale of the
        raw shapes], or None.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> f, M = point_features(modes(robot, [0, 0, 0.5], count=2), robot)
    >>> bool(np.allclose(np.sum(f * f, axis=1), np.diag(M)))
    True
    """
    from casflex.modal.normalize import modal_mass_matrix
    from casflex.modal.tracking import shape_features

    f = shape_features(shapes, robot, weighting)
    if not (exact_mass and robot is not None):
        return f, None
    M = modal_mass_matrix(robot, shapes)
    scale = np.sqrt(np.diag(M) / np.maximum(np.sum(f * f, axis=1), 1e-300))
    return f * scale[:, None], M


def track_features_smooth(features: np.ndarray, omega: ArrayLike, count: int,
                          mass: ArrayLike | None = None, gap: float = DEFAULT_GAP
                          ) -> SmoothBasis:
    """:func:`track_grid_smooth` from per-point features (:func:`point_features`).

    Parameters
    ----------
    features : numpy.ndarray
        Object array of the grid's shape of (m, f) feature rows.
    omega : array_like
        ``grid_shape + (m,)`` natural frequencies [rad/s], ascending.
    count : int
        Modes needed (whole clusters).
    mass : array_like, optional
        ``grid_shape + (m, m)`` exact modal masses.
    gap : float
        Relative frequency gap of the clusters.

    Returns
    -------
    SmoothBasis

    Raises
    ------
    ModelError
        When ``count`` splits a cluster.

    Examples
    --------
    >>> F = np.empty((2,), dtype=object)
    >>> F[0], F[1] = np.eye(2), np.eye(2)
    >>> track_features_smooth(F, np.array([[1.0, 2.0], [1.0, 2.0]]), 1).clusters
    ((0,),)
    """
    omega = np.asarray(omega, dtype=float)
    clusters = mode_clusters(omega, count, gap)
    if clusters[-1][-1] + 1 != count:
        raise ModelError(f"{count} modes split the cluster of close modes "
                         f"{[k + 1 for k in clusters[-1]]} (relative gap < {gap:g} "
                         f"somewhere): use {clusters[-1][-1] + 1} modes")
    return smooth_basis(features, omega, clusters, mass)
