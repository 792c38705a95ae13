"""Frequencies and mode shapes of one configuration in one compiled call.

``natural_frequencies(robot, q)`` and ``modes(robot, q)`` at one configuration of a
prepared robot (:mod:`casflex.tmm.fast`) ran four compiled kernels — the pose, the root
search, the system matrix at the roots, the shapes — with Python between them: the packed
arrays' dict, the result lists, the sample points' positions in numpy. On the Table 8 arm
that glue was ~24 % of ``modes`` (57 of 242 µs, measured under load). Here the same
kernels are called from one compiled function (:func:`single`), with the same arguments in
the same order, so the roots and the shapes are bit for bit those of the four separate
calls; only the Python around them is gone.

Whatever the separate calls would hand to the full path still goes there: a robot not
prepared, a ``q`` to refuse, a search breakdown (:func:`single` returns None), and multiple
roots or a failed null vector (it returns the roots without shapes; the numpy shapes then).
"""

from __future__ import annotations

import hashlib
import threading

import numpy as np

from casflex.tmm import fast, kernels, shape_kernel

__all__ = ["single"]

_KERNEL: dict = {}
_LOCK = threading.Lock()
# the compiled kernels :func:`_single` calls, set by :func:`_compile` before it is wrapped
_pose = _search = _system = _shapes = _body = None
#: the sample points and moduli when no shapes are wanted (read-only like a layout's ``s``,
#: so both calls share one compiled specialisation)
_NO_POINTS = np.zeros((0, 2))
_NO_POINTS.flags.writeable = False
_NO_MODULI = np.zeros((0, 4))
_NO_INDEX = np.zeros(0, dtype=np.intp)


def single(robot, q, count: int | None, omega_max: float | None, double_tol: float,
           rtol: float, n_points: int) -> tuple | None:
    """The roots, and the mode-shape fields of simple roots, of one configuration.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        (n_joints,) joint variables [rad].
    count, omega_max, double_tol, rtol
        As for :func:`casflex.tmm.natural_frequencies` (omega_max in rad/s).
    n_points : int
        Sample points per beam of the shapes; 0 for the frequencies alone.

    Returns
    -------
    tuple or None
        ``(values, multiplicities, fields)``: the roots [rad/s] with their
        multiplicities, and the keyword arguments of :class:`casflex.tmm.ModeShapes`, or
        None for the fields when none were asked for or the compiled shapes cannot make
        them (multiple roots, fewer than 2 points, no null vector). None instead of the
        tuple where the full path must run (no kernels, a ``q`` it refuses with its
        message, a breakdown to diagnose).

    Examples
    --------
    >>> from casflex.robot import load
    >>> w, mult, fields = single(load("problems/arm2link.toml"), [0.0, 0.0, 0.0], 2, None,
    ...                          1e-9, 1e-12, 11)
    >>> w.round(2).tolist(), mult.tolist(), fields["displacement"].shape
    ([8.31, 11.97], [1, 1], (2, 2, 11, 3))
    """
    prepared = fast.prepare(robot)
    if prepared is None or (omega_max is not None and not omega_max > 0.0):
        return None
    try:
        q = np.asarray(q, dtype=float)
    except (TypeError, ValueError):
        return None
    if q.shape != prepared.joint_rows.shape:
        return None
    points = prepared.search_grid(omega_max)
    kernel = _KERNEL.get("single")
    if kernel is None:
        kernel = _compile()
    if n_points > 0:
        layout = prepared.shape_layout(n_points)
        s, moduli, beams, bodies = (layout["s"], layout["moduli"], layout["beams"],
                                    layout["bodies"])
    else:
        s, moduli, beams, bodies = _NO_POINTS, _NO_MODULI, _NO_INDEX, _NO_INDEX
    constants = prepared.constants
    out = kernel(q, prepared.theta, prepared.joint_rows, prepared.alpha, *prepared.program,
                 constants["beam"], constants["flat"], constants["gather"],
                 constants["ratio"], points, float(prepared.cap),
                 -1 if count is None else int(count),
                 -1.0 if omega_max is None else float(omega_max), float(double_tol),
                 float(rtol), 64 if count is None else int(count), s, moduli, beams, bodies)
    values, multiplicity, status, shaped, fields, R, position, body_position = out
    if status:
        return None
    if not shaped:
        return values, multiplicity, None
    result = dict(zip(fast.SHAPE_FIELDS, fields, strict=True))
    result.update(
        omega=values, multiplicity=multiplicity, s=s, rows=layout["rows"], R=R,
        position=position, body_position=body_position, body_rows=layout["body_rows"],
        spring_rows=layout["spring_rows"])
    return values, multiplicity, result


