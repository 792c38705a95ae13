"""Modal tables over a grid of shape joints: parallel TMM, tracking, cache, interpolants.

The flexible part of the model (118) depends on the configuration only through the mode
shapes, and those depend only on the joints that change the *shape* of the structure
(§3.3.6.2: "all of the modes can be computed a-priori based on the joint configuration
space"). This module tabulates them:

1. :func:`shape_joints` finds those joints (the rule is written there).
2. :func:`build_table` runs the TMM (:func:`casflex.tmm.modes`) at every point of a grid of
   the shape joints — in parallel, on a local process pool or a Dask cluster (without a
   cache the raw modes stay on its workers) — then tracks identity and sign sequentially
   (:mod:`casflex.modal.tracking`; on a Dask cluster without a cache, a grid of two or
   more shape joints line by line on the workers: :mod:`casflex.modal.gridlines`), then
   evaluates the model quantities (by default
   :func:`casflex.modal.integrals.configuration_quantities` after
   :func:`casflex.modal.normalize.mass_normalize`).
3. :class:`ModalTable` turns any tabulated quantity into a ``casadi.Function`` of the
   shape-joint values with ``casadi.interpolant`` (B-spline by default; one-axis tables
   also by :mod:`casflex.modal.table_functions`): what the dynamics consumes.

Multiple roots
--------------
Where the TMM reports a multiple root (the Table 8 arm folded at q3 = 90°) the modes are
taken "from the direct vicinity" (§3.3.6.1): the point's frequencies are kept and the
shapes are computed at ``q + ε`` along a shape joint (ε = 1e-4, 1e-3 or 1e-2 rad, the
first at which every root is simple). The tracker then treats the point like any other.
(The degenerate-subspace fit of :func:`casflex.modal.tracking.track` is the fallback when
no such ε is found.)

Cache
-----
Results are cached on disk under ``cache_dir`` (default ``$CASFLEX_CACHE`` or
``~/.cache/casflex``) in two directories:

``modes-<key>/``
    one ``.npz`` per grid point with the raw TMM modes, written atomically (temporary
    file + ``os.replace``) as each point finishes; key = SHA-256 of the robot's parameters
    (every field of every link: DH row, joint, section, material, tip body, motor inertia,
    joint spring; gravity and damping — not its name, description or file path), the
    shape joints and the fixed joints' values, the grid, the number of modes, the sample
    points per beam, ``casflex.__version__`` and a digest of the TMM source files.
``table-<key>/``
    one ``.npz`` per point with the quantities and the consolidated ``table.npz``; key =
    the modes key plus the tracking settings and the quantity function's identity (module,
    name, version attribute, digest of its source).

Every file stores its key and a digest of its content and is verified on reading; a file
that does not verify (stale, foreign, truncated, altered) is recomputed and overwritten,
so a stale cache is never used. A build that is interrupted resumes where it stopped:
finished points are skipped on restart, and its leftover temporary files are removed.
Processes building the same table at once share the work: each point is claimed with a
``.claim`` file (:func:`casflex._cache.build_shared`), computed by one process and read
by the others.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
import uuid
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike

import casflex
from casflex._cache import (
    atomic_write_text,
    build_shared,
    default_cache_dir,
    digest,
    load_verified,
    remove_stale_files,
    save_verified,
    source_digest,
)
from casflex._parallel import drop_kept, map_keep, map_kept, parallel_map
from casflex.errors import ModelError
from casflex.modal import gridlines, rotated, subspace
from casflex.modal import tracking as trk
from casflex.modal.fits import periodic_axis_kind
from casflex.modal.table_functions import grid_function
from casflex.modal.tablekeys import (
    canonical,
    function_identity,
    robot_fingerprint,
    tmm_digest,
)

if TYPE_CHECKING:
    import casadi as ca
    from dask.distributed import Client

    from casflex.robot import Robot
    from casflex.tmm.solve import ModeShapes

__all__ = [
    "shape_joints",
    "compute_modes",
    "build_table",
    "ModalTable",
    "default_quantities",
    "robot_fingerprint",
    "default_cache_dir",
]

FORMAT_VERSION = 1
#: modes computed beyond the requested count so that modes crossing in from above are seen
EXTRA_MODES = 2
#: shifts [rad] tried, in order, to step off a configuration with a multiple root
DEGENERATE_SHIFTS = (1e-4, 1e-3, 1e-2)
#: below this MAC between tracked grid neighbours build_table warns (RuntimeWarning)
MIN_MAC = 0.8
#: Largest grid (points) :func:`build_table` starts on: a grid of ``max_points`` points
#: holds every point's mode shapes in memory (roughly ``count × flexible links × n_points ×
#: 12 × 8`` bytes each, ~80 kB for the case-study arm) and costs one TMM solve per point
#: (~15 ms per flexible link on one core). Override per call (``max_points=``) or with the
#: environment variable ``CASFLEX_MAX_GRID_POINTS``.
MAX_GRID_POINTS = 100_000
#: basis of the time estimate in the grid-size error [s per point and flexible link]
SECONDS_PER_POINT_AND_LINK = 0.015
#: keep a Dask build's raw modes on the workers (no cache; False: the path before)
KEEP_ON_WORKERS = True
#: with them kept, track grids of 2+ shape joints there by lines (casflex.modal.gridlines)
TRACK_ON_WORKERS = True


# ------------------------------------------------------------------ shape joints


def _collinear(p1, a1, p2, a2, tol=1e-9):
    """True when the lines ``p1 + t a1`` and ``p2 + t a2`` coincide."""
    a1 = a1 / np.linalg.norm(a1)
    a2 = a2 / np.linalg.norm(a2)
    if np.linalg.norm(np.cross(a1, a2)) > tol:
        return False
    d = p2 - p1
    return np.linalg.norm(d - np.dot(d, a1) * a1) <= tol * max(1.0, np.linalg.norm(d))


#: shape_joints' answers by (robot fingerprint, samples)
_SHAPE_JOINTS: dict = {}


def shape_joints(robot: Robot, samples: int = 3) -> tuple[int, ...]:
    """Indices (0-based) of the joints that change the shape of the structure.

    Rule: rotating joint ``k`` moves everything outboard of it rigidly about the joint's
    axis line. If nothing inboard of that rotation could tell — every element the chain
    walk (:func:`casflex.tmm.chain.build_chain`) meets before joint ``k``'s rotation is a
    massless rigid offset, or a joint spring whose axis line coincides with joint ``k``'s
    axis line (a spring is invariant under rotations about its own axis) — the whole
    structure including the clamp is congruent for every value of ``q_k``, so its natural
    frequencies and its mode shapes in the link frames do not depend on ``q_k``. Any
    beam or tip body inboard (or a spring about another line) makes ``q_k`` a shape joint.
    The test is made at ``q = 0`` and at ``samples`` fixed pseudo-random configurations
    (the geometry of the inboard springs may depend on other joints).

    Parameters
    ----------
    robot : casflex.robot.Robot
    samples : int
        Extra configurations checked besides ``q = 0``.

    Returns
    -------
    tuple of int
        Joint indices (0-based, i.e. ``q[k]``) in increasing order.

    Examples
    --------
    >>> from casflex.robot import load
    >>> shape_joints(load("problems/arm2link.toml"))   # only the elbow q3
    (2,)
    >>> shape_joints(load("problems/testbed.toml"))    # joint springs: q2 and q3
    (1, 2)
    """
    from casflex.tmm.chain import build_chain

    # the answer depends on the links alone: kept per fingerprint (a table build asks
    # for it every time, ~1 ms of a Dask build's client CPU)
    key = (robot_fingerprint(robot), int(samples))
    if key in _SHAPE_JOINTS:
        return _SHAPE_JOINTS[key]
    rng = np.random.default_rng(12345)
    configs = [np.zeros(robot.n_joints)]
    configs += [rng.uniform(-math.pi, math.pi, robot.n_joints) for _ in range(samples)]
    rows = robot.joint_rows
    out = set()
    for q in configs:
        chain = build_chain(robot, q)
        frames = robot.frames(q)
        for k, row in enumerate(rows):
            point, axis = frames[row][:3, 3], frames[row][:3, 2]
            link = robot.links[row]
            for e in chain.elements:
                inboard = e.row < row or (
                    e.row == row and link.beam_along == "a" and e.kind in ("beam", "body"))
                if not inboard or e.kind == "offset":
                    continue
                if e.kind == "spring" and _collinear(e.start, e.params["axis"], point, axis):
                    continue
                out.add(k)
                break
    if len(_SHAPE_JOINTS) >= 64:
        _SHAPE_JOINTS.clear()
    _SHAPE_JOINTS[key] = tuple(sorted(out))
    return _SHAPE_JOINTS[key]


# ------------------------------------------------------------------ per-point work


def _point_modes(robot, q, count, n_points, directions):
    """Raw TMM modes at ``q`` as a dict of arrays (run in worker processes)."""
    from casflex.tmm import modes

    shapes = modes(robot, q, count=count, n_points=n_points)
    shift = np.zeros(len(q))
    if np.any(np.asarray(shapes.multiplicity) > 1):
        done = False
        for eps in DEGENERATE_SHIFTS:
            for d in directions:
                near = modes(robot, np.asarray(q) + eps * d, count=count, n_points=n_points)
                if np.all(np.asarray(near.multiplicity) == 1):
                    # shapes (local components) from q + eps·d; frequencies and geometry of q
                    shapes = dataclasses.replace(
                        shapes, multiplicity=np.ones_like(near.multiplicity),
                        **{f: getattr(near, f) for f in trk.MODE_FIELDS})
                    shift = eps * np.asarray(d, dtype=float)
                    done = True
                    break
            if done:
                break
    out = _shapes_to_arrays(shapes)
    out["shift"] = shift
    return out


def _shapes_to_arrays(shapes):
    out = {}
    for f in dataclasses.fields(shapes):
        v = getattr(shapes, f.name)
        out[f.name] = np.asarray(v, dtype=int if isinstance(v, tuple) else None)
    return out


def _arrays_to_shapes(arrays):
    from casflex.tmm.solve import ModeShapes

    kw = {}
    for f in dataclasses.fields(ModeShapes):
        v = arrays[f.name]
        kw[f.name] = tuple(int(x) for x in np.ravel(v)) if f.name.endswith("rows") else v
    return ModeShapes(**kw)


def default_quantities(robot: Robot, q: np.ndarray, shapes: ModeShapes) -> dict[str, np.ndarray]:
    """Mass-normalise the tracked shapes and evaluate the model quantities at ``q``.

    ``casflex.modal.integrals.configuration_quantities(robot, q,
    casflex.modal.normalize.mass_normalize(...))``; the normalisation must scale every mode
    by a positive factor so that the tracked sign survives.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : numpy.ndarray
        Joint variables [rad].
    shapes : ModeShapes
        Tracked, sign-corrected modes.

    Returns
    -------
    dict of str to numpy.ndarray
        Keys, shapes and units as in :mod:`casflex.modal.integrals`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> q = np.zeros(3)
    >>> values = default_quantities(robot, q, modes(robot, q, count=2))
    >>> print(*sorted(values))
    C1 C2 N end_theta end_u eps omega sample_theta sample_u spring_phi
    >>> values["omega"].round(3), values["C2"].shape
    (array([ 8.307, 11.97 ]), (2, 2, 2, 4, 4))
    """
    from casflex.modal.integrals import configuration_quantities
    from casflex.modal.normalize import mass_normalize

    return configuration_quantities(robot, q, mass_normalize(robot, shapes))


def _point_quantities(func, robot, q, arrays):
    """Quantities of one point from the tracked shape arrays (run in worker processes)."""
    values = func(robot, np.asarray(q, dtype=float), _arrays_to_shapes(arrays))
    if not isinstance(values, dict):
        raise ModelError(f"the quantity function must return a dict; got {type(values)}")
    return {str(k): np.asarray(v, dtype=float) for k, v in values.items()}


def _first_modes(t, n_modes):
    keep = slice(0, int(n_modes))
    return dataclasses.replace(t, **{f: getattr(t, f)[keep] for f in (
        "omega", "multiplicity", *trk.MODE_FIELDS)})


def _point_kept(robot, q, count, n_points, directions, weighting):
    """Raw modes at ``q`` to keep on the worker, and the tracking's data of them (what
    the client needs: :func:`casflex.modal.tracking.point_tracking_data`)."""
    arrays = _point_modes(robot, q, count, n_points, directions)
    data = trk.point_tracking_data(_arrays_to_shapes(arrays), robot, weighting)
    data["shift"] = arrays["shift"]
    return data, arrays


def _tracked_point(arrays, func, robot, q, transform, order, n_modes, boundary, weighting,
                   redo):
    """Quantities of a point from its kept raw modes (or ``redo``ne), tracked here; the
    tracked features where the periodicity check needs them (``boundary``); if redone."""
    redone = arrays is None
    arrays = _point_modes(*redo) if redone else arrays
    tracked = _first_modes(trk.combine(_arrays_to_shapes(arrays), transform, order), n_modes)
    return (_point_quantities(func, robot, q, _shapes_to_arrays(tracked)),
            trk.shape_features(tracked, robot, weighting) if boundary else None, redone)


def compute_modes(robot: Robot, qs: ArrayLike, count: int, *, n_points: int = 51,
                  client: Client | None = None, processes: int | None = None,
                  progress: bool = False,
                  directions: Sequence[ArrayLike] | None = None) -> list[ModeShapes]:
    """Raw TMM modes at many configurations, in parallel, in the order of ``qs``.

    Parameters
    ----------
    robot : casflex.robot.Robot
    qs : array_like
        (N, n_joints) joint variables [rad].
    count : int
        Modes per configuration.
    n_points : int
        Sample points per beam.
    client : dask.distributed.Client, optional
        Map over this cluster instead of a local process pool.
    processes : int, optional
        Local worker processes (default ``os.cpu_count()``; ``1`` runs in this process).
    progress : bool
        Show a tqdm progress bar on stderr.
    directions : sequence of array_like, optional
        Unit joint-space directions tried to step off a multiple root (see the module
        notes); default ``±e_k`` for every shape joint (:func:`shape_joints`).

    Returns
    -------
    list of ModeShapes

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> out = compute_modes(robot, [[0, 0, 0.0], [0, 0, 0.1]], 3, processes=1)
    >>> [s.omega.size for s in out]
    [3, 3]
    """
    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    if directions is None:
        eye = np.eye(robot.n_joints)
        directions = [s * eye[k] for k in (shape_joints(robot) or range(robot.n_joints))
                      for s in (1.0, -1.0)]
    jobs = [(i, (robot, q, count, n_points, directions)) for i, q in enumerate(qs)]
    out = [None] * len(qs)
    for i, arrays in parallel_map(_point_modes, jobs, client=client, processes=processes,
                               progress=progress, desc="TMM"):
        out[i] = _arrays_to_shapes(arrays)
    return out


# ------------------------------------------------------------------ keys and files


# ------------------------------------------------------------------ the table


@dataclass(frozen=True)
class ModalTable:
    """Tabulated modal quantities over a grid of shape joints.

    Attributes
    ----------
    grid : tuple of numpy.ndarray
        One strictly increasing axis per shape joint [rad].
    shape_joints : tuple of int
        0-based joint index of each grid axis.
    values : dict of str to numpy.ndarray
        ``grid_shape + value_shape`` arrays; always holds ``"omega"``.
    omega : numpy.ndarray
        ``grid_shape + (n_modes,)`` tracked natural frequencies [rad/s].
    q_fixed : numpy.ndarray
        Values of the other joints used in the computation [rad] (they do not change the
        tabulated quantities).
    periodic : tuple of bool
        Per axis: spans a full turn and the tracked modes close up consistently (identity
        and sign), so :meth:`function` wraps that input periodically.
    info : dict
        Build information: keys, computed/cached point counts, tracking quality, timing.

    Examples
    --------
    >>> t = ModalTable(grid=(np.linspace(0, 1, 5),), shape_joints=(2,),
    ...                values={"omega": np.outer(np.arange(5.0), [1.0, 2.0])},
    ...                omega=np.outer(np.arange(5.0), [1.0, 2.0]))
    >>> t.function("omega")(0.5).full().ravel().round(6).tolist()
    [2.0, 4.0]
    """

    grid: tuple[np.ndarray, ...]
    shape_joints: tuple[int, ...]
    values: dict[str, np.ndarray]
    omega: np.ndarray
    q_fixed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    periodic: tuple[bool, ...] = ()
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape."""
        return tuple(a.size for a in self.grid)

    @property
    def names(self) -> list[str]:
        """Names of the tabulated quantities."""
        return sorted(self.values)

    def q(self, index: Sequence[int]) -> np.ndarray:
        """Full joint vector [rad] of the grid point ``index``.

        Parameters
        ----------
        index : tuple of int
            One index per grid axis.

        Returns
        -------
        numpy.ndarray, shape (n_joints,)
            ``q_fixed`` with the shape joints set to the grid values [rad].

        Examples
        --------
        >>> t = ModalTable(grid=(np.linspace(0, 1, 5),), shape_joints=(2,),
        ...                values={"omega": np.ones((5, 1))}, omega=np.ones((5, 1)),
        ...                q_fixed=np.array([0.1, 0.2, 0.0]))
        >>> t.q((3,)).tolist()
        [0.1, 0.2, 0.75]
        """
        q = np.array(self.q_fixed, dtype=float)
        for axis, k, i in zip(self.grid, self.shape_joints, index, strict=True):
            q[k] = axis[i]
        return q

    def function(self, name: str, method: str = "bspline", entries: ArrayLike | None = None,
                 lookup: str = "interpolant") -> ca.Function:
        """``casadi.Function`` interpolating quantity ``name`` over the grid.

        Parameters
        ----------
        name : str
            A key of ``values`` (``"omega"`` included).
        method : {"bspline", "linear"}
            ``casadi.interpolant`` plugin; B-splines (cubic, interpolating, needing at
            least 4 points per axis) give smooth derivatives for the dynamics.
        entries : sequence of int, optional
            Interpolate only these entries of the value (indices into the value flattened
            in C order); the output is then the column vector of those entries. The
            model uses it to leave out entries that vanish everywhere.
        lookup : {"interpolant", "local", "static"}
            ``"local"``: one-axis B-splines by :func:`casflex.modal.table_functions.
            local_bspline_function` (the same spline, leaner C); ``"static"``: the same
            with its table kept out of the declared work memory (``rows="static"``); else
            ``casadi.interpolant``.

        Returns
        -------
        casadi.Function
            ``f(q_shape) -> value`` with ``q_shape`` the vector of the shape joints'
            values (in the order of ``shape_joints``, rad). Scalars and vectors come out
            as column vectors, matrices with their shape, higher arrays flattened in C
            order. Periodic axes are wrapped into the grid's period; beyond a
            non-periodic axis (a joint limit) the value at its end is held.

        Examples
        --------
        >>> t = ModalTable(grid=(np.linspace(0, 3, 7),), shape_joints=(0,),
        ...                values={"m": np.arange(7.0)[:, None, None] * np.ones((7, 2, 2))},
        ...                omega=np.ones((7, 1)))
        >>> t.function("m")(1.0).shape
        (2, 2)
        """
        values = {"omega": self.omega, **self.values}
        if name not in values:
            raise ModelError(f"no quantity {name!r} in the table; it has {self.names}")
        data = np.asarray(values[name], dtype=float)
        nd = len(self.shape)
        if entries is not None:
            cols = np.asarray(entries, dtype=int).ravel()
            size = int(np.prod(data.shape[nd:]))
            if cols.size and (cols.min() < 0 or cols.max() >= size):
                raise ModelError(f"entries of {name!r} must lie in [0, {size}); got "
                                 f"{cols.min()}..{cols.max()}")
            data = data.reshape(self.shape + (size,))[..., cols]
        return grid_function(name, self.grid, data, periodic=self.periodic, method=method,
                             lookup=lookup)


