"""Results of the simulators: time histories and what is read from them.

* :class:`SimulationResult` — prescribed or torque-driven motion (:func:`simulate_prescribed`,
  :func:`simulate_torque`);
* :class:`ClosedLoopResult` — a run under a tracking controller
  (:func:`simulate_closed_loop`);
* :func:`decay_time` — when a signal has decayed after a disturbance;
* :func:`tip_positions` — tip with and without the deflections along a state history.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError, SolverError

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = ["SimulationResult", "ClosedLoopResult", "decay_time", "tip_positions",
           "check_divergence", "robot_reach", "DIVERGED_DEFLECTION"]

#: A tip deflection larger than this multiple of the robot's reach (the sum of its DH
#: offsets) is no result: the integration diverged, or the motion lies far outside the
#: model's small-deflection range (a 10 ms move of the case-study arm "deflects" its 2 m
#: arm by 3.7 m, with RK4 and CVODES alike).
DIVERGED_DEFLECTION = 1.0


@dataclass
class SimulationResult:
    """Time histories of a simulation (rows are time samples).

    Attributes
    ----------
    t : numpy.ndarray, shape (N,)
        Time [s].
    q, dq, ddq : numpy.ndarray, shape (N, n)
        Joint positions [rad], velocities [rad/s], accelerations [rad/s²].
    tau : numpy.ndarray, shape (N, n)
        Joint torques [N m] (prescribed motion: the torques that produce it; torque-driven:
        the applied torques, held over each step).
    delta, ddelta : numpy.ndarray, shape (N, m)
        Modal amplitudes and their rates (mass-normalised modes).
    tip : numpy.ndarray, shape (N, 3)
        Tip position with the deflections [m] (base frame).
    tip_rigid : numpy.ndarray, shape (N, 3)
        Tip position from the rigid kinematics (δ = 0) [m].
    tip_deflection : numpy.ndarray, shape (N, 3)
        ``tip − tip_rigid`` [m].
    t_move_end : float
        End of the planned motion [s] (``nan`` when unknown).
    method : str
    info : dict
        Timing and bookkeeping (``{"steps": ..., "wall_s": ...}``).

    Examples
    --------
    >>> r = SimulationResult(t=np.array([0.0, 1.0]), q=np.zeros((2, 1)), dq=np.zeros((2, 1)),
    ...                      ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
    ...                      delta=np.zeros((2, 1)), ddelta=np.zeros((2, 1)),
    ...                      tip=np.array([[1.0, 0, 0], [1.0, 0, 0.002]]),
    ...                      tip_rigid=np.array([[1.0, 0, 0], [1.0, 0, 0]]), t_move_end=0.5)
    >>> r.max_tip_deflection, r.residual_tip_deflection
    (0.002, 0.002)
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    delta: np.ndarray
    ddelta: np.ndarray
    tip: np.ndarray
    tip_rigid: np.ndarray
    tip_deflection: np.ndarray = None
    t_move_end: float = math.nan
    method: str = "rk4"
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.tip_deflection is None:
            self.tip_deflection = np.asarray(self.tip) - np.asarray(self.tip_rigid)

    @property
    def max_tip_deflection(self) -> float:
        """Largest norm of the tip deflection over the whole simulation [m]."""
        return float(np.max(np.linalg.norm(self.tip_deflection, axis=1)))

    @property
    def residual_tip_deflection(self) -> float:
        """Largest norm of the tip deflection after the move ends [m] (``nan`` if the
        simulation stops before ``t_move_end`` or the end is unknown)."""
        if not math.isfinite(self.t_move_end):
            return math.nan
        after = self.t >= self.t_move_end - 1e-12
        if not np.any(after):
            return math.nan
        return float(np.max(np.linalg.norm(self.tip_deflection[after], axis=1)))

    @property
    def torque_peak(self) -> np.ndarray:
        """Peak absolute torque per joint [N m]."""
        return np.max(np.abs(self.tau), axis=0)

    def to_dict(self) -> dict:
        """Plain-Python dictionary (lists and floats) for :mod:`json` (SI units).

        Examples
        --------
        >>> r = SimulationResult(t=np.zeros(1), q=np.zeros((1, 1)), dq=np.zeros((1, 1)),
        ...                      ddq=np.zeros((1, 1)), tau=np.ones((1, 1)),
        ...                      delta=np.zeros((1, 1)), ddelta=np.zeros((1, 1)),
        ...                      tip=np.zeros((1, 3)), tip_rigid=np.zeros((1, 3)))
        >>> sorted(r.to_dict())[:4]
        ['ddelta', 'ddq', 'delta', 'dq']
        """
        out = {}
        for key in ("t", "q", "dq", "ddq", "tau", "delta", "ddelta", "tip", "tip_rigid",
                    "tip_deflection"):
            out[key] = np.asarray(getattr(self, key)).tolist()
        for key in ("max_tip_deflection", "residual_tip_deflection", "t_move_end"):
            v = float(getattr(self, key))
            out[key] = v if math.isfinite(v) else None
        out["torque_peak"] = self.torque_peak.tolist()
        out["method"] = self.method
        out["info"] = {k: v for k, v in self.info.items()
                       if isinstance(v, (int, float, str, bool))}
        return out


