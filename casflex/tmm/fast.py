"""The TMM's fast path: a robot's set-up prepared once, its poses and mode shapes compiled.

One configuration of a small robot is ~0.1 ms of compiled root search (kernels.py); posing
the chain element by element in numpy, stacking it and checking it cost more than that.
Everything that does not depend on q — the element sequence, the beams' constants, the
conditioning verdict (:func:`casflex.tmm.check_chain` depends on the parameters only),
the search grid — is computed once per robot and kept in :data:`CACHE`, keyed on the
robot's ``links`` (a tuple of frozen dataclasses, hashed by value: a robot with any
changed parameter is a different key, so an entry can never be stale). Per call only the
rotations and the pose-dependent matrices are made, by one compiled walk of the DH rows
(:meth:`Prepared.pose`, the same walk as :func:`casflex.tmm.build_chain`).

The mode shapes of simple roots are made by one compiled call (:func:`shape_fields`):
the null vector of ``subU`` by inverse iteration, the state carried along the chain, the
fields sampled along every beam with angle-addition recurrences on the uniform grid (one
``sin``/``cos``/``sinh``/``cosh`` per beam and mode instead of twelve per point), the
derived fields and the unit-peak scaling. A k-fold root (k ≥ 2) takes the numpy path,
whose basis of the null space is orthonormalised on the sampled fields.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict

import numpy as np

from casflex.errors import ModelError
from casflex.tmm import elements as el
from casflex.tmm import kernels, shape_kernel
from casflex.tmm.chain import build_chain
from casflex.tmm.conditioning import check_chain, lowest_beam_frequency

__all__ = [
    "CACHE", "Prepared", "compiled_kernel", "compiled_shapes", "prepare", "roots",
    "search_points", "search_scales", "shape_fields", "shape_layout", "SHAPE_FIELDS",
]

#: Prepared set-ups (or None: the robot needs the full path) by ``robot.links``, newest last
CACHE: OrderedDict = OrderedDict()
CACHE_SIZE = 32

#: the static probe of the root search, relative to the lowest beam frequency
STATIC_PROBE = 1e-6


@functools.lru_cache(maxsize=64)
def _geomspace(start, stop, num):
    grid = np.geomspace(start, stop, num)
    grid.flags.writeable = False
    return grid


def search_points(reference_frequency: float, lowest_beam_frequency: float,
                  omega_max: float | None) -> tuple[float, np.ndarray]:
    """The static probe and the search grid of the root search [rad/s].

    Parameters
    ----------
    reference_frequency : float
        Lowest cantilever frequency of the whole length with the softest section [rad/s].
    lowest_beam_frequency : float
        Lowest clamped–free frequency of any beam alone [rad/s].
    omega_max : float or None
        Upper limit of the search [rad/s], or None for a search by count.

    Returns
    -------
    (float, numpy.ndarray)
        The probe, 1e-6 of the lowest beam frequency, where a clamped structure has no
        natural frequency; the grid (36 points over 1e-3–1e2 of the reference frequency,
        or 32 up to ``omega_max``), read-only.

    Examples
    --------
    >>> probe, grid = search_points(6.4, 6.4, None)
    >>> float(probe), grid.size, float(grid[0]), float(grid[-1])
    (6.4e-06, 36, 0.0064, 640.0)
    """
    if omega_max is None:
        grid = _geomspace(float(1e-3 * reference_frequency),
                          float(1e2 * reference_frequency), 36)
    else:
        grid = _geomspace(float(min(1e-2, omega_max / 10.0)), float(omega_max), 32)
    return STATIC_PROBE * lowest_beam_frequency, grid


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _program(robot):
    """The walk of :func:`casflex.tmm.build_chain` as data, element by element: the row,
    the stage (0 after Rx(α), 1 after Rz(θ)), the constant right factor C (R_e = R C),
    the step t of the start point after it (p += R t) and the kind (0–3 as in kernels)."""
    rows, stages, C, t, kind = [], [], [], [], []
    beam_to_local = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

    def add(row, stage, right, step, k):
        rows.append(row)
        stages.append(stage)
        C.append(right)
        t.append(step)
        kind.append(k)

    for row, link in enumerate(robot.links):
        body = None if link.tip.is_empty else el.body_mass_matrix(
            link.tip.mass, link.tip.inertia, link.tip.com_offset)
        if link.beam_along == "a":
            right = beam_to_local @ _rz(link.section_angle)
            add(row, 0, right, [link.a, 0.0, 0.0], 0)
            if body is not None:
                add(row, 0, right, [0.0, 0.0, 0.0], 1)
        elif link.a != 0.0:
            add(row, 0, np.eye(3), [link.a, 0.0, 0.0], 2)
        if link.joint_stiffness is not None:
            add(row, 1, np.eye(3), [0.0, 0.0, 0.0], 3)
        if link.beam_along == "d":
            right = _rz(link.section_angle)
            add(row, 1, right, [0.0, 0.0, link.d], 0)
            if body is not None:
                add(row, 1, right, [0.0, 0.0, 0.0], 1)
        else:
            if link.d != 0.0:
                add(row, 1, np.eye(3), [0.0, 0.0, link.d], 2)
            if link.beam_along is None and body is not None:
                add(row, 1, np.eye(3), [0.0, 0.0, 0.0], 1)
    return (np.array(rows, dtype=np.int64), np.array(stages, dtype=np.int64),
            np.array(C).reshape(-1, 3, 3), np.array(t, dtype=float).reshape(-1, 3),
            np.array(kind, dtype=np.int64))


def roots(robot, qs, count: int | None, omega_max: float | None, double_tol: float,
          rtol: float) -> tuple[list | None, tuple | None]:
    """The root search of ``robot`` at configurations ``qs`` by the prepared set-up and
    the compiled search (:func:`casflex.tmm.kernels.search`).

    Parameters
    ----------
    robot : casflex.robot.Robot
    qs : array_like
        (C, n_joints) or (n_joints,) joint variables [rad].
    count, omega_max, double_tol, rtol
        As for :func:`casflex.tmm.natural_frequencies` (omega_max in rad/s).

    Returns
    -------
    (list or None, tuple or None)
        ``(values, multiplicities)`` per configuration and ``(prepared, posed arrays)``;
        None where the full path must run (no kernels, a q it refuses with its message, a
        breakdown to diagnose).

    Examples
    --------
    >>> from casflex.robot import load
    >>> found, _ = roots(load("problems/arm2link.toml"), [0, 0, 0], 2, None, 1e-9, 1e-12)
    >>> found[0][0].round(2).tolist()
    [8.31, 11.97]
    """
    prepared = prepare(robot)
    if prepared is None:
        return None, None
    try:
        arrays = prepared.pose(np.atleast_2d(np.asarray(qs, dtype=float)))
    except (TypeError, ValueError):
        return None, None
    if arrays is None:
        return None, None
    points = prepared.search_grid(omega_max)
    found = kernels.search(arrays, points, prepared.cap, count, omega_max, double_tol, rtol)
    return found, (prepared, arrays)


def search_scales(chain) -> tuple[float, float, float]:
    """Frequency scales of a chain's root search [rad/s] (parameters only, not the pose).

    Parameters
    ----------
    chain : casflex.tmm.Chain

    Returns
    -------
    (float, float, float)
        ``cap``: the highest ω at which every beam keeps λL ≤ 80 (cosh within range);
        ``reference_frequency``: the lowest cantilever frequency of the whole length with
        the softest section (the scale of the grid); ``lowest_beam_frequency``: the lowest
        clamped–free frequency of any beam in bending, torsion or tension (the scale of
        the static probe: a robot whose torsion is far softer than its bending has
        natural frequencies far below the reference frequency).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0.0, 0.0, 0.0])
    >>> [round(float(v), 3) for v in search_scales(chain)]
    [46698.402, 6.413, 6.413]
    """
    beams = chain.beams
    cap = np.inf
    for b in beams:
        sec, mat, L = b.params["section"], b.params["material"], b.params["length"]
        ei = mat.E * min(sec.Ix, sec.Iy)
        cap = min(cap, (80.0 / L) ** 2 * np.sqrt(ei / (mat.rho * sec.A)))
    total = sum(b.params["length"] for b in beams) or 1.0
    soft = [b.params["material"].E * min(b.params["section"].Ix, b.params["section"].Iy)
            / (b.params["material"].rho * b.params["section"].A) for b in beams]
    reference = (1.875 / total) ** 2 * np.sqrt(min(soft)) if soft else 1.0
    lowest = min([reference] + [lowest_beam_frequency(b) for b in beams])
    return cap, reference, lowest


def prepare(robot) -> Prepared | None:
    """The robot's prepared set-up, from :data:`CACHE` or made now and kept there.

    Parameters
    ----------
    robot : casflex.robot.Robot

    Returns
    -------
    Prepared or None
        None without the compiled kernels, for unhashable links, or for a robot
        :func:`casflex.tmm.check_chain` refuses (the full path then raises its message
        at the caller's q).

    Examples
    --------
    >>> from casflex.robot import load
    >>> arm = load("problems/arm2link.toml")
    >>> prepare(arm) is prepare(load("problems/arm2link.toml"))   # equal links: one entry
    True
    """
    if not kernels.AVAILABLE:
        return None
    key = robot.links
    try:
        found = CACHE[key]
    except TypeError:  # unhashable parameters
        return None
    except KeyError:
        pass
    else:
        try:
            CACHE.move_to_end(key)
        except KeyError:  # evicted meanwhile by another thread: still a valid set-up
            pass
        return found
    template = build_chain(robot, np.zeros(robot.n_joints))
    try:
        check_chain(template)
        found = Prepared(robot, template)
    except ModelError:
        found = None
    CACHE[key] = found
    while len(CACHE) > CACHE_SIZE:
        try:
            CACHE.popitem(last=False)
        except KeyError:  # emptied meanwhile by another thread
            break
    return found


class Prepared:
    """A robot's chain set-up that does not depend on q (see the module docstring).

    Parameters
    ----------
    robot : casflex.robot.Robot
    template : casflex.tmm.Chain
        The robot's chain at any q (its element sequence and parameters do not depend
        on q), accepted by :func:`casflex.tmm.check_chain`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import build_chain
    >>> arm = load("problems/arm2link.toml")
    >>> prepared = Prepared(arm, build_chain(arm, [0.0, 0.0, 0.0]))
    >>> prepared.beam_rows, round(float(prepared.reference_frequency), 3)
    ((2, 3), 6.413)
    """

    def __init__(self, robot, template):
        rows, stages, C, t, kind = _program(robot)
        if [("beam", "body", "offset", "spring")[k] for k in kind] != [
                e.kind for e in template.elements]:
            raise ValueError("the compiled walk does not match build_chain")  # a bug
        self.constants = kernels.constants(template.elements)
        masses = np.zeros((kind.size, 6, 6))
        for j, e in enumerate(template.elements):
            if e.kind == "body":
                P = e.params
                masses[j] = el.body_mass_matrix(P["mass"], P["inertia"], P["com_offset"])
        self.program = (rows, stages, C, t, kind, masses, self.constants["stiffness"])
        self.theta = np.array([link.theta for link in robot.links], dtype=float)
        self.alpha = np.array([link.alpha for link in robot.links], dtype=float)
        self.joint_rows = np.array(robot.joint_rows, dtype=np.int64)
        self.cap, self.reference_frequency, self.lowest_beam_frequency = search_scales(
            template)
        self.elements = template.elements  # kinds, rows and parameters (not the poses)
        self.beam_rows = template.beam_rows
        self.layouts = {}
        self.points = {}  # the probe and the search grid by omega_max

    def shape_layout(self, n_points: int) -> dict:
        """:func:`shape_layout` of the robot's chain, kept per ``n_points``.

        Parameters
        ----------
        n_points : int
            Sample points per beam.

        Examples
        --------
        >>> from casflex.robot import load
        >>> prepare(load("problems/arm2link.toml")).shape_layout(5)["rows"]
        (2, 3)
        """
        layout = self.layouts.get(n_points)
        if layout is None:
            layout = self.layouts[n_points] = shape_layout(self.elements, n_points)
        return layout

    def search_grid(self, omega_max: float | None) -> np.ndarray:
        """The static probe, then the search grid (:func:`search_points`), kept per
        ``omega_max`` (64 at most).

        Parameters
        ----------
        omega_max : float or None
            Upper limit of the search [rad/s], or None for a search by count.

        Returns
        -------
        numpy.ndarray
            (37,) or (33,) [rad/s].

        Examples
        --------
        >>> from casflex.robot import load
        >>> prepare(load("problems/arm2link.toml")).search_grid(None).size
        37
        """
        points = self.points.get(omega_max)
        if points is None:
            probe, grid = search_points(self.reference_frequency, self.lowest_beam_frequency,
                                        omega_max)
            points = np.concatenate([[probe], grid])
            if len(self.points) < 64:
                self.points[omega_max] = points
        return points

    def pose(self, qs: np.ndarray) -> dict | None:
        """The packed arrays of :mod:`casflex.tmm.kernels` at configurations ``qs``.

        Parameters
        ----------
        qs : numpy.ndarray
            (C, n_joints) joint variables [rad].

        Returns
        -------
        dict or None
            The constants with ``R3``, ``M``, ``G``, ``T``, ``axis`` (per configuration
            and element) and ``start`` (C, E, 3) [m]; None for a q the full path must
            refuse with its message (wrong length, not finite).

        Examples
        --------
        >>> import numpy as np
        >>> from casflex.robot import load
        >>> arrays = prepare(load("problems/arm2link.toml")).pose(np.zeros((1, 3)))
        >>> arrays["R3"].shape, arrays["start"][0, 1].tolist()   # link 2 starts at the elbow
        ((1, 2, 3, 3), [1.0, 0.0, 0.0])
        """
        if qs.ndim != 2 or qs.shape[1] != self.joint_rows.size or not np.isfinite(qs).all():
            return None
        theta = np.empty((qs.shape[0], self.theta.size))  # (not broadcast_to: 10x slower)
        theta[:] = self.theta
        theta[:, self.joint_rows] += qs
        _compile()
        R3, start, M, G, T, axis = _KERNELS["pose"](theta, self.alpha, *self.program)
        return dict(self.constants, R3=R3, start=start, M=M, G=G, T=T, axis=axis)


def _pose(theta, alpha, rows, stages, C, t, kind, Mloc, stiffness):
    """Compiled walk of the DH rows at every configuration (see :class:`Prepared`)."""
    n_cfg, n_rows = theta.shape
    E = kind.size
    R3 = np.zeros((n_cfg, E, 3, 3))
    start = np.zeros((n_cfg, E, 3))
    M = np.zeros((n_cfg, E, 6, 6))
    G = np.zeros((n_cfg, E, 6, 6))
    T = np.zeros((n_cfg, E, 12, 12))
    axis = np.zeros((n_cfg, E, 3))
    R = np.empty((3, 3))
    F = np.empty((3, 3))
    W = np.empty((3, 3))
    Re = np.empty((3, 3))
    for c in range(n_cfg):
        R[:, :] = 0.0
        for i in range(3):
            R[i, i] = 1.0
        p = np.zeros(3)
        e = 0
        for row in range(n_rows):
            for stage in range(2):
                angle = alpha[row] if stage == 0 else theta[c, row]
                co, si = math.cos(angle), math.sin(angle)
                F[:, :] = 0.0
                if stage == 0:  # Rx(α)
                    F[0, 0], F[1, 1], F[1, 2], F[2, 1], F[2, 2] = 1.0, co, -si, si, co
                else:  # Rz(θ)
                    F[0, 0], F[0, 1], F[1, 0], F[1, 1], F[2, 2] = co, -si, si, co, 1.0
                for i in range(3):
                    for j in range(3):
                        W[i, j] = R[i, 0] * F[0, j] + R[i, 1] * F[1, j] + R[i, 2] * F[2, j]
                R[:, :] = W
                while e < E and rows[e] == row and stages[e] == stage:
                    for i in range(3):
                        for j in range(3):
                            Re[i, j] = (R[i, 0] * C[e, 0, j] + R[i, 1] * C[e, 1, j]
                                        + R[i, 2] * C[e, 2, j])
                    R3[c, e] = Re
                    start[c, e] = p
                    r0 = R[0, 0] * t[e, 0] + R[0, 1] * t[e, 1] + R[0, 2] * t[e, 2]
                    r1 = R[1, 0] * t[e, 0] + R[1, 1] * t[e, 1] + R[1, 2] * t[e, 2]
                    r2 = R[2, 0] * t[e, 0] + R[2, 1] * t[e, 1] + R[2, 2] * t[e, 2]
                    p[0] += r0
                    p[1] += r1
                    p[2] += r2
                    if kind[e] == 1:  # body: blockdiag(R, R) M blockdiag(R, R)ᵀ
                        for a in range(6):
                            for b in range(6):
                                s = 0.0
                                for k in range(3):
                                    for m in range(3):
                                        s += (Re[a % 3, k] * Mloc[e, 3 * (a // 3) + k,
                                                                  3 * (b // 3) + m]
                                              * Re[b % 3, m])
                                M[c, e, a, b] = s
                    elif kind[e] == 2:  # offset r: u -= [r]× θ, M -= [r]× F
                        for i in range(12):
                            T[c, e, i, i] = 1.0
                        for i in range(6):
                            G[c, e, i, i] = 1.0
                        for off in (0, 6):
                            T[c, e, off + 0, off + 4], T[c, e, off + 0, off + 5] = r2, -r1
                            T[c, e, off + 1, off + 3], T[c, e, off + 1, off + 5] = -r2, r0
                            T[c, e, off + 2, off + 3], T[c, e, off + 2, off + 4] = r1, -r0
                        for i in range(3):
                            for j in range(3):
                                G[c, e, i, 3 + j] = T[c, e, i, 3 + j]
                    elif kind[e] == 3:  # spring about the joint axis z
                        norm = math.sqrt(R[0, 2] ** 2 + R[1, 2] ** 2 + R[2, 2] ** 2)
                        for i in range(12):
                            T[c, e, i, i] = 1.0
                        for i in range(3):
                            axis[c, e, i] = R[i, 2]
                        for i in range(3):
                            for j in range(3):
                                T[c, e, 3 + i, 6 + j] = ((R[i, 2] / norm) * (R[j, 2] / norm)
                                                         / stiffness[e])
                    e += 1
    return R3, start, M, G, T, axis


def shape_fields(arrays: dict, c: int, omega: np.ndarray, s: np.ndarray,
                 moduli: np.ndarray) -> dict | None:
    """Mode shapes of simple roots in one compiled call (see the module docstring).

    Parameters
    ----------
    arrays : dict
        Packed arrays of :mod:`casflex.tmm.kernels` with ``R3`` for every element.
    c : int
        The configuration.
    omega : numpy.ndarray
        (m,) simple natural frequencies [rad/s].
    s : numpy.ndarray
        (n_beams, n_points) uniform sample points from each beam's start [m].
    moduli : numpy.ndarray
        (n_beams, 4) ``EIx, EIy, GJ, EA`` [N m², N m², N m², N].

    Returns
    -------
    dict or None
        The :class:`casflex.tmm.ModeShapes` fields of the modes (scaled to unit peak
        displacement), or None when a null vector cannot be made (the numpy path then).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> modes(load("problems/arm2link.toml"), [0.0, 0.0, 0.0], 2).displacement.shape
    (2, 2, 51, 3)
    """
    _compile()
    k = arrays
    sub = kernels.system_points(np.full(omega.size, c, dtype=np.int64), omega, k["kind"],
                                k["beam"], k["flat"], k["gather"], k["ratio"], k["R3"],
                                k["M"], k["T"])
    out = _KERNELS["shapes"](c, omega, sub, s, moduli, k["kind"], k["beam"], k["flat"],
                             k["gather"], k["ratio"], k["R3"], k["M"], k["T"], k["axis"],
                             k["stiffness"])
    if not out[-1]:
        return None
    return dict(zip(SHAPE_FIELDS, out[:-1], strict=True))


def shape_layout(elements, n_points: int) -> dict:
    """What the mode shapes of a chain need besides its pose: which elements are beams
    and bodies, the sample points and the beams' moduli (see :func:`compiled_shapes`).

    Parameters
    ----------
    elements : sequence of casflex.tmm.Element
        The chain's elements (kinds, rows, parameters; not their poses).
    n_points : int
        Sample points per beam, ends included.

    Returns
    -------
    dict
        ``beams``, ``bodies`` (element indices), ``s`` (n_beams, n_points) [m],
        ``moduli`` (n_beams, 4) ``EIx, EIy, GJ, EA``, ``rows``, ``body_rows``,
        ``spring_rows``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import build_chain
    >>> chain = build_chain(load("problems/arm2link.toml"), [0.0, 0.0, 0.0])
    >>> shape_layout(chain.elements, 3)["s"].tolist()
    [[0.0, 0.5, 1.0], [0.0, 0.5, 1.0]]
    """
    beams = [j for j, e in enumerate(elements) if e.kind == "beam"]
    frac = np.linspace(0.0, 1.0, n_points)
    params = [elements[j].params for j in beams]
    s = np.array([frac * P["length"] for P in params]).reshape(-1, n_points)
    s.flags.writeable = False  # shared by every ModeShapes made from this layout
    return {
        "beams": np.array(beams, dtype=np.intp),
        "bodies": np.array([j for j, e in enumerate(elements) if e.kind == "body"],
                           dtype=np.intp),
        "s": s,
        "moduli": np.array([[P["material"].E * P["section"].Ix,
                             P["material"].E * P["section"].Iy,
                             P["material"].G * P["section"].J,
                             P["material"].E * P["section"].A] for P in params]).reshape(-1, 4),
        "rows": tuple(elements[j].row for j in beams),
        "body_rows": tuple(e.row for e in elements if e.kind == "body"),
        "spring_rows": tuple(e.row for e in elements if e.kind == "spring"),
    }


def compiled_shapes(layout: dict, arrays: dict | None, omega: np.ndarray,
                    multiplicity: np.ndarray) -> dict | None:
    """Every :class:`casflex.tmm.ModeShapes` field of configuration 0 of ``arrays``.

    Parameters
    ----------
    layout : dict
        :func:`shape_layout` of the chain.
    arrays : dict or None
        Packed arrays of :mod:`casflex.tmm.kernels` with ``R3`` for every element and
        ``start`` (C, E, 3) [m].
    omega : numpy.ndarray
        (m,) natural frequencies [rad/s].
    multiplicity : numpy.ndarray
        (m,) their multiplicities.

    Returns
    -------
    dict or None
        The keyword arguments of ModeShapes; None for a multiple root, no arrays, fewer
        than 2 points or no null vector (the numpy path then).

    Examples
    --------
    >>> import numpy as np
    >>> from casflex.robot import load
    >>> from casflex.tmm import natural_frequencies
    >>> arm = load("problems/arm2link.toml")
    >>> prepared = prepare(arm)
    >>> w = natural_frequencies(arm, [0.0, 0.0, 0.0], count=2)
    >>> fields = compiled_shapes(prepared.shape_layout(11), prepared.pose(np.zeros((1, 3))),
    ...                          w, np.ones(2, dtype=int))
    >>> fields["displacement"].shape, float(abs(fields["displacement"]).max())
    ((2, 2, 11, 3), 1.0)
    """
    s = layout["s"]
    if arrays is None or not (multiplicity == 1).all() or s.shape[1] < 2 or omega.size == 0:
        return None
    fields = shape_fields(arrays, 0, omega, s, layout["moduli"])
    if fields is None:
        return None
    beams = layout["beams"]
    R = arrays["R3"][0].take(beams, axis=0)
    start = arrays["start"][0]
    fields.update(
        omega=omega, multiplicity=multiplicity, s=s, rows=layout["rows"], R=R,
        position=start.take(beams, axis=0)[:, None, :] + s[:, :, None] * R[:, None, :, 2],
        body_position=start.take(layout["bodies"], axis=0),
        body_rows=layout["body_rows"], spring_rows=layout["spring_rows"])
    return fields


#: the fields :func:`shape_fields` returns, in order
SHAPE_FIELDS = ("displacement", "rotation", "moment", "force", "slope", "curvature",
                 "twist_rate", "axial_strain", "body_state", "body_state_local",
                 "spring_rotation")
_KERNELS: dict = {}
_COMPILE_LOCK = threading.Lock()


def compiled_kernel(name: str):
    """This module's compiled kernel ``name``, wrapped with numba on first use (for
    :mod:`casflex.tmm.one_call`, which calls it from its own compiled code).

    Parameters
    ----------
    name : str
        ``"pose"`` (the walk of :meth:`Prepared.pose`) or ``"shapes"`` (the body of
        :func:`shape_fields`).

    Returns
    -------
    numba.core.registry.CPUDispatcher

    Examples
    --------
    >>> compiled_kernel("pose").py_func.__name__
    '_pose'
    """
    _compile()
    return _KERNELS[name]


def _compile():
    """Wrap the kernels with numba once (cached machine code, as in kernels.py), under a
    lock: Dask worker threads of one process may call this at the same time."""
    if _KERNELS:
        return
    with _COMPILE_LOCK:
        if _KERNELS:
            return
        import numba

        jit = numba.njit(cache=True)
        _KERNELS.update(pose=jit(_pose), shapes=shape_kernel.wrap(jit))
