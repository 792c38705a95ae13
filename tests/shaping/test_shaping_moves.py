"""Input shaping for planned moves of the Table 8 arm (dissertation §6.1.4–6.1.5).

The dissertation's figures (moves 1–3 of Table 9, three modes, §6.1.5.1):

==========  =====================  =============================  ==========
move        r (eq. 196, normed)    Vtol (eq. 198)                 duration
==========  =====================  =============================  ==========
1           [0.647, 1, 0.13]       [0.078, 0.05, 0.36]            0.87 s
2           [0, 1, 0]              [1, 0.05, 1]                   0.53 s
3           [1, 0, 0.38]           [0.05, 1, 0.13]                0.39 s
==========  =====================  =============================  ==========

casflex gets r = [0.650, 1, 0.132], [0, 1, 0], [1, 0, 0.381] and, from the frequency spans
along the moves without a margin (the dissertation's Table 14 spans; its ±20 % is the
testbed's robustness margin), 0.886, 0.540 and 0.392 s. The small differences come from
the modal model: casflex's frequencies at q = 0 are 8.31, 11.97, 22.75 rad/s against the
dissertation's 8.26, 11.93, 23.37 (its section and tip conventions differ slightly), and
so are the spans (Table 14: 6.64–8.26, 9.36–11.9, 23.36–35.21; casflex: 6.61–8.31,
9.31–11.97, 22.75–34.58 rad/s). Mode numbering is by frequency at the start of the move
and the modes are tracked along it (mode 3 rises from 22.7 to 34.6 rad/s without crossing).

The residual-vibration checks use two models: the decoupled modal model of eq. 194,
``δ̈ + Ω²(q) δ = −M_qδᵀ(q) q̈`` integrated here step by step with casflex's RK4 step
(independent of casflex.simulate's model), and — when it is available — the full model
through ``casflex.simulate.simulate_prescribed``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from regression_pins import (
    ARM2LINK_Q0_OMEGA,
    ARM2LINK_Q0_OMEGA_ATOL,
    SHAPER_DURATION_ATOL,
    SHAPER_DURATION_MARGIN_20,
)
from scipy.integrate import solve_ivp

from casflex.errors import ModelError, ProblemFileError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.shaping import (
    FrequencyRange,
    apply_shaper,
    frequencies_along,
    frequency_ranges_along,
    modal_contributions,
    modal_displacements,
    residual_amplitude,
    residual_vibration,
    shaped_reference,
    shaper_for_move,
    si_shaper,
    tolerances_from_contributions,
    zv,
)
from casflex.simulate.integrators import rk4_step

MOVES = ("move1", "move2", "move3")
DISSERTATION = {
    "move1": {"r": [0.647, 1.0, 0.13], "vtol": [0.078, 0.05, 0.36], "duration": 0.87},
    "move2": {"r": [0.0, 1.0, 0.0], "vtol": [1.0, 0.05, 1.0], "duration": 0.53},
    "move3": {"r": [1.0, 0.0, 0.38], "vtol": [0.05, 1.0, 0.13], "duration": 0.39},
}
TABLE14 = ([6.64, 9.36, 23.36], [8.26, 11.9, 35.21])  # rad/s, moves 1 and 2
#: a coarse grid of q3 covering the moves (-75°…15°, 7.5° steps), rad
GRID = [np.radians(np.arange(-75.0, 15.1, 7.5))]


@pytest.fixture(scope="module")
def model(arm_model):
    """Three-mode gravity-free model of the Table 8 arm on :data:`GRID`."""
    model, _ = arm_model(3, grid=GRID, gravity=None)
    return model


@pytest.fixture(scope="module")
def designs(model, move):
    """Shapers of moves 1-3 with the dissertation's spans (no margin) and with ±20 %."""
    out = {}
    for name in MOVES:
        out[name, 0.0] = shaper_for_move(model, move(name), margin=0.0)
        out[name, 0.2] = shaper_for_move(model, move(name), margin=0.2)
    return out


