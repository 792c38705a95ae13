"""The exact-kinematics rows truncated at degree p in δ (casflex/simulate/exact_taylor.py):
what a ``poly`` form of ``kinematics="exact"`` would integrate (issue 19).

The references are independent of the truncation's construction (derivatives along the
ray through the state): the exact model's own rows (``functions()["dddelta"]``), models
whose rows are polynomials of a known degree in δ, and the model's RK4 simulation.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.simulate import simulate_prescribed, simulate_taylor, taylor_modal_rows

Q = np.array([0.1, 0.3, -0.8])  # in- and out-of-plane modes (test_exact_kinematics.py)
RNG = np.random.default_rng(1955)


@pytest.fixture(scope="module")
def exact(arm):
    """The exact kinematics on two modes frozen at ``Q``, gravity on (its δ-terms too)."""
    return FlexibleModel(arm, PointwiseProvider(arm, Q, count=2), kinematics="exact")


def _state():
    return (Q, RNG.normal(0.0, 1.0, 3), RNG.normal(0.0, 3.0, 3))


@pytest.mark.slow  # three graphs of the exact rows' ray derivatives: ~10 s of CPU
def test_truncation_error_falls_as_the_next_power(exact):
    """The degree-p rows differ from the exact ones by O(|δ|^(p+1)): halving δ (along a
    fixed direction, δ̇ fixed) divides the difference by 2^(p+1). δ from 0.02 to 0.005
    √kg m (tip deflections of ~1-4 cm, rotations of ~0.01-0.05 rad, where the series'
    next term is a few % of the leading one): the ratio within 2^(p+1) x/÷ 1.3."""
    f = exact.functions()["dddelta"]
    q, dq, ddq = _state()
    u, v = RNG.normal(0.0, 1.0, 2), RNG.normal(0.0, 1.0, 2)
    u /= np.linalg.norm(u)
    for p in (1, 2, 3):
        fp = taylor_modal_rows(exact, p)
        errors = [np.linalg.norm((fp(q, dq, ddq, s * u, v) - f(q, dq, ddq, s * u, v)).full())
                  for s in (0.02, 0.01, 0.005)]
        for big, small in zip(errors[:-1], errors[1:], strict=True):
            assert 2 ** (p + 1) / 1.3 < big / small < 2 ** (p + 1) * 1.3, (p, errors)
        # at δ = 0 every degree is the exact rows (to the rounding of the solve)
        at_rest = (fp(q, dq, ddq, 0 * u, v) - f(q, dq, ddq, 0 * u, v)).full()
        assert np.abs(at_rest).max() < 1e-12 * np.abs(f(q, dq, ddq, 0 * u, v).full()).max()


def test_a_foreshortening_model_is_reproduced_from_degree_one(arm):
    """``foreshortening=True`` keeps M_qq and the gravity potential to δ² (the rest of M
    affine). Its modal rows are nevertheless affine in δ: M_qq enters them through
    ``−½ q̇ᵀ ∂M_qq/∂δ q̇`` (linear in δ: the geometric stiffening) and gravity through
    ``∂V/∂δ`` (linear too). So degree 1 gives them, and degree 2 as well, to rounding,
    though the ray's second derivative of M_qq is not zero."""
    model = FlexibleModel(arm, PointwiseProvider(arm, Q, count=2), foreshortening=True)
    f = model.functions()["dddelta"]
    q, dq, ddq = _state()
    d, v = RNG.normal(0.0, 0.05, 2), RNG.normal(0.0, 1.0, 2)
    exact = f(q, dq, ddq, d, v).full()
    for p in (1, 2):
        rows = taylor_modal_rows(model, p)(q, dq, ddq, d, v).full()
        assert np.abs(rows - exact).max() < 1e-11 * np.abs(exact).max()
    # the default model without the option differs by the stiffening (first order in δ)
    plain = FlexibleModel(arm, PointwiseProvider(arm, Q, count=2)).functions()["dddelta"]
    assert np.abs(plain(q, dq, ddq, d, v).full() - exact).max() > 1e-6 * np.abs(exact).max()


@pytest.mark.slow  # two RK4 runs of 300 steps on the ray derivatives, ~30 s of CPU
def test_simulation_within_the_row_error_bound(exact):
    """Degree 2 and 3 against RK4 on the exact rows (same model, same steps) on a quick
    turn of q1 (the shapes stay put, ``M_δδ`` stays the identity to 1e-4). Bound: a row
    error ``e_j(t)`` moves mode j, an oscillator of frequency ``ω_j``, by at most
    ``∫|e_j| dt / ω_j`` (Duhamel); ``e_j`` is taken along the exact run, its largest value
    times the run's length, doubled for the error's own feedback and ``M_δδ``'s 1e-4."""
    move = Move(np.zeros(3), [-1.0, 0.0, 0.0], 0.4, settle=0.2)
    dt = 2e-3
    ref = simulate_prescribed(exact, move, dt=dt)
    f = exact.functions()["dddelta"]
    omega = exact.functions()["stiffness"](ref.q[0]).full().diagonal() ** 0.5
    errors = {}
    for p in (2, 3):
        fp = taylor_modal_rows(exact, p)
        rows = [(fp(*x) - f(*x)).full().ravel() for x in zip(
            ref.q, ref.dq, ref.ddq, ref.delta, ref.ddelta, strict=True)]
        bound = 2.0 * ref.t[-1] * np.abs(rows).max(axis=0) / omega
        run = simulate_taylor(exact, move, p, dt=dt)
        errors[p] = np.abs(run["delta"] - ref.delta).max(axis=0)
        assert np.all(errors[p] <= bound), (p, errors[p], bound)
    assert np.all(errors[3] < errors[2])


@pytest.mark.parametrize("order", [0, 6, 1.5, True])
def test_order_checked(arm, order):
    model = FlexibleModel(arm, PointwiseProvider(arm, Q, count=1), gravity=None)
    with pytest.raises(ModelError, match="order must be an integer from 1 to 5"):
        taylor_modal_rows(model, order)
