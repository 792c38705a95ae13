"""Planned joint moves: bang-bang point-to-point profiles and move files.

A move takes every joint from ``q0`` to ``qf`` in ``duration`` seconds with a bang-bang
acceleration (§3.3.7.1): constant acceleration for the first half, the opposite for the
second, so that position is an S-curve and velocity a triangle. Joints that do not move
hold their value. After ``duration`` the joints stay at ``qf``.

Move files are TOML with one table per move (see ``problems/moves.toml``)::

    [move1]
    description = "Table 9, move 1"
    duration = 2.0          # s
    q0 = [0.0, 0.0, 0.0]    # rad
    qf = [-1.0, -1.0, -1.0]
    settle = 3.0            # s simulated after the move ends (optional, default 3)

A move is referred to as ``FILE:NAME`` (``problems/moves.toml:move1``).

This module owns every way of sampling a reference:

* :meth:`Move.sample`, :meth:`ShapedMove.sample` — numeric samples of a move;
* :func:`reference_function` — the reference as a ``casadi.Function`` of time (a move,
  a shaped move, or piecewise-linear interpolants of sampled arrays);
* :func:`reference_sampler` — a numeric sampler of any reference (a move, a shaped move,
  or sampled arrays ``(t, q, dq, ddq)`` with cubic Hermite interpolation), with its time
  span and the end of its motion;
* :attr:`Move.breakpoints`, :attr:`ShapedMove.breakpoints` — where the acceleration jumps.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._problemfile import read_toml
from casflex._validate import BOUNDS, plausible, to_float
from casflex.errors import ModelError, ProblemFileError

__all__ = ["Move", "ShapedMove", "load_moves", "load_move", "reference_function",
           "reference_sampler", "ReferenceSampler"]

_PROFILES = ("bang-bang",)


@dataclass(frozen=True)
class Move:
    """A point-to-point joint move with a bang-bang acceleration profile.

    Attributes
    ----------
    q0, qf : numpy.ndarray
        Start and end joint values [rad].
    duration : float
        Move time T [s]; the acceleration switches sign at T/2.
    settle : float
        Time simulated after the move ends [s].
    name, description : str

    Examples
    --------
    >>> m = Move(q0=np.zeros(2), qf=np.array([-1.0, 0.5]), duration=2.0)
    >>> m.peak_acceleration.tolist()
    [-1.0, 0.5]
    """

    q0: np.ndarray
    qf: np.ndarray
    duration: float
    settle: float = 3.0
    name: str = "move"
    description: str = ""
    profile: str = "bang-bang"

    def __post_init__(self):
        q0 = np.atleast_1d(np.asarray(self.q0, dtype=float))
        qf = np.atleast_1d(np.asarray(self.qf, dtype=float))
        object.__setattr__(self, "q0", q0)
        object.__setattr__(self, "qf", qf)
        if q0.shape != qf.shape:
            raise ProblemFileError(None, f"{self.name}.qf", qf.tolist(),
                                   f"must have as many values as q0 ({q0.size})")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qf))):
            raise ProblemFileError(None, f"{self.name}.q0/qf", None, "must be finite")
        if not (math.isfinite(self.duration) and self.duration > 0.0):
            raise ProblemFileError(None, f"{self.name}.duration", self.duration, "must be > 0")
        if not (math.isfinite(self.settle) and self.settle >= 0.0):
            raise ProblemFileError(None, f"{self.name}.settle", self.settle, "must be >= 0")
        self._check_plausible()

    def _check_plausible(self):
        """Plausibility bounds (casflex._validate.BOUNDS): angles, times, peak rates."""
        def check(value, quantity, key):
            plausible(value, quantity, f"{self.name}.{key}", error=ProblemFileError)

        for key in ("q0", "qf"):
            for v in getattr(self, key):
                check(float(v), "angle", key)
        check(self.duration, "move_duration", "duration")
        check(self.settle, "settle", "settle")
        # bang-bang: peak speed 2 |Δq| / T at T/2, acceleration 4 |Δq| / T² throughout
        span = float(np.max(np.abs(self.qf - self.q0), initial=0.0))
        for quantity, what, peak in (
                ("joint_velocity", "speed 2 |qf - q0| / T", 2.0 * span / self.duration),
                ("joint_acceleration", "acceleration 4 |qf - q0| / T^2",
                 4.0 * span / self.duration**2)):
            bound = BOUNDS[quantity]
            if peak > bound.high:
                raise ProblemFileError(None, f"{self.name}.duration", self.duration,
                                       f"gives a peak joint {what} = {peak:.4g} "
                                       f"{bound.unit}; that {bound.rule}")

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return self.q0.size

    @property
    def t_end(self) -> float:
        """End of the simulated interval, ``duration + settle`` [s]."""
        return self.duration + self.settle

    @property
    def peak_acceleration(self) -> np.ndarray:
        """Joint accelerations of the first half [rad/s²]: ``4 (qf − q0) / T²``."""
        return 4.0 * (self.qf - self.q0) / self.duration**2

    @property
    def breakpoints(self) -> np.ndarray:
        """Times [s] where the acceleration jumps: start, half time and end of the move.

        Examples
        --------
        >>> Move([0.0], [1.0], 2.0).breakpoints.tolist()
        [0.0, 1.0, 2.0]
        """
        T = float(self.duration)
        return np.array([0.0, 0.5 * T, T])

    def sample(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint position, velocity and acceleration at times ``t``.

        Parameters
        ----------
        t : float or array_like
            Times [s] (before 0 the move has not started; after ``duration`` it holds).

        Returns
        -------
        q, qd, qdd : numpy.ndarray
            Each of shape ``(len(t), n_joints)`` [rad, rad/s, rad/s²]
            (``(n_joints,)`` for a scalar ``t``).

        Examples
        --------
        >>> m = Move(q0=[0.0], qf=[-1.0], duration=2.0)
        >>> q, qd, qdd = m.sample([0.0, 1.0, 2.0, 3.0])
        >>> q.ravel().tolist(), qd.ravel().tolist()
        ([0.0, -0.5, -1.0, -1.0], [0.0, -1.0, 0.0, 0.0])
        """
        scalar = np.ndim(t) == 0
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        T, a = self.duration, self.peak_acceleration[None, :]
        first = (t >= 0.0) & (t < T / 2.0)
        second = (t >= T / 2.0) & (t < T)
        after = t >= T
        tt = np.clip(t, 0.0, T)
        q = np.where(first, self.q0 + 0.5 * a * tt**2,
                     np.where(second | after, self.qf - 0.5 * a * (T - tt) ** 2, self.q0))
        qd = np.where(first, a * tt, np.where(second, a * (T - tt), 0.0)) + 0.0
        qdd = np.where(first, a, np.where(second, -a, 0.0))
        q = np.broadcast_to(q, (t.shape[0], self.n_joints)).copy()
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd

    def time_grid(self, dt: float) -> np.ndarray:
        """Uniform time grid from 0 to ``t_end`` with step ``dt`` [s] (end included).

        Parameters
        ----------
        dt : float
            Time step [s]; ``t_end / dt`` is rounded to a whole number of steps.

        Returns
        -------
        numpy.ndarray
            ``0, dt, 2 dt, ...`` up to about ``t_end`` [s].

        Examples
        --------
        >>> m = Move(q0=[0.0], qf=[1.0], duration=1.0, settle=0.5)
        >>> m.time_grid(0.25).tolist()
        [0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5]
        """
        n = int(round(self.t_end / dt))
        return np.arange(n + 1) * dt


