"""FlexibleModel with a full modal stiffness block (a rotated, smooth mode basis).

A provider that offers ``stiffness`` (K̃) and ``stiffness_root`` (Ω̃ = sqrtm K̃) makes the
model use ``½ δᵀK̃δ`` and the damping ``2ζ Ω̃``. The references are independent of that
code path: today's diagonal model (the eigen-basis limit), the same model seen through a
constant change of modal coordinates δ' = R δ (a change of coordinates must give the
same motion), and the physics (energy conservation, skew symmetry of Ṁ − 2C).
"""

import dataclasses

import numpy as np
import pytest

from casflex.modal import build_table, rotate_quantities
from casflex.model import ConstantProvider, FlexibleModel, PointwiseProvider, TableProvider
from casflex.robot import load

Q_POINT = [0.0, 0.0, 0.5]


def _rotation(angle):
    """A rotation of the modes 2 and 3 of three into each other, by ``angle`` [rad]."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotated(quantities, R):
    """Quantities of the basis δ' = R δ, with K̃ and Ω̃ built here from the eigen ω."""
    w = np.asarray(quantities["omega"], dtype=float)
    out = rotate_quantities(quantities, R)
    out["stiffness"] = R @ np.diag(w**2) @ R.T
    out["stiffness_root"] = R @ np.diag(w) @ R.T
    out["omega"] = np.sqrt(np.diag(out["stiffness"]))  # Rayleigh frequencies
    return out


@pytest.fixture(scope="module")
def arm():
    return load("problems/arm2link.toml")


@pytest.fixture(scope="module")
def point_quantities(arm):
    return PointwiseProvider(arm, Q_POINT, count=3, shape_joints=(2,)).quantities


def _random_states(rng, n, m, count=4):
    return [(rng.normal(size=2 * (n + m)), rng.normal(size=n)) for _ in range(count)]


def test_eigen_basis_limit_is_todays_model(arm, point_quantities):
    """K̃ = diag(ω²), Ω̃ = diag(ω): the same numbers as the diagonal model."""
    w = point_quantities["omega"]
    full = dict(point_quantities, stiffness=np.diag(w**2), stiffness_root=np.diag(w))
    models = [FlexibleModel(arm, ConstantProvider(p, (2,)), damping_ratio=0.03)
              for p in (point_quantities, full)]
    assert [m.full_stiffness for m in models] == [False, True]
    f = [m.functions() for m in models]
    rng = np.random.default_rng(7)
    for x, tau in _random_states(rng, 3, 3):
        q, d, dq, dd = x[:3], x[3:6], x[6:9], x[9:]
        a, b = (g["ode"](x, tau).full() for g in f)
        assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()
        for name, args in (("energy", (q, dq, d, dd)), ("stiffness", (q,)),
                           ("damping", (q,)), ("potential_forces", (q, d))):
            outs = [g[name](*args) for g in f]
            outs = [o if isinstance(o, tuple) else (o,) for o in outs]
            for u, v in zip(*outs, strict=True):
                u, v = np.asarray(u), np.asarray(v)
                assert np.abs(u - v).max() <= 1e-12 * max(np.abs(u).max(), 1.0), name


def test_a_constant_rotation_is_a_change_of_modal_coordinates(arm, point_quantities):
    """The basis δ' = R δ (R constant, mixing modes of different ω) is the same system:
    ẋ' = T ẋ with T = diag(I, R, I, R), damping included (2ζ R diag(ω) Rᵀ)."""
    R = _rotation(0.7)
    models = [FlexibleModel(arm, ConstantProvider(p, (2,)), damping_ratio=0.05)
              for p in (point_quantities, _rotated(point_quantities, R))]
    f = [m.functions()["ode"] for m in models]
    T = np.zeros((12, 12))
    T[:3, :3] = T[6:9, 6:9] = np.eye(3)
    T[3:6, 3:6] = T[9:, 9:] = R
    rng = np.random.default_rng(11)
    for x, tau in _random_states(rng, 3, 3):
        a = T @ f[0](x, tau).full().ravel()
        b = f[1](T @ x, tau).full().ravel()
        # the kinematics sum the same products in another order: round-off ~1e-14
        assert np.abs(a - b).max() <= 1e-11 * np.abs(a).max()


@pytest.fixture(scope="module")
def turning_basis_model(arm):
    """A table whose pair (modes 2, 3) is rotated by an angle that changes with the elbow
    (2 rad per rad): K̃(q3) is a full, configuration-dependent block, as in a smooth basis
    around a crossing."""
    grid = np.linspace(0.3, 1.0, 11)
    table = build_table(arm, grid, 3, cache_dir=False, processes=1)
    nd = len(table.shape)
    per_point = []
    for i in range(grid.size):
        values = {k: v[i] for k, v in table.values.items()}
        per_point.append(_rotated(values, _rotation(2.0 * (grid[i] - 0.3))))
    values = {k: np.stack([p[k] for p in per_point]) for k in per_point[0]}
    rotated = dataclasses.replace(table, values=values, omega=values["omega"])
    assert np.abs(values["stiffness"][..., 1, 2]).max() > 10.0  # rad²/s²: really coupled
    assert len(rotated.shape) == nd
    return FlexibleModel(arm, TableProvider(rotated), gravity=None, damping_ratio=0.0)


