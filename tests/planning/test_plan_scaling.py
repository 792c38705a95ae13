"""The NLP's state scaling: rows the guess leaves near zero keep a sane scale, the others
their own.

A move that holds some joints (move 3 of the design study holds joints 2 and 3) gives a
guess whose modal rows for a mode it does not excite are ~0. Their scale must not follow
them to zero, or Ipopt's scaled problem is ill-conditioned (with a floor of 1e-6 of the
largest modal row move 3 stopped at an acceptable point of 5.96 s, twice the shaped move's
2.87 s). A row the guess does excite, however small, keeps its own magnitude: a floor of
1e-2 raised move 1's third-mode rows and its warm re-solve took 151 iterations instead of
59 (benchmarks/README_planning.md, session 17)."""

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
    # the rows at zero and at round-off take the smallest row the guess excites (1e-3)
    np.testing.assert_allclose(scale[[n + 1, n + 2, 2 * n + m + 1, 2 * n + m + 2]], 1e-3,
                               rtol=1e-2)
    # the rows the guess does fill keep their own magnitude
    assert scale[n] >= 1e-3 * 0.99 and scale[0] >= 2.0 * 0.99


def test_joint_rows_keep_their_floor_and_scale_never_shrinks_a_row():
    n, m = 2, 2
    guess = _guess(n, m, [1e-4, 1e-5])
    scale = state_scales(guess, n, m)
    assert np.all(scale >= np.max(np.abs(guess), axis=1))
    joint = np.r_[0:n, n + m:2 * n + m]
    assert np.all(scale[joint] >= 0.1)


def test_small_excited_modal_rows_keep_their_own_magnitude():
    # move 1's guess: the third mode's rows two decades below the first's
    n, m = 3, 3
    guess = _guess(n, m, [1.1e-2, 5.5e-3, 2.0e-4])
    scale = state_scales(guess, n, m)
    modal = np.r_[n:n + m, 2 * n + m:2 * (n + m)]
    np.testing.assert_array_equal(scale[modal], np.max(np.abs(guess[modal]), axis=1))


def test_a_guess_without_vibration_scales_the_modal_rows_by_one():
    n, m = 1, 2
    scale = state_scales(_guess(n, m, [0.0, 0.0]), n, m)
    assert scale[n:n + m].tolist() == [1.0, 1.0] and scale[2 * n + m:].tolist() == [1.0, 1.0]
