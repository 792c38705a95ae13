"""The EKF plant of a model with ``kinematics="exact"`` (issue 19).

The plant is tabulated from the model's own modal rows (``dddelta``), expanded in Δ and
stored as B-splines over the provider's shape joints times Fourier series in the other
joints. The exact kinematics' own modal block ``M_δδ(q, 0)`` (``modal_mass="kinematic"``,
its default) depends on the elbow angle through the rods' kinematics; on a provider
without the elbow as a shape joint the rows are then rational in its cosine and no
Fourier series holds them (measured: the plant's check error 0.38 against 1.7e-5 for the
truncated model, two modes frozen at one configuration). That case is refused with a
ModelError naming the joint and the two ways out; ``modal_mass="first_order"`` (M_δδ(q, 0)
= I) is accepted.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.estimation import tabulate_plant
from casflex.model import FlexibleModel, PointwiseProvider

Q = np.array([0.0, 0.3, -0.8])


def test_exact_modal_block_on_a_fourier_joint_is_refused(arm):
    """A pointwise provider has no shape joints: the elbow is a Fourier joint of the plant,
    and the exact model's modal block changes with it by ~0.3 (of 1): refused before any
    tabulation, the message naming q3 and the options."""
    provider = PointwiseProvider(arm, Q, count=1)
    model = FlexibleModel(arm, provider, gravity=None, kinematics="exact")
    with pytest.raises(ModelError, match=r"changes with q3 .*modal_mass='first_order'"):
        tabulate_plant(model, cache_dir=False)


DT = 1e-3
DQ, DDQ = np.array([0.5, -1.5, 2.0]), np.array([1.0, -2.0, 3.0])
# [δ; δ̇] of the one mode, small enough that the plant's truncation (second order in Δ)
# is far below the tolerance, as in test_plant_model_options.py
X = np.array([0.001, 0.01])


@pytest.mark.slow
def test_ekf_runs_on_an_exact_model(arm_model, accel_sensors):
    """An exact model on the 15° table (one mode, q3 the shape joint: its modal block is
    held by the B-spline), its plant tabulated on every sixth grid point (4 points: the
    tabulation of the exact rows costs ~7× the truncated model's, 304 s against 41 s
    with 3 modes on the full 24-point grid under load). At a grid point the EKF step
    (mask 0) predicts as RK4 on the model's own rows, to the plant's truncation in Δ
    (~|X|² ~ 1e-4 of δ̈; measured 1.3e-7 of the step's change, bound 1e-3); given the
    signals the exact sensor model gives at the prior (``kinematic_measurement`` with
    the plant's δ̈), the update (before the prediction) leaves the state unchanged, to
    rounding (measured 4e-17): the EKF measures with the exact rods. The truncated
    model's signals at that state move it by 7e-4, so the check would see a truncated
    measurement."""
    from casflex.estimation import ekf_step_function
    from casflex.sensors import kinematic_measurement
    from casflex.simulate.integrators import rk4_step

    model, table = arm_model(1, step_deg=15, gravity=None, points=accel_sensors.points,
                             kinematics="exact")
    grid = (np.asarray(table.grid[0])[::6],)
    plant = tabulate_plant(model, grid=grid, cache_dir=False)
    q = np.array([0.2, -0.4, grid[0][1]])
    u = np.r_[q, DQ, DDQ]
    # the model's rows alone (functions() would build every Function of the exact model)
    f = ca.Function("dddelta", [model.q, model.dq, model.ddq, model.delta, model.ddelta],
                    [model.prescribed_dddelta])
    m, ny = model.m, accel_sensors.n_outputs

    def rhs(x):
        return np.r_[x[m:], f(q, DQ, DDQ, x[:m], x[m:]).full().ravel()]

    ref = rk4_step(rhs, X, DT)
    step = ekf_step_function(plant, accel_sensors, 5e-6, 1e-4, DT)
    P = 1e-4 * np.eye(2 * m)
    pred = step(X, P, u, np.zeros(ny), np.zeros(ny))[0].full().ravel()
    change = np.abs(ref - X).max()
    np.testing.assert_allclose(pred, ref, rtol=0, atol=1e-3 * change)
    # the signals of the prior (the step updates, then predicts), with the plant's δ̈
    ddd = plant.rhs_function()(u, X).full().ravel()
    y = kinematic_measurement(model, accel_sensors)(X, u, ddd).full().ravel()
    post = step(X, P, u, y, np.ones(ny))[0].full().ravel()
    np.testing.assert_allclose(post, pred, rtol=0, atol=1e-9 * np.abs(pred).max())
    plain, _ = arm_model(1, step_deg=15, gravity=None, points=accel_sensors.points)
    y_plain = kinematic_measurement(plain, accel_sensors)(X, u, ddd).full().ravel()
    moved = step(X, P, u, y_plain, np.ones(ny))[0].full().ravel()
    assert np.abs(moved - pred).max() > 1e3 * 1e-9 * np.abs(pred).max()