# ------------------------------------------------------------------ the decoupled model
def modal_response(model, reference, dt):
    """RK4 of eq. 194, δ̈ + Ω²(q) δ = −M_qδᵀ(q) q̈ (M_δδ = I), on a sampled reference.

    The reference is linearly interpolated at the half steps. Returns t, δ (N, m) and the
    tip deflection (N, 3) from the first-order kinematics ``∂tip/∂δ(q) δ``.
    """
    t, q, _, ddq = reference
    n, m = model.n, model.m
    f = model.functions()
    qs = ca.SX.sym("q", n)
    mqd = ca.Function("mqd", [qs], [f["mass"](qs, ca.DM.zeros(m))[:n, n:]])
    d = ca.SX.sym("d", m)
    jac = ca.Function("tip_jacobian", [qs], [ca.substitute(ca.jacobian(f["tip"](qs, d), d), d,
                                                  ca.DM.zeros(m))])
    tm = np.concatenate([t, 0.5 * (t[:-1] + t[1:])])
    qm = np.concatenate([q, 0.5 * (q[:-1] + q[1:])])
    am = np.concatenate([ddq, 0.5 * (ddq[:-1] + ddq[1:])])
    N = t.size
    B = mqd.map(tm.size)(qm.T).full().reshape(n, tm.size, m)  # M_qδ per sample
    force = -np.einsum("ikj,ki->kj", B, am)  # (samples, m)
    k = f["stiffness"].map(tm.size)(qm.T).full().reshape(m, tm.size, m)
    w2 = k[np.arange(m), :, np.arange(m)].T  # (samples, m)
    F0, F1, W0, W1 = force[:N], force[N:], w2[:N], w2[N:]

    def rhs(y, u):  # y = (δ, δ̇), u = (force, ω²)
        return np.concatenate([y[m:], u[0] - u[1] * y[:m]])

    y = np.zeros(2 * m)
    out = np.zeros((N, m))
    for i in range(N - 1):
        h = t[i + 1] - t[i]
        y = rk4_step(rhs, y, h, (F0[i], W0[i]), (F1[i], W1[i]), (F0[i + 1], W0[i + 1]))
        out[i + 1] = y[:m]
    J = jac.map(N)(q.T).full().reshape(3, N, m)
    tip = np.einsum("knj,nj->nk", J, out)
    return t, out, tip


# ------------------------------------------------------------------- contributions
@pytest.mark.parametrize("name", MOVES)
def test_contributions_match_dissertation(model, name, move):
    r = modal_contributions(model, move(name))
    np.testing.assert_allclose(r, DISSERTATION[name]["r"], atol=0.01)
    assert r.max() == 1.0


def test_contributions_quadrature_independent_and_raw(model, move):
    """The midpoint rule on a Move and the trapezoid on its samples agree; raw values scale."""
    mv = move("move1")
    t = np.linspace(0.0, mv.duration, 4001)
    q, dq, ddq = mv.sample(t)
    r_move = modal_contributions(model, mv, normalize=False)
    r_samp = modal_contributions(model, (t, q, dq, ddq), normalize=False)
    np.testing.assert_allclose(r_samp, r_move, rtol=2e-3)
    # with the settle phase appended (a = 0) nothing changes
    t2 = np.linspace(0.0, mv.t_end, 10001)
    r_long = modal_contributions(model, (t2, *mv.sample(t2)), normalize=False)
    np.testing.assert_allclose(r_long, r_move, rtol=2e-3)
    # r scales with the acceleration: half the move's amplitude, half the contributions
    half = Move(q0=mv.q0, qf=0.5 * mv.qf, duration=mv.duration)
    ratio = modal_contributions(model, half, normalize=False)[:2] / r_move[:2]
    assert ratio.max() < 0.6  # the end configuration differs, so not exactly 1/2


def test_modal_displacement_against_finite_differences(model):
    """w_j(p) = |∂tip/∂δ_j| from CasADi against central differences of the tip."""
    q = np.array([-1.0, -1.0, -1.0])
    tip = model.functions()["tip"]
    h = 1e-6
    fd = []
    for j in range(model.m):
        e = np.zeros(model.m)
        e[j] = h
        fd.append(np.linalg.norm((tip(q, e) - tip(q, -e)).full().ravel() / (2 * h)))
    np.testing.assert_allclose(modal_displacements(model, q), fd, rtol=1e-6)
    # the last DH frame is the tip; frame 2 (end of link 1) moves less for mode 1
    np.testing.assert_allclose(modal_displacements(model, q, point=3), fd, rtol=1e-9)
    assert modal_displacements(model, q, point=2)[0] < fd[0]


