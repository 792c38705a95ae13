"""``method="poly"`` with ``foreshortening=True``: M_qq quadratic in δ (issue 19).

The polynomial form keeps its shape (M_δδ affine in δ, r quadratic in (δ, δ̇)); the δ² part
of M_qq adds ``−½ q̇ᵀ ∂²M_qq/∂δ_a∂δ_k q̇`` to the δ coefficient of the modal rows and terms
in δδ and δδ̇ to the torques. Checked against the model's own rows (``prescribed``,
``dddelta``: the CasADi expressions of FlexibleModel) at random states, and the whole
simulation against ``method="rk4"`` on the same model.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.moves import load_move, reference_sampler
from casflex.simulate import poly, simulate_prescribed
from casflex.simulate.chebyshev import evaluate


@pytest.fixture(scope="module")
def models(arm_model):
    """Table 8 arm, 3 modes, 15° grid: both options, with gravity and without, and the
    shape_rates-only model (to show that foreshortening's terms are not negligible here)."""
    out = {}
    for key, gravity in (("free", None), ("gravity", "robot")):
        out[key] = arm_model(3, step_deg=15, gravity=gravity, shape_rates=True,
                             foreshortening=True)[0]
    out["rates"] = arm_model(3, step_deg=15, gravity=None, shape_rates=True)[0]
    return out


def _poly_rows(model, q, dq, ddq, d, v, dd):
    n, m = model.n, model.m
    A = poly.unpack(evaluate(poly.configuration_function(model), q[None]), n, m, dq[None])
    assert "H" in A  # the foreshortening layout was read
    rows = poly.rows(A, dq[None], n, m, model.damping_ratio)
    stage, _ = poly.stage(m)
    ddd = stage(poly.modal(rows, ddq[None])[0], np.r_[d, v]).full().ravel()[m:]
    tau = poly.torque(poly.torque_rows(rows, ddq[None]), n, m, d[None], v[None],
                      dd[None])[0]
    return ddd, tau


@pytest.mark.parametrize("key", ["free", "gravity"])
def test_poly_rows_equal_the_model_with_foreshortening(models, key):
    """At random configurations (every joint moving, the shape joint off the table's
    knots) and δ, δ̇ of the size of a fast move's: δ̈ and τ of the polynomial form equal
    the model's to 1e-10 (round-off of the central differences that extract the δ²
    coefficients, relative to M's largest entry), while the δ² terms change δ̈ by far more."""
    model = models[key]
    f = model.functions()
    rates = models["rates"].functions()
    rng = np.random.default_rng(19)
    n, m = model.n, model.m
    seen = 0.0
    for _ in range(5):
        q = rng.uniform(-2.5, 2.5, n)
        dq, ddq = rng.normal(0.0, 1.5, n), rng.normal(0.0, 3.0, n)
        d, v = rng.normal(0.0, 0.03, m), rng.normal(0.0, 0.3, m)
        tau_ref, dd_ref = (x.full().ravel() for x in f["prescribed"](q, dq, ddq, d, v))
        dd, tau = _poly_rows(model, q, dq, ddq, d, v, dd_ref)
        assert np.abs(dd - dd_ref).max() <= 1e-10 * np.abs(dd_ref).max()
        assert np.abs(tau - tau_ref).max() <= 1e-10 * np.abs(tau_ref).max()
        if key == "free":
            other = rates["dddelta"](q, dq, ddq, d, v).full().ravel()
            seen = max(seen, np.abs(other - dd_ref).max() / np.abs(dd_ref).max())
    if key == "free":
        assert seen > 1e-4  # the test would see the δ² terms missing


def test_first_order_rows_keep_their_layout(models):
    """A first-order model's F has the six outputs of before; unpack reads both layouts
    and refuses rows of neither."""
    from casflex.errors import ModelError

    F = poly.configuration_function(models["rates"])
    assert F.name_out() == ["M", "dM", "omega", "domega2", "g0", "gd"]
    G = poly.configuration_function(models["free"])
    assert G.name_out()[6:] == ["Mqq2", "dMqq2", "gq2"]
    raw = evaluate(G, np.zeros((1, 3)))
    with pytest.raises(ModelError, match="layout"):
        poly.unpack(raw[:, :-1], 3, 3, np.zeros((1, 3)))


@pytest.mark.slow
def test_poly_matches_rk4_with_foreshortening(models):
    """The 1 s elbow move of the fidelity cases (q2 → −0.8, q3 → +1.2 rad), with gravity
    and both options: poly equals RK4 on the same steps to the interpolation error."""
    from casflex.moves import Move

    model = models["gravity"]
    move = Move([0.0, 0.0, 0.0], [0.0, -0.8, 1.2], 1.0)
    dt, t_end = 2e-3, 1.6
    r = simulate_prescribed(model, move, dt=dt, t_end=t_end)
    p = simulate_prescribed(model, move, dt=dt, t_end=t_end, method="poly")
    assert p.info["poly_interp_rel_err"] <= 1e-10
    for name in ("delta", "ddelta"):
        a, b = getattr(p, name), getattr(r, name)
        # a mode the planar move leaves at round-off (out of plane, ~1e-17) is held to the
        # round-off of 800 steps of the largest one: eps · 800 ≈ 2e-13 = 1e-8 · 2e-5 of
        # its span (the former floor 1e-9 asked 1e-17 of it, below double precision)
        span = np.maximum(np.ptp(b, axis=0), 2e-5 * np.ptp(b, axis=0).max())
        # 1e-8: the 1e-10 interpolation error grown by the 800 steps (as for the
        # first-order model in test_simulate)
        assert np.all(np.abs(a - b).max(axis=0) <= 1e-8 * span), name
    assert np.abs(p.tau - r.tau).max() <= 1e-8 * np.abs(r.tau).max()
    np.testing.assert_allclose(p.tip, r.tip, rtol=0, atol=1e-9)


@pytest.mark.slow
def test_poly_with_foreshortening_on_move3(models):
    """Table 9 move 3 (q1 turns by π; shapes constant): the centrifugal stiffening is the
    only foreshortening term, and poly follows RK4 through it."""
    model = models["free"]
    move = load_move("problems/moves.toml:move3")
    assert reference_sampler(move, 3)[0](np.array([1.0]))[1][0, 0] != 0.0
    r = simulate_prescribed(model, move, dt=2e-3, t_end=2.5)
    p = simulate_prescribed(model, move, dt=2e-3, t_end=2.5, method="poly")
    np.testing.assert_allclose(p.tip, r.tip, rtol=0, atol=1e-9)
    assert np.abs(p.tau - r.tau).max() <= 1e-8 * np.abs(r.tau).max()
