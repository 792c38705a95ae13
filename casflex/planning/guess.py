"""The start of :func:`casflex.planning.plan_move`: the initial guess on the OCP's grid and
the numbers that size the problem.

* :func:`rigid_bang_bang_duration`: the duration of the rigid bang-bang move within the
  limits (the ``guess="rigid"`` start is 1.3 times it);
* :func:`time_scaled`: a reference run at another speed (a guess of another duration,
  e.g. an energy plan's fixed one);
* :func:`guess_on_grid`: a reference simulated with the joints on it, sampled at the
  nodes and the collocation points (states, torques, joint accelerations);
* :func:`highest_free_frequency`: the highest frequency of the arm with its joints free,
  which sets the default number of intervals and RK4 substeps;
* :func:`warm_duals`: a neighbouring plan's NLP iterate and multipliers, when they fit.
"""

from __future__ import annotations

import math
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.model import FlexibleModel
from casflex.planning.scenarios import static_deflection

__all__ = ["rigid_bang_bang_duration", "time_scaled", "guess_on_grid",
           "highest_free_frequency", "warm_duals"]


def rigid_bang_bang_duration(model: FlexibleModel, q0: ArrayLike, qf: ArrayLike,
                             tau_max: ArrayLike, v_max: ArrayLike) -> float:
    """Duration of the rigid bang-bang move from ``q0`` to ``qf`` within the limits, every
    joint on its own with the diagonal inertia at ``q0``: ``2 √(Δq J / τ_max)``, and at
    least ``2 Δq / v_max`` (a triangle at the velocity limit).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q0, qf : array_like
        Start and goal joint values [rad].
    tau_max, v_max : array_like
        Per-joint torque [N m] and velocity [rad/s] limits (``inf``: none).

    Returns
    -------
    float
        [s], at least 1 ms.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> round(rigid_bang_bang_duration(model, np.zeros(1), np.ones(1), [0.1], [np.inf]), 4)
    1.2884
    >>> rigid_bang_bang_duration(model, np.zeros(1), np.ones(1), [0.1], [0.5])  # 2 rad / 0.5
    4.0
    """
    q0, qf = (np.asarray(q, dtype=float).ravel() for q in (q0, qf))
    tau_max, v_max = (np.broadcast_to(np.asarray(a, dtype=float), (model.n,))
                      for a in (tau_max, v_max))
    M = model.functions()["mass"](q0, np.zeros(model.m)).full()
    d = np.abs(qf - q0)
    T = 1e-3
    for j in range(model.n):
        if d[j] == 0.0:
            continue
        J = M[j, j]
        if np.isfinite(tau_max[j]):
            T = max(T, 2.0 * math.sqrt(d[j] * J / tau_max[j]))
        if np.isfinite(v_max[j]):
            T = max(T, 2.0 * d[j] / v_max[j])
    return float(T)


