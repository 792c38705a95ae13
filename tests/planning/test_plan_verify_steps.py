"""The verification's simulations of a plan converge at their default steps.

A plan's q̈ jumps at every OCP node (piecewise-constant torques) and drops to zero at its
end. Fixed-step RK4 is first order wherever a step straddles such a jump or samples it
from the wrong side, so the verified residuals of a plan were off by up to 1 % on move 1
of the design study at 0.1 ms, jumping with the plan's duration, and a rest-to-rest
plan of the one-link arm was verified at 0.78 mm where it leaves 0.4 µm
(benchmarks/README_planning.md, session 32). The reference here is the same simulation
at a hundred times finer step: the errors in question are of the step, not of the model.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from casflex.model import FlexibleModel, PointwiseProvider
from casflex.planning import plan_move, verify_plan
from casflex.robot import load
from casflex.simulate.integrators import LEFT_LIMIT


@pytest.fixture(scope="module")
def rest_to_rest():
    """A minimum-time rest-to-rest plan of the one-link arm (δ = δ̇ = 0 at its end)."""
    robot = load("problems/onelink.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    return model, plan_move(model, [0.0], [0.5], torque_limit=0.5, intervals=12, settle=0.5)


def test_a_plan_rests_from_its_end_and_takes_the_next_interval_at_a_node(rest_to_rest):
    _, plan = rest_to_rest
    T = plan.duration
    q, dq, ddq = plan.sample([T, T - 1e-7])
    assert q[0] == pytest.approx(plan.q[-1], abs=1e-12)
    assert dq[0] == pytest.approx([0.0]) and ddq[0] == pytest.approx([0.0])
    assert abs(ddq[1, 0]) > 0.1  # the last interval still accelerates just before
    # at an inner node: the next interval's q̈ on it, the last one's a simulator's left
    # limit before it (one step of 0.1 ms)
    k = 6
    node = plan.node_t[k]
    at, left = plan.sample([node, node - LEFT_LIMIT * 1e-4])[2][:, 0]
    inside_next, inside_last = plan.sample([node + 1e-7, node - 1e-7])[2][:, 0]
    assert abs(at - left) > 0.1
    assert at == pytest.approx(inside_next, rel=1e-4)
    assert left == pytest.approx(inside_last, rel=1e-4)


def test_the_verification_steps_divide_the_intervals(rest_to_rest):
    model, plan = rest_to_rest
    h = plan.node_t[1] - plan.node_t[0]
    v = verify_plan(model, plan, dt=1e-3, torque=False)
    steps = h / v["dt"]
    assert v["dt"] <= 1e-3 and steps == pytest.approx(math.ceil(h / 1e-3), rel=1e-12)


def test_the_verified_residuals_converge_at_a_coarse_step(rest_to_rest):
    model, plan = rest_to_rest
    coarse = verify_plan(model, plan, dt=1e-3)
    fine = verify_plan(model, plan, dt=1e-5)
    # joints on the plan: the plan ends at rest, so almost nothing is left (the OCP's
    # own discretisation: 0.4 µm); the old steps reported 0.78 mm at 1 ms, 7.5 µm at 0.01
    assert fine["prescribed"] < 1e-6
    assert coarse["prescribed"] == pytest.approx(fine["prescribed"], rel=1e-3)
    # under the torques: the collocation's joint motion is not exactly theirs, so more
    # is left; 1 ms gives the 0.01 ms figure to 2e-4 (the old steps: 4 times it)
    assert coarse["torque"] == pytest.approx(fine["torque"], rel=1e-3)
    assert np.isfinite(coarse["torque"]) and coarse["torque"] > fine["prescribed"]
