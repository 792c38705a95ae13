"""Model quantities in a rotated mode basis (the smooth basis of :mod:`casflex.modal.subspace`).

A basis vector of the smooth basis is a combination ``ψ_j = Σ_i R_ji φ_i`` of
mass-normalised eigenmodes ``φ_i`` of *different* frequencies. The shape quadratures of
:mod:`casflex.modal.integrals` rebuild every mode between its samples from its own ω
(:func:`casflex.modal.normalize.local_state`), so they cannot be evaluated on ``ψ``
directly (errors up to 6e-7 in the modal mass of the 4-joint arm's pair). They are
evaluated on the eigenmodes instead and transformed:

* quantities **linear** in the shapes (``C1``, ``eps``, ``end_u``, ``end_theta``,
  ``spring_phi``, ``sample_*``, ``point_*``) transform with ``R`` along their mode axis;
* quantities **bilinear** in the shapes (``C2``, ``N``) with ``R · Rᵀ`` on both mode axes.

``omega`` becomes the basis' Rayleigh frequencies ``sqrt(diag K̃)``, and two matrices are
added: ``stiffness`` ``K̃ = R diag(ω²) Rᵀ`` [rad²/s²] and its square root
``stiffness_root`` ``Ω̃ = R diag(ω) Rᵀ`` [rad/s] (the modal damping ``2ζ Ω̃`` of
:class:`casflex.model.FlexibleModel`). In the eigen basis (``R`` the identity) ``K̃ =
diag(ω²)`` and ``Ω̃ = diag(ω)``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.modal.subspace import SmoothBasis
    from casflex.robot import Robot
    from casflex.tmm.solve import ModeShapes

__all__ = ["MODE_AXES", "rotate_quantities", "stiffness_values", "rotated_quantities",
           "normalized_quantities"]

#: mode axes of every quantity of :func:`casflex.modal.integrals.configuration_quantities`
#: (one axis: linear in the shapes; two: bilinear)
MODE_AXES = {
    "C1": (1,), "C2": (1, 2), "N": (1, 2), "eps": (1,), "end_u": (1,), "end_theta": (1,),
    "spring_phi": (1,), "sample_u": (2,), "sample_theta": (2,), "point_u": (1,),
    "point_theta": (1,), "point_curvature": (1,), "point_twist_rate": (1,),
    "point_axial_strain": (1,),
}


def rotate_quantities(values: Mapping[str, ArrayLike], rotation: ArrayLike
                      ) -> dict[str, np.ndarray]:
    """Transform eigenmode quantities to the basis ``ψ_j = Σ_i rotation[j, i] φ_i``.

    Parameters
    ----------
    values : dict of str to array_like
        Quantities of the mass-normalised eigenmodes ``φ`` (keys of
        :data:`MODE_AXES`, units as in :mod:`casflex.modal.integrals`); ``omega`` and
        keys ending in ``stiffness`` / ``stiffness_root`` are left out (they are not
        linear in the shapes).
    rotation : array_like
        (n, m) change of basis (dimensionless; orthogonal for a mass-orthonormal ``ψ``).

    Returns
    -------
    dict of str to numpy.ndarray
        The same keys with ``n`` modes along each mode axis.

    Raises
    ------
    ModelError
        A key whose transformation is not known (never guessed), or a mode count that
        does not match ``rotation``.

    Examples
    --------
    >>> R = np.array([[0.6, 0.8], [-0.8, 0.6]])
    >>> out = rotate_quantities({"N": np.eye(2)[None], "end_u": np.ones((1, 2, 3))}, R)
    >>> out["N"][0].round(12).tolist(), out["end_u"][0, :, 0].round(12).tolist()
    ([[1.0, 0.0], [0.0, 1.0]], [1.4, -0.2])
    """
    R = np.asarray(rotation, dtype=float)
    if R.ndim != 2:
        raise ModelError(f"rotation must be an (n, m) matrix; got shape {R.shape}")
    out = {}
    for name, value in values.items():
        if name in ("omega", "stiffness", "stiffness_root"):
            continue
        if name not in MODE_AXES:
            raise ModelError(f"quantity {name!r}: unknown how it transforms with a change of "
                             f"mode basis (known: {sorted(MODE_AXES)})")
        v = np.asarray(value, dtype=float)
        for ax in MODE_AXES[name]:
            if v.shape[ax] != R.shape[1]:
                raise ModelError(f"quantity {name!r} has {v.shape[ax]} modes on axis {ax}; "
                                 f"the rotation takes {R.shape[1]}")
            v = np.moveaxis(np.tensordot(R, v, axes=(1, ax)), 0, ax)
        out[name] = v
    return out


def stiffness_values(basis: SmoothBasis) -> dict[str, np.ndarray]:
    """``stiffness`` ``K̃`` and ``stiffness_root`` ``Ω̃ = sqrtm(K̃)`` over a smooth basis' grid.

    Parameters
    ----------
    basis : casflex.modal.subspace.SmoothBasis

    Returns
    -------
    dict of str to numpy.ndarray
        ``grid_shape + (n, n)``: ``K̃`` [rad²/s²] and its symmetric positive square root
        [rad/s] (block-diagonal like ``K̃``; ``diag(ω)`` where a block is one mode).

    Examples
    --------
    >>> from casflex.modal.subspace import smooth_basis
    >>> F = np.empty((1,), dtype=object)
    >>> F[0] = np.array([[1.0, 1.0], [1.0, -1.0]])
    >>> v = stiffness_values(smooth_basis(F, np.array([[3.0, 4.0]]), ((0, 1),)))
    >>> bool(np.allclose(v["stiffness_root"][0] @ v["stiffness_root"][0], v["stiffness"][0]))
    True
    """
    K = np.asarray(basis.stiffness, dtype=float)
    lam, V = np.linalg.eigh(0.5 * (K + np.swapaxes(K, -1, -2)))
    root = np.einsum("...ij,...j,...kj->...ik", V, np.sqrt(np.clip(lam, 0.0, None)), V)
    return {"stiffness": K, "stiffness_root": 0.5 * (root + np.swapaxes(root, -1, -2))}


def normalized_quantities(func: Callable[..., Mapping[str, ArrayLike]], robot: Robot,
                          q: ArrayLike, shapes: ModeShapes, count: int | None = None
                          ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Quantities of the mass-normalised raw modes, and the map back to the raw modes.

    Parameters
    ----------
    func : callable
        ``func(robot, q, shapes) -> dict`` that mass-normalises the shapes it is given by
        a positive scaling (as :func:`casflex.modal.tables.default_quantities` does).
    robot : casflex.robot.Robot
    q : array_like
        Joint variables [rad] the shapes belong to.
    shapes : casflex.tmm.ModeShapes
        Raw modes sorted by frequency.
    count : int, optional
        Use the lowest ``count`` modes only (default all).

    Returns
    -------
    values : dict of str to numpy.ndarray
        ``func``'s quantities of the normalised modes ``φ`` (``omega`` included).
    raw_from_normalized : numpy.ndarray
        (count, count) ``S⁻¹`` with raw mode ``i`` = ``Σ_k S⁻¹[i, k] φ_k`` (diagonal at
        simple roots, block-triangular at multiple ones): a basis ``T · raw`` is
        ``(T S⁻¹) · φ``, whose quantities are ``rotate_quantities(values, T @ S⁻¹)``.

    Examples
    --------
    >>> from casflex.modal.normalize import modal_mass_matrix
    >>> from casflex.modal.tables import default_quantities
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> raw = modes(robot, [0.0, 0.0, 0.5], count=2)
    >>> values, S_inv = normalized_quantities(default_quantities, robot, [0, 0, 0.5], raw)
    >>> bool(np.allclose(np.diag(S_inv) ** 2, np.diag(modal_mass_matrix(robot, raw))))
    True
    """
    import dataclasses

    from casflex.modal.normalize import SHAPE_FIELDS, mass_normalize

    used = np.asarray(shapes.omega).size if count is None else int(count)
    shapes = dataclasses.replace(shapes, **{
        f: np.asarray(getattr(shapes, f))[:used]
        for f in ("omega", "multiplicity") + tuple(SHAPE_FIELDS)})
    normalized = mass_normalize(robot, shapes)
    # normalized = S · raw (S from the modal mass, block-triangular at multiple roots),
    # read off the displacement samples
    raw_f = np.asarray(shapes.displacement, dtype=float).reshape(used, -1)
    norm_f = np.asarray(normalized.displacement, dtype=float).reshape(used, -1)
    S_inv = np.linalg.lstsq(norm_f.T, raw_f.T, rcond=None)[0].T
    values = func(robot, np.asarray(q, dtype=float), normalized)
    if not isinstance(values, Mapping):
        raise ModelError(f"the quantity function must return a dict; got {type(values)}")
    return {str(k): np.asarray(v, dtype=float) for k, v in values.items()}, S_inv


