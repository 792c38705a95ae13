"""What makes the modal model deflect too far under large static loads (issue 19, s8).

test_spatial_static.py: the Table 8 arm at q = 0 under a uniform field across the joints'
plane deflects +2.5 % too far at 254 mm (move 3's size) against the 3-D geometrically
exact reference, growing as the deflection squared. Hypothesis: the elastic potential
lacks the inextensible beam's nonlinear curvature, ``κ² ≈ w''²(1 + w'²)``.

Checked here against two independent calculations:

* a **planar elastica** (the exact nonlinear ODE of an inextensible cantilever, solved by
  scipy's ``solve_bvp``; checked against Bisshopp & Drucker's tabulated tip load case):
  the quartic curvature term is exactly what a single beam's stiffening is, to
  O(slope⁴);
* a **geometrically exact Ritz model in the same five TMM modes** (``exact_ritz.py``:
  the modes' curvatures superposed, the rods rebuilt exactly, the strain energy the same
  ``½ δᵀKδ``): it matches the 3-D reference to 0.07 % at 254 mm, and so does its field
  potential truncated to δ³, while truncated to δ² it misses by 1.9 %. The excess is
  geometric and of fourth order in the energy.

Measured (benchmarks/README_fidelity.md, ``bench_fidelity.py --stiffening``): with the
quartic curvature term added, casflex's excess at 254 mm falls from +2.53 % only to
+1.72 %; with the twist–bending term and link 2's third-order rotation about the elbow
too, to +0.54 %. The rest and the radial and vertical parts (23 % and 6 % short in
casflex at every load: second order) come from casflex's δ² kinematics of the
out-of-plane modes, which differ from the exact second order (last test).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from exact_ritz import ExactRitz, quartic_terms
from scipy.integrate import solve_bvp

from casflex.robot import load

# the Table 8 link bending along its joint axis (the 5 mm side): EI [N m²], ρA [kg/m]
EI = 69.0e9 * 0.007 * 0.005**3 / 12.0
RHO_A = 2700.0 * 0.007 * 0.005


def elastica_tip(q: float, P: float, EI: float = EI, L: float = 1.0) -> tuple[float, float]:
    """Tip deflection [m] and tip rotation [rad] of an inextensible cantilever under a
    dead uniform load ``q`` [N/m] and tip force ``P`` [N], both across the undeformed
    beam: ``EI θ'' = −(q (L − s) + P) cos θ``, ``θ(0) = 0``, ``θ'(L) = 0``, ``w' = sin θ``."""
    def rhs(s, z):
        return np.vstack([z[1], -(q * (L - s) + P) * np.cos(z[0]) / EI, np.sin(z[0])])

    def bc(a, b):
        return np.array([a[0], b[1], a[2]])

    s = np.linspace(0.0, L, 101)
    theta = (q * L**3 / 6 + P * L**2 / 2) / EI * (1 - (1 - s / L) ** 3)
    sol = solve_bvp(rhs, bc, s, np.vstack([theta, np.gradient(theta, s), theta * s]),
                    tol=1e-10, max_nodes=100000)
    assert sol.success, sol.message
    end = sol.sol(L)
    return float(end[2]), float(end[0])


def quartic_ritz_tip(q: float, P: float, quartic: bool = True, n: int = 8,
                     L: float = 1.0) -> float:
    """Tip deflection [m] of the same cantilever from the potential ``½ EI ∫ w''²(1 +
    w'²) − ∫ q w − P w(L)`` (without ``w'²`` if not ``quartic``), Ritz in ``s², …, s^(n+1)``."""
    c = ca.SX.sym("c", n)
    x, wq = np.polynomial.legendre.leggauss(40)
    s, wq = 0.5 * L * (x + 1), 0.5 * L * wq
    k = np.arange(n) + 2
    w = ca.DM(s[:, None] ** k) @ c
    w1 = ca.DM(k * s[:, None] ** (k - 1)) @ c
    w2 = ca.DM(k * (k - 1) * s[:, None] ** (k - 2)) @ c
    V = (0.5 * EI * ca.dot(ca.DM(wq), w2**2 * (1 + (w1**2 if quartic else 0)))
         - q * ca.dot(ca.DM(wq), w) - P * ca.dot(ca.DM(L**k), c))
    newton = ca.Function("newton", [c], [ca.gradient(V, c), ca.hessian(V, c)[0]])
    a = np.zeros(n)
    for _ in range(50):
        g, H = newton(a)
        g = g.full().ravel()
        if np.abs(g).max() < 1e-14:
            break
        a -= np.linalg.solve(H.full(), g)
    return float(np.dot(L**k, a))


def test_elastica_against_bisshopp_drucker():
    """Tip force with ``PL²/EI = 1`` (Bisshopp & Drucker 1945, Q. Appl. Math. 3, table):
    tip deflection 0.30172 L and tip rotation 0.46135 rad, to their 5 digits."""
    w, theta = elastica_tip(0.0, EI)
    assert w == pytest.approx(0.30172, abs=1e-5)
    assert theta == pytest.approx(0.46135, abs=1e-5)


@pytest.mark.parametrize("q, P", [(12.0 * RHO_A, 0.0), (40.0 * RHO_A, 0.0),
                                  (0.0, 1.2), (0.0, 1.6)],
                         ids=["uniform_28mm", "uniform_94mm", "tip_79mm", "tip_105mm"])
def test_quartic_curvature_is_the_planar_elastica(q, P):
    """One Table 8 link across its weak plane: the linear deflection exceeds the
    elastica's by (measured) +0.063 %, +0.70 %, +0.65 %, +1.14 % (tip rotations 0.04 to
    0.16 rad); the quartic curvature term removes all but O(θ⁴) of it (measured
    residuals 1e-6 to 2e-4): under 3 % of the excess. The linear Ritz equals
    ``qL⁴/8EI + PL³/3EI`` to round-off (the basis holds the exact linear solution)."""
    linear = q / (8 * EI) + P / (3 * EI)
    assert quartic_ritz_tip(q, P, quartic=False) == pytest.approx(linear, rel=1e-10)
    exact, theta = elastica_tip(q, P)
    excess = linear / exact - 1
    assert 0.3 * theta**2 < excess < 0.7 * theta**2   # a slope-squared stiffening
    assert abs(quartic_ritz_tip(q, P) / exact - 1) < 0.03 * excess


@pytest.fixture(scope="module")
def ritz():
    return ExactRitz(load("problems/arm2link.toml"))


def test_exact_ritz_first_order_is_the_modes(ritz):
    """To first order in δ the exact Ritz model's tip moves by the modes' tip
    displacements (the mode shapes' own samples), and its stiffness is ``diag(ω²)``:
    midpoint rule on 100 steps per beam, O((βh)²/24) ≈ 4e-4 for the fifth mode's
    wavenumber β ≈ 10/m (measured 1.6e-4 and 9e-5)."""
    sh, d = ritz.shapes, ritz.delta
    J = ca.Function("J", [d], [ca.jacobian(ritz.tip, d)])(np.zeros(5)).full()
    expected = sh.displacement_global[:, 1, -1, :].T
    assert np.abs(J - expected).max() < 1e-3 * np.abs(expected).max()
    assert np.abs(ritz.K - np.diag(sh.omega**2)).max() < 1e-3 * sh.omega.max() ** 2


@pytest.mark.slow
def test_exact_ritz_matches_the_reference_at_fourth_order(ritz):
    """At 12 m/s² across the plane (254 mm) the exact Ritz model is within 0.3 % (3-D)
    of the 3-D reference (measured 0.07 %: the five modes' and the reference's 32
    elements' errors), and so is its field potential truncated to δ³ (measured 0.06 %),
    while truncated to δ² (the order of casflex's ``foreshortening``) it is +1.9 % too
    far across: the missing terms are of fourth order in the energy."""
    rb = pytest.importorskip("reference_beam_3d")
    ref = rb.SpatialArm(n_elements=32).static((0.0, 0.0, 0.0), (0.0, 12.0, 0.0))["tip"]
    for order in (None, 3):
        tip = ritz.static([0.0, 12.0, 0.0], load_order=order)["tip"]
        assert np.linalg.norm(tip - ref) < 3e-3 * np.linalg.norm(ref), (order, tip, ref)
    tip2 = ritz.static([0.0, 12.0, 0.0], load_order=2)["tip"]
    assert tip2[1] / ref[1] - 1 > 1e-2, (tip2, ref)


@pytest.fixture(scope="module")
def unit_field_model(arm_model):
    """test_spatial_static.py's model (shared in a session)."""
    return arm_model(5, step_deg=1.5, gravity=[0.0, 1.0, 0.0], foreshortening=True)[0]


def _tip_hessians(tip, d):
    return np.stack([ca.Function("h", [d], [ca.hessian(tip[i], d)[0]])(np.zeros(5)).full()
                     for i in range(3)])


@pytest.mark.slow
def test_in_plane_second_order_kinematics_agree(ritz, unit_field_model):
    """The model's and the exact Ritz model's modes are the same (signs included: equal
    tip Jacobians), and the second-order tip terms of the in-plane modes (indices 1 and
    3: a planar arm) agree to the Ritz's O(h²): ``foreshortening`` is exact to δ² in the
    plane."""
    f, d = unit_field_model.functions(), ritz.delta
    tip = f["tip"](np.zeros(3), d)
    J = ca.Function("J", [d], [ca.jacobian(tip, d)])(np.zeros(5)).full()
    Jr = ca.Function("J", [d], [ca.jacobian(ritz.tip, d)])(np.zeros(5)).full()
    assert np.abs(J - Jr).max() < 1e-3 * np.abs(J).max()  # the Ritz's O(h²), above
    in_plane = np.ix_(range(3), [1, 3], [1, 3])
    H, Hr = _tip_hessians(tip, d)[in_plane], _tip_hessians(ritz.tip, d)[in_plane]
    assert np.abs(H - Hr).max() < 3e-3 * np.abs(Hr).max()  # the Ritz's O(h²), above


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="issue 19, measured: the out-of-plane modes' second-order tip "
                          "terms differ by up to 138 (the fifth mode squared along x0: "
                          "195 against 334 m/kg): foreshortening lacks second-order rotations")
def test_out_of_plane_second_order_kinematics_agree(ritz, unit_field_model):
    """The same for the out-of-plane modes (indices 0, 2, 4: link 1 bending along its joint axis
    and twisting, link 2 along its joint axis). They differ: the static test's radial
    and vertical tip parts are 23 % and 6 % short in the model at every load (second
    order), and the exact Ritz model, with these terms, gets them within 0.4 %."""
    f, d = unit_field_model.functions(), ritz.delta
    out = np.ix_(range(3), [0, 2, 4], [0, 2, 4])
    H = _tip_hessians(f["tip"](np.zeros(3), d), d)[out]
    Hr = _tip_hessians(ritz.tip, d)[out]
    assert np.abs(H - Hr).max() < 3e-3 * np.abs(Hr).max(), (H, Hr)


@pytest.mark.slow
def test_quartic_terms_close_most_of_the_static_excess(ritz, unit_field_model):
    """casflex's model (``foreshortening``) at 12 m/s²: +2.53 % across the plane against
    the exact Ritz model (measured; 254 mm). Adding the quartic curvature term alone
    leaves +1.7 %: the hypothesis explains a third. With the twist–bending term and link
    2's third-order rotation about the elbow too: +0.5 % (measured 0.48 %). Asserted:
    each term lowers the excess, the curvature term alone leaves over 1 %, all three
    leave under 1 %."""
    model = unit_field_model
    f, d = model.functions(), ritz.delta
    q0, a = np.zeros(3), 12.0
    exact = ritz.static([0.0, a, 0.0])["tip"][1]
    terms = quartic_terms(load("problems/arm2link.toml"), d, [0.0, 1.0, 0.0])
    excess = {}
    for label, V4 in {"none": 0, "curvature": terms["curvature"],
                      "all": terms["curvature"] + terms["twist"] + a * terms["rigid3"]}.items():
        rows = f["stiffness"](q0) @ d + a * f["gravity"](q0, d)[model.n:] + (
            ca.gradient(V4, d) if label != "none" else 0)
        newton = ca.Function("n", [d], [rows, ca.jacobian(rows, d),
                                         f["tip"](q0, d) - f["tip"](q0, np.zeros(5))])
        x = np.zeros(5)
        for _ in range(50):
            r, J, _ = newton(x)
            if np.abs(r.full()).max() < 1e-13:
                break
            x -= np.linalg.solve(J.full(), r.full().ravel())
        excess[label] = newton(x)[2].full()[1, 0] / exact - 1
    assert excess["none"] > excess["curvature"] > excess["all"] > 0, excess
    assert excess["curvature"] > 1e-2 > excess["all"], excess
