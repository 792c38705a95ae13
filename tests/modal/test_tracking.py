"""Mode tracking (modified MAC, sign, multiple roots) on the Table 8 arm's q3 sweep."""

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal.tables import compute_modes
from casflex.modal.tracking import (
    combine,
    correlation,
    mac,
    point_tracking_data,
    shape_features,
    track,
    track_grid,
    track_grid_features,
)
from casflex.robot import load
from casflex.tmm import modes

N_MODES = 5
STEP = np.radians(1.5)


@pytest.fixture(scope="module")
def sweep(arm):
    """Fig. 25/26: q3 over [-pi, pi] every 1.5 deg, 5 modes + 2 extra."""
    q3 = np.arange(-np.pi, np.pi + 0.5 * STEP, STEP)
    qs = np.column_stack([np.zeros_like(q3), np.zeros_like(q3), q3])
    seq = compute_modes(arm, qs, N_MODES + 2, processes=2)
    tr = track(seq, robot=arm)
    return q3, seq, tr


def test_features_make_distinct_modes_orthogonal(arm):
    shapes = modes(arm, [0.0, 0.0, 0.7], count=5)
    c = correlation(shapes, shapes, arm)
    assert np.allclose(np.diag(c), 1.0)
    assert np.max(np.abs(c - np.eye(5))) < 1e-3  # mass-weighted: quadrature of M_jk
    # the literal (uniform) sum of eq. 119-120 does not separate them as well
    cu = correlation(shapes, shapes)
    assert np.max(np.abs(cu - np.eye(5))) > 10 * np.max(np.abs(c - np.eye(5)))
    assert shape_features(shapes, arm).shape[0] == 5
    with pytest.raises(ModelError):
        shape_features(shapes, None, "mass")


def test_tracked_frequencies_continuous_across_crossings(sweep):
    q3, seq, tr = sweep
    raw = np.array([s.omega[:N_MODES] for s in seq])
    w = tr.omega(seq)[:, :N_MODES]
    # tracking really changes the order somewhere (the crossings of Fig. 25)
    assert np.any(w != raw)
    assert np.all(tr.order[:, :N_MODES] < N_MODES + 2)
    # curvature of the curves: a crossing followed by sorting leaves a kink (a jump of
    # the slope) in the raw curves; the tracked branches stay smooth (Fig. 26)
    d2_raw = np.abs(np.diff(raw, 2, axis=0)).max(axis=0)
    d2_trk = np.abs(np.diff(w, 2, axis=0)).max(axis=0)
    assert np.all(d2_trk <= d2_raw + 1e-9)
    # modes 2 and 3 cross near +-51 deg and +-130 deg: measured 0.23 rad/s raw vs 0.03
    assert np.all(d2_trk[1:3] < 0.2 * d2_raw[1:3])
    # neighbour-to-neighbour change bounded by the raw one (continuity, no identity jump)
    jump_trk = np.abs(np.diff(w, axis=0)).max()
    jump_raw = np.abs(np.diff(raw, axis=0)).max()
    assert jump_trk <= jump_raw * (1 + 1e-9)
    # the sweep closes up: q3 = -pi and q3 = pi are the same configuration
    np.testing.assert_allclose(w[0], w[-1], rtol=1e-9)


def test_signs_never_flip_and_mac_stays_high(sweep, arm):
    q3, seq, tr = sweep
    tracked = tr.apply(seq)
    corr = np.array([np.diag(correlation(a, b, arm))[:N_MODES]
                     for a, b in zip(tracked[:-1], tracked[1:], strict=True)])
    assert corr.min() > 0.0  # eq. 121: never on the other "side"
    assert (corr**2).min() >= 0.9  # MAC of tracked neighbours
    assert np.nanmin(tr.mac[:, :N_MODES]) >= 0.9
    assert set(np.unique(tr.sign)) <= {-1.0, 1.0}


