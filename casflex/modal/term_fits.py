"""Chebyshev fits of every model term over the joint box, checked against direct TMM.

:func:`casflex.modal.fits.fit_chebyshev` fits the natural frequencies; a model needs every
tabulated quantity (:mod:`casflex.modal.integrals`: ``C1``, ``C2``, ``N``, ``eps``, the end
transforms, the springs, the sampled shapes and the sensor values). :func:`fit_model_terms`
fits them all with the same tensor-product Chebyshev machinery, so that a model
(:class:`casflex.model.providers.ChebyshevProvider`) can take the fit instead of the grid.

How
---
1. Raw TMM modes at the tensor Chebyshev–Lobatto points of the box
   (:func:`casflex.modal.tables.compute_modes`) and, once per point, the quantities of the
   mass-normalised raw modes (:func:`casflex.modal.rotated.normalized_quantities`).
2. A basis over those points: tracked eigenmodes (``basis="eigen"``,
   :func:`casflex.modal.tracking.track_grid`; analytic along one shape joint, where
   tracked eigen branches are analytic through crossings) or the smooth basis of clusters
   of close modes (``basis="smooth"``, :func:`casflex.modal.subspace.track_grid_smooth`;
   for two or more shape joints, where eigenvectors are not smooth around conical
   intersections). The quantities of that basis are those of step 1 transformed
   (:func:`casflex.modal.rotated.rotate_quantities`), so no quadrature is repeated.
   Within each cluster the smooth basis is chosen either against the grid neighbours
   (``gauge="neighbour"``: continuous, but it depends on the path through the grid, so
   over two or more shape joints the fits converge only algebraically) or against a
   fixed polynomial reference field (``gauge="reference"``,
   :mod:`casflex.modal.gauge`: an analytic function of the joints; the 4-joint arm at
   32 × 32 gives held-out ω 4.7e-8 and terms 6.0e-7, against 3.4e-5 and 9.9e-4).
3. Coefficients; each axis's degree doubles while the tail estimate (twice the larger of
   the two highest coefficients along it) of any term exceeds its target: ``target``
   relative to the term's scale for the model terms, ``omega_target`` relative to ω (or
   to ``2 λ_min`` for the stiffness block of the smooth basis). A term's scale is its peak
   over the box, but at least :data:`TERM_FLOOR` times the largest peak of its family
   (:data:`TERM_FAMILIES`: the same field at other places, e.g. every sensor value): a
   term that is zero to round-off (the axial strain of bending modes, coefficients
   ~1e-20) would otherwise read its round-off as an O(1) relative error and never
   converge.

The estimate is checked at held-out configurations against direct TMM (``held_out=``):
the modes are solved there, matched to the tracked modes of the nearest sample by their
signed correlation (eigen basis), and every term is compared (error relative to the
term's peak). In the smooth basis the basis vectors between samples are defined by the
fit itself, so what is compared is what does not depend on the basis within the clusters:
the natural frequencies (eigenvalues of the fitted ``K̃``), ``Lᵀ L`` of every linear term
``L`` (modes × entries) and the trace over the modes of the bilinear ones (``C2``,
``N``), against those of the lowest eigenmodes of the direct solve. The reference gauge
defines the basis at any configuration, so there the direct solve is put in the same
gauge and every entry of every term is compared.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.fits import (
    OMEGA_TARGET,
    ChebyshevFit,
    chebyshev_coefficients,
    joint_box,
    lobatto_points,
)
from casflex.modal.rotated import (
    MODE_AXES,
    normalized_quantities,
    rotate_quantities,
    stiffness_values,
)
from casflex.modal.subspace import DEFAULT_GAP

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = ["TERM_TARGET", "TERM_FLOOR", "TERM_FAMILIES", "term_scales", "fit_model_terms"]

#: default error target of the model terms, relative to each term's peak (issue 21)
TERM_TARGET = 1e-3
#: a term's error is relative to at least this fraction of the largest peak of its family
#: (module notes): round-off of the family's values is ~1e-16 of its peak, so a term that
#: is zero to round-off reads ~1e-7 at most, and a term that is really this small
#: matters to the model no more than the family's error target allows
TERM_FLOOR = 1e-9
#: families of terms whose values are the same kind of quantity (a term not listed is its
#: own family): the sensor values, the sampled shapes and the end transforms
TERM_FAMILIES = (
    ("point_u", "point_theta", "point_curvature", "point_twist_rate", "point_axial_strain"),
    ("sample_u", "sample_theta"), ("end_u", "end_theta"),
)
#: new sample points solved at once: their raw mode shapes (~0.1 MB each for three
#: flexible links) are held only while their quantities are computed
CHUNK_POINTS = 1024
#: quantities that are not linear in the mode shapes (fitted with the ω target)
FREQUENCY_TERMS = ("omega", "stiffness", "stiffness_root")


def fit_model_terms(robot: Robot, n_modes: int, *,
                    quantities: Callable[..., Mapping[str, ArrayLike]] | None = None,
                    joints: ArrayLike | None = None, box: ArrayLike | None = None,
                    basis: str = "eigen", target: float = TERM_TARGET,
                    omega_target: float = OMEGA_TARGET, start_degree: int = 8,
                    max_degree: int = 64, extra_modes: int = 2, gap: float = DEFAULT_GAP,
                    held_out: ArrayLike | None = None, processes: int | None = None,
                    progress: bool = False, gauge: str | None = None,
                    reference_degree: int = 4, refine: str = "all",
                    max_points: int | None = None,
                    checkpoint: str | os.PathLike | None = None) -> ChebyshevFit:
    """Fit every model term (and ω) over the joint box with tensor Chebyshev series.

    Parameters
    ----------
    robot : casflex.robot.Robot
    n_modes : int
        Modes of the model (whole clusters with ``basis="smooth"``).
    quantities : callable, optional
        ``quantities(robot, q, shapes) -> dict`` as for
        :func:`casflex.modal.tables.build_table` (default
        :func:`casflex.modal.tables.default_quantities`; sensor points:
        :func:`casflex.model.build.sensor_quantities` with ``functools.partial``).
    joints : sequence of int, optional
        Shape joints (0-based); default :func:`casflex.modal.tables.shape_joints`.
    box : sequence of (float, float), optional
        Interval per shape joint [rad]; default its joint limits, or a full turn
        [−π, π].
    basis : {"eigen", "smooth"}
        Tracked eigenmodes, or the smooth basis of clusters (module notes; adds
        ``stiffness`` and ``stiffness_root``).
    target : float
        Relative error target of the model terms (of each term's peak; dimensionless).
    omega_target : float
        Relative error target of ω (dimensionless).
    start_degree, max_degree : int
        First and largest degree per axis (the degree doubles).
    refine : {"all", "worst"}
        Each round doubles the degree of every axis over its target, or only of the axis
        furthest over it (dimension-adaptive: axes that vary little keep few points).
    max_points : int, optional
        Stop refining before a grid of more points (the fit is then reported
        ``converged=False`` if a target is still missed).
    extra_modes : int
        Modes computed beyond ``n_modes`` (modes crossing in from above).
    gap : float
        Relative frequency gap of the clusters (``basis="smooth"``).
    held_out : array_like, optional
        (k, n_joints) configurations inside the box [rad] at which the fit is compared
        with direct TMM (module notes); the errors go to ``info["held_out"]``.
    processes : int, optional
        Local worker processes (default ``os.cpu_count()``).
    progress : bool
        Progress bars on stderr.
    gauge : {"reference", "neighbour"}, optional
        How the smooth basis is chosen within each cluster: against a fixed polynomial
        reference field (:func:`casflex.modal.gauge.reference_basis`: analytic in the
        joints, so the fits converge geometrically; ``info["min_overlap"]`` is the
        smallest singular value of the overlap with the reference; the default of
        ``basis="smooth"``), or Procrustes against the grid neighbours
        (:func:`casflex.modal.subspace.smooth_basis`; converges only algebraically over
        two or more shape joints). The eigen basis has no gauge to choose (reported as
        ``"neighbour"``: its tracking follows the neighbours).
    reference_degree : int
        Degree per axis of the reference field (``gauge="reference"``): the neighbour
        basis at the Lobatto points of that degree, interpolated by its Chebyshev
        polynomial; ``0`` takes the eigenmodes at the box's centre everywhere. Its points
        are nested in the fit's when it divides ``start_degree``.
    checkpoint : str or os.PathLike, optional
        Directory that keeps the solved points, a file per chunk of
        :data:`CHUNK_POINTS` (``basis="smooth"`` only; ~8 KB a point for three flexible
        links and two modes). A fit interrupted and started again with the same inputs
        and code takes them from there instead of solving them again (the files carry a
        key of everything the points depend on and a digest of their content; stale or
        damaged files are ignored). ``info["resumed_points"]`` counts them.

    Returns
    -------
    ChebyshevFit
        Coefficients of every term (``value_shape`` as in
        :func:`casflex.modal.integrals.quantity_shapes`); ``info`` holds ``points``,
        ``seconds``, ``estimate`` (per term, relative), ``converged``,
        ``axis_ratio`` (per axis: the worst estimate over its target), ``basis``,
        ``periodic`` (per axis: a full-turn box whose terms close up) and ``held_out``.

    Raises
    ------
    ModelError
        Bad box, degrees or targets, or a tracking that cannot match a held-out point.

    Examples
    --------
    >>> import dataclasses
    >>> from casflex.robot import load
    >>> arm = load("problems/arm2link.toml")
    >>> arm = dataclasses.replace(arm, joint_limits=(None, None, (0.2, 0.6)))
    >>> fit = fit_model_terms(arm, 1, start_degree=4, max_degree=16, processes=1,
    ...                       held_out=[[0.0, 0.0, 0.37]])
    >>> fit.info["converged"], fit.info["held_out"]["C2"] < 1e-3
    (True, True)
    """
    from casflex.modal.tables import default_quantities, shape_joints

    t0 = time.perf_counter()
    func = default_quantities if quantities is None else quantities
    joints = shape_joints(robot) if joints is None else tuple(int(k) for k in joints)
    if not joints:
        raise ModelError(f"robot '{robot.name}' has no shape joint to fit over")
    box = joint_box(robot, joints, box)
    if basis not in ("eigen", "smooth"):
        raise ModelError(f"basis must be 'eigen' or 'smooth'; got {basis!r}")
    if refine not in ("all", "worst"):
        raise ModelError(f"refine must be 'all' or 'worst'; got {refine!r}")
    if not (isinstance(start_degree, (int, np.integer)) and start_degree >= 2
            and max_degree >= start_degree):
        raise ModelError(f"need 2 <= start_degree <= max_degree; got {start_degree}, "
                         f"{max_degree}")
    if not (target > 0.0 and omega_target > 0.0):
        raise ModelError(f"targets must be positive relative errors; got {target!r}, "
                         f"{omega_target!r}")
    if gauge is None:
        gauge = "reference" if basis == "smooth" else "neighbour"
    if gauge not in ("neighbour", "reference"):
        raise ModelError(f"gauge must be 'neighbour' or 'reference'; got {gauge!r}")
    nd, count = len(joints), int(n_modes) + int(extra_modes)
    if not (isinstance(reference_degree, (int, np.integer)) and reference_degree >= 0
            and reference_degree != 1):
        raise ModelError(f"reference_degree must be 0 or an integer >= 2; got "
                         f"{reference_degree!r}")
    degrees = [int(start_degree)] * nd
    store = _PointGrid([lobatto_points(lo, hi, d) for (lo, hi), d in zip(box, degrees,
                                                                          strict=True)])
    saved = None if checkpoint is None else _Checkpoint(
        checkpoint, robot, func, joints, box, count, int(n_modes), basis, gauge,
        int(reference_degree), gap)
    reference = None
    if basis == "smooth" and gauge == "reference":
        reference = _reference_field(func, robot, joints, box, count, int(n_modes),
                                     int(reference_degree), gap, store, processes, progress)
    while True:
        axes = store.axes
        if saved is not None:
            saved.fill(store)
        todo = np.argwhere(~store.have)  # C order, as np.ndindex
        for start in range(0, len(todo), CHUNK_POINTS):  # mode shapes of a chunk at a time
            chunk = [tuple(int(i) for i in idx) for idx in todo[start:start + CHUNK_POINTS]]
            qs = np.zeros((len(chunk), robot.n_joints))
            qs[:, list(joints)] = [store.coordinates(idx) for idx in chunk]
            got = _solve(func, robot, qs, count, int(n_modes), basis, processes, progress)
            if reference is not None:  # features -> overlap with the reference field
                got = _overlaps(got, reference, qs[:, list(joints)])
            for idx, point in zip(chunk, got, strict=True):
                store.put(idx, point)
            store.solved += len(chunk)
            del got
            if saved is not None:
                saved.save(store, chunk)
        coefficients, peaks, tracking, low, estimate, per_axis, ends = _round(
            store, int(n_modes), robot, basis, gap, reference, target, omega_target)
        grow = [ax for ax in range(nd) if per_axis[ax] > 1.0 and degrees[ax] < max_degree]
        if grow and refine == "worst":
            grow = [max(grow, key=lambda ax: per_axis[ax])]
        nxt = [min(2 * d, int(max_degree)) if ax in grow else d
               for ax, d in enumerate(degrees)]
        if not grow or (max_points is not None
                        and int(np.prod([d + 1 for d in nxt])) > int(max_points)):
            break
        del coefficients
        degrees = nxt
        store.regrid([lobatto_points(lo, hi, d) for (lo, hi), d in zip(box, degrees,
                                                                       strict=True)])
    clusters = (tracking.clusters if basis == "smooth"
                else tuple((k,) for k in range(int(n_modes))))
    info = {"points": store.solved, "grid_shape": list(store.shape), "estimate": estimate,
            "target": float(target), "omega_target": float(omega_target),
            "converged": bool(max(per_axis) <= 1.0), "basis": basis,
            "axis_ratio": [float(r) for r in per_axis],
            "quantity": "model terms", "periodic": _periodic(box, ends, peaks, estimate),
            "min_mac": float(np.nanmin(tracking.mac)) if np.isfinite(tracking.mac).any()
            else (None if reference is not None else 1.0), "gauge": gauge}
    if saved is not None:
        info["resumed_points"] = saved.resumed
    if low is not None:
        info["min_overlap"] = float(np.min(low))
    raw = store.slots[0] if basis == "eigen" else None
    fit = ChebyshevFit(box=box, shape_joints=joints, degrees=tuple(degrees),
                       coefficients=coefficients, clusters=clusters, info=info)
    if held_out is not None:
        info["held_out"] = _held_out(fit, func, robot, held_out, raw, tracking, axes,
                                     peaks, count, reference)
    info["seconds"] = time.perf_counter() - t0
    return fit


class _PointGrid:
    """The solved sample points of the current tensor grid, held as one preallocated
    array per slot of a point's tuple (:func:`_point_solve`: raw modes, the dict of
    normalised quantities, S⁻¹, features or overlap, modal mass, ω) over the grid and
    filled in place, so that nothing is held per point beyond its values (a dict of
    arrays per point had cost ~41 KB a point on arm6 against 7.7 KB of values)."""

    def __init__(self, axes):
        self.axes = [np.asarray(a, dtype=float) for a in axes]
        self.shape = tuple(a.size for a in self.axes)
        self.size = int(np.prod(self.shape))
        self.have = np.zeros(self.shape, dtype=bool)
        self.slots: list | None = None
        self.solved = 0  # TMM solves made for the fit (this grid and the earlier ones)

    def coordinates(self, idx):
        return [float(a[i]) for a, i in zip(self.axes, idx, strict=True)]

    def _empty(self, item):
        """Storage for one slot over the grid, from its value at one point."""
        if item is None:
            return None
        if isinstance(item, Mapping):
            return {k: self._empty(np.asarray(v, dtype=float)) for k, v in item.items()}
        if isinstance(item, np.ndarray):
            return np.empty(self.shape + item.shape, dtype=item.dtype)
        return np.empty(self.shape, dtype=object)  # raw mode shapes (eigen basis)

    def put(self, idx, point):
        if self.slots is None:
            self.slots = [self._empty(p) for p in point]
        for slot, item in zip(self.slots, point, strict=True):
            if isinstance(slot, dict):
                if set(slot) != set(item):
                    raise ModelError(f"the quantity function returned the keys "
                                     f"{sorted(item)} at one point and {sorted(slot)} at "
                                     "another")
                for k, v in item.items():
                    slot[k][idx] = v
            elif slot is not None:
                slot[idx] = item
        self.have[idx] = True

    def merge(self, other):
        """Copy ``other``'s points that lie on this grid (exactly equal coordinates:
        Lobatto points of degree d are among those of degree 2d) into this fresh grid."""
        if other.slots is None:
            return
        new, old = [], []
        for a_new, a_old in zip(self.axes, other.axes, strict=True):
            pos = np.clip(np.searchsorted(a_old, a_new), 0, a_old.size - 1)
            hit = a_old[pos] == a_new
            new.append(np.flatnonzero(hit))
            old.append(pos[hit])
        if self.slots is None:
            nd = len(other.shape)
            self.slots = [None if s is None else
                          {k: np.empty(self.shape + v.shape[nd:]) for k, v in s.items()}
                          if isinstance(s, dict) else np.empty(self.shape + s.shape[nd:],
                                                               dtype=s.dtype)
                          for s in other.slots]
        if any(ix.size == 0 for ix in new):
            return
        to, frm = np.ix_(*new), np.ix_(*old)
        for mine, theirs in zip(self.slots, other.slots, strict=True):
            if isinstance(mine, dict):
                for k, v in theirs.items():
                    mine[k][to] = v[frm]
            elif mine is not None:
                mine[to] = theirs[frm]
        self.have[to] = other.have[frm]

    def regrid(self, axes):
        """Move to a finer tensor grid, keeping the points it shares with this one."""
        finer = _PointGrid(axes)
        finer.merge(self)
        finer.solved = self.solved
        self.__dict__.update(finer.__dict__)

    def index(self, x):
        """The grid index of the point ``x`` (exact coordinates), or None."""
        idx = []
        for a, xi in zip(self.axes, x, strict=True):
            i = int(np.clip(np.searchsorted(a, xi), 0, a.size - 1))
            if a[i] != xi:
                return None
            idx.append(i)
        return tuple(idx)


class _Checkpoint:
    """The solved points of a fit on disk, a file per chunk, keyed by everything a point
    depends on (``fit_model_terms(checkpoint=)``)."""

    def __init__(self, directory, robot, func, joints, box, count, n_modes, basis, gauge,
                 reference_degree, gap):
        import casflex
        import casflex.modal.gauge
        import casflex.modal.integrals
        import casflex.modal.normalize
        import casflex.modal.rotated
        import casflex.modal.subspace
        import casflex.tmm.chain
        import casflex.tmm.fast
        import casflex.tmm.kernels
        import casflex.tmm.solve
        from casflex._cache import digest, source_digest
        from casflex.modal.tablekeys import function_identity, robot_fingerprint

        if basis != "smooth":
            raise ModelError("checkpoint= needs basis='smooth' (the eigen basis keeps every "
                             "point's mode shapes for its tracking)")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.key = digest({
            "casflex": casflex.__version__, "robot": robot_fingerprint(robot),
            "function": function_identity(func), "joints": list(joints),
            "box": [list(b) for b in box], "count": count, "n_modes": n_modes,
            "gauge": gauge, "reference_degree": reference_degree, "gap": float(gap),
            "code": source_digest(casflex.tmm.chain, casflex.tmm.fast, casflex.tmm.kernels,
                                  casflex.tmm.solve, casflex.modal.normalize,
                                  casflex.modal.integrals, casflex.modal.rotated,
                                  casflex.modal.subspace, casflex.modal.gauge,
                                  _point_solve, _point_terms, _overlaps, _reference_field,
                                  lobatto_points, chebyshev_coefficients)})
        self.resumed = 0
        self.used: set[str] = set()

    def save(self, store, chunk):
        from casflex._cache import save_verified

        arrays = {"x": np.array([store.coordinates(idx) for idx in chunk])}
        ix = tuple(np.array(chunk).T)
        for k, slot in enumerate(store.slots):
            if isinstance(slot, dict):
                arrays.update({f"v_{name}": v[ix] for name, v in slot.items()})
            elif slot is not None:
                arrays[f"s{k}"] = slot[ix]
        n = len(list(self.directory.glob("points-*.npz")))
        save_verified(self.directory / f"points-{n:05d}-{os.getpid()}.npz", self.key,
                      **arrays)

    def fill(self, store):
        """Put the stored points that lie on ``store``'s grid and are not in it yet."""
        from casflex._cache import load_verified

        for path in sorted(self.directory.glob("points-*.npz")):
            if path.name in self.used:
                continue
            data = load_verified(path, self.key)
            if data is None:  # another key, truncated or altered: not used
                continue
            left = 0
            for r, x in enumerate(data["x"]):
                idx = store.index(x)
                if idx is None:
                    left += 1
                    continue
                if store.have[idx]:
                    continue
                store.put(idx, (None, {k[2:]: v[r] for k, v in data.items()
                                       if k.startswith("v_")})
                          + tuple(data[f"s{k}"][r] if f"s{k}" in data else None
                                  for k in range(2, 6)))
                self.resumed += 1
                store.solved += 1
            if not left:
                self.used.add(path.name)


