"""Dimension-adaptive refinement of fit_model_terms (refine=, max_points=, axis_ratio).

Reference: the Table 8 arm's modes do not depend on its shoulder joint q2 (only the elbow
q3 changes the shape of the structure), so over (q2, q3) every term is constant along q2:
an adaptive fit must not refine that axis.
"""

import numpy as np

from casflex.modal import fit_model_terms
from casflex.robot import load

BOX = [(-0.5, 0.5), (0.2, 0.6)]


def test_an_axis_the_terms_do_not_depend_on_keeps_its_first_degree():
    arm = load("problems/arm2link.toml")
    fit = fit_model_terms(arm, 1, joints=(1, 2), box=BOX, start_degree=4, max_degree=16,
                          refine="worst", processes=1, held_out=[[0.0, 0.31, 0.47]])
    assert fit.info["converged"]
    assert fit.degrees[0] == 4 and fit.degrees[1] > 4
    assert fit.info["axis_ratio"][0] < 1e-6  # round-off only: constant along q2
    assert fit.info["points"] == 5 * (fit.degrees[1] + 1)
    assert fit.info["held_out"]["C2"] < 1e-3 and fit.info["held_out"]["omega"] < 1e-4


def test_a_point_budget_stops_the_refinement_and_says_so():
    arm = load("problems/arm2link.toml")
    fit = fit_model_terms(arm, 1, joints=(1, 2), box=BOX, start_degree=2, max_degree=16,
                          refine="worst", max_points=10, processes=1)
    assert fit.degrees == (2, 2) and fit.info["points"] == 9
    assert not fit.info["converged"] and max(fit.info["axis_ratio"]) > 1.0
    assert np.isfinite(fit.info["axis_ratio"]).all()
