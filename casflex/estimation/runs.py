"""Running an EKF step over recorded data, and the offset prefilter that goes with it.

:func:`run_ekf` runs a step of :mod:`casflex.estimation.ekf` over sampled arrays as one
CasADi ``mapaccum`` call and returns an :class:`EKFResult`. Offsets of the signals are
handled by a first-order high-pass (§5.5.1.1): :func:`highpass_cutoff` places its
cut-off one decade below the lowest natural frequency, :func:`prefilter_initial` starts
the filter inside the step in steady state, and :func:`highpass` filters recorded signals.

Examples
--------
>>> y = highpass(np.full(5, 2.0), 1e-3, 1.0, start="first")
>>> y.tolist()
[0.0, 0.0, 0.0, 0.0, 0.0]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import choice, fail
from casflex.sensors import SensorSet, kinematic_measurement

if TYPE_CHECKING:
    from casflex.estimation.plant import FlexiblePlant
    from casflex.model import FlexibleModel

__all__ = ["EKFResult", "run_ekf", "prefilter_initial", "highpass", "highpass_cutoff"]


@dataclass
class EKFResult:
    """Estimates over a run.

    Attributes
    ----------
    x : numpy.ndarray
        (N, 2m) filtered estimates ``x̂_{k|k}``.
    x_prior : numpy.ndarray
        (N + 1, 2m) priors ``x̂_{k|k−1}`` (row 0: the initial guess).
    P : numpy.ndarray
        (N + 1, 2m, 2m) prior covariances (``S Sᵀ`` for the square-root form).
    status : numpy.ndarray or None
        (N,) status words of a guarded step (:mod:`casflex.estimation.guard`), else
        ``None``.

    Examples
    --------
    From :func:`run_ekf`; here with a toy one-state step that adds 1 per sample:

    >>> x, P, u, y, k = [ca.SX.sym(s) for s in "xPuyk"]
    >>> f = ca.Function("s", [x, P, u, y, k], [x + 1, 2 * P, x], ["x", "P", "u", "y", "mask"],
    ...                 ["x_next", "P_next", "x_post"])
    >>> r = run_ekf(f, np.zeros((3, 1)), np.zeros((3, 1)), [0.0], [[1.0]])
    >>> r.x.shape, r.x_prior.shape, r.P.shape
    ((3, 1), (4, 1), (4, 1, 1))
    >>> r.x_prior.ravel().tolist(), r.P.ravel().tolist()
    ([0.0, 1.0, 2.0, 3.0], [1.0, 2.0, 4.0, 8.0])
    """

    x: np.ndarray
    x_prior: np.ndarray
    P: np.ndarray
    status: np.ndarray | None = None


def prefilter_initial(plant: FlexiblePlant, sensors: SensorSet, x0: ArrayLike, u0: ArrayLike,
                      y0: ArrayLike) -> np.ndarray:
    """Prefilter state in steady state at the first sample: ``[y0, 0, h(x̂0, u0), 0]``.

    The difference between the first signals and their prediction is taken as an offset
    and removed from the start (a filter started at rest would let it decay with
    ``1/ω_c`` instead).

    Parameters
    ----------
    plant : casflex.estimation.FlexiblePlant
    sensors : casflex.sensors.SensorSet
    x0 : array_like
        Initial estimate ``[δ; δ̇]`` (2m).
    u0 : array_like
        First ``[q; q̇; q̈]`` (3n).
    y0 : array_like
        First signals (r); NaN (a missing sample) is replaced by the prediction.

    Returns
    -------
    numpy.ndarray
        (4r) prefilter state, the ``f`` input of a step with ``prefilter``
        (:func:`casflex.estimation.ekf_step_function`; ``f0`` of :func:`run_ekf`).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> from casflex.estimation import tabulate_plant
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> prefilter_initial(tabulate_plant(model), ss, [0, 0], np.zeros(9), [1e-6, 0]).size
    8
    """
    u0 = np.asarray(u0, dtype=float)
    x0 = np.asarray(x0, dtype=float)
    acc = np.asarray(plant.rhs_function()(u0, x0)).ravel()
    h0 = np.asarray(kinematic_measurement(plant.model, sensors)(x0, u0, acc)).ravel()
    y0 = np.asarray(y0, dtype=float).ravel()
    y0 = np.where(np.isfinite(y0), y0, h0)
    return np.concatenate([y0, np.zeros_like(y0), h0, np.zeros_like(h0)])


def highpass_cutoff(model: FlexibleModel, q: ArrayLike) -> float:
    """Cut-off one decade below the lowest natural frequency at ``q`` [rad/s] (§5.5.1.1).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like
        Configuration [rad] (n).

    Returns
    -------
    float
        ``min ω(q) / 10`` [rad/s], the ``prefilter`` of
        :func:`casflex.estimation.ekf_step_function`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> round(highpass_cutoff(model, [0, 0, 0]), 3)
    0.831
    """
    q = np.asarray(q, dtype=float)
    if getattr(model, "full_stiffness", False):  # a rotated basis: ω are Rayleigh quotients
        K = model.functions()["stiffness"](q).full()
        return float(np.sqrt(max(np.linalg.eigvalsh(K)[0], 0.0))) / 10.0
    w = ca.Function("w", [model.q], [model.omega])(q)
    return float(np.min(np.asarray(w))) / 10.0


def highpass(signal: ArrayLike, dt: float, omega_c: float, start: str = "rest") -> np.ndarray:
    """First-order high-pass filter ``s / (s + ω_c)`` (Tustin) of sampled signals.

    Parameters
    ----------
    signal : array_like
        (N,) or (N, channels).
    dt : float
        Sample time [s].
    omega_c : float
        Cut-off [rad/s].
    start : {"rest", "first"}
        ``"rest"``: the filter is at rest and the input zero before the first sample (an
        offset present from the start is a step that decays with ``1/ω_c``);
        ``"first"``: the input was the first sample forever (the first sample is
        removed at once — right for a pure offset, wrong when the first sample carries
        signal).

    Examples
    --------
    >>> y = highpass(np.full(2000, 0.5), 1e-3, 1.0, start="first")
    >>> float(abs(y).max())
    0.0
    >>> round(float(highpass(np.full(2000, 0.5), 1e-3, 1.0)[-1]), 4)   # 0.5 exp(-2)
    0.0677
    """
    x = np.asarray(signal, dtype=float)
    choice(start, "start", ("rest", "first"))
    a = (2.0 - omega_c * dt) / (2.0 + omega_c * dt)
    b = 2.0 / (2.0 + omega_c * dt)
    out = np.empty_like(x)
    prev_x = x[0] if start == "first" else np.zeros_like(x[0])
    prev_y = np.zeros_like(x[0])
    for k in range(x.shape[0]):
        prev_y = a * prev_y + b * (x[k] - prev_x)
        prev_x = x[k]
        out[k] = prev_y
    return out


def run_ekf(step: ca.Function, u: ArrayLike | None, y: ArrayLike, x0: ArrayLike,
            P0: ArrayLike, mask: ArrayLike | None = None,
            f0: ArrayLike | None = None, u_last: ArrayLike | None = None) -> EKFResult:
    """Run an EKF step function over recorded arrays (one CasADi ``mapaccum`` call).

    Parameters
    ----------
    step : casadi.Function
        From :func:`casflex.estimation.ekf_step_function` (plain or square-root form;
        give ``P0`` as ``S0`` for the latter).
    u : array_like or None
        (N, 3n) measured ``[q, q̇, q̈]``; ``None`` for steps without inputs
        (:func:`casflex.estimation.full_state_step_function`).
    y : array_like
        (N, r) signals; NaN marks a missing sample (an unguarded step never sees it: it
        is masked here; a guarded step gets the raw sample and ``mask`` as given).
    x0, P0 : array_like
        Initial guess and its covariance (or square root).
    mask : array_like, optional
        (N, r) 1/0 validity; default ``isfinite(y)``.
    f0 : array_like, optional
        Initial prefilter state (steps with ``prefilter``); default 0, the filter at rest.
        :func:`prefilter_initial` starts it in steady state on the first samples.
    u_last : array_like, optional
        Guarded steps: the last valid input before the first sample (default ``u[0]``;
        its non-finite entries count as 0).

    Returns
    -------
    EKFResult

    Examples
    --------
    >>> import casadi as ca
    >>> x, P, u, y, k = [ca.SX.sym(s) for s in "xPuyk"]
    >>> f = ca.Function("s", [x, P, u, y, k], [x + 1, P, x], ["x", "P", "u", "y", "mask"],
    ...                 ["x_next", "P_next", "x_post"])
    >>> run_ekf(f, np.zeros((3, 1)), np.zeros((3, 1)), [0.0], [[1.0]]).x.ravel().tolist()
    [0.0, 1.0, 2.0]
    """
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    u = np.zeros((y.shape[0], 0)) if u is None else np.atleast_2d(np.asarray(u, dtype=float))
    N = u.shape[0]
    if y.shape[0] != N:
        raise fail("y", y.shape, f"must have as many samples (rows) as u: {N}")
    guarded = "u_last" in step.name_in()
    if guarded:  # the step checks the samples itself
        valid = np.ones(y.shape, bool) if mask is None else np.asarray(mask, bool)
        yc = y
    else:
        valid = np.isfinite(y)
        if mask is not None:
            valid &= np.asarray(mask, dtype=bool)
        yc = np.where(valid, y, 0.0)
    nx = step.size1_in(0)
    args = [np.asarray(x0, dtype=float).reshape(nx, 1), np.asarray(P0, dtype=float),
            u.T, yc.T, valid.astype(float).T]
    acc_in, acc_out = [0, 1], [0, 1]
    if "f" in step.name_in():  # prefilter state
        acc_in.append(step.index_in("f"))
        acc_out.append(step.index_out("f_next"))
        args.append(np.zeros(step.size1_in(5)) if f0 is None else np.asarray(f0, float))
    if guarded:
        acc_in.append(step.index_in("u_last"))
        acc_out.append(step.index_out("u_next"))
        args.append(u[0] if u_last is None else np.asarray(u_last, float))
    F = step.mapaccum("ekf_run", N, acc_in, acc_out)
    out = F(*args)
    xn = np.asarray(out[0]).T
    Pn = np.asarray(out[1]).reshape(nx, N, nx).transpose(1, 0, 2)
    xp = np.asarray(out[2]).T
    sqrt = step.name_in(1) == "S"
    if sqrt:
        Pn = np.einsum("nij,nkj->nik", Pn, Pn)
        S0 = np.asarray(P0, dtype=float)
        P0m = S0 @ S0.T
    else:
        P0m = np.asarray(P0, dtype=float)
    status = (np.asarray(out[step.index_out("status")]).ravel().astype(np.int64)
              if guarded else None)
    return EKFResult(x=xp, x_prior=np.vstack([np.asarray(x0, dtype=float).ravel(), xn]),
                     P=np.concatenate([P0m[None], Pn]), status=status)