@dataclass
class ClosedLoopResult:
    """A closed-loop run (:func:`simulate_closed_loop`).

    Attributes
    ----------
    t : numpy.ndarray
        (N,) times [s].
    x : numpy.ndarray
        (N, 2(n+m)) states ``[q, δ, q̇, δ̇]``.
    tau : numpy.ndarray
        (N, n) torques applied from ``t[k]`` to ``t[k+1]`` [N·m] (last row repeated).
    qd : numpy.ndarray
        (N, n) reference [rad].
    tip, tip_rigid : numpy.ndarray
        (N, 3) tip position with and without deflection [m], base frame.
    x_hat : numpy.ndarray or None
        (N, 2m) estimates ``[δ̂, δ̂̇]`` used by the controller when an estimator ran.
    n, m : int
        Numbers of joints and modes (they split ``x``).

    Examples
    --------
    Usually from :func:`simulate_closed_loop`; the properties split the state:

    >>> r = ClosedLoopResult(t=np.array([0.0, 0.1]),
    ...                      x=np.array([[0.0, 0.01, 0.0, 0.0], [0.2, -0.01, 1.0, 0.5]]),
    ...                      tau=np.zeros((2, 1)), qd=np.array([[0.0], [0.25]]),
    ...                      tip=np.array([[1.0, 0.0, 0.0], [0.98, 0.2, 0.0]]),
    ...                      tip_rigid=np.array([[1.0, 0.0, 0.0], [0.98, 0.199, 0.0]]),
    ...                      n=1, m=1)
    >>> r.q.ravel().tolist(), r.delta.ravel().tolist(), r.dq.ravel().tolist()
    ([0.0, 0.2], [0.01, -0.01], [0.0, 1.0])
    >>> r.tracking_error.ravel().round(6).tolist()
    [0.0, -0.05]
    >>> r.tip_deflection[1].round(6).tolist()
    [0.0, 0.001, 0.0]
    """

    t: np.ndarray
    x: np.ndarray
    tau: np.ndarray
    qd: np.ndarray
    tip: np.ndarray
    tip_rigid: np.ndarray
    n: int
    m: int
    x_hat: np.ndarray | None = None

    @property
    def q(self) -> np.ndarray:
        """Joint angles [rad]."""
        return self.x[:, :self.n]

    @property
    def delta(self) -> np.ndarray:
        """Modal amplitudes [√kg·m]."""
        return self.x[:, self.n:self.n + self.m]

    @property
    def dq(self) -> np.ndarray:
        """Joint rates [rad/s]."""
        return self.x[:, self.n + self.m:2 * self.n + self.m]

    @property
    def ddelta(self) -> np.ndarray:
        """Modal rates."""
        return self.x[:, 2 * self.n + self.m:]

    @property
    def tip_deflection(self) -> np.ndarray:
        """(N, 3) tip position minus that of the undeformed arm [m]."""
        return self.tip - self.tip_rigid

    @property
    def tracking_error(self) -> np.ndarray:
        """(N, n) ``q − q_d`` [rad]."""
        return self.q - self.qd


def decay_time(t: ArrayLike, signal: ArrayLike, t0: float = 0.0, fraction: float = 0.05,
               floor: float = 0.0) -> float:
    """Time after ``t0`` from which ``‖signal‖`` stays below a fraction of its peak.

    Parameters
    ----------
    t : array_like
        (N,) times [s].
    signal : array_like
        (N,) or (N, k) samples (the Euclidean norm over columns is used).
    t0 : float
        Start of the window (e.g. the instant of a disturbance) [s].
    fraction : float
        Threshold as a fraction of the peak of ``‖signal‖`` after ``t0``.
    floor : float
        Absolute threshold added to the relative one.

    Returns
    -------
    float
        Seconds from ``t0``; ``inf`` if the signal is still above the threshold in the
        last tenth of the window (it does not decay within the run).

    Examples
    --------
    >>> tt = np.linspace(0, 10, 1001)
    >>> round(decay_time(tt, np.exp(-tt) * np.cos(20 * tt)), 1)
    3.0
    """
    t = np.asarray(t, dtype=float)
    s = np.asarray(signal, dtype=float)
    s = np.linalg.norm(s, axis=1) if s.ndim == 2 else np.abs(s)
    sel = t >= t0
    tt, ss = t[sel], s[sel]
    if tt.size == 0:
        raise ModelError(f"decay_time: no samples after t0 = {t0} s")
    thr = fraction * float(np.max(ss)) + floor
    above = np.nonzero(ss > thr)[0]
    if above.size == 0:
        return 0.0
    last = tt[above[-1]]
    if last >= tt[-1] - 0.1 * (tt[-1] - tt[0]):
        return math.inf
    return float(last - t0)


