"""Fidelity of the modal model on planar moves, against an independent nonlinear beam model.

The reference (tests/reference_beam_dynamics.py) is a planar ANCF Euler–Bernoulli model of
the Table 8 arm with prescribed joints, written without casflex; tests/fidelity_cases.py
maps the arm and the moves into its plane and defines the tip deflection identically on
both sides (issue 19). The reference runs are committed in tests/reference_runs/, keyed by
a hash of the reference's source and the run's parameters (checked and reproduced in
test_reference_convergence.py); a run without a current stored file is computed and kept
in pytest's cache directory.
"""

from __future__ import annotations

import numpy as np
import pytest
from fidelity_cases import BEAM, MOVES, SMALL_SLOW, casflex_run, compare, reference_run
from reference_beam_dynamics import TwoLinkArm


def _in_plane(omega_tmm, omega_ref):
    """The TMM frequency nearest to each reference frequency (the in-plane modes)."""
    omega_tmm = np.asarray(omega_tmm)
    return np.array([omega_tmm[np.argmin(np.abs(omega_tmm - w))] for w in omega_ref])


@pytest.mark.parametrize("q3", [-1.0, 0.0, 1.2])
def test_reference_frequencies_match_tmm(q3):
    """The linearised reference has the TMM's in-plane frequencies: same arm, same plane.

    Tolerance 2e-5: the cubic elements' discretisation error at 16 elements per link is
    ~3e-6 on the third in-plane mode (O(h⁴)), the TMM is exact to round-off.
    """
    from casflex.robot import load
    from casflex.tmm import modes

    robot = load("problems/arm2link.toml")
    omega_tmm = modes(robot, [0.0, 0.3, q3], count=8).omega
    arm = TwoLinkArm((BEAM, BEAM), 16)
    omega_ref = arm.frequencies(0.3, q3 + 0.5 * np.pi, 3)
    np.testing.assert_allclose(_in_plane(omega_tmm, omega_ref), omega_ref, rtol=2e-5)


def test_reference_rigid_when_stiff():
    """A very stiff arm follows the joints rigidly: tip deflection → 0 as EI, EA → ∞
    (checks the prescribed-motion constraints ``B(t)``, ``g(t)`` and their rates)."""
    from reference_beam_dynamics import BangBang, PlanarBeam

    stiff = PlanarBeam(1.0, BEAM.EA * 1e4, BEAM.EI * 1e4, BEAM.rhoA)
    th, ph = BangBang(0.0, -0.8, 0.5), BangBang(0.5 * np.pi, 0.5 * np.pi + 1.2, 0.5)

    def deflection(beam):
        run = TwoLinkArm((beam, beam), 2).simulate(th, ph, 0.5, 2e-3)
        return np.abs(run["tip"] - run["tip_rigid"]).max()

    d_soft, d_hard = deflection(BEAM), deflection(stiff)
    # quasi-static deflection scales as 1/EI: 1e4 stiffer -> ~1e-4 of the deflection
    assert d_hard < 3e-4 * d_soft


@pytest.mark.slow
@pytest.mark.parametrize("shape_rates", [False, True])
def test_small_slow_move_agrees(arm_model, ref_cache, shape_rates):
    """Where the theory says the modal model is right — deflections and joint rates small,
    so every neglected term (second order in δ, foreshortening, δ·q̇ terms) is small —
    casflex (5 modes: the two lowest in-plane modes) follows the reference within 2 % of
    the peak: the third in-plane mode (161 rad/s) is left out and the grid is 7.5°."""
    model, _ = arm_model(5, step_deg=7.5, gravity=None, shape_rates=shape_rates)
    ref = reference_run(SMALL_SLOW, 16, 1e-3, ref_cache)
    c = compare(casflex_run(model, SMALL_SLOW), ref, SMALL_SLOW.duration)
    assert abs(c["peak_pct"]) < 2.0 and c["gap_pct"] < 2.0, c


# The targets of issue 19: peak within 2 %, residual within 5 %, time history within 5 %
# of the peak, against the converged reference (16 elements, 1 ms: 32 elements and 0.5 ms
# move it by < 0.5 % of the peak). Measured with 5 modes, default 1.5° grid, RK4 at 1 ms
# (benchmarks/README_fidelity.md); a model variant that misses is xfail(strict) with its
# numbers, so that a fix shows as XPASS. The default model's misses (move2: peak +0.90 %,
# residual +0.53 %, gap 8.4 % of peak; elbow2_1s: +5.66 / +1.68 / 24.9 %; elbow2_2s:
# +1.39 / +5.44 / 20.7 %) are the issue's own table; they are measured by
# `python benchmarks/bench_fidelity.py --variants base` and no longer re-run here (~50 s
# of the suite's 15 minutes for a known miss).
_VARIANTS = {
    "rates": {"shape_rates": True},
    "rates_short": {"shape_rates": True, "foreshortening": True},
    # the links rebuilt from the modal strains, with the shapes' rates (session 9),
    # measured at 5 ms: move2 -0.01 / -0.01 / 0.06 %, elbow2_1s -0.10 / +0.12 / 0.31 %,
    # elbow2_2s -0.06 / -0.07 / 0.28 % (peak / residual / gap); at 1 ms elbow2_1s is
    # -0.11 / -0.04 / 0.31 %, the same verdict (benchmarks/README_fidelity.md). 5 ms keeps
    # each run near 15 s; the variant without shape_rates misses (gap up to 38 %).
    "rates_exact": {"shape_rates": True, "kinematics": "exact"},
}
_STEPS = {"rates_exact": 5e-3}
_MISSES = {
    ("elbow2_1s", "rates"): "peak +1.35 %, residual +5.64 %, gap 3.6 % of peak",
}


def _target_cases():
    for name in MOVES:
        for variant in _VARIANTS:
            reason = _MISSES.get((name, variant))
            marks = [pytest.mark.slow]
            if reason:
                # raises=AssertionError: a broken fixture is a failure, not an xfail
                marks.append(pytest.mark.xfail(strict=True, raises=AssertionError,
                                               reason=f"issue 19, measured: {reason}"))
            yield pytest.param(name, variant, marks=marks, id=f"{name}-{variant}")


@pytest.mark.parametrize("name, variant", list(_target_cases()))
def test_fidelity_targets(arm_model, ref_cache, name, variant):
    move = MOVES[name]
    model, _ = arm_model(5, step_deg=1.5, gravity=None, **_VARIANTS[variant])
    c = compare(casflex_run(model, move, dt=_STEPS.get(variant, 1e-3)),
                reference_run(move, 16, 1e-3, ref_cache), move.duration)
    assert abs(c["peak_pct"]) < 2.0, c
    assert abs(c["residual_pct"]) < 5.0, c
    assert c["gap_pct"] < 5.0, c
