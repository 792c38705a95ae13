"""A robot with one joint and no modes builds (the prescribed-motion rows have no modal
part): its mass is the hub's plus the beam's inertia about the joint, by hand."""

import numpy as np

from casflex.model import FlexibleModel, rigid_provider
from casflex.robot import load


def test_one_joint_rigid_model_mass_and_prescribed_torque():
    robot = load("problems/onelink.toml")
    model = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    f = model.functions()
    rho, a, b, length, hub = 2700.0, 0.007, 0.005, 1.0, 0.01  # problems/onelink.toml
    slender = hub + rho * a * b * length**3 / 3.0  # thin rod about its end
    # plus the section's own rotary inertia rho L I, I = a b^3/12 or b a^3/12 by the plane
    rotary = rho * length * a * b * max(a, b) ** 2 / 12.0
    J = float(f["mass"]([0.3], []))
    assert slender <= J <= slender + rotary * (1 + 1e-9)
    # prescribed motion, no gravity, at rest: tau = J qdd, no modal rows
    assert model.prescribed_dddelta.shape == (0, 1)
    tau, dddelta = f["prescribed"]([0.3], [0.0], [2.0], [], [])
    assert dddelta.shape == (0, 1)
    np.testing.assert_allclose(float(tau), J * 2.0, rtol=1e-12)
