"""Fixtures shared by the planner's tests."""

from __future__ import annotations

import pytest

from casflex.model import FlexibleModel, PointwiseProvider
from casflex.robot import load


@pytest.fixture(scope="module")
def onelink():
    """The one-link flexible arm (``problems/onelink.toml``): its mode at ``q = 0``
    (no shape joint: the modes do not depend on the configuration), no gravity."""
    robot = load("problems/onelink.toml")
    return FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
