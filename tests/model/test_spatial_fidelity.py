"""Fidelity of the modal model on Table 9 move 3 (q1 turns by −π in 2 s) against the 3-D
geometrically exact beam reference (issue 19).

The reference (tests/reference_beam_3d.py: Exudyn's beams with torsion, prescribed joints,
checked on its own in test_spatial_reference.py) knows nothing of casflex; its converged
run is test data keyed by its source (tests/data/reference_beam_3d), so this test costs
only casflex's runs. Tip deflection in 3-D, figures of merit as for the planar moves
(tests/fidelity_spatial.py).
"""

from __future__ import annotations

import pytest

pytest.importorskip("exudyn")

from fidelity_spatial import MOVE3, casflex_run, compare, reference_run  # noqa: E402

# The targets of issue 19: peak within 2 %, residual within 5 %, time history within 5 %
# of the peak. Measured with 5 modes, the 1.5° grid, RK4 at 1 ms against the stored run
# (benchmarks/README_fidelity.md); a variant that misses is xfail(strict) with its
# numbers, so that a fix shows as XPASS. The cause (session 8, test_spatial_static.py):
# at this size (239 mm, 17 % of the tip's radius) the reference stiffens with the
# rotations (twist and slope of link 1 ~0.13-0.15 rad), a term of third order in δ beyond
# the model's structure: statically the model is 2.5 % too soft across the plane at 254
# mm, as the swing here is 3.0 % too large; with the arm 4 times stiffer (69 mm) both
# variants meet the targets (benchmarks/README_fidelity.md). The kinematics truncated at
# δ² are the cause: ``kinematics="exact"`` meets the targets (session 9).
_VARIANTS = {
    "default": {},
    # ("rates", shape_rates alone, is the default model on this move: q2 and q3 are held,
    # so the shapes do not change; it gave the same numbers and is not run twice)
    "rates_short": {"shape_rates": True, "foreshortening": True},
    # the links rebuilt from the modal strains (session 9): measured peak -0.006 %,
    # residual -0.010 %, gap 0.127 % of peak at 1 ms; the same at 2 ms and within 0.002 %
    # at 5 ms (gap 0.129 %), the step used here to keep the test near 20 s
    "exact": {"kinematics": "exact"},
}
_STEPS = {"exact": 5e-3}
_MISSES = {
    "default": "peak -0.41 %, residual +0.28 %, gap 7.5 % of peak",
    "rates_short": "peak +2.81 %, residual -1.40 %, gap 5.4 % of peak",
}


def _cases():
    for variant in _VARIANTS:
        marks = [pytest.mark.slow]
        reason = _MISSES.get(variant)
        if reason:
            # raises=AssertionError: a broken fixture or setup is a failure, not an xfail
            marks.append(pytest.mark.xfail(strict=True, raises=AssertionError,
                                           reason=f"issue 19, measured: {reason}"))
        yield pytest.param(variant, marks=marks, id=variant)


@pytest.mark.parametrize("variant", list(_cases()))
def test_move3_fidelity_targets(arm_model, variant):
    model, _ = arm_model(5, step_deg=1.5, gravity=None, **_VARIANTS[variant])
    c = compare(casflex_run(model, MOVE3, dt=_STEPS.get(variant, 1e-3)), reference_run(),
                MOVE3.duration)
    assert abs(c["peak_pct"]) < 2.0, c
    assert abs(c["residual_pct"]) < 5.0, c
    assert c["gap_pct"] < 5.0, c
