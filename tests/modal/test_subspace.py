"""Smooth mode bases over grids with close and crossing modes (casflex.modal.subspace).

The constructed case is a symmetric "stiffness" K(x, y) on a 5-D feature space whose two
lowest eigenvalues meet at a conical intersection at the origin (the generic way two modes
meet in a 2-parameter family) inside a plane that itself turns slowly with (x, y); a
third mode stays far above. Its eigenvectors turn by 90° around the cone, so no ordering
or sign of them is smooth, while the plane is. References are computed here from K
itself (numpy.linalg.eigh, projectors, quadratic forms), not from the code under test.
"""

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal.normalize import modal_mass_matrix, modal_stiffness_matrix
from casflex.modal.subspace import mode_clusters, smooth_basis, track_grid_smooth
from casflex.modal.tracking import track_grid
from casflex.robot import load
from casflex.tmm import modes


def _frame(x, y):
    """An orthonormal 5 × 5 frame turning smoothly with (x, y) (a product of rotations)."""
    def rot(i, j, a):
        R = np.eye(5)
        R[[i, i, j, j], [i, j, i, j]] = [np.cos(a), -np.sin(a), np.sin(a), np.cos(a)]
        return R
    return rot(0, 3, 0.3 * x) @ rot(1, 4, 0.2 * y) @ rot(0, 2, 0.1 * x * y)


def _stiffness(x, y):
    """K with eigenvalues 4 ± 0.5·sqrt(x² + y²) on the frame's first two axes, 25 and up
    on the others."""
    H = np.diag([0.0, 0.0, 25.0, 36.0, 49.0])
    H[:2, :2] = [[4.0 + 0.5 * x, 0.5 * y], [0.5 * y, 4.0 - 0.5 * x]]
    V = _frame(x, y)
    return V @ H @ V.T


AXIS = np.linspace(-1.0, 1.0, 21)  # includes the cone's apex (0, 0): an exact double root


def _eigen_grid(y_offset=0.0):
    features = np.empty((AXIS.size, AXIS.size), dtype=object)
    omega = np.empty((AXIS.size, AXIS.size, 5))
    K = np.empty((AXIS.size, AXIS.size, 5, 5))
    for i, x in enumerate(AXIS):
        for j, y in enumerate(AXIS + y_offset):
            K[i, j] = _stiffness(x, y)
            e, V = np.linalg.eigh(K[i, j])
            features[i, j] = V.T  # rows: unit eigenvectors, ascending frequency
            omega[i, j] = np.sqrt(e)
    return features, omega, K


def test_clusters_from_the_gaps():
    _, omega, _ = _eigen_grid()
    assert mode_clusters(omega, 3) == ((0, 1), (2,))
    assert mode_clusters(omega, 1) == ((0, 1),)  # a cluster is never split
    with pytest.raises(ModelError, match="compute more modes"):
        mode_clusters(omega[..., :2], 1)


@pytest.mark.parametrize("y_offset", [0.0, 0.05])
def test_cone_basis_is_smooth_and_spans_the_eigen_subspace(y_offset):
    # y_offset 0: the apex is a grid point (exact double root, arbitrary eigen basis);
    # 0.05: the apex is inside a cell, where the eigenvectors turn fastest between points
    features, omega, K = _eigen_grid(y_offset)
    sb = smooth_basis(features, omega, mode_clusters(omega, 3))
    # the eigenvectors themselves are not smooth around the cone: with the best
    # permutation between neighbours the worse MAC of the pair falls below 0.95 (so the
    # check below can fail): cos²(22.5°) = 0.85 next to the apex, cos²(31.7°) = 0.72
    # next to the cell that holds it
    worst_eigen = 1.0
    for i in range(1, AXIS.size):
        for j in range(AXIS.size):
            c = (features[i, j][:2] @ features[i - 1, j][:2].T) ** 2
            worst_eigen = min(worst_eigen, max(min(c[0, 0], c[1, 1]), min(c[0, 1], c[1, 0])))
    assert worst_eigen < (0.8 if y_offset else 0.9)
    assert sb.min_mac >= 0.95
    for idx in np.ndindex(AXIS.size, AXIS.size):
        B = sb.transform[idx] @ features[idx]  # basis vectors in the 5-D space
        # orthonormal, and the pair spans the solver's 2-D eigen-subspace (projectors)
        assert np.abs(B @ B.T - np.eye(3)).max() < 1e-12
        P_basis = B[:2].T @ B[:2]
        P_eig = features[idx][:2].T @ features[idx][:2]
        assert np.abs(P_basis - P_eig).max() < 1e-12
        # stiffness of the basis: the quadratic form of K itself, block-diagonal
        assert np.allclose(sb.stiffness[idx], B @ K[idx] @ B.T, rtol=0, atol=1e-12)
        assert sb.stiffness[idx][:2, 2] == pytest.approx([0.0, 0.0], abs=0.0)
    # its eigenvalues are the natural frequencies; the Rayleigh ones are not
    assert np.allclose(sb.eigenfrequencies(), omega[..., :3], rtol=1e-13)
    assert np.allclose(sb.omega ** 2, np.diagonal(sb.stiffness, axis1=-2, axis2=-1))


