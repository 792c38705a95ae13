"""casflex.modal.gridlines: a Dask table build tracked on the workers, by grid lines."""

import functools

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal import gridlines, tables
from casflex.modal.gridlines import BLOCKS_PER_WORKER, MAX_BLOCK_POINTS, line_blocks
from casflex.modal.tables import build_table
from casflex.modal.tracking import (
    point_tracking_data,
    track_grid,
    track_path_features,
    tracked_unit_features,
)
from casflex.robot import load
from casflex.tmm import modes

TIMINGS = ("seconds", "seconds_modes", "seconds_tracking", "seconds_quantities")


def test_line_blocks_cover_every_line_once_in_order():
    for n_lines in (1, 2, 5, 10, 37):
        for workers in (1, 2, 3, 8):
            for per_worker in (None, 1, 2):
                blocks = line_blocks(n_lines, workers, per_worker)
                assert np.concatenate(blocks).tolist() == list(range(n_lines))
                sizes = [b.size for b in blocks]
                assert len(blocks) == min(n_lines, (per_worker or BLOCKS_PER_WORKER)
                                          * workers)
                assert max(sizes) - min(sizes) <= 1
    # a large grid: blocks of at most MAX_BLOCK_POINTS points, as many on every worker
    for n_lines, line_points, workers in ((144, 12, 2), (4096, 16, 3), (10, 300, 4)):
        blocks = line_blocks(n_lines, workers, line_points=line_points)
        assert np.concatenate(blocks).tolist() == list(range(n_lines))
        assert len(blocks) % workers == 0 or len(blocks) == n_lines
        assert max(b.size for b in blocks) * line_points <= max(MAX_BLOCK_POINTS,
                                                                line_points)


def test_a_path_tracked_from_its_data_equals_the_grid_tracking(arm):
    # the second row of a 2 x 5 grid through the double root at q3 = 90 deg (a degenerate
    # point: the subspace fit and the unit-peak rescaling), tracked on its own from the
    # grid's transform of its first point: bit for bit the grid's arithmetic
    q3 = np.radians(np.arange(75.0, 106.0, 7.5))
    raw = [[modes(arm, [0.0, q2, x], count=6) for x in q3] for q2 in (0.0, 0.4)]
    gt = track_grid(raw, robot=arm)
    data = [point_tracking_data(s, arm) for s in raw[1]]
    tr = track_path_features(data[1:], gt.transform[1, 0] @ data[0]["features"])
    assert tr.degenerate.any()
    for k in range(1, q3.size):
        np.testing.assert_array_equal(tr.transform[k - 1], gt.transform[1, k])
    np.testing.assert_array_equal(tr.mac, gt.mac[1, 1:])
    np.testing.assert_array_equal(tr.degenerate, gt.degenerate[1, 1:])
    # the edge correlations from the tracked unit rows: along the row and across rows
    unit = [[tracked_unit_features(gt.transform[i, k], point_tracking_data(
        raw[i][k], arm)["features"]) for k in range(q3.size)] for i in (0, 1)]
    for k in range(1, q3.size):
        np.testing.assert_array_equal(np.sum(unit[1][k - 1] * unit[1][k], axis=1),
                                      gt.edge_correlation[1, k, 1])
        np.testing.assert_array_equal(np.sum(unit[0][k] * unit[1][k], axis=1),
                                      gt.edge_correlation[1, k, 0])


def _same_table(ours, theirs):
    np.testing.assert_array_equal(ours.omega, theirs.omega)
    assert sorted(ours.values) == sorted(theirs.values)
    for name in theirs.values:
        np.testing.assert_array_equal(ours.values[name], theirs.values[name])
    assert ours.periodic == theirs.periodic
    assert {k: v for k, v in ours.info.items() if k not in TIMINGS} == {
        k: v for k, v in theirs.info.items() if k not in TIMINGS}


def _shape_quantities(robot, q, shapes, axis):
    """A quantity function whose value has 1 element where q[axis] > 0, else 2."""
    return {"x": np.zeros(1 if q[axis] > 0 else 2)}


def _keep_nothing(keep, *args):
    summary, _ = keep(*args)
    return summary, None


def _forgetting(real):
    """map_keep_reduce_use whose kept raw modes are gone by the last stage (a worker
    left): every block must recompute them."""
    def call(keep, reduce, use, jobs, client, token, **kw):
        return real(functools.partial(_keep_nothing, keep), reduce, use, jobs, client,
                    token, **kw)
    return call


@pytest.mark.slow  # ~6 s on two cores: the serial builds and five on the cluster
@pytest.mark.filterwarnings("ignore:modal table of")  # the coarse grids' MAC
def test_tables_by_lines_equal_the_serial_build_bit_for_bit(testbed, monkeypatch):
    # 2-D: 5 lines in blocks of 3 and 2 on 2 workers (3, 1 and 1 per block with two
    # blocks per worker), so edges between lines both inside a block and across blocks;
    # both axes full turns (the periodicity check on both ends); 3-D: 6 lines of the
    # 3-link spatial arm, edges across blocks along axis 0 (and along axis 1 with two
    # blocks per worker)
    distributed = pytest.importorskip("distributed")
    arm3 = load("problems/arm3_spatial.toml")
    cases = [(testbed, [np.linspace(-np.pi, np.pi, 5, endpoint=False),
                        np.linspace(-np.pi, np.pi, 3)], 3),
             (arm3, [np.linspace(-1.0, 1.0, 2), np.linspace(-1.5, 1.5, 3),
                     np.linspace(-1.0, 1.0, 2)], 3)]
    serial = [build_table(robot, grid, n, cache_dir=False, processes=1)
              for robot, grid, n in cases]
    assert serial[0].periodic == (True, True)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        assert tables.KEEP_ON_WORKERS and tables.TRACK_ON_WORKERS
        for per_worker in (1, 2):
            monkeypatch.setattr(gridlines, "BLOCKS_PER_WORKER", per_worker)
            for (robot, grid, n), theirs in zip(cases, serial, strict=True):
                _same_table(build_table(robot, grid, n, cache_dir=False, client=client),
                            theirs)
        # a quantity that changes shape: one line, inside a block (along the lines) or
        # between blocks (across them)
        robot, grid, _ = cases[0]
        for axis in (2, 1):
            with pytest.raises(ModelError, match="'x' changes shape across the grid"):
                build_table(robot, grid, 2, cache_dir=False, client=client,
                            quantities=functools.partial(_shape_quantities, axis=axis))
        # raw modes gone from the workers (a worker left): recomputed, still identical
        monkeypatch.setattr(gridlines, "map_keep_reduce_use",
                            _forgetting(gridlines.map_keep_reduce_use))
        robot, grid, n = cases[0]
        _same_table(build_table(robot, grid, n, cache_dir=False, client=client), serial[0])
