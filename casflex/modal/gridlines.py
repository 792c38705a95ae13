"""A table build on a Dask cluster by grid lines: the tracking done on the workers.

:func:`casflex.modal.build_table` without a cache on a Dask cluster, for a grid of two or
more shape joints. :func:`casflex.modal.track_grid`'s spanning tree is a comb: the base
plane (every point whose last index is 0) is tracked first, then every line along the
last axis from its base point, each line on its own. So, as one graph
(:func:`casflex._parallel.map_keep_reduce_use`):

1. each task takes a block of whole lines (consecutive in the grid's C order), computes
   the raw modes of their points and keeps them on its worker; only the tracking data of
   the lines' base points (one point per line) leave it, for
2. one task that tracks the base plane (:func:`casflex.modal.track_grid_features` on
   it), whose result goes to
3. each block's second task, on the worker holding the block: it tracks its lines from
   their base transforms (:func:`casflex.modal.track_path_features`), makes the tracked
   modes and the quantities, and the edge correlations between neighbours it holds
   (:func:`casflex.modal.tracked_unit_features`). Only these results come to the client,
   and the unit feature rows of lines that meet a line of another block, for the edges
   between blocks.

Every number is made by the same calls on the same inputs as :func:`track_grid` and the
per-point quantities: the table is bit for bit the serial one. Per point, the client
receives the quantities and a few numbers (transform, MAC, edges), not the 20–30 kB of
MAC features; a build is two tasks per block and one more, submitted at once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from casflex._parallel import map_keep_reduce_use
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
    base points' tracking data (one per line) go on to the base plane's tracking."""
    kept = [point_kept(*a) for a in args["points"]]
    return [kept[i][0] for i in range(0, len(kept), args["n_last"])], kept


def _track_base(summaries, blocks, line_shape):
    """Stage 2, one task: the base plane tracked from the blocks' base points."""
    base = np.empty(line_shape, dtype=object)
    flat = base.reshape(-1)  # a view: C order, as the lines are numbered
    for b, data in summaries.items():
        for line, point in zip(blocks[b], data, strict=True):
            flat[int(line)] = point
    return trk.track_grid_features(base)


def _edge(u_prev, u_cur):
    """Signed correlation of the tracked modes across a grid edge (as track_grid)."""
    return np.sum(u_prev * u_cur, axis=1)


