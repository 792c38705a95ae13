"""Simulation (casflex.simulate) against independent references.

* q held constant: each modal amplitude oscillates at the TMM natural frequency of that
  configuration (casflex.tmm.modes, not the tables);
* torque-driven RK4 at 1 ms against scipy's DOP853 (rtol 1e-11) on the model's ``ode``;
  prescribed RK4 against DOP853 on the model's ``prescribed`` function;
* energy balance in free motion (τ = 0, no damping, no gravity);
* Table 9 moves on the Table 8 arm (coarse grid, 2 modes): deflections of the expected
  order, planar move 2, move 3 with constant shape joint and constant mass matrix;
* a shaped reference (casflex.shaping.apply_shaper) reduces the residual vibration;
* the CLI JSON contract and its errors.

Coarse grids (7.5°) and few modes keep the module fast.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from casflex.errors import ModelError
from casflex.model import ConstantProvider, FlexibleModel, PointwiseProvider
from casflex.moves import Move, load_move, reference_sampler
from casflex.robot import load
from casflex.simulate import (
    SimulationResult,
    chebyshev,
    poly,
    simulate_prescribed,
    simulate_torque,
)
from casflex.simulate.integrators import STEP_CACHE

try:
    import regression_pins as pins
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests import regression_pins as pins

ARM = load("problems/arm2link.toml")


@pytest.fixture(scope="module")
def arm2(arm_model):
    """Table 8 arm, 2 tracked modes on a 7.5° grid of q3, gravity neglected (§3.3.7.1)."""
    model, table = arm_model(2, step_deg=7.5, gravity=None)
    return model, table


def _with_motors(robot, inertia=0.01):
    links = list(robot.links)
    for row in robot.joint_rows:
        links[row] = dataclasses.replace(links[row], motor_inertia=inertia)
    return dataclasses.replace(robot, links=tuple(links))


# ------------------------------------------------------------------ frequencies


@pytest.mark.slow
def test_held_joints_oscillate_at_tmm_frequencies(arm2):
    from casflex.tmm import modes

    model, table = arm2
    q3 = table.grid[0][28]  # a grid point (30°): the tables are exact there
    q = np.array([0.3, -0.4, q3])
    omega = modes(ARM, q, count=2).omega
    t = np.arange(0.0, 2.0 + 1e-9, 2e-3)
    ref = (t, np.tile(q, (t.size, 1)), np.zeros((t.size, 3)), np.zeros((t.size, 3)))
    for j in range(2):
        d0 = np.zeros(2)
        d0[j] = 1e-4  # small: the quadratic terms of the modal rows stay negligible
        r = simulate_prescribed(model, ref, dt=2e-3, delta0=d0)
        expected = 1e-4 * np.cos(omega[j] * r.t)
        np.testing.assert_allclose(r.delta[:, j], expected, atol=2e-7)
        assert np.abs(r.delta[:, 1 - j]).max() < 1e-8  # modes are decoupled at rest
        # frequency from the zero crossings, independent of the fit above
        s = np.sign(r.delta[:, j])
        idx = np.nonzero(s[1:] != s[:-1])[0]
        tz = r.t[idx] - r.delta[idx, j] * (r.t[idx + 1] - r.t[idx]) / (
            r.delta[idx + 1, j] - r.delta[idx, j])
        w = np.pi / np.mean(np.diff(tz))
        assert w == pytest.approx(omega[j], rel=2e-3)


# ------------------------------------------------------------------ against scipy


def _small_model():
    robot = _with_motors(ARM)
    p = PointwiseProvider(robot, [0.0, 0.0, 0.6], count=2)
    return robot, FlexibleModel(robot, ConstantProvider(p.quantities, (2,)), gravity=None,
                                damping_ratio=0.01, modal_mass="kinematic")


@pytest.mark.slow
def test_torque_rk4_matches_scipy_dop853():
    _, model = _small_model()
    f = model.functions()
    n, m = model.n, model.m
    x0 = np.r_[0.1, -0.2, 0.6, 1e-3, -5e-4, 0.2, 0.0, -0.1, 0.0, 0.02]
    tau = np.array([0.05, -0.1, 0.02])
    r = simulate_torque(model, tau, x0, t_end=0.5, dt=1e-3)

    def rhs(_, x):
        return f["ode"](x, tau).full().ravel()

    ref = solve_ivp(rhs, (0.0, 0.5), x0, method="DOP853", rtol=1e-11, atol=1e-13,
                    t_eval=r.t)
    X = np.hstack([r.q, r.delta, r.dq, r.ddelta])
    scale = np.abs(ref.y.T).max(axis=0) + 1e-12
    # stated tolerance: 1e-6 of each state's range (RK4 at 1 ms, modes at 8–12 rad/s)
    assert np.max(np.abs(X - ref.y.T) / scale) < 1e-6
    assert np.allclose(r.tau, tau)
    assert r.delta.shape == (501, m) and r.q.shape == (501, n)
    rc = simulate_torque(model, lambda t, x: tau, x0, t_end=0.1, dt=1e-2, method="cvodes")
    k = np.searchsorted(ref.t, rc.t)
    Xc = np.hstack([rc.q, rc.delta, rc.dq, rc.ddelta])
    assert np.max(np.abs(Xc - ref.y.T[k]) / scale) < 1e-6


@pytest.mark.slow
def test_prescribed_rk4_and_cvodes_match_scipy_dop853(arm2):
    model, _ = arm2
    f = model.functions()
    m = model.m
    move = Move([0.0, 0.2, 0.1], [-0.3, -0.1, 0.4], duration=0.4, settle=0.2)
    r = simulate_prescribed(model, move, dt=1e-3)

    def rhs(t, z):
        q, dq, ddq = move.sample(t)
        return np.r_[z[m:], f["prescribed"](q, dq, ddq, z[:m], z[m:])[1].full().ravel()]

    z = np.zeros(2 * m)
    parts = []
    for a, b in [(0.0, 0.2), (0.2, 0.4), (0.4, 0.6)]:  # the bang-bang switches
        t_eval = r.t[(r.t >= a - 1e-12) & (r.t <= b + 1e-12)]
        sol = solve_ivp(rhs, (a, b), z, method="DOP853", rtol=1e-11, atol=1e-14,
                        t_eval=t_eval)
        parts.append(sol.y.T if not parts else sol.y.T[1:])
        z = sol.y[:, -1]
    Z = np.vstack(parts)
    scale = np.abs(Z).max(axis=0)
    assert np.max(np.abs(np.hstack([r.delta, r.ddelta]) - Z) / scale) < 1e-5
    # the torques are those of the model's prescribed function on the solution
    k = 250
    tau = f["prescribed"](r.q[k], r.dq[k], r.ddq[k], Z[k, :m], Z[k, m:])[0].full().ravel()
    np.testing.assert_allclose(r.tau[k], tau, rtol=1e-5, atol=1e-9)
    rc = simulate_prescribed(model, move, dt=1e-3, method="cvodes")
    assert np.max(np.abs(rc.delta - Z[:, :m]) / scale[:m]) < 1e-5


@pytest.mark.slow
def test_free_motion_energy_balance():
    robot, _ = _small_model()
    p = PointwiseProvider(robot, [0.0, 0.0, 0.6], count=2)
    model = FlexibleModel(robot, ConstantProvider(p.quantities, (2,)), gravity=None,
                          damping_ratio=0.0, modal_mass="kinematic")
    f = model.functions()
    x0 = np.r_[0.0, 0.3, 0.6, 2e-3, -1e-3, 0.4, -0.3, 0.2, 0.0, 0.05]
    r = simulate_torque(model, None, x0, t_end=3.0, dt=1e-3)
    E = f["energy"].map(r.t.size)(r.q.T, r.dq.T, r.delta.T, r.ddelta.T)[2].full().ravel()
    T0 = float(f["energy"](r.q[0], r.dq[0], r.delta[0], r.ddelta[0])[0])
    assert np.max(np.abs(E - E[0])) < 1e-7 * T0
    assert np.ptp(r.delta[:, 0]) > 1e-3  # the modes did move


# ------------------------------------------------------------------ Table 9 moves


@pytest.fixture(scope="module")
def moves(arm2):
    model, _ = arm2
    out = {}
    for name in ("move1", "move2", "move3"):
        out[name] = simulate_prescribed(model, load_move(f"problems/moves.toml:{name}"),
                                        dt=2e-3)
    return out


@pytest.mark.slow
def test_table9_moves_give_centimetre_deflections(moves):
    for name, r in moves.items():
        assert isinstance(r, SimulationResult)
        assert r.t[-1] == pytest.approx(5.0) and r.t_move_end == 2.0
        # 1 m + 1 m aluminium links of 5 x 7 mm, first mode 6.6–8.3 rad/s, 1 rad/s² peak:
        # deflections of centimetres to decimetres (quasi-static a_tip / ω² ≈ 3 cm)
        assert 5e-3 < r.max_tip_deflection < 0.5, name
        assert 0.0 < r.residual_tip_deflection <= r.max_tip_deflection
        # casflex's own values, regression pins (tests/regression_pins.py)
        np.testing.assert_allclose(
            (r.max_tip_deflection, r.residual_tip_deflection),
            pins.TABLE9_TIP_DEFLECTION[name], rtol=pins.TABLE9_TIP_DEFLECTION_RTOL)
        np.testing.assert_allclose(r.tip_deflection, r.tip - r.tip_rigid)
        d = r.to_dict()
        assert json.loads(json.dumps(d))["max_tip_deflection"] == r.max_tip_deflection


@pytest.mark.slow
def test_move2_is_planar(moves):
    r = moves["move2"]
    # q1 = 0: the arm moves in the x-z plane of the base; deflections stay in it
    assert np.abs(r.tip[:, 1]).max() < 1e-9
    assert np.abs(r.tip_deflection[:, [0, 2]]).max() > 1e-3


@pytest.mark.slow
def test_move3_keeps_the_tables_constant(arm2, moves):
    model, table = arm2
    r = moves["move3"]
    assert table.shape_joints == (2,)
    # the shape-joint input of the tables does not move, so neither do ω(q) and M's
    # table-dependent entries (M does not depend on q1, which moves)
    assert np.ptp(r.q[:, 2]) == 0.0 and np.ptp(r.q[:, 0]) > 3.0
    f = model.functions()
    N = r.t.size
    K = f["stiffness"].map(N)(r.q.T).full().reshape(model.m, N, model.m)
    assert np.ptp(K, axis=1).max() == 0.0
    M0 = f["mass"].map(N)(r.q.T, np.zeros((model.m, N))).full().reshape(5, N, 5)
    assert np.ptp(M0, axis=1).max() < 1e-12 * np.abs(M0).max()
    # rotation about the vertical axis: the deflection is mostly horizontal (the modes
    # of the L-shaped arm couple some vertical bending of link 1)
    assert np.abs(r.tip_deflection[:, 2]).max() < 0.3 * np.abs(r.tip_deflection[:, :2]).max()


@pytest.mark.slow
def test_shaped_reference_reduces_residual_vibration(arm2, moves):
    from casflex.shaping import apply_shaper, convolve, zv

    model, _ = arm2
    move = load_move("problems/moves.toml:move3")
    omega = model.functions()["stiffness"](move.q0).full().diagonal() ** 0.5
    t = np.arange(0.0, 2.0 + 1e-9, 2e-3)
    q, dq, ddq = move.sample(t)
    shaped = apply_shaper(convolve(zv(omega[0]), zv(omega[1])), t, q, dq, ddq)
    assert shaped[0][-1] > t[-1]  # the shaped reference is longer
    r = simulate_prescribed(model, shaped, dt=2e-3, t_end=5.0)
    assert r.t_move_end == pytest.approx(shaped[0][-1], abs=2.1e-3)
    assert r.residual_tip_deflection < 0.1 * moves["move3"].residual_tip_deflection


def test_errors(arm2):
    model, _ = arm2
    with pytest.raises(ModelError, match="2 joints"):
        simulate_prescribed(model, Move([0.0, 0.0], [1.0, 1.0], 1.0))
    with pytest.raises(ModelError, match="method"):
        simulate_prescribed(model, load_move("problems/moves.toml:move1"), method="euler")
    with pytest.raises(ModelError, match="dt"):
        simulate_prescribed(model, load_move("problems/moves.toml:move1"), dt=-1.0)
    with pytest.raises(ModelError, match="x0"):
        simulate_torque(model, None, np.zeros(3), t_end=1.0)


def test_casadi_controller_runs_in_one_call():
    _, model = _small_model()
    n, m = model.n, model.m
    t = ca.SX.sym("t")
    x = ca.SX.sym("x", 2 * (n + m))
    # joint PD towards q = [0.2, 0, 0.6]
    u = -2.0 * (x[:n] - ca.DM([0.2, 0.0, 0.6])) - 0.5 * x[n + m:2 * n + m]
    ctrl = ca.Function("pd", [t, x], [u])
    x0 = np.r_[0.0, 0.0, 0.6, np.zeros(m), np.zeros(n + m)]
    r1 = simulate_torque(model, ctrl, x0, t_end=0.2, dt=2e-3)
    r2 = simulate_torque(model, lambda tt, xx: ctrl(tt, xx).full().ravel(), x0, t_end=0.2,
                         dt=2e-3)
    np.testing.assert_allclose(r1.q, r2.q, atol=1e-12)
    np.testing.assert_allclose(r1.tau, r2.tau, atol=1e-12)
    # an impulse-like disturbance on the first mode moves the modes
    r3 = simulate_torque(model, lambda tt, xx: np.zeros(n), x0, t_end=0.1, dt=1e-3,
                         disturbance=lambda tt: np.r_[0, 0, 0, 1.0 if tt < 0.005 else 0, 0])
    assert np.abs(r3.delta[:, 0]).max() > 1e-6


# ------------------------------------------------------------------ CLI


def _cli(argv):
    from casflex.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_cli_json_contract(tmp_path):
    rc, out, err = _cli(["simulate", "problems/arm2link.toml", "--move",
                         "problems/moves.toml:move3", "--modes", "1", "--dt", "0.01",
                         "--step", "15deg", "--cache-dir", str(tmp_path), "--json",
                         "--plot", str(tmp_path / "sim.png")])
    assert rc == 0, err
    assert out.count("\n") == 1
    data = json.loads(out)
    assert set(data) == {"t_end", "max_tip_deflection", "residual_tip_deflection",
                         "torque_peak"}
    assert data["t_end"] == pytest.approx(5.0)
    assert 0.0 < data["residual_tip_deflection"] <= data["max_tip_deflection"] < 0.5
    assert len(data["torque_peak"]) == 3 and data["torque_peak"][0] > 0.0
    assert (tmp_path / "sim.png").stat().st_size > 0


@pytest.mark.slow
@pytest.mark.needs_cc
def test_cli_poly_jit_equals_rk4(tmp_path):
    """``--method poly --jit``: compiled fast path, same figures as RK4; the library goes
    into the cache directory; ``--jit`` needs ``--method poly``."""
    common = ["simulate", "problems/arm2link.toml", "--move", "problems/moves.toml:move1",
              "--modes", "1", "--dt", "0.005", "--step", "15deg", "--cache-dir",
              str(tmp_path), "--json"]
    rc, out, err = _cli([*common, "--method", "rk4"])
    assert rc == 0, err
    rk4 = json.loads(out)
    rc, out, err = _cli([*common, "--method", "poly", "--jit"])
    assert rc == 0, err
    fast = json.loads(out)
    for key in ("max_tip_deflection", "residual_tip_deflection"):
        assert fast[key] == pytest.approx(rk4[key], rel=1e-8)
    assert fast["torque_peak"] == pytest.approx(rk4["torque_peak"], rel=1e-8)
    assert len(list((tmp_path / "jit").glob("casflex_poly_F-*/libcasflex_poly_F.*"))) == 1
    rc, out, err = _cli([*common, "--method", "rk4", "--jit"])
    assert rc == 2 and out == "" and "--jit" in err and "--method poly" in err


def test_cli_errors(tmp_path):
    rc, out, err = _cli(["simulate", "problems/arm2link.toml", "--move",
                         "problems/moves.toml:nosuchmove", "--json"])
    assert rc == 2 and out == "" and "nosuchmove" in err
    moves = tmp_path / "m.toml"
    moves.write_text("[two]\nduration = 1.0\nq0 = [0.0, 0.0]\nqf = [1.0, 1.0]\n")
    rc, out, err = _cli(["simulate", "problems/arm2link.toml", "--move", f"{moves}:two",
                         "--json"])
    assert rc == 2 and out == "" and "2 joint values" in err and "3 joints" in err


# ------------------------------------------------------------------ method="poly"


@pytest.fixture(scope="module")
def small3(arm_model):
    """Table 8 arm, 3 modes on a 15° grid (the table knots are crossed by move 1)."""
    models = {}
    for key, gravity in (("free", None), ("gravity", "robot")):
        models[key] = arm_model(3, step_deg=15, gravity=gravity)[0]
    return models


def _poly_ddelta_tau(model, raw, dq, ddq, d, v, dd):
    """δ̈ from the polynomial/affine form and τ from the configuration arrays ``raw``
    (one row of F)."""
    n, m = model.n, model.m
    A = poly.unpack(raw, n, m, dq[None])
    rows = poly.rows(A, dq[None], n, m, model.damping_ratio)
    coef = poly.modal(rows, ddq[None])[0]
    stage, _ = poly.stage(m)
    ddd = stage(coef, np.r_[d, v]).full().ravel()[m:]
    tau = poly.torque(poly.torque_rows(rows, ddq[None]), n, m, d[None], v[None],
                      dd[None])[0]
    return ddd, tau


@pytest.mark.parametrize("key", ["free", "gravity"])
def test_poly_form_reproduces_the_model_rows(small3, key):
    """At random (t, δ, δ̇) on move 1 the affine M_δδ and the quadratic r give the model's
    δ̈ (`prescribed_dddelta`), and the configuration arrays give its torques — with F
    evaluated exactly and with F interpolated in time (Chebyshev pieces)."""
    model = small3[key]
    f = model.functions()
    F = poly.configuration_function(model)
    move = load_move("problems/moves.toml:move1")
    sampler = reference_sampler(move, model.n)[0]
    breaks = chebyshev.breaks(model, move, sampler, 0.0, move.t_end)
    pieces, err, _, _ = chebyshev.interpolants(F, sampler, breaks, 1e-10)
    assert err <= 1e-10
    rng = np.random.default_rng(7)
    for t in rng.uniform(0.0, move.duration, 6):
        q, dq, ddq = (a[0] for a in sampler(np.array([t])))
        d, v = rng.normal(0.0, 0.03, model.m), rng.normal(0.0, 0.3, model.m)
        tau_ref, dd_ref = (x.full().ravel() for x in f["prescribed"](q, dq, ddq, d, v))
        dd_model = f["dddelta"](q, dq, ddq, d, v).full().ravel()
        np.testing.assert_allclose(dd_model, dd_ref, rtol=0, atol=1e-14)
        dd, tau = _poly_ddelta_tau(model, chebyshev.evaluate(F, np.atleast_2d(q)), dq, ddq, d, v,
                                   dd_ref)
        scale_d, scale_t = np.abs(dd_ref).max(), np.abs(tau_ref).max()
        assert np.abs(dd - dd_ref).max() <= 1e-10 * scale_d
        assert np.abs(tau - tau_ref).max() <= 1e-10 * scale_t
        # the interpolated arrays at the same time
        i = int(np.searchsorted([p[0] for p in pieces], t, side="right")) - 1
        raw = chebyshev.values_at(pieces, [p[4] for p in pieces], np.array([t]), np.array([i]))
        dd_i, tau_i = _poly_ddelta_tau(model, raw, dq, ddq, d, v, dd_ref)
        assert np.abs(dd_i - dd_ref).max() <= 1e-8 * scale_d
        assert np.abs(tau_i - tau_ref).max() <= 1e-8 * scale_t


def test_poly_piece_choice_at_breaks():
    """At a break the piece follows the reference's side; a break that misses the
    reference's switch by round-off still gets the piece with the reference's q̈."""
    tn, w = chebyshev.chebyshev_nodes(0.0, 1.0, 2)
    pieces = [(0.0, 1.0, tn, w, None), (1.0, 2.0, tn + 1.0, w, None)]
    acc = np.array([[1.0], [-1.0]])
    t = np.array([0.5, 1.0, 1.0, 1.0 - 1e-15, 1.0 + 1e-15, 1.5])
    ddq = np.array([[1.0], [-1.0], [1.0], [-1.0], [1.0], [-1.0]])
    assert chebyshev.piece_index(pieces, t[:2], ddq[:2], acc).tolist() == [0, 1]
    assert chebyshev.piece_index(pieces, t[2:3], ddq[2:3], acc, left=True).tolist() == [0]
    assert chebyshev.piece_index(pieces, t[3:], ddq[3:], acc).tolist() == [1, 0, 1]


def _compare_poly_rk4(model, reference, dt, t_end):
    r = simulate_prescribed(model, reference, dt=dt, t_end=t_end)
    p = simulate_prescribed(model, reference, dt=dt, t_end=t_end, method="poly")
    assert p.method == "poly" and p.info["poly_interp_rel_err"] <= 1e-10
    np.testing.assert_array_equal(p.t, r.t)
    for name in ("delta", "ddelta"):
        a, b = getattr(p, name), getattr(r, name)
        # modes that stay at round-off level (out-of-plane modes of a planar move) are
        # compared on the scale of the largest mode
        span = np.maximum(np.ptp(b, axis=0), 1e-9 * np.ptp(b, axis=0).max())
        assert np.all(np.abs(a - b).max(axis=0) <= 1e-8 * span), name
    assert np.abs(p.tau - r.tau).max() <= 1e-8 * np.abs(r.tau).max()
    np.testing.assert_allclose(p.tip, r.tip, rtol=0, atol=1e-9)
    return r, p


@pytest.mark.slow
def test_poly_matches_rk4_on_move1(small3):
    r, p = _compare_poly_rk4(small3["free"], load_move("problems/moves.toml:move1"),
                             dt=2e-3, t_end=3.0)
    assert p.info["poly_pieces"] >= 5  # three switches and the 15° knots of q3
    assert p.max_tip_deflection == pytest.approx(r.max_tip_deflection, rel=1e-8)


@pytest.mark.slow
def test_poly_matches_rk4_on_a_shaped_move_with_gravity(small3):
    from casflex.moves import ShapedMove
    from casflex.shaping import zv

    model = small3["gravity"]
    move = load_move("problems/moves.toml:move2")
    omega = model.functions()["stiffness"](move.q0).full().diagonal() ** 0.5
    # 0.3 s after a zero-vibration impulse pair: the switches fall between samples
    shaped = ShapedMove(move, zv(float(omega[0]), 0.0))
    assert not np.allclose(shaped.breakpoints / 2e-3, np.round(shaped.breakpoints / 2e-3))
    _compare_poly_rk4(model, shaped, dt=2e-3, t_end=shaped.duration + 0.3)


def test_poly_errors(small3):
    model = small3["free"]
    move = load_move("problems/moves.toml:move1")
    sampled = move.sample(np.linspace(0.0, 2.0, 11))
    with pytest.raises(ModelError, match="Move or ShapedMove"):
        simulate_prescribed(model, (np.linspace(0.0, 2.0, 11), *sampled), method="poly")
    with pytest.raises(ModelError, match="method"):
        simulate_torque(model, None, np.zeros(12), t_end=0.01, method="poly")


@pytest.mark.slow
@pytest.mark.needs_cc
def test_poly_jit_equals_the_virtual_machine(small3, tmp_path):
    """``jit``: F and the RK4 chunk compiled to C give the VM's result to round-off; the
    library is built once and loaded from the on-disk cache afterwards (also by a fresh
    model object, as in another process); other flags build another library."""
    model = small3["gravity"]
    move = load_move("problems/moves.toml:move1")
    vm = simulate_prescribed(model, move, dt=2e-3, t_end=2.0, method="poly")
    c = simulate_prescribed(model, move, dt=2e-3, t_end=2.0, method="poly", jit=("-O0",),
                            cache_dir=tmp_path)
    assert c.info["poly_jit_built"]
    for name in ("delta", "ddelta", "tau"):
        a, b = getattr(c, name), getattr(vm, name)
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max(), name
    STEP_CACHE.clear()  # forget the loaded functions: the next call reads the disk cache
    again = simulate_prescribed(model, move, dt=2e-3, t_end=2.0, method="poly",
                                jit="-O0", cache_dir=tmp_path)  # the same flags
    assert not again.info["poly_jit_built"]
    np.testing.assert_array_equal(again.delta, c.delta)
    libs = sorted(p.name.split("-")[0] for p in (tmp_path / "jit").iterdir())
    assert libs == ["casflex_poly_F", "casflex_poly_rk4"]
    with pytest.raises(ModelError, match="jit"):
        simulate_prescribed(model, move, dt=2e-3, t_end=0.1, jit=True)
    with pytest.raises(ModelError, match="compiler flags"):
        simulate_prescribed(model, move, dt=2e-3, t_end=0.1, method="poly", jit=3)
