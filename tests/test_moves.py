"""Bang-bang moves: kinematic consistency, move-file validation, reference samplers."""

import numpy as np
import pytest

from casflex.errors import ProblemFileError
from casflex.moves import Move, load_move, load_moves, reference_function


def test_bang_bang_is_consistent():
    m = Move(q0=[0.0, 1.0, 6.2], qf=[-1.0, 2.0, 5.2], duration=2.0, settle=1.0)
    t = np.linspace(-0.5, m.t_end, 7001)
    q, qd, qdd = m.sample(t)
    # integrate the acceleration twice with the trapezoidal rule: recovers qd and q
    dt = t[1] - t[0]
    qd_int = np.concatenate([[qd[0]], qd[0] + np.cumsum(0.5 * (qdd[1:] + qdd[:-1]), 0) * dt])
    q_int = np.concatenate([[q[0]], q[0] + np.cumsum(0.5 * (qd[1:] + qd[:-1]), 0) * dt])
    np.testing.assert_allclose(qd_int, qd, atol=2e-3)
    np.testing.assert_allclose(q_int, q, atol=2e-6)
    np.testing.assert_allclose(q[t < 0], np.broadcast_to(m.q0, q[t < 0].shape))
    np.testing.assert_allclose(q[-1], m.qf)
    assert np.all(qd[t >= m.duration] == 0.0)
    # peak velocity 2 (qf - q0) / T at mid-move
    np.testing.assert_allclose(m.sample(1.0)[1], 2 * (m.qf - m.q0) / 2.0)


def test_shipped_moves():
    moves = load_moves("problems/moves.toml")
    assert {"move1", "move2", "move3", "control_move1", "testbed_move1"} <= set(moves)
    m3 = load_move("problems/moves.toml:move3")
    assert m3.qf[0] == pytest.approx(-np.pi) and m3.duration == 2.0
    assert load_move("problems/moves.toml:testbed_move1").duration == 1.0


@pytest.mark.parametrize("text, match", [
    ('[m]\nduration = 2.0\nq0 = [0.0]\n', "qf.*required"),
    ('[m]\nduration = -1.0\nq0 = [0.0]\nqf = [1.0]\n', "duration.*must be > 0"),
    ('[m]\nduration = 1.0\nq0 = [0.0, 1.0]\nqf = [1.0]\n', "as many values as q0"),
    ('[m]\nduration = 1.0\nq0 = [nan]\nqf = [1.0]\n', "finite"),
    ('[m]\nduration = 1.0\nq0 = [0.0]\nqf = [1.0]\nspeed = 2\n', "unknown key"),
    ('[m]\nduration = 1.0\nq0 = [0.0]\nqf = [1.0]\nunit = "grad"\n', "'rad' or 'deg'"),
    ('[m]\nduration = 1.0\nq0 = [0.0]\nqf = [1.0]\nprofile = "cubic"\n', "must be one of"),
])
def test_bad_move_files(tmp_path, text, match):
    p = tmp_path / "moves.toml"
    p.write_text(text)
    with pytest.raises(ProblemFileError, match=match) as info:
        load_moves(p)
    assert str(p) in str(info.value)


def test_move_names(tmp_path):
    with pytest.raises(ProblemFileError, match="no such move"):
        load_move("problems/moves.toml:move9")
    with pytest.raises(ProblemFileError, match="name a move as FILE:NAME"):
        load_move("problems/moves.toml")
    p = tmp_path / "one.toml"
    p.write_text('[only]\nduration = 1.0\nq0 = [0.0]\nqf = [1.0]\nunit = "deg"\n')
    assert load_move(p).qf[0] == pytest.approx(np.pi / 180)


def test_reference_matches_move_sample():
    move = load_move("problems/moves.toml:control_move1")
    ref = reference_function(move)
    for t in np.linspace(-0.5, 3.0, 37):
        for got, want in zip(ref(t), move.sample(t), strict=True):
            np.testing.assert_allclose(got.full().ravel(), want, atol=1e-14)