def _check_grid(robot, grid, joints):
    if len(joints) == 1 and np.ndim(grid) == 1 and not isinstance(grid[0], (list, tuple,
                                                                           np.ndarray)):
        grid = [grid]
    grid = [np.asarray(a, dtype=float) for a in grid]
    if len(grid) != len(joints):
        raise ModelError(f"the grid has {len(grid)} axes but the shape joints are "
                         f"{[k + 1 for k in joints]} (1-based); give one axis per shape joint")
    for i, a in enumerate(grid):
        if a.ndim != 1 or a.size < 1:
            raise ModelError(f"grid axis {i} must be a non-empty 1-D array; got shape "
                             f"{a.shape}")
        if not np.all(np.isfinite(a)):
            raise ModelError(f"grid axis {i} must be finite")
        if a.size > 1 and np.any(np.diff(a) <= 0.0):
            raise ModelError(f"grid axis {i} must be strictly increasing")
    for k in joints:
        if not 0 <= k < robot.n_joints:
            raise ModelError(f"shape joint index {k} out of range for a robot with "
                             f"{robot.n_joints} joints")
    return tuple(grid)


def _check_grid_size(robot, grid, joints, count, n_points, max_points):
    """Refuse a grid too large to tabulate before any work (a 20-link robot: 19-D)."""
    if max_points is None:
        env = os.environ.get("CASFLEX_MAX_GRID_POINTS")
        if env is None:
            max_points = MAX_GRID_POINTS
        else:
            try:
                max_points = int(env)
            except ValueError:
                raise ModelError(f"CASFLEX_MAX_GRID_POINTS = {env!r}: must be a whole "
                                 "number of grid points") from None
    points = math.prod(a.size for a in grid)
    if points <= max_points:
        return
    links = max(len(robot.flexible_links), 1)
    seconds = points * links * SECONDS_PER_POINT_AND_LINK
    memory = points * count * links * int(n_points) * 12 * 8
    sizes = " x ".join(str(a.size) for a in grid)
    raise ModelError(
        f"robot '{robot.name}': the modal table's grid over the {len(joints)} shape joints "
        f"{[k + 1 for k in joints]} has {sizes} = {float(points):.3g} points, above the "
        f"limit of {max_points} (about {seconds / 3600.0:.3g} h of TMM on one core and "
        f"{memory / 1e9:.3g} GB of mode shapes); use fewer shape joints (lock joints or "
        "make links rigid), a coarser grid step, or raise max_points / "
        "CASFLEX_MAX_GRID_POINTS if the grid is meant")


