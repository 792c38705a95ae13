"""tabulate_plant's exact derivatives in Δ (algorithmic differentiation, one evaluation per
design) against its central and second differences (55 evaluations per design)."""

import numpy as np
import pytest

from casflex.estimation import tabulate_plant


@pytest.mark.slow
def test_exact_derivatives_agree_with_differences(arm_model):
    model, _ = arm_model(2, 15.0, gravity=None)
    exact = tabulate_plant(model, cache_dir=False)
    differences = tabulate_plant(model, cache_dir=False, derivatives="differences")
    # same number of evaluations of the rows' value: one per design instead of 1 + 4·2m +
    # 2m(2m − 1) (= 29 for two modes)
    assert differences.info["evaluations"] == 29 * exact.info["evaluations"]
    fe, fd = exact.function(), differences.function()
    rng = np.random.default_rng(7)
    for _ in range(10):
        u = np.r_[rng.uniform(-np.pi, np.pi, 3), rng.normal(size=3), rng.normal(size=3)]
        for a, b in zip(fe(u), fd(u), strict=True):
            a, b = np.asarray(a), np.asarray(b)
            # the differences' truncation errors: eps² f'''/6 with eps = 1e-4 for the
            # Jacobian, eps2² f''''/12 with eps2 = 1e-3 for the quadratic terms, plus their
            # round-off 1e-16 |f| / eps2² ~ 1e-10 |f|; measured 3e-6 of the block's largest
            # entry, so 1e-4 holds with margin and still fails on any wrong term or factor 2
            assert np.max(np.abs(a - b)) <= 1e-4 * np.max(np.abs(a)), u
    # both stay as close to the exact rows (the spline and Fourier errors dominate)
    assert exact.info["check_rel_error"] == pytest.approx(
        differences.info["check_rel_error"], rel=1e-3)
