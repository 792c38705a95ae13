"""FlexibleModel(kinematics="exact"): the flexible links rebuilt from the modal strains.

The option (casflex/model/strain_kinematics.py, issue 19) keeps the modes, δ and K of the
default model and rebuilds each link exactly from the modes' curvature, twist and axial
strain. Checked here: the rod integrator against the analytic circular arc and helix;
first-order agreement with the default model (M at δ = 0, the tip Jacobian, M's
first-order part in M_qq); the rigid limit; the structure of the equations (the bias
forces equal the Christoffel form C Ẋ, Ṁ − 2C skew, T + V conserved in free motion with
tabulated shapes); the option's validation. Its fidelity against the independent 3-D
and planar references is in test_spatial_static.py, test_spatial_fidelity.py and
test_model_fidelity.py.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal.integrals import RATE_SAMPLES, rate_samples
from casflex.model import FlexibleModel, PointwiseProvider, rigid_provider
from casflex.model.strain_kinematics import node_interpolation, rod_nodes

RNG = np.random.default_rng(1919)
Q = np.array([0.1, 0.3, -0.8])  # a configuration with in- and out-of-plane modes


@pytest.fixture(scope="module")
def pointwise(arm):
    """Both kinematics on the same five modes frozen at ``Q``."""
    provider = PointwiseProvider(arm, Q, count=5)
    return (FlexibleModel(arm, provider, gravity=None),
            FlexibleModel(arm, provider, gravity=None, kinematics="exact"))


# ------------------------------------------------------------------ the rod alone


def _rod_end(link, theta, u, points=None):
    """End transform of the rod whose one mode has the link-local rotation ``theta(s)``
    and deflection ``u(s)`` (callables of the arc length, (3,) each), at δ = 1."""
    s = rate_samples(link)[0]
    values_u = np.stack([u(x) for x in s])[:, None, :]  # (S, m = 1, 3)
    values_t = np.stack([theta(x) for x in s])[:, None, :]
    d = ca.SX.sym("d", 1)
    rod = rod_nodes(link, 0, ca.SX(values_u.ravel()), ca.SX(values_t.ravel()), d, points)
    return np.array(ca.evalf(ca.substitute(rod["end"], d, ca.DM(1.0))))


def _error_bounds(link, turn_rate, points=None):
    """The leading error terms of the rod's integrator for a constant turn rate ``|κ|``
    [rad/m]: the midpoint rule on ``∫ R(s) e_z ds`` (``Σ h³ |κ|² / 24`` [m]) and the
    Cayley half-turns' angle (``2·2 atan(x/4) = x − x³/48``: ``Σ (|κ| h)³ / 48`` [rad])."""
    from casflex.model.strain_kinematics import ROD_POINTS

    h = np.diff(node_interpolation(link, points or ROD_POINTS)[0])
    return (h**3).sum() * turn_rate**2 / 24.0, ((turn_rate * h) ** 3).sum() / 48.0


@pytest.mark.parametrize("bend", [0.15, 1.5])
def test_rod_of_constant_curvature_is_a_circular_arc(arm, bend):
    """A mode with constant curvature κ about x (``ϑ = κ s e_x``, ``w = −½ κ s² e_y``,
    the first-order arc) becomes the exact arc: end at ``(0, −(1 − cos κL)/κ,
    sin(κL)/κ)``, turned by κL about x. Error budget: the integrator's two leading terms
    (:func:`_error_bounds`, 2 % for the next order, (κh)² ≤ 2e-2); measured exactly at
    them: 5.6e-6 m at 0.15 rad (move 3's rotations), 5.6e-4 m at 1.5 rad, and 9× less
    with 48 points (O(h²))."""
    link = arm.links[2]
    k = bend / link.length
    ends = {}
    for points in (None, 48):
        E = _rod_end(link, lambda s: np.array([k * s, 0.0, 0.0]),
                     lambda s: np.array([0.0, -0.5 * k * s**2, 0.0]), points)
        exact = np.array([0.0, -(1.0 - np.cos(bend)) / k, np.sin(bend) / k])
        c, s = np.cos(bend), np.sin(bend)
        position, angle = _error_bounds(link, k, points)
        assert np.abs(E[:3, 3] - exact).max() < 1.02 * position
        assert np.abs(E[:3, :3] - [[1, 0, 0], [0, c, -s], [0, s, c]]).max() < 1.02 * angle
        ends[points] = np.abs(E[:3, 3] - exact).max()
    assert ends[48] < ends[None] / 8.0