def build_table(robot: Robot, grid: ArrayLike | Sequence[ArrayLike], n_modes: int,
                quantities: (Callable[[Robot, np.ndarray, ModeShapes], Mapping[str, ArrayLike]]
                             | Literal[False] | None) = None,
                cache_dir: str | os.PathLike[str] | Literal[False] | None = None,
                client: Client | None = None, processes: int | None = None,
                progress: bool = False, *, joints: Sequence[int] | None = None,
                q_fixed: ArrayLike | None = None, extra_modes: int = EXTRA_MODES,
                n_points: int = 51, weighting: str | None = None,
                max_points: int | None = None, basis: str = "eigen") -> ModalTable:
    """Tabulate tracked modes and model quantities over a grid of the shape joints.

    Parameters
    ----------
    robot : casflex.robot.Robot
    grid : array_like or sequence of array_like
        One strictly increasing axis [rad] per shape joint (a single 1-D array when there
        is one). An axis spanning a full turn (ends 2π apart, or uniform with the next
        step closing the turn) is extended periodically by :meth:`ModalTable.function`.
    n_modes : int
        Number of tracked modes to tabulate.
    quantities : callable or False, optional
        ``quantities(robot, q, tracked_shapes) -> dict[str, array]`` evaluated at every
        point (must be picklable for the process pool: a module-level function). Default:
        :func:`default_quantities`; ``False`` tabulates ω and the tracked shape fields
        (unit peak displacement).
    cache_dir : str or Path or False, optional
        Cache directory (default :func:`default_cache_dir`); ``False`` disables caching.
    client : dask.distributed.Client, optional
        Map the per-point work over this cluster instead of a local process pool
        (without a cache and with two or more shape joints, the tracking too, by grid
        lines: :func:`casflex.modal.tabulate_by_lines`).
    processes : int, optional
        Local worker processes (default ``os.cpu_count()``; ``1`` runs in-process).
    progress : bool
        tqdm progress bars on stderr (off by default; the CLI turns them on).
    joints : sequence of int, optional
        Shape joints (0-based) to tabulate over; default :func:`shape_joints`.
    q_fixed : array_like, optional
        Values of the other joints [rad] (default 0).
    extra_modes : int
        Modes computed beyond ``n_modes`` so that modes crossing in from above are tracked.
    n_points : int
        Sample points per beam of the TMM shapes.
    weighting : {"mass", "uniform"}, optional
        MAC weighting (see :mod:`casflex.modal.tracking`); default ``"mass"``.
    max_points : int, optional
        Largest grid to start on (default ``$CASFLEX_MAX_GRID_POINTS`` or
        :data:`MAX_GRID_POINTS`); a larger grid is a ``ModelError`` before any work,
        naming its size, the estimated time and memory, and what to do.
    basis : {"eigen", "smooth"}
        Tracked eigenmodes (default), or a smooth basis of clusters of close modes
        (:mod:`casflex.modal.subspace`, quantities by :mod:`casflex.modal.rotated`:
        ``omega`` = Rayleigh ω, and the ``stiffness``/``stiffness_root`` a model must use).

    Returns
    -------
    ModalTable

    Raises
    ------
    ModelError
        Bad grid, joints or counts.

    Warns
    -----
    RuntimeWarning
        When a tracked mode's MAC between grid neighbours falls below ``MIN_MAC`` (grid
        too coarse, or a requested mode left the computed set).

    Notes
    -----
    The per-point work is short (one TMM solve), so it is sent to workers in chunks (see
    :func:`casflex._parallel.parallel_map`). Dask's nanny starts workers with
    ``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-environ``): the
    TMM allocates many medium-sized arrays and glibc then returns memory to the system
    after every call, which slows it in a worker (see ``benchmarks/README_tables.md``).
    For table builds start the cluster under
    ``dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_":
    2**27})``.

    Examples
    --------
    >>> import tempfile
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> table = build_table(robot, np.radians([0.0, 10.0, 20.0, 30.0]), 3, quantities=False,
    ...                     cache_dir=tempfile.mkdtemp(), processes=1)
    >>> table.shape_joints, table.omega.shape
    ((2,), (4, 3))
    >>> f = table.function("omega")
    >>> bool(np.allclose(f(np.radians(10.0)).full().ravel(), table.omega[1]))
    True
    """
    t_start = time.perf_counter()
    if not isinstance(n_modes, (int, np.integer)) or n_modes < 1:
        raise ModelError(f"n_modes must be a positive integer; got {n_modes!r}")
    if basis not in ("eigen", "smooth"):
        raise ModelError(f"basis must be 'eigen' or 'smooth'; got {basis!r}")
    joints = shape_joints(robot) if joints is None else tuple(int(k) for k in joints)
    if not joints:
        raise ModelError(f"robot '{robot.name}' has no joint that changes its shape: its "
                         "modes are the same in every configuration; use casflex.tmm.modes")
    grid = _check_grid(robot, grid, joints)
    count = int(n_modes) + int(extra_modes)
    _check_grid_size(robot, grid, joints, count, n_points, max_points)
    q_fixed = (np.zeros(robot.n_joints) if q_fixed is None
               else robot.check_q(q_fixed).astype(float))
    if quantities is None:
        quantities = default_quantities
    gshape = tuple(a.size for a in grid)
    indices = list(np.ndindex(gshape))

    def q_at(idx):
        q = q_fixed.copy()
        for a, k, i in zip(grid, joints, idx, strict=True):
            q[k] = a[i]
        return q

    modes_key = digest({
        "format": FORMAT_VERSION, "casflex": casflex.__version__, "tmm": tmm_digest(),
        "robot": robot_fingerprint(robot), "joints": list(joints),
        "q_fixed": canonical(q_fixed), "grid": [canonical(a) for a in grid],
        "count": count, "n_points": int(n_points), "shifts": canonical(DEGENERATE_SHIFTS),
        "point": source_digest(_point_modes, _shapes_to_arrays),
    })
    table_key = digest({
        "modes": modes_key, "n_modes": int(n_modes), "weighting": weighting,
        "tracking": source_digest(trk), "quantities": function_identity(
            quantities if quantities else None),
        "tables": source_digest(build_table, ModalTable, grid_function),
        **({} if basis == "eigen" else {"basis": basis,
                                        "subspace": source_digest(subspace, rotated)}),
    })
    use_cache = cache_dir is not False
    root = Path(default_cache_dir() if cache_dir is None else cache_dir) if use_cache else None
    info = {"modes_key": modes_key, "key": table_key, "grid_shape": list(gshape),
            "n_points_total": len(indices)}
    if use_cache:
        tdir = root / f"table-{table_key[:32]}"
        cached = load_verified(tdir / "table.npz", table_key)
        if cached is not None:
            table = _table_from_arrays(cached)
            table.info.update(computed_modes=0, cached_modes=0, computed_quantities=0,
                              from_cache=True, seconds=time.perf_counter() - t_start)
            return table
        mdir = root / f"modes-{modes_key[:32]}"
        atomic_write_text(mdir / "key.json", json.dumps({"key": modes_key}))
        for directory in (root, mdir, tdir):  # leftovers of killed builds
            remove_stale_files(directory)

    # ---- stage 1: raw modes at every point (parallel, cached per point). On a Dask
    # cluster without a cache they stay on the workers: only the tracking's data of each
    # point comes here, and the tracked points are made where their raw modes are.
    eye = np.eye(robot.n_joints)
    directions = [d for k in joints for d in (eye[k].copy(), -eye[k])]
    kept = (KEEP_ON_WORKERS and client is not None and not use_cache and bool(quantities)
            and basis == "eigen")
    token, where = uuid.uuid4().hex, {}
    by_lines = kept and TRACK_ON_WORKERS and len(gshape) > 1
    try:
        if by_lines:  # tracking and quantities on the workers, by grid lines
            got = gridlines.tabulate_by_lines(
                client, token, gshape, [(robot, q_at(idx), count, n_points, directions,
                                         weighting) for idx in indices], _point_kept,
                _tracked_point, quantities, n_modes, _boundary_points(grid, gshape),
                weighting, progress=progress)
            gt, omega, shifted, tracked = (got[k] for k in ("tracking", "omega", "shifted",
                                                             "tracked"))
            per_point = None  # got["values"]: stacked over the grid by the driver
            info.update(computed_modes=len(indices), cached_modes=0,
                        computed_quantities=len(indices))
            t_modes = got["modes_done"]
            if got["redone"]:
                drop_kept(client, token)
        elif kept:
            points, shifted = np.empty(gshape, dtype=object), np.zeros(gshape, dtype=bool)
            for flat, data, worker in map_keep(
                    _point_kept, [(flat, (robot, q_at(idx), count, n_points, directions,
                                          weighting)) for flat, idx in enumerate(indices)],
                    client, token, progress=progress, desc="TMM"):
                points[indices[flat]], where[flat] = data, worker
                shifted[indices[flat]] = bool(np.any(data["shift"] != 0.0))
            info.update(computed_modes=len(indices), cached_modes=0)
            t_modes = time.perf_counter()
            gt = trk.track_grid_features(points)
            omega = np.array([points[idx]["omega"][gt.order[idx]][:n_modes]
                              for idx in indices]).reshape(gshape + (n_modes,))
        else:
            raw = np.empty(gshape, dtype=object)
            missing = []
            for flat, idx in enumerate(indices):
                arrays = (load_verified(mdir / f"p{flat:07d}.npz", modes_key) if use_cache
                          else None)
                if arrays is None:
                    missing.append(flat)
                else:
                    raw[idx] = arrays

            def compute_modes_at(flats):
                jobs = [(flat, (robot, q_at(indices[flat]), count, n_points, directions))
                        for flat in flats]
                return parallel_map(_point_modes, jobs, client=client, processes=processes,
                                    progress=progress, desc="TMM")

            computed = 0
            results = (build_shared(missing, lambda flat: mdir / f"p{flat:07d}.npz",
                                    modes_key, compute_modes_at) if use_cache
                       else ((f, a, True) for f, a in compute_modes_at(missing)))
            for flat, arrays, by_us in results:
                raw[indices[flat]] = arrays
                computed += by_us
            info.update(computed_modes=computed, cached_modes=len(indices) - computed)
            t_modes = time.perf_counter()
            shifted = np.zeros(gshape, dtype=bool)
            shapes = np.empty(gshape, dtype=object)
            for idx in indices:
                shifted[idx] = bool(np.any(raw[idx]["shift"] != 0.0))
                shapes[idx] = _arrays_to_shapes(raw[idx])
            del raw

            # ---- stage 2: tracking (sequential)
            gt = (subspace.track_grid_smooth(shapes, int(n_modes), robot, weighting)
                  if basis == "smooth"
                  else trk.track_grid(shapes, robot=robot, weighting=weighting))
            tracked = gt.apply(shapes)
            for idx in indices:
                tracked[idx] = _first_modes(tracked[idx], n_modes)
            omega = np.array([tracked[idx].omega for idx in indices]
                             ).reshape(gshape + (n_modes,))
        mac = gt.mac[..., :n_modes]
        edge = gt.edge_correlation[..., :n_modes]
        worst = float(np.nanmin(mac)) if np.isfinite(mac).any() else 1.0
        if worst < MIN_MAC:
            warnings.warn(f"modal table of '{robot.name}': a tracked mode changes fast "
                          f"between grid neighbours (lowest MAC {worst:.3f} < {MIN_MAC}); "
                          "refine the grid or raise extra_modes", RuntimeWarning,
                          stacklevel=2)
        info.update(
            min_mac=worst,
            min_edge_correlation=(float(np.nanmin(edge)) if np.isfinite(edge).any()
                                  else 1.0),
            degenerate_points=int(gt.degenerate.sum()), shifted_points=int(shifted.sum()),
            periodic=None, joints=list(joints))
        t_tracking = got["tracking_done"] if by_lines else time.perf_counter()

        # ---- stage 3: quantities (parallel, cached per point)
        values = {"omega": omega}
        if basis == "smooth":  # clusters: 1-based sorted modes, as in the messages
            values.update(rotated.stiffness_values(gt))
            info["clusters"] = gt.clusters_1based()
        if kept and not by_lines:
            boundary = _boundary_points(grid, gshape)
            per_point, tracked, redone = [None] * len(indices), np.empty(gshape, object), False
            for flat, (result, features, again) in map_kept(
                    _tracked_point, [(flat, (
                        quantities, robot, q_at(idx), gt.transform[idx], gt.order[idx],
                        int(n_modes), idx in boundary, weighting,
                        (robot, q_at(idx), count, n_points, directions)))
                        for flat, idx in enumerate(indices)],
                    client, token, where, progress=progress, desc="quantities"):
                per_point[flat], tracked[indices[flat]] = result, features
                redone = redone or again
            if redone:  # some ran away from their kept parts: free those
                drop_kept(client, token)
            info["computed_quantities"] = len(indices)
        elif quantities and not kept:
            per_point = [None] * len(indices)
            missing = []
            for flat in range(len(indices)):
                got = (load_verified(tdir / f"q{flat:07d}.npz", table_key) if use_cache
                       else None)
                if got is None:
                    missing.append(flat)
                else:
                    per_point[flat] = got

            def compute_quantities_at(flats):
                smooth = basis == "smooth"  # on the eigenmodes, then rotated
                jobs = [(flat, (quantities, robot, q_at(indices[flat])) + (
                    (shapes[indices[flat]], gt.transform[indices[flat]]) if smooth
                    else (_shapes_to_arrays(tracked[indices[flat]]),))) for flat in flats]
                return parallel_map(
                    rotated.rotated_quantities if smooth else _point_quantities, jobs,
                    client=client, processes=processes, progress=progress,
                    desc="quantities")

            results = (build_shared(missing, lambda flat: tdir / f"q{flat:07d}.npz",
                                    table_key, compute_quantities_at) if use_cache
                       else ((f, r, True) for f, r in compute_quantities_at(missing)))
            info["computed_quantities"] = 0
            for flat, result, by_us in results:
                per_point[flat] = result
                info["computed_quantities"] += by_us
    except BaseException:
        if kept:
            drop_kept(client, token)
        raise
    info["periodic"] = periodic = _periodic_flags(grid, tracked, omega, robot, weighting)
    if by_lines:
        values.update(sorted((k, v) for k, v in got["values"].items() if k != "omega"))
    elif quantities:
        names = sorted(per_point[0])
        for name in names:
            if name == "omega":
                continue
            stack = [np.asarray(p[name], dtype=float) for p in per_point]
            if any(s.shape != stack[0].shape for s in stack):
                raise ModelError(f"quantity {name!r} changes shape across the grid")
            values[name] = np.array(stack).reshape(gshape + stack[0].shape)
    else:
        info["computed_quantities"] = 0
        for name in trk.MODE_FIELDS:
            values[name] = np.array([getattr(tracked[idx], name) for idx in indices]
                                    ).reshape(gshape + getattr(tracked[indices[0]],
                                                                name).shape)
    t_end = time.perf_counter()
    info.update(from_cache=False, seconds=t_end - t_start, seconds_modes=t_modes - t_start,
                seconds_tracking=t_tracking - t_modes, seconds_quantities=t_end - t_tracking)
    table = ModalTable(grid=grid, shape_joints=joints, values=values, omega=omega,
                       q_fixed=q_fixed, periodic=tuple(periodic), info=info)
    if use_cache:
        save_verified(tdir / "table.npz", table_key,
                      **_table_to_arrays(table))
    return table


