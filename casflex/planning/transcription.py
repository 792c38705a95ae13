"""The interval functions of the planner's explicit transcriptions.

:func:`casflex.planning.plan_move` maps one SX function of an interval over its ``N``
intervals: the implicit collocation's is
:func:`casflex.planning.derivatives.implicit_collocation_function`; here are the explicit
collocation's (:func:`explicit_collocation_function`) and the multiple shooting's
(:func:`shooting_interval_function`), both of the ODE of the nominal state with the
scenarios' modal rows appended (:func:`augmented_ode`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import casadi as ca

from casflex.model import FlexibleModel
from casflex.planning.derivatives import collocation_matrices
from casflex.simulate.integrators import rk4_step

__all__ = ["augmented_ode", "shooting_interval_function", "explicit_collocation_function"]


def augmented_ode(model: FlexibleModel, shifted: Sequence[FlexibleModel]) -> Callable:
    """``ẋa = f(xa, τ)``: the nominal state and the modal state of every shifted model,
    the latter driven by the nominal joint motion (prescribed-motion modal rows, as a
    joint servo would impose it).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The nominal model (``x = [q; δ; q̇; δ̇]``, ``2 (n + m)`` rows).
    shifted : sequence of casflex.model.FlexibleModel
        The scenarios' models (:func:`casflex.planning.frequency_shifted_model`), each
        adding the rows ``[δ_k; δ̇_k]`` (``2 m``).

    Returns
    -------
    callable
        ``ode(xa, tau)`` of CasADi expressions.

    Examples
    --------
    >>> from casflex.model import PointwiseProvider
    >>> from casflex.planning import frequency_shifted_model
    >>> from casflex.robot import load
    >>> robot = load("problems/onelink.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    >>> ode = augmented_ode(model, [frequency_shifted_model(model, 0.1)])
    >>> ode(ca.DM([0, 1e-3, 0, 0, 1e-3, 0]), 0.0).shape
    (6, 1)
    """
    n, m = model.n, model.m
    nx = 2 * (n + m)
    f = model.functions()
    rows = [s.functions()["dddelta"] for s in shifted]

    def ode(xa, tau):
        x = xa[:nx]
        xdot = f["ode"](x, tau)
        if not rows:
            return xdot
        q, dq = x[:n], x[n + m:2 * n + m]
        ddq = xdot[n + m:2 * n + m]
        out = [xdot]
        for k, row in enumerate(rows):
            z = xa[nx + 2 * m * k:nx + 2 * m * (k + 1)]
            out += [z[m:], row(q, dq, ddq, z[:m], z[m:])]
        return ca.vertcat(*out)

    return ode


def shooting_interval_function(ode: Callable, nxa: int, n: int, substeps: int
                               ) -> ca.Function:
    """``F(x, τ, h) -> (x_end, states)``: ``substeps`` RK4 steps of length ``h``.

    One step is an SX function; the substeps are a ``mapaccum`` of it, so the
    derivatives of the step are built once, not once per substep.

    Parameters
    ----------
    ode : callable
        ``ode(x, tau)`` (:func:`augmented_ode`).
    nxa, n : int
        State rows and torques.
    substeps : int
        RK4 steps per interval.

    Returns
    -------
    casadi.Function
        Inputs ``x`` (nxa), ``tau`` (n), ``h`` [s]; outputs ``xf`` and ``states``
        (nxa × substeps, the state after each step).

    Examples
    --------
    >>> import numpy as np
    >>> F = shooting_interval_function(lambda x, u: ca.vertcat(x[1], u), 2, 1, 4)
    >>> xf, _ = F([0.0, 0.0], 1.0, 0.25)
    >>> np.round(np.asarray(xf).ravel(), 12).tolist()  # q = t²/2 at t = 1, exact for RK4
    [0.5, 1.0]
    """
    x = ca.SX.sym("x", nxa)
    u = ca.SX.sym("tau", n)
    h = ca.SX.sym("h")
    step = ca.Function("rk4", [x, u, h], [rk4_step(ode, x, h, u)])
    try:  # the model's Functions are SX inside: one flat SX step is faster
        step = step.expand()
    except RuntimeError:
        pass
    acc = step.mapaccum("substeps", substeps, [0], [0])
    xm = ca.MX.sym("x", nxa)
    um = ca.MX.sym("tau", n)
    hm = ca.MX.sym("h")
    states = acc(xm, ca.repmat(um, 1, substeps), ca.repmat(hm, 1, substeps))
    return ca.Function("interval", [xm, um, hm], [states[:, -1], states],
                       ["x", "tau", "h"], ["xf", "states"])


def explicit_collocation_function(ode: Callable, nxa: int, n: int, degree: int
                                  ) -> ca.Function:
    """``G(x, Xc, τ, h) -> (defects, x_end)``: Gauss–Legendre collocation of ``degree``
    points on one interval of length ``h`` (torque constant), expanded to one SX function
    so that the NLP's derivatives come from one compact function mapped over the
    intervals.

    The state is the polynomial of ``degree`` through ``x`` at 0 and ``Xc`` at the
    collocation points; ``defects`` are ``h ẋ(t_j) − p'(t_j)`` at those points and
    ``x_end`` the polynomial at the end of the interval (order ``2 degree`` there).

    Parameters
    ----------
    ode : callable
        ``ode(x, tau)`` (:func:`augmented_ode`).
    nxa, n : int
        State rows and torques.
    degree : int
        Collocation points.

    Returns
    -------
    casadi.Function
        Inputs ``x``, ``Xc`` (nxa × degree), ``tau``, ``h`` [s]; outputs ``defects``
        (nxa × degree) and ``xf``.

    Examples
    --------
    The states of ``q̈ = τ`` from rest, at the points: the defects vanish.

    >>> import numpy as np
    >>> G = explicit_collocation_function(lambda x, u: ca.vertcat(x[1], u), 2, 1, 2)
    >>> t = np.asarray(ca.collocation_points(2, "legendre"))
    >>> d, xf = G([0.0, 0.0], np.vstack([t**2 / 2, t]), 1.0, 1.0)
    >>> float(np.max(np.abs(d))) < 1e-12, np.round(np.asarray(xf).ravel(), 12).tolist()
    (True, [0.5, 1.0])
    """
    C, D = collocation_matrices(degree)
    x = ca.SX.sym("x", nxa)
    Xc = ca.SX.sym("Xc", nxa, degree)
    u = ca.SX.sym("tau", n)
    h = ca.SX.sym("h")
    P = ca.horzcat(x, Xc)
    defects = [h * ode(Xc[:, j - 1], u) - P @ C[:, j] for j in range(1, degree + 1)]
    G = ca.Function("collocation", [x, Xc, u, h], [ca.horzcat(*defects), P @ D],
                    ["x", "Xc", "tau", "h"], ["defects", "xf"])
    try:
        G = G.expand()
    except RuntimeError:
        pass
    return G