def test_rod_of_constant_curvature_and_twist_is_a_helix(arm):
    """Constant material curvature (κ, 0, τ) makes a helix about the fixed axis
    ``ω = (κ, 0, τ)``: the end frame is ``exp([ω]× L)`` and the end point
    ``∫₀ᴸ exp([ω]× s) e_z ds`` (closed form by Rodrigues). Same budget as the arc."""
    link = arm.links[2]
    L = link.length
    w = np.array([0.8, 0.0, 0.6]) / L  # 1 rad of total turn
    E = _rod_end(link, lambda s: w * s, lambda s: np.cross(w * s, [0.0, 0.0, 1.0]) * s / 2)
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    a = np.linalg.norm(w)
    n = W / a
    rot = np.eye(3) + np.sin(a * L) * n + (1 - np.cos(a * L)) * n @ n
    integral = L * np.eye(3) + (1 - np.cos(a * L)) / a * n + (L - np.sin(a * L) / a) * n @ n
    position, angle = _error_bounds(link, a)
    assert np.abs(E[:3, :3] - rot).max() < 1.02 * angle
    assert np.abs(E[:3, 3] - integral @ [0.0, 0.0, 1.0]).max() < 1.02 * position


@pytest.mark.slow
def test_node_interpolation_gives_the_tmm_shapes(arm):
    """The polynomial through the 17 tabulated samples (and the base) gives the modes'
    link-local w and ϑ anywhere: compared at 24 Gauss points with the TMM's own local
    state (:func:`casflex.modal.normalize.local_state`), 8 modes. Measured 1e-13 of
    each shape's peak; the bound 1e-9 leaves room for a worse-conditioned arm."""
    from casflex.modal.integrals import configuration_quantities
    from casflex.modal.normalize import local_state, mass_normalize
    from casflex.tmm import modes

    shapes = mass_normalize(arm, modes(arm, Q, count=8))
    values = configuration_quantities(arm, Q, shapes)
    for b, row in enumerate(shapes.rows):
        s, _, P = node_interpolation(arm.links[row], 24)
        z = local_state(arm, shapes, b, s)
        w = z[..., 0:3] - z[:, :1, 0:3] - np.cross(z[:, :1, 3:6], np.c_[0 * s, 0 * s, s][None])
        th = z[..., 3:6] - z[:, :1, 3:6]
        for name, ref in (("sample_u", w), ("sample_theta", th)):
            got = np.einsum("kp,pmc->mkc", P, values[name][b])
            peak = np.abs(ref).max(axis=(1, 2))[:, None, None]
            assert np.abs((got - ref) / peak).max() < 1e-9, name
    assert node_interpolation(arm.links[2])[2].shape == (RATE_SAMPLES + 2, RATE_SAMPLES + 1)


# ------------------------------------------------------------------ against the default


@pytest.mark.slow
def test_first_order_agrees_with_the_default_model(pointwise):
    """At δ = 0 the two kinematics are the same model: M (the 16 rod points against the
    tables' 48-point integrals: Gauss–Legendre exact for these shapes, measured 5e-14),
    the tip and its Jacobian in δ, and M_qq's first-order part (both exact to first
    order; the exact model's M_qδ and M_δδ differ at first order by its second-order
    kinematics, which is the point of the option)."""
    plain, exact = pointwise
    z = np.zeros(5)
    for q in (Q, np.array([-1.0, 0.7, Q[2]])):  # the shapes are those of q3 = Q[2]
        np.testing.assert_allclose(exact.functions()["mass"](q, z).full(),
                                   plain.functions()["mass"](q, z).full(), rtol=0,
                                   atol=1e-12)
    slopes = []
    for model in (plain, exact):
        tip = ca.substitute(model.tip, model.q, ca.DM(Q))
        Mqq = ca.substitute(model.M[:3, :3], model.q, ca.DM(Q))
        slopes.append(ca.Function("J", [model.delta], [ca.jacobian(tip, model.delta),
                                                        ca.jacobian(ca.vec(Mqq), model.delta)]))
    for a, b in zip(slopes[0](z), slopes[1](z), strict=True):
        a, b = a.full(), b.full()
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-11 * np.abs(a).max())


