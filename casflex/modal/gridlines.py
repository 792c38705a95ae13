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
from casflex.errors import ModelError
from casflex.modal import tracking as trk

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["tabulate_by_lines", "BLOCKS_PER_WORKER", "MAX_BLOCK_POINTS", "line_blocks"]

#: blocks of lines per worker thread: the tasks of each stage. More would balance
#: workers of unequal speed (a shared machine, a mixed cluster); each task costs the
#: scheduler and the client ~1.5-4 ms of CPU (benchmarks/README_tables.md), so one
BLOCKS_PER_WORKER = 1
#: most grid points in one block, where the grid allows: a block reports when it is
#: done, so this keeps the progress bar moving on a large grid (a few s of TMM between
#: steps) at a per-task cost of < 0.1 % of the block's work
MAX_BLOCK_POINTS = 256


def line_blocks(n_lines: int, workers: int, per_worker: int | None = None,
                line_points: int = 1) -> list[np.ndarray]:
    """The lines of each task: blocks of consecutive lines, their sizes differing by one
    at most; ``per_worker`` blocks per worker thread, or as many more per worker as keep
    a block within :data:`MAX_BLOCK_POINTS` points; at most one block per line.

    Parameters
    ----------
    n_lines : int
        Lines along the grid's last axis (the product of the other axes' sizes).
    workers : int
        Worker threads of the cluster.
    per_worker : int, optional
        Blocks per worker thread at least (default :data:`BLOCKS_PER_WORKER`).
    line_points : int
        Points of a line (the size of the grid's last axis).

    Returns
    -------
    list of numpy.ndarray
        Line indices (C order over all axes but the last) of each block.

    Examples
    --------
    >>> [b.tolist() for b in line_blocks(5, 1, per_worker=2)]
    [[0, 1, 2], [3, 4]]
    >>> len(line_blocks(144, 2, line_points=12))   # 12 x 12 x 12: 8 blocks of 216 points
    8
    """
    if per_worker is None:
        per_worker = BLOCKS_PER_WORKER
    workers = max(1, int(workers))
    per_worker = max(int(per_worker),
                     -(-int(n_lines) * int(line_points) // (MAX_BLOCK_POINTS * workers)))
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
    ndim, m = len(strides) + 1, T[0].shape[0]
    # the block's results stacked per field: a few arrays for the client to unpickle,
    # not a dict per point
    edges = np.full((n_points, ndim, m), np.nan)
    has_edge = np.zeros((n_points, ndim), dtype=bool)
    order = np.argmax(np.abs(np.array(T)), axis=2)
    sign = np.empty((n_points, m))
    values, features = [], {}
    for p, ((_, arrays), t) in enumerate(zip(kept, T, strict=True)):
        j, i = divmod(p, n_last)
        s = np.sign(t[np.arange(m), order[p]])
        s[s == 0] = 1.0
        sign[p] = s
        if i > 0:  # along the last axis, inside the line; the others: across lines
            edges[p, ndim - 1], has_edge[p, ndim - 1] = _edge(unit[p - 1], unit[p]), True
            for axis, (stride, at_start) in enumerate(strides):
                prev = position.get(int(lines[j]) - stride)
                if not at_start[j] and prev is not None:
                    edges[p, axis] = _edge(unit[prev * n_last + i], unit[p])
                    has_edge[p, axis] = True
        got, tracked, _ = tracked_point(
            arrays, args["func"], args["robot"], args["points"][p][1], t, order[p],
            args["n_modes"], args["boundary"][p], args["weighting"], None)
        values.append(got)
        if tracked is not None:
            features[p] = tracked
    blank = np.full(m, np.nan)
    block = {"transform": np.array(T), "order": order, "sign": sign,
             "mac": np.array([blank if q is None else q for q in mac]),
             "degenerate": np.array([bool(d) for d in degenerate]), "edges": edges,
             "has_edge": has_edge, "values": _stack_values(values),
             "omega": np.array([data["omega"][o][:args["n_modes"]]
                                for (data, _), o in zip(kept, order, strict=True)]),
             "features": features}
    units = {int(lines[j]): unit[j * n_last:(j + 1) * n_last] for j in range(len(lines))
             if send_unit[j]}
    return block, units, redone


def _stack_values(values):
    """Per quantity, the points' values stacked (equal names and shapes, or the error
    build_table gives)."""
    names = sorted(values[0])
    out = {}
    for name in names:
        try:
            stack = [np.asarray(v[name], dtype=float) for v in values]
        except KeyError as missing:
            raise ModelError(f"quantity {missing} is missing at some grid points") from None
        if any(a.shape != stack[0].shape for a in stack):
            raise ModelError(f"quantity {name!r} changes shape across the grid")
        out[name] = np.array(stack)
    return out


def tabulate_by_lines(client: Client, token: str, gshape: tuple[int, ...],
                      point_args: Sequence[tuple], point_kept: Callable,
                      tracked_point: Callable, quantities: Callable, n_modes: int,
                      boundary: set, weighting: str | None, *, progress: bool = False,
                      per_worker: int | None = None) -> dict:
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
    per_worker : int, optional
        Blocks per worker thread (:func:`line_blocks`; default :data:`BLOCKS_PER_WORKER`).

    Returns
    -------
    dict
        ``tracking`` (:class:`casflex.modal.GridTracking` of all the computed modes),
        ``omega`` (grid shape + (n_modes,)) [rad/s], ``shifted`` (grid of bool: modes from
        a shifted configuration), ``values`` (per quantity, its values over the grid:
        grid shape + the quantity's shape),
        ``tracked`` (object grid: tracked features at ``boundary``), ``redone`` (a block
        whose raw modes were gone was recomputed), ``modes_done`` and
        ``tracking_done`` (``time.perf_counter()`` [s] at the end of the first stage and
        of the base plane's tracking).

    Examples
    --------
    On a cluster ``client`` (a doctest would pay its start-up; see
    ``tests/modal/test_gridlines.py``), :func:`casflex.modal.build_table` calls it for a grid
    of two or more shape joints without a cache. Without one the blocks are planned alone:

    >>> [b.tolist() for b in line_blocks(10, 2, per_worker=2)]
    [[0, 1, 2], [3, 4, 5], [6, 7], [8, 9]]
    """
    import time

    n_last, ndim = gshape[-1], len(gshape)
    line_shape = gshape[:-1]
    n_lines = int(np.prod(line_shape))
    workers = max(1, sum(client.nthreads().values()))
    blocks = line_blocks(n_lines, workers, per_worker, n_last)
    block_of = np.empty(n_lines, dtype=int)
    for b, lines in enumerate(blocks):
        block_of[lines] = b
    # per axis but the last: the line index offset of the previous neighbour
    line_strides = [int(np.prod(line_shape[a + 1:])) for a in range(ndim - 1)]
    line_index = list(np.ndindex(line_shape)) if line_shape else [()]
    on_boundary = np.zeros(int(np.prod(gshape)), dtype=bool)
    for idx in boundary:
        on_boundary[np.ravel_multi_index(idx, gshape)] = True

    def block_args(lines):
        flats = [int(line) * n_last + i for line in lines for i in range(n_last)]
        return {"points": [point_args[f] for f in flats], "n_last": n_last,
                "lines": lines, "func": quantities, "robot": point_args[0][0],
                "n_modes": int(n_modes), "weighting": weighting,
                "boundary": [bool(on_boundary[f]) for f in flats],
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

    m, n_total = gb.order.shape[-1], int(np.prod(gshape))
    # the grid's arrays, and flat views of them in C order: a block's points are one
    # contiguous range
    transform = np.empty(n_total, dtype=object)
    order = np.empty((n_total, m), dtype=int)
    sign = np.empty((n_total, m))
    mac = np.full((n_total, m), np.nan)
    degenerate = np.zeros(n_total, dtype=bool)
    edge = np.full((n_total, ndim, m), np.nan)
    omega = np.empty((n_total, int(n_modes)))
    tracked = np.empty(n_total, dtype=object)
    base_flat = np.arange(n_lines) * n_last
    mac[base_flat] = gb.mac.reshape(n_lines, m)  # the base plane: tracked here
    degenerate[base_flat] = gb.degenerate.reshape(n_lines)
    edge[base_flat, :ndim - 1] = gb.edge_correlation.reshape(n_lines, ndim - 1, m)
    values, units, redone = [None] * len(blocks), {}, False
    jobs = [(b, (point_kept, tracked_point, a,
                 [gb.transform[line_index[int(line)]] for line in a["lines"]],
                 [int(line) in need for line in a["lines"]])) for b, a in enumerate(args)]
    for b, (block, got_units, again) in map_kept(
            _block_tables, jobs, client, token, where, progress=progress,
            desc="quantities (blocks of grid lines)", chunksize=1):
        units.update(got_units)
        redone = redone or again
        at = slice(int(blocks[b][0]) * n_last, (int(blocks[b][-1]) + 1) * n_last)
        for k, t in enumerate(block["transform"]):
            transform[at.start + k] = t
        order[at], sign[at], omega[at] = block["order"], block["sign"], block["omega"]
        rest = np.arange(at.start, at.stop) % n_last > 0  # the base plane's are set
        mac[at][rest], degenerate[at][rest] = block["mac"][rest], block["degenerate"][rest]
        edge[at][block["has_edge"]] = block["edges"][block["has_edge"]]
        for p, features in block["features"].items():
            tracked[at.start + p] = features
        values[b] = block["values"]
    for a, prev, line in cross:
        for i in range(1, n_last):
            edge[line * n_last + i, a] = _edge(units[prev][i], units[line][i])
    stacked = {}
    for name in values[0]:
        parts = [v.get(name) for v in values]
        if any(v is None or v.shape[1:] != parts[0].shape[1:] for v in parts):
            raise ModelError(f"quantity {name!r} changes shape across the grid")
        stacked[name] = np.concatenate(parts).reshape(gshape + parts[0].shape[1:])
    transform = transform.reshape(gshape)
    result = trk.GridTracking(
        transform=transform, order=order.reshape(gshape + (m,)),
        sign=sign.reshape(gshape + (m,)), mac=mac.reshape(gshape + (m,)),
        degenerate=degenerate.reshape(gshape), edge_correlation=edge.reshape(
            gshape + (ndim, m)))
    return {"tracking": result, "omega": omega.reshape(gshape + (int(n_modes),)),
            "shifted": shifted, "values": stacked, "tracked": tracked.reshape(gshape),
            "redone": redone, "modes_done": t_modes, "tracking_done": t_tracking}
