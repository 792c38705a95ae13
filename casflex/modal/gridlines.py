"""A table build on a Dask cluster by grid lines: the tracking done on the workers.

:func:`casflex.modal.build_table` without a cache on a Dask cluster, for a grid of two or
more shape joints. :func:`casflex.modal.track_grid`'s spanning tree is a comb: the base
plane (every point whose last index is 0) is tracked first, then every line along the
last axis from its base point, each line on its own. So here:

1. each task takes a block of whole lines (consecutive in the grid's C order), computes
   the raw modes of their points and keeps them on its worker
   (:func:`casflex._parallel.map_keep`); only the tracking data of the lines' base points
   come to the client (one point per line);
2. the client tracks the base plane (:func:`casflex.modal.track_grid_features` on it);
3. each block goes back to the worker holding it with its base points' transforms
   (:func:`casflex._parallel.map_kept`); the worker tracks its lines
   (:func:`casflex.modal.track_path_features`), makes the tracked modes and the
   quantities, and the edge correlations between neighbours it holds
   (:func:`casflex.modal.tracked_unit_features`). Only the unit feature rows of lines
   that meet a line of another block come to the client, for the edges between blocks.

Every number is made by the same calls on the same inputs as :func:`track_grid` and the
per-point quantities: the table is bit for bit the serial one. Per point, the client
receives the quantities and a few numbers (transform, MAC, edges), not the 20–30 kB of
MAC features; a build is two tasks per block, ``2 × blocks`` in all.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from casflex._parallel import map_keep, map_kept
from casflex.modal import tracking as trk

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["tabulate_by_lines", "BLOCKS_PER_WORKER", "line_blocks"]

#: blocks of lines per worker thread: the tasks of each stage (more balance the load
#: of a busy machine; fewer cost the scheduler less)
BLOCKS_PER_WORKER = 2


def line_blocks(n_lines: int, workers: int, per_worker: int = BLOCKS_PER_WORKER
                ) -> list[np.ndarray]:
    """The lines of each task: ``min(n_lines, per_worker × workers)`` blocks of
    consecutive lines, their sizes differing by one at most.

    Parameters
    ----------
    n_lines : int
        Lines along the grid's last axis (the product of the other axes' sizes).
    workers : int
        Worker threads of the cluster.
    per_worker : int
        Blocks per worker thread.

    Returns
    -------
    list of numpy.ndarray
        Line indices (C order over all axes but the last) of each block.

    Examples
    --------
    >>> [b.tolist() for b in line_blocks(5, 1)]
    [[0, 1, 2], [3, 4]]
    """
    return [b for b in np.array_split(np.arange(n_lines),
                                      max(1, min(n_lines, per_worker * workers))) if b.size]


def _block_modes(point_kept, args):
    """Stage 1 of a block: every point's raw modes and tracking data, kept here; the
    base points' tracking data (one per line) and every point's shift go back."""
    kept = [point_kept(*a) for a in args["points"]]
    n_last = args["n_last"]
    summary = {"base": [kept[i][0] for i in range(0, len(kept), n_last)],
               "shifted": [bool(np.any(data["shift"] != 0.0)) for data, _ in kept]}
    return summary, kept


def _edge(u_prev, u_cur):
    """Signed correlation of the tracked modes across a grid edge (as track_grid)."""
    return np.sum(u_prev * u_cur, axis=1)


def _block_tables(kept, point_kept, tracked_point, args, base_transforms, send_unit):
    """Stage 3 of a block on the worker keeping its modes (recomputed where they are
    gone): track its lines from their base transforms, the edges inside the block, the
    tracked modes' quantities."""
    redone = kept is None
    if redone:
        kept = _block_modes(point_kept, args)[1]
    n_last, lines, strides = args["n_last"], args["lines"], args["line_strides"]
    n_points = len(kept)
    T = [None] * n_points
    mac = [None] * n_points
    degenerate = [None] * n_points
    for j, base in enumerate(base_transforms):
        first = j * n_last
        T[first] = base
        if n_last > 1:
            path = [kept[first + i][0] for i in range(1, n_last)]
            tr = trk.track_path_features(path, base @ kept[first][0]["features"])
            for i in range(1, n_last):
                T[first + i] = tr.transform[i - 1]
                mac[first + i], degenerate[first + i] = tr.mac[i - 1], tr.degenerate[i - 1]
    unit = [trk.tracked_unit_features(t, data["features"])
            for t, (data, _) in zip(T, kept, strict=True)]
    position = {int(line): j for j, line in enumerate(lines)}
    points = []
    for p, ((data, arrays), t) in enumerate(zip(kept, T, strict=True)):
        j, i = divmod(p, n_last)
        order = np.argmax(np.abs(t), axis=1)
        sign = np.sign(t[np.arange(t.shape[0]), order])
        sign[sign == 0] = 1.0
        edges = {}
        if i > 0:  # along the last axis, inside the line; the others: across lines
            edges[len(strides)] = _edge(unit[p - 1], unit[p])
            for axis, (stride, at_start) in enumerate(strides):
                prev = position.get(int(lines[j]) - stride)
                if not at_start[j] and prev is not None:
                    edges[axis] = _edge(unit[prev * n_last + i], unit[p])
        quantities, features, _ = tracked_point(
            arrays, args["func"], args["robot"], args["points"][p][1], t, order,
            args["n_modes"], args["boundary"][p], args["weighting"], None)
        points.append({"transform": t, "order": order, "sign": sign, "mac": mac[p],
                       "degenerate": degenerate[p], "edges": edges,
                       "omega": data["omega"][order][:args["n_modes"]],
                       "quantities": quantities, "features": features})
    units = {int(lines[j]): unit[j * n_last:(j + 1) * n_last] for j in range(len(lines))
             if send_unit[j]}
    return points, units, redone


