"""Mass normalisation and modal integrals (casflex.modal.normalize, casflex.modal.integrals).

Independent checks: orthogonality of modes of different frequencies in the mass inner
product (physics, not enforced by the normalisation), the strain energy of the normalised
modes computed here from the sampled curvature fields (Simpson) against ω², and the
normalised amplitudes against the mass-normalised modes of the independent beam FE model
in tests/reference_fem.py.
"""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest
import reference_fem as fem
from scipy.integrate import simpson

from casflex.errors import ModelError
from casflex.modal.integrals import configuration_quantities, quantity_shapes
from casflex.modal.normalize import mass_normalize, modal_mass_matrix, modal_stiffness_matrix
from casflex.robot import Section, TipBody, load, loads
from casflex.tmm import modes

ARM = load("problems/arm2link.toml")
TESTBED = load("problems/testbed.toml")

def _with_tips(robot):
    links = list(robot.links)
    links[2] = dataclasses.replace(links[2], tip=TipBody(0.5, (517e-6, 72e-6, 520e-6),
                                                         (0.01, 0.0, 0.02)))
    links[3] = dataclasses.replace(links[3], tip=TipBody(0.15, (25e-6, 78e-6, 56e-6)))
    return dataclasses.replace(robot, links=tuple(links))


def _strain_energy_simpson(robot, shapes):
    """K_jk from the sampled fields, composite Simpson; no code shared with the library."""
    m = shapes.omega.size
    K = np.zeros((m, m))
    for b, row in enumerate(shapes.rows):
        link = robot.links[row]
        E, G, sec = link.material.E, link.material.G, link.section
        s = shapes.s[b]
        kx, ky = shapes.curvature[:, b, :, 0], shapes.curvature[:, b, :, 1]
        tw, ax = shapes.twist_rate[:, b], shapes.axial_strain[:, b]
        dens = (E * sec.Iy * kx[:, None] * kx[None] + E * sec.Ix * ky[:, None] * ky[None]
                + G * sec.J * tw[:, None] * tw[None] + E * sec.A * ax[:, None] * ax[None])
        K += simpson(dens, x=s, axis=-1)
    for i, row in enumerate(shapes.spring_rows):
        phi = shapes.spring_rotation[:, i]
        K += robot.links[row].joint_stiffness * np.outer(phi, phi)
    return K


@pytest.mark.parametrize("q", [[0.0, 0.0, 0.0], [0.3, -0.4, 0.7], [1.0, 0.5, -2.0]])
def test_modes_of_different_frequencies_are_mass_orthogonal(q):
    shapes = mass_normalize(ARM, modes(ARM, q, count=6))
    M = modal_mass_matrix(ARM, shapes)
    off = M - np.diag(np.diag(M))
    assert np.abs(np.diag(M) - 1.0).max() < 1e-12
    assert np.abs(off).max() < 1e-8


@pytest.mark.parametrize("stiffness", [[None, None, 90.0], [120.0, 100.0, 90.0]])
def test_orthogonality_with_joint_springs(stiffness):
    robot = ARM.with_joint_stiffness(stiffness)
    shapes = mass_normalize(robot, modes(robot, [0.2, 0.3, 0.9], count=5))
    assert np.abs(modal_mass_matrix(robot, shapes) - np.eye(5)).max() < 1e-8


@pytest.mark.parametrize("robot", [_with_tips(ARM), TESTBED], ids=["arm+tips", "testbed"])
def test_orthogonality_with_tip_bodies(robot):
    shapes = mass_normalize(robot, modes(robot, [0.2, 0.3, 0.9], count=5))
    assert np.abs(modal_mass_matrix(robot, shapes) - np.eye(5)).max() < 1e-8


@pytest.mark.parametrize("stiffness", [[None, None, None], [120.0, 100.0, 90.0]])
def test_strain_energy_equals_omega_squared(stiffness):
    robot = ARM.with_joint_stiffness(stiffness)
    shapes = mass_normalize(robot, modes(robot, [0.1, 0.2, 1.1], count=5, n_points=201))
    K = _strain_energy_simpson(robot, shapes)
    w2 = shapes.omega**2
    assert np.allclose(np.diag(K) / w2, 1.0, rtol=0, atol=1e-6)
    assert np.abs(K - np.diag(np.diag(K))).max() / w2.max() < 1e-6
    # the library's Gauss version agrees to round-off
    Kg = modal_stiffness_matrix(robot, shapes)
    assert np.allclose(Kg, np.diag(w2), rtol=0, atol=1e-9 * w2.max())


def test_quadrature_converges():
    shapes = mass_normalize(ARM, modes(ARM, [0.0, 0.0, 0.4], count=6, n_points=201))
    M48 = modal_mass_matrix(ARM, shapes, points=48)
    M96 = modal_mass_matrix(ARM, shapes, points=96)
    Ms = modal_mass_matrix(ARM, shapes, method="simpson")
    assert np.abs(M48 - M96).max() < 1e-13
    assert np.abs(Ms - M48).max() < 1e-8
    with pytest.raises(ModelError):
        modal_mass_matrix(ARM, shapes, method="trapezoid")


