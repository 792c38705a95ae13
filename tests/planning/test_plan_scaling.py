"""The NLP's state scaling: rows the guess leaves near zero keep a sane scale.

A move that holds some joints (move 3 of the design study holds joints 2 and 3) gives a
guess whose modal rows for those joints are ~0. Their scale must stay within two decades of
the largest modal row, or Ipopt's scaled problem is ill-conditioned (with a floor of 1e-6
move 3 stopped at an acceptable point of 5.96 s, twice the shaped move's 2.87 s)."""

import numpy as np

from casflex.planning.staged import state_scales


def _guess(n, m, modal_peaks, samples=50):
    """Rows [q (n), delta (m), qdot (n), deltadot (m)] x samples with the given modal peaks."""
    t = np.linspace(0.0, 1.0, samples)
    rows = np.zeros((2 * (n + m), samples))
    rows[0] = 2.0 * t  # a joint that moves 2 rad
    rows[n + m] = 2.0  # its velocity
    for i, peak in enumerate(modal_peaks):
        rows[n + i] = peak * np.sin(7 * t)
        rows[2 * n + m + i] = 50 * peak * np.cos(7 * t)
    return rows


def test_held_joint_modal_rows_are_not_scaled_to_zero():
    n, m = 3, 3
    scale = state_scales(_guess(n, m, [1e-3, 0.0, 1e-14]), n, m)
    modal = np.r_[scale[n:n + m], scale[2 * n + m:]]
    assert modal.min() >= 1e-2 * modal.max()
    # the rows the guess does fill keep their own magnitude
    assert scale[n] >= 1e-3 * 0.99 and scale[0] >= 2.0 * 0.99


def test_joint_rows_keep_their_floor_and_scale_never_shrinks_a_row():
    n, m = 2, 2
    guess = _guess(n, m, [1e-4, 1e-5])
    scale = state_scales(guess, n, m)
    assert np.all(scale >= np.max(np.abs(guess), axis=1))
    joint = np.r_[0:n, n + m:2 * n + m]
    assert np.all(scale[joint] >= 0.1)