def test_rigid_limit(arm):
    """Without modes, the exact kinematics are the rigid arm: M and the gravity torques
    equal the default model's (the rods' 16-point quadrature of a uniform rod is exact)."""
    a = FlexibleModel(arm, rigid_provider(arm)).functions()
    b = FlexibleModel(arm, rigid_provider(arm), kinematics="exact").functions()
    for _ in range(3):
        q = RNG.uniform(-np.pi, np.pi, 3)
        e = np.zeros(0)
        np.testing.assert_allclose(b["mass"](q, e).full(), a["mass"](q, e).full(), atol=1e-12)
        np.testing.assert_allclose(b["gravity"](q, e).full(), a["gravity"](q, e).full(),
                                   atol=1e-11)


# ------------------------------------------------------------------ structure


@pytest.fixture(scope="module")
def tabulated(arm, arm_model):
    """3 modes on the 15° table, shapes following q3 (``shape_rates``), motor inertias of
    0.01 kg m² (as test_shape_rates.py), no damping and no gravity."""
    from casflex.model import TableProvider

    _, table = arm_model(3, step_deg=15, gravity=None)
    links = list(arm.links)
    for row in arm.joint_rows:
        links[row] = dataclasses.replace(links[row], motor_inertia=0.01)
    robot = dataclasses.replace(arm, links=tuple(links))
    return FlexibleModel(robot, TableProvider(table), gravity=None, damping_ratio=0.0,
                         shape_rates=True, kinematics="exact")


def _state(n, m):
    return (RNG.uniform(-0.4, 0.6, n), RNG.normal(0, 1.0, n), RNG.normal(0, 0.05, m),
            RNG.normal(0, 0.3, m))


@pytest.mark.slow
def test_bias_is_the_christoffel_form_and_mdot_minus_2c_is_skew(tabulated):
    """The bias forces the option computes from the points' accelerations equal the
    Christoffel form of its M (``d/dt(M Ẋ) − ∂T/∂X`` at ``Ẍ = 0``, the default model's
    construction, formed here symbolically); its Coriolis matrix gives the same ``C Ẋ``
    and ``Ṁ − 2C`` is skew (Ṁ by central differences, error ~h² ~1e-12)."""
    model = tabulated
    f = model.functions()
    n, m = model.n, model.m
    X, dX = model.X, model.dX
    christoffel = ca.jtimes(model.M @ dX, X, dX) - ca.gradient(model.kinetic, X)
    both = ca.Function("h", [model.q, model.delta, model.dq, model.ddelta],
                       [model.h - model.G, christoffel])
    for _ in range(3):
        q, dq, d, dd = _state(n, m)
        h, ref = (v.full().ravel() for v in both(q, d, dq, dd))
        scale = max(1.0, np.abs(ref).max())
        np.testing.assert_allclose(h, ref, rtol=0, atol=1e-10 * scale)
        C = f["coriolis"](q, d, dq, dd).full()
        np.testing.assert_allclose(C @ np.r_[dq, dd], ref, rtol=0, atol=1e-10 * scale)
        e = 1e-6
        Mdot = (f["mass"](q + e * dq, d + e * dd).full()
                - f["mass"](q - e * dq, d - e * dd).full()) / (2 * e)
        S = Mdot - 2 * C
        assert np.abs(S + S.T).max() < 1e-7 * max(1.0, np.abs(Mdot).max())