def test_normalized_amplitudes_match_reference_fem():
    # the FE model is built from the problem file's numbers alone (reference_fem); its own
    # error on these modes is < 1e-7 (40 elements, tests/tmm/test_tmm.py). Observed:
    # frequencies 1.7e-9, mass-normalised shapes 5e-9 of their peak; both to 1e-6 allowed
    # (the FE budget; a 0.05 % mass error changes the normalisation by 2.5e-4)
    q = [0.2, -0.3, 0.8]
    shapes = mass_normalize(ARM, modes(ARM, q, count=4))
    with open("problems/arm2link.toml", "rb") as fh:
        data = tomllib.load(fh)
    w, fshapes = fem.robot_modes(data, q, n_modes=4)
    np.testing.assert_allclose(shapes.omega, w, rtol=1e-6)
    tmm = shapes.displacement_global[:, 1]  # (m, points, 3) along link 2
    ref = fshapes.sample(1, np.linspace(0.0, 1.0, tmm.shape[1]))
    for j in range(4):
        sign = np.sign(np.sum(tmm[j] * ref[j]))
        assert np.abs(tmm[j] - sign * ref[j]).max() < 1e-6 * np.abs(ref[j]).max()


def test_double_root_is_mass_orthonormalized():
    robot = loads("""
        name = "tube"
        [[link]]
        joint = "revolute"
        d = 1.0
        [link.section]
        shape = "tube"
        outer_diameter = 0.02
        wall = 0.002
        [link.material]
        E = 69e9
        G = 26.9e9
        rho = 2700.0
    """)
    raw = modes(robot, [0.0], count=2)
    assert list(raw.multiplicity) == [2, 2]
    # scramble the pair so that it is far from mass-orthogonal
    S = np.array([[1.0, 0.0], [3.0, 0.5]])
    mixed = dataclasses.replace(raw, **{
        f: np.tensordot(S, getattr(raw, f), axes=(1, 0))
        for f in ("displacement", "rotation", "moment", "force", "slope", "curvature",
                  "twist_rate", "axial_strain", "body_state", "body_state_local",
                  "spring_rotation")})
    shapes = mass_normalize(robot, mixed)
    assert np.abs(modal_mass_matrix(robot, shapes) - np.eye(2)).max() < 1e-12
    assert np.allclose(modal_stiffness_matrix(robot, shapes), np.diag(shapes.omega**2),
                       rtol=1e-9)
    # Gram-Schmidt keeps the direction of the first vector
    a, b = shapes.displacement[0].ravel(), mixed.displacement[0].ravel()
    assert abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b) == pytest.approx(1.0)


def test_configuration_quantities_shapes_and_rigid_rotation_invariance():
    q1, q2 = [0.0, 0.0, 0.6], [1.2, -0.7, 0.6]  # same elbow angle
    pts = [(2, 0.3), (3, 1.0)]
    Q1 = configuration_quantities(ARM, q1, mass_normalize(ARM, modes(ARM, q1, count=4)), pts)
    Q2 = configuration_quantities(ARM, q2, mass_normalize(ARM, modes(ARM, q2, count=4)), pts)
    shapes = quantity_shapes(ARM, 4, n_points=2)
    assert set(Q1) == set(shapes)
    for k in Q1:
        assert Q1[k].shape == shapes[k]
        assert np.allclose(Q1[k], Q2[k], atol=1e-8 * max(1.0, np.abs(Q1[k]).max(initial=0.0))), k
    # the link-local modal mass of eq. 94 is part of the identity
    assert np.all(np.linalg.eigvalsh(Q1["N"].sum(axis=0)) <= 1.0 + 1e-9)
    # curvature at a sensor point agrees with the sampled field (s = 1 m is a sample)
    shp = mass_normalize(ARM, modes(ARM, q1, count=4))
    assert np.allclose(Q1["point_curvature"][1], shp.curvature[:, 1, -1], atol=1e-9)


def test_configuration_quantities_errors():
    q = [0.0, 0.0, 0.6]
    shapes = mass_normalize(ARM, modes(ARM, q, count=2))
    with pytest.raises(ModelError):
        configuration_quantities(ARM, [0.0, 0.0, 1.6], shapes)
    with pytest.raises(ModelError):
        configuration_quantities(ARM, q, shapes, points=[(1, 0.2)])
    with pytest.raises(ModelError):
        configuration_quantities(ARM, q, shapes, points=[(3, 1.5)])


def test_section_helper_consistency():
    # a tube's J equals Ip, used by the torsional inertia of the integrals
    s = Section.tube(0.0127, 0.00041)
    assert s.J == s.Ip
