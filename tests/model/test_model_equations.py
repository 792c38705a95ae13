"""Symbolic rigid–flexible dynamics (casflex.model.equations).

Every symbolic quantity is evaluated and compared with an independent numeric
computation that does not share its code path (pinocchio-style):

* M_qq against a Jacobian-based rigid-body mass matrix Σ(m JvᵀJv + JωᵀIJω) written here
  from the numpy DH frames of casflex.robot, uniform slender beams (torsional inertia ρI_p
  about the axis, no rotary inertia of bending, as in the TMM) and tip bodies;
* Ṁ from finite differences of the mass Function against the Christoffel C;
* energy conservation in free motion integrated with CVODES;
* the model's own kinetic energy of the modes and its tip kinematics against the TMM
  (absolute mode shapes, frequencies);
* g_δ against an integral of the sampled absolute shapes.
"""

from __future__ import annotations

import copy
import dataclasses
import tomllib

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import simpson

from casflex.errors import ModelError
from casflex.model import ConstantProvider, FlexibleModel, PointwiseProvider, rigid_provider
from casflex.robot import TipBody, load, loads

try:
    import reference_fem as fem
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests import reference_fem as fem

ARM = load("problems/arm2link.toml")
TESTBED = load("problems/testbed.toml")

ODD_TEXT = """
name = "odd"
gravity = [0.3, -1.0, -9.81]
[[link]]
joint = "revolute"
motor_inertia = 0.01
d = 0.2
[link.tip]
mass = 0.7
inertia = [0.01, 0.02, 0.03]
com_offset = [0.05, -0.02, 0.1]
[[link]]
joint = "revolute"
alpha = { value = 90, unit = "deg" }
theta = 0.3
a = 0.8
section_angle = 0.4
motor_inertia = 0.002
[link.section]
shape = "rectangle"
a = 0.01
b = 0.02
[link.material]
E = 69e9
G = 26.9e9
rho = 2700.0
[link.tip]
mass = 0.3
inertia = [0.001, 0.002, 0.0015]
com_offset = [0.01, 0.02, 0.03]
[[link]]
joint = "revolute"
alpha = { value = -60, unit = "deg" }
a = 0.1
d = 0.05
[link.tip]
mass = 0.2
inertia = [0.0005, 0.0004, 0.0003]
com_offset = [0.0, 0.03, 0.0]
[[link]]
joint = "fixed"
alpha = { value = 90, unit = "deg" }
d = 0.6
section_angle = -0.2
[link.section]
shape = "tube"
outer_diameter = 0.02
wall = 0.002
[link.material]
E = 200e9
G = 80e9
rho = 7800.0
[link.tip]
mass = 0.1
inertia = [1e-4, 2e-4, 3e-4]
com_offset = [0.01, 0.0, 0.02]
"""
ODD = loads(ODD_TEXT)


with open("problems/arm2link.toml", "rb") as _fh:
    ARM_DATA = tomllib.load(_fh)
with open("problems/testbed.toml", "rb") as _fh:
    TESTBED_DATA = tomllib.load(_fh)
#: the problem-file numbers of each robot, for the references written in this module
DATA = {"arm2link": ARM_DATA, "testbed": TESTBED_DATA, "odd": tomllib.loads(ODD_TEXT)}


