"""casflex.control.stability: the zero-dynamics condition and the fast loop along moves."""

import numpy as np
import pytest

from casflex import control
from casflex.moves import Move, load_move


def test_inversion_stability_check(table_model):
    model, _ = table_model
    move = load_move("problems/moves.toml:control_move1")
    r = control.inversion_stability(model, move, alpha=1.0)
    margin = r["conditions"]["zero_dynamics_margin"]
    assert margin["holds"] and r["worst_margin"] > 0 and margin["value"] == r["worst_margin"]
    assert 1.0 < r["time_scale_max"] < np.inf
    # running the move just faster than the allowed factor breaks eq. 226
    s = r["time_scale_max"] * 1.05
    fast = Move(move.q0, move.qf, move.duration / s)
    eq226 = "zero_dynamics_margin"
    assert not control.inversion_stability(model, fast, alpha=1.0)["conditions"][eq226]["holds"]
    slow = Move(move.q0, move.qf, move.duration / (0.95 * r["time_scale_max"]))
    assert control.inversion_stability(model, slow, alpha=1.0)["conditions"][eq226]["holds"]
    assert r["gamma"] < 0 and not r["damping_condition"]  # no modal damping in Table 8
    # eq. 225 fails without damping: the headline may not say stable (issue 18)
    damping = r["conditions"]["modal_damping"]
    assert not damping["holds"] and damping["value"] == -1.0  # λ_min(D) − α = 0 − 1
    assert r["stable"] is False


def test_inversion_headline_is_the_conjunction_of_its_conditions():
    """Frozen shapes (K̇ = 0, eq. 226 holds for any α > 0) with modal damping ζ: eq. 225
    holds iff α < 2ζω_min, its value is 2ζω_min − α with ω_min from the TMM directly, and
    the headline ``stable`` follows it (issue 18)."""
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load
    from casflex.tmm import modes

    robot = load("problems/arm2link.toml")
    q = [0.0, 0.3, -1.0]
    zeta = 0.05
    model = FlexibleModel(robot, PointwiseProvider(robot, q, 2), gravity=None,
                          damping_ratio=zeta)
    wmin = float(modes(robot, np.array(q), count=2).omega[0])
    bound = 2 * zeta * wmin  # rad/s: D − αI ≻ 0 iff α < 2ζω_min
    move = Move(q, q, 1.0)
    for alpha, expected in ((0.5 * bound, True), (1.5 * bound, False)):
        r = control.inversion_stability(model, move, alpha=alpha)
        c = r["conditions"]
        assert c["zero_dynamics_margin"]["holds"]
        assert c["modal_damping"]["holds"] is expected
        # ω_min from two TMM solves, each converged far below 1e-6 relative
        assert c["modal_damping"]["value"] == pytest.approx(bound - alpha, rel=1e-6)
        assert r["stable"] is expected and r["damping_condition"] is expected


def test_composite_end_gains_unstable_along_move1_schedule_better(table_model):
    model, table = table_model
    move = load_move("problems/moves.toml:control_move1")
    eps = control.perturbation_parameter(model, table=table)
    assert 6.0 < 1 / eps < 7.0  # 6.35 rad/s in the dissertation
    end = control.composite_stability(model, move, epsilon=eps)
    assert not end["stable"] and end["worst_time"] < 0.5
    sch = control.gain_schedule(model, epsilon=eps, table=table)
    assert sch.joints == (1, 2)
    r = control.composite_stability(model, move, gain=sch)
    assert r["worst_real"] < end["worst_real"] / 10
