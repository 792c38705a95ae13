"""``method="poly"`` on the exact kinematics, truncated at degree 2 in δ
(casflex/simulate/exact_poly.py, issue 19).

References, each computed without the coefficient arrays under test: the exact model's own
rows and torques (``functions()["prescribed"]``), which the degree-2 form must match to
O(|δ|³); the degree-2 truncation of :func:`casflex.simulate.simulate_taylor`, which
differentiates the assembled rows along the ray through the state (a scalar), never
forming a coefficient; RK4 on the exact rows.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.simulate import exact_poly, simulate_prescribed, simulate_taylor
from casflex.simulate.chebyshev import evaluate

Q = np.array([0.1, 0.3, -0.8])  # in- and out-of-plane modes (test_exact_kinematics.py)
RNG = np.random.default_rng(1919)


@pytest.fixture(scope="module")
def exact(arm):
    """The exact kinematics on two modes frozen at ``Q``, gravity on (its δ-terms too);
    its coefficient function is ~0.2 M instructions, ~10 s to build."""
    return FlexibleModel(arm, PointwiseProvider(arm, Q, count=2), kinematics="exact")


@pytest.mark.slow  # the 2-mode coefficient function's graph: ~10 s of CPU
def test_rows_and_torques_differ_from_the_exact_model_by_the_cube(exact):
    """The degree-2 stage and torque rows at one state differ from the exact model's by
    O(|δ|³): halving δ along a fixed direction (δ̇, q̇, q̈ fixed) divides the difference
    by 8, within x/÷ 1.3 (δ from 0.01 to 0.0025 √kg m, tip deflections of a few mm:
    from 0.02 to 0.01 the ratio is still ~10.7, the δ⁴ term a third of the δ³ one). The
    torques take the exact δ̈, so that they test the torque rows alone. At δ = 0 both
    agree to rounding."""
    n, m = exact.n, exact.m
    q, dq, ddq = Q, RNG.normal(0.0, 1.0, 3), RNG.normal(0.0, 3.0, 3)
    u, v = RNG.normal(0.0, 1.0, m), RNG.normal(0.0, 1.0, m)
    u /= np.linalg.norm(u)
    raw = evaluate(exact_poly.configuration_function(exact), q[None], dq[None])
    modal, torques = exact_poly.node_rows(raw, n, m, ddq[None])
    rhs, size = exact_poly.stage(m)
    assert modal.shape == (1, size)
    prescribed = exact.functions()["prescribed"]
    errors = {"dd": [], "tau": []}
    for s in (0.0, 0.01, 0.005, 0.0025):
        d = s * u
        tau, dd = (x.full().ravel() for x in prescribed(q, dq, ddq, d, v))
        dd_poly = rhs(modal[0], np.r_[d, v]).full().ravel()[m:]
        tau_poly = exact_poly.torque(torques, n, m, d[None], v[None], dd[None])[0]
        errors["dd"].append(np.linalg.norm(dd_poly - dd) / np.linalg.norm(dd))
        errors["tau"].append(np.linalg.norm(tau_poly - tau) / np.linalg.norm(tau))
    for key, e in errors.items():
        assert e[0] < 1e-12, (key, e)
        for big, small in zip(e[1:-1], e[2:], strict=True):
            assert 8 / 1.3 < big / small < 8 * 1.3, (key, e)


@pytest.mark.slow  # the degree-2 ray graph of simulate_taylor and the coefficients: ~25 s
def test_poly_runs_the_degree_two_truncation(exact):
    """poly on the exact model integrates the rows that :func:`simulate_taylor` (degree
    2) integrates, by another path (coefficients interpolated in time against derivatives
    along the ray at every stage): same RK4 steps, so the runs agree to the interpolation
    tolerance (1e-10 of each array's range), here within 1e-9 of the peak. Against RK4 on
    the exact rows they differ by the truncation: not zero, and within a few % of the
    peak on this hard turn of all joints with gravity (|δ| up to 0.27 √kg m)."""
    move = Move(Q, Q + np.array([-1.0, 0.5, 0.5]), 0.5, settle=0.2)
    poly = simulate_prescribed(exact, move, dt=1e-3, method="poly")
    taylor = simulate_taylor(exact, move, 2, dt=1e-3)
    rk4 = simulate_prescribed(exact, move, dt=1e-3)
    peak = np.abs(taylor["tip_deflection"]).max()
    assert np.abs(poly.tip_deflection - taylor["tip_deflection"]).max() < 1e-9 * peak
    assert np.abs(poly.delta - taylor["delta"]).max() < 1e-9 * np.abs(taylor["delta"]).max()
    gap = np.abs(poly.tip_deflection - rk4.tip_deflection).max() / peak
    assert 1e-3 < gap < 0.05, gap  # measured 1.3 % (|δ| up to 0.27 √kg m, gravity on)


def test_jit_and_the_truncated_configuration_refuse_the_exact_model(exact):
    """The exact model's coefficient function is too large to compile (jit), and the
    truncated kinematics' F(q) is not its form: ModelErrors that name the way out."""
    from casflex.simulate import poly

    move = Move(Q, Q + np.array([-0.1, 0.0, 0.0]), 0.2)
    with pytest.raises(ModelError, match="jit.*kinematics='exact'"):
        simulate_prescribed(exact, move, dt=0.01, method="poly", jit=True)
    with pytest.raises(ModelError, match="exact_poly.configuration_function"):
        poly.configuration_function(exact)
    with pytest.raises(ModelError, match="kinematics='exact'"):
        exact_poly.configuration_function(FlexibleModel(exact.robot, exact.provider))


def test_a_graph_over_the_budget_is_refused(arm, monkeypatch):
    """The directional derivatives build ~8× the rows' graph before their fold at δ = 0:
    over :data:`exact_poly.GRAPH_BUDGET` the build is refused up front, naming the
    projection and the way out (here a 1-mode model, rows ~0.1 M nodes, against a budget
    lowered to 1e5)."""
    model = FlexibleModel(arm, PointwiseProvider(arm, Q, count=1), kinematics="exact")
    monkeypatch.setattr(exact_poly, "GRAPH_BUDGET", 1e5)
    with pytest.raises(ModelError, match=r"1 modes.*times 8\.5\), over the budget of "
                                         r"1e\+05; use method='rk4'"):
        exact_poly.configuration_function(model)


def _nested_jacobians(model):
    """The coefficients as session 11 built them, written again here: nested CasADi
    Jacobians of the assembled rows in δ̇ and δ, one expanded graph, folded at
    δ = δ̇ = 0; returns the stacked (R × L) array of ``G``'s outputs at ``(Q, dq)``."""
    import casadi as ca

    m, N = model.m, model.n + model.m
    q, dq, d, v = model.q, model.dq, model.delta, model.ddelta
    iu = np.triu_indices(N)
    pairs = np.triu_indices(m)

    def taylor(E, x):
        J = ca.jacobian(E, x)
        H = [ca.jacobian(J[:, int(b)], x)[:, int(a)] * (0.5 if a == b else 1.0)
             for a, b in zip(*pairs, strict=True)]
        return J, H

    h = model.h
    hv, hvv = taylor(h, v)
    E = ca.vertcat(*[model.M[int(i), int(k)] for i, k in zip(*iu, strict=True)], h,
                   ca.vec(hv), *hvv)
    E = ca.substitute(E, v, ca.DM.zeros(m))
    Ed, Edd = taylor(E, d)
    C = ca.substitute(ca.horzcat(E, Ed, *Edd), d, ca.DM.zeros(m))
    return lambda x, dx: ca.Function("nested", [q, dq], [C])(x, dx).full()


@pytest.mark.slow  # two 2-mode coefficient graphs: ~45 s at load 8
def test_the_directional_coefficients_equal_nested_jacobians(exact):
    """The coefficients from directional derivatives mapped over the pairs of unit
    vectors equal those of nested Jacobians of the assembled rows (the session-11 path,
    rewritten in the test) to round-off: 1e-14 of each column's largest entry (measured
    3e-16 at 2 and 3 modes; the 3-mode figure in README_fidelity.md), the off-diagonal
    pairs included (two modes)."""
    dq = RNG.normal(0.0, 1.0, 3)
    new = np.vstack([x.full() for x in exact_poly.configuration_function(exact)(Q, dq)])
    ref = _nested_jacobians(exact)(Q, dq)
    assert new.shape == ref.shape == (15 + 5 + 10 + 15, 6)  # N = 5 rows; L = 1 + 2 + 3
    scale = np.abs(ref).max(axis=0)
    assert np.all(scale > 0)
    assert np.all(np.abs(new - ref).max(axis=0) <= 1e-14 * scale)


@pytest.mark.slow  # 3 and 5 frozen modes, the degree-2 ray graph: minutes at load 8
@pytest.mark.parametrize("modes", [3, 5])
def test_poly_equals_the_taylor_path_at_three_and_five_modes(arm, modes):
    """At the model's default count (5) and at 3 modes, poly on the exact model equals
    :func:`simulate_taylor` at degree 2 (independent: derivatives along the ray through
    the state at every stage) within 1e-9 of the peak, as at 2 modes."""
    model = FlexibleModel(arm, PointwiseProvider(arm, Q, count=modes), gravity=None,
                          kinematics="exact")
    move = Move(Q, Q + np.array([-1.0, 0.5, 0.5]), 0.4, settle=0.1)
    poly = simulate_prescribed(model, move, dt=2e-3, method="poly")
    taylor = simulate_taylor(model, move, 2, dt=2e-3)
    peak = np.abs(taylor["tip_deflection"]).max()
    assert peak > 1e-2
    assert np.abs(poly.tip_deflection - taylor["tip_deflection"]).max() < 1e-9 * peak
