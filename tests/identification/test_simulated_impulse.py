"""Identification of a simulated impulse response of the testbed (casflex's own model).

The testbed at q = (0, 0, 300°) with 1 % modal damping is given an impulse (initial modal
velocities) and its free response simulated by :func:`casflex.simulate.simulate_data`
(the nonlinear flexible rows, RK4) with two three-axis accelerometers (link 2's tip and
link 1's end) and 250 µg noise. The modes identified from the six channels must match the
TMM natural frequencies at that configuration within 0.5 % (the issue's target; the
simulation's RK4 step of 2 ms shifts a 9 Hz mode by (ωh)⁴/120 ≈ 1e-6 relative).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from casflex.identification import identify_modes
from casflex.tmm import natural_frequencies


@pytest.mark.slow  # about 15–25 s of simulation on a shared core
def test_testbed_impulse_response_modes_match_tmm(testbed):
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.moves import Move
    from casflex.sensors import Accelerometer, SensorSet
    from casflex.simulate import simulate_data

    robot = replace(testbed, damping_ratio=0.01)
    q = np.array([0.0, 0.0, np.radians(300.0)])
    sensors = SensorSet([Accelerometer(3, 0.48, name="tip", gravity=False),
                         Accelerometer(2, 0.53, name="elbow", gravity=False)])
    model = FlexibleModel(robot, PointwiseProvider(robot, q, 4, sensors.points), gravity=None)
    x0 = np.zeros(8)
    x0[4:] = [0.05, 0.03, 0.02, 0.02]  # the impulse: modal velocities [√kg m/s]
    data = simulate_data(model, sensors, Move(q, q, 0.1, settle=0.0), dt=2e-3, t_end=6.0,
                         x0=x0, noise=250e-6 * 9.81, seed=1)
    est = identify_modes(data.t, data.y, channels=sensors.output_names)
    tmm_hz = natural_frequencies(robot, q, count=4) / (2 * np.pi)
    assert est.frequency_hz.size == 4, est.frequency_hz
    assert np.all(np.abs(est.frequency_hz / tmm_hz - 1) < 5e-3)
    assert est.damping == pytest.approx(0.01, rel=0.1)