def _reference_field(func, robot, joints, box, count, n_modes, degree, gap, store,
                     processes, progress):
    """The reference of the fixed gauge as a Chebyshev series of mass-orthonormal feature
    rows (``"rows"``, n × f): the neighbour basis at the Lobatto points of ``degree``, or
    the eigenmodes at the box's centre (``degree`` 0). The points solved for it go to
    ``store`` (those on its grid) with their features replaced by their overlap with the
    field."""
    from casflex.modal.gauge import reference_rows
    from casflex.modal.subspace import track_features_smooth

    nd = len(joints)
    if degree == 0:
        q = np.zeros((1, robot.n_joints))
        q[0, list(joints)] = [0.5 * (lo + hi) for lo, hi in box]
        _, _, _, features, mass, _ = _solve(func, robot, q, count, n_modes, "smooth", 1,
                                            False)[0]
        rows = reference_rows(features, mass, n_modes)
        return ChebyshevFit(box=box, shape_joints=joints, degrees=(0,) * nd,
                            coefficients={"rows": rows.reshape((1,) * nd + rows.shape)},
                            clusters=())
    axes = [lobatto_points(lo, hi, degree) for lo, hi in box]
    gshape = tuple(a.size for a in axes)
    keys = [tuple(float(a[i]) for a, i in zip(axes, idx, strict=True))
            for idx in np.ndindex(gshape)]
    qs = np.zeros((len(keys), robot.n_joints))
    qs[:, list(joints)] = keys
    got = _solve(func, robot, qs, count, n_modes, "smooth", processes, progress)
    features = np.empty(gshape, dtype=object)
    for idx, p in zip(np.ndindex(gshape), got, strict=True):
        features[idx] = p[3]
    mass = np.array([p[4] for p in got]).reshape(gshape + (n_modes, n_modes))
    omega = np.array([p[5] for p in got]).reshape(gshape + got[0][5].shape)
    sb = track_features_smooth(features, omega, n_modes, mass, gap)
    rows = np.array([sb.transform[idx] @ features[idx] for idx in np.ndindex(gshape)])
    field = ChebyshevFit(box=box, shape_joints=joints, degrees=(degree,) * nd,
                         coefficients={"rows": chebyshev_coefficients(
                             rows.reshape(gshape + rows.shape[1:]), nd)},
                         clusters=sb.clusters, info={"min_mac": sb.min_mac})
    own = _PointGrid(axes)
    for idx, point in zip(np.ndindex(gshape), _overlaps(got, field, qs[:, list(joints)]),
                          strict=True):
        own.put(idx, point)
    store.merge(own)
    store.solved += own.size
    return field