def test_double_root_is_taken_from_the_neighbourhood(arm):
    """At a k-fold root, the combination within the subspace closest to the neighbours."""
    q = np.radians([87.0, 88.5, 90.0, 91.5, 93.0])
    good = [modes(arm, [0, 0, x], count=4) for x in q]
    good[2] = modes(arm, [0, 0, q[2] + 1e-4], count=4)  # distinct modes next to the root
    reference = track(good, robot=arm).apply(good)[2]
    # present the middle point as the TMM does at a double root: equal frequencies and an
    # arbitrary orthonormal basis of each two-dimensional subspace
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, s, 0, 0], [-s, c, 0, 0], [0, 0, c, -s], [0, 0, s, c]])
    mixed = combine(good[2], rot, order=[0, 1, 2, 3])
    w = mixed.omega.copy()
    w[1], w[3] = w[0], w[2]
    from dataclasses import replace

    mixed = replace(mixed, omega=w, multiplicity=np.array([2, 2, 2, 2]))
    seq = good[:2] + [mixed] + good[3:]
    tr = track(seq, robot=arm)
    assert tr.degenerate.tolist() == [False, False, True, False, False]
    fitted = tr.apply(seq)[2]
    m = np.diag(mac(fitted, reference, arm))
    assert m.min() > 0.999
    assert np.all(np.diag(correlation(fitted, reference, arm)) > 0)


def test_uniform_weighting_without_robot_tracks_the_crossing(arm):
    seq = [modes(arm, [0, 0, x], count=5) for x in np.radians([45.0, 50.0, 55.0])]
    tr = track(seq, count=3)
    assert tr.order.tolist() == [[0, 1, 2], [0, 1, 2], [0, 2, 1]]


def test_track_rejects_bad_input(arm):
    with pytest.raises(ModelError):
        track([])
    seq = [modes(arm, [0, 0, 0.1], count=3)]
    with pytest.raises(ModelError):
        track(seq, count=5)


def test_grid_tracking_consistent_on_every_edge():
    testbed = load("problems/testbed.toml")
    q2 = np.array([0.0, 0.05, 0.1])
    q3 = np.array([0.3, 0.35, 0.4, 0.45])
    qs = np.array([[0.0, a, b] for a in q2 for b in q3])
    flat = compute_modes(testbed, qs, 6, processes=2)
    grid = [[flat[i * q3.size + j] for j in range(q3.size)] for i in range(q2.size)]
    gt = track_grid(grid, count=4, robot=testbed)
    assert gt.order.shape == (3, 4, 4)
    # every grid edge, including those outside the spanning tree, keeps sign and identity
    assert np.nanmin(gt.edge_correlation) > 0.9
    tracked = gt.apply(_obj(grid))
    assert tracked.shape == (3, 4)


def _obj(nested):
    arr = np.empty((len(nested), len(nested[0])), dtype=object)
    for i, row in enumerate(nested):
        for j, item in enumerate(row):
            arr[i, j] = item
    return arr


def test_grid_tracking_from_per_point_data_equals_tracking_the_shapes(arm):
    # through the double root at q3 = 90 deg (a degenerate point: its subspace fit and
    # the unit-peak rescaling read the displacement the per-point data carries)
    raw = np.empty(9, dtype=object)
    data = np.empty(9, dtype=object)
    for i, x in enumerate(np.radians(np.arange(60.0, 121.0, 7.5))):
        raw[i] = modes(arm, [0.0, 0.0, x], count=6)
        data[i] = point_tracking_data(raw[i], arm)
    a, b = track_grid_features(data), track_grid(raw, robot=arm)
    assert b.degenerate.any() and sum(d["displacement"] is not None for d in data) == 1
    for name in ("order", "sign", "mac", "degenerate", "edge_correlation"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for ta, tb in zip(a.transform, b.transform, strict=True):
        np.testing.assert_array_equal(ta, tb)  # bit for bit: the same arithmetic