def _boundary_points(grid, gshape):
    """Both ends of every axis that may be periodic (what _periodic_flags compares)."""
    return {idx[:ax] + (i,) + idx[ax:] for ax, a in enumerate(grid)
            if periodic_axis_kind(a) is not None
            for idx in np.ndindex(gshape[:ax] + gshape[ax + 1:]) for i in (0, gshape[ax] - 1)}


def _periodic_flags(grid, tracked, omega, robot, weighting, threshold=0.9):
    """Per axis: full turn with tracked modes closing up in identity and sign (``tracked``:
    ModeShapes or their features, at least at :func:`_boundary_points`)."""
    flags = []
    gshape = omega.shape[:-1]
    for ax, a in enumerate(grid):
        kind = periodic_axis_kind(a)
        if kind is None:
            flags.append(False)
            continue
        good = True
        for idx in np.ndindex(gshape[:ax] + gshape[ax + 1:]):
            first = idx[:ax] + (0,) + idx[ax:]
            last = idx[:ax] + (gshape[ax] - 1,) + idx[ax:]
            c = np.diag(trk.correlation(tracked[first], tracked[last], robot, weighting))
            good = bool(np.all(c > threshold)) and (kind != "closed" or np.allclose(
                omega[first], omega[last], rtol=1e-6))
            if not good:
                break
        flags.append(bool(good))
    return flags


def _table_to_arrays(table):
    out = {"__info__": np.array(json.dumps(table.info)),
           "__joints__": np.array(table.shape_joints, dtype=int),
           "__q_fixed__": np.asarray(table.q_fixed, dtype=float),
           "__periodic__": np.array(table.periodic, dtype=bool),
           "__omega__": table.omega}
    for i, a in enumerate(table.grid):
        out[f"__axis{i}__"] = a
    for name, v in table.values.items():
        out[f"v:{name}"] = v
    return out


def _table_from_arrays(arrays):
    joints = tuple(int(k) for k in arrays["__joints__"])
    grid = tuple(np.asarray(arrays[f"__axis{i}__"]) for i in range(len(joints)))
    values = {k[2:]: np.asarray(v) for k, v in arrays.items() if k.startswith("v:")}
    return ModalTable(grid=grid, shape_joints=joints, values=values,
                      omega=np.asarray(arrays["__omega__"]),
                      q_fixed=np.asarray(arrays["__q_fixed__"]),
                      periodic=tuple(bool(x) for x in arrays["__periodic__"]),
                      info=json.loads(str(arrays["__info__"])))
