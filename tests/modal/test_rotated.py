"""Model quantities of a rotated mode basis (casflex.modal.rotated).

The quantities are evaluated on the eigenmodes and transformed (linear: R, bilinear:
R·Rᵀ). References: explicit einsums for the rules; on the 4-joint arm, the quadratures
of the rotated shapes themselves where they are valid (at the double root both modes of
the pair have one ω), and everywhere the model's own kinetic energy: the modal block of
M at δ = 0 built from the rotated C2, end transforms and springs is the identity (the
basis is mass-orthonormal by the exact modal-mass quadrature).
"""

import warnings

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal import (
    build_table,
    configuration_quantities,
    default_quantities,
    rotate_quantities,
    rotated_quantities,
    track_grid_smooth,
)
from casflex.robot import load
from casflex.tmm import modes


def test_linear_and_bilinear_rules_against_einsum():
    rng = np.random.default_rng(0)
    R = rng.normal(size=(2, 3))
    C1, C2 = rng.normal(size=(2, 3, 4, 4)), rng.normal(size=(2, 3, 3, 4, 4))
    samples, point = rng.normal(size=(2, 5, 3, 3)), rng.normal(size=(4, 3))
    out = rotate_quantities({"C1": C1, "C2": C2, "sample_u": samples,
                             "point_twist_rate": point, "omega": np.ones(3)}, R)
    assert "omega" not in out
    assert np.allclose(out["C1"], np.einsum("ji,bixy->bjxy", R, C1), rtol=1e-14, atol=0)
    assert np.allclose(out["C2"], np.einsum("ji,lk,bikxy->bjlxy", R, R, C2), rtol=1e-14,
                       atol=1e-14)
    assert np.allclose(out["sample_u"], np.einsum("ji,bpix->bpjx", R, samples), rtol=1e-14,
                       atol=1e-14)
    assert np.allclose(out["point_twist_rate"], point @ R.T, rtol=1e-14, atol=1e-14)


def test_unknown_quantities_and_counts_are_refused():
    with pytest.raises(ModelError, match="unknown how it transforms"):
        rotate_quantities({"mystery": np.ones((1, 2))}, np.eye(2))
    with pytest.raises(ModelError, match="has 3 modes on axis 1"):
        rotate_quantities({"C1": np.ones((1, 3, 4, 4))}, np.eye(2))


@pytest.fixture(scope="module")
def arm4_pair():
    """Raw modes of the 4-joint arm on a 3 × 3 grid around the straight wrist (0, 0), a
    double root of every bending pair, and their smooth basis (4 modes: 2 pairs)."""
    robot = load("problems/arm4_spatial.toml")
    axis = np.radians([-4.0, 0.0, 4.0])
    raw = np.empty((3, 3), dtype=object)
    for i, a in enumerate(axis):
        for j, b in enumerate(axis):
            raw[i, j] = modes(robot, [0.0, 0.0, a, b], count=6)
    return robot, axis, raw, track_grid_smooth(raw, 4, robot)


def _kinematic_modal_mass(robot, q, values, omega):
    from casflex.model import ConstantProvider, FlexibleModel

    provider = ConstantProvider(dict(values, omega=omega), shape_joints=(2, 3))
    model = FlexibleModel(robot, provider, gravity=None, modal_mass="kinematic")
    m = omega.size
    return model.functions()["mass"](q, np.zeros(m)).full()[-m:, -m:]


@pytest.mark.slow
def test_at_the_double_root_the_rotated_quadratures_agree(arm4_pair):
    """Both modes of a pair share ω at the double root, so there the rotated shapes may be
    integrated directly: the two ways agree to round-off."""
    robot, axis, raw, sb = arm4_pair
    q = np.array([0.0, 0.0, 0.0, 0.0])
    assert np.all(np.asarray(raw[1, 1].multiplicity)[:4] == 2)
    rot = rotated_quantities(default_quantities, robot, q, raw[1, 1], sb.transform[1, 1])
    direct = configuration_quantities(robot, q, sb.apply(raw)[1, 1])
    for name, value in rot.items():
        if value.size:
            # round-off of the quadratures (sums of ~50 terms), relative to the peak
            assert np.abs(value - direct[name]).max() <= 1e-12 * np.abs(value).max(), name