def test_contributions_pointwise_model_for_move3(arm, move):
    """Move 3 keeps q3 = 0: a model frozen at q = 0 (no tables) gives the same r."""
    frozen = FlexibleModel(arm, PointwiseProvider(arm, [0.0, 0.0, 0.0], count=3),
                           gravity=None)
    r = modal_contributions(frozen, move("move3"))
    np.testing.assert_allclose(r, DISSERTATION["move3"]["r"], atol=0.01)


# ---------------------------------------------------------------------- tolerances
def test_tolerances_eq198():
    # the README's example: the formula gives 0.10 for mode 2 (the text prints 0.05)
    np.testing.assert_allclose(tolerances_from_contributions([4.0, 2.0, 0.3]),
                               [0.05, 0.10, 0.05 * 4 / 0.3])
    np.testing.assert_allclose(tolerances_from_contributions([0.647, 1.0, 0.13]),
                               [0.0773, 0.05, 0.3846], atol=1e-4)
    assert tolerances_from_contributions([0.0, 1.0, 1e-12]).tolist() == [1.0, 0.05, 1.0]
    assert tolerances_from_contributions([0.0, 0.0]).tolist() == [1.0, 1.0]
    assert tolerances_from_contributions([2.0, 1.0], vtol=0.6).tolist() == [0.6, 1.0]


@pytest.mark.slow
@pytest.mark.parametrize("name", MOVES)
def test_tolerances_for_moves(designs, name):
    np.testing.assert_allclose(designs[name, 0.0].tolerances, DISSERTATION[name]["vtol"],
                               atol=0.025)


# --------------------------------------------------------------------- frequencies
def test_frequency_spans_match_table14(model, move):
    t, omega = frequencies_along(model, move("move1"))
    assert omega.shape == (t.size, 3)
    np.testing.assert_allclose(omega.min(axis=0), TABLE14[0], rtol=0.03)
    np.testing.assert_allclose(omega.max(axis=0), TABLE14[1], rtol=0.03)
    # monotonic along the move: modes 1, 2 fall, mode 3 rises as q3 goes 0 -> -1 rad
    assert np.all(np.diff(omega[:, 0]) <= 1e-9) and np.all(np.diff(omega[:, 2]) >= -1e-9)
    # move 3 keeps the shape joint still: single frequencies
    _, w3 = frequencies_along(model, move("move3"))
    np.testing.assert_allclose(w3, np.broadcast_to(w3[0], w3.shape), rtol=1e-12)
    np.testing.assert_allclose(w3[0], ARM2LINK_Q0_OMEGA, atol=ARM2LINK_Q0_OMEGA_ATOL)


def test_frequency_ranges_margin_and_table_form(model, arm_model, move):
    ranges = frequency_ranges_along(model, move("move2"), margin=0.2, vtol=[1.0, 0.05, 1.0])
    plain = frequency_ranges_along(model, move("move2"), margin=0.0)
    for a, b in zip(ranges, plain, strict=True):
        assert a.omega_min == pytest.approx(0.8 * b.omega_min)
        assert a.omega_max == pytest.approx(1.2 * b.omega_max)
    assert [r.vtol for r in ranges] == [1.0, 0.05, 1.0]
    assert [r.vtol for r in plain] == [0.05] * 3
    # a ModalTable gives the same spans as the model built on it
    _, table = arm_model(3, grid=GRID, gravity=None)
    from_table = frequency_ranges_along(table, move("move2"), margin=0.0)
    for a, b in zip(from_table, plain, strict=True):
        assert a.omega_min == pytest.approx(b.omega_min, rel=1e-9)
        assert a.omega_max == pytest.approx(b.omega_max, rel=1e-9)


# -------------------------------------------------------------------------- shapers
@pytest.mark.slow
@pytest.mark.parametrize("name", MOVES)
def test_shaper_durations_match_dissertation(designs, name):
    res = designs[name, 0.0]
    assert res.duration == pytest.approx(DISSERTATION[name]["duration"], rel=0.03)
    assert np.all(res.max_prv <= res.tolerances + 1e-6)
    for r in res.ranges:  # verified on every design range
        w = np.linspace(r.omega_min, r.omega_max, 400)
        assert residual_vibration(res.shaper, w, r.zeta).max() <= r.vtol + 1e-6


