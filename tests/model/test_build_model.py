"""build_model: tables + B-spline provider + symbolic model agree with a pointwise model."""

import numpy as np
import pytest

from casflex.model import FlexibleModel, PointwiseProvider


@pytest.mark.slow
def test_tabulated_model_matches_pointwise(arm, arm_model):
    robot = arm
    model, table = arm_model(3, step_deg=7.5, gravity=None)
    assert table.shape_joints == (2,)
    f = model.functions()
    for q3, tol in [(table.grid[0][30], 1e-9), (0.5, 1e-6)]:  # a grid point, then between
        q = [0.3, -0.2, q3]
        ref = FlexibleModel(robot, PointwiseProvider(robot, q, count=3), gravity=None)
        fr = ref.functions()
        np.testing.assert_allclose(f["mass"](q, [0, 0, 0]).full(),
                                   fr["mass"](q, [0, 0, 0]).full(), atol=tol)
        np.testing.assert_allclose(f["stiffness"](q).full(), fr["stiffness"](q).full(),
                                   rtol=tol)


def test_build_model_forwards_shape_rates(arm_model):
    """build_model passes shape_rates on to FlexibleModel (the study files' route)."""
    plain, _ = arm_model(3, step_deg=15, gravity=None)
    rates, _ = arm_model(3, step_deg=15, gravity=None, shape_rates=True)
    assert (plain.shape_rates, rates.shape_rates) == (False, True)
    q, d = [0.3, -0.4, 0.9], [0.02, -0.01, 0.015]
    diff = rates.functions()["mass"](q, d).full() - plain.functions()["mass"](q, d).full()
    assert np.abs(diff[:, 2]).max() > 1e-6  # the shape-joint column carries the rates
