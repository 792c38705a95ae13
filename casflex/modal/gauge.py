"""An analytic basis of clusters of close modes: the fixed-reference gauge (issue 21).

:func:`casflex.modal.subspace.smooth_basis` chooses a cluster's basis point by point
along the grid (Procrustes against the neighbours already chosen). Over two or more shape
joints that choice depends on the path through the grid (the subspace's curvature), so it
is continuous but not an analytic function of the joints, and Chebyshev fits of the
quantities in that basis converge only algebraically (the 6-joint arm: error ∝
degree^−3.6).

Here every point's basis is the orthonormal basis of its cluster subspace closest to ONE
fixed reference basis (the eigenmodes at one configuration, e.g. the box's centre):
``Q = polar(R_g · Fᵀ · C)``, with ``R_g`` the reference's mass-orthonormal rows of the
cluster, ``F`` the point's mode features (:func:`casflex.modal.subspace.point_features`)
and ``C = G^(−1/2)`` the Löwdin orthonormalisation of the point's raw modes. The spectral
projector of an isolated cluster is analytic in the joints, and so is the polar factor of
its overlap with a fixed basis as long as that overlap stays non-singular. The basis is
then an analytic function of the configuration alone (no grid, no path), and so is every
quantity in it: the fits converge geometrically, like those of the cluster invariants.

Where the overlap comes close to singular (a cluster subspace nearly orthogonal to the
reference one somewhere in the box) the gauge is not usable: the smallest singular value
of each cluster's overlap is returned, and the fit refuses a box where it falls below
:data:`MIN_OVERLAP` (use the neighbour gauge, or split the box).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.subspace import SmoothBasis

__all__ = ["MIN_OVERLAP", "reference_rows", "reference_basis"]

#: smallest singular value of a cluster's overlap with the reference accepted: the polar
#: factor's derivative grows as 1 / (σ_1 + σ_2), so below this the basis turns fast and
#: the fits would need many more points; at 0 it is not defined
MIN_OVERLAP = 0.1


def reference_rows(features: ArrayLike, mass: ArrayLike, count: int) -> np.ndarray:
    """Mass-orthonormal feature rows of the lowest ``count`` modes of the reference point.

    Parameters
    ----------
    features : array_like
        (m, f) feature rows of the reference's raw modes
        (:func:`casflex.modal.subspace.point_features`), sorted by frequency.
    mass : array_like
        (m, m) their exact modal mass matrix (same scale as the raw modes).
    count : int
        Modes of the basis.

    Returns
    -------
    numpy.ndarray
        (count, f) rows ``G^(−1/2) F`` (``G`` the mass block of the ``count`` modes).

    Examples
    --------
    >>> R = reference_rows(2.0 * np.eye(2), 4.0 * np.eye(2), 2)
    >>> R.tolist()
    [[1.0, 0.0], [0.0, 1.0]]
    """
    F = np.asarray(features, dtype=float)[:int(count)]
    G = np.asarray(mass, dtype=float)[:int(count), :int(count)]
    e, V = np.linalg.eigh(0.5 * (G + G.T))
    if e.min() <= 1e-14 * max(e.max(), 1e-300):
        raise ModelError("the reference modes are linearly dependent (zero modal mass "
                         "eigenvalue)")
    return ((V / np.sqrt(e)) @ V.T) @ F


def reference_basis(overlap: ArrayLike, omega: ArrayLike,
                    clusters: tuple[tuple[int, ...], ...], mass: ArrayLike
                    ) -> tuple[SmoothBasis, np.ndarray]:
    """Every cluster's basis closest to a fixed reference basis (module notes).

    Parameters
    ----------
    overlap : array_like
        ``grid_shape + (n, n)``: ``R @ F[:n].T`` with ``R`` from :func:`reference_rows` and
        ``F`` each point's feature rows (``n`` = modes of the basis; the mass scale of
        the raw modes).
    omega : array_like
        ``grid_shape + (m,)`` natural frequencies of the raw modes [rad/s], ascending
        (``m >= n``).
    clusters : tuple of tuple of int
        From :func:`casflex.modal.subspace.mode_clusters`, covering exactly ``0 .. n − 1``.
    mass : array_like
        ``grid_shape + (n, n)`` exact modal masses of the raw modes.

    Returns
    -------
    basis : casflex.modal.subspace.SmoothBasis
        ``transform`` maps the raw modes to the basis (unit modal mass), ``stiffness`` is
        ``K̃`` (block-diagonal by cluster); ``neighbour_mac`` is NaN (the basis is not
        built from neighbours).
    min_overlap : numpy.ndarray
        ``grid_shape + (len(clusters),)`` smallest singular value of each cluster's
        overlap with the reference (1 where the subspace is the reference's; 0 where it
        is orthogonal to it).

    Examples
    --------
    A pair whose eigenvectors turn by 60° within a fixed plane: the basis stays the
    reference's and ``K̃`` carries the rotation.

    >>> a = np.radians(60.0)
    >>> A = np.array([[[1.0, 0.0], [0.0, 1.0]],
    ...               [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]])
    >>> sb, low = reference_basis(A, [[1.0, 2.0], [1.0, 2.0]], ((0, 1),), [np.eye(2)] * 2)
    >>> sb.transform[1].round(6).tolist(), low.round(6).ravel().tolist()
    ([[0.5, -0.866025], [0.866025, 0.5]], [1.0, 1.0])
    >>> sb.eigenfrequencies()[1].round(12).tolist()
    [1.0, 2.0]
    """
    A = np.asarray(overlap, dtype=float)
    n = A.shape[-1]
    gshape = A.shape[:-2]
    w = np.asarray(omega, dtype=float)[..., :n]
    G = np.asarray(mass, dtype=float)[..., :n, :n]
    G = 0.5 * (G + np.swapaxes(G, -1, -2))
    if sum(len(c) for c in clusters) != n or clusters[-1][-1] + 1 != n:
        raise ModelError(f"the clusters {[[k + 1 for k in c] for c in clusters]} must cover "
                         f"exactly modes 1..{n}")
    T = np.zeros(gshape + (n, n))
    K = np.zeros(gshape + (n, n))
    low = np.empty(gshape + (len(clusters),))
    for ci, c in enumerate(clusters):
        g = np.asarray(c, dtype=int)
        Gg = G[..., g[:, None], g[None, :]]
        e, V = np.linalg.eigh(Gg)
        if np.any(e.min(axis=-1) <= 1e-14 * np.maximum(e.max(axis=-1), 1e-300)):
            raise ModelError(f"modes {[k + 1 for k in c]} are linearly dependent somewhere "
                             "on the grid (zero Gram eigenvalue)")
        C = np.einsum("...ij,...j,...kj->...ik", V, 1.0 / np.sqrt(e), V)  # G^(-1/2)
        M = A[..., g[:, None], g[None, :]] @ C  # reference rows · orthonormalised rows
        U, s, Vt = np.linalg.svd(M)
        low[..., ci] = s[..., -1]
        Tg = (U @ Vt) @ C
        T[..., g[:, None], g[None, :]] = Tg
        Kraw = w[..., g, None] ** 2 * Gg  # diag(ω²) G, exact for eigenmodes
        Kg = Tg @ (0.5 * (Kraw + np.swapaxes(Kraw, -1, -2))) @ np.swapaxes(Tg, -1, -2)
        K[..., g[:, None], g[None, :]] = 0.5 * (Kg + np.swapaxes(Kg, -1, -2))
    transform = np.empty(gshape, dtype=object)
    for idx in np.ndindex(gshape):
        transform[idx] = T[idx]
    diag = np.diagonal(K, axis1=-2, axis2=-1)
    basis = SmoothBasis(transform=transform, stiffness=K,
                        omega=np.sqrt(np.clip(diag, 0.0, None)),
                        clusters=tuple(tuple(int(k) for k in c) for c in clusters),
                        neighbour_mac=np.full(gshape + (len(gshape), n), np.nan))
    return basis, low