# ------------------------------------------------------------------ independent references


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rigid_pieces(data, q):
    """(mass, com, I_global, row, outboard_of_row_joint) of every rigid piece at q.

    From the problem file's numbers alone: the DH frames of reference_fem.dh_frames, ρA
    and ρI_p from reference_fem.section_constants, the beam and body frames of the
    documented conventions (problems/README.md) built here.
    """
    rows = data["link"]
    T = fem.dh_frames(rows, q)
    pieces = []
    for i, row in enumerate(rows):
        Ti = T[i]
        Tp = T[i - 1] if i else np.eye(4)
        Rp = Tp[:3, :3] @ _rx(fem.angle_value(row.get("alpha", 0.0)))
        turn = _rz(fem.angle_value(row.get("section_angle", 0.0)))
        a, d = float(row.get("a", 0.0)), float(row.get("d", 0.0))
        if "section" in row:
            sec = fem.section_constants(row["section"])
            rho = float(row["material"]["rho"])
            rA, rIp = rho * sec["A"], rho * sec["Ip"]
            if a != 0.0:
                L, start, axis = abs(a), Tp[:3, 3], Rp[:, 0]
                Rl = np.column_stack([Rp[:, 1], Rp[:, 2], Rp[:, 0]]) @ turn
                outboard = False
            else:
                L, axis = abs(d), Ti[:3, 2]
                start = Ti[:3, 3] - L * axis
                Rl = Ti[:3, :3] @ turn
                outboard = True
            assert np.allclose(Rl[:, 2], axis)
            # slender beam: ρA L³/12 about the transverse axes, ρI_p L about its own
            I_loc = np.diag([rA * L**3 / 12, rA * L**3 / 12, rIp * L])
            pieces.append((rA * L, start + 0.5 * L * axis, Rl @ I_loc @ Rl.T, i, outboard))
            end, Rt = start + L * axis, Rl
        else:
            end, Rt, outboard = Ti[:3, 3], Ti[:3, :3], True
        tip = row.get("tip", {})
        mass = float(tip.get("mass", 0.0))
        inertia = np.asarray(tip.get("inertia", (0.0, 0.0, 0.0)), dtype=float)
        if mass or inertia.any():
            com = np.asarray(tip.get("com_offset", (0.0, 0.0, 0.0)), dtype=float)
            pieces.append((mass, end + Rt @ com, Rt @ np.diag(inertia) @ Rt.T, i, outboard))
    return T, pieces


def _joint_rows(data):
    return [i for i, row in enumerate(data["link"]) if row.get("joint") == "revolute"]


def rigid_mass_matrix(data, q):
    """Σ (m JvᵀJv + JωᵀIJω) + motor inertias, from the problem file's numbers."""
    T, pieces = _rigid_pieces(data, q)
    rows = _joint_rows(data)
    n = len(rows)
    M = np.zeros((n, n))
    for mass, com, I, row, outboard in pieces:
        Jv, Jw = np.zeros((3, n)), np.zeros((3, n))
        for k, r in enumerate(rows):
            if r < row or (r == row and outboard):
                z, o = T[r][:3, 2], T[r][:3, 3]
                Jv[:, k] = np.cross(z, com - o)
                Jw[:, k] = z
        M += mass * Jv.T @ Jv + Jw.T @ I @ Jw
    M += np.diag([float(data["link"][r].get("motor_inertia", 0.0)) for r in rows])
    return M


def rigid_gravity(data, q, g):
    """g_q = −Σ m Jvᵀ g (eq. 107 at δ = 0)."""
    T, pieces = _rigid_pieces(data, q)
    rows = _joint_rows(data)
    out = np.zeros(len(rows))
    for mass, com, _, row, outboard in pieces:
        for k, r in enumerate(rows):
            if r < row or (r == row and outboard):
                out[k] -= mass * g @ np.cross(T[r][:3, 2], com - T[r][:3, 3])
    return out


def _model(robot, q, count, **kw):
    provider = PointwiseProvider(robot, q, count=count)
    return provider, FlexibleModel(robot, provider, **kw)


# ------------------------------------------------------------------ mass matrix


@pytest.mark.parametrize("robot", [ARM, TESTBED, ODD], ids=["arm", "testbed", "odd"])
def test_rigid_mass_matrix_matches_jacobian_reference(robot, rng):
    f = FlexibleModel(robot, rigid_provider(robot)).functions()
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, robot.n_joints)
        M = f["mass"](q, []).full()
        ref = rigid_mass_matrix(DATA[robot.name], q)
        assert np.abs(M - ref).max() <= 1e-9 * np.abs(ref).max()