#: points whose reference rows are evaluated at once: the first contraction holds
#: (points × the field's coefficients per value × n × f) floats, ~40 MB at 32 points for
#: a degree-4 field over four axes and three flexible links
OVERLAP_BLOCK = 32


def _overlaps(got, field, x):
    """Per point: the features (slot 3) replaced by ``rows(x) @ features.T``, with the
    reference field's rows evaluated a block of points at a time."""
    coef = field.coefficients["rows"]
    out = []
    for start in range(0, len(got), OVERLAP_BLOCK):
        xb = x[start:start + OVERLAP_BLOCK]
        rows = None
        for ax, (lo, hi) in enumerate(field.box):
            t = np.clip((2.0 * xb[:, ax] - (lo + hi)) / (hi - lo), -1.0, 1.0)
            T = np.cos(np.arange(coef.shape[ax])[None, :] * np.arccos(t)[:, None])
            rows = (np.tensordot(T, coef, axes=(1, 0)) if rows is None
                    else np.einsum("ki,ki...->k...", T, rows))
        out += [p[:3] + (r @ np.asarray(p[3]).T,) + p[4:]
                for p, r in zip(got[start:start + OVERLAP_BLOCK], rows, strict=True)]
    return out


def _solve(func, robot, qs, count, n_modes, basis, processes, progress):
    """Per configuration: (raw modes or, in the smooth basis, the features and modal mass
    of the lowest ``n_modes`` — all the tracking needs, a tenth of the shapes' size),
    normalised quantities, S⁻¹. One task per point does the TMM and the quantities, so
    that the mode shapes (~0.1 MB a point for three flexible links) never travel between
    processes in the smooth basis."""
    from casflex._parallel import parallel_map

    jobs = [(r, (func, robot, q, count, basis, n_modes)) for r, q in enumerate(qs)]
    got = dict(parallel_map(_point_solve, jobs, processes=processes, progress=progress,
                            desc="TMM and terms"))
    return [got[r] for r in range(len(qs))]


