"""Integration machinery shared by the simulators: one RK4 step, CasADi integrators.

:func:`rk4_step` is plain arithmetic on its arguments, so the same function takes numpy
arrays (simulation, the estimator's reference runs) and CasADi ``SX``/``MX`` expressions
(a step built once as a ``casadi.Function`` and mapped or generated to C).

* :func:`rk4_step` — the one fixed-step Runge–Kutta scheme of casflex;
* :func:`rk4_interval` — RK4 substeps over one sample interval, stage times as input;
* :func:`time_grid` — the uniform output grid of a simulation;
* :func:`casadi_integrator`, :func:`integrate` — an adaptive CasADi integrator
  (``cvodes``/``idas``) with output on a grid, and its evaluation;
* :func:`call_buffered` — evaluate a ``casadi.Function`` on numpy buffers;
* :data:`STEP_CACHE`, :func:`step_cache` — the per-model memo of the step functions that
  the simulators build (mapaccum RK4 steps, the polynomial form's arrays and their
  compiled versions).
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.errors import ModelError, SolverError

if TYPE_CHECKING:
    from casflex.model import FlexibleModel

__all__ = ["rk4_step", "rk4_interval", "time_grid", "casadi_integrator", "integrate",
           "call_buffered", "STEP_CACHE", "step_cache", "LEFT_LIMIT"]

#: where the end stage of a step ``[t, t + dt]`` samples a prescribed reference: at
#: ``t + dt − LEFT_LIMIT dt``, so that a switch of q̈ on the grid belongs to the next step
#: (the left limit). Larger than the samplers' round-off tolerance at a switch
#: (:class:`casflex.planning.PlannedMove`: 1e-12 of the duration, which a step of 1e-4 s
#: with 1e-9 of it did not pass: every OCP node on the grid then took the next interval's
#: q̈ into the step before, 1 % off the residual of move 1 of the design study), and small
#: enough to be the left limit of a smooth q̈ to round-off
LEFT_LIMIT = 1e-5

#: model -> dict of the step Functions built for it by casflex.simulate (weak keys: the
#: entry goes with the model)
STEP_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

_SAME = object()

#: a state: a numpy array or a CasADi expression
State = np.ndarray | ca.SX | ca.MX | ca.DM | float


def rk4_step(f: Callable, x: State, h: float | ca.SX | ca.MX, u: object = None,
             u_half: object = _SAME, u_end: object = _SAME) -> State:
    """One classical 4th-order Runge–Kutta step of ``x' = f(x, u)``.

    Parameters
    ----------
    f : callable
        ``f(x, u)``, or ``f(x)`` when ``u`` is ``None``; numeric or symbolic.
    x : array_like or casadi.SX or casadi.MX
        State at the start of the step.
    h : float or casadi expression
        Step length [s].
    u : optional
        Input at the start of the step (for a time-varying ``f``, the time itself).
    u_half, u_end : optional
        Input at the middle and at the end of the step (both default to ``u``: an input
        held over the step; ``u_end`` defaults to ``u_half`` when only that is given).

    Returns
    -------
    State after the step, of the type of ``x``.

    Examples
    --------
    One step of x' = -x from 1 matches exp(-h) to the scheme's order:

    >>> import math
    >>> x1 = rk4_step(lambda x: -x, 1.0, 0.1)
    >>> abs(x1 - math.exp(-0.1)) < 1e-7
    True

    Time-varying: x' = t from t = 0 to 1 (exact: 1/2).

    >>> rk4_step(lambda x, t: t, 0.0, 1.0, 0.0, 0.5, 1.0)
    0.5
    """
    if u_half is _SAME:
        u_half = u
    if u_end is _SAME:
        u_end = u_half
    if u is None:
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
    else:
        k1 = f(x, u)
        k2 = f(x + 0.5 * h * k1, u_half)
        k3 = f(x + 0.5 * h * k2, u_half)
        k4 = f(x + h * k3, u_end)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def rk4_interval(rhs: Callable, x: State, t: float | ca.SX | ca.MX, dt: float,
                 substeps: int = 1, nudge: float = 0.0) -> State:
    """``substeps`` RK4 steps of ``x' = rhs(x, s)`` over ``[t, t + dt]``, ``s`` the stage
    time.

    Parameters
    ----------
    rhs : callable
        ``rhs(x, s)``, numeric or symbolic.
    x : array_like or casadi.SX or casadi.MX
        State at ``t``.
    t : float or casadi expression
        Start of the interval [s].
    dt : float
        Length of the interval [s].
    substeps : int
        RK4 steps of ``dt / substeps`` each.
    nudge : float
        The first and last stages of each step are evaluated ``nudge`` steps inside it,
        so that the jumps of a bang-bang reference on the step boundaries fall between
        steps, not on a stage.

    Returns
    -------
    State at ``t + dt``, of the type of ``x``.

    Examples
    --------
    x' = s from 0 to 1 (exact: 1/2):

    >>> rk4_interval(lambda x, s: s, 0.0, 0.0, 1.0, substeps=2)
    0.5
    """
    h = dt / substeps
    for i in range(substeps):
        ti = t + i * h
        x = rk4_step(rhs, x, h, ti + nudge * h, ti + 0.5 * h, ti + (1.0 - nudge) * h)
    return x


def step_cache(model: FlexibleModel) -> dict:
    """The memo of step functions built for ``model`` (a dict, created on first use).

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    dict
        Keyed by what each simulator builds (e.g. ``("prescribed", dt, steps)``);
        :data:`STEP_CACHE` ``.clear()`` forgets every model's functions.

    Examples
    --------
    >>> class Model:
    ...     pass
    >>> m = Model()
    >>> step_cache(m) is step_cache(m)
    True
    """
    memo = STEP_CACHE.get(model)
    if memo is None:
        memo = STEP_CACHE[model] = {}
    return memo


def time_grid(t_start: float, t_end: float, dt: float) -> tuple[np.ndarray, int]:
    """Uniform grid ``t_start + dt k``, ``k = 0 … steps``, ``steps = round((t_end −
    t_start)/dt)``.

    Parameters
    ----------
    t_start, t_end : float
        Interval [s].
    dt : float
        Step [s].

    Returns
    -------
    t : numpy.ndarray
    steps : int

    Raises
    ------
    casflex.errors.ModelError
        A step that is not positive and finite, or an interval shorter than a step.

    Examples
    --------
    >>> t, steps = time_grid(0.0, 1.0, 0.25)
    >>> t.tolist(), steps
    ([0.0, 0.25, 0.5, 0.75, 1.0], 4)
    """
    if not (math.isfinite(dt) and dt > 0.0):
        raise ModelError(f"dt must be a positive step [s]; got {dt!r}")
    if not (math.isfinite(t_end) and t_end > t_start):
        raise ModelError(f"t_end must be after the start {t_start} s; got {t_end!r}")
    steps = int(round((t_end - t_start) / dt))
    if steps < 1:
        raise ModelError(f"t_end - t_start = {t_end - t_start} s is shorter than dt = {dt} s")
    return t_start + dt * np.arange(steps + 1), steps


def casadi_integrator(name: str, method: str, dae: dict, t0: float, grid: Sequence[float],
                      options: dict) -> ca.Function:
    """A CasADi integrator from ``t0`` with output at the times ``grid``.

    Parameters
    ----------
    name : str
    method : {"cvodes", "idas"}
    dae : dict
        ``{"x": ..., "t": ..., "p": ..., "ode": ...}`` (CasADi's DAE dictionary).
    t0 : float
        Start time [s].
    grid : sequence of float
        Output times [s].
    options : dict
        Integrator options; defaults ``abstol=1e-10``, ``reltol=1e-8``,
        ``max_num_steps=1e6``.

    Returns
    -------
    casadi.Function

    Raises
    ------
    casflex.errors.SolverError
        CasADi could not create the integrator.

    Examples
    --------
    >>> x = ca.SX.sym("x")
    >>> F = casadi_integrator("decay", "cvodes", {"x": x, "ode": -x}, 0.0, [1.0], {})
    >>> round(float(integrate(F, 1.0)[-1, 0]), 6)
    0.367879
    """
    opts = {"abstol": 1e-10, "reltol": 1e-8, "max_num_steps": 1_000_000}
    opts.update(options)
    try:
        return ca.integrator(name, method, dae, t0, list(grid), opts)
    except RuntimeError as exc:
        raise SolverError(f"could not create the {method} integrator: {exc}") from exc


def integrate(integrator: ca.Function, x0: np.ndarray, p: np.ndarray | None = None
              ) -> np.ndarray:
    """States at the output times of a :func:`casadi_integrator`, one row per time.

    Parameters
    ----------
    integrator : casadi.Function
    x0 : array_like
        Initial state.
    p : array_like, optional
        Parameters (held over the whole interval).

    Returns
    -------
    numpy.ndarray, shape (len(grid), len(x0))

    Raises
    ------
    casflex.errors.SolverError
        The integration failed.

    Examples
    --------
    >>> x, p = ca.SX.sym("x"), ca.SX.sym("p")
    >>> F = casadi_integrator("ramp", "cvodes", {"x": x, "p": p, "ode": p}, 0.0, [1.0, 2.0], {})
    >>> integrate(F, 0.0, 3.0).ravel().round(9).tolist()
    [3.0, 6.0]
    """
    try:
        args = {"x0": x0} if p is None else {"x0": x0, "p": p}
        return integrator(**args)["xf"].full().T
    except RuntimeError as exc:
        raise SolverError(f"integration failed: {exc}") from exc


def call_buffered(fun: ca.Function, args: Sequence[np.ndarray],
                  shapes: Sequence[tuple[int, ...]]) -> list[np.ndarray]:
    """Evaluate ``fun`` without converting large arrays to DM: CasADi reads and writes
    the numpy buffers directly (column-major, so an input of shape (r, c) is passed as a
    C-contiguous (c, r) array).

    Parameters
    ----------
    fun : casadi.Function
    args : sequence of numpy.ndarray
        One array per input, in CasADi's column-major layout (see above).
    shapes : sequence of tuple
        Shapes of the numpy arrays that receive the outputs.

    Returns
    -------
    list of numpy.ndarray

    Examples
    --------
    >>> x = ca.SX.sym("x", 2, 3)
    >>> twice = ca.Function("twice", [x], [2 * x])
    >>> call_buffered(twice, [np.arange(6.0).reshape(3, 2)], [(3, 2)])[0].tolist()
    [[0.0, 2.0], [4.0, 6.0], [8.0, 10.0]]
    """
    buf, run = fun.buffer()
    keep = []
    for i, a in enumerate(args):
        a = np.ascontiguousarray(a, dtype=float)
        keep.append(a)
        buf.set_arg(i, memoryview(a))
    outs = [np.zeros(s) for s in shapes]
    for i, o in enumerate(outs):
        buf.set_res(i, memoryview(o))
    run()
    return outs