def tabulate_by_lines(client: Client, token: str, gshape: tuple[int, ...],
                      point_args: Sequence[tuple], point_kept: Callable,
                      tracked_point: Callable, quantities: Callable, n_modes: int,
                      boundary: set, weighting: str | None, *, progress: bool = False,
                      per_worker: int = BLOCKS_PER_WORKER) -> dict:
    """Raw modes, tracking and quantities of a grid by lines on a Dask cluster (see the
    module notes).

    Parameters
    ----------
    client : dask.distributed.Client
    token : str
        Names the raw modes kept on the workers (:func:`casflex._parallel.map_keep`);
        the caller frees them with :func:`casflex._parallel.drop_kept` after an error.
    gshape : tuple of int
        The grid's shape (two axes or more).
    point_args : sequence of tuple
        Per grid point (C order), the arguments of ``point_kept``; the second is the
        configuration ``q`` [rad].
    point_kept : callable
        ``point_kept(*args) -> (tracking data, raw modes)`` of one point: the data as
        :func:`casflex.modal.point_tracking_data` with a ``"shift"`` entry [rad].
    tracked_point : callable
        ``tracked_point(raw, quantities, robot, q, transform, order, n_modes, boundary,
        weighting, None) -> (values, tracked features or None, redone)``.
    quantities : callable
        The quantity function, ``quantities(robot, q, shapes) -> dict``.
    n_modes : int
        Tracked modes tabulated.
    boundary : set of tuple
        Grid indices whose tracked features the periodicity check needs.
    weighting : {"mass", "uniform"} or None
        Of the MAC (:func:`casflex.modal.shape_features`).
    progress : bool
        Progress bars on stderr (blocks of lines).
    per_worker : int
        Blocks per worker thread (:func:`line_blocks`).

    Returns
    -------
    dict
        ``tracking`` (:class:`casflex.modal.GridTracking` of all the computed modes),
        ``omega`` (grid shape + (n_modes,)) [rad/s], ``shifted`` (grid of bool: modes from
        a shifted configuration), ``values`` (per point, C order, the quantities),
        ``tracked`` (object grid: tracked features at ``boundary``), ``redone`` (a block
        whose raw modes were gone was recomputed), ``modes_done`` and
        ``tracking_done`` (``time.perf_counter()`` [s] at the end of the first stage and
        of the base plane's tracking).

    Examples
    --------
    On a cluster ``client`` (a doctest would pay its start-up; see
    ``tests/modal/test_gridlines.py``), :func:`casflex.modal.build_table` calls it for a grid
    of two or more shape joints without a cache. Without one the blocks are planned alone:

    >>> [b.tolist() for b in line_blocks(10, 2)]
    [[0, 1, 2], [3, 4, 5], [6, 7], [8, 9]]
    """
    import time

    n_last, ndim = gshape[-1], len(gshape)
    line_shape = gshape[:-1]
    n_lines = int(np.prod(line_shape))
    workers = max(1, sum(client.nthreads().values()))
    blocks = line_blocks(n_lines, workers, per_worker)
    block_of = np.empty(n_lines, dtype=int)
    for b, lines in enumerate(blocks):
        block_of[lines] = b
    # per axis but the last: the line index offset of the previous neighbour
    line_strides = [int(np.prod(line_shape[a + 1:])) for a in range(ndim - 1)]
    line_index = list(np.ndindex(line_shape)) if line_shape else [()]
    bset = set(boundary)

    def block_args(lines):
        flats = [int(line) * n_last + i for line in lines for i in range(n_last)]
        return {"points": [point_args[f] for f in flats], "n_last": n_last,
                "lines": lines, "func": quantities, "robot": point_args[0][0],
                "n_modes": int(n_modes), "weighting": weighting,
                "boundary": [np.unravel_index(f, gshape) in bset for f in flats],
                "line_strides": [(s, [line_index[int(line)][a] == 0 for line in lines])
                                 for a, s in enumerate(line_strides)]}

    args = [block_args(lines) for lines in blocks]
    base = np.empty(line_shape, dtype=object)
    shifted = np.zeros(gshape, dtype=bool)
    where = {}
    for b, summary, worker in map_keep(
            _block_modes, [(b, (point_kept, a)) for b, a in enumerate(args)], client,
            token, progress=progress, desc="TMM (blocks of grid lines)", chunksize=1):
        where[b] = worker
        for j, (line, data) in enumerate(zip(blocks[b], summary["base"], strict=True)):
            base[line_index[int(line)]] = data
            shifted[line_index[int(line)]] = summary["shifted"][j * n_last:(j + 1) * n_last]
    t_modes = time.perf_counter()
    gb = trk.track_grid_features(base)
    t_tracking = time.perf_counter()

    # lines whose neighbour along an axis but the last lies in another block: their
    # unit feature rows come here for the edges between blocks
    cross = []
    for line in range(n_lines):
        for a, s in enumerate(line_strides):
            if line_index[line][a] > 0 and block_of[line - s] != block_of[line]:
                cross.append((a, line - s, line))
    need = {line for _, prev, line in cross} | {prev for _, prev, _ in cross}

    m = gb.order.shape[-1]
    transform = np.empty(gshape, dtype=object)
    order = np.empty(gshape + (m,), dtype=int)
    sign = np.empty(gshape + (m,))
    mac = np.full(gshape + (m,), np.nan)
    degenerate = np.zeros(gshape, dtype=bool)
    edge = np.full(gshape + (ndim, m), np.nan)
    omega = np.empty(gshape + (int(n_modes),))
    tracked = np.empty(gshape, dtype=object)
    values = [None] * int(np.prod(gshape))
    units, redone = {}, False
    for li in line_index:  # the base plane: tracked here
        mac[li + (0,)], degenerate[li + (0,)] = gb.mac[li], gb.degenerate[li]
        edge[li + (0, slice(0, ndim - 1))] = gb.edge_correlation[li]
    jobs = [(b, (point_kept, tracked_point, a,
                 [gb.transform[line_index[int(line)]] for line in a["lines"]],
                 [int(line) in need for line in a["lines"]])) for b, a in enumerate(args)]
    for b, (points, got_units, again) in map_kept(
            _block_tables, jobs, client, token, where, progress=progress,
            desc="quantities (blocks of grid lines)", chunksize=1):
        units.update(got_units)
        redone = redone or again
        for p, point in enumerate(points):
            j, i = divmod(p, n_last)
            idx = line_index[int(blocks[b][j])] + (i,)
            transform[idx], order[idx], sign[idx] = (point["transform"], point["order"],
                                                     point["sign"])
            if i > 0:
                mac[idx], degenerate[idx] = point["mac"], point["degenerate"]
            for axis, e in point["edges"].items():
                edge[idx + (axis,)] = e
            omega[idx], tracked[idx] = point["omega"], point["features"]
            values[int(np.ravel_multi_index(idx, gshape))] = point["quantities"]
    for a, prev, line in cross:
        for i in range(1, n_last):
            edge[line_index[line] + (i, a)] = _edge(units[prev][i], units[line][i])
    result = trk.GridTracking(transform=transform, order=order, sign=sign, mac=mac,
                              degenerate=degenerate, edge_correlation=edge)
    return {"tracking": result, "omega": omega, "shifted": shifted, "values": values,
            "tracked": tracked, "redone": redone, "modes_done": t_modes,
            "tracking_done": t_tracking}