@pytest.mark.slow
def test_energy_is_conserved_with_a_configuration_dependent_stiffness_block(
        turning_basis_model):
    """No damping, no input: T + ½ δᵀK̃(q)δ is a constant of the motion. RK4 conserves it
    to its own order: the drift falls ~2⁴–2⁵ times when the step halves."""
    from casflex.simulate.integrators import rk4_step

    f = turning_basis_model.functions()
    ode, energy = f["ode"], f["energy"]
    tau = np.zeros(3)
    x0 = np.array([0.0, 0.1, 0.6, 0.01, -0.02, 0.015, 0.3, -0.5, 0.6, 0.2, 0.1, -0.3])

    def total(x):
        return float(energy(x[:3], x[6:9], x[3:6], x[9:])[2])

    drift = []
    for dt in (2e-3, 1e-3):
        x = x0.copy()
        for _ in range(int(round(0.25 / dt))):
            x = rk4_step(lambda s: ode(s, tau).full().ravel(), x, dt)
        drift.append(abs(total(x) / total(x0) - 1.0))
    assert 0.1 < x[2] - x0[2] < 0.35  # the elbow moved (K̃(q3) changed), inside the grid
    assert drift[1] < 1e-5
    assert drift[0] / drift[1] > 12.0  # RK4's order (16 to 32), not a drift of the model


@pytest.mark.slow
def test_mdot_minus_two_c_is_skew_symmetric(turning_basis_model):
    """Ṁ − 2C is skew (C from the Christoffel symbols); Ṁ by central differences of M along
    the velocity (error ~h², h = 1e-5: ~1e-9 relative)."""
    f = turning_basis_model.functions()
    rng = np.random.default_rng(3)
    h = 1e-5
    for _ in range(3):
        q = np.array([0.0, 0.2, 0.6]) + 0.1 * rng.normal(size=3)
        d, dq, dd = 0.01 * rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
        X, dX = np.r_[q, d], np.r_[dq, dd]
        Mp = f["mass"]((X + h * dX)[:3], (X + h * dX)[3:]).full()
        Mm = f["mass"]((X - h * dX)[:3], (X - h * dX)[3:]).full()
        Mdot = (Mp - Mm) / (2.0 * h)
        C = f["coriolis"](q, d, dq, dd).full()
        N = Mdot - 2.0 * C
        assert np.abs(N + N.T).max() <= 1e-7 * np.abs(Mdot).max()


def test_poly_refuses_a_full_stiffness_block(arm, point_quantities):
    """poly's stage rows take the stiffness as diag(ω²): with a rotated basis that would be
    the Rayleigh frequencies' diagonal, silently wrong — it must refuse."""
    from casflex.errors import ModelError
    from casflex.moves import Move
    from casflex.simulate import simulate_prescribed

    model = FlexibleModel(arm, ConstantProvider(_rotated(point_quantities, _rotation(0.7)),
                                                (2,)), gravity=None)
    with pytest.raises(ModelError, match="full K̃"):
        simulate_prescribed(model, Move(Q_POINT, [0.1, 0.0, 0.5], 0.5), dt=0.01,
                            method="poly")


def test_consumers_of_the_frequencies_see_a_full_stiffness_block(arm, point_quantities):
    """Consumers that read frequencies take K̃'s eigenvalues or refuse, never the Rayleigh
    diagonal: a frequency-shifted scenario scales K̃ by (1 + r)² (its eigenvalues, the
    natural frequencies, by 1 + r), the EKF's high-pass cutoff is a tenth of the lowest
    natural frequency, and planning (decoupled free vibration at the end) refuses."""
    from casflex.errors import ModelError
    from casflex.estimation.runs import highpass_cutoff
    from casflex.planning import plan_move
    from casflex.planning.scenarios import frequency_shifted_model

    w = np.sort(np.asarray(point_quantities["omega"], dtype=float).ravel())
    R = _rotation(0.7)[[1, 2, 0]][:, [1, 2, 0]]  # modes 1 and 2 mixed: the lowest Rayleigh
    model = FlexibleModel(arm, ConstantProvider(_rotated(point_quantities, R), (2,)),
                          gravity=None)  # frequency lies above the lowest natural one
    assert float(np.min(np.sqrt(np.diag(model.functions()["stiffness"](Q_POINT).full())))) \
        > 1.01 * w[0]
    shifted = frequency_shifted_model(model, 0.1)
    natural = [np.sqrt(np.linalg.eigvalsh(m.functions()["stiffness"](Q_POINT).full()))
               for m in (model, shifted)]
    np.testing.assert_allclose(natural[0], w, rtol=1e-12)
    np.testing.assert_allclose(natural[1], 1.1 * w, rtol=1e-12)
    assert highpass_cutoff(model, Q_POINT) == pytest.approx(w[0] / 10.0, rel=1e-12)
    with pytest.raises(ModelError, match="diagonal modal stiffness"):
        plan_move(model, Q_POINT, [0.1, 0.0, 0.5], torque_limit=1.0, intervals=10)
