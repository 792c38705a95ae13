"""Orders of accuracy of the integration pieces the simulators share, against analytic
solutions: the one RK4 step (casflex.simulate.integrators.rk4_step, with the input at the
stage times) and the cubic Hermite interpolation of a sampled reference
(casflex.moves.reference_sampler)."""

from __future__ import annotations

import numpy as np
import pytest

from casflex.moves import reference_sampler
from casflex.simulate.integrators import rk4_step


def _rk4_error(h):
    # x' = -x + u(t), u = sin t, x(0) = 1: x(t) = 1.5 e^{-t} + (sin t − cos t)/2
    def f(x, u):
        return -x + u

    x, t = 1.0, 0.0
    for _ in range(int(round(1.0 / h))):
        x = rk4_step(f, x, h, np.sin(t), np.sin(t + h / 2), np.sin(t + h))
        t += h
    exact = 1.5 * np.exp(-1.0) + 0.5 * (np.sin(1.0) - np.cos(1.0))
    return abs(x - exact)


def test_rk4_step_with_input_is_fourth_order():
    # halving h divides the global error by 2⁴ = 16 as h → 0 (17.0, 16.5 measured at
    # these h, 17.4, 16.7 below); a second- or third-order slip gives 4 or 8
    e = [_rk4_error(h) for h in (0.1, 0.05, 0.025)]
    ratios = np.array(e[:-1]) / np.array(e[1:])
    assert np.all((ratios > 14.0) & (ratios < 18.5)), ratios


def test_rk4_step_without_input_is_fourth_order():
    def err(h):
        x = 1.0
        for _ in range(int(round(1.0 / h))):
            x = rk4_step(lambda y: -2.0 * y, x, h)
        return abs(x - np.exp(-2.0))

    e = [err(h) for h in (0.1, 0.05, 0.025)]
    ratios = np.array(e[:-1]) / np.array(e[1:])
    assert np.all((ratios > 14.0) & (ratios < 18.5)), ratios


@pytest.mark.parametrize("h", [0.1, 0.05])
def test_sampled_reference_hermite_interpolation(h):
    # samples of q = sin t (dq, ddq exact): between samples q is the cubic Hermite
    # interpolant, error <= h⁴/384 max|q⁗| = h⁴/384; dq is Hermite on (dq, ddq), the same
    # bound; ddq is linear, error <= h²/8 max|q⁗|
    t_ref = np.arange(0.0, 2.0 + h / 2, h)
    sampler = reference_sampler((t_ref, np.sin(t_ref), np.cos(t_ref), -np.sin(t_ref)), 1)
    t = np.linspace(0.0, 2.0, 1001)
    q, dq, ddq = (a.ravel() for a in sampler.sample(t))
    assert np.abs(q - np.sin(t)).max() <= h**4 / 384 * (1 + 1e-6)
    assert np.abs(dq - np.cos(t)).max() <= h**4 / 384 * (1 + 1e-6)
    assert np.abs(ddq + np.sin(t)).max() <= h**2 / 8 * (1 + 1e-6)
    # and at the samples themselves, the samples
    q_s, dq_s, _ = (a.ravel() for a in sampler.sample(t_ref))
    np.testing.assert_allclose(q_s, np.sin(t_ref), rtol=0, atol=1e-15)
    np.testing.assert_allclose(dq_s, np.cos(t_ref), rtol=0, atol=1e-15)
