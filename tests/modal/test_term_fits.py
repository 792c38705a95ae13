"""Chebyshev fits of every model term (casflex.modal.term_fits).

References: direct TMM (the model of one configuration, PointwiseProvider, computed here
at configurations between the Chebyshev samples) and, in the smooth basis, the basis
invariants of the lowest eigenmodes of a direct solve (the fit's own held-out check).
"""

import dataclasses

import numpy as np
import pytest

from casflex.modal import TERM_TARGET, fit_model_terms
from casflex.modal.fits import OMEGA_TARGET
from casflex.model import ChebyshevProvider, FlexibleModel, PointwiseProvider
from casflex.robot import load


@pytest.mark.slow
def test_model_from_the_fit_matches_the_model_of_one_configuration():
    """Inside the box, M (any δ), K and the gravity forces at δ = 0 (no derivative of the
    modal terms enters them) equal those of the model built on the TMM modes of exactly
    that configuration, within the targets."""
    arm = load("problems/arm2link.toml")
    arm = dataclasses.replace(arm, joint_limits=(None, None, (0.2, 0.7)))
    fit = fit_model_terms(arm, 2, processes=1)
    assert fit.info["converged"]
    f_fit = FlexibleModel(arm, ChebyshevProvider(fit)).functions()
    rng = np.random.default_rng(8)
    for q3 in (0.23, 0.41, 0.66):  # between the Lobatto samples
        q = np.array([0.3, -0.4, q3])
        f_ref = FlexibleModel(arm, PointwiseProvider(arm, q, count=2, shape_joints=(2,))
                              ).functions()
        d = 0.01 * rng.normal(size=2)
        M = [f["mass"](q, d).full() for f in (f_fit, f_ref)]
        assert np.abs(M[0] - M[1]).max() <= TERM_TARGET * np.abs(M[1]).max()
        g = [f["gravity"](q, np.zeros(2)).full() for f in (f_fit, f_ref)]
        assert np.abs(g[0] - g[1]).max() <= TERM_TARGET * np.abs(g[1]).max()
        w = [np.sqrt(np.diag(f["stiffness"](q).full())) for f in (f_fit, f_ref)]
        assert np.abs(w[0] / w[1] - 1.0).max() <= OMEGA_TARGET


@pytest.mark.slow
def test_smooth_basis_fit_of_the_four_joint_arm_meets_the_targets():
    """Around the straight wrist (a double root of both bending pairs) in the smooth
    basis with the neighbour gauge (not the default since session 9): the natural
    frequencies and the basis invariants of every term at held-out configurations
    against direct TMM."""
    robot = load("problems/arm4_spatial.toml")
    held_out = np.array([[0.1, 0.2, 0.05, -0.1], [0.0, 0.0, 0.17, 0.13],
                         [0.0, 0.5, -0.11, 0.02]])
    fit = fit_model_terms(robot, 4, basis="smooth", box=[(-0.2, 0.2), (-0.2, 0.2)],
                          processes=1, held_out=held_out, gauge="neighbour")
    assert fit.info["converged"] and fit.clusters == ((0, 1), (2, 3))
    errors = fit.info["held_out"]
    assert errors["omega"] <= OMEGA_TARGET
    assert {"C1", "C2", "N", "end_u", "end_theta", "sample_u"} <= set(errors)
    assert max(v for k, v in errors.items() if k != "omega") <= TERM_TARGET