@dataclass(frozen=True)
class ShapedMove:
    """A move convolved with an input shaper, in closed form.

    ``q(t) = Σ A_i q_move(t − t_i)`` (and likewise for the rates): the shaped reference
    of a bang-bang move is a sum of shifted bang-bang moves, so it can be sampled exactly
    at any time and written as a CasADi function of time (for the closed-loop
    simulations and the generated controllers). The shaper's amplitudes sum to 1, so the
    shaped move ends at ``qf``, ``shaper.duration`` later than the move.

    Parameters
    ----------
    move : Move
        The planned (unshaped) move.
    shaper : casflex.shaping.Shaper
        Impulse times [s] (from 0) and amplitudes.

    Examples
    --------
    >>> from casflex.shaping import Shaper
    >>> s = ShapedMove(Move([0.0], [-1.0], 2.0), Shaper([0.0, 0.5], [0.5, 0.5]))
    >>> s.duration, s.t_end
    (2.5, 5.5)
    >>> [round(float(v), 6) for v in s.sample(2.25)[0]], float(s.sample(2.5)[0][0])
    ([-0.984375], -1.0)
    """

    move: Move
    shaper: object

    def __post_init__(self):
        amplitudes = np.asarray(self.shaper.amplitudes, dtype=float)
        if not abs(amplitudes.sum() - 1.0) < 1e-9:
            raise ProblemFileError(None, "shaper.amplitudes", amplitudes.tolist(),
                                   "must sum to 1 to reach the move's end values")

    @property
    def q0(self) -> np.ndarray:
        """Start joint values [rad]."""
        return self.move.q0

    @property
    def qf(self) -> np.ndarray:
        """End joint values [rad]."""
        return self.move.qf

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return self.move.n_joints

    @property
    def duration(self) -> float:
        """Time until the shaped reference comes to rest [s]: move plus shaper."""
        return self.move.duration + float(self.shaper.duration)

    @property
    def settle(self) -> float:
        """Time simulated after the shaped move ends [s] (the move's ``settle``)."""
        return self.move.settle

    @property
    def t_end(self) -> float:
        """End of the simulated interval [s]."""
        return self.duration + self.settle

    @property
    def name(self) -> str:
        """The move's name with a ``+shaper`` suffix."""
        return f"{self.move.name}+shaper"

    @property
    def description(self) -> str:
        """Human-readable description."""
        return (f"{self.move.description or self.move.name}, shaped by "
                f"{len(self.shaper.times)} impulses over {self.shaper.duration:.4g} s")

    @property
    def breakpoints(self) -> np.ndarray:
        """Times [s] where the shaped acceleration jumps (sorted, unique)."""
        T = self.move.duration
        pts = [t + k * T / 2.0 for t in np.asarray(self.shaper.times, dtype=float)
               for k in (0, 1, 2)]
        return np.unique(np.round(pts, 15))

    def sample(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shaped position, velocity and acceleration at times ``t`` (see :meth:`Move.sample`).

        Parameters
        ----------
        t : float or array_like
            Times [s] from the start of the shaped move.

        Returns
        -------
        q, qd, qdd : numpy.ndarray
            Each of shape ``(len(t), n_joints)`` [rad, rad/s, rad/s²]
            (``(n_joints,)`` for a scalar ``t``).

        Examples
        --------
        >>> from casflex.shaping import Shaper
        >>> s = ShapedMove(Move([0.0], [-1.0], 2.0), Shaper([0.0], [1.0]))
        >>> [a.ravel().tolist() for a in s.sample([1.0])]
        [[-0.5], [-1.0], [1.0]]
        """
        scalar = np.ndim(t) == 0
        t = np.atleast_1d(np.asarray(t, dtype=float))
        q = np.zeros((t.size, self.n_joints))
        qd, qdd = np.zeros_like(q), np.zeros_like(q)
        for ti, ai in zip(self.shaper.times, self.shaper.amplitudes, strict=True):
            a, b, c = self.move.sample(t - ti)
            q += ai * a
            qd += ai * b
            qdd += ai * c
        if scalar:
            return q[0], qd[0], qdd[0]
        return q, qd, qdd

    def casadi_reference(self) -> ca.Function:
        """``reference (t) -> (qd, dqd, ddqd)`` as a CasADi function, equal to :meth:`sample`.

        Examples
        --------
        >>> from casflex.shaping import Shaper
        >>> s = ShapedMove(Move([0.0], [-1.0], 2.0), Shaper([0.0, 0.5], [0.5, 0.5]))
        >>> round(float(s.casadi_reference()(2.25)[0]), 6)
        -0.984375
        """
        base = reference_function(self.move)
        t = ca.SX.sym("t")
        out = [0, 0, 0]
        for ti, ai in zip(self.shaper.times, self.shaper.amplitudes, strict=True):
            parts = base(t - float(ti))
            out = [o + float(ai) * p for o, p in zip(out, parts, strict=True)]
        return ca.Function("reference", [t], out, ["t"], ["qd", "dqd", "ddqd"])

    def time_grid(self, dt: float) -> np.ndarray:
        """Uniform time grid from 0 to ``t_end`` with step ``dt`` [s] (end included).

        Parameters
        ----------
        dt : float
            Time step [s]; ``t_end / dt`` is rounded to a whole number of steps.

        Returns
        -------
        numpy.ndarray
            ``0, dt, 2 dt, ...`` up to about ``t_end`` [s] (the shaper's duration included).

        Examples
        --------
        >>> from casflex.shaping import Shaper
        >>> s = ShapedMove(Move([0.0], [1.0], 1.0, settle=0.5), Shaper([0.0, 0.5], [0.5, 0.5]))
        >>> s.time_grid(0.5).tolist()
        [0.0, 0.5, 1.0, 1.5, 2.0]
        """
        n = int(round(self.t_end / dt))
        return np.arange(n + 1) * dt


# ---------------------------------------------------------------------------- sampling


def _is_move(reference) -> bool:
    """A Move or a closed-form shaped move (anything with ``casadi_reference``)."""
    return isinstance(reference, Move) or hasattr(reference, "casadi_reference")


def reference_function(move: Move | ShapedMove | tuple) -> ca.Function:
    """A reference as a CasADi function of time.

    Parameters
    ----------
    move : Move or ShapedMove or tuple
        A move with ``q0``, ``qf``, ``duration`` and ``peak_acceleration``; a move that
        has its own ``casadi_reference()`` (e.g. :class:`ShapedMove`) supplies its
        reference itself. Before ``t = 0`` a move rests at ``q0``, after the duration at
        ``qf``. Sampled arrays ``(t, q, dq, ddq)`` [s, rad, rad/s, rad/s²] give
        piecewise-linear interpolants of the samples.

    Returns
    -------
    casadi.Function
        ``reference (t) -> (qd, dqd, ddqd)`` [rad, rad/s, rad/s²], equal to
        :meth:`Move.sample` for a move.

    Examples
    --------
    >>> r = reference_function(Move([0.0], [-1.0], 2.0))
    >>> [float(v) for v in r(1.5)]
    [-0.875, -0.5, 1.0]
    >>> t = np.array([0.0, 1.0])
    >>> r = reference_function((t, np.c_[[0.0, 1.0]], np.c_[[1.0, 1.0]], np.c_[[0.0, 0.0]]))
    >>> [float(v) for v in r(0.25)]
    [0.25, 1.0, 0.0]
    """
    if hasattr(move, "casadi_reference"):  # e.g. ShapedMove
        return move.casadi_reference()
    t = ca.SX.sym("t")
    if not isinstance(move, Move):  # sampled arrays
        t_ref, qs, dqs, ddqs = (np.asarray(v, dtype=float) for v in move)
        parts = []
        for arr in (qs, dqs, ddqs):
            arr = arr.reshape(t_ref.size, -1)
            li = ca.interpolant("ref", "linear", [t_ref], arr.T.ravel(order="F"))
            parts.append(li(t))
        return ca.Function("reference", [t], parts, ["t"], ["qd", "dqd", "ddqd"])
    T = float(move.duration)
    q0, qf = ca.DM(move.q0), ca.DM(move.qf)
    a = ca.DM(move.peak_acceleration)
    tc = ca.fmin(ca.fmax(t, 0.0), T)
    first = ca.logic_and(t >= 0.0, t < T / 2.0)
    second = ca.logic_and(t >= T / 2.0, t < T)
    q = ca.if_else(t < 0.0, q0, ca.if_else(first, q0 + 0.5 * a * tc**2,
                                           qf - 0.5 * a * (T - tc) ** 2))
    dq = ca.if_else(first, a * tc, ca.if_else(second, a * (T - tc), ca.DM.zeros(q0.shape)))
    ddq = ca.if_else(first, a, ca.if_else(second, -a, ca.DM.zeros(q0.shape)))
    return ca.Function("reference", [t], [q, dq, ddq], ["t"], ["qd", "dqd", "ddqd"])


class ReferenceSampler(NamedTuple):
    """A numeric sampler of a reference (:func:`reference_sampler`).

    Attributes
    ----------
    sample : callable
        ``sample(t) -> (q, dq, ddq)``, each of shape ``(len(t), n)`` [rad, rad/s, rad/s²].
    t_start, t_last : float
        First and last time of the reference [s] (a move: 0 and ``t_end``).
    t_move_end : float
        End of the motion [s] (a move: its duration; samples: the sample after the last
        one that moves).

    Examples
    --------
    >>> r = reference_sampler(Move([0.0], [1.0], 1.0, settle=0.5), 1)
    >>> r.t_start, r.t_last, r.t_move_end
    (0.0, 1.5, 1.0)
    >>> q, dq, ddq = r.sample([0.0, 0.5, 1.0])
    >>> q.ravel().tolist(), dq.ravel().tolist()
    ([0.0, 0.5, 1.0], [0.0, 2.0, 0.0])
    """

    sample: Callable
    t_start: float
    t_last: float
    t_move_end: float


def _hermite(t_ref, y, dy, t):
    """Cubic Hermite interpolation of samples ``y`` with slopes ``dy`` at times ``t``."""
    idx = np.clip(np.searchsorted(t_ref, t, side="right") - 1, 0, t_ref.size - 2)
    h = (t_ref[idx + 1] - t_ref[idx])[:, None]
    s = ((t - t_ref[idx])[:, None] / h).clip(0.0, 1.0)
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    out = h00 * y[idx] + h10 * h * dy[idx] + h01 * y[idx + 1] + h11 * h * dy[idx + 1]
    before, after = t < t_ref[0], t > t_ref[-1]
    out[before] = y[0]
    out[after] = y[-1] + dy[-1] * (t[after] - t_ref[-1])[:, None]
    return out


def reference_sampler(reference: Move | ShapedMove | tuple, n_joints: int
                      ) -> ReferenceSampler:
    """A numeric sampler of a move, a shaped move or sampled arrays.

    Parameters
    ----------
    reference : Move or ShapedMove or tuple
        A move, or sampled arrays ``(t, q, dq, ddq)`` [s, rad, rad/s, rad/s²] (shape
        ``(N,)`` and ``(N, n)``), e.g. from :func:`casflex.shaping.apply_shaper`. Between
        samples ``q`` and ``dq`` are cubic Hermite interpolants, ``ddq`` is linear.
    n_joints : int
        Expected number of joints (checked).

    Returns
    -------
    ReferenceSampler

    Raises
    ------
    casflex.errors.ModelError
        Another number of joints, or malformed sampled arrays.

    Examples
    --------
    >>> r = reference_sampler(Move([0.0], [-1.0], 2.0, settle=1.0), 1)
    >>> r.t_start, r.t_last, r.t_move_end
    (0.0, 3.0, 2.0)
    >>> [a.ravel().tolist() for a in r.sample([0.5])]
    [[-0.125], [-0.5], [-1.0]]
    >>> t = np.array([0.0, 1.0, 2.0])
    >>> s = reference_sampler((t, *Move([0.0], [1.0], 1.0).sample(t)), 1)
    >>> s.t_move_end, s.sample([0.5])[0].ravel().tolist()
    (1.0, [0.5])
    """
    n = n_joints
    if _is_move(reference):
        if reference.n_joints != n:
            raise ModelError(f"move '{reference.name}' has {reference.n_joints} joints; the "
                             f"model has {n}")
        return ReferenceSampler(reference.sample, 0.0, reference.t_end,
                                float(reference.duration))
    try:
        t_ref, q, dq, ddq = reference
    except (TypeError, ValueError):
        raise ModelError("reference must be a casflex.moves.Move or a tuple (t, q, dq, ddq) "
                         f"of sampled arrays; got {type(reference).__name__}") from None
    if dq is None or ddq is None:
        raise ModelError("a sampled reference needs q, dq and ddq (e.g. apply_shaper(s, t, "
                         "q, dq, ddq)); got None")
    t_ref = np.asarray(t_ref, dtype=float).ravel()
    arrays = []
    for name, a in (("q", q), ("dq", dq), ("ddq", ddq)):
        a = np.asarray(a, dtype=float)
        if a.ndim == 1:
            a = a[:, None]
        if a.shape != (t_ref.size, n):
            raise ModelError(f"reference {name} has shape {a.shape}; expected "
                             f"({t_ref.size}, {n}) for a model with {n} joints")
        arrays.append(a)
    q, dq, ddq = arrays
    if t_ref.size < 2 or np.any(np.diff(t_ref) <= 0.0) or not np.all(np.isfinite(t_ref)):
        raise ModelError("reference t must hold >= 2 finite, strictly increasing times [s]")
    moving = (np.abs(dq).max(axis=1) > 1e-12) | (np.abs(ddq).max(axis=1) > 1e-12)
    if np.any(moving):
        last = int(np.nonzero(moving)[0][-1])
        t_move_end = float(t_ref[min(last + 1, t_ref.size - 1)])
    else:
        t_move_end = float(t_ref[0])

    def sample(t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        ddq_t = np.column_stack([np.interp(t, t_ref, ddq[:, j]) for j in range(n)])
        return _hermite(t_ref, q, dq, t), _hermite(t_ref, dq, ddq, t), ddq_t

    return ReferenceSampler(sample, float(t_ref[0]), float(t_ref[-1]), t_move_end)


# ---------------------------------------------------------------------------- move files


def _angles(r, path, name, key, value, n=None):
    if not isinstance(value, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ProblemFileError(path, f"{name}.{key}", value, "must be a list of numbers [rad]")
    out = np.array([to_float(v) for v in value], dtype=float) * r
    if not np.all(np.isfinite(out)):
        raise ProblemFileError(path, f"{name}.{key}", value, "must be finite (no NaN or inf)")
    if n is not None and out.size != n:
        raise ProblemFileError(path, f"{name}.{key}", value,
                               f"must have as many values as q0 ({n})")
    return out


def load_moves(path: str | Path) -> dict[str, Move]:
    """Read every move of a move file.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    dict of str to Move

    Examples
    --------
    >>> list(load_moves("problems/moves.toml"))[:3]
    ['move1', 'move2', 'move3']
    """
    path = Path(path)
    data = read_toml(path)
    moves = {}
    known = {"description", "duration", "q0", "qf", "settle", "unit", "profile", "robot"}
    for name, table in data.items():
        if not isinstance(table, dict):
            raise ProblemFileError(path, name, table, "each move must be a table [name]")
        unknown = sorted(set(table) - known)
        if unknown:
            raise ProblemFileError(path, f"{name}.{unknown[0]}", table[unknown[0]],
                                   f"unknown key; known keys are {sorted(known)}")
        for key in ("duration", "q0", "qf"):
            if key not in table:
                raise ProblemFileError(path, f"{name}.{key}", None, "is required but missing")
        unit = table.get("unit", "rad")
        if unit not in ("rad", "deg"):
            raise ProblemFileError(path, f"{name}.unit", unit, "must be 'rad' or 'deg'")
        profile = table.get("profile", "bang-bang")
        if profile not in _PROFILES:
            raise ProblemFileError(path, f"{name}.profile", profile,
                                   f"must be one of {list(_PROFILES)}")
        r = math.pi / 180.0 if unit == "deg" else 1.0
        q0 = _angles(r, path, name, "q0", table["q0"])
        qf = _angles(r, path, name, "qf", table["qf"], q0.size)
        for key in ("duration", "settle"):
            v = table.get(key, 3.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ProblemFileError(path, f"{name}.{key}", v, "must be a number [s]")
        try:
            moves[name] = Move(q0=q0, qf=qf, duration=to_float(table["duration"]),
                               settle=to_float(table.get("settle", 3.0)), name=name,
                               description=str(table.get("description", "")), profile=profile)
        except ProblemFileError as exc:
            raise ProblemFileError(path, exc.field, exc.value, exc.rule) from None
    if not moves:
        raise ProblemFileError(path, "<file>", None, "holds no move tables")
    return moves


def load_move(spec: str | Path) -> Move:
    """Read one move given as ``FILE:NAME`` (or a file holding exactly one move).

    Parameters
    ----------
    spec : str or pathlib.Path
        ``"path/to/moves.toml:name"``, or just the path of a file with one move.

    Returns
    -------
    Move

    Raises
    ------
    ProblemFileError
        Unreadable or malformed file, unknown name, or no name for a file of several moves.

    Examples
    --------
    >>> load_move("problems/moves.toml:move1").qf.tolist()
    [-1.0, -1.0, -1.0]
    """
    spec = str(spec)
    file, sep, name = spec.rpartition(":")
    if not sep or not file:
        file, name = spec, ""
    moves = load_moves(file)
    if not name:
        if len(moves) != 1:
            raise ProblemFileError(file, "<move>", spec,
                                   f"name a move as FILE:NAME; the file holds {sorted(moves)}")
        return next(iter(moves.values()))
    if name not in moves:
        raise ProblemFileError(file, name, spec, f"no such move; the file holds {sorted(moves)}")
    return moves[name]