def _single(q, theta0, joint_rows, alpha, rows, stages, C, t, kind, Mloc, stiffness, beam,
            flat, gather, ratio, points, cap, count, omega_max, double_tol, rtol, width, s,
            moduli, beams, bodies):
    """Compiled body of :func:`single`: the calls of ``Prepared.pose``, ``kernels.search``,
    ``fast.shape_fields`` and ``fast.compiled_shapes``, in that order, for configuration
    0. Status 1: a q not finite or a search breakdown (the full path then)."""
    n_rows = theta0.size
    theta = np.empty((1, n_rows))
    finite = True
    for i in range(n_rows):
        theta[0, i] = theta0[i]
    for i in range(joint_rows.size):
        finite = finite and np.isfinite(q[i])
        theta[0, joint_rows[i]] += q[i]
    R3, start, M, G, T, axis = _pose(theta, alpha, rows, stages, C, t, kind, Mloc, stiffness)
    if finite:
        values, multiplicity, filled, status = _search(
            points, cap, count, omega_max, double_tol, rtol, kind, beam, flat, gather, ratio,
            R3, M, G, T, axis, stiffness, width)
        n = filled[0]
        bad = status[0] != 0
    else:
        values, multiplicity = np.zeros((1, 0)), np.zeros((1, 0), dtype=np.int64)
        n = 0
        bad = True
    shaped = not bad and s.shape[0] > 0 and s.shape[1] >= 2 and n > 0
    for i in range(n):
        shaped = shaped and multiplicity[0, i] == 1
    w = values[0, :n].copy()  # contiguous: the kernels' compiled versions for the
    # four-call path's arrays are reused (another layout would compile them again)
    wm = w.copy() if shaped else np.empty(0)  # no shapes: the kernels on no mode
    sub = _system(np.zeros(wm.size, dtype=np.int64), wm, kind, beam, flat, gather, ratio,
                  R3, M, T)
    fields = _shapes(0, wm, sub, s, moduli, kind, beam, flat, gather, ratio, R3, M, T, axis,
                     stiffness)
    shaped = shaped and fields[-1]
    nb, P = s.shape
    R = np.empty((nb, 3, 3))
    position = np.empty((nb, P, 3))
    for b in range(nb):
        e = beams[b]
        for i in range(3):
            for k in range(3):
                R[b, i, k] = R3[0, e, i, k]
        for p in range(P):  # start + s R e_z, as compiled_shapes
            for i in range(3):
                position[b, p, i] = start[0, e, i] + s[b, p] * R3[0, e, i, 2]
    body_position = np.empty((bodies.size, 3))
    for b in range(bodies.size):
        for i in range(3):
            body_position[b, i] = start[0, bodies[b], i]
    return (w, multiplicity[0, :n].copy(), bad, shaped, fields[:-1], R, position,
            body_position)


def _compile():
    """Wrap :func:`_single` once, with the other modules' compiled kernels as the globals
    it calls (numba resolves them when it compiles; its machine code is cached).

    Numba keys a function's cache on its own bytecode and closure, not on the source of
    what it calls: after a change to kernels.py, fast.py or shape_kernel.py a cached
    ``_single`` would still run their old code. So the cached function is a closure over
    the SHA-256 of those modules' source (:func:`_keyed`), and ``_single`` is compiled
    into it (not cached on its own)."""
    with _LOCK:
        if "single" not in _KERNEL:
            import numba

            g = globals()
            g.update(_pose=fast.compiled_kernel("pose"), _shapes=fast.compiled_kernel("shapes"),
                     _search=kernels.search_roots, _system=kernels.system_points,
                     _body=numba.njit(_single))
            digest = hashlib.sha256()
            for module in (kernels, fast, shape_kernel):
                with open(module.__file__, "rb") as source:
                    digest.update(source.read())
            _KERNEL["single"] = numba.njit(cache=True)(_keyed(digest.hexdigest()))
    return _KERNEL["single"]


def _keyed(digest):
    """:func:`_single` (as ``_body``) in a closure over ``digest`` (see :func:`_compile`)."""
    def single(q, theta0, joint_rows, alpha, rows, stages, C, t, kind, Mloc, stiffness, beam,
               flat, gather, ratio, points, cap, count, omega_max, double_tol, rtol, width, s,
               moduli, beams, bodies):
        digest  # noqa: B018 (a closure variable: part of numba's cache key)
        return _body(q, theta0, joint_rows, alpha, rows, stages, C, t, kind, Mloc, stiffness,
                     beam, flat, gather, ratio, points, cap, count, omega_max, double_tol,
                     rtol, width, s, moduli, beams, bodies)
    return single
