"""The result of the planner: a joint motion with its torques, usable as a move.

A :class:`PlannedMove` holds the optimal trajectory on a dense grid (``substeps`` samples
per interval of the optimal control problem's own discretisation) and behaves like
:class:`casflex.moves.Move` wherever a reference is sampled
(:func:`casflex.moves.reference_sampler`,
:func:`casflex.moves.reference_function`, :func:`casflex.simulate.simulate_prescribed`,
closed-loop tracking): before 0 it rests at ``q0``, after ``duration`` at ``qf``. Its
torques are a torque law for :func:`casflex.simulate.simulate_torque`
(:meth:`PlannedMove.torque_law`).
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._json import jsonable
from casflex._problemfile import read_npz
from casflex._validate import output_file
from casflex.errors import ProblemFileError
from casflex.moves import reference_sampler

__all__ = ["PlannedMove", "Propagator", "PLAN_FORMAT"]

#: format version of :meth:`PlannedMove.save`'s files. 2: the NLP's start and goal rows
#: divided by the state scales (format 1's, in the states' units, are still read: their
#: multipliers are converted, :meth:`PlannedMove.load`)
PLAN_FORMAT = 2

#: the arrays of a :class:`PlannedMove`, as :meth:`PlannedMove.save` stores them
_PLAN_ARRAYS = ("t", "q", "dq", "ddq", "tau", "delta", "ddelta", "node_t", "node_x",
                "node_tau", "hold_torque")


class Propagator:
    """The state of the planner's model a time ``s`` after node ``k``, by the OCP's own
    discretisation of the interval (:attr:`PlannedMove.propagator`).

    Shooting (``Xc`` None): ``substeps`` RK4 steps of ``s / substeps`` from the node under
    the interval's torque (the OCP's interval at ``s = h``). Collocation: the interval's
    collocation polynomial through the node and the states ``Xc`` at the points ``tc``.
    A plain object of arrays and CasADi functions, so a :class:`PlannedMove` pickles with
    it (the mapped copies of the functions are rebuilt on demand, not stored).

    Parameters
    ----------
    ode : casadi.Function
        ``ode(x, tau) -> ẋ`` of the model, ``x = [q; δ; q̇; δ̇]``.
    node_x : numpy.ndarray, shape (N + 1, nx)
        States at the nodes.
    node_tau : numpy.ndarray, shape (N, n)
        Torque of every interval [N m].
    h : float
        Interval length [s].
    substeps : int
        RK4 steps per interval (shooting).
    tc : numpy.ndarray, optional
        Collocation points as fractions of an interval (collocation).
    Xc : numpy.ndarray, shape (N degree, nx), optional
        States at the collocation points, interval by interval (collocation).

    Examples
    --------
    A double integrator, ``ẋ = [v; τ]``, under a unit torque from rest: ``q = s² / 2``.

    >>> x, tau = ca.SX.sym("x", 2), ca.SX.sym("tau")
    >>> ode = ca.Function("ode", [x, tau], [ca.vertcat(x[1], tau)])
    >>> p = Propagator(ode, np.zeros((2, 2)), np.ones((1, 1)), 1.0, 4)
    >>> xs, xdot = p([0], [0.5])
    >>> [round(float(v), 12) for v in xs[:, 0]]
    [0.125, 0.5]
    """

    def __init__(self, ode: ca.Function, node_x: np.ndarray, node_tau: np.ndarray,
                 h: float, substeps: int, tc: np.ndarray | None = None,
                 Xc: np.ndarray | None = None) -> None:
        self.ode, self.node_x, self.node_tau = ode, node_x, node_tau
        self.h, self.substeps, self.Xc = float(h), int(substeps), Xc
        self.tc = None if tc is None else np.asarray(tc, dtype=float)
        self._mapped: dict = {}
        if Xc is None:
            from casflex.simulate.integrators import rk4_step

            x = ca.SX.sym("x", node_x.shape[1])
            u = ca.SX.sym("tau", node_tau.shape[1])
            s = ca.SX.sym("s")
            xs = x
            for _ in range(substeps):
                xs = rk4_step(lambda y, v: ode(y, v), xs, s / substeps, u)
            self.step = ca.Function("propagate", [x, u, s], [xs, ode(xs, u)])
            return
        # Lagrange basis on [0, tc]: one polynomial in the fraction of the interval per
        # point (the node first)
        points = np.r_[0.0, tc]
        self.basis = []
        for r in range(points.size):
            coeff = np.array([1.0])
            for j in range(points.size):
                if j != r:
                    coeff = np.convolve(coeff, [1.0, -points[j]]) / (points[r] - points[j])
            self.basis.append(coeff)

    def _map(self, fn: ca.Function, count: int) -> ca.Function:
        key = (fn.name(), count)
        if key not in self._mapped:
            self._mapped[key] = fn.map(count)
        return self._mapped[key]

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_mapped": {}}

    def arrays(self) -> dict[str, np.ndarray]:
        """What :meth:`PlannedMove.save` stores of it besides the node values: the ODE
        in CasADi's own serialisation (UTF-8 bytes, not a pickle), ``h``, ``substeps``,
        and ``tc`` and ``Xc`` of a collocation.

        Returns
        -------
        dict of str to numpy.ndarray

        Examples
        --------
        >>> x, tau = ca.SX.sym("x", 2), ca.SX.sym("tau")
        >>> ode = ca.Function("ode", [x, tau], [ca.vertcat(x[1], tau)])
        >>> sorted(Propagator(ode, np.zeros((2, 2)), np.ones((1, 1)), 1.0, 4).arrays())
        ['h', 'ode', 'substeps']
        """
        # UTF-8 bytes: a numpy string array would hold 4 bytes a character
        out = {"ode": np.frombuffer(self.ode.serialize().encode(), dtype=np.uint8),
               "h": np.array(self.h),
               "substeps": np.array(self.substeps)}
        if self.Xc is not None:
            out.update(tc=self.tc, Xc=self.Xc)
        return out

    def __call__(self, k: ArrayLike, s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """``(x, ẋ)``, one column per sample, ``s`` [s] after the nodes ``k``."""
        k = np.asarray(k, dtype=int).ravel()
        s = np.asarray(s, dtype=float).ravel()
        if self.Xc is None:
            xt, xdot = self._map(self.step, k.size)(self.node_x[k].T, self.node_tau[k].T,
                                                    s.reshape(1, -1))
            return xt.full(), xdot.full()
        degree = len(self.basis) - 1
        w = np.array([np.polyval(c, s / self.h) for c in self.basis])  # (degree + 1, K)
        xt = w[0][:, None] * self.node_x[k]
        for j in range(degree):
            xt = xt + w[j + 1][:, None] * self.Xc[k * degree + j]
        xdot = self._map(self.ode, k.size)(xt.T, self.node_tau[k].T)
        return xt.T, xdot.full()


@dataclass
class PlannedMove:
    """An optimal point-to-point motion (:func:`casflex.planning.plan_move`).

    Attributes
    ----------
    t : numpy.ndarray, shape (K,)
        Times of the dense grid, 0 to ``duration`` [s].
    q, dq, ddq : numpy.ndarray, shape (K, n)
        Joint positions [rad], velocities [rad/s], accelerations [rad/s²].
    tau : numpy.ndarray, shape (K, n)
        Joint torques [N m] (piecewise constant over the intervals; at an interval
        boundary the torque of the interval that starts there, at the end the last one).
    delta, ddelta : numpy.ndarray, shape (K, m)
        Modal amplitudes [√kg m] and rates of the nominal model.
    node_t : numpy.ndarray, shape (N + 1,)
        Times of the shooting nodes [s].
    node_x : numpy.ndarray, shape (N + 1, 2 (n + m))
        States ``[q; δ; q̇; δ̇]`` at the nodes.
    node_tau : numpy.ndarray, shape (N, n)
        Torque of every interval [N m].
    hold_torque : numpy.ndarray, shape (n,)
        Torque that holds the arm at rest at ``qf`` after the move [N m].
    stats : dict
        Solver statistics: ``status``, ``success``, ``iterations``, ``solve_s``,
        ``objective``, ``intervals``, ``substeps``, ``scenarios`` (frequency errors),
        ``ocp_residual`` (the residual tip deflection the OCP's end state predicts, m).
    settle : float
        Time simulated after the move [s] (as :attr:`casflex.moves.Move.settle`).
    name, description : str
    propagator : callable, optional
        ``propagator(k, s) -> (x, ẋ)``: the model's state a time ``s`` after node ``k``
        under the interval's torque, and its derivative (``k``, ``s`` arrays; one column
        per sample): the OCP's own discretisation of the interval (the RK4 substeps
        scaled to ``s``, or the collocation polynomial). With it, :meth:`sample`
        integrates from the node before every sample time, so the joint motion is the
        one the torques produce, acceleration jumps at the nodes included; without it
        the dense samples are interpolated. :func:`casflex.planning.plan_move` sets a
        :class:`Propagator`, which pickles: so does the plan (``pickle.dumps(plan)``;
        the copy samples, simulates and warm-starts a neighbouring problem as the plan
        does). Its size is mostly the model's ODE with its tables: 25 MB for move 1 of
        the design study (:meth:`save`, compressed), 50 kB for the one-link arm.
    solution : dict, optional
        The OCP's last iterate: ``x`` (all NLP variables), ``lam_g`` (the constraints'
        multipliers), ``scales`` (the scales of the NLP's rows: ``x`` states, ``tau``
        torques [N m], ``ddq`` collocated accelerations or ``None``, ``T`` [s]) and
        ``layout`` (where each named block of variables and constraints lies:
        :class:`casflex.planning.lifting.BlockLayout`; ``None`` for Fatrop's), for a
        warm start of a neighbouring problem (:func:`casflex.planning.plan_move` with
        this plan as ``guess``, which solves it in the same scales; a nominal plan also
        starts the robust problem, lifted: :mod:`casflex.planning.lifting`).

    Examples
    --------
    >>> t = np.linspace(0.0, 1.0, 11)
    >>> q = (3 * t**2 - 2 * t**3)[:, None]
    >>> dq, ddq = (6 * t - 6 * t**2)[:, None], (6 - 12 * t)[:, None]
    >>> p = PlannedMove(t=t, q=q, dq=dq, ddq=ddq, tau=ddq, delta=np.zeros((11, 0)),
    ...                 ddelta=np.zeros((11, 0)), node_t=t, node_x=np.c_[q, dq],
    ...                 node_tau=ddq[:-1], hold_torque=np.zeros(1))
    >>> p.duration, p.t_end, p.qf.tolist()
    (1.0, 4.0, [1.0])
    >>> [round(float(a[0]), 6) for a in p.sample(0.5)]
    [0.5, 1.5, 0.0]
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    delta: np.ndarray
    ddelta: np.ndarray
    node_t: np.ndarray
    node_x: np.ndarray
    node_tau: np.ndarray
    hold_torque: np.ndarray
    stats: dict = field(default_factory=dict)
    settle: float = 3.0
    name: str = "planned"
    description: str = ""
    propagator: Callable | None = field(default=None, repr=False, compare=False)
    solution: dict | None = field(default=None, repr=False, compare=False)

    @property
    def duration(self) -> float:
        """Duration of the motion [s]."""
        return float(self.t[-1])

    @property
    def t_end(self) -> float:
        """End of the simulated interval, ``duration + settle`` [s]."""
        return self.duration + self.settle

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return self.q.shape[1]

    @property
    def q0(self) -> np.ndarray:
        """Start joint values [rad]."""
        return self.q[0].copy()

    @property
    def qf(self) -> np.ndarray:
        """End joint values [rad]."""
        return self.q[-1].copy()

    @property
    def breakpoints(self) -> np.ndarray:
        """Times [s] where the torque (and the joint acceleration) jumps: the nodes."""
        return np.asarray(self.node_t, dtype=float)

    @property
    def torque_peak(self) -> np.ndarray:
        """Peak absolute planned torque per joint [N m]."""
        return np.max(np.abs(self.node_tau), axis=0)

    @property
    def velocity_peak(self) -> np.ndarray:
        """Peak absolute joint velocity of the dense trajectory per joint [rad/s]."""
        return np.max(np.abs(self.dq), axis=0)

    def _samples(self):
        return (self.t, self.q, self.dq, self.ddq)

    def sample(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint position, velocity and acceleration at times ``t``.

        With a ``propagator`` the state is integrated from the node that starts the
        interval holding ``t`` (the right limit at a node); otherwise, between the dense
        samples, ``q`` and ``q̇`` are cubic Hermite interpolants and ``q̈`` is linear
        (:func:`casflex.moves.reference_sampler`). Before 0 the joints rest at ``q0``,
        after ``duration`` at ``qf``.

        Parameters
        ----------
        t : float or array_like
            Times [s].

        Returns
        -------
        q, qd, qdd : numpy.ndarray
            Each of shape ``(len(t), n_joints)`` [rad, rad/s, rad/s²]
            (``(n_joints,)`` for a scalar ``t``).

        Examples
        --------
        >>> t = np.array([0.0, 1.0])
        >>> p = PlannedMove(t=t, q=np.c_[[0.0, 1.0]], dq=np.zeros((2, 1)),
        ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
        ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
        ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
        ...                 hold_torque=np.zeros(1))
        >>> [a.ravel().tolist() for a in p.sample([-1.0, 2.0])]
        [[0.0, 1.0], [0.0, 0.0], [0.0, 0.0]]
        """
        scalar = np.ndim(t) == 0
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        if self.propagator is None:
            q, dq, ddq = reference_sampler(self._samples(), self.n_joints).sample(tt)
        else:
            q, dq, ddq = self._propagated(tt)
        # the arm rests from the end on: at ``duration`` itself (within the nodes'
        # round-off) q̈ is the right limit, 0, as at a node the next interval's
        eps = 1e-12 * max(float(self.duration), 1.0)
        before, after = tt < 0.0, tt >= self.duration - eps
        q[before], dq[before], ddq[before] = self.q[0], 0.0, 0.0
        q[after], dq[after], ddq[after] = self.q[-1], 0.0, 0.0
        if scalar:
            return q[0], dq[0], ddq[0]
        return q, dq, ddq

    def _interval_of(self, t):
        """Index of the OCP interval that starts at or before each time of ``t`` (the
        right limit at a node). A time within round-off of a node belongs to the interval
        the node starts: dense sample times and node times are computed apart and differ
        in the last digits, and the interval before would be propagated past its end. The
        tolerance (1e-12 of the duration) stays below a simulator's left limit
        (:data:`casflex.simulate.integrators.LEFT_LIMIT` of a step)."""
        eps = 1e-12 * max(float(self.node_t[-1]), 1.0)
        k = np.searchsorted(self.node_t, np.asarray(t, dtype=float) + eps, side="right") - 1
        return np.clip(k, 0, self.node_tau.shape[0] - 1)

    def _propagated(self, tt):
        n = self.n_joints
        nx = self.node_x.shape[1]
        m = nx // 2 - n
        q = np.empty((tt.size, n))
        dq, ddq = np.zeros_like(q), np.zeros_like(q)
        inside = (tt >= 0.0) & (tt <= self.duration)
        ti = tt[inside]
        if ti.size:
            k = self._interval_of(ti)
            x, xdot = self.propagator(k, np.maximum(ti - self.node_t[k], 0.0))
            x, xdot = np.asarray(x).T, np.asarray(xdot).T
            q[inside], dq[inside] = x[:, :n], x[:, n + m:2 * n + m]
            ddq[inside] = xdot[:, n + m:2 * n + m]
        return q, dq, ddq

    def casadi_reference(self) -> ca.Function:
        """``reference (t) -> (qd, dqd, ddqd)``: piecewise cubic in the dense samples.

        On every step ``[t_j, t_j+1]`` of the dense grid ``q`` is the cubic Hermite
        interpolant of ``q`` and ``q̇``, ``q̇`` that of ``q̇`` and ``q̈``, and ``q̈`` is
        linear (as :func:`casflex.moves.reference_sampler` interpolates samples), from
        the values at the step's start and (with a ``propagator``) their left limits at
        its end: the torque switches at the nodes stay jumps of ``q̈``, and the reference
        equals :meth:`sample` at the dense samples. Before 0 it rests at ``q0``,
        after ``duration`` at ``qf`` (velocity and acceleration zero).

        Examples
        --------
        >>> t = np.array([0.0, 1.0])
        >>> p = PlannedMove(t=t, q=np.c_[[0.0, 1.0]], dq=np.zeros((2, 1)),
        ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
        ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
        ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
        ...                 hold_torque=np.zeros(1))
        >>> [float(v) for v in p.casadi_reference()(0.5)]
        [0.5, 0.0, 0.0]
        >>> [float(v) for v in p.casadi_reference()(2.0)]
        [1.0, 0.0, 0.0]
        """
        t = np.asarray(self.t, dtype=float)
        start = self.sample(t[:-1])
        if self.propagator is None:
            end = (self.q[1:], self.dq[1:], self.ddq[1:])
        else:  # left limits: the state of the step's own interval at its end
            n = self.n_joints
            m = self.node_x.shape[1] // 2 - n
            k = self._interval_of(t[:-1])
            x, xdot = self.propagator(k, t[1:] - self.node_t[k])
            x, xdot = np.asarray(x).T, np.asarray(xdot).T
            end = (x[:, :n], x[:, n + m:2 * n + m], xdot[:, n + m:2 * n + m])
        return _hermite_reference(t, start, end, self.q0, self.qf)

    def time_grid(self, dt: float) -> np.ndarray:
        """Uniform time grid from 0 to ``t_end`` with step ``dt`` [s] (end included).

        Parameters
        ----------
        dt : float
            Time step [s].

        Examples
        --------
        >>> t = np.array([0.0, 1.0])
        >>> p = PlannedMove(t=t, q=np.zeros((2, 1)), dq=np.zeros((2, 1)),
        ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
        ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
        ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
        ...                 hold_torque=np.zeros(1), settle=0.5)
        >>> p.time_grid(0.5).tolist()
        [0.0, 0.5, 1.0, 1.5]
        """
        n = int(round(self.t_end / dt))
        return np.arange(n + 1) * dt

    def torque_law(self):
        """The planned torques as a law ``u(t, x) -> τ`` for
        :func:`casflex.simulate.simulate_torque`.

        The torque of the interval that holds ``t`` (piecewise constant); before 0 and
        after ``duration`` the holding torque at the end (the start's for ``t < 0``).

        Returns
        -------
        callable
            ``u(t, x) -> numpy.ndarray`` of shape (n,) [N m].

        Examples
        --------
        >>> t = np.array([0.0, 0.5, 1.0])
        >>> p = PlannedMove(t=t, q=np.zeros((3, 1)), dq=np.zeros((3, 1)),
        ...                 ddq=np.zeros((3, 1)), tau=np.zeros((3, 1)),
        ...                 delta=np.zeros((3, 0)), ddelta=np.zeros((3, 0)), node_t=t,
        ...                 node_x=np.zeros((3, 2)), node_tau=np.c_[[1.0, -1.0]],
        ...                 hold_torque=np.zeros(1))
        >>> u = p.torque_law()
        >>> [float(u(s, None)[0]) for s in (0.1, 0.6, 1.2)]
        [1.0, -1.0, 0.0]
        """
        node_t, taus, hold, T, eps = self._torque_schedule()

        def law(t: float, x: object) -> np.ndarray:
            if t >= T - eps:
                return hold
            k = int(np.searchsorted(node_t, t + eps, side="right") - 1)
            return taus[min(max(k, 0), taus.shape[0] - 1)]

        return law

    def torque_function(self) -> ca.Function:
        """:meth:`torque_law` as a ``casadi.Function`` ``(t, x) -> τ``: the same torques,
        with which :func:`casflex.simulate.simulate_torque` runs the whole simulation in
        one ``mapaccum`` call instead of a Python loop over its steps (move 1's
        verification at 0.1 ms: 51 000 steps).

        Returns
        -------
        casadi.Function
            Inputs ``t`` [s] and ``x`` (the state, unused: the law is open loop), output
            ``τ`` of shape (n,) [N m].

        Examples
        --------
        >>> t = np.array([0.0, 0.5, 1.0])
        >>> p = PlannedMove(t=t, q=np.zeros((3, 1)), dq=np.zeros((3, 1)),
        ...                 ddq=np.zeros((3, 1)), tau=np.zeros((3, 1)),
        ...                 delta=np.zeros((3, 0)), ddelta=np.zeros((3, 0)), node_t=t,
        ...                 node_x=np.zeros((3, 2)), node_tau=np.c_[[1.0, -1.0]],
        ...                 hold_torque=np.zeros(1))
        >>> u = p.torque_function()
        >>> [float(u(s, np.zeros(2))) for s in (-0.1, 0.1, 0.6, 1.2)]
        [1.0, 1.0, -1.0, 0.0]
        """
        node_t, taus, hold, T, eps = self._torque_schedule()
        n = taus.shape[1]
        t = ca.MX.sym("t")
        x = ca.MX.sym("x", self.node_x.shape[1])
        # the interval holding t + eps (CasADi's low: clamped to the first and the last),
        # its torques read off a table at that integer index (exact: weight 0 on the next)
        k = ca.low(ca.DM(node_t[:taus.shape[0] + 1]), t + eps)
        if taus.shape[0] > 1:
            table = ca.interpolant("planned_torques", "linear",
                                   [np.arange(taus.shape[0], dtype=float)],
                                   taus.ravel().tolist())
            tau = table(k)
        else:
            tau = ca.MX(ca.DM(taus[0]))
        tau = ca.if_else(t >= T - eps, ca.DM(hold).reshape((n, 1)), tau)
        return ca.Function("planned_torque", [t, x], [tau], ["t", "x"], ["tau"])

    def _torque_schedule(self):
        """The torque laws' data: nodes [s], torques per interval and at rest [N m], the
        end T [s] and the tolerance on the times [s] (a step that starts a hair before a
        node belongs to the interval after it: the simulator's step times are sums of dt
        and carry round-off)."""
        node_t = np.asarray(self.node_t, dtype=float)
        T = float(node_t[-1])
        return (node_t, np.asarray(self.node_tau, dtype=float),
                np.asarray(self.hold_torque, dtype=float), T, 1e-9 * max(T, 1.0))

    def save(self, path: str | os.PathLike) -> Path:
        """Write the plan to a NumPy ``.npz`` file that :meth:`load` reads back.

        Everything a later run needs is kept: the dense and node values, the statistics
        (as JSON: a non-finite number becomes ``None``), the OCP's last iterate and
        multipliers (a warm start of a neighbouring problem, e.g. the robust plan from a
        saved nominal one: ``casflex plan --guess``) and the propagator (its ODE in
        CasADi's serialisation, with the model's tables: most of the file, 25 MB for move
        1 of the design study). No pickle: loading runs no code from the file.

        Parameters
        ----------
        path : str or os.PathLike
            Output file (checked before writing; written as given, no suffix added).

        Returns
        -------
        pathlib.Path

        Examples
        --------
        >>> import tempfile
        >>> t = np.array([0.0, 1.0])
        >>> p = PlannedMove(t=t, q=np.c_[[0.0, 1.0]], dq=np.zeros((2, 1)),
        ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
        ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
        ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
        ...                 hold_torque=np.zeros(1), name="swing")
        >>> back = PlannedMove.load(p.save(Path(tempfile.mkdtemp()) / "plan.npz"))
        >>> back.name, back.duration, back.propagator is None
        ('swing', 1.0, True)
        """
        out = output_file(path, "path")
        arrays = {k: np.asarray(getattr(self, k), dtype=float) for k in _PLAN_ARRAYS}
        meta = {"format": PLAN_FORMAT, "settle": self.settle, "name": self.name,
                "description": self.description, "stats": jsonable(self.stats),
                "layout": (self.solution or {}).get("layout")}
        arrays["meta"] = np.array(json.dumps(meta, default=repr))
        if self.solution:
            scales = self.solution["scales"]
            arrays.update({"solution_x": self.solution["x"],
                           "solution_lam_g": self.solution["lam_g"],
                           "scales_x": scales["x"], "scales_tau": scales["tau"],
                           "scales_T": np.array(scales["T"])})
            if scales.get("ddq") is not None:
                arrays["scales_ddq"] = scales["ddq"]
        if isinstance(self.propagator, Propagator):
            arrays.update({f"propagator_{k}": v for k, v in self.propagator.arrays().items()})
        with open(out, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        return out

    @classmethod
    def load(cls, path: str | os.PathLike) -> PlannedMove:
        """The plan :meth:`save` wrote to ``path``.

        Parameters
        ----------
        path : str or os.PathLike
            A ``.npz`` file of :meth:`save`.

        Returns
        -------
        PlannedMove

        Raises
        ------
        casflex.errors.ProblemFileError
            The file is missing or unreadable, not such a file, of another format
            version, or its arrays do not fit together (the message names the array).

        Examples
        --------
        >>> PlannedMove.load("no/such/plan.npz")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
            ...
        casflex.errors.ProblemFileError: no/such/plan.npz: field '<file>' = ...: cannot be read: ...
        """
        path = Path(path)

        def bad(field, value, rule):
            return ProblemFileError(path, field, value, rule)

        arrays = read_npz(path, "a plan is the plan.npz that PlannedMove.save "
                                "(casflex plan --out) writes")
        if "meta" not in arrays:
            raise bad("meta", None, "missing: not a plan written by PlannedMove.save")
        try:
            meta = json.loads(str(arrays.pop("meta")))
        except json.JSONDecodeError as exc:
            raise bad("meta", "...", f"is not JSON: {exc}") from exc
        if meta.get("format") not in (1, PLAN_FORMAT):
            raise bad("meta.format", meta.get("format"),
                      f"this casflex reads plans of formats 1 and {PLAN_FORMAT}")
        for k in _PLAN_ARRAYS:
            if k not in arrays:
                raise bad(k, None, "missing")
        K, N = arrays["t"].size, arrays["node_tau"].shape[0]
        n = arrays["q"].shape[1] if arrays["q"].ndim == 2 else -1
        nx = arrays["node_x"].shape[1] if arrays["node_x"].ndim == 2 else -1
        m = nx // 2 - n
        shapes = {"q": (K, n), "dq": (K, n), "ddq": (K, n), "tau": (K, n), "delta": (K, m),
                  "ddelta": (K, m), "node_t": (N + 1,), "node_x": (N + 1, 2 * (n + m)),
                  "node_tau": (N, n), "hold_torque": (n,)}
        for k, shape in shapes.items():
            if n < 1 or m < 0 or arrays[k].shape != shape:
                raise bad(f"{k}.shape", arrays[k].shape, f"must be {shape} (t has {K} "
                          f"samples, node_tau {N} intervals, q {n} joints)")
        solution = None
        if "solution_x" in arrays:
            solution = {"x": arrays["solution_x"], "lam_g": arrays["solution_lam_g"],
                        "scales": {"x": arrays["scales_x"], "tau": arrays["scales_tau"],
                                   "ddq": arrays.get("scales_ddq"),
                                   "T": float(arrays["scales_T"])},
                        "layout": meta.get("layout")}
            if meta["format"] == 1:
                solution = _format1_solution(solution, n, m)
        propagator = None
        if "propagator_ode" in arrays:
            try:
                ode = ca.Function.deserialize(arrays["propagator_ode"].tobytes().decode())
            except (RuntimeError, UnicodeDecodeError) as exc:
                raise bad("propagator_ode", "...", f"is not a CasADi function: {exc}") from exc
            propagator = Propagator(ode, arrays["node_x"], arrays["node_tau"],
                                    float(arrays["propagator_h"]),
                                    int(arrays["propagator_substeps"]),
                                    arrays.get("propagator_tc"), arrays.get("propagator_Xc"))
        return cls(**{k: arrays[k] for k in _PLAN_ARRAYS}, stats=meta["stats"],
                   settle=float(meta["settle"]), name=str(meta["name"]),
                   description=str(meta["description"]), propagator=propagator,
                   solution=solution)

    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write the dense trajectory: columns ``t, q1.., dq1.., ddq1.., tau1..``.

        Parameters
        ----------
        path : str or os.PathLike
            Output file (checked before writing).

        Returns
        -------
        pathlib.Path

        Examples
        --------
        >>> import tempfile
        >>> t = np.array([0.0, 1.0])
        >>> p = PlannedMove(t=t, q=np.c_[[0.0, 1.0]], dq=np.zeros((2, 1)),
        ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
        ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
        ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
        ...                 hold_torque=np.zeros(1))
        >>> out = p.to_csv(Path(tempfile.mkdtemp()) / "trajectory.csv")
        >>> out.read_text().splitlines()[0]
        't,q1,dq1,ddq1,tau1'
        """
        out = output_file(path, "path")
        n = self.n_joints
        header = ["t"] + [f"{k}{j + 1}" for k in ("q", "dq", "ddq", "tau") for j in range(n)]
        rows = np.column_stack([self.t, self.q, self.dq, self.ddq, self.tau])
        with open(out, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for row in rows:
                w.writerow([repr(float(v)) for v in row])
        return out


def _hermite_reference(t, start, end, q0, qf):
    """CasADi ``reference(t)`` from per-step start values and end (left-limit) values."""
    tt = ca.SX.sym("t")
    steps = t.size - 1
    # the step that holds t (clipped to the first / last): the index grid read at t
    position = ca.interpolant("step", "linear", [t], np.arange(t.size, dtype=float))(tt)
    index = ca.fmin(ca.fmax(ca.floor(position), 0.0), steps - 1.0)
    grid = [np.arange(max(steps, 2), dtype=float)]

    def lookup(name, values):  # the row of a step: a linear interpolant read at an integer
        values = np.asarray(values, dtype=float).reshape(steps, -1)
        if steps == 1:
            values = np.vstack([values, values])
        f = ca.interpolant(name, "linear", grid, values.T.ravel(order="F"))
        return f(index)

    qa, va, aa = (lookup(f"a{i}", v) for i, v in enumerate(start))
    qb, vb, ab = (lookup(f"b{i}", v) for i, v in enumerate(end))
    t0, h = lookup("t0", t[:-1]), lookup("h", np.diff(t))
    s = ca.fmin(ca.fmax((tt - t0) / h, 0.0), 1.0)
    # cubic Hermite basis: q from (q, q̇), q̇ from (q̇, q̈) at both ends; q̈ linear
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    q = h00 * qa + h10 * h * va + h01 * qb + h11 * h * vb
    dq = h00 * va + h10 * h * aa + h01 * vb + h11 * h * ab
    ddq = (1 - s) * aa + s * ab
    zero = ca.DM.zeros(len(q0))
    before, after = tt < t[0], tt > t[-1]
    q = ca.if_else(before, ca.DM(q0), ca.if_else(after, ca.DM(qf), q))
    dq = ca.if_else(ca.logic_or(before, after), zero, dq)
    ddq = ca.if_else(ca.logic_or(before, after), zero, ddq)
    return ca.Function("reference", [tt], [q, dq, ddq], ["t"], ["qd", "dqd", "ddqd"])


def _format1_solution(solution: dict, n: int, m: int) -> dict | None:
    """A format-1 plan's NLP solution with the start and goal rows of format 2.

    Format 1 posed ``X[:, 0] = x0``, ``q(T) = qf`` and ``q̇(T) = 0`` in the states' units;
    format 2 divides each row by its state's scale, which multiplies its multiplier by the
    scale. Without a layout (plans saved before it was recorded) the rows cannot be found:
    no solution (a guess by its trajectory, not its multipliers).
    """
    layout = solution.get("layout")
    if not layout:
        return None
    sx = np.asarray(solution["scales"]["x"], dtype=float)
    lam = np.array(solution["lam_g"], dtype=float)
    scales = {"start": sx, "goal": sx[:n], "goal velocity": sx[n + m:2 * n + m]}
    for name, offset, rows, columns in layout["g"]:
        if name in scales:
            lam[offset:offset + rows * columns] *= scales[name][:rows * columns]
    return {**solution, "lam_g": lam}