@pytest.mark.slow
def test_margin_makes_shapers_longer(designs):
    """±20 % ranges: move 3 then needs ~0.87 s, not the dissertation's 0.39 s."""
    durations = {name: designs[name, 0.2].duration for name in MOVES}
    for name in MOVES:
        assert durations[name] > designs[name, 0.0].duration + 0.1
    for name, pinned in SHAPER_DURATION_MARGIN_20.items():  # regression pins, not references
        assert durations[name] == pytest.approx(pinned, abs=SHAPER_DURATION_ATOL), name


def test_unconstrained_ranges_do_not_break_the_design():
    """Regression: a vtol = 1 range must not feed its V = 1 peaks back as samples."""
    ranges = [FrequencyRange(9.307738784276948, 11.97004502528341, 0.0, 0.05),
              FrequencyRange(22.74676580978592, 34.581990179015285, 0.0, 1.0)]
    assert si_shaper(ranges).duration == pytest.approx(0.5402, abs=1e-3)


# ----------------------------------------------------------------- shaped references
def test_shaped_bang_bang_reference_is_consistent():
    """A bang-bang move starts with a jump in acceleration: the shaped q̈ integrates to q̇."""
    mv = Move(q0=[0.0], qf=[-np.pi], duration=2.0, settle=1.0)
    s = zv(8.3)
    t, q, dq, ddq = shaped_reference(s, mv, dt=1e-3)
    assert t[-1] == pytest.approx(mv.t_end + s.duration, abs=1e-3)
    v = np.concatenate([[0.0], np.cumsum(0.5 * (ddq[1:, 0] + ddq[:-1, 0]) * np.diff(t))])
    np.testing.assert_allclose(v, dq[:, 0], atol=5e-3)
    np.testing.assert_allclose(ddq[:10, 0], 0.5 * mv.peak_acceleration[0])
    assert q[-1, 0] == pytest.approx(-np.pi)