@pytest.mark.slow
def test_free_motion_conserves_energy(tabulated):
    """τ = 0, no damping, tabulated shapes following q3: T + V conserved over 0.3 s (about
    a period of the first mode) with deflections of ~0.1 rad at the links' ends, far into
    the nonlinear range. RK4 at 2 and 1 ms: the drift is the integrator's, so it must be
    small (< 1e-6 of E) and fall with the step as O(h⁴) (ratio ≥ 8 allowed for 16)."""
    from casflex.simulate.integrators import rk4_step

    f = tabulated.functions()
    n, m = tabulated.n, tabulated.m
    ode = f["ode"]
    x0 = np.r_[0.1, -0.3, 0.5, 0.04, -0.03, 0.02, 0.2, 0.3, 0.1, 0.5, 0.0, -0.5]

    def energy(xv):
        return float(f["energy"](xv[:n], xv[n + m:2 * n + m], xv[n:n + m],
                                 xv[2 * n + m:])[2])

    E0, drift = energy(x0), {}
    for dt in (2e-3, 1e-3):
        x, peak = x0.copy(), 0.0
        for _ in range(int(round(0.3 / dt))):
            x = rk4_step(lambda v: ode(v, np.zeros(n)).full().ravel(), x, dt)
            peak = max(peak, np.abs(x[n:n + m]).max())
        drift[dt] = abs(energy(x) - E0) / abs(E0)
    assert peak > 0.01  # it did deflect
    assert drift[1e-3] < 1e-6, drift
    assert drift[2e-3] > 8.0 * drift[1e-3], drift


def _full_chain(model):
    """The exact model's mass matrix, bias forces and Coriolis matrix straight from the
    points (session 9's construction): every node's position and section axes, the tip
    body's pose rows and the rigid pieces' pose rows, in the base frame, stacked in
    ``y(X)`` with weights ``W`` and differentiated through the whole chain: ``M = Jᵀ W J``
    (plus the motor inertias), ``C Ẋ = Jᵀ W ∂²y[Ẋ, Ẋ]``, ``C = Jᵀ W J̇``. The rods are
    rebuilt here from the provider's shapes as functions of the shape joints, so the
    derivatives see the shapes follow them (the model's ``shape_rates=True``)."""
    from casflex.modal.integrals import pseudo_inertia

    shapes = {k: ca.SX(model.provider.function(k)(model.q_shape))
              for k in ("sample_u", "sample_theta")}
    rows, blocks = [], []
    for body in model.bodies:
        T = body["T"]
        if body.get("rod") is None:
            poses = [(T, np.asarray(body["C0"]))]
        else:
            link = model.robot.links[body["row"]]
            rod = rod_nodes(link, body["beam"], shapes["sample_u"], shapes["sample_theta"],
                            model.delta)
            R0, p0 = T[:3, :3], T[:3, 3]
            for k, w in enumerate(rod["weights"]):
                if w == 0.0:
                    continue
                R = R0 @ rod["R"][k]
                c = 0.5 * rod["rhoIp"] * w
                rows += [p0 + R0 @ rod["r"][k], R[:, 0], R[:, 1], R[:, 2]]
                blocks += [rod["rhoA"] * w, c, c, -c]
            poses = [] if link.tip.is_empty else [(T @ rod["end"], pseudo_inertia(
                link.tip.mass, link.tip.inertia, link.tip.com_offset))]
        for pose, Psi in poses:
            rows.append(ca.vec(pose[:3, :].T))
            blocks.append(np.kron(np.eye(3), Psi))
    W = ca.diagcat(*[ca.DM(np.atleast_2d(b) * np.eye(3) if np.ndim(b) == 0 else b)
                     for b in blocks])
    y, X, dX = ca.vertcat(*rows), model.X, model.dX
    J = ca.jacobian(y, X)
    motors = np.zeros(model.n + model.m)
    motors[:model.n] = [model.robot.links[row].motor_inertia for row in model.robot.joint_rows]
    WJ = W @ J
    return ca.Function("full", [model.q, model.delta, model.dq, model.ddelta],
                       [J.T @ WJ + ca.diag(motors),
                        WJ.T @ ca.jtimes(ca.jtimes(y, X, dX), X, dX),
                        WJ.T @ ca.jtimes(J, X, dX)])