@pytest.mark.parametrize("robot", [ARM, TESTBED, ODD], ids=["arm", "testbed", "odd"])
def test_flexible_mass_matrix_at_zero_deflection_is_rigid(robot, rng):
    q0 = rng.uniform(-1.0, 1.0, robot.n_joints)
    _, model = _model(robot, q0, 3)
    f = model.functions()
    for _ in range(3):
        q = rng.uniform(-np.pi, np.pi, robot.n_joints)
        M = f["mass"](q, np.zeros(3)).full()
        ref = rigid_mass_matrix(DATA[robot.name], q)
        n = robot.n_joints
        assert np.abs(M[:n, :n] - ref).max() <= 1e-9 * np.abs(ref).max()
        assert np.allclose(M[n:, n:], np.eye(3))


@pytest.mark.parametrize("robot", [ARM, TESTBED, ODD], ids=["arm", "testbed", "odd"])
def test_kinematic_modal_mass_is_identity_and_tip_follows_tmm(robot, rng):
    """The Book-style kinematics (link-local deflections, end transforms, springs)
    reproduce the TMM's absolute modes: the kinetic energy they give at δ = 0 is the
    identity, and the tip moves as the TMM's absolute tip displacement."""
    q = rng.uniform(-1.0, 1.0, robot.n_joints)
    provider, model = _model(robot, q, 4, modal_mass="kinematic")
    n = robot.n_joints
    M = model.functions()["mass"](q, np.zeros(4)).full()
    assert np.abs(M[n:, n:] - np.eye(4)).max() < 1e-9
    J = ca.Function("J", [model.q, model.delta],
                    [ca.jacobian(model.tip, model.delta)])(q, np.zeros(4)).full()
    shapes = provider.shapes
    tip_last = shapes.displacement_global[:, -1, -1]
    if robot.links[-1].flexible:
        assert np.abs(J.T - tip_last).max() < 1e-9 * np.abs(tip_last).max()


# ------------------------------------------------------------------ Coriolis


def _random_state(rng, n, m, scale_delta=0.01):
    return (rng.uniform(-np.pi, np.pi, n), rng.normal(0, 1.0, n),
            rng.normal(0, scale_delta, m), rng.normal(0, 0.1, m))


@pytest.mark.parametrize("modal_mass", ["first_order", "identity"])
@pytest.mark.parametrize("robot", [ARM, ODD], ids=["arm", "odd"])
def test_mdot_minus_2c_is_skew(robot, modal_mass, rng):
    _, model = _model(robot, np.zeros(robot.n_joints), 3, modal_mass=modal_mass)
    f = model.functions()
    n, m = robot.n_joints, 3
    for _ in range(4):
        q, dq, d, dd = _random_state(rng, n, m)
        C = f["coriolis"](q, d, dq, dd).full()
        h = 1e-6  # central difference of M along the velocity
        Mp = f["mass"](q + h * dq, d + h * dd).full()
        Mm = f["mass"](q - h * dq, d - h * dd).full()
        Mdot = (Mp - Mm) / (2 * h)
        S = Mdot - 2 * C
        assert np.abs(S + S.T).max() < 1e-7 * max(1.0, np.abs(Mdot).max())
        if modal_mass == "identity":  # M_δδ ≡ I: C_δδ alone is skew
            Cdd = C[n:, n:]
            assert np.abs(Cdd + Cdd.T).max() < 1e-12
            assert np.abs(Mdot[n:, n:]).max() < 1e-9


# ------------------------------------------------------------------ energy


def _with_motors(robot, inertia=0.01):
    links = list(robot.links)
    for row in robot.joint_rows:
        links[row] = dataclasses.replace(links[row], motor_inertia=inertia)
    return dataclasses.replace(robot, links=tuple(links))


