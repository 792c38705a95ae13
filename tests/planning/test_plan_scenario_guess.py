"""Each frequency-shifted model of a robust plan gets its own modal guess
(:func:`casflex.planning.scenarios.modal_guess`), checked against a linear oscillator
integrated here with scipy on the one-link arm."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.planning import frequency_shifted_model
from casflex.planning.scenarios import modal_guess
from casflex.robot import load


@pytest.fixture(scope="module")
def flexible():
    robot = load("problems/onelink.toml")
    return FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)


@pytest.mark.parametrize("error", [-0.1, 0.0, 0.1])
def test_modal_guess_is_the_shifted_oscillator_driven_by_the_joint(flexible, error):
    # a small, slow move: the velocity-dependent terms (~ q'^2) are ~1e-6 of the inertial
    # coupling, so the mode is the linear oscillator
    #   M_dd delta'' + D delta' + K (1 + e)^2 delta = -M_dq q''
    model = frequency_shifted_model(flexible, error)
    move = Move([0.0], [0.01], 0.3, settle=0.0)
    f = model.functions()
    M = f["mass"]([0.0], [0.0]).full()
    K = float(f["stiffness"]([0.0]).full().squeeze())
    D = float(f["damping"]([0.0]).full().squeeze()) if f["damping"].n_in() == 1 else \
        float(f["damping"]([0.0], [0.0]).full().squeeze())
    assert K == pytest.approx(658.181 * (1.0 + error) ** 2, rel=1e-5)

    def rhs(t, z):
        qdd = move.sample(t)[2][0]
        return [z[1], -(D * z[1] + K * z[0] + M[1, 0] * qdd) / M[1, 1]]

    T, steps = 0.4, 4000
    node_steps = np.arange(0, steps + 1, 100)
    times = np.linspace(0.0, T, 37)
    nodes, points = modal_guess(model, move, T, steps, node_steps, times)
    ref = solve_ivp(rhs, (0.0, T), [0.0, 0.0], method="DOP853", rtol=1e-10, atol=1e-14,
                    dense_output=True, max_step=1e-3)
    peak = np.max(np.abs(ref.sol(times)), axis=1)
    np.testing.assert_allclose(nodes[:, 0], ref.sol(node_steps * T / steps)[0],
                               atol=2e-3 * peak[0])
    np.testing.assert_allclose(nodes[:, 1], ref.sol(node_steps * T / steps)[1],
                               atol=2e-3 * peak[1])
    # the points between steps: linear interpolation of a 0.1 ms step, ~1e-3 of the peak
    for col in range(2):
        np.testing.assert_allclose(points[:, col], ref.sol(times)[col], atol=5e-3 * peak[col])