def _point_solve(func, robot, q, count, basis, n_modes):
    """Raw modes at ``q`` (kept in the eigen basis only) and :func:`_point_terms`."""
    from casflex.modal.tables import compute_modes

    shapes = compute_modes(robot, np.asarray(q)[None, :], count, processes=1)[0]
    return ((shapes if basis == "eigen" else None),) + _point_terms(func, robot, q, shapes,
                                                                      basis, n_modes)


def _point_terms(func, robot, q, shapes, basis, n_modes):
    """Normalised quantities, S⁻¹ and (smooth basis) the tracking features of one point.

    The eigen basis may take tracked modes from above ``n_modes`` (crossings): every
    computed mode is kept. The smooth basis spans exactly the lowest ``n_modes`` (whole
    clusters, checked by the tracking), so only those are kept; all the frequencies are
    (the cluster boundary)."""
    from casflex.modal.subspace import point_features

    if basis == "eigen":
        return normalized_quantities(func, robot, q, shapes) + (None, None, None)
    values, S_inv = normalized_quantities(func, robot, q, shapes, n_modes)
    features, mass = point_features(shapes, robot)
    return (values, S_inv, features[:n_modes], mass[:n_modes, :n_modes],
            np.asarray(shapes.omega, dtype=float))


def _basis(store, n_modes, robot, basis, gap, reference):
    """The tracking of the chosen basis over the sample grid, the map from every point's
    normalised modes to it (``grid_shape + (n, k)``) and (reference gauge) the smallest
    overlap with the reference per point."""
    from casflex.modal.gauge import MIN_OVERLAP, reference_basis
    from casflex.modal.subspace import mode_clusters, track_features_smooth
    from casflex.modal.tracking import track_grid

    gshape = store.shape
    _, _, S, features, mass, omega = store.slots
    low = None
    if reference is not None:
        clusters = mode_clusters(omega, n_modes, gap)
        if clusters[-1][-1] + 1 != n_modes:
            raise ModelError(f"{n_modes} modes split the cluster of close modes "
                             f"{[k + 1 for k in clusters[-1]]} (relative gap < {gap:g} "
                             f"somewhere): use {clusters[-1][-1] + 1} modes")
        tracking, low = reference_basis(features, omega, clusters, mass)
        if float(np.min(low)) < MIN_OVERLAP:
            where = np.unravel_index(int(np.argmin(low)), low.shape)
            raise ModelError(f"the reference gauge breaks down: at sample {where[:-1]} the "
                             f"subspace of modes {[k + 1 for k in clusters[where[-1]]]} is "
                             f"nearly orthogonal to the box centre's (overlap "
                             f"{float(np.min(low)):.3g} < {MIN_OVERLAP}); use "
                             "gauge='neighbour' or a smaller box")
    elif basis == "smooth":
        rows = np.empty(gshape, dtype=object)
        for idx in np.ndindex(gshape):
            rows[idx] = features[idx]
        tracking = track_features_smooth(rows, omega, n_modes, mass, gap)
    else:
        tracking = track_grid(store.slots[0], count=n_modes, robot=robot)
    T = None
    for idx in np.ndindex(gshape):
        t = np.asarray(tracking.transform[idx], dtype=float)[:, :S.shape[-1]] @ S[idx]
        if basis == "eigen":  # tracked modes are scaled raw modes: unit modal mass rows
            t = t / np.linalg.norm(t, axis=1, keepdims=True)
        if T is None:
            T = np.empty(gshape + t.shape)
        T[idx] = t
    return tracking, T, low