def test_single_mode_residual_is_shaper_prv():
    """LTI mode driven by a shaped bang-bang move: residual = V(ω) × unshaped residual."""
    w = 8.31
    mv = Move(q0=[0.0], qf=[-1.0], duration=2.0, settle=1.0)
    t0 = mv.time_grid(1e-3)
    ref0 = (t0, *mv.sample(t0))
    s = zv(1.1 * w)  # off-design so that V is neither 0 nor 1

    def residual(t, ddq, t_from):
        sol = solve_ivp(lambda tt, x: [x[1], -w * w * x[0] - np.interp(tt, t, ddq)],
                        (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=1e-3, rtol=1e-10,
                        atol=1e-12)
        return residual_amplitude(t, sol.y[0], t_from)

    ts, _, _, dds = shaped_reference(s, mv, dt=1e-3)
    unshaped = residual(ref0[0], ref0[3][:, 0], mv.duration)
    shaped = residual(ts, dds[:, 0], mv.duration + s.duration)
    assert shaped / unshaped == pytest.approx(residual_vibration(s, w), rel=0.02)


@pytest.mark.slow
@pytest.mark.parametrize("name", MOVES)
def test_decoupled_model_residual_reduced(model, designs, name, move):
    """Eq. 194 model: the shaped moves cut the residual tip deflection by >= 90 %."""
    mv = move(name)
    dt = 2e-3
    res = designs[name, 0.0]
    t0 = mv.time_grid(dt)
    _, _, tip0 = modal_response(model, (t0, *mv.sample(t0)), dt)
    ref = shaped_reference(res.shaper, mv, dt=dt)
    _, _, tip1 = modal_response(model, ref, dt)
    unshaped = residual_amplitude(t0, tip0, mv.duration)
    shaped = residual_amplitude(ref[0], tip1, mv.duration + res.duration)
    assert unshaped > 0.05  # the 2 s moves leave ~0.1-0.2 m of residual tip vibration
    assert shaped < 0.1 * unshaped


@pytest.mark.slow
def test_full_model_residual_reduced(model, designs, move):
    """Full model (casflex.simulate): the ±20 % shaper cuts move 1's residual by >= 80 %.

    Move 1 is the hardest case (measured: 85 % less with ±20 %, 75 % with the bare spans;
    moves 2 and 3: 95 % and 97 % with ±20 %, see notebooks/04_input_shaping)."""
    from casflex import simulate
    mv = move("move1")
    res = designs["move1", 0.2]
    plain = simulate.simulate_prescribed(model, mv, dt=2e-3, t_end=mv.t_end)
    ref = shaped_reference(res.shaper, mv, dt=2e-3)
    shaped = simulate.simulate_prescribed(model, ref, dt=2e-3, t_end=mv.t_end + res.duration)
    r0 = residual_amplitude(plain.t, plain.tip_deflection, mv.duration)
    r1 = residual_amplitude(shaped.t, shaped.tip_deflection, mv.duration + res.duration)
    assert r1 <= 0.2 * r0


# ---------------------------------------------------------------------- bad inputs
def test_bad_inputs(model, move):
    mv = move("move1")
    with pytest.raises(ModelError, match="2 joint"):
        modal_contributions(model, Move(q0=[0.0, 0.0], qf=[1.0, 1.0], duration=1.0))
    with pytest.raises(ModelError, match="FlexibleModel"):
        modal_contributions(object(), mv)
    with pytest.raises(ModelError, match="frame index 9"):
        modal_contributions(model, mv, point=9)
    with pytest.raises(ModelError, match="point"):
        modal_contributions(model, mv, point="tip")
    with pytest.raises(ProblemFileError, match="reference"):
        modal_contributions(model, (np.zeros(3), np.zeros((3, 3))))
    with pytest.raises(ProblemFileError, match="reference.t"):
        modal_contributions(model, (np.array([0.0, 1.0, 1.0]), np.zeros((3, 3)), None,
                                    np.zeros((3, 3))))
    with pytest.raises(ProblemFileError, match="reference.ddq"):
        modal_contributions(model, (np.array([0.0, 1.0]), np.zeros((2, 3)), None, None))
    with pytest.raises(ProblemFileError, match="n_samples"):
        modal_contributions(model, mv, n_samples=1)
    with pytest.raises(ProblemFileError, match="'r'.*>= 0"):
        tolerances_from_contributions([1.0, -0.1])
    with pytest.raises(ProblemFileError, match="'r'"):
        tolerances_from_contributions([1.0, np.nan])
    with pytest.raises(ProblemFileError, match="'r'"):
        tolerances_from_contributions([])
    with pytest.raises(ProblemFileError, match="vtol"):
        tolerances_from_contributions([1.0], vtol=0.0)
    with pytest.raises(ProblemFileError, match="margin"):
        frequency_ranges_along(model, mv, margin=1.0)
    with pytest.raises(ProblemFileError, match="vtol"):
        frequency_ranges_along(model, mv, vtol=[0.05, 0.05])
    with pytest.raises(ProblemFileError, match="zeta"):
        frequency_ranges_along(model, mv, zeta=1.5)
    with pytest.raises(ProblemFileError, match="n_impulses"):
        shaper_for_move(model, mv, n_impulses="many")
    with pytest.raises(ProblemFileError, match="t_from"):
        residual_amplitude([0.0, 1.0], [0.0, 0.0], 2.0)
    with pytest.raises(ProblemFileError, match="dt"):
        shaped_reference(zv(10.0), mv, dt=-1.0)
    with pytest.raises(ProblemFileError, match="move"):
        shaped_reference(zv(10.0), (0, 1), dt=1e-3)
    t = np.linspace(0, 1, 5)
    with pytest.raises(ProblemFileError, match="qdd"):
        apply_shaper(zv(10.0), t, t, t, np.zeros(3))


@pytest.mark.slow
def test_si_design_recovers_from_infeasible_restart():
    """Regression: with Vtol = (0.05, 0.1, 0.666…) the restart from the pruned solution
    can end in Ipopt's 'Infeasible_Problem_Detected'; the design retries from the guess."""
    hz = 2.0 * np.pi
    vt = tolerances_from_contributions([4.0, 2.0, 0.3])
    ranges = [FrequencyRange(a * hz, b * hz, 0.0, v)
              for (a, b), v in zip([(3, 4), (9, 13), (20, 24)], vt, strict=True)]
    res = si_shaper(ranges)
    assert res.duration == pytest.approx(0.2984, abs=2e-4)
    assert np.all(res.max_prv <= vt + 1e-6)