@pytest.mark.slow
@pytest.mark.parametrize("modal_mass, gravity", [
    ("first_order", None),               # eq. 114 at δ = 0, starts at the table's q3
    ("kinematic", [0.0, 0.0, -0.981]),   # frozen shapes, any q, with gravity
])
def test_free_motion_conserves_energy(modal_mass, gravity):
    """τ = 0, no damping: T + V is conserved over 10 s (CVODES, Adams, tol 1e-10).

    Motor inertias of 0.01 kg m² keep M well conditioned: with locked-joint modes the
    residual joint inertia M_qq − M_qδ M_qδᵀ of the bare Table 8 arm is ~3e-4 kg m², and
    its first-order δ terms make M indefinite once the arm deflects by a few cm (which
    1 g of free fall produces; 0.1 g is used here).
    """
    robot = _with_motors(ARM)
    provider = PointwiseProvider(robot, [0.0, 0.0, 0.7], count=4)
    model = FlexibleModel(robot, ConstantProvider(provider.quantities, (2,)),
                          gravity=gravity, damping_ratio=0.0, modal_mass=modal_mass)
    f = model.functions()
    n, m = model.n, model.m
    x = ca.SX.sym("x", 2 * (n + m))
    integ = ca.integrator("F", "cvodes", {"x": x, "ode": f["ode"](x, ca.DM.zeros(n))},
                          0.0, 10.0, {"abstol": 1e-10, "reltol": 1e-10,
                                      "max_num_steps": 100000,
                                      "linear_multistep_method": "adams",
                                      "nonlinear_solver_iteration": "functional"})
    rng = np.random.default_rng(1)
    q = rng.uniform(-np.pi, np.pi, n)
    dq = rng.normal(0.0, 0.3, n)
    if modal_mass == "first_order":
        q[2], dq[2] = 0.7, 0.0
    x0 = np.r_[q, rng.normal(0.0, 0.005, m), dq, rng.normal(0.0, 0.1, m)]

    def energy(xv):
        out = f["energy"](xv[:n], xv[n + m:2 * n + m], xv[n:n + m], xv[2 * n + m:])
        return float(out[0]), float(out[2])

    T0, E0 = energy(x0)
    xf = integ(x0=x0)["xf"].full().ravel()
    _, E1 = energy(xf)
    assert abs(E1 - E0) < 1e-6 * max(abs(E0), T0)
    assert np.abs(xf[n:n + m]).max() < 0.05  # stayed a small-deflection motion


# ------------------------------------------------------------------ linearisation


@pytest.mark.parametrize("robot", [ARM, TESTBED], ids=["arm", "testbed"])
def test_locked_linearization_oscillates_at_tmm_frequencies(robot, rng):
    """With ``modal_mass="kinematic"`` the modal block of M comes from the kinematics
    (not set to I), so the locked frequencies √(ω²/M_δδ) test that kinetic energy; K =
    diag(ω²) itself is set by the model (the damped test below checks D against ζ)."""
    q = rng.uniform(-1.0, 1.0, robot.n_joints)
    provider, model = _model(robot, q, 4, gravity=None, modal_mass="kinematic")
    n, m = model.n, model.m
    # q locked: the prescribed-motion form with q̇ = q̈ = 0
    dddelta = ca.substitute(model.prescribed_dddelta,
                            ca.vertcat(model.dq, model.ddq), ca.DM.zeros(2 * n))
    z = ca.vertcat(model.delta, model.ddelta)
    A = ca.Function("A", [model.q, z], [ca.jacobian(ca.vertcat(model.ddelta, dddelta), z)])
    eig = np.linalg.eigvals(A(q, np.zeros(2 * m)).full())
    w = np.sort(np.abs(eig.imag))[::2]
    assert np.allclose(w, provider.shapes.omega, rtol=1e-8)
    assert np.abs(eig.real).max() < 1e-8 * w.max()


@pytest.mark.parametrize("robot", [ARM, TESTBED], ids=["arm", "testbed"])
def test_locked_linearization_decays_at_the_damping_ratio(robot, rng):
    # modal damping ratio ζ: each locked mode is ẍ + 2ζωẋ + ω²x = 0, eigenvalues
    # −ζω ± iω√(1 − ζ²) (the definition of ζ, with ω from the TMM); to 1e-8 as above
    zeta = 0.03
    q = rng.uniform(-1.0, 1.0, robot.n_joints)
    provider, model = _model(robot, q, 4, gravity=None, modal_mass="kinematic",
                             damping_ratio=zeta)
    n, m = model.n, model.m
    dddelta = ca.substitute(model.prescribed_dddelta,
                            ca.vertcat(model.dq, model.ddq), ca.DM.zeros(2 * n))
    z = ca.vertcat(model.delta, model.ddelta)
    A = ca.Function("A", [model.q, z], [ca.jacobian(ca.vertcat(model.ddelta, dddelta), z)])
    eig = np.linalg.eigvals(A(q, np.zeros(2 * m)).full())
    eig = eig[eig.imag > 0]
    eig = eig[np.argsort(eig.imag)]
    w = provider.shapes.omega
    np.testing.assert_allclose(eig.real, -zeta * w, rtol=1e-8)
    np.testing.assert_allclose(eig.imag, w * np.sqrt(1 - zeta**2), rtol=1e-8)