def test_basis_follows_a_smooth_reference_frame():
    """Away from the apex the basis turns with the frame (smooth), not with the
    eigenvectors: neighbouring basis vectors differ by O(step), far less than the
    eigenvectors' turn across the apex."""
    features, omega, _ = _eigen_grid()
    sb = smooth_basis(features, omega, ((0, 1), (2,)))
    mid = AXIS.size // 2
    B = [sb.transform[i, mid] @ features[i, mid] for i in (mid - 1, mid, mid + 1)]
    step = AXIS[1] - AXIS[0]
    # the frame turns by at most (0.3 + 0.2 + 0.1)·step per step; Procrustes changes the
    # pair by no more in total (sum of squares) than that transported basis, so each
    # vector moves by < sqrt(2)·0.6·step; the eigenvectors swap across the apex (|Δ| = √2)
    for a, b in zip(B[:-1], B[1:], strict=True):
        assert np.linalg.norm(a[:2] - b[:2], axis=1).max() < np.sqrt(2.0) * 0.6 * step
    e = [features[i, mid][:2] for i in (mid - 1, mid + 1)]
    assert np.abs(np.diag(e[0] @ e[1].T)).max() < 0.2  # the eigenvectors swap there


@pytest.mark.slow
def test_arm4_pair_is_mass_orthonormal_with_the_strain_energy_stiffness():
    """Real TMM modes of the 4-joint arm around its straight wrist (a double root), where
    the tubes' two bending directions are nearly equal: the smooth basis has unit modal
    mass and its stiffness block equals the strain energy of the basis vectors (an
    independent quadrature: modal_stiffness_matrix agrees with ω² to ~1e-9 relative)."""
    robot = load("problems/arm4_spatial.toml")
    axis = np.radians([-4.0, 0.0, 4.0])
    raw = np.empty((3, 3), dtype=object)
    for i, a in enumerate(axis):
        for j, b in enumerate(axis):
            raw[i, j] = modes(robot, [0.0, 0.0, a, b], count=6)
    sb = track_grid_smooth(raw, 4, robot)
    assert sb.clusters[0] == (0, 1)
    assert sb.min_mac >= 0.95
    eig = track_grid(raw, count=4, robot=robot)
    assert sb.min_mac >= float(np.nanmin(eig.mac))
    n = sb.omega.shape[-1]
    for idx in np.ndindex(3, 3):
        # exact quadratures of the eigenmodes (each reconstructed with its own ω), then
        # the change of basis: unit modal mass, and K̃ = the basis' strain energy
        T = sb.transform[idx]
        G = modal_mass_matrix(robot, raw[idx])
        Ks = modal_stiffness_matrix(robot, raw[idx])
        assert np.abs(T @ G @ T.T - np.eye(n)).max() < 1e-9  # the double root: ~1e-10
        w2max = float(np.max(sb.stiffness[idx]))
        assert np.abs(T @ Ks @ T.T - sb.stiffness[idx]).max() < 1e-8 * w2max


def test_a_count_that_splits_a_cluster_is_refused():
    robot = load("problems/arm2link.toml")
    raw = np.empty((2,), dtype=object)
    raw[0], raw[1] = (modes(robot, [0, 0, x], count=4) for x in (0.9, 0.95))
    assert track_grid_smooth(raw, 3, robot).clusters == ((0,), (1, 2))
    with pytest.raises(ModelError, match="split the cluster of close modes \\[2, 3\\]"):
        track_grid_smooth(raw, 2, robot)


def test_build_table_refuses_an_unknown_basis(tmp_path):
    from casflex.modal import build_table

    robot = load("problems/arm2link.toml")
    grid = np.radians([0.0, 10.0, 20.0, 30.0])
    with pytest.raises(ModelError, match="basis must be"):
        build_table(robot, grid, 2, cache_dir=tmp_path, processes=1, basis="qr")