def _basis_terms(store, T, tracking, basis) -> Iterator[tuple[str, np.ndarray]]:
    """Every term of the chosen basis over the sample grid (``grid_shape + value``), one
    term at a time (:func:`_round` turns each into coefficients before the next)."""
    values = store.slots[1]
    for name, stored in values.items():
        if name in ("omega", "stiffness", "stiffness_root"):  # not linear in the shapes
            continue
        out = None
        for idx in np.ndindex(store.shape):
            v = rotate_quantities({name: stored[idx]}, T[idx])[name]
            if out is None:
                out = np.empty(store.shape + v.shape)
            out[idx] = v
        yield name, out
    if basis == "smooth":
        yield from stiffness_values(tracking).items()
        yield "omega", tracking.omega
        return
    omega = values["omega"]
    out = np.empty(store.shape + tracking.order[(0,) * len(store.shape)].shape)
    for idx in np.ndindex(store.shape):
        out[idx] = omega[idx][tracking.order[idx]]
    yield "omega", out


def _round(store, n_modes, robot, basis, gap, reference, target, omega_target):
    """One round of the fit on the current grid: the basis, then term by term its values,
    their peak, the mismatch of their ends along every axis and their coefficients (the
    values of a term are dropped before the next is formed: the round holds the stored
    points, the coefficients and one term's values)."""
    nd = len(store.shape)
    tracking, T, low = _basis(store, n_modes, robot, basis, gap, reference)
    coefficients, peaks, ends = {}, {}, {}
    omega_min = None
    for name, values in _basis_terms(store, T, tracking, basis):
        if values.size:
            peaks[name] = float(np.max(np.abs(values)))
            ends[name] = [float(np.max(np.abs(np.take(values, 0, axis=ax)
                                              - np.take(values, -1, axis=ax))))
                          for ax in range(nd)]
        else:
            peaks[name] = 0.0
        if name == "omega":
            omega_min = np.min(values.reshape(-1, values.shape[-1]), axis=0)
        coefficients[name] = chebyshev_coefficients(values, nd)
        del values
    estimate, per_axis = _estimates(peaks, omega_min, coefficients, nd, target,
                                    omega_target)
    return coefficients, peaks, tracking, low, estimate, per_axis, ends


