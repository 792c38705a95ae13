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
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from casflex.errors import ProblemFileError

__all__ = ["Move", "load_moves", "load_move"]

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

    @property
    def n_joints(self):
        """Number of joints."""
        return self.q0.size

    @property
    def t_end(self):
        """End of the simulated interval, ``duration + settle`` [s]."""
        return self.duration + self.settle

    @property
    def peak_acceleration(self):
        """Joint accelerations of the first half [rad/s²]: ``4 (qf − q0) / T²``."""
        return 4.0 * (self.qf - self.q0) / self.duration**2

    def sample(self, t):
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

    def time_grid(self, dt):
        """Uniform time grid from 0 to ``t_end`` with step ``dt`` [s] (end included)."""
        n = int(round(self.t_end / dt))
        return np.arange(n + 1) * dt


def _angles(r, path, name, key, value, n=None):
    if not isinstance(value, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ProblemFileError(path, f"{name}.{key}", value, "must be a list of numbers [rad]")
    out = np.array(value, dtype=float) * r
    if not np.all(np.isfinite(out)):
        raise ProblemFileError(path, f"{name}.{key}", value, "must be finite (no NaN or inf)")
    if n is not None and out.size != n:
        raise ProblemFileError(path, f"{name}.{key}", value,
                               f"must have as many values as q0 ({n})")
    return out


def load_moves(path):
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
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ProblemFileError(path, "<file>", str(path), f"cannot be read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(path, "<toml>", None, f"is not valid TOML: {exc}") from exc
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
            moves[name] = Move(q0=q0, qf=qf, duration=float(table["duration"]),
                               settle=float(table.get("settle", 3.0)), name=name,
                               description=str(table.get("description", "")), profile=profile)
        except ProblemFileError as exc:
            raise ProblemFileError(path, exc.field, exc.value, exc.rule) from None
    if not moves:
        raise ProblemFileError(path, "<file>", None, "holds no move tables")
    return moves


def load_move(spec):
    """Read one move given as ``FILE:NAME`` (or a file holding exactly one move).

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