@pytest.mark.parametrize("robot", [ARM, ODD], ids=["arm", "odd"])
def test_forward_dynamics_is_m_c_g_d(robot, rng):
    """The ``forward`` and ``ode`` Functions solve M Ẍ + C Ẋ + G + [0; D δ̇] = [τ; 0] with
    the separately built M, C (checked by the skew property above), G and D."""
    _, model = _model(robot, np.zeros(robot.n_joints), 3, damping_ratio=0.02)
    f = model.functions()
    n, m = robot.n_joints, 3
    for _ in range(3):
        q, dq, d, dd = _random_state(rng, n, m)
        tau = rng.normal(0, 1.0, n)
        ddq, dddelta = (v.full().ravel() for v in f["forward"](q, dq, d, dd, tau))
        M = f["mass"](q, d).full()
        C = f["coriolis"](q, d, dq, dd).full()
        G = f["potential_forces"](q, d).full().ravel()
        D = f["damping"](q).full()
        lhs = M @ np.r_[ddq, dddelta] + C @ np.r_[dq, dd] + G + np.r_[np.zeros(n), D @ dd]
        scale = np.abs(M @ np.r_[ddq, dddelta]).max() + np.abs(tau).max()
        assert np.abs(lhs - np.r_[tau, np.zeros(m)]).max() < 1e-9 * scale
        xdot = f["ode"](np.r_[q, d, dq, dd], tau).full().ravel()
        np.testing.assert_allclose(xdot, np.r_[dq, dd, ddq, dddelta], rtol=1e-12, atol=1e-12)


def test_prescribed_motion_inverts_forward_dynamics(rng):
    _, model = _model(ODD, np.zeros(3), 3, damping_ratio=0.02)
    f = model.functions()
    q, dq, d, dd = _random_state(rng, 3, 3)
    ddq = rng.normal(0, 1.0, 3)
    tau, dddelta = f["prescribed"](q, dq, ddq, d, dd)
    ddq2, dddelta2 = f["forward"](q, dq, d, dd, tau)
    assert np.allclose(ddq2.full().ravel(), ddq, atol=1e-9)
    assert np.allclose(dddelta2.full(), dddelta.full(), atol=1e-9)


# ------------------------------------------------------------------ gravity


@pytest.mark.parametrize("robot", [ARM, TESTBED, ODD], ids=["arm", "testbed", "odd"])
def test_gravity_matches_independent_integrals(robot, rng):
    q = rng.uniform(-1.0, 1.0, robot.n_joints)
    provider = PointwiseProvider(robot, q, count=3)
    model = FlexibleModel(robot, provider)
    g = np.asarray(robot.gravity)
    G = model.functions()["gravity"](q, np.zeros(3)).full().ravel()
    n = robot.n_joints
    assert np.allclose(G[:n], rigid_gravity(DATA[robot.name], q, g), atol=1e-9)
    # g_δj = −Σ ∫ g·φ_j dm with the absolute (TMM) shapes, eq. 108
    sh = provider.shapes
    ref = np.zeros(3)
    for b, row in enumerate(sh.rows):
        link = robot.links[row]
        u = sh.displacement_global[:, b]  # (m, points, 3)
        ref -= link.mass_per_length * simpson(u @ g, x=sh.s[b], axis=-1)
    for i, row in enumerate(sh.body_rows):
        tip = robot.links[row].tip
        u, th = sh.body_state[:, i, :3], sh.body_state[:, i, 3:]
        R = _body_rotation(robot, q, row)
        c = R @ np.array(tip.com_offset)
        ref -= tip.mass * (u + np.cross(th, c)) @ g
    assert np.allclose(G[n:], ref, atol=1e-6 * np.abs(ref).max())


