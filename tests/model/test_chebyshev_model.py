"""A model built from Chebyshev fits of its terms instead of the grid (issue 21).

References: direct TMM at held-out configurations (the fit's own check, recomputed here
from the modes solved at those configurations), and the grid model (B-splines on a 1.5°
grid, whose own error is ~1e-6) on the model's outputs M, h and ω at random
configurations, within the issue's error target (1e-3 of the model terms, 1e-4 on ω).
"""

import numpy as np
import pytest

from casflex.modal import TERM_TARGET, fit_model_terms
from casflex.modal.fits import OMEGA_TARGET
from casflex.model import ChebyshevProvider, build_model
from casflex.robot import load


@pytest.fixture(scope="module")
def held_out():
    rng = np.random.default_rng(2024)
    qs = np.zeros((6, 3))
    qs[:, 2] = rng.uniform(-np.pi, np.pi, 6)
    return qs


@pytest.fixture(scope="module")
def fitted(held_out):
    arm = load("problems/arm2link.toml")
    return build_model(arm, 3, fit="chebyshev", processes=2,
                       fit_options={"held_out": held_out})


@pytest.mark.slow
def test_fit_meets_the_targets_at_held_out_configurations(fitted):
    _, fit = fitted
    assert fit.info["converged"]
    errors = fit.info["held_out"]
    assert {"C1", "C2", "N", "eps", "end_u", "end_theta", "omega"} <= set(errors)
    assert errors["omega"] <= OMEGA_TARGET
    assert max(v for k, v in errors.items() if k != "omega") <= TERM_TARGET
    assert fit.info["periodic"] == [True]  # the elbow's full turn closes up


@pytest.mark.slow
def test_model_from_the_fit_matches_the_grid_model(fitted, arm_model):
    model_fit, fit = fitted
    model_grid, _ = arm_model(3, 1.5)
    f_fit, f_grid = model_fit.functions(), model_grid.functions()
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, 3)
        q[2] = rng.uniform(-4.0, 4.0)  # beyond ±π too: the fit wraps the full turn
        d, dq, dd = 0.01 * rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
        M = [f["mass"](q, d).full() for f in (f_fit, f_grid)]
        h = [(f["coriolis"](q, d, dq, dd) @ np.r_[dq, dd] + f["potential_forces"](q, d)
              ).full().ravel() for f in (f_fit, f_grid)]
        assert np.abs(M[0] - M[1]).max() <= TERM_TARGET * np.abs(M[1]).max()
        assert np.abs(h[0] - h[1]).max() <= TERM_TARGET * np.abs(h[1]).max()
        w = [np.sqrt(np.diag(f["stiffness"](q).full())) for f in (f_fit, f_grid)]
        assert np.abs(w[0] / w[1] - 1.0).max() <= OMEGA_TARGET


def test_a_fit_of_frequencies_alone_is_refused():
    from casflex.errors import ModelError
    from casflex.modal import ChebyshevFit

    fit = ChebyshevFit(box=((0.0, 1.0),), shape_joints=(2,), degrees=(1,),
                       coefficients={"omega": np.ones((2, 1))}, clusters=((0,),))
    with pytest.raises(ModelError, match="fit_model_terms"):
        ChebyshevProvider(fit)


def test_fit_refuses_bad_options():
    from casflex.errors import ModelError

    arm = load("problems/arm2link.toml")
    with pytest.raises(ModelError, match="basis must be"):
        fit_model_terms(arm, 1, basis="qr", processes=1)
    with pytest.raises(ModelError, match="fit must be None"):
        build_model(arm, 1, fit="spline", processes=1)