def time_scaled(reference: Any, duration: float, samples: int = 4001
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``reference`` run at another speed so that it lasts ``duration``.

    Parameters
    ----------
    reference : move-like
        Anything with ``duration`` [s] and ``sample(t) -> (q, q̇, q̈)``.
    duration : float
        The new duration [s].
    samples : int
        Samples over the new duration.

    Returns
    -------
    (t, q, dq, ddq) : tuple of ndarray
        Sampled, as :func:`casflex.simulate.simulate_prescribed` takes a motion [s, rad,
        rad/s, rad/s²].

    Examples
    --------
    >>> from casflex.moves import Move
    >>> t, q, dq, ddq = time_scaled(Move([0.0], [1.0], 2.0), 4.0)
    >>> float(t[-1]), float(q[-1, 0]), bool(np.isclose(dq.max(), 0.5 * Move([0.0], [1.0],
    ...     2.0).sample(np.linspace(0.0, 2.0, 4001))[1].max()))
    (4.0, 1.0, True)
    """
    s = float(reference.duration) / duration
    t = np.linspace(0.0, duration, samples)
    q, dq, ddq = reference.sample(t * s)
    return t, q, dq * s, ddq * s**2


def guess_on_grid(model: FlexibleModel, reference: Any, T: float, N: int, substeps: int,
                  x0: np.ndarray, tc: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """States and torques of ``reference`` on the node grid (the joints on the reference,
    the modes simulated), and the states and joint accelerations at the collocation
    points ``tc`` of every interval, interpolated linearly between the simulation steps.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    reference : move-like or tuple
        What :func:`casflex.simulate.simulate_prescribed` takes (a move, or sampled
        ``(t, q, q̇, q̈)`` such as :func:`time_scaled`'s).
    T : float
        Duration [s].
    N : int
        Intervals.
    substeps : int
        Simulation steps per interval (step ``T / (N substeps)``).
    x0 : numpy.ndarray
        Start state ``[q; δ; q̇; δ̇]`` (its ``δ`` is the modes' start).
    tc : numpy.ndarray
        Collocation points as fractions of an interval (empty: none).

    Returns
    -------
    (X, U, Xc, Ac) : tuple of ndarray
        Node states ``(N + 1, 2 (n + m))``, interval torques ``(N, n)`` (the mean over
        the interval) [N m], states ``(N len(tc), 2 (n + m))`` and joint accelerations
        ``(N len(tc), n)`` [rad/s²] at the collocation points, interval-major.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> X, U, Xc, Ac = guess_on_grid(model, Move([0.0], [1.0], 2.0), 2.0, 10, 4,
    ...                              np.zeros(4), np.array([0.5]))
    >>> X.shape, U.shape, Xc.shape, Ac.shape, float(X[-1, 0])
    ((11, 4), (10, 1), (10, 4), (10, 1), 1.0)
    """
    from casflex.simulate import simulate_prescribed

    dt = T / (N * substeps)
    m = model.m
    run = simulate_prescribed(model, reference, dt=dt, t_end=T,
                              delta0=x0[model.n:model.n + m] if m else None)
    idx = np.arange(N + 1) * substeps
    idx = np.minimum(idx, run.t.size - 1)
    X = np.hstack([run.q[idx], run.delta[idx], run.dq[idx], run.ddelta[idx]])
    U = np.array([run.tau[k * substeps:(k + 1) * substeps].mean(axis=0) for k in range(N)])
    full = np.hstack([run.q, run.delta, run.dq, run.ddelta, run.ddq])
    times = ((np.arange(N)[:, None] + np.asarray(tc)[None, :]) * (T / N)).ravel()
    Xc = np.stack([np.interp(times, run.t, col) for col in full.T], axis=1)
    nx = 2 * (model.n + m)
    return X, U, Xc[:, :nx], Xc[:, nx:]


def highest_free_frequency(model: FlexibleModel, q0: ArrayLike, qf: ArrayLike) -> float:
    """Highest frequency of the torque-driven arm linearised at rest along the straight
    path from ``q0`` to ``qf`` (nine configurations): with the joints free the modes
    vibrate faster than with them locked (``Ω``), by up to ``√(J / J_res)`` on a light hub.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q0, qf : array_like
        Start and goal joint values [rad].

    Returns
    -------
    float
        [rad/s]; 0 for a model without modes.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> round(float(model.provider.function("omega")(0.0)), 3)   # the joint locked [rad/s]
    25.655
    >>> round(highest_free_frequency(model, np.zeros(1), np.ones(1)), 2)   # free
    50.01
    """
    if not model.m:
        return 0.0
    q0, qf = (np.asarray(q, dtype=float).ravel() for q in (q0, qf))
    f = model.functions()
    n, m = model.n, model.m
    x = ca.SX.sym("x", 2 * (n + m))
    u = ca.SX.sym("tau", n)
    A = ca.Function("A", [x, u], [ca.jacobian(f["ode"](x, u), x)])
    top = 0.0
    for a in np.linspace(0.0, 1.0, 9):
        q = q0 + a * (qf - q0)
        d = static_deflection(model, q)
        hold = f["potential_forces"](q, d).full().ravel()[:n]
        eig = np.linalg.eigvals(A(np.r_[q, d, np.zeros(n + m)], hold).full())
        top = max(top, float(np.max(np.abs(eig.imag))))
    return top


def warm_duals(guess: Any, nx: int, ng: int, solver: str) -> dict | None:
    """The NLP iterate and multipliers of the plan ``guess`` when its OCP has this one's
    shape (``nx`` variables, ``ng`` constraints, the same solver's variable order: e.g.
    another end bound or other limits), else ``None``.

    Only the sizes are compared: a problem of the same sizes but other meaning (another
    robust error, limits moved from one joint to another) gets a poor start, never a
    wrong plan: the start only changes where Ipopt begins, not what it accepts.

    Parameters
    ----------
    guess : PlannedMove or any
        The start of the new solve (anything without a ``solution`` gives ``None``).
    nx, ng : int
        Variables and constraints of the new NLP.
    solver : str
        Its solver (``"ipopt"``; Fatrop takes none: below).

    Returns
    -------
    dict or None
        ``guess.solution`` (``x``, ``lam_g``, ``scales``) or ``None``.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.planning import plan_move
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> p = plan_move(model, [0.0], [1.0], torque_limit=0.1, intervals=20)
    >>> nx, ng = p.solution["x"].size, p.solution["lam_g"].size
    >>> warm_duals(p, nx, ng, "ipopt") is p.solution, warm_duals(p, nx, ng + 1, "ipopt")
    (True, None)
    """
    solution = getattr(guess, "solution", None)
    if not solution or solver != "ipopt":
        # CasADi 3.8's Fatrop has no warm_start_init_point: from a neighbouring solution
        # with its multipliers it took 133 iterations on the one-link arm (80 intervals,
        # end bound 5 % tighter), from the iterate alone 33, cold 34
        return None
    if solution["x"].size != nx or solution["lam_g"].size != ng or \
            guess.stats.get("solver", "ipopt") != solver:  # another variable order
        return None
    return solution
