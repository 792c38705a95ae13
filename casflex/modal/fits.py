"""Smooth fits of the modal frequencies over the joint box: tensor-product Chebyshev.

(The fits of every model term, for a model without a grid, are in
:mod:`casflex.modal.term_fits`, on the same machinery.)

The grid path (:func:`casflex.modal.tables.build_table`) tabulates on a uniform grid whose
size grows as (span / step) to the power of the number of shape joints. A function that is
analytic over the box is approximated far more cheaply by a tensor-product Chebyshev
series ``f(x) = Σ c_{i…k} T_i(t_0) … T_k(t_{d−1})`` (``t`` the joint mapped to [−1, 1]),
whose coefficients decay geometrically; the degree of each axis is chosen by that decay.

What is fitted
--------------
Eigenfrequencies are *not* analytic where two modes meet (a cone over two joints), but
the symmetric functions of the eigenvalues ``λ = ω²`` of an isolated cluster of close
modes (:func:`casflex.modal.subspace.mode_clusters`) are. ``quantity="frequencies"``
(default) fits, per cluster, ``λ`` itself (a lone mode) or the pair's mean
``(λ1 + λ2)/2`` and squared split ``(λ2 − λ1)²`` (clusters of at most two modes), from
the sorted natural frequencies alone (no mode shapes, no tracking), and gives back
``ω = sqrt(mean ∓ sqrt(split)/2)``, ascending: a cone is reproduced exactly by the outer
square root. ``quantity="stiffness"`` fits every entry of the smooth basis' modal
stiffness ``K̃`` (:mod:`casflex.modal.subspace`) and its Rayleigh frequencies; that basis is
chosen point by point along the grid, so on a 2-D grid it depends on the grid (the
subspaces' curvature) and its fit converges only algebraically (4-joint arm, degree 16 /
32 per axis: held-out 1.3e-4 / 3.4e-5, against 2.2e-4 / 1.5e-7 for the frequencies).

Degree per axis
---------------
Lobatto points of degree d are nested in those of degree 2d, so raising a degree reuses
every TMM solve. Starting from ``start_degree`` the fit doubles the degree of every axis
whose error estimate — the largest of the two highest coefficients along that axis, as a
relative error of ω (``|δλ| / (2 λ_min)``; a split ``δs`` counts as ``sqrt(|δs|)/2``, its
worst case at the cone) — exceeds the target, up to ``max_degree``. The estimate is
checked at held-out configurations against direct TMM by :func:`held_out_error` (a
missed target is reported, not hidden: ``ChebyshevFit.info["converged"]``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.subspace import DEFAULT_GAP

if TYPE_CHECKING:
    import casadi as ca

    from casflex.robot import Robot

__all__ = ["OMEGA_TARGET", "joint_box", "lobatto_points", "chebyshev_coefficients", "ChebyshevFit",
           "fit_chebyshev", "held_out_error", "periodic_axis_kind"]

#: default relative error target on ω (issue 21)
OMEGA_TARGET = 1e-4


def lobatto_points(lo: float, hi: float, degree: int) -> np.ndarray:
    """Chebyshev–Lobatto points of ``degree`` on [lo, hi], ascending.

    Parameters
    ----------
    lo, hi : float
        Interval [rad].
    degree : int
        Polynomial degree (``degree + 1`` points, both ends included).

    Returns
    -------
    numpy.ndarray
        (degree + 1,) points [rad].

    Examples
    --------
    >>> lobatto_points(-1.0, 1.0, 2).round(12).tolist()
    [-1.0, 0.0, 1.0]
    """
    k = np.arange(int(degree), -1, -1)
    t = np.cos(np.pi * k / int(degree))
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * t


def chebyshev_coefficients(values: ArrayLike, axes: int) -> np.ndarray:
    """Tensor Chebyshev coefficients from values at ascending Lobatto points.

    Parameters
    ----------
    values : array_like
        ``(d_0 + 1, …, d_{axes−1} + 1) + value_shape`` samples at the tensor grid of
        :func:`lobatto_points` (any unit).
    axes : int
        Number of leading grid axes.

    Returns
    -------
    numpy.ndarray
        Same shape: ``c[i, …]`` multiplies ``T_i(t_0) …`` (the interpolant through the
        samples).

    Examples
    --------
    >>> x = lobatto_points(-1.0, 1.0, 4)
    >>> np.abs(chebyshev_coefficients(2 * x**2 - 1, 1)).round(12).tolist()   # T_2
    [0.0, 0.0, 1.0, 0.0, 0.0]
    """
    from scipy.fft import dct

    c = np.asarray(values, dtype=float)
    for ax in range(axes):
        d = c.shape[ax] - 1
        if d < 1:
            raise ModelError("a Chebyshev axis needs at least 2 points")
        c = dct(np.flip(c, axis=ax), type=1, axis=ax) / d
        first = [slice(None)] * c.ndim
        first[ax] = 0
        c[tuple(first)] *= 0.5
        first[ax] = d
        c[tuple(first)] *= 0.5
    return c


def _clenshaw_values(coef, t):
    """Numeric tensor Chebyshev series at one point ``t`` (mapped to [−1, 1])."""
    out = coef
    for x in t:
        n = out.shape[0]
        T = np.cos(np.arange(n) * np.arccos(np.clip(x, -1.0, 1.0)))
        out = np.tensordot(T, out, axes=(0, 0))
    return out


@dataclass(frozen=True)
class ChebyshevFit:
    """Tensor-product Chebyshev fits of modal quantities over a joint box.

    Attributes
    ----------
    box : tuple of (float, float)
        Per shape joint the interval fitted [rad].
    shape_joints : tuple of int
        0-based joint of each axis.
    degrees : tuple of int
        Polynomial degree per axis.
    coefficients : dict of str to numpy.ndarray
        ``(d_0 + 1, …) + value_shape`` per quantity (``"omega"`` [rad/s], ``"stiffness"``
        [rad²/s²]).
    clusters : tuple of tuple of int
        Sorted modes spanning each block of the stiffness.
    info : dict
        Points, seconds, error estimates per axis, convergence.

    Examples
    --------
    >>> f = ChebyshevFit(box=((0.0, 1.0),), shape_joints=(2,), degrees=(1,),
    ...                  coefficients={"omega": np.array([[5.0], [1.0]])}, clusters=((0,),))
    >>> f.evaluate("omega", [1.0]).tolist(), float(f.function("omega")(0.5))
    ([6.0], 5.0)
    """

    box: tuple[tuple[float, float], ...]
    shape_joints: tuple[int, ...]
    degrees: tuple[int, ...]
    coefficients: dict[str, np.ndarray]
    clusters: tuple[tuple[int, ...], ...]
    info: dict[str, Any] = field(default_factory=dict)

    def _t(self, x):
        return [(2.0 * xi - (lo + hi)) / (hi - lo) for xi, (lo, hi) in zip(x, self.box,
                                                                            strict=True)]

    def evaluate(self, name: str, q_shape: ArrayLike) -> np.ndarray:
        """Numeric value of quantity ``name`` at the shape joints' values ``q_shape``.

        Parameters
        ----------
        name : str
            ``"omega"`` or ``"stiffness"``.
        q_shape : array_like
            One value per shape joint [rad], inside the box.

        Returns
        -------
        numpy.ndarray
            The value's shape (``(n,)`` or ``(n, n)``).

        Examples
        --------
        >>> f = ChebyshevFit(box=((-1.0, 1.0),), shape_joints=(0,), degrees=(2,),
        ...                  coefficients={"omega": np.array([[0.0], [0.0], [1.0]])},
        ...                  clusters=((0,),))
        >>> f.evaluate("omega", [0.5]).round(12).tolist()   # T_2(0.5) = -0.5
        [-0.5]
        """
        x = np.atleast_1d(np.asarray(q_shape, dtype=float))
        if x.size != len(self.box):
            raise ModelError(f"q_shape needs {len(self.box)} values; got {x.size}")
        if name == "omega" and "invariants" in self.coefficients:
            v = _clenshaw_values(self.coefficients["invariants"], self._t(x))
            return np.array([float(w) for w in self._omega_from(v, np.sqrt, max)])
        return _clenshaw_values(self._coef(name), self._t(x))

    def _omega_from(self, inv, sqrt, fmax):
        """Ascending ω from the cluster invariants (numeric or casadi)."""
        out, r = [], 0
        for c in self.clusters:
            if len(c) == 1:
                out.append(sqrt(fmax(inv[r], 0.0)))
            else:
                half = 0.5 * sqrt(fmax(inv[r + 1], 0.0))
                out += [sqrt(fmax(inv[r] - half, 0.0)), sqrt(fmax(inv[r] + half, 0.0))]
            r += len(c)
        return out

    def _coef(self, name):
        if name not in self.coefficients:
            raise ModelError(f"no quantity {name!r} in the fit; it has "
                             f"{sorted(self.coefficients)}")
        return self.coefficients[name]

    def function(self, name: str) -> ca.Function:
        """``casadi.Function`` ``f(q_shape) -> value``, like :meth:`ModalTable.function`.

        Parameters
        ----------
        name : str
            ``"omega"`` (column vector) or ``"stiffness"`` (matrix).

        Returns
        -------
        casadi.Function
            Polynomial in the shape joints [rad] (valid inside the box; outside it the
            polynomial is extrapolated, which is not a fit).

        Examples
        --------
        >>> f = ChebyshevFit(box=((0.0, 2.0), (0.0, 1.0)), shape_joints=(2, 3),
        ...                  degrees=(1, 1), clusters=((0,),),
        ...                  coefficients={"omega": np.arange(4.0).reshape(2, 2, 1)})
        >>> float(f.function("omega")([2.0, 1.0])), float(f.evaluate("omega", [2.0, 1.0])[0])
        (6.0, 6.0)
        """
        import casadi as ca

        if name == "omega" and "invariants" in self.coefficients:
            inner = self.function("invariants")
            x = ca.MX.sym("q_shape", len(self.box))
            v = inner(x)
            w = self._omega_from([v[i] for i in range(v.size1())], ca.sqrt, ca.fmax)
            return ca.Function(name, [x], [ca.vertcat(*w)], ["q_shape"], [name])
        coef = self._coef(name)
        nd = len(self.box)
        vshape = coef.shape[nd:]
        if len(vshape) == 2:  # matrices column-major, as casadi reshapes
            coef = np.swapaxes(coef, nd, nd + 1)
        flat = coef.reshape(coef.shape[:nd] + (-1,))
        x = ca.MX.sym("q_shape", nd)
        rest = ca.DM(flat.reshape(flat.shape[0], -1))
        out = None
        for ax, (lo, hi) in enumerate(self.box):
            t = (2.0 * x[ax] - (lo + hi)) / (hi - lo)
            n = flat.shape[ax]
            T = [ca.MX(1.0), t]
            while len(T) < n:
                T.append(2.0 * t * T[-1] - T[-2])
            row = ca.horzcat(*T[:n])  # 1 × n
            out = ca.mtimes(row, rest if out is None else out)  # 1 × (remaining)
            if ax + 1 < nd:
                m_next = flat.shape[ax + 1]
                cols = out.size2() // m_next
                out = ca.reshape(out, cols, m_next).T  # C-order (m_next, cols)
        out = out.T
        if len(vshape) == 2:
            out = ca.reshape(out, vshape[0], vshape[1])
        return ca.Function(name, [x], [out], ["q_shape"], [name])


def periodic_axis_kind(axis: ArrayLike) -> str | None:
    """Whether a grid axis spans a full turn, as the tables' periodic wrapping reads it.

    Parameters
    ----------
    axis : array_like
        Strictly increasing grid axis of one joint [rad].

    Returns
    -------
    str or None
        ``"closed"`` (the ends are 2π apart), ``"open"`` (uniform, and last + step =
        first + 2π) or None (not a full turn, or fewer than three points). The
        tolerance is 1e-9 of a turn.

    Examples
    --------
    >>> import numpy as np
    >>> periodic_axis_kind(np.linspace(-np.pi, np.pi, 13))
    'closed'
    >>> periodic_axis_kind(np.linspace(-np.pi, np.pi, 13)[:-1])
    'open'
    >>> periodic_axis_kind(np.linspace(-1.0, 1.0, 13)) is None
    True
    """
    a = np.asarray(axis, dtype=float).ravel()
    if a.size < 3:
        return None
    turn = 2.0 * np.pi
    span = a[-1] - a[0]
    if abs(span - turn) <= 1e-9 * turn:
        return "closed"
    steps = np.diff(a)
    if np.allclose(steps, steps[0], rtol=1e-9, atol=0.0) and abs(
            span + steps[0] - turn) <= 1e-9 * turn:
        return "open"
    return None


def joint_box(robot: Robot, joints: tuple[int, ...], box: ArrayLike | None = None
              ) -> tuple[tuple[float, float], ...]:
    """The interval fitted per shape joint: ``box``, else the joint limits, else a full turn.

    Parameters
    ----------
    robot : casflex.robot.Robot
    joints : tuple of int
        Shape joints (0-based).
    box : sequence of (float, float), optional
        Explicit intervals [rad], one per joint.

    Returns
    -------
    tuple of (float, float)
        ``(lo, hi)`` per joint [rad].

    Examples
    --------
    >>> from casflex.robot import load
    >>> [tuple(round(v, 4) for v in b) for b in joint_box(load("problems/arm2link.toml"), (2,))]
    [(-3.1416, 3.1416)]
    """
    if box is not None:
        out = tuple((float(lo), float(hi)) for lo, hi in box)
        if len(out) != len(joints):
            raise ModelError(f"box needs one interval per shape joint {[k + 1 for k in joints]}")
    else:
        out = tuple(tuple(float(v) for v in robot.joint_limits[k])
                    if robot.joint_limits[k] is not None else (-np.pi, np.pi) for k in joints)
    for k, (lo, hi) in zip(joints, out, strict=True):
        if not lo < hi:
            raise ModelError(f"box of joint {k + 1}: need lo < hi; got [{lo}, {hi}]")
    return out


def fit_chebyshev(robot: Robot, n_modes: int, *, joints: ArrayLike | None = None,
                  box: ArrayLike | None = None, target: float = OMEGA_TARGET,
                  start_degree: int = 8, max_degree: int = 64, extra_modes: int = 2,
                  gap: float = DEFAULT_GAP, processes: int | None = None,
                  progress: bool = False, quantity: str = "frequencies") -> ChebyshevFit:
    """Fit the natural frequencies (or the smooth-basis stiffness) over the joint box.

    Parameters
    ----------
    robot : casflex.robot.Robot
    n_modes : int
        Modes to fit (whole clusters; see :func:`casflex.modal.subspace.mode_clusters`).
    joints : sequence of int, optional
        Shape joints (0-based); default :func:`casflex.modal.tables.shape_joints`.
    box : sequence of (float, float), optional
        Interval per shape joint [rad]; default its joint limits, or a full turn.
    target : float
        Relative error target on ω of the coefficient-tail estimate (module notes).
    start_degree, max_degree : int
        First and largest degree per axis (powers of two times ``start_degree``).
    extra_modes : int
        Modes computed beyond ``n_modes`` (to see the cluster boundary).
    gap : float
        Relative frequency gap defining the clusters.
    processes : int, optional
        Local worker processes for the TMM (default ``os.cpu_count()``).
    progress : bool
        Progress bars on stderr.
    quantity : {"frequencies", "stiffness"}
        What is fitted (module notes): the clusters' invariants of ω² (``"omega"``
        ascending; clusters of at most two modes), or ``K̃`` and the Rayleigh ω of the
        smooth basis (needs the mode shapes).

    Returns
    -------
    ChebyshevFit
        ``info`` holds the points solved, the seconds, the estimate per axis and
        ``converged``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> import dataclasses
    >>> arm = load("problems/arm2link.toml")
    >>> arm = dataclasses.replace(arm, joint_limits=(None, None, (0.2, 0.6)))
    >>> fit = fit_chebyshev(arm, 1, start_degree=4, max_degree=16, processes=1)
    >>> fit.degrees, fit.info["converged"]
    ((8,), True)
    """
    from casflex.modal.subspace import track_grid_smooth
    from casflex.modal.tables import shape_joints

    t0 = time.perf_counter()
    joints = shape_joints(robot) if joints is None else tuple(int(k) for k in joints)
    if not joints:
        raise ModelError(f"robot '{robot.name}' has no shape joint to fit over")
    box = joint_box(robot, joints, box)
    if not (isinstance(start_degree, (int, np.integer)) and start_degree >= 2
            and max_degree >= start_degree):
        raise ModelError(f"need 2 <= start_degree <= max_degree; got {start_degree}, "
                         f"{max_degree}")
    if not target > 0.0:
        raise ModelError(f"target must be a positive relative error; got {target!r}")
    if quantity not in ("frequencies", "stiffness"):
        raise ModelError(f"quantity must be 'frequencies' or 'stiffness'; got {quantity!r}")
    nd = len(joints)
    degrees = [int(start_degree)] * nd
    solved: dict[tuple[float, ...], Any] = {}
    while True:
        axes = [lobatto_points(lo, hi, d) for (lo, hi), d in zip(box, degrees, strict=True)]
        gshape = tuple(a.size for a in axes)
        keys = [tuple(float(a[i]) for a, i in zip(axes, idx, strict=True))
                for idx in np.ndindex(gshape)]
        todo = [k for k in keys if k not in solved]
        if todo:
            qs = np.zeros((len(todo), robot.n_joints))
            for r, key in enumerate(todo):
                qs[r, list(joints)] = key
            solved.update(zip(todo, _solve(robot, qs, n_modes + extra_modes, quantity,
                                           processes, progress), strict=True))
        points = np.empty(gshape, dtype=object)
        for idx, key in zip(np.ndindex(gshape), keys, strict=True):
            points[idx] = solved[key]
        if quantity == "stiffness":
            sb = track_grid_smooth(points, n_modes, robot, gap=gap)
            clusters, min_mac = sb.clusters, sb.min_mac
            data = {"stiffness": sb.stiffness, "omega": sb.omega}
            lam = np.diagonal(sb.stiffness, axis1=-2, axis2=-1)
            tails = _tails(chebyshev_coefficients(sb.stiffness, nd), nd)
            scale = 2.0 * np.sqrt(np.outer(*[lam.reshape(-1, n_modes).min(axis=0)] * 2))
            estimate = [float(np.max(t / scale)) for t in tails]
        else:
            omega = np.array([points[i] for i in np.ndindex(gshape)]).reshape(gshape + (-1,))
            clusters = _clusters(omega, n_modes, gap)
            min_mac = None
            lam = omega[..., :n_modes] ** 2
            inv = _invariants(lam, clusters)
            data = {"invariants": inv}
            lam_min = lam.reshape(-1, n_modes).min(axis=0)
            split = np.array([len(c) == 2 and k == c[1] for c in clusters for k in c])
            estimate = []
            for t in _tails(chebyshev_coefficients(inv, nd), nd):
                err = np.where(split, 0.5 * np.sqrt(t), t)
                estimate.append(float(np.max(err / (2.0 * lam_min))))
        grow = [ax for ax in range(nd) if estimate[ax] > target and degrees[ax] < max_degree]
        if not grow:
            break
        for ax in grow:
            degrees[ax] = min(2 * degrees[ax], int(max_degree))
    coefficients = {k: chebyshev_coefficients(v, nd) for k, v in data.items()}
    info = {"points": len(solved), "grid_shape": list(gshape), "estimate": estimate,
            "target": float(target), "converged": bool(max(estimate) <= target),
            "quantity": quantity, "min_mac": min_mac,
            "seconds": time.perf_counter() - t0}
    return ChebyshevFit(box=box, shape_joints=joints, degrees=tuple(degrees),
                        coefficients=coefficients, clusters=clusters, info=info)


def _solve(robot, qs, count, quantity, processes, progress):
    """Raw modes (stiffness) or sorted natural frequencies at the configurations."""
    from casflex._parallel import parallel_map
    from casflex.modal.sweep import point_frequencies
    from casflex.modal.tables import compute_modes

    if quantity == "stiffness":
        return compute_modes(robot, qs, count, processes=processes, progress=progress)
    jobs = [(i, (robot, q, count)) for i, q in enumerate(qs)]
    got = dict(parallel_map(point_frequencies, jobs, processes=processes, progress=progress,
                            desc="TMM"))
    return [got[i] for i in range(len(qs))]


def _clusters(omega, n_modes, gap):
    from casflex.modal.subspace import mode_clusters

    clusters = mode_clusters(omega, n_modes, gap)
    if clusters[-1][-1] + 1 != n_modes:
        raise ModelError(f"{n_modes} modes split the cluster of close modes "
                         f"{[k + 1 for k in clusters[-1]]}: use {clusters[-1][-1] + 1} modes")
    big = [c for c in clusters if len(c) > 2]
    if big:
        raise ModelError(f"the frequencies fit handles clusters of at most two close modes; "
                         f"modes {[k + 1 for k in big[0]]} come within {gap:g} of each "
                         "other: use a smaller gap or quantity='stiffness'")
    return clusters


def _invariants(lam, clusters):
    """Per cluster: λ (one mode) or the mean and squared split of λ (a pair)."""
    cols = []
    for c in clusters:
        if len(c) == 1:
            cols.append(lam[..., c[0]])
        else:
            cols += [0.5 * (lam[..., c[0]] + lam[..., c[1]]),
                     (lam[..., c[1]] - lam[..., c[0]]) ** 2]
    return np.stack(cols, axis=-1)


def _tails(coef, nd):
    """Per axis: the largest |coefficient| among the two highest along it, per entry."""
    out = []
    for ax in range(nd):
        t = np.abs(np.take(coef, [-2, -1], axis=ax))
        out.append(np.max(t.reshape(-1, *coef.shape[nd:]), axis=0))
    return out


def held_out_error(fit: ChebyshevFit, robot: Robot, qs: ArrayLike) -> np.ndarray:
    """Relative error of the fitted natural frequencies against direct TMM.

    Parameters
    ----------
    fit : ChebyshevFit
    robot : casflex.robot.Robot
    qs : array_like
        (k, n_joints) configurations inside the box [rad].

    Returns
    -------
    numpy.ndarray
        (k, n) ``|ω_fit / ω_TMM − 1|`` with ``ω_fit`` the eigenvalues of the fitted
        stiffness, both ascending.

    Examples
    --------
    >>> from casflex.robot import load
    >>> import dataclasses
    >>> arm = load("problems/arm2link.toml")
    >>> arm = dataclasses.replace(arm, joint_limits=(None, None, (0.2, 0.6)))
    >>> fit = fit_chebyshev(arm, 1, start_degree=8, max_degree=8, processes=1)
    >>> bool(held_out_error(fit, arm, [[0.0, 0.0, 0.33]]).max() < 1e-6)
    True
    """
    from casflex.tmm import natural_frequencies

    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    n = sum(len(c) for c in fit.clusters)
    out = np.empty((len(qs), n))
    for r, q in enumerate(qs):
        x = q[list(fit.shape_joints)]
        if "stiffness" in fit.coefficients:
            K = fit.evaluate("stiffness", x)
            w = np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (K + K.T)), 0.0, None))
        else:
            w = fit.evaluate("omega", x)
        out[r] = np.abs(w / natural_frequencies(robot, q, count=n) - 1.0)
    return out
