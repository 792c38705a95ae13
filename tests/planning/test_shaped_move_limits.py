"""The planner's limits from a shaped move: the rigid hub's peaks in closed form, a held
joint unlimited in torque and nearly still."""

from __future__ import annotations

import math

import numpy as np
import pytest

from casflex.model import FlexibleModel, rigid_provider
from casflex.moves import Move, ShapedMove
from casflex.planning import shaped_move_limits
from casflex.robot import loads
from casflex.shaping import Shaper

HUB, RHO, AREA, L = 0.01, 2700.0, 0.007 * 0.005, 1.0  # problems/onelink.toml


def test_rigid_hub_limits_in_closed_form():
    # the one-link arm with a second joint at the beam end carrying only a rotor (as in
    # test_plan_onelink.py): rigid, the hub's torque is J q1'' with J = J_hub + rho A L^3/3
    text = open("problems/onelink.toml").read().replace(
        'joint = "fixed"', 'joint = "revolute"\nmotor_inertia = 0.002')
    arm = loads(text)
    model = FlexibleModel(arm, rigid_provider(arm), gravity=None)
    T, theta, d = 1.0, 0.5, 0.1  # s, rad, s (the shaper's delay, < T / 2)
    move = Move([0.0, 0.3], [theta, 0.3], T, settle=0.5)
    shaped = ShapedMove(move, Shaper([0.0, d], [0.5, 0.5]))
    tau, v = shaped_move_limits(model, move, shaped, dt=1e-4)
    a = 4.0 * theta / T**2
    J = HUB + RHO * AREA * L**3 / 3.0
    # two half-amplitude copies d apart: |q''| peaks at a (both accelerating), q' is flat
    # at a (T - d) / 2 between the copies' peaks (one rises as the other falls), so the
    # sampled peak is exact. The section's own inertia about the beam axis adds ~1e-5
    # relative to J (hence 1e-4)
    assert tau[0] == pytest.approx(J * a, rel=1e-4)
    assert v[0] == pytest.approx(a * T / 2 - a * d / 2, rel=1e-6)
    # the held joint: no torque limit, velocity 1e-3 of the moving joint's
    assert math.isinf(tau[1]) and v[1] == pytest.approx(1e-3 * v[0], rel=1e-12)
    assert np.all(np.isfinite(v))
