"""Simulated sensor data: the flexible states along a prescribed joint motion and the
signals of a sensor set, with noise and offsets (the truth the estimators are tested on).

:func:`simulate_data` integrates the model's exact flexible rows along a move with
:func:`casflex.simulate.integrators.rk4_step` and samples the exact measurement model of
:mod:`casflex.sensors`; :class:`SimulatedData` holds the result.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.moves import Move
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> from casflex.sensors import SensorSet, StrainPair
>>> robot = load("problems/arm2link.toml")
>>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
...                       gravity=None)
>>> d = simulate_data(model, ss, Move([0, 0, 0], [-1, 0, 0], 0.2), t_end=0.002, noise=0.0)
>>> d.t.tolist()
[0.0, 0.001, 0.002]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.sensors import SensorSet, measurement_function
from casflex.simulate.integrators import rk4_step
from casflex.simulate.results import (
    DIVERGED_DEFLECTION,
    check_divergence,
    robot_reach,
    tip_positions,
)

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move

__all__ = ["SimulatedData", "simulate_data"]


@dataclass
class SimulatedData:
    """Simulated sensor data of a prescribed joint motion (:func:`simulate_data`).

    Attributes
    ----------
    t : numpy.ndarray
        (N,) sample times [s].
    u : numpy.ndarray
        (N, 3n) exact ``[q, q̇, q̈]``.
    x : numpy.ndarray
        (N, 2m) true ``[δ, δ̇]``.
    y_clean, y : numpy.ndarray
        (N, r) exact signals and signals with noise (and offset).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> d = simulate_data(model, ss, Move([0, 0, 0], [-1, 0, 0], 0.2), t_end=0.01,
    ...                   noise=0.0, offset=1e-6)
    >>> d.t.shape, d.u.shape, d.x.shape, d.y.shape
    ((11,), (11, 9), (11, 2), (11, 2))
    >>> (d.y - d.y_clean).round(12).max().item()    # the sensor bias, no noise
    1e-06
    """

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    y_clean: np.ndarray
    y: np.ndarray


def simulate_data(model: FlexibleModel, sensors: SensorSet, move: Move, dt: float = 1e-3,
                  t_end: float | None = None, noise: ArrayLike | None = None,
                  offset: ArrayLike = 0.0, seed: int = 0,
                  x0: ArrayLike | None = None) -> SimulatedData:
    """Integrate the model's flexible rows along a move and sample the sensors.

    The truth uses the exact (nonlinear) flexible rows of the model (its ``dddelta``
    function, :meth:`casflex.model.FlexibleModel.functions`) with classical RK4
    (:func:`casflex.simulate.integrators.rk4_step`) at step ``dt``, the joint motion
    evaluated at the RK4 stage times, and the exact measurement model
    (:func:`casflex.sensors.measurement_function`).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    sensors : casflex.sensors.SensorSet
    move : casflex.moves.Move
    dt : float
        Sample and integration step [s].
    t_end : float, optional
        Default ``move.t_end``.
    noise : float or array_like, optional
        Standard deviation(s) of white noise added per sample (default the sensors'
        ``noise``, 0 where none is given).
    offset : float or array_like
        Constant offset added to every signal (sensor bias).
    seed : int
    x0 : array_like, optional
        Initial flexible state (default 0).

    Returns
    -------
    SimulatedData

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> d = simulate_data(model, ss, Move([0, 0, 0], [0, -1, 0], 0.2), t_end=0.05)
    >>> d.x.shape, d.y.shape
    ((51, 2), (51, 2))
    """
    n, m = model.n, model.m
    t_end = move.t_end if t_end is None else float(t_end)
    N = int(round(t_end / dt)) + 1
    t = np.arange(N) * dt
    dddelta = model.functions()["dddelta"]  # (q, dq, ddq, delta, ddelta) -> δ̈
    ut = ca.SX.sym("ut", 3 * n, 3)  # inputs at t, t + dt/2, t + dt
    xs = ca.SX.sym("x", 2 * m)

    def f(xx, uu):
        return ca.vertcat(xx[m:], dddelta(uu[:n], uu[n:2 * n], uu[2 * n:], xx[:m], xx[m:]))

    step = ca.Function("rk4", [xs, ut], [rk4_step(f, xs, dt, ut[:, 0], ut[:, 1], ut[:, 2])])

    def sample(times):
        q, qd, qdd = move.sample(times)
        return np.hstack([q, qd, qdd])

    u0 = sample(t[:-1])
    uh = sample(t[:-1] + 0.5 * dt)
    u1 = sample(t[1:])
    U = np.stack([u0, uh, u1], axis=2)  # (N-1, 3n, 3)
    # mapaccum takes the per-step (3n x 3) inputs side by side
    Ucat = np.hstack([U[k] for k in range(N - 1)]) if N > 1 else np.zeros((3 * n, 0))
    xinit = np.zeros(2 * m) if x0 is None else np.asarray(x0, dtype=float)
    if N > 1:
        X = np.asarray(step.mapaccum("sim", N - 1)(xinit, Ucat)).T
        X = np.vstack([xinit, X])
    else:
        X = xinit[None]
    hint = (f"the step dt = {dt} s is too large for the highest mode (RK4 needs "
            "omega dt < 2.8), or the move too fast for the model's small deflections")
    check_divergence("simulate_data", t, {"delta": X[:, :m], "ddelta": X[:, m:]}, hint)
    u = sample(t)
    tip, tip_rigid = tip_positions(model.functions()["tip"], u[:, :n], X[:, :m])
    check_divergence("simulate_data", t, {"tip_deflection": tip - tip_rigid}, hint,
                     limits={"tip_deflection": DIVERGED_DEFLECTION * robot_reach(model.robot)})
    h = measurement_function(model, sensors)
    Y = np.asarray(h.map(N)(X.T, u.T)[len(sensors)]).T
    check_divergence("simulate_data", t, {"y": Y}, hint)
    rng = np.random.default_rng(seed)
    std = sensors.noise_std if noise is None else np.broadcast_to(
        np.asarray(noise, dtype=float), (sensors.n_outputs,))
    std = np.nan_to_num(std, nan=0.0)
    Yn = Y + rng.normal(size=Y.shape) * std + np.asarray(offset, dtype=float)
    return SimulatedData(t=t, u=u, x=X, y_clean=Y, y=Yn)