def term_scales(peaks: Mapping[str, float]) -> dict[str, float]:
    """The scale each term's error is measured against: its peak, floored by its family's.

    Parameters
    ----------
    peaks : dict of str to float
        Largest magnitude of every term over the sample grid (units of each term).

    Returns
    -------
    dict of str to float
        ``max(peak, TERM_FLOOR · largest peak of the family)`` per term
        (:data:`TERM_FAMILIES`; a term not in a family is its own).

    Examples
    --------
    >>> s = term_scales({"point_curvature": 2.0, "point_axial_strain": 8e-21, "C1": 0.5})
    >>> s["point_axial_strain"], s["point_curvature"], s["C1"]
    (2e-09, 2.0, 0.5)
    """
    out = {}
    for name, peak in peaks.items():
        family = next((f for f in TERM_FAMILIES if name in f), (name,))
        top = max(float(peaks.get(m, 0.0)) for m in family)
        out[name] = max(float(peak), TERM_FLOOR * top)
    return out


#: the tail estimate is this multiple of the larger of the two highest coefficients: the
#: truncated series and the aliasing of the interpolant add up to about twice the last
#: coefficients when they decay geometrically (arm2link, 3 modes, full turn: with a factor
#: 1 the held-out ω error was 1.3e-4 at an estimate of 9.8e-5)
TAIL_FACTOR = 2.0


