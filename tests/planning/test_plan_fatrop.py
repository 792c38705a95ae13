"""The planner with Fatrop on the stage-ordered OCP (casflex.planning.staged) against Ipopt
on the same OCP, on the one-link flexible arm (problems/onelink.toml)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.planning import plan_move
from casflex.planning.staged import stage_order, stage_variables
from casflex.robot import load

TAU_MAX = 0.1   # N m
V_MAX = 1.0     # rad/s: below the 1.55 rad/s peak of the torque-limited move, so active
# Both solvers stop at an optimality error of 1e-8 in the scaled NLP (torques by TAU_MAX,
# T by its guess, states by their magnitudes). At this solution the active bounds are
# strictly complementary (bang-bang torques, the velocity limit on an arc), so the primal
# error is of the order of that tolerance times the conditioning of the reduced KKT
# matrix; 1e-6 relative (1e-7 N m on the torques) leaves a factor 100 for the latter
# (measured differences: 3.5e-8 relative in T, 3.3e-8 N m in the torques).
RTOL = 1e-6


@pytest.fixture(scope="module")
def flexible():
    robot = load("problems/onelink.toml")
    return FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)


@pytest.fixture(scope="module")
def plans(flexible):
    kw = {"torque_limit": TAU_MAX, "velocity_limit": V_MAX, "intervals": 20}
    return {s: plan_move(flexible, [0.0], [1.0], solver=s, **kw) for s in ("ipopt", "fatrop")}


def test_fatrop_plan_equals_ipopt_plan(plans):
    ip, fa = plans["ipopt"], plans["fatrop"]
    assert ip.stats["converged"] and fa.stats["converged"]
    assert fa.stats["solver"] == "fatrop" and fa.stats["status"] == "Solve_Succeeded"
    assert fa.duration == pytest.approx(ip.duration, rel=RTOL)
    np.testing.assert_allclose(fa.node_tau, ip.node_tau, rtol=0, atol=RTOL * TAU_MAX)
    # the states, each row against its magnitude
    scale = np.max(np.abs(ip.node_x), axis=0)
    np.testing.assert_allclose(fa.node_x / scale, ip.node_x / scale, rtol=0, atol=RTOL)


def test_fatrop_plan_is_rest_to_rest_within_the_limits(flexible, plans):
    p = plans["fatrop"]
    x0, xf = p.node_x[0], p.node_x[-1]
    # rest at both ends: joint at 0 / 1 rad, joint rate, mode and its rate zero (no gravity)
    np.testing.assert_allclose(x0, [0.0, 0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(xf, [1.0, 0.0, 0.0, 0.0], atol=1e-8)
    # the bound rows are posed in N m and rad/s, met to the solvers' tolerance 1e-8
    assert p.stats["constraint_violation"] <= 1e-8
    assert np.max(np.abs(p.node_tau)) <= TAU_MAX + 1e-8
    assert np.max(np.abs(p.node_x[:, 2])) <= V_MAX + 1e-8
    # both limits active: the torque at its bound on the first interval, the rate on an arc
    assert abs(p.node_tau[0, 0]) == pytest.approx(TAU_MAX, rel=1e-6)
    assert np.max(np.abs(p.node_x[:, 2])) == pytest.approx(V_MAX, rel=1e-6)
    # the rigid bound with the rate limit: accelerate to V_MAX at TAU_MAX / J, cruise,
    # decelerate: T >= THETA / V_MAX + V_MAX J / TAU_MAX with J the arm's inertia at rest
    J = float(flexible.functions()["mass"]([0.0], [0.0]).full()[0, 0])
    assert p.duration >= 1.0 / V_MAX + V_MAX * J / TAU_MAX * (1.0 - 1e-9)


def test_robust_plan_with_an_end_bound(flexible):
    # the augmented state (the modal rows at 1 ± r) and the end-bound rows in stage order
    kw = {"torque_limit": TAU_MAX, "intervals": 20, "end": 2e-3, "robust": 0.1,
          "progress_stop": False}
    ip, fa = (plan_move(flexible, [0.0], [1.0], solver=s, **kw) for s in ("ipopt", "fatrop"))
    assert fa.stats["converged"]
    assert fa.duration == pytest.approx(ip.duration, rel=RTOL)
    # the torques off their bounds (a singular arc, fixed only through the end-bound rows)
    # are the worst-conditioned part of the KKT system: 1e-5 of the limit (measured
    # 1.3e-6 of it on interval 10; 3e-7 at the bounds)
    np.testing.assert_allclose(fa.node_tau, ip.node_tau, rtol=0, atol=1e-5 * TAU_MAX)
    # every scenario's residual bound met to the solvers' tolerance on the rows [m]
    assert max(fa.stats["residual_bound"]) <= 2e-3 + 1e-8


def test_multipliers_pass_only_from_ipopt_to_ipopt(flexible, plans):
    # a Fatrop plan has the sizes of an Ipopt one in another variable order: no start for
    # Ipopt's iterate; Fatrop takes no multipliers (none of this CasADi's warm-start options)
    kw = {"torque_limit": TAU_MAX, "velocity_limit": V_MAX}
    for guess, solver in (("fatrop", "ipopt"), ("fatrop", "fatrop"), ("ipopt", "fatrop")):
        p = plan_move(flexible, [0.0], [1.0], guess=plans[guess], solver=solver, **kw)
        assert p.stats["warm_start"] and not p.stats["warm_start_duals"]
        assert p.duration == pytest.approx(plans["ipopt"].duration, rel=RTOL)
    p = plan_move(flexible, [0.0], [1.0], guess=plans["ipopt"], solver="ipopt", **kw)
    assert p.stats["warm_start_duals"]


@pytest.mark.parametrize("kw, field", [
    ({"solver": "snopt"}, "solver"),
    ({"solver": "fatrop", "transcription": "shooting"}, "solver"),
    ({"solver": "fatrop", "dynamics": "explicit"}, "solver"),
    ({"solver": "fatrop", "derivatives": "points"}, "derivatives"),
])
def test_bad_solver_is_named(flexible, kw, field):
    with pytest.raises(ModelError, match=field):
        plan_move(flexible, [0.0], [1.0], torque_limit=TAU_MAX, intervals=4, **kw)


def test_stage_order_sorts_rows_by_stage():
    # rows posed out of order come back per stage: the gap first, then the stage's rows
    opti = ca.Opti()
    (X,), (U,), stages = stage_variables(opti, 3, [np.ones(1)], [(np.ones(1), 1)])
    opti.subject_to(X[:, 3] == 2)                       # terminal
    opti.subject_to(opti.bounded(-1, U, 1))             # stages 0..2
    opti.subject_to(X[:, 1:] == X[:, :3] + U)           # gaps 0..2
    opti.subject_to(X[:, 0] == 0)                       # stage 0
    equality = stage_order(opti, stages)
    assert equality == [True, False, True, True, False, True, False, True]
    # at (x0, u0, x1, u1, x2, u2, x3) = (0, 1, ..., 6): gap 0, u0, x0, gap 1, u1, gap 2,
    # u2, terminal
    g = ca.Function("g", [opti.x], [opti.g])(np.arange(7.0)).full().ravel()
    np.testing.assert_array_equal(g, [1, 1, 0, -1, 3, -3, 5, 6])
    lbg = np.asarray(ca.evalf(opti.lbg)).ravel()
    np.testing.assert_array_equal(lbg, [0, -1, 0, 0, -1, 0, -1, 2])


def test_stage_order_refuses_rows_across_stages():
    opti = ca.Opti()
    (X,), (U,), stages = stage_variables(opti, 2, [np.ones(1)], [(np.ones(1), 1)])
    opti.subject_to(X[:, 2] == X[:, 0])
    with pytest.raises(ModelError, match="variables"):  # the controls: in nothing
        stage_order(opti, stages)
    opti.subject_to(ca.vertcat(U.T, X[:, 1]) == 0)
    with pytest.raises(ModelError, match="two neighbouring"):
        stage_order(opti, stages)


def test_plan_cli_bad_solver_exits_2(tmp_path, capsys):
    from casflex.cli import main

    moves = tmp_path / "moves.toml"
    moves.write_text('[swing]\nduration = 2.0\nq0 = [0.0]\nqf = [1.0]\nsettle = 1.0\n')
    code = main(["plan", "problems/onelink.toml", "--move", f"{moves}:swing",
                 "--solver", "snopt"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--solver" in err and "snopt" in err and "fatrop" in err