def tip_positions(tip: ca.Function, q: np.ndarray, delta: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Tip positions with and without the deflections along a history (rows are times).

    Parameters
    ----------
    tip : casadi.Function
        The model's ``tip (q, delta) -> p``.
    q, delta : numpy.ndarray, shape (N, n) and (N, m)
        Joint angles [rad] and modal amplitudes.

    Returns
    -------
    tip, tip_rigid : numpy.ndarray, shape (N, 3)
        Tip position [m] (base frame), with ``delta`` and with δ = 0.

    Examples
    --------
    >>> q, d = ca.SX.sym("q"), ca.SX.sym("d")
    >>> tip = ca.Function("tip", [q, d], [ca.vertcat(ca.cos(q), ca.sin(q), d)])
    >>> p, p0 = tip_positions(tip, np.zeros((2, 1)), np.array([[0.0], [0.01]]))
    >>> p.tolist(), p0.tolist()
    ([[1.0, 0.0, 0.0], [1.0, 0.0, 0.01]], [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    """
    N = q.shape[0]
    tipm = tip.map(N)
    return (tipm(q.T, delta.T).full().T,
            tipm(q.T, np.zeros_like(delta.T)).full().T)


def check_divergence(where: str, t: np.ndarray, quantities: dict[str, np.ndarray],
                     hint: str, *, limits: dict[str, float] | None = None) -> None:
    """Raise a :class:`~casflex.errors.SolverError` naming the first time and quantity at
    which a simulated history is non-finite or beyond its limit (a diverging integration),
    instead of returning ``inf``/``nan`` results.

    Parameters
    ----------
    where : str
        The simulating function, named first in the message.
    t : numpy.ndarray, shape (N,)
        Sample times [s].
    quantities : dict of str to numpy.ndarray
        Histories (rows are times) by name, e.g. ``{"delta": ..., "tau": ...}``.
    hint : str
        What to try, appended to the message.
    limits : dict of str to float, optional
        Largest plausible absolute value of a quantity (by name); a 2-D history of three
        columns named ``tip_deflection`` is compared by its row norms [m].

    Raises
    ------
    casflex.errors.SolverError
        With the attribute ``divergence``: ``{"time": s, "quantity": "name[column]"}``
        (1-based column; the bare name for the row norm of ``tip_deflection``).

    Examples
    --------
    >>> t = np.array([0.0, 0.1, 0.2])
    >>> check_divergence("sim", t, {"delta": np.array([[0.0], [1.0], [2.0]])}, "smaller dt")
    >>> check_divergence("sim", t, {"delta": np.array([[0.0], [np.inf], [np.nan]])},
    ...                  "try a smaller dt")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.SolverError: sim: the integration diverged at t = 0.1 s: delta[1] = inf ...
    >>> check_divergence("sim", t, {"tip_deflection": [[0, 0, 0.1], [0, 0, 3.0], [0, 0, 0]]},
    ...                  "a slower move", limits={"tip_deflection": 2.0})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.SolverError: sim: the integration diverged at t = 0.1 s: |tip_deflection| = 3 ...
    """
    limits = limits or {}
    first = None
    for name, values in quantities.items():
        a = np.asarray(values, dtype=float)
        a = a.reshape(a.shape[0], -1) if a.ndim else a.reshape(1, 1)
        size = np.linalg.norm(a, axis=1, keepdims=True) if name == "tip_deflection" \
            else np.abs(a)
        bad = ~np.isfinite(a)
        if name in limits:
            bad |= np.broadcast_to(size > limits[name], a.shape)
        rows = np.flatnonzero(bad.any(axis=1))
        if rows.size and (first is None or rows[0] < first[0]):
            k = rows[0]
            col = int(np.flatnonzero(bad[k])[0])
            first = (k, name, col, a[k, col], size[k].max() if name == "tip_deflection"
                     else None)
    if first is None:
        return
    k, name, col, value, norm = first
    if not math.isfinite(value):
        what = f"{name}[{col + 1}] = {float(value)!r} (non-finite)"
    elif norm is not None:
        what = (f"|{name}| = {norm:.4g} m, beyond {limits[name]:.4g} m "
                f"({DIVERGED_DEFLECTION:g} x the robot's reach: no small deflection)")
    else:
        what = f"|{name}[{col + 1}]| = {abs(value):.4g}, beyond {limits[name]:.4g}"
    time = float(np.asarray(t, dtype=float).ravel()[min(k, np.size(t) - 1)])
    error = SolverError(f"{where}: the integration diverged at t = {time:.6g} s: {what}; "
                        f"{hint}")
    # Callers that report rather than raise (the design job) read these, not the message.
    error.divergence = {"time": time,
                        "quantity": name if norm is not None else f"{name}[{col + 1}]"}
    raise error


def robot_reach(robot: Robot) -> float:
    """Sum of the robot's DH offsets and tip-body offsets [m] (at least 1 mm): no tip
    is farther than this from the base.

    Parameters
    ----------
    robot : casflex.robot.Robot
        The robot.

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot_reach(load("problems/arm2link.toml"))
    2.0
    """
    total = sum(abs(link.a) + abs(link.d) + float(np.linalg.norm(link.tip.com_offset))
                for link in robot.links)
    return max(total, 1e-3)
