"""Static large deflection of the Table 8 arm across the joints' plane: casflex's modal
model against the 3-D geometrically exact reference (issue 19, session 8).

Why: on Table 9 move 3 (q1 turns by −π in 2 s) the model with both options swings 3 %
too far sideways at the 239 mm peak (test_spatial_fidelity.py). A uniform body-force
field along ``y0`` (across the plane of q2 and q3 at q = 0: link 1 bends along its
joint axis and twists, link 2 bends along its joint axis; the inertial load of the swing
in static form) separates stiffness from inertia: there is no velocity here. The
model's static equilibrium is ``∂V/∂δ = 0`` with the field as its "gravity" (with
``foreshortening`` the potential is kept to δ², so the field's own geometric stiffness
is in); the reference solves the nonlinear beams.

Measured (5 modes; reference 32 elements; tangential tip deflection, model against
reference): 10.8 mm +0.07 %, 87 mm +0.35 %, 172 mm +1.2 %, 254 mm +2.5 %, 333 mm
+4.4 %: above the linear floor the excess grows as the deflection squared, alike with
and without ``foreshortening``. At link 1's end the twist and the slope (126 and 148
mrad at 254 mm) are 1.5–1.9 % larger in the model. The reference stiffens at large
rotations, a term of third order in δ in the equations (fourth in the energy), beyond
the model's quadratic elastic potential and second-order kinematics: the same size as
move 3's tangential excess (+3.0 %), with no velocity involved.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("exudyn")

import casadi as ca  # noqa: E402
import reference_beam_3d as rb  # noqa: E402


def _model_static_tip(model, accel: float) -> np.ndarray:
    """Tip displacement [m] of ``model`` (built with the unit field ``gravity = [0, 1,
    0]``) at q = 0 in static equilibrium under ``accel`` [m/s²] along y0: Newton on the
    modal rows ``K δ + accel g_δ(δ) = 0`` (``∂V_g/∂X`` is linear in the field), to 1e-13."""
    f = model.functions()
    q = np.zeros(model.n)
    delta = ca.SX.sym("delta", model.m)
    rows = f["stiffness"](q) @ delta + accel * f["gravity"](q, delta)[model.n:]
    residual = ca.Function("residual", [delta], [rows, ca.jacobian(rows, delta)])
    x = np.zeros(model.m)
    for _ in range(30):
        r, J = (v.full() for v in residual(x))
        if np.abs(r).max() < 1e-13:
            break
        x -= np.linalg.solve(J, r.ravel())
    else:
        raise AssertionError("the static Newton did not converge")
    return (f["tip"](q, x) - f["tip"](q, np.zeros(model.m))).full().ravel()


def _unit_field_model(arm_model):
    """5 modes, ``foreshortening`` (the potential to δ²), the unit field along y0; the
    1.5° table of test_spatial_fidelity.py (shared in a session; q3 = 0 is a node)."""
    return arm_model(5, step_deg=1.5, gravity=[0.0, 1.0, 0.0], foreshortening=True)[0]


# the field [m/s² along y0] and the measured tangential excess of the model; 12 m/s² puts
# the tip 254 mm across the plane, move 3's size
_LEVELS = {
    "linear_11mm": 0.5,
    "move3_size_254mm": pytest.param(12.0, marks=pytest.mark.xfail(
        strict=True, raises=AssertionError,
        reason="issue 19, measured: tangential +2.5 % (default +2.46 %, foreshortening "
               "+2.53 %) at 254 mm: the model's kinematics truncated at δ² (an exact-kinematics "
               "model in the same modes is within 0.07 %: test_elastica_stiffening.py)")),
}


@pytest.mark.slow
@pytest.mark.parametrize("accel", list(_LEVELS.values()), ids=list(_LEVELS))
def test_static_deflection_across_the_plane(arm_model, accel):
    """Tangential tip deflection within 2 % of the reference (the issue's peak target)
    and the 3-D tip displacement within 5 % of it. The linear floor (11 mm): measured
    +0.07 % and a 3-D gap of 0.11 % (default 0.32 %: the small radial and vertical
    parts need the δ² terms): 5 modes and the reference's own O(h²) error (32 elements,
    ~1e-4). The 16-element reference would change the figures by < 0.1 %."""
    ref = rb.SpatialArm(n_elements=32).static((0.0, 0.0, 0.0), (0.0, accel, 0.0))["tip"]
    tip = _model_static_tip(_unit_field_model(arm_model), accel)
    assert tip[1] / ref[1] - 1 == pytest.approx(0.0, abs=2e-2), (tip, ref)
    assert np.linalg.norm(tip - ref) < 5e-2 * np.linalg.norm(ref), (tip, ref)


@pytest.mark.slow
def test_static_excess_grows_as_the_deflection_squared(arm_model):
    """Above the linear floor, the model's tangential excess at 4, 8 and 12 m/s² (87, 172,
    254 mm) grows as the load squared (measured 0.28, 1.11, 2.46 % after the floor of
    0.07 % at 0.5 m/s²: ratios 4.0 and 8.8 for 4 and 9): the signature of a term of
    higher order in δ, not of a wrong linear one (which would give a constant ratio)."""
    model, excess = _unit_field_model(arm_model), {}
    for accel in (0.5, 4.0, 8.0, 12.0):
        ref = rb.SpatialArm(n_elements=32).static((0.0, 0.0, 0.0), (0.0, accel, 0.0))["tip"]
        excess[accel] = _model_static_tip(model, accel)[1] / ref[1] - 1
    above = {a: excess[a] - excess[0.5] for a in (4.0, 8.0, 12.0)}
    assert above[8.0] / above[4.0] == pytest.approx(4.0, rel=0.1)
    assert above[12.0] / above[4.0] == pytest.approx(9.0, rel=0.1)


@pytest.mark.slow
def test_exact_kinematics_static_deflection_across_the_plane(arm_model):
    """``kinematics="exact"`` (the links rebuilt from the modal strains, issue 19) at the
    linear floor (11 mm) and at move 3's size (254 mm): tangential deflection and 3-D
    tip within 0.2 % of the reference, where the default kinematics are 2.5 % off.
    Measured +0.069 % and +0.064 % (3-D 0.069 %, 0.067 %). Budget: five modes (an
    exact-kinematics Ritz model in the same modes is +0.06 %, with 8 modes 0.002 %,
    tests/exact_ritz.py), the reference's 32 elements (O(h²), ~0.05 %), the rods'
    16-point integrator (0.001 % against 48 points)."""
    model = arm_model(5, step_deg=1.5, gravity=[0.0, 1.0, 0.0], kinematics="exact")[0]
    for accel in (0.5, 12.0):
        ref = rb.SpatialArm(n_elements=32).static((0.0, 0.0, 0.0), (0.0, accel, 0.0))["tip"]
        tip = _model_static_tip(model, accel)
        assert tip[1] / ref[1] - 1 == pytest.approx(0.0, abs=2e-3), (accel, tip, ref)
        assert np.linalg.norm(tip - ref) < 2e-3 * np.linalg.norm(ref), (accel, tip, ref)
