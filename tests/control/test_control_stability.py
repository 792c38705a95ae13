"""casflex.control.stability: the zero-dynamics condition and the fast loop along moves."""

import numpy as np

from casflex import control
from casflex.moves import Move, load_move


def test_inversion_stability_check(table_model):
    model, _ = table_model
    move = load_move("problems/moves.toml:control_move1")
    r = control.inversion_stability(model, move, alpha=1.0)
    assert r["stable"] and r["worst_margin"] > 0
    assert 1.0 < r["time_scale_max"] < np.inf
    # running the move just faster than the allowed factor breaks eq. 226
    s = r["time_scale_max"] * 1.05
    fast = Move(move.q0, move.qf, move.duration / s)
    assert not control.inversion_stability(model, fast, alpha=1.0)["stable"]
    slow = Move(move.q0, move.qf, move.duration / (0.95 * r["time_scale_max"]))
    assert control.inversion_stability(model, slow, alpha=1.0)["stable"]
    assert r["gamma"] < 0 and not r["damping_condition"]  # no modal damping in Table 8


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
