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
