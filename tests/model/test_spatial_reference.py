"""The 3-D beam reference itself (tests/reference_beam_3d.py), checked independently of
casflex: statics and free vibration of a cantilever against Euler–Bernoulli/Timoshenko
and St-Venant formulas, a stiff arm following the joints, its convergence on Table 9
move 3, its planar limit against the planar ANCF reference (slow), and the stored test
data against its source (issue 19)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("exudyn")  # the test extra ships it; the message names it if absent

import reference_beam_3d as rb  # noqa: E402
from fidelity_spatial import DATA, MOVE3, REFERENCE, reference_run  # noqa: E402

BEAM = rb.TABLE8
KGA = rb.SHEAR_COEFFICIENT * BEAM.G * BEAM.area


def test_torsion_constant_of_a_rectangle():
    """The series against the tabulated St-Venant coefficients β (J = β a b³): square
    0.1406, 2:1 0.2287, and the thin-strip limit 1/3 (Timoshenko & Goodier, Table 109)."""
    assert rb.torsion_constant(1.0, 1.0) == pytest.approx(0.1406, abs=1e-4)
    assert rb.torsion_constant(2.0, 1.0) / 2.0 == pytest.approx(0.2287, abs=1e-4)
    assert rb.torsion_constant(1000.0, 1.0) / 1000.0 == pytest.approx(1 / 3, rel=1e-3)


@pytest.mark.parametrize("axis", [1, 2], ids=["in_plane", "along_joint_axis"])
def test_static_tip_load(axis):
    """Tip force P: ``P L³/(3 EI) + P L/(κ G A)`` (the shear part is 3e-5 of it). 16
    elements: the two-node elements' error is O(h²), 1e-3 here (measured 8 → 16 → 32
    elements: 3.9e-3, 1.0e-3, 2.6e-4); the load is small enough (deflection L/150) that
    the geometric nonlinearity stays below 1e-4."""
    force = np.zeros(3)
    force[axis] = 0.1
    EI = BEAM.E * (BEAM.I_z if axis == 1 else BEAM.I_y)
    expected = 0.1 / (3 * EI) + 0.1 / KGA
    u = rb.cantilever(BEAM, 16, force=force)["u"]
    assert u[axis] == pytest.approx(expected, rel=1.5e-3)
    assert abs(u[3 - axis]) < 1e-9 * abs(u[axis])  # principal axes: no cross deflection


def test_static_tip_torque():
    """Tip torque T: twist ``T L/(G J)``, exact for any mesh of a uniform beam."""
    phi = rb.cantilever(BEAM, 4, torque=(0.01, 0.0, 0.0))["phi"]
    assert phi[0] == pytest.approx(0.01 / (BEAM.G * BEAM.J), rel=1e-9)


def _frequency(t, x):
    """Mean frequency [rad/s] of the upward zero crossings of ``x`` (linear interpolation)."""
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    crossings = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    return 2 * np.pi * (len(crossings) - 1) / (crossings[-1] - crossings[0])


@pytest.mark.slow
@pytest.mark.parametrize("case", [
    # measured in CI and on its branch: 35.880 against 35.917 rad/s, 1.04e-3 low, with 32
    # elements the static solve fails; the budget below does not explain it (issue 19)
    pytest.param("bend_in_plane", marks=pytest.mark.xfail(
        strict=True, raises=AssertionError,
        reason="issue 19: in-plane bending 1.04e-3 below Euler-Bernoulli, unexplained")),
    "bend_along_axis", "torsion"])
def test_free_vibration_frequencies(case):
    """A step tip load on the clamped beam: it vibrates about the static solution at the
    first frequency, Euler–Bernoulli ``1.8751² √(EI/(ρA L⁴))`` for bending and
    ``π/(2L) √(GJ/(ρ I_p))`` for torsion. The tip force excites the first bending mode to
    97 % (the higher modes shift the zero crossings by < 1e-4 of the period over 6
    periods; the tip torque's higher torsion modes are odd multiples of the first, which
    leave its zero crossings in place); 200 steps per period: 1e-3 (the trapezoidal
    rule's period error (ωh)²/12 = 8e-5, the rotary inertia of bending ~1e-5, and the
    elements' error: bending at 16 elements the O(h²) stiffness error halved; torsion
    measured 1.5e-3 at 16 elements and 5e-5 at 32, so 32)."""
    n_elements = 32 if case == "torsion" else 16
    if case == "torsion":
        load = {"torque": (1e-3, 0.0, 0.0)}
        omega = np.pi / 2 * np.sqrt(BEAM.G * BEAM.J / (BEAM.rho * (BEAM.I_y + BEAM.I_z)))
        t_end, key, k = 6 * 2 * np.pi / omega, "phi", 0
    else:
        k = 1 if case == "bend_in_plane" else 2
        force = np.zeros(3)
        force[k] = 0.02
        load = {"force": force}
        EI = BEAM.E * (BEAM.I_z if k == 1 else BEAM.I_y)
        omega = 1.8751040687119611**2 * np.sqrt(EI / (BEAM.rho * BEAM.area))
        t_end, key = 6 * 2 * np.pi / omega, "u"
    dt = 2 * np.pi / omega / 200
    static = rb.cantilever(BEAM, n_elements, **load)[key][k]
    run = rb.cantilever(BEAM, n_elements, t_end=t_end, dt=dt, **load)
    assert _frequency(run["t"], run[key][:, k] - static) == pytest.approx(omega, rel=1e-3)


def test_stored_reference_matches_its_source():
    """The converged move-3 run of the spatial comparison is test data keyed by a hash of
    reference_beam_3d.py (cached_run): a change to the reference must come with its data
    (regenerate: ``python benchmarks/bench_fidelity.py --spatial --store``)."""
    name = rb.run_file(MOVE3, REFERENCE["n_elements"], REFERENCE["dt"])
    assert (DATA / name).exists(), (
        "tests/data/reference_beam_3d has no run for the current reference source")


def test_stiff_arm_follows_the_joints_rigidly():
    """The first 0.3 s of move 3 on a coarse mesh (the reference runs, Exudyn present): it
    starts on the rigid arm, and an arm 1e4 times stiffer (E, G) deflects ~1e-4 as much
    (quasi-static deflection ∝ 1/stiffness): the prescribed joints reach the beams."""
    import dataclasses

    stiff = dataclasses.replace(BEAM, E=BEAM.E * 1e4, G=BEAM.G * 1e4)

    def deflection(beam, newton_tol):
        run = rb.SpatialArm((beam, beam), 2).simulate(MOVE3, dt=2e-3, t_end=0.3,
                                                      newton_tol=newton_tol)
        d = run["tip"] - run["tip_rigid"]
        assert np.abs(d[0]).max() < 1e-12
        return np.linalg.norm(d, axis=1).max()

    # the stiff arm's axial forces are 1e4 larger, and with them the round-off that the
    # Newton tolerance must clear (measured ratio 1.10e-4 with 1e-5 N and with 1e-3 N)
    assert deflection(stiff, 1e-5) < 3e-4 * deflection(BEAM, 1e-7)


@pytest.mark.slow
def test_reference_converged_on_move3(tmp_path):
    """The stored run (32 elements per link, 1 ms) is converged: 16 elements are within
    1 % of its peak all along move 3 (measured 0.64 %; the elements' error is O(h²), see
    test_static_tip_load, so the stored run's own is about a third of that, ~0.2 %), and
    halving the step changes the 16-element run by less than 0.1 % of the peak (measured
    0.042 %, a phase drift of the trapezoidal rule late in the settle; the bound keeps
    the reference's share of the model's 2–5 % targets small)."""
    base = reference_run()
    peak = np.linalg.norm(base["d"], axis=1).max()

    def gap(run, other):
        on_run = np.column_stack([np.interp(run["t"], other["t"], other["d"][:, k])
                                  for k in range(3)])
        return np.linalg.norm(on_run - run["d"], axis=1).max() / peak

    coarse = rb.cached_run(MOVE3, 16, 1e-3, cache=tmp_path)
    assert gap(base, coarse) < 1e-2
    assert gap(coarse, rb.cached_run(MOVE3, 16, 5e-4, cache=tmp_path)) < 1e-3


@pytest.mark.slow
def test_planar_limit_matches_the_planar_ancf_reference(ref_cache, tmp_path):
    """Table 9 move 2 (q2, q3 → −1 rad in 2 s, q1 held) is planar: the 3-D reference
    stays in the plane (< 1e-8 m out of it) and follows the planar ANCF reference
    (tests/reference_beam_dynamics.py, a different formulation and integrator, both 16
    elements, 1 ms) within 1 % of the peak all along (measured 0.37 %, late in the
    settle: the 3-D elements' O(h²) error, 0.64 % on move 3 at 16 elements) and within
    0.2 % in peak and residual (measured −0.03 %, −0.05 %)."""
    from fidelity_cases import MOVES, compare
    from fidelity_cases import reference_run as planar_run

    move = MOVES["move2"]
    joint_move = rb.JointMove((0.0, 0.0, 0.0), (0.0, move.q2f, move.q3f), move.duration,
                              settle=move.settle)
    spatial = rb.cached_run(joint_move, 16, 1e-3, cache=tmp_path)
    d3 = spatial["d"]
    assert np.abs(d3[:, 1]).max() < 1e-8
    # the planar reference's coordinates: (x0, −z0) (fidelity_cases)
    run = {"t": spatial["t"], "d": np.column_stack([d3[:, 0], -d3[:, 2]])}
    c = compare(run, planar_run(move, 16, 1e-3, ref_cache), move.duration)
    assert abs(c["peak_pct"]) < 0.2 and abs(c["residual_pct"]) < 0.2, c
    assert c["gap_pct"] < 1.0, c
