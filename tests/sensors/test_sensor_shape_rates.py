"""Accelerometer kinematics with mode shapes that follow the elbow (issue 19).

The acceleration of a sensor point is ``d²/dt² p(q(t), δ(t))`` where ``p`` is the point's
position with the tabulated shapes of the current configuration, so it contains the
``∂w/∂q q̇ δ`` terms whatever the dynamics keeps. The independent check: a central finite
difference in time of the sensor's position (``point_position_function``) along a smooth
trajectory of ``q`` and ``δ``, against ``kinematic_measurement`` (inertial frame, gravity
off, rigid part kept) with ``q̇, q̈, δ̇, δ̈`` of the same trajectory, for the plain and the
``shape_rates`` model, and the lean and the full sensor graphs.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.sensors import kinematic_measurement, point_position_function

# q(t) = Q0 + QA sin(W t), δ(t) = D0 + DA sin(W t): elbow travel ±0.8 rad at 3 rad/s
Q0, QA = np.array([0.2, -0.3, 0.4]), np.array([0.5, -0.7, 0.8])
D0, DA = np.array([0.01, -0.02, 0.015]), np.array([0.02, 0.01, -0.015])
W = 3.0


def _traj(t):
    s, c = np.sin(W * t), np.cos(W * t)
    return (Q0 + QA * s, QA * W * c, -QA * W**2 * s,
            D0 + DA * s, DA * W * c, -DA * W**2 * s)


@pytest.mark.slow
@pytest.mark.parametrize("shape_rates", [False, True])
@pytest.mark.parametrize("lean", [False, True])
def test_acceleration_is_second_derivative_of_position(arm_model, accel_sensors, lean,
                                                       shape_rates):
    sensors = accel_sensors.with_options(frame="inertial", gravity=False, rigid=True)
    model, _ = arm_model(3, step_deg=15, gravity=None, points=sensors.points,
                         shape_rates=shape_rates)
    pos = point_position_function(model, sensors)
    h = kinematic_measurement(model, sensors, lean=lean)
    for t0 in (0.1, 0.45, 0.8):
        q, dq, ddq, d, dd, ddd = _traj(t0)
        y = h(np.r_[d, dd], np.r_[q, dq, ddq], ddd).full().ravel()
        # central difference, Richardson-extrapolated over dt = 2e-3 and 1e-3 s:
        # truncation ~ dt^4 |p^(6)| / 360 ~ 1e-10 m/s^2 with |p^(6)| ~ W^6 x 1 m; rounding
        # ~ 1e-16 m / dt^2 ~ 1e-10 m/s^2
        fd2 = []
        for dt in (2e-3, 1e-3):
            p = [np.concatenate([o.full().ravel()
                                 for o in pos(*(_traj(t)[i] for i in (0, 3)))])
                 for t in (t0 - dt, t0, t0 + dt)]
            fd2.append((p[0] - 2.0 * p[1] + p[2]) / dt**2)
        fd = (4.0 * fd2[1] - fd2[0]) / 3.0
        # the shape-rate part of the acceleration is of order |dw/dq| |dq| |d(delta)| ~
        # 0.1 m/s^2: 1e-6 m/s^2 lies well above the difference's error and far below it
        np.testing.assert_allclose(y, fd, rtol=0, atol=1e-6)