def rotated_quantities(func: Callable[..., Mapping[str, ArrayLike]], robot: Robot,
                       q: ArrayLike, shapes: ModeShapes, transform: ArrayLike
                       ) -> dict[str, np.ndarray]:
    """Model quantities of a rotated basis of raw modes (run in worker processes).

    ``func`` (e.g. :func:`casflex.modal.tables.default_quantities`) is evaluated on the
    mass-normalised eigenmodes, each rebuilt with its own ω
    (:func:`normalized_quantities`); the result is transformed with
    :func:`rotate_quantities` (module notes).

    Parameters
    ----------
    func : callable
        ``func(robot, q, shapes) -> dict`` that mass-normalises the shapes it is given by
        a positive scaling (as ``default_quantities`` does).
    robot : casflex.robot.Robot
    q : array_like
        Joint variables [rad] the shapes belong to.
    shapes : casflex.tmm.ModeShapes
        The raw modes, sorted by frequency (as given to
        :func:`casflex.modal.subspace.track_grid_smooth`).
    transform : array_like
        (n, m) ``SmoothBasis.transform`` of this point: basis vector ``j`` =
        ``Σ_i transform[j, i]`` · raw mode ``i`` (its rows of unit modal mass).

    Returns
    -------
    dict of str to numpy.ndarray
        ``func``'s quantities of the ``n`` basis vectors (``omega`` left out: the
        Rayleigh frequencies come with the basis).

    Examples
    --------
    At a simple root the smooth basis of one mode is the mass-normalised mode itself:

    >>> from casflex.modal.normalize import modal_mass_matrix
    >>> from casflex.modal.tables import default_quantities
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> q = np.array([0.0, 0.0, 0.5])
    >>> raw = modes(robot, q, count=1)
    >>> T = 1.0 / np.sqrt(modal_mass_matrix(robot, raw))
    >>> out = rotated_quantities(default_quantities, robot, q, raw, T)
    >>> bool(np.allclose(out["C1"], default_quantities(robot, q, raw)["C1"], rtol=1e-12,
    ...                  atol=1e-15))
    True
    """
    T = np.asarray(transform, dtype=float)
    used = int(np.max(np.flatnonzero(np.any(T != 0.0, axis=0)), initial=-1)) + 1
    values, S_inv = normalized_quantities(func, robot, q, shapes, used)
    return rotate_quantities(values, T[:, :used] @ S_inv)