def _tail(coef, nd, ax):
    t = np.abs(np.take(coef, [-2, -1], axis=ax))
    return TAIL_FACTOR * np.max(t.reshape(-1, *coef.shape[nd:]), axis=0)


def _estimates(peaks, omega_min, coefficients, nd, target, omega_target):
    """Per term: the tail estimate as a relative error; per axis: the worst ratio to its
    target (``peaks``: each term's largest magnitude over the grid; ``omega_min``: each
    mode's lowest ω)."""
    estimate, per_axis = {}, [0.0] * nd
    scales = term_scales(peaks)
    lam_min = float(np.min(omega_min)) ** 2
    for name, coef in coefficients.items():
        worst = 0.0
        if not coef.size:  # a quantity without entries (no joint springs)
            estimate[name] = worst
            continue
        for ax in range(nd):
            tail = _tail(coef, nd, ax)
            if name == "omega":
                rel = float(np.max(tail / omega_min))
            elif name in FREQUENCY_TERMS:  # [rad²/s²] and [rad/s]: as a relative ω error
                scale = 2.0 * lam_min if name == "stiffness" else np.sqrt(lam_min)
                rel = float(np.max(tail) / scale)
            else:
                peak = scales[name]
                rel = float(np.max(tail)) / peak if peak > 0.0 else 0.0
            worst = max(worst, rel)
            goal = omega_target if name in FREQUENCY_TERMS else target
            per_axis[ax] = max(per_axis[ax], rel / goal)
        estimate[name] = worst
    return estimate, per_axis


