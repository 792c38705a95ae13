"""FlexibleModel(shape_rates=True): the velocity terms of configuration-dependent shapes.

The option adds, to first order in δ, the ``∂w/∂q q̇ δ`` part of the velocity of every
point (issue 19). Checked here: it changes nothing where it must not (δ = 0, shapes that
do not depend on q), the structure of the equations survives (Ṁ − 2C skew, energy
conserved in free motion), and it does change M where the shapes move. Its physical
effect is checked against the ANCF reference in test_model_fidelity.py.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from casflex.model import ConstantProvider, FlexibleModel, PointwiseProvider

RNG = np.random.default_rng(19)


@pytest.fixture(scope="module")
def models(arm_model):
    plain, _ = arm_model(3, step_deg=15, gravity=None)
    rates, _ = arm_model(3, step_deg=15, gravity=None, shape_rates=True)
    return plain, rates


def _state(n, m):
    return (RNG.uniform(-np.pi, np.pi, n), RNG.normal(0, 1.0, n),
            RNG.normal(0, 0.01, m), RNG.normal(0, 0.1, m))


def test_no_change_at_zero_deflection(models):
    """The new terms are O(δ): the rigid limit and M_δδ = I are untouched (to round-off)."""
    plain, rates = (m.functions()["mass"] for m in models)
    for _ in range(4):
        q = RNG.uniform(-np.pi, np.pi, 3)
        np.testing.assert_allclose(rates(q, np.zeros(3)).full(),
                                   plain(q, np.zeros(3)).full(), rtol=0, atol=1e-12)


def test_changes_mass_where_shapes_move(models):
    """With δ ≠ 0 the shape-joint column of M changes (the ∂w/∂q3 terms), the others not:
    only the elbow q3 moves the mode shapes of the Table 8 arm."""
    plain, rates = (m.functions()["mass"] for m in models)
    q, d = np.array([0.3, -0.4, 0.9]), np.array([0.02, -0.01, 0.015])
    diff = rates(q, d).full() - plain(q, d).full()
    assert np.abs(diff[:, 2]).max() > 1e-4 * np.abs(plain(q, d).full()).max()
    keep = [0, 1, 3, 4, 5]
    assert np.abs(diff[np.ix_(keep, keep)]).max() < 1e-12


def test_constant_shapes_unchanged(arm):
    """Shapes frozen at one configuration have no rate: the option is a no-op."""
    provider = PointwiseProvider(arm, [0.0, 0.0, 0.7], count=3)
    const = ConstantProvider(provider.quantities, (2,))
    a = FlexibleModel(arm, const, gravity=None, modal_mass="kinematic").functions()
    b = FlexibleModel(arm, const, gravity=None, modal_mass="kinematic",
                      shape_rates=True).functions()
    q, _, d, _ = _state(3, 3)
    np.testing.assert_allclose(b["mass"](q, d).full(), a["mass"](q, d).full(), atol=1e-14)


def test_mdot_minus_2c_is_skew(models):
    f = models[1].functions()
    for _ in range(4):
        q, dq, d, dd = _state(3, 3)
        C = f["coriolis"](q, d, dq, dd).full()
        h = 1e-6  # central difference of M along the velocity
        Mdot = (f["mass"](q + h * dq, d + h * dd).full()
                - f["mass"](q - h * dq, d - h * dd).full()) / (2 * h)
        S = Mdot - 2 * C
        assert np.abs(S + S.T).max() < 1e-7 * max(1.0, np.abs(Mdot).max())


@pytest.mark.slow
def test_free_motion_conserves_energy(arm, arm_model):
    """τ = 0, no damping, tabulated shapes following q3: T + V conserved over 5 s.

    Motor inertias of 0.01 kg m² keep M positive definite at the deflections reached (see
    test_model_equations.test_free_motion_conserves_energy). q3 stays within
    [−0.4, 0.6] rad, away from the table's periodic wrap at −π: the padded (not truly
    periodic) B-spline's slope jumps there, and with this option M holds the tables'
    slopes, so crossing the wrap changes T + V by ~1e-6 relative. The bound is the
    integrator's: the drift is 3.6e-8 at tolerance 1e-12 and falls with it.
    """
    from casflex.model import TableProvider

    _, table = arm_model(3, step_deg=15, gravity=None, shape_rates=True)
    links = list(arm.links)
    for row in arm.joint_rows:
        links[row] = dataclasses.replace(links[row], motor_inertia=0.01)
    robot = dataclasses.replace(arm, links=tuple(links))
    model = FlexibleModel(robot, TableProvider(table), gravity=None, damping_ratio=0.0,
                          shape_rates=True)
    f = model.functions()
    n, m = model.n, model.m
    x = ca.SX.sym("x", 2 * (n + m))
    integ = ca.integrator("F", "cvodes", {"x": x, "ode": f["ode"](x, ca.DM.zeros(n))},
                          0.0, 5.0, {"abstol": 1e-12, "reltol": 1e-12,
                                     "max_num_steps": 200000})
    x0 = np.r_[0.1, -0.3, 0.5, 0.004, -0.003, 0.002, 0.2, 0.3, 0.1, 0.05, 0.0, -0.05]

    def energy(xv):
        return float(f["energy"](xv[:n], xv[n + m:2 * n + m], xv[n:n + m],
                                 xv[2 * n + m:])[2])

    E0 = energy(x0)
    xf = integ(x0=x0)["xf"].full().ravel()
    assert abs(energy(xf) - E0) < 1e-6 * abs(E0)


def _kinetic_from_sampled_points(model, q, dq, d, dd):
    """Twice the kinetic energy, summed over the points of every link, each point moved by
    the tabulated shapes of the current configuration: ``Σ_p Tr(Ḟ_p J_p Ḟ_pᵀ)`` with
    ``F_p = T_b (L0(s_p) + Σ δ_j L_j(s_p))`` and the rate from CasADi's derivative of the
    *positions* — exact in δ, no mass matrix, no Christoffel symbols, no truncation."""
    from casflex.modal import rate_samples

    X, dX = ca.vertcat(model.q, model.delta), ca.vertcat(model.dq, model.ddelta)
    m = model.m
    su = ca.SX(model.provider.function("sample_u")(model.q_shape))
    st = ca.SX(model.provider.function("sample_theta")(model.q_shape))
    two_t = ca.SX(0)
    for body in model.bodies:
        T = body["T"]
        if body["beam"] is None:
            Td = ca.jtimes(T, X, dX)
            two_t += ca.trace(Td @ body["C0"] @ Td.T)
            continue
        s, J = rate_samples(model.robot.links[body["row"]])
        for p in range(s.size):
            L = ca.SX.eye(4)
            L[2, 3] = s[p]
            for j in range(m):
                k = ((body["beam"] * s.size + p) * m + j) * 3
                Lj = ca.SX.zeros(4, 4)
                Lj[:3, :3] = ca.skew(st[k:k + 3])
                Lj[:3, 3] = su[k:k + 3]
                L += model.delta[j] * Lj
            Fd = ca.jtimes(T @ L, X, dX)
            two_t += ca.trace(Fd @ ca.DM(J[p]) @ Fd.T)
    for k, row in enumerate(model.robot.joint_rows):
        two_t += model.robot.links[row].motor_inertia * model.dq[k] ** 2
    f = ca.Function("t_ref", [model.q, model.dq, model.delta, model.ddelta], [0.5 * two_t])
    return float(f(q, dq, d, dd))


def test_kinetic_energy_first_order_in_delta(models):
    """M with the shape rates is the kinetic energy of the sampled points to first order in
    δ: the model's T differs from the points' by O(δ²) (halving δ quarters the gap), the
    plain model's by O(δ) (halving δ halves it) — every first-order term, the one inside
    each link (δ_k ∫ Tr(L_j J ∂L_kᵀ/∂q3)) included, is in M. q3 on a grid point (45°) so
    that the sampled shapes are mass-normalised as the TMM's (M_δδ(q, 0) = I)."""
    plain, rates = models
    q, dq = np.array([0.3, -0.4, np.radians(45.0)]), np.array([0.5, -0.8, 1.5])
    d0, dd = np.array([0.02, -0.015, 0.01]), np.array([0.3, -0.2, 0.25])
    for model, slope in ((rates, 4.0), (plain, 2.0)):
        energy = model.functions()["energy"]
        gaps = []
        for eps in (1.0, 0.5, 0.25):
            d = eps * d0
            ref = _kinetic_from_sampled_points(model, q, dq, d, dd)
            gaps.append(float(energy(q, dq, d, dd)[0]) - ref)
        # the gap at δ = 0 is round-off (tables exact on grid points, 16-point quadrature
        # reproduces the 48-point C2 to 1e-14); the ratios test the order in δ
        assert abs(gaps[0] / gaps[1] - slope) < 0.2 * slope, (gaps, slope)
        assert abs(gaps[1] / gaps[2] - slope) < 0.2 * slope, (gaps, slope)