def _block_tables(kept, base, point_kept, tracked_point, args, send_unit):
    """Stage 3 of a block on the worker keeping its modes (recomputed where they are
    gone): track its lines from their base transforms (``base``: the base plane's
    :class:`casflex.modal.GridTracking`), the edges inside the block, the tracked modes'
    quantities."""
    redone = kept is None
    if redone:
        kept = _block_modes(point_kept, args)[1]
    n_last, lines, strides = args["n_last"], args["lines"], args["line_strides"]
    n_points = len(kept)
    ndim, m = len(strides) + 1, base.order.shape[-1]
    T = [None] * n_points
    mac = [None] * n_points
    degenerate = [None] * n_points
    # the base plane's results at this block's lines (the base plane's flat index of a
    # point is its line's)
    rows = np.asarray(lines, dtype=int)
    base_T = base.transform.reshape(-1)[rows]
    base_mac = base.mac.reshape(-1, m)[rows]
    base_degenerate = base.degenerate.reshape(-1)[rows]
    base_edges = base.edge_correlation.reshape(-1, ndim - 1, m)[rows]
    edges = np.full((n_points, ndim, m), np.nan)  # NaN: no neighbour
    for j in range(len(rows)):
        first = j * n_last
        T[first], mac[first], degenerate[first] = base_T[j], base_mac[j], base_degenerate[j]
        edges[first, :ndim - 1] = base_edges[j]
        if n_last > 1:
            path = [kept[first + i][0] for i in range(1, n_last)]
            tr = trk.track_path_features(path, T[first] @ kept[first][0]["features"])
            for i in range(1, n_last):
                T[first + i] = tr.transform[i - 1]
                mac[first + i], degenerate[first + i] = tr.mac[i - 1], tr.degenerate[i - 1]
    unit = [trk.tracked_unit_features(t, data["features"])
            for t, (data, _) in zip(T, kept, strict=True)]
    position = {int(line): j for j, line in enumerate(lines)}
    # the block's results stacked per field: a few arrays for the client to unpickle,
    # not a dict per point
    order = np.argmax(np.abs(np.array(T)), axis=2)
    sign = np.empty((n_points, m))
    values, features = [], {}
    for p, ((_, arrays), t) in enumerate(zip(kept, T, strict=True)):
        j, i = divmod(p, n_last)
        s = np.sign(t[np.arange(m), order[p]])
        s[s == 0] = 1.0
        sign[p] = s
        if i > 0:  # along the last axis, inside the line; the others: across lines
            edges[p, ndim - 1] = _edge(unit[p - 1], unit[p])
            for axis, (stride, at_start) in enumerate(strides):
                prev = position.get(int(lines[j]) - stride)
                if not at_start[j] and prev is not None:
                    edges[p, axis] = _edge(unit[prev * n_last + i], unit[p])
        got, tracked, _ = tracked_point(
            arrays, args["func"], args["robot"], args["points"][p][1], t, order[p],
            args["n_modes"], args["boundary"][p], args["weighting"], None)
        values.append(got)
        if tracked is not None:
            features[p] = tracked
    block = {"transform": np.array(T), "order": order, "sign": sign, "mac": np.array(mac),
             "degenerate": np.array([bool(d) for d in degenerate]), "edges": edges,
             "shifted": np.array([bool(np.any(data["shift"] != 0.0)) for data, _ in kept]),
             "values": _stack_values(values),
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
    n_last, ndim = gshape[-1], len(gshape)
    line_shape = gshape[:-1]
    n_lines = int(np.prod(line_shape))
    nthreads = client.nthreads()
    blocks = line_blocks(n_lines, max(1, sum(nthreads.values())), per_worker, n_last)
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
    # lines whose neighbour along an axis but the last lies in another block: their
    # unit feature rows come here for the edges between blocks
    cross = []
    for line in range(n_lines):
        for a, s in enumerate(line_strides):
            if line_index[line][a] > 0 and block_of[line - s] != block_of[line]:
                cross.append((a, line - s, line))
    need = {line for _, prev, line in cross} | {prev for _, prev, _ in cross}

    results, units, redone, times = [None] * len(blocks), {}, False, {}
    jobs = [(b, (point_kept, a), (point_kept, tracked_point, a,
                                  [int(line) in need for line in a["lines"]]))
            for b, a in enumerate(args)]
    for b, (block, got_units, again) in map_keep_reduce_use(
            _block_modes, functools.partial(_track_base, blocks=blocks,
                                            line_shape=line_shape),
            _block_tables, jobs, client, token, nthreads=nthreads, progress=progress,
            descs=("TMM (blocks of grid lines)", "quantities (blocks of grid lines)"),
            stage_times=times):
        results[b] = block
        units.update(got_units)
        redone = redone or again

    # the blocks are consecutive ranges of the grid in C order: joined in block order,
    # their rows are the grid's
    def joined(field):
        return np.concatenate([r[field] for r in results])

    edge = joined("edges")
    for a, prev, line in cross:
        for i in range(1, n_last):
            edge[line * n_last + i, a] = _edge(units[prev][i], units[line][i])
    stacked = {}
    for name in results[0]["values"]:
        parts = [r["values"].get(name) for r in results]
        if any(v is None or v.shape[1:] != parts[0].shape[1:] for v in parts):
            raise ModelError(f"quantity {name!r} changes shape across the grid")
        stacked[name] = np.concatenate(parts).reshape(gshape + parts[0].shape[1:])
    transform = np.empty(int(np.prod(gshape)), dtype=object)
    for k, t in enumerate(joined("transform")):
        transform[k] = t
    transform = transform.reshape(gshape)
    tracked = np.empty(transform.size, dtype=object)
    start = 0
    for r in results:
        for p, features in r["features"].items():
            tracked[start + p] = features
        start += len(r["order"])
    m = results[0]["order"].shape[1]
    result = trk.GridTracking(
        transform=transform, order=joined("order").reshape(gshape + (m,)),
        sign=joined("sign").reshape(gshape + (m,)), mac=joined("mac").reshape(gshape + (m,)),
        degenerate=joined("degenerate").reshape(gshape),
        edge_correlation=edge.reshape(gshape + (ndim, m)))
    return {"tracking": result, "omega": joined("omega").reshape(gshape + (int(n_modes),)),
            "shifted": joined("shifted").reshape(gshape), "values": stacked,
            "tracked": tracked.reshape(gshape), "redone": redone,
            "modes_done": times["keep"], "tracking_done": times["reduce"]}
