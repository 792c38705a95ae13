"""Validation of the independent frame finite-element reference (tests/reference_fem.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

try:
    from reference_fem import JointSpring, PointBody, Segment, modes
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests.reference_fem import JointSpring, PointBody, Segment, modes

# aluminium-like rectangular section b (local x) x h (local y)
E, G, RHO = 70e9, 26e9, 2700.0
B, H = 0.02, 0.04
AREA = B * H
IX = B * H**3 / 12  # about local x -> deflection w_y
IY = H * B**3 / 12  # about local y -> deflection w_x
J_T = 0.229 * H * B**3  # St-Venant constant, aspect ratio 2
IP = IX + IY
BETA_L = np.array([1.87510407, 4.69409113, 7.85475744, 10.99554073])


def make_segment(start, end, local_x, n_elements=40, **kw):
    props = dict(E=E, G=G, rho=RHO, A=AREA, Ix=IX, Iy=IY, J=J_T, Ip=IP)
    props.update(kw)
    return Segment(start, end, local_x, n_elements=n_elements, **props)


def cantilever_bending(EI, L, mu=RHO * AREA):
    return BETA_L**2 * np.sqrt(EI / (mu * L**4))


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def match(omega_fe, targets):
    """For each target frequency the closest FE frequency."""
    return np.array([omega_fe[np.argmin(np.abs(omega_fe - t))] for t in targets])


# ----------------------------------------------------------------------------- cantilever
def test_cantilever_bending_both_planes_vs_analytic():
    L = 1.2
    seg = make_segment([0, 0, 0], [0, 0, L], [1, 0, 0])
    omega, _ = modes([seg], clamp=[0, 0, 0], n_modes=10)
    for EI in (E * IY, E * IX):
        ref = cantilever_bending(EI, L)
        fe = match(omega, ref)
        rel = fe / ref - 1
        # consistent-mass FE converges from above
        assert np.all(rel > -1e-8), rel
        assert np.all(rel < 1e-4), rel


def test_rectangular_section_planes_follow_docstring_convention():
    # beam along a skew direction, local x = global z
    start = np.array([0.1, -0.2, 0.3])
    axis = unit([1.0, 1.0, 0.0])
    L = 1.0
    ex = np.array([0.0, 0.0, 1.0])
    ey = np.cross(axis, ex)
    seg = make_segment(start, start + L * axis, ex)
    omega, shapes = modes([seg], clamp=start, n_modes=2)
    tip = shapes.sample(0, [1.0])[:, 0, :]
    # Iy < Ix: the lowest mode deflects along local x (w_x), the second along local y
    assert abs(omega[0] / cantilever_bending(E * IY, L)[0] - 1) < 1e-4
    assert abs(omega[1] / cantilever_bending(E * IX, L)[0] - 1) < 1e-4
    assert np.isclose(omega[1] / omega[0], np.sqrt(IX / IY), rtol=1e-8)
    assert abs(unit(tip[0]) @ ex) > 1 - 1e-10
    assert abs(unit(tip[1]) @ ey) > 1 - 1e-10
    # nodal rotations: w_x bends about local y, w_y bends about local x
    rot = shapes.at(start + L * axis)[:, 3:]
    assert abs(unit(rot[0]) @ ey) > 1 - 1e-10
    assert abs(unit(rot[1]) @ ex) > 1 - 1e-10


def test_cantilever_first_torsion_and_axial():
    L = 0.8
    seg = make_segment([0, 0, 0], [L, 0, 0], [0, 0, 1])
    omega, shapes = modes([seg], clamp=[0, 0, 0], n_modes=14)
    w_t = np.pi / (2 * L) * np.sqrt(G * J_T / (RHO * IP))
    w_a = np.pi / (2 * L) * np.sqrt(E / RHO)
    tip = shapes.at([L, 0, 0])
    i_t = int(np.argmax(np.abs(tip[:, 3]) / np.linalg.norm(tip, axis=1)))
    i_a = int(np.argmax(np.abs(tip[:, 0]) / np.linalg.norm(tip, axis=1)))
    assert 0 < omega[i_t] / w_t - 1 < 1e-4
    assert 0 < omega[i_a] / w_a - 1 < 1e-4
    # the identified modes are pure torsion / pure axial
    assert np.allclose(tip[i_t, [0, 1, 2, 4, 5]], 0, atol=1e-9 * np.abs(tip[i_t, 3]))
    assert np.allclose(tip[i_a, 1:], 0, atol=1e-9 * np.abs(tip[i_a, 0]))


@pytest.mark.parametrize("mass_ratio", [0.3, 1.0, 5.0])
def test_cantilever_with_tip_mass_vs_analytic(mass_ratio):
    L = 1.0
    m_tip = mass_ratio * RHO * AREA * L

    def f(beta):
        return (
            1
            + np.cos(beta) * np.cosh(beta)
            + mass_ratio * beta * (np.cos(beta) * np.sinh(beta) - np.sin(beta) * np.cosh(beta))
        )

    grid = np.linspace(0.1, 12.0, 2000)
    vals = f(grid)
    roots = [
        brentq(f, grid[i], grid[i + 1])
        for i in range(len(grid) - 1)
        if np.sign(vals[i]) != np.sign(vals[i + 1])
    ][:3]
    assert len(roots) == 3
    ref = np.array(roots) ** 2 * np.sqrt(E * IY / (RHO * AREA * L**4))
    seg = make_segment([0, 0, 0], [0, 0, L], [1, 0, 0])
    body = PointBody([0, 0, L], m_tip, np.zeros((3, 3)))
    omega, _ = modes([seg], bodies=[body], clamp=[0, 0, 0], n_modes=8)
    rel = match(omega, ref) / ref - 1
    assert np.all(rel > -1e-8), rel
    assert np.all(rel < 1e-4), rel


# ----------------------------------------------------------------------------- frames
def test_l_frame_in_plane_and_out_of_plane_modes_separate():
    a, b = 1.0, 0.7
    segs = [
        make_segment([0, 0, 0], [a, 0, 0], [0, 0, 1]),
        make_segment([a, 0, 0], [a, b, 0], [0, 0, 1]),
    ]
    omega, shapes = modes(segs, clamp=[0, 0, 0], n_modes=8)
    u = shapes.u  # (modes, nodes, 6)
    in_plane = np.concatenate([u[:, :, 0:2], u[:, :, 5:6]], axis=2).reshape(len(omega), -1)
    out_plane = u[:, :, 2:5].reshape(len(omega), -1)
    kinds = []
    for ip, op in zip(in_plane, out_plane, strict=True):
        n_ip, n_op = np.linalg.norm(ip), np.linalg.norm(op)
        assert min(n_ip, n_op) < 1e-8 * max(n_ip, n_op)
        kinds.append("in" if n_ip > n_op else "out")
    assert "in" in kinds and "out" in kinds
    # the in-plane modes keep the frame planar also between the nodes
    for k, kind in enumerate(kinds):
        if kind == "in":
            for s in range(2):
                pts = shapes.sample(s, np.linspace(0, 1, 17), what="both")[k]
                assert np.max(np.abs(pts[:, [2, 3, 4]])) < 1e-8 * np.max(np.abs(pts))


def spatial_frame(n_elements):
    p0 = np.zeros(3)
    p1 = np.array([0.0, 0.0, 0.6])
    p2 = np.array([0.5, 0.0, 0.9])
    p3 = np.array([0.6, 0.45, 0.7])
    return [
        make_segment(p0, p1, [1, 0, 0], n_elements),
        make_segment(p1, p2, [0, 1, 0], n_elements, Ix=0.6 * IX, J=0.7 * J_T),
        make_segment(p2, p3, [0, 0, 1], n_elements, A=0.8 * AREA, Iy=1.3 * IY),
    ]


def test_convergence_spatial_frame_40_vs_80_elements():
    body = PointBody(
        [0.6, 0.45, 0.7], 0.8, np.diag([1e-3, 2e-3, 1.5e-3]), com_offset=[0.02, -0.01, 0.03]
    )
    w40, s40 = modes(spatial_frame(40), bodies=[body], clamp=[0, 0, 0], n_modes=6)
    w80, s80 = modes(spatial_frame(80), bodies=[body], clamp=[0, 0, 0], n_modes=6)
    rel = np.abs(w40 / w80 - 1)
    assert np.all(rel < 1e-4), rel
    # nested meshes: Rayleigh-Ritz bound (up to the ~1e-8 round-off floor of the solver)
    assert np.all(w40 >= w80 * (1 - 1e-7))
    # mode shapes sampled at the same points agree (MAC ~ 1)
    s = np.linspace(0, 1, 21)
    a = np.concatenate([s40.sample(i, s) for i in range(3)], axis=1).reshape(6, -1)
    b = np.concatenate([s80.sample(i, s) for i in range(3)], axis=1).reshape(6, -1)
    mac = (a @ b.T) ** 2 / np.outer(np.sum(a * a, 1), np.sum(b * b, 1))
    assert np.all(np.diag(mac) > 1 - 1e-6), np.diag(mac)


def test_sample_interpolates_nodal_values():
    segs = spatial_frame(10)
    _, shapes = modes(segs, clamp=[0, 0, 0], n_modes=4)
    for i in range(3):
        s_nodes = np.linspace(0, 1, 11)
        both = shapes.sample(i, s_nodes, what="both")
        assert np.allclose(both, shapes.node_values(i), atol=1e-12 * np.abs(both).max())
        assert np.allclose(shapes.nodes(i)[[0, -1]], [segs[i].start, segs[i].end])
    # the shared node is the same in both segments
    assert np.allclose(shapes.sample(0, [1.0], "both"), shapes.sample(1, [0.0], "both"))


# ----------------------------------------------------------------------------- point bodies
def test_point_body_mass_matrix_is_rigid_body_kinetic_energy():
    rng = np.random.default_rng(0)
    m = 1.7
    c = np.array([0.1, -0.3, 0.2])
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    inertia = Q @ np.diag([0.1, 0.2, 0.35]) @ Q.T
    Mb = PointBody([0, 0, 0], m, inertia, com_offset=c).mass_matrix()
    assert np.allclose(Mb, Mb.T)
    for _ in range(5):
        u, th = rng.normal(size=3), rng.normal(size=3)
        v_com = u + np.cross(th, c)
        energy = m * v_com @ v_com + th @ inertia @ th
        assert np.isclose(np.r_[u, th] @ Mb @ np.r_[u, th], energy, rtol=1e-12)


def test_offset_body_equals_body_on_rigid_massless_link():
    L = 1.0
    c = np.array([0.05, 0.08, 0.15])
    inertia = np.diag([2e-3, 3e-3, 1e-3])
    m = 0.9
    beam = make_segment([0, 0, 0], [0, 0, L], [1, 0, 0])
    tip = np.array([0, 0, L])
    w_off, _ = modes(
        [beam], bodies=[PointBody(tip, m, inertia, com_offset=c)], clamp=[0, 0, 0], n_modes=6
    )
    # the same body placed at the end of a (nearly) rigid, (nearly) massless link
    link = make_segment(tip, tip + c, [1, 0, 0], n_elements=2, E=E * 1e6, G=G * 1e6, rho=RHO * 1e-9)
    w_link, _ = modes([beam, link], bodies=[PointBody(tip + c, m, inertia)], clamp=[0, 0, 0])
    assert np.allclose(w_off, w_link, rtol=1e-5), w_off / w_link - 1


# ----------------------------------------------------------------------------- joint springs
def test_joint_spring_stiff_reproduces_rigid_and_soft_lowers():
    segs = spatial_frame(30)
    joint = segs[1].end
    axis = unit([0.3, -0.2, 1.0])
    w_rigid, _ = modes(segs, clamp=[0, 0, 0], n_modes=6)
    k_ref = E * IX / 0.5
    w_stiff, _ = modes(segs, springs=[JointSpring(joint, axis, 1e8 * k_ref)], clamp=[0, 0, 0])
    assert np.allclose(w_stiff, w_rigid, rtol=1e-7), w_stiff / w_rigid - 1
    w_soft, _ = modes(segs, springs=[JointSpring(joint, axis, 0.05 * k_ref)], clamp=[0, 0, 0])
    assert np.all(w_soft <= w_rigid * (1 + 1e-10))
    assert w_soft[0] < 0.99 * w_rigid[0]
    # monotone in the stiffness
    w_mid, _ = modes(segs, springs=[JointSpring(joint, axis, 0.5 * k_ref)], clamp=[0, 0, 0])
    assert np.all(w_soft <= w_mid * (1 + 1e-10)) and np.all(w_mid <= w_rigid * (1 + 1e-10))


def test_soft_hinge_at_clamp_gives_rigid_pendulum_frequency():
    # cantilever hinged at the clamp with a weak spring about local x (deflection w_y):
    # omega^2 ~= k / (rho A L^3 / 3) for k << EI / L
    L = 0.9
    seg = make_segment([0, 0, 0], [0, 0, L], [1, 0, 0])
    k = 1e-4 * E * IX / L
    omega, shapes = modes(
        [seg], springs=[JointSpring([0, 0, 0], [1, 0, 0], k)], clamp=[0, 0, 0], n_modes=2
    )
    ref = np.sqrt(3 * k / (RHO * AREA * L**3))
    assert abs(omega[0] / ref - 1) < 1e-3
    tip = shapes.sample(0, [1.0])[0, 0]
    assert abs(unit(tip)[1]) > 1 - 1e-10
    # the ground-side node does not move, the beam-side node rotates about the axis
    assert np.allclose(shapes.at([0, 0, 0], side="inboard"), 0)
    root = shapes.at([0, 0, 0], side="outboard")[0]
    assert np.allclose(root[:3], 0) and np.allclose(root[4:], 0) and abs(root[3]) > 0


# ----------------------------------------------------------------------------- sections
try:
    from reference_fem import prandtl_torsion_constant, rectangle_torsion_constant
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests.reference_fem import prandtl_torsion_constant, rectangle_torsion_constant

#: Timoshenko & Goodier, Theory of Elasticity (3rd ed., 1970), §109 table: J = k1 · b t³
#: of a rectangle with sides b >= t, printed to three digits
TIMOSHENKO_K1 = {1.0: 0.141, 1.5: 0.196, 2.0: 0.229, 2.5: 0.249, 3.0: 0.263, 4.0: 0.281,
                 5.0: 0.291, 10.0: 0.312}


def test_rectangle_torsion_series_against_published_table():
    for ratio, k1 in TIMOSHENKO_K1.items():
        # the table's rounding: half a unit of the third digit
        assert abs(rectangle_torsion_constant(ratio, 1.0) / ratio - k1) <= 5e-4, ratio
        assert rectangle_torsion_constant(1.0, ratio) == rectangle_torsion_constant(ratio, 1.0)
    # thin strip: b t³ / 3 (1 − 0.630 t/b)
    assert rectangle_torsion_constant(50.0, 1.0) == pytest.approx(50 / 3 * (1 - 0.630 / 50),
                                                                  rel=1e-4)


@pytest.mark.parametrize("a, b", [(1.0, 1.0), (0.005, 0.007), (0.02, 0.01)])
def test_rectangle_torsion_series_against_prandtl_solution(a, b):
    # second-order finite differences on 40 and 80 cells across, Richardson-extrapolated:
    # the remaining h⁴ error is 1.0e-6 (square) .. 3e-7; 3e-6 allowed
    coarse, fine = (prandtl_torsion_constant(a, b, n) for n in (40, 80))
    assert (4 * fine - coarse) / 3 == pytest.approx(rectangle_torsion_constant(a, b), rel=3e-6,
                                                    abs=0)
