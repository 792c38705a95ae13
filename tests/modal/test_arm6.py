"""The 6-joint arm with three flexible links (problems/arm6_3flex.toml, issue 21)."""

import numpy as np
import pytest

from casflex.modal import shape_joints
from casflex.robot import load
from casflex.tmm import natural_frequencies


def test_four_shape_joints_inside_stated_limits():
    robot = load("problems/arm6_3flex.toml")
    assert robot.n_joints == 6
    # every joint outboard of link 1 moves a beam or a body relative to the clamp
    assert shape_joints(robot) == (2, 3, 4, 5)
    assert robot.joint_limits[0] is None  # the base turns freely
    for k in range(1, 6):
        lo, hi = robot.joint_limits[k]
        assert -np.pi < lo < 0.0 < hi < np.pi


@pytest.mark.slow
def test_base_and_shoulder_do_not_change_the_frequencies():
    """The shape-joint rule's claim, checked with the TMM: q1 and q2 move the whole
    flexible structure rigidly (clamped at the shoulder), so the frequencies stay."""
    robot = load("problems/arm6_3flex.toml")
    q = np.array([0.0, 0.0, 0.4, -0.7, 0.5, 1.0])
    moved = q + np.array([1.3, -0.8, 0.0, 0.0, 0.0, 0.0])
    w0 = natural_frequencies(robot, q, count=4)
    w1 = natural_frequencies(robot, moved, count=4)
    assert np.allclose(w0, w1, rtol=1e-9)