@pytest.mark.slow
def test_off_the_double_root_the_modal_mass_stays_the_identity(arm4_pair):
    """Away from the double root the pair's ω differ by ~1e-3; the rotated quantities give
    the model a modal mass I to 1e-12, the quadratures of the rotated shapes do not (each
    shape rebuilt with a Rayleigh ω that is not its own: ~4e-5)."""
    robot, axis, raw, sb = arm4_pair
    shapes = sb.apply(raw)
    for idx in ((2, 2), (0, 2)):
        q = np.array([0.0, 0.0, axis[idx[0]], axis[idx[1]]])
        rot = rotated_quantities(default_quantities, robot, q, raw[idx], sb.transform[idx])
        M = _kinematic_modal_mass(robot, q, rot, sb.omega[idx])
        assert np.abs(M - np.eye(4)).max() < 1e-12
    # at (−4°, 4°) the basis mixes the pair most: the error the rotation avoids
    direct = configuration_quantities(robot, q, shapes[idx])
    M = _kinematic_modal_mass(robot, q, direct, sb.omega[idx])
    assert np.abs(M - np.eye(4)).max() > 1e-6


@pytest.mark.slow
def test_build_table_smooth_basis_with_quantities(arm4_pair):
    """build_table(basis="smooth") tabulates the rotated quantities, K̃ and Ω̃ = sqrtm K̃,
    and the model's modal mass from the table is the identity at the grid points."""
    robot, axis, raw, sb = arm4_pair
    table = build_table(robot, [axis, axis], 4, cache_dir=False, processes=1,
                        basis="smooth")
    v = table.values
    assert table.info["clusters"] == [[1, 2], [3, 4]]
    assert v["C2"].shape == (3, 3, 3, 4, 4, 4, 4)
    root = v["stiffness_root"]
    assert np.allclose(root @ root, v["stiffness"], rtol=0, atol=1e-9 * v["stiffness"].max())
    # the double root's shapes come from q + 1e-4 rad (tables' module notes): there the
    # eigen-basis table is off by 1.2e-8 as well; elsewhere round-off
    for idx, tol in (((1, 1), 3e-8), ((0, 2), 1e-12), ((1, 2), 1e-12)):
        q = table.q(idx)
        values = {k: val[idx] for k, val in v.items()
                  if k not in ("omega", "stiffness", "stiffness_root")}
        M = _kinematic_modal_mass(robot, q, values, v["omega"][idx])
        assert np.abs(M - np.eye(4)).max() < tol, idx


@pytest.mark.slow
def test_smooth_and_eigen_models_agree_on_basis_invariants(arm4_pair):
    """At the grid points both tables hold the same raw modes in two bases related by an
    orthogonal R: what the joints feel of the modes is basis-free. With B = M_qδ at δ = 0,
    B Bᵀ, B K⁻¹ Bᵀ and B D Bᵀ are the same for the two models (K = diag(ω²) and K̃)."""
    from casflex.model import FlexibleModel, TableProvider

    robot = arm4_pair[0]
    axis = np.radians([-4.0, 0.0, 4.0, 8.0])  # the B-splines need 4 points per axis
    models = {}
    for basis in ("eigen", "smooth"):
        with warnings.catch_warnings():  # the eigen basis' low MAC at the double root
            warnings.simplefilter("ignore", RuntimeWarning)
            table = build_table(robot, [axis, axis], 4, cache_dir=False, processes=1,
                                basis=basis)
        models[basis] = FlexibleModel(robot, TableProvider(table), gravity=None,
                                      damping_ratio=0.02).functions()
    for a, b in ((0, 2), (2, 1), (3, 3)):
        q = np.array([0.3, -0.2, axis[a], axis[b]])
        inv = []
        for basis in ("eigen", "smooth"):
            f = models[basis]
            B = f["mass"](q, np.zeros(4)).full()[:4, 4:]
            K, D = f["stiffness"](q).full(), f["damping"](q).full()
            inv.append([B @ B.T, B @ np.linalg.solve(K, B.T), B @ D @ B.T])
        for u, v in zip(*inv, strict=True):
            assert np.abs(u - v).max() <= 1e-9 * np.abs(u).max()
