"""The restructured TMM kernels give the same numbers (issue 17 part 2).

* ``beam_field`` (per-beam constants, one gather into the 12 × 12 layout) against an
  independent reference: the field equations of the module docstring written here as a
  first-order system ``z' = A(ω) z`` and solved by ``scipy.linalg.expm(A s)``.
* ``modes`` (one stack for the roots and the shapes) against the two public steps it
  replaces, ``natural_frequencies`` then ``mode_shapes``: identical, bit for bit, on random
  configurations.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from casflex.robot import load
from casflex.tmm import (
    MODE_FIELDS,
    beam_field,
    build_chain,
    count_below,
    frequency_determinant,
    mode_shapes,
    modes,
    natural_frequencies,
)


def field_matrix(omega, EA, EIx, EIy, GJ, rho_A, rho_Ip):
    """A(ω) of z = [u, θ, M, F]: u' = θ × e_z + e_z F_z/EA, θ' = (M_x/EIx, M_y/EIy, M_z/GJ),
    M' = −e_z × F − ω² ρIp θ_z e_z, F' = −ω² ρA u."""
    A = np.zeros((12, 12))
    A[0, 4], A[1, 3], A[2, 11] = 1.0, -1.0, 1.0 / EA
    A[3, 6], A[4, 7], A[5, 8] = 1.0 / EIx, 1.0 / EIy, 1.0 / GJ
    A[6, 10], A[7, 9], A[8, 5] = 1.0, -1.0, -omega**2 * rho_Ip
    A[9, 0] = A[10, 1] = A[11, 2] = -omega**2 * rho_A
    return A


@pytest.mark.parametrize("seed", range(6))
def test_beam_field_is_the_exponential_of_the_field_equations(seed):
    rng = np.random.default_rng(seed)
    # stiffnesses and masses around the Table 8 link (EA 2.4e6 N, EI 5–10 N m², GJ 4.4
    # N m², ρA 0.09 kg/m, ρIp 6e-7 kg m), each spread over a decade
    EA, EIx, EIy, GJ = (v * 10 ** rng.uniform(-0.5, 0.5) for v in (2.4e6, 5.0, 10.0, 4.4))
    rho_A, rho_Ip = (v * 10 ** rng.uniform(-0.5, 0.5) for v in (0.0945, 5.8e-7))
    s = rng.uniform(0.05, 1.0, 4)
    omega = rng.uniform(0.5, 200.0, 4)   # λs ≤ 7: cosh ≤ 600, expm stays accurate
    U = beam_field(s, omega, EA, EIx, EIy, GJ, rho_A, rho_Ip)
    for i in range(s.size):
        ref = scipy.linalg.expm(field_matrix(omega[i], EA, EIx, EIy, GJ, rho_A, rho_Ip)
                                * s[i])
        # entries span 1e-7 (s/EA) to 1e3 (λ³T·EI): compare each column block against its
        # own scale; expm's error is ~1e-13 of ‖A s‖-weighted entries, the closed forms
        # are exact up to round-off (a few ulp of cosh)
        scale = np.abs(ref).max(axis=0, keepdims=True)
        assert np.all(np.abs(U[i] - ref) <= 1e-10 * scale + 1e-300)


def test_beam_field_static_limit_is_the_exponential_too():
    # ω = 0 takes the closed forms' static branch (T/λ → s, ...)
    args = (2.4e6, 5.0, 10.0, 4.4, 0.0945, 5.8e-7)
    U = beam_field(0.7, 0.0, *args)
    ref = scipy.linalg.expm(field_matrix(0.0, *args) * 0.7)
    scale = np.abs(ref).max(axis=0, keepdims=True)
    assert np.all(np.abs(U - ref) <= 1e-12 * scale)


@pytest.fixture(scope="module")
def arm():
    return load("problems/arm2link.toml")


@pytest.mark.parametrize("seed", range(4))
def test_modes_equals_the_two_public_steps(arm, seed, monkeypatch):
    # on the numpy path; with the compiled kernels modes() poses the chain by its own
    # compiled walk (round-off apart from build_chain): test_tmm_prepared.py compares those
    from casflex.tmm import kernels
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    q = np.random.default_rng(100 + seed).uniform(-np.pi, np.pi, 3)
    shapes = modes(arm, q, count=5)
    chain = build_chain(arm, q)
    w, mult = natural_frequencies(chain, count=5, return_multiplicity=True)
    reference = mode_shapes(chain, w, mult, n_points=51)
    np.testing.assert_array_equal(shapes.omega, reference.omega)
    for name in MODE_FIELDS:
        np.testing.assert_array_equal(getattr(shapes, name), getattr(reference, name))


# ----------------------------------------------------------------- compiled kernels


def both(monkeypatch, compute):
    """``compute()`` with the compiled kernels and with the numpy path."""
    from casflex.tmm import kernels
    if not kernels.AVAILABLE:
        pytest.skip("numba is not installed: only the numpy path runs")
    compiled = compute()
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    reference = compute()
    monkeypatch.undo()
    return compiled, reference


@pytest.mark.parametrize("name", ["arm2link", "testbed", "arm2link_actuated"])
def test_kernels_equal_the_numpy_path(name, monkeypatch):
    robot = load(f"problems/{name}.toml")
    rng = np.random.default_rng(7)
    for q in rng.uniform(-np.pi, np.pi, (4, robot.n_joints)):
        chain = build_chain(robot, q)
        # up to 10x the lowest modes' range (λL ≤ 6 on these links, cosh λL ≤ 200)
        top = 10.0 * natural_frequencies(chain, count=1)[0]
        omega = np.geomspace(1e-2, top, 60) * rng.uniform(0.97, 1.03, 60)
        # the count is an integer: equal wherever no natural frequency lies within
        # round-off of the point (none of these random points does)
        new, old = both(monkeypatch, lambda c=chain, w=omega: count_below(c, w))
        np.testing.assert_array_equal(new, old)
        new, old = both(monkeypatch, lambda c=chain, w=omega: frequency_determinant(c, w))
        np.testing.assert_array_equal(np.sign(new), np.sign(old))
        # same products in another order: the row-scaled determinant (|d| ≤ 6³) agrees
        # to the round-off of the chain product, eps·cosh²(λL) ≈ 1e-11
        np.testing.assert_allclose(new, old, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", ["arm2link", "testbed"])
def test_roots_and_shapes_with_and_without_kernels(name, monkeypatch):
    robot = load(f"problems/{name}.toml")
    for q in np.random.default_rng(11).uniform(-np.pi, np.pi, (4, robot.n_joints)):
        new, old = both(monkeypatch, lambda q=q: modes(robot, q, count=5))
        np.testing.assert_array_equal(new.multiplicity, old.multiplicity)
        # Brent (compiled) and batched subdivision + inverse cubic interpolation (numpy)
        # both refine to ~1e-13 from determinants equal to round-off
        np.testing.assert_allclose(new.omega, old.omega, rtol=1e-11)
        # the scaling makes the largest displacement +1; a mode whose largest |entry| is
        # reached twice with opposite signs (to round-off) may come out with either sign
        m_count = old.displacement.shape[0]
        flip = np.sign(np.sum(new.displacement.reshape(m_count, -1)
                              * old.displacement.reshape(m_count, -1), axis=1))
        for m in np.flatnonzero(flip < 0):
            flat = old.displacement[m].ravel()
            assert abs(flat.max() + flat.min()) < 1e-8, f"mode {m} flipped without a tie"
        for field in MODE_FIELDS:
            a, b = getattr(new, field), getattr(old, field)
            a = a * flip.reshape((-1,) + (1,) * (a.ndim - 1))
            # unit-peak shapes from null vectors of subU at roots that differ by 1e-11:
            # the shapes move by that times the null space's sensitivity; 1e-8 of each
            # field's largest entry
            scale = np.abs(b).max() if b.size else 1.0
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-8 * scale, err_msg=field)


@pytest.mark.parametrize("name", ["arm2link", "testbed", "arm2link_actuated"])
def test_compiled_search_equals_the_numpy_search(name, monkeypatch):
    # the whole root search in one compiled call (grid counts, bisection, Brent, the grid
    # extension, count and omega_max limits) against the numpy path's search
    from casflex.tmm import sweep_frequencies
    robot = load(f"problems/{name}.toml")
    qs = np.random.default_rng(3).uniform(-np.pi, np.pi, (6, robot.n_joints))
    new, old = both(monkeypatch, lambda: sweep_frequencies(robot, qs, 6))
    # Brent (compiled) vs subdivision + inverse cubic interpolation (numpy), both on
    # determinants equal to round-off, as in test_roots_and_shapes_with_and_without_kernels
    np.testing.assert_allclose(new, old, rtol=1e-11)
    chain = build_chain(robot, qs[0])
    top = 0.5 * (old[0, 4] + old[0, 5])  # between the 5th and 6th frequency
    for kwargs in ({"omega_max": top}, {"count": 3, "omega_max": top}):
        (wn, mn), (wo, mo) = both(monkeypatch, lambda kw=kwargs: natural_frequencies(
            chain, return_multiplicity=True, **kw))
        np.testing.assert_array_equal(mn, mo)
        np.testing.assert_allclose(wn, wo, rtol=1e-11)
    assert natural_frequencies(chain, omega_max=top).size == 5