def _body_rotation(robot, q, row):
    from casflex.tmm import build_chain

    for e in build_chain(robot, q).elements:
        if e.kind == "body" and e.row == row:
            return e.R
    raise AssertionError(row)


# ------------------------------------------------------------------ providers


def test_bspline_provider_interface():
    """An interpolant provider (the modal tables' form) builds and agrees at a node."""
    grid = np.linspace(0.4, 1.0, 4)
    data = [PointwiseProvider(ARM, [0.0, 0.0, x], count=2).quantities for x in grid]

    class Spline:
        shape_joints = (2,)

        def function(self, name):
            values = np.stack([d[name].ravel() for d in data], axis=1)  # (size, grid)
            if values.shape[0] == 0:
                x = ca.SX.sym("q_shape", 1)
                return ca.Function(name, [x], [ca.DM.zeros(0, 1)])
            return ca.interpolant(name, "bspline", [grid], values.T.ravel())

    model = FlexibleModel(ARM, Spline(), gravity=None)
    ref = FlexibleModel(ARM, ConstantProvider(data[1], (2,)), gravity=None)
    q = [0.3, 0.2, grid[1]]
    M = model.functions()["mass"](q, [0.01, -0.02]).full()
    Mr = ref.functions()["mass"](q, [0.01, -0.02]).full()
    assert np.allclose(M, Mr, atol=1e-9)
    # the Coriolis matrix includes ∂M/∂q3 through the spline: the Christoffel sum
    # C_ij = ½ Σ_k (∂M_ij/∂X_k + ∂M_ik/∂X_j − ∂M_jk/∂X_i) Ẋ_k with ∂M/∂X from central
    # differences of the mass Function (h = 1e-6: truncation ~1e-12, round-off ~1e-10)
    f = model.functions()
    d, dq, dd = np.array([0.01, -0.02]), np.array([0.1, 0.2, 0.3]), np.array([0.1, 0.1])
    X, dX = np.r_[q, d], np.r_[dq, dd]
    h, N = 1e-6, X.size
    dM = np.zeros((N, N, N))  # dM[k] = ∂M/∂X_k
    for k in range(N):
        e = np.zeros(N)
        e[k] = h
        dM[k] = (f["mass"]((X + e)[:3], (X + e)[3:]).full()
                 - f["mass"]((X - e)[:3], (X - e)[3:]).full()) / (2 * h)
    ref = 0.5 * (np.einsum("kij,k->ij", dM, dX) + np.einsum("jik,k->ij", dM, dX)
                 - np.einsum("ijk,k->ij", dM, dX))
    C = f["coriolis"](q, d, dq, dd).full()
    assert np.abs(dM[2]).max() > 1e-3 * np.abs(dM).max()  # M does depend on q3 here
    assert np.abs(C - ref).max() < 1e-7 * np.abs(ref).max()


def test_errors():
    with pytest.raises(ModelError):
        FlexibleModel(ARM, rigid_provider(ARM), gravity=[0.0, 9.81])
    with pytest.raises(ModelError):
        FlexibleModel(ARM, ConstantProvider({"omega": [1.0]}, ()))
    bad = rigid_provider(ARM)
    bad.shape_joints = (5,)
    with pytest.raises(ModelError):
        FlexibleModel(ARM, bad)


def test_tip_bodies_and_motor_inertia_enter_mass_matrix():
    links = list(ARM.links)
    links[3] = dataclasses.replace(links[3], tip=TipBody(0.2, (1e-3, 2e-3, 3e-3)))
    links[0] = dataclasses.replace(links[0], motor_inertia=0.05)
    robot = dataclasses.replace(ARM, links=tuple(links))
    data = copy.deepcopy(ARM_DATA)
    data["link"][3]["tip"] = {"mass": 0.2, "inertia": [1e-3, 2e-3, 3e-3]}
    data["link"][0]["motor_inertia"] = 0.05
    M = FlexibleModel(robot, rigid_provider(robot)).functions()["mass"]([0, 0, 0], []).full()
    assert np.allclose(M, rigid_mass_matrix(data, np.zeros(3)), atol=1e-12)
