"""Guards of the real-time path: the EKF step and ``rt_step`` survive bad samples.

A :class:`Guard` given to :func:`casflex.estimation.ekf_step_function` (and through it to
:func:`casflex.codegen.rt_step_function`) adds checks to the step's CasADi graph, so the
Python evaluation and the generated C do exactly the same thing (no branch of either is
written twice):

* **non-finite inputs.** A sample ``y_i`` that is NaN or ±inf on a channel with
  ``mask_i = 1`` is skipped (as a dropout); a non-finite entry of ``u`` is replaced by the
  last valid one (input ``u_last``, output ``u_next``; 0 if there is none); a non-finite
  prior ``x`` is reset to ``x_reset`` with ``P`` reset too;
* **innovation gating.** Channel ``i`` is rejected (treated as a dropout) when its
  normalised innovation ``ν_i² / S_ii`` exceeds ``gate``, with ``S_ii = h_i P h_iᵀ + R_ii``
  from the prior covariance: under the filter's own model ``ν_i² / S_ii`` is χ²(1), so the
  default ``gate`` (:data:`DEFAULT_GATE`, the χ²(1) quantile of 1 − 1e-9, 6.1 σ) rejects a
  consistent sample once in 10⁹. All channels are tested against the prior, before any
  of them updates the state;
* **covariance bounds.** The prior ``P`` (symmetrised) and the result ``P_next`` are
  checked: every diagonal entry within ``[floor, ceiling]`` and every pivot ``d_j`` of
  the ``LDLᵀ`` factorisation above ``floor`` (positive definite with a margin; a NaN or
  inf entry anywhere makes a pivot or a diagonal fail). A covariance that fails is
  replaced by ``P_reset``;
* **status word.** The step returns ``status``, the sum of the bits below (a double in
  CasADi and C: cast it to an integer); 0 means nothing happened.

Status bits (also ``#define``\\ d in the headers of guarded bundles, prefix ``CASFLEX_``):

=======================  =====  ===============================================
``STATUS_SAMPLE_REJECTED``   1  a channel failed the innovation gate (skipped)
``STATUS_SAMPLE_NONFINITE``  2  a channel with mask 1 had a NaN/inf sample (skipped)
``STATUS_INPUT_HELD``        4  a non-finite input held at its last valid value
``STATUS_COVARIANCE_RESET``  8  ``P`` or ``P_next`` failed its bounds: set to ``P_reset``
``STATUS_STATE_RESET``      16  ``x`` or ``x_next`` not finite: set to ``x_reset``
``STATUS_TORQUE_CLIPPED``   32  ``rt_step``: a torque clipped to its limit
``STATUS_TORQUE_HELD``      64  ``rt_step``: a non-finite torque replaced by the last one
=======================  =====  ===============================================

The generated checks rely on IEEE comparisons (a NaN compares false): never compile a
guarded bundle with ``-ffast-math`` / ``-ffinite-math-only``.

Examples
--------
>>> g = Guard(P_reset=np.eye(2) * 1e-4)
>>> round(g.gate, 2), g.ceiling
(37.32, 100.0)
>>> status_names(STATUS_SAMPLE_REJECTED | STATUS_COVARIANCE_RESET)
['sample_rejected', 'covariance_reset']
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from casflex._validate import fail, number, square_matrix

__all__ = [
    "Guard",
    "DEFAULT_GATE",
    "STATUS_BITS",
    "STATUS_SAMPLE_REJECTED",
    "STATUS_SAMPLE_NONFINITE",
    "STATUS_INPUT_HELD",
    "STATUS_COVARIANCE_RESET",
    "STATUS_STATE_RESET",
    "STATUS_TORQUE_CLIPPED",
    "STATUS_TORQUE_HELD",
    "status_names",
    "is_finite",
    "held",
    "any_of",
    "all_of",
    "covariance_ok",
]

STATUS_SAMPLE_REJECTED = 1
STATUS_SAMPLE_NONFINITE = 2
STATUS_INPUT_HELD = 4
STATUS_COVARIANCE_RESET = 8
STATUS_STATE_RESET = 16
STATUS_TORQUE_CLIPPED = 32
STATUS_TORQUE_HELD = 64

#: bit name -> value, in bit order
STATUS_BITS = {
    "sample_rejected": STATUS_SAMPLE_REJECTED,
    "sample_nonfinite": STATUS_SAMPLE_NONFINITE,
    "input_held": STATUS_INPUT_HELD,
    "covariance_reset": STATUS_COVARIANCE_RESET,
    "state_reset": STATUS_STATE_RESET,
    "torque_clipped": STATUS_TORQUE_CLIPPED,
    "torque_held": STATUS_TORQUE_HELD,
}

#: χ²(1) quantile of 1 − 1e-9: a sample consistent with the filter is rejected once in 1e9.
#: The value of ``2 * scipy.special.erfcinv(1e-9) ** 2`` written out (tests compare the two
#: bit for bit): importing scipy.special costs every command that builds an EKF ~0.5 s.
DEFAULT_GATE = 37.324893051362345

_DBL_MAX = float(np.finfo(float).max)


@dataclass(frozen=True)
class Guard:
    """Options of the guarded EKF step (module docstring).

    Parameters
    ----------
    P_reset : array_like
        Covariance that replaces a failed one (2m × 2m, symmetric positive definite; the
        initial ``P0`` of the filter is the natural choice).
    gate : float or None
        Threshold of ``ν_i² / S_ii`` (dimensionless); ``None`` or ``inf``: no gating.
    floor : float, optional
        Smallest admitted diagonal entry and ``LDLᵀ`` pivot of ``P`` [units of P]; default
        ``1e-16 × min diag P_reset``.
    ceiling : float, optional
        Largest admitted diagonal entry of ``P``; default ``1e6 × max diag P_reset``.
    x_reset : array_like, optional
        State that replaces a non-finite one (default 0, the modes at rest).

    Examples
    --------
    >>> Guard(P_reset=[[1.0, 0.0], [0.0, 1.0]], gate=9.0).gate
    9.0
    >>> Guard(P_reset=[[1.0, 0.0], [0.0, 0.0]])
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: P_reset = [[1.0, 0.0], [0.0, 0.0]]: must be positive definite
    """

    P_reset: np.ndarray
    gate: float | None = DEFAULT_GATE
    floor: float | None = None
    ceiling: float | None = None
    x_reset: np.ndarray | None = field(default=None)

    def __post_init__(self):
        P = np.asarray(self.P_reset, dtype=float)
        nx = P.shape[0] if P.ndim == 2 else 0
        P = square_matrix(P, nx, "P_reset", psd=True)
        if np.min(np.linalg.eigvalsh(P)) <= 0:
            raise fail("P_reset", np.asarray(self.P_reset).tolist(),
                       "must be positive definite")
        object.__setattr__(self, "P_reset", P)
        gate = np.inf if self.gate is None else number(self.gate, "gate", low=0.0,
                                                       low_open=True)
        object.__setattr__(self, "gate", float(gate))
        d = np.diag(P)
        floor = 1e-16 * d.min() if self.floor is None else self.floor
        ceiling = 1e6 * d.max() if self.ceiling is None else self.ceiling
        floor = number(floor, "floor", low=0.0, low_open=True)
        ceiling = number(ceiling, "ceiling", low=floor, low_open=True)
        if d.min() < floor or d.max() > ceiling:
            raise fail("P_reset", d.tolist(), f"diagonal must lie in [{floor}, {ceiling}]")
        object.__setattr__(self, "floor", float(floor))
        object.__setattr__(self, "ceiling", float(ceiling))
        x = np.zeros(nx) if self.x_reset is None else np.asarray(self.x_reset, float)
        if x.shape != (nx,) or not np.all(np.isfinite(x)):
            raise fail("x_reset", x.tolist(), f"must be {nx} finite numbers")
        object.__setattr__(self, "x_reset", x)


def status_names(status: int | float) -> list[str]:
    """Names of the bits set in a status word.

    Parameters
    ----------
    status : int or float
        The ``status`` output of a guarded step.

    Returns
    -------
    list of str
        Keys of :data:`STATUS_BITS`, in bit order.

    Examples
    --------
    >>> status_names(5.0)
    ['sample_rejected', 'input_held']
    """
    s = int(status)
    return [k for k, b in STATUS_BITS.items() if s & b]


def is_finite(v: ca.SX) -> ca.SX:
    """Elementwise ``1`` where ``v`` is finite, ``0`` for NaN and ±inf (an IEEE comparison
    with the largest double: NaN compares false).

    Parameters
    ----------
    v : casadi.SX

    Returns
    -------
    casadi.SX
        Same shape, 0/1.

    Examples
    --------
    >>> x = ca.SX.sym("x")
    >>> f = ca.Function("f", [x], [is_finite(x)])
    >>> [float(f(v)) for v in (1.0, np.nan, np.inf)]
    [1.0, 0.0, 0.0]
    """
    return ca.fabs(v) <= _DBL_MAX


def held(v: ca.SX, last: ca.SX) -> tuple[ca.SX, ca.SX]:
    """``v`` with its non-finite entries replaced by ``last`` (or 0 where that is not
    finite either), and the flag "an entry was replaced".

    Parameters
    ----------
    v, last : casadi.SX
        Column vectors of the same size.

    Returns
    -------
    tuple of casadi.SX
        The finite vector and a 0/1 scalar.

    Examples
    --------
    >>> a, b = ca.SX.sym("a", 2), ca.SX.sym("b", 2)
    >>> f = ca.Function("f", [a, b], list(held(a, b)))
    >>> [np.asarray(o).ravel().tolist() for o in f([1.0, np.nan], [3.0, 4.0])]
    [[1.0, 4.0], [1.0]]
    """
    ok = is_finite(v)
    fallback = [ca.if_else(is_finite(last[i]), last[i], 0) for i in range(last.numel())]
    out = ca.vertcat(*[ca.if_else(ok[i], v[i], fallback[i]) for i in range(v.numel())])
    flag = any_of([1 - ok[i] for i in range(v.numel())])
    return out, flag


def any_of(flags) -> ca.SX:
    """Logical or of 0/1 SX scalars (a sequence, or the entries of a column).

    Parameters
    ----------
    flags : sequence of casadi.SX or casadi.SX

    Returns
    -------
    casadi.SX
        0/1 scalar (0 for none).

    Examples
    --------
    >>> float(ca.evalf(any_of([ca.SX(0), ca.SX(1)])))
    1.0
    """
    if isinstance(flags, ca.SX):
        flags = [flags[i] for i in range(flags.numel())]
    out = ca.SX(0)
    for f in flags:
        out = ca.logic_or(out, f)
    return out


def all_of(flags) -> ca.SX:
    """Logical and of 0/1 SX scalars (a sequence, or the entries of a column).

    Parameters
    ----------
    flags : sequence of casadi.SX or casadi.SX

    Returns
    -------
    casadi.SX
        0/1 scalar (1 for none).

    Examples
    --------
    >>> float(ca.evalf(all_of(ca.SX([1, 0]))))
    0.0
    """
    if isinstance(flags, ca.SX):
        flags = [flags[i] for i in range(flags.numel())]
    out = ca.SX(1)
    for f in flags:
        out = ca.logic_and(out, f)
    return out


def covariance_ok(P: ca.SX, floor: float, ceiling: float) -> ca.SX:
    """``1`` if the symmetric ``P`` has every diagonal entry in ``[floor, ceiling]`` and
    every ``LDLᵀ`` pivot above ``floor``, else ``0`` (NaN or inf anywhere gives 0).

    Parameters
    ----------
    P : casadi.SX
        Symmetric matrix (only the lower triangle is read).
    floor, ceiling : float
        Bounds [units of P].

    Returns
    -------
    casadi.SX
        0/1 scalar.

    Examples
    --------
    >>> P = ca.SX.sym("P", 2, 2)
    >>> f = ca.Function("f", [P], [covariance_ok(P, 1e-9, 10.0)])
    >>> bad = np.array([[1, np.nan], [np.nan, 1]])
    >>> float(f(np.eye(2))), float(f(np.ones((2, 2)))), float(f(bad))
    (1.0, 0.0, 0.0)
    """
    r = P.shape[0]
    L = [[None] * r for _ in range(r)]
    d = [None] * r
    ok = ca.SX(1)
    for j in range(r):
        ok = ca.logic_and(ok, ca.logic_and(P[j, j] >= floor, P[j, j] <= ceiling))
        s = P[j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k] * d[k]
        d[j] = s
        ok = ca.logic_and(ok, s > floor)
        for i in range(j + 1, r):
            t = P[i, j]
            for k in range(j):
                t = t - L[i][k] * L[j][k] * d[k]
            L[i][j] = t / s
    return ok