def _periodic(box, ends, peaks, estimate):
    """Per axis: a full-turn box whose terms agree at both ends (to their estimates;
    ``ends[name][axis]``: the largest mismatch of a term's two ends along the axis)."""
    out = []
    for ax, (lo, hi) in enumerate(box):
        full = abs((hi - lo) - 2.0 * np.pi) <= 1e-9
        ok = full
        for name, mismatch in ends.items():
            if not ok:
                continue
            ok = mismatch[ax] <= 10.0 * max(estimate[name], 1e-9) * peaks[name]
        out.append(bool(ok))
    return out


def _invariant(name, value):
    """What an orthogonal change of basis within the clusters leaves unchanged: ``Lᵀ L``
    of a linear quantity (modes × rest), the trace over the modes of a bilinear one."""
    axes = MODE_AXES[name]
    if len(axes) == 2:
        return np.trace(value, axis1=axes[0], axis2=axes[1])
    L = np.moveaxis(value, axes[0], 0)
    L = L.reshape(L.shape[0], -1)
    return L.T @ L


def _entrywise(errors, fit, func, robot, q, shapes, reference, peaks):
    """The reference gauge defines the basis at any configuration, not only on the grid:
    the direct solve is put in that basis and every entry of every term compared (relative
    to the term's peak; ω of the eigenvalues of ``K̃``, relative)."""
    from casflex.modal.gauge import reference_basis

    n = sum(len(c) for c in fit.clusters)
    x = q[list(fit.shape_joints)]
    point = (None,) + _point_terms(func, robot, q, shapes, "smooth", n)
    point = _overlaps([point], reference, x[None, :])[0]
    values, S_inv, overlap, mass, omega = point[1:]
    sb, _ = reference_basis(overlap[None], omega[None], fit.clusters, mass[None])
    direct = rotate_quantities(values, sb.transform[0] @ S_inv)
    direct.update({k: v[0] for k, v in stiffness_values(sb).items()})
    K = fit.evaluate("stiffness", x)
    w = np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (K + K.T)), 0.0, None))
    errors["omega"] = max(errors.get("omega", 0.0),
                          float(np.max(np.abs(w / omega[:n] - 1.0))))
    for name, ref in direct.items():
        if not ref.size or name not in fit.coefficients:
            continue
        peak = term_scales(peaks)[name]
        err = float(np.max(np.abs(fit.evaluate(name, x) - ref))) / peak if peak else 0.0
        errors[name] = max(errors.get(name, 0.0), err)


def _held_out(fit, func, robot, qs, raw, tracking, axes, peaks, count, reference=None):
    """Largest error of every term at ``qs`` against direct TMM (module notes)."""
    from casflex.modal.tables import compute_modes
    from casflex.modal.tracking import combine, correlation

    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    joints = list(fit.shape_joints)
    errors: dict[str, float] = {}
    direct_shapes = compute_modes(robot, qs, count, processes=1)
    for q, shapes in zip(qs, direct_shapes, strict=True):
        x = q[joints]
        if reference is not None:
            _entrywise(errors, fit, func, robot, q, shapes, reference, peaks)
            continue
        values, S_inv = normalized_quantities(func, robot, q, shapes)
        if fit.info["basis"] == "smooth":
            K = fit.evaluate("stiffness", x)
            w = np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (K + K.T)), 0.0, None))
            ref = np.sort(values["omega"])[:w.size]
            errors["omega"] = max(errors.get("omega", 0.0), float(np.max(np.abs(w / ref - 1))))
            n = w.size  # the clusters span the lowest n eigenmodes: compare invariants
            for name, value in values.items():
                if name == "omega" or not value.size or name not in fit.coefficients:
                    continue
                got = _invariant(name, fit.evaluate(name, x))
                first = np.eye(n, value.shape[MODE_AXES[name][0]])  # the lowest n modes
                ref = _invariant(name, rotate_quantities({name: value}, first)[name])
                peak = float(np.max(np.abs(ref)))
                err = float(np.max(np.abs(got - ref))) / peak if peak > 0.0 else 0.0
                errors[name] = max(errors.get(name, 0.0), err)
            continue
        idx = tuple(int(np.argmin(np.abs(a - xi))) for a, xi in zip(axes, x, strict=True))
        near = combine(raw[idx], tracking.transform[idx], tracking.order[idx])
        c = correlation(near, shapes, robot)  # (n, count), signed
        order = np.argmax(np.abs(c), axis=1)
        if len(set(order.tolist())) != order.size:
            raise ModelError(f"held-out q = {q.tolist()}: its modes do not match the "
                             "nearest sample's one to one; use more samples")
        R = np.zeros((order.size, S_inv.shape[0]))
        R[np.arange(order.size), order] = np.sign(c[np.arange(order.size), order])
        direct = rotate_quantities(values, R)
        direct["omega"] = values["omega"][order]
        for name, ref in direct.items():
            if not ref.size:
                continue
            got = fit.evaluate(name, x)
            if name == "omega":
                err = float(np.max(np.abs(got / ref - 1.0)))
            else:
                err = float(np.max(np.abs(got - ref))) / term_scales(peaks)[name]
            errors[name] = max(errors.get(name, 0.0), err)
    return errors
