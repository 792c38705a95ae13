"""The one fixed-step Runge–Kutta scheme of casflex, numeric and symbolic.

:func:`rk4_step` is plain arithmetic on its arguments, so the same function takes numpy
arrays (simulation, the estimator's reference runs) and CasADi ``SX``/``MX`` expressions
(a step built once as a ``casadi.Function`` and mapped or generated to C).
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["rk4_step"]

_SAME = object()


def rk4_step(f: Callable, x, h, u=None, u_half=_SAME, u_end=_SAME):
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
