"""Models shared by the tests of casflex.control."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def elbow_model(arm):
    """Shapes frozen at q3 = -pi/2: exact for every q1, q2 with that elbow angle."""
    from casflex.model import FlexibleModel, PointwiseProvider

    return FlexibleModel(arm, PointwiseProvider(arm, np.array([0.0, 0.0, -np.pi / 2]),
                                                count=3),
                         gravity=None, delta_order=0)


@pytest.fixture(scope="module")
def table_model(arm_model):
    """The Table 8 arm of the control studies: 3 modes, 15-degree table, no gravity,
    ``M(q)`` without deflection terms (``delta_order=0``)."""
    return arm_model(3, 15, gravity=None, delta_order=0)