@pytest.mark.slow
@pytest.mark.parametrize("which", ["pointwise", "tabulated"])
def test_link_frame_assembly_equals_the_full_chain(which, request):
    """``point_mass_terms`` differentiates each link's points once in the link's frame
    and the chain only through the base poses; M, the bias forces and C must equal the
    straightforward Jacobian of every point through the whole chain (:func:`_full_chain`)
    at random states, to round-off: 1e-12 of each quantity's largest entry (the two
    differ only in the order of the sums and in |R v̇| = |v̇| for the orthogonal poses).
    Five modes frozen at one configuration (the tip body, no shape joint), and three
    modes on the table with the shapes following q3 (``shape_rates``)."""
    model = request.getfixturevalue(which)
    model = model[1] if which == "pointwise" else model
    f = model.functions()
    n, m = model.n, model.m
    full = _full_chain(model)
    for _ in range(3):
        q, dq, d, dd = _state(n, m)
        d = 4.0 * d  # ~0.2 √kg m: well into the nonlinear range of the rods
        M, bias, C = (v.full() for v in full(q, d, dq, dd))
        got = {"M": f["mass"](q, d).full(), "C": f["coriolis"](q, d, dq, dd).full(),
               "bias": (f["coriolis"](q, d, dq, dd) @ np.r_[dq, dd]).full()}
        for name, ref in (("M", M), ("C", C), ("bias", bias)):
            np.testing.assert_allclose(got[name], ref, rtol=0,
                                       atol=1e-12 * np.abs(ref).max(), err_msg=name)
    h = ca.Function("h", [model.q, model.delta, model.dq, model.ddelta], [model.h - model.G])
    np.testing.assert_allclose(h(q, d, dq, dd).full(), bias, rtol=0,
                               atol=1e-12 * np.abs(bias).max())


# ------------------------------------------------------------------ validation


@pytest.mark.parametrize("options, words", [
    ({"kinematics": "nonlinear"}, "kinematics must be one of 'truncated', 'exact'"),
    ({"kinematics": "exact", "foreshortening": True}, "foreshortening"),
    ({"kinematics": "exact", "delta_order": 0}, "delta_order=0"),
    ({"kinematics": "exact", "modal_mass": "identity"}, "modal_mass='identity'"),
])
def test_invalid_options_are_refused(arm, options, words):
    provider = PointwiseProvider(arm, Q, count=1)
    with pytest.raises(ModelError, match=words):
        FlexibleModel(arm, provider, **options)


def test_default_and_modal_mass(arm):
    provider = PointwiseProvider(arm, Q, count=1)
    assert FlexibleModel(arm, provider).kinematics == "truncated"
    assert FlexibleModel(arm, provider).modal_mass == "first_order"
    assert FlexibleModel(arm, provider, kinematics="exact").modal_mass == "kinematic"


# ------------------------------------------------------------------ consumers


@pytest.mark.slow
def test_consumers_that_need_truncated_kinematics_refuse(arm):
    """Compiled ``poly`` simulation cannot take the exact model (its degree-2 coefficient
    function is too large to compile; uncompiled poly takes it: tests/simulate/
    test_exact_poly.py): a ModelError naming the option. The accelerometers take it
    (tests/sensors/test_sensor_exact_kinematics.py), and so does RK4."""
    from casflex.moves import Move
    from casflex.sensors import Accelerometer, SensorSet, kinematic_measurement
    from casflex.simulate import simulate_prescribed

    sensors = SensorSet([Accelerometer(3, 1.0, name="tip")])
    model = FlexibleModel(arm, PointwiseProvider(arm, Q, count=1, points=sensors.points),
                          gravity=None, kinematics="exact")
    move = Move(np.zeros(3), np.array([-0.1, 0.0, 0.0]), 0.2, settle=0.0)
    with pytest.raises(ModelError, match="kinematics='exact'"):
        simulate_prescribed(model, move, dt=0.01, method="poly", jit=True)
    assert kinematic_measurement(model, sensors).name_out() == ["y"]
    result = simulate_prescribed(model, move, dt=0.01, method="rk4")  # rk4 takes it
    assert np.isfinite(result.tip_deflection).all()
