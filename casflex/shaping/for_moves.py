"""Shapers for planned moves of a flexible arm (§6.1.4–6.1.5 of the reference dissertation).

Everything here needs the arm: a :class:`~casflex.model.FlexibleModel`, a
:class:`~casflex.modal.tables.ModalTable` or a planned :class:`~casflex.moves.Move`.

* what the move excites: :func:`modal_displacements` (eq. 197) and
  :func:`modal_contributions` (eq. 196), and the tolerances they give
  (:func:`tolerances_from_contributions`, eq. 198);
* the frequencies the modes sweep along the move (:func:`frequencies_along`) and the
  frequency ranges they give (:func:`frequency_ranges_along`);
* the SI shaper of a move (:func:`shaper_for_move`, :class:`MoveShaperResult`), also
  with the model built from the robot (:func:`shaper_for_robot_move`);
* the shaped reference of a move (:func:`shaped_reference`) and the residual vibration
  of a simulated response (:func:`residual_amplitude`).

Units are SI: times in s, angles in rad, frequencies in rad/s, deflections in m.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import fail, number
from casflex.errors import ModelError, ProblemFileError, SolverError
from casflex.moves import Move
from casflex.shaping.ranges import FrequencyRange
from casflex.shaping.shapers import Shaper, apply_shaper, as_shaper, check_vtol, check_zeta
from casflex.shaping.si import (
    DEFAULT_TIME_LIMIT,
    SIShaperResult,
    initial_si_guess,
    si_shaper,
)
from casflex.shaping.si_cache import cached_si_design

if TYPE_CHECKING:
    from casflex.modal.tables import ModalTable
    from casflex.model import FlexibleModel
    from casflex.robot import Robot

__all__ = [
    "modal_displacements",
    "modal_contributions",
    "tolerances_from_contributions",
    "frequencies_along",
    "frequency_ranges_along",
    "MoveShaperResult",
    "shaper_for_move",
    "shaper_for_robot_move",
    "shaped_reference",
    "residual_amplitude",
]

#: a sampled joint reference ``(t, q, dq, ddq)``: s, rad, rad/s, rad/s²
SampledReference = tuple[ArrayLike, ArrayLike, ArrayLike | None, ArrayLike]


def _model_functions(model):
    """``model.functions()`` of a :class:`casflex.model.FlexibleModel` or ModelError."""
    if not hasattr(model, "functions") or not hasattr(model, "m") or not hasattr(model, "n"):
        raise ModelError(
            f"model: expected a casflex.model.FlexibleModel (e.g. from "
            f"casflex.model.build_model); got {type(model).__name__}"
        )
    if int(model.m) < 1:
        raise ModelError("model: has no flexible modes (m = 0); nothing to shape")
    return model.functions()


def _check_samples(n_samples, name="n_samples"):
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)):
        raise fail(name, n_samples, "must be an integer >= 2", error=ProblemFileError)
    return number(n_samples, name, low=2, integer=True, error=ProblemFileError)


def _sampled_reference(reference, n_joints=None):
    """Validate a sampled reference ``(t, q, dq, ddq)``; return t (N,), q, ddq (N, n)."""
    if not isinstance(reference, (tuple, list)) or len(reference) != 4:
        raise ProblemFileError(
            None,
            "reference",
            type(reference).__name__,
            "must be a casflex.moves.Move or a sampled (t, q, dq, ddq) tuple "
            "(e.g. the output of apply_shaper)",
        )
    t, q, _, ddq = reference
    t = np.asarray(t, dtype=float).reshape(-1)
    if t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise ProblemFileError(
            None,
            "reference.t",
            f"{t.size} samples",
            "needs >= 2 finite, strictly increasing times [s]",
        )
    out = []
    for name, x in (("q", q), ("ddq", ddq)):
        if x is None:
            raise ProblemFileError(None, f"reference.{name}", None, "is required [rad, rad/s²]")
        x = np.asarray(x, dtype=float)
        x = x.reshape(t.size, 1) if x.ndim == 1 and x.size == t.size else x
        if x.ndim != 2 or x.shape[0] != t.size:
            raise ProblemFileError(
                None, f"reference.{name}", x.shape, f"must have shape ({t.size}, n_joints)"
            )
        if not np.all(np.isfinite(x)):
            raise ProblemFileError(None, f"reference.{name}", "...", "must be finite")
        out.append(x)
    q, ddq = out
    if q.shape != ddq.shape:
        raise ProblemFileError(
            None, "reference.ddq", ddq.shape, f"must have the shape of reference.q {q.shape}"
        )
    if n_joints is not None and q.shape[1] != n_joints:
        raise ModelError(
            f"reference: has {q.shape[1]} joint(s) but the model has {n_joints}; "
            "give one column per joint"
        )
    return t, q, ddq


def _check_move_joints(move, n_joints):
    if n_joints is not None and move.n_joints != n_joints:
        raise fail("reference", move.name, f"the move has {move.n_joints} joint(s) but the "
                   f"model has {n_joints}")


def _quadrature(reference, n_samples, n_joints=None):
    """Nodes and weights to integrate along the reference: ``t, q, ddq, weights``.

    A :class:`~casflex.moves.Move` is integrated over ``[0, duration]`` with the midpoint
    rule on an even number of intervals, so that no node falls on a switch of the
    bang-bang acceleration (at 0, T/2 and T) and the integral is exact to O(h²) on each
    smooth piece. A sampled reference uses its own samples and the trapezoidal rule.
    """
    if isinstance(reference, Move):
        _check_move_joints(reference, n_joints)
        n = _check_samples(n_samples)
        n += n % 2
        h = reference.duration / n
        t = (np.arange(n) + 0.5) * h
        q, _, ddq = reference.sample(t)
        return t, q, ddq, np.full(n, h)
    t, q, ddq = _sampled_reference(reference, n_joints)
    dt = np.diff(t)
    w = np.zeros(t.size)
    w[:-1] += 0.5 * dt
    w[1:] += 0.5 * dt
    return t, q, ddq, w


def _path(reference, n_samples, n_joints=None):
    """Positions along the reference (end points included): ``t, q``."""
    if isinstance(reference, Move):
        _check_move_joints(reference, n_joints)
        t = np.linspace(0.0, reference.duration, _check_samples(n_samples) + 1)
        return t, reference.sample(t)[0]
    t, q, _ = _sampled_reference(reference, n_joints)
    return t, q


def _point_jacobian(model, functions, point):
    """casadi.Function ``q -> ∂p/∂δ (3, m)`` at δ = 0 for the chosen point."""
    q = ca.SX.sym("q", model.n)
    d = ca.SX.sym("delta", model.m)
    if point is None:
        p = functions["tip"](q, d)
    elif isinstance(point, ca.Function):
        if point.n_in() != 2 or point.numel_out(0) != 3:
            raise ModelError(
                f"point: a casadi.Function must map (q, delta) to a 3-vector [m]; got "
                f"{point.n_in()} input(s) and {point.numel_out(0)} output entries"
            )
        p = point(q, d)
    elif isinstance(point, (int, np.integer)) and not isinstance(point, bool):
        frames = functions["frames"]
        if not 0 <= int(point) < frames.n_out():
            raise ModelError(
                f"point: frame index {point} out of range; the robot has {frames.n_out()} "
                f"DH rows (0-based; {frames.n_out() - 1} is the last frame, the tip)"
            )
        p = frames(q, d)[int(point)][:3, 3]
    else:
        raise ModelError(
            f"point: {point!r} is not None (the tip), a 0-based DH row index (origin of its "
            "frame) or a casadi.Function (q, delta) -> 3-vector"
        )
    jac = ca.substitute(ca.jacobian(p, d), d, ca.SX.zeros(model.m))
    return ca.Function("point_modal_displacement", [q], [jac], ["q"], ["W"])


def modal_displacements(model: FlexibleModel, q: ArrayLike,
                        point: int | ca.Function | None = None) -> np.ndarray:
    """Total modal displacement ``w_j(p)`` of a point at a configuration (eq. 197).

    ``w_j(p) = ‖∂p/∂δ_j‖`` at ``δ = 0``: the length of the displacement of point ``p``
    caused by a unit amplitude of the mass-normalised mode ``j``, from the model's
    kinematics (CasADi Jacobian of the point's position with respect to ``δ``).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    q : array_like, shape (n,)
        Configuration, rad.
    point : None, int or casadi.Function, optional
        ``None`` for the tip (``model.functions()["tip"]``), an integer for the origin of
        the frame of that 0-based DH row (``frames``), or a ``casadi.Function`` mapping
        ``(q, delta)`` to a position (3-vector, m).

    Returns
    -------
    numpy.ndarray, shape (m,)
        Modal displacements, m per unit modal amplitude.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=3),
    ...                       gravity=None)
    >>> modal_displacements(model, [0.0, 0.0, 0.0]).round(2).tolist()
    [4.73, 4.56, 4.18]
    """
    functions = _model_functions(model)
    q = np.asarray(q, dtype=float).reshape(-1)
    if q.size != model.n or not np.all(np.isfinite(q)):
        raise ModelError(f"q: expected {model.n} finite joint values [rad]; got {q.tolist()}")
    jac = _point_jacobian(model, functions, point)(q).full()
    return np.linalg.norm(jac, axis=0)


def modal_contributions(model: FlexibleModel, reference: Move | SampledReference,
                        point: int | ca.Function | None = None, n_samples: int = 400,
                        normalize: bool = True) -> np.ndarray:
    """Relative contribution of every mode to the deflection of a point (eq. 196–197).

    ``r_j = ∫ (|M_qδᵀ(q_d(t))| |q̈_d(t)|)_j dt · w_j(p)`` from the start to the end of the
    planned trajectory, with ``|·|`` taken element-wise (eq. 194: the joint accelerations
    drive the modes through ``M_qδ``) and ``w_j(p)`` the total modal displacement of the
    point at the end configuration (eq. 197, :func:`modal_displacements`). Coriolis and
    centrifugal coupling are neglected, as in the dissertation.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Its ``mass`` function gives ``M_qδ = M[:n, n:]`` at ``δ = 0``.
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
        The planned joint trajectory: a move (integrated over ``[0, duration]`` with the
        midpoint rule, which never samples the switches of the bang-bang acceleration) or
        sampled arrays (s, rad, rad/s, rad/s²; shape (N,) and (N, n); trapezoidal rule;
        ``dq`` is not used), e.g. the output of :func:`apply_shaper`. The end configuration
        is ``move.qf`` or the last sample.
    point : None, int or casadi.Function, optional
        The point ``p`` (default the tip), see :func:`modal_displacements`.
    n_samples : int, optional
        Quadrature intervals for a move (rounded up to an even number).
    normalize : bool, optional
        Divide by the largest contribution (the dissertation's normalised ``r``; all zeros
        if nothing is excited). With ``False`` the raw values are returned: with the mass
        normalisation ``M_δδ = I`` they are a bound on the speed, m/s, that each mode gives
        the point by the end of the move. Values below 1e-12 of the largest (round-off of
        couplings that vanish, e.g. out-of-plane modes in a planar move) are set to 0.

    Returns
    -------
    numpy.ndarray, shape (m,)
        ``r`` (dimensionless, max 1) or the raw values.

    Examples
    --------
    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=3),
    ...                       gravity=None)
    >>> move3 = load_move("problems/moves.toml:move3")    # q1 only: shapes do not change
    >>> modal_contributions(model, move3).round(2).tolist()
    [1.0, 0.0, 0.38]
    """
    functions = _model_functions(model)
    n, m = int(model.n), int(model.m)
    t, q, ddq, w = _quadrature(reference, n_samples, n)
    mass = functions["mass"].map(t.size)
    big = mass(q.T, np.zeros((m, t.size))).full()  # (n+m, N*(n+m))
    mqd = big.reshape(n + m, t.size, n + m)[:n, :, n:]  # (n, N, m)
    integrand = np.einsum("inj,ni->nj", np.abs(mqd), np.abs(ddq))  # (N, m)
    integral = w @ integrand
    q_end = reference.qf if isinstance(reference, Move) else q[-1]
    r = integral * modal_displacements(model, q_end, point)
    r[r <= 1e-12 * float(np.max(r))] = 0.0  # round-off of couplings that vanish exactly
    if not normalize:
        return r
    peak = float(np.max(r))
    return r / peak if peak > 0.0 else np.zeros_like(r)


def tolerances_from_contributions(r: ArrayLike, vtol: float = 0.05) -> np.ndarray:
    """Tolerable residual vibration of every mode from its contribution (eq. 198).

    The mode with the largest contribution ``r_j`` gets ``vtol``; every other mode ``s``
    gets ``Vtol_s = (r_j / r_s) vtol``, clamped to at most 1 (1 imposes nothing: a mode
    that is not excited, ``r_s → 0``, gets 1). If no mode is excited all are 1.

    Note that the dissertation's example in §6.1.4 quotes ``Vtol = [0.05, 0.05, 0.67]``
    for ``r = [4, 2, 0.3]``; the formula gives ``[0.05, 0.10, 0.67]`` (the 0.30 s shaper
    it reports is the one for the latter).

    Parameters
    ----------
    r : array_like, shape (m,)
        Contributions (normalised or raw; only ratios matter), finite and >= 0.
    vtol : float, optional
        Tolerable residual vibration fraction of the dominant mode, 0 < vtol <= 1.

    Returns
    -------
    numpy.ndarray, shape (m,)
        Residual vibration fractions in ``[vtol, 1]``.

    Examples
    --------
    >>> tolerances_from_contributions([4.0, 2.0, 0.3]).round(3).tolist()
    [0.05, 0.1, 0.667]
    >>> tolerances_from_contributions([0.0, 1.0, 0.0]).tolist()
    [1.0, 0.05, 1.0]
    """
    vtol = check_vtol(vtol)
    try:
        arr = np.asarray(r, dtype=float)
    except (TypeError, ValueError):
        raise ProblemFileError(None, "r", r, "contributions must be numbers") from None
    if arr.ndim != 1 or arr.size == 0:
        raise ProblemFileError(
            None, "r", np.shape(r), "contributions must be a non-empty 1-D array"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise ProblemFileError(None, "r", arr.tolist(), "contributions must be finite and >= 0")
    peak = float(arr.max())
    out = np.ones_like(arr)
    if peak <= 0.0:
        return out
    pos = arr > 0.0
    out[pos] = np.minimum(1.0, vtol * peak / arr[pos])
    return out


def frequencies_along(model_or_table: FlexibleModel | ModalTable,
                      reference: Move | SampledReference, n_samples: int = 200
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Tracked natural frequencies along a planned joint trajectory.

    Parameters
    ----------
    model_or_table : casflex.model.FlexibleModel or casflex.modal.tables.ModalTable
        A model (``ω = sqrt(diag K(q))`` from its ``stiffness`` function) or a modal table
        (its B-spline ``omega`` interpolant over the shape joints).
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
        The trajectory (see :func:`modal_contributions`); a move is sampled at
        ``n_samples + 1`` evenly spaced times over ``[0, duration]``.
    n_samples : int, optional
        Intervals for a move.

    Returns
    -------
    t : numpy.ndarray, shape (N,)
        Times, s.
    omega : numpy.ndarray, shape (N, m)
        Frequencies of the tracked modes, rad/s.

    Examples
    --------
    >>> from casflex.modal.tables import ModalTable
    >>> from casflex.moves import Move
    >>> axis = np.linspace(-1.0, 0.0, 5)
    >>> table = ModalTable(grid=(axis,), shape_joints=(0,), values={},
    ...                    omega=np.column_stack([10 + axis, 30 - 2 * axis]))
    >>> t, w = frequencies_along(table, Move(q0=[0.0], qf=[-1.0], duration=1.0), 4)
    >>> w[[0, -1]].round(6).tolist()
    [[10.0, 30.0], [9.0, 32.0]]
    """
    obj = model_or_table
    if hasattr(obj, "grid") and hasattr(obj, "shape_joints") and hasattr(obj, "omega"):
        joints = tuple(int(k) for k in obj.shape_joints)
        t, q = _path(reference, n_samples)
        if q.shape[1] <= max(joints):
            raise ModelError(
                f"reference: has {q.shape[1]} joint(s) but the table's shape joints are "
                f"{[k + 1 for k in joints]} (1-based)"
            )
        f = obj.function("omega")
        omega = f.map(t.size)(q[:, list(joints)].T).full().T
        return t, omega.reshape(t.size, -1)
    functions = _model_functions(obj)
    t, q = _path(reference, n_samples, int(obj.n))
    k = functions["stiffness"].map(t.size)(q.T).full()  # (m, N*m)
    m = int(obj.m)
    diag = k.reshape(m, t.size, m)[np.arange(m), :, np.arange(m)].T  # (N, m)
    return t, np.sqrt(np.clip(diag, 0.0, None))


def _per_mode(value, m, name, check):
    arr = np.asarray(value, dtype=float) if not isinstance(value, (int, float)) else None
    if arr is None or arr.ndim == 0:
        v = check(value if arr is None else float(arr), name)
        return [v] * m
    arr = arr.reshape(-1)
    if arr.size != m:
        raise ProblemFileError(None, name, arr.tolist(), f"needs one value per mode ({m})")
    return [check(float(v), f"{name}[{i}]") for i, v in enumerate(arr)]


def _check_margin(margin):
    return number(margin, "margin", low=0.0, high=1.0, high_open=True, error=ProblemFileError)


def frequency_ranges_along(model_or_table: FlexibleModel | ModalTable,
                           reference: Move | SampledReference, margin: float = 0.20,
                           zeta: ArrayLike | None = None, vtol: ArrayLike = 0.05,
                           n_samples: int = 200) -> list[FrequencyRange]:
    """Frequency ranges the modes sweep during a planned move, widened by a margin.

    Every mode's range is ``[(1 - margin) min ω_j, (1 + margin) max ω_j]`` over the
    trajectory (:func:`frequencies_along`): the ±20 % robustness margin of §6.1.5 by
    default. With ``margin = 0`` a mode whose frequency does not change gives a single
    frequency.

    Parameters
    ----------
    model_or_table : casflex.model.FlexibleModel or casflex.modal.tables.ModalTable
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
    margin : float, optional
        Relative widening on each side, 0 <= margin < 1.
    zeta : float or array_like, optional
        Damping ratio per mode (or one for all); default the model's ``damping_ratio``
        (0 for a table).
    vtol : float or array_like, optional
        Tolerable residual vibration per mode (or one for all), 0 < vtol <= 1.
    n_samples : int, optional
        Samples of a move (see :func:`frequencies_along`).

    Returns
    -------
    list of FrequencyRange
        One per mode, rad/s.

    Examples
    --------
    >>> from casflex.modal.tables import ModalTable
    >>> from casflex.moves import Move
    >>> axis = np.linspace(-1.0, 0.0, 5)
    >>> table = ModalTable(grid=(axis,), shape_joints=(0,), values={},
    ...                    omega=np.column_stack([10 + axis, 30 - 2 * axis]))
    >>> r = frequency_ranges_along(table, Move(q0=[0.0], qf=[-1.0], duration=1.0),
    ...                            vtol=[0.05, 1.0])
    >>> [(round(x.omega_min, 3), round(x.omega_max, 3), x.vtol) for x in r]
    [(7.2, 12.0, 0.05), (24.0, 38.4, 1.0)]
    """
    margin = _check_margin(margin)
    _, omega = frequencies_along(model_or_table, reference, n_samples)
    if zeta is None:
        zeta = float(getattr(model_or_table, "damping_ratio", 0.0) or 0.0)
    return _ranges_from_omega(omega, margin, zeta, vtol)


def _ranges_from_omega(omega, margin, zeta, vtol):
    m = omega.shape[1]
    zetas = _per_mode(zeta, m, "zeta", check_zeta)
    vtols = _per_mode(vtol, m, "vtol", check_vtol)
    lo, hi = omega.min(axis=0), omega.max(axis=0)
    if np.any(lo <= 0.0):
        j = int(np.argmin(lo))
        raise ModelError(f"mode {j + 1} has a non-positive frequency ({lo[j]:.4g} rad/s) along "
                         "the trajectory: a rigid-body mode cannot be shaped")
    return [
        FrequencyRange(float(a) * (1.0 - margin), float(b) * (1.0 + margin), z, v)
        for a, b, z, v in zip(lo, hi, zetas, vtols, strict=True)
    ]


@dataclass(frozen=True, eq=False)
class MoveShaperResult:
    """Result of :func:`shaper_for_move`.

    Attributes
    ----------
    shaper : Shaper
        The SI shaper.
    ranges : list of FrequencyRange
        Design ranges (rad/s, margin included) with the tolerances of every mode.
    contributions : numpy.ndarray, shape (m,)
        Normalised modal contributions ``r`` (eq. 196, max 1).
    raw_contributions : numpy.ndarray, shape (m,)
        The same before normalisation, m/s (see :func:`modal_contributions`).
    tolerances : numpy.ndarray, shape (m,)
        ``Vtol`` of every mode (eq. 198).
    omega_min, omega_max : numpy.ndarray, shape (m,)
        Frequency span of every mode along the move without the margin, rad/s.
    margin : float
        Relative margin added to the spans.
    si : SIShaperResult
        The full SI design result (verified maximum PRV per range, solver statuses).

    Examples
    --------
    Two modes of the arm frozen at one configuration, so each range is a single frequency:

    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=2),
    ...                       gravity=None)
    >>> res = shaper_for_move(model, load_move("problems/moves.toml:move3"), margin=0.0,
    ...                       n_samples=50)
    >>> res.contributions.round(3).tolist(), res.tolerances.round(3).tolist()
    ([1.0, 0.0], [0.05, 1.0])
    >>> res.omega_min.round(3).tolist(), round(res.duration, 3)
    ([8.307, 11.97], 0.366)
    """

    shaper: Shaper
    ranges: list
    contributions: np.ndarray
    raw_contributions: np.ndarray
    tolerances: np.ndarray
    omega_min: np.ndarray
    omega_max: np.ndarray
    margin: float
    si: SIShaperResult

    @property
    def duration(self) -> float:
        """Shaper duration, s."""
        return self.shaper.duration

    @property
    def max_prv(self) -> np.ndarray:
        """Verified maximum residual vibration fraction on every range."""
        return self.si.max_prv


def shaper_for_move(model: FlexibleModel, reference: Move | SampledReference,
                    vtol: float = 0.05, margin: float = 0.20, zeta: ArrayLike | None = None,
                    *, point: int | ca.Function | None = None, n_samples: int = 400,
                    n_impulses: str | int | None = "auto",
                    time_limit: float | None = DEFAULT_TIME_LIMIT,
                    cache_dir: str | os.PathLike | bool = False,
                    **si_options) -> MoveShaperResult:
    """Design the SI shaper of a planned move from its modal contributions (§6.1.4).

    The steps of the dissertation: the contributions ``r`` of every mode to the deflection
    of ``point`` (:func:`modal_contributions`, eq. 196–197), the tolerances
    ``Vtol`` (:func:`tolerances_from_contributions`, eq. 198), the frequency span of every
    mode along the move widened by ``±margin`` (:func:`frequency_ranges_along`), and the
    minimum-duration SI shaper for those ranges (:func:`si_shaper`).

    The dissertation's simulated moves (§6.1.5.1, Table 14) use the frequency spans
    without a margin (``margin=0``), which reproduces its durations; its ±20 % is the
    robustness margin of the testbed experiments and the default here.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    reference : casflex.moves.Move or tuple (t, q, dq, ddq)
        Planned joint trajectory (s, rad, rad/s, rad/s²).
    vtol : float, optional
        Tolerable residual vibration of the dominant mode, 0 < vtol <= 1.
    margin : float, optional
        Relative widening of every frequency span, 0 <= margin < 1.
    zeta : float or array_like, optional
        Damping ratio per mode; default the model's ``damping_ratio``.
    point : None, int or casadi.Function, optional
        Point whose deflection matters (default the tip), see :func:`modal_displacements`.
    n_samples : int, optional
        Samples along a move for the contributions and the frequencies.
    n_impulses : "auto", int or None, optional
        Impulses of the initial guess (see :func:`si_shaper`). ``"auto"`` first tries
        four per constrained range (the convolved EI guess of wide, overlapping ranges can
        have dozens of impulses, most of which the optimum drops, and an NLP that large is
        slow) and falls back to the full guess if that design fails; ``None`` always uses
        the full guess.
    time_limit : float or None, optional
        Wall-clock limit of the SI design, s (both attempts of ``"auto"`` together; see
        :func:`si_shaper`; None: no limit).
    cache_dir : str or os.PathLike or bool, optional
        Keep the SI design in casflex's cache (:func:`~casflex.shaping.cached_si_design`,
        keyed on the ranges and every option): a path, ``None`` for the default cache
        directory, ``False`` (default) to design without the cache.
    **si_options
        Further keyword arguments of :func:`si_shaper`.

    Returns
    -------
    MoveShaperResult

    Raises
    ------
    SolverError
        If the SI design fails.

    Examples
    --------
    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=3),
    ...                       gravity=None)
    >>> res = shaper_for_move(model, load_move("problems/moves.toml:move3"), margin=0.0)
    >>> res.tolerances.round(2).tolist(), round(res.duration, 2)
    ([0.05, 1.0, 0.13], 0.39)
    """
    raw = modal_contributions(model, reference, point=point, n_samples=n_samples,
                              normalize=False)
    peak = float(np.max(raw))
    r = raw / peak if peak > 0.0 else np.zeros_like(raw)
    tol = tolerances_from_contributions(r, vtol)
    margin = _check_margin(margin)
    _, omega = frequencies_along(model, reference, n_samples)
    ranges = _ranges_from_omega(omega, margin, model.damping_ratio if zeta is None else zeta,
                                tol)
    if isinstance(n_impulses, str) and n_impulses != "auto":
        raise fail("n_impulses", n_impulses, "must be 'auto', None or an integer >= 1",
                   error=ProblemFileError)
    options = {"n_impulses": n_impulses, "time_limit": time_limit, **si_options}
    si = cached_si_design(ranges, options, lambda: _si_design(ranges, n_impulses, time_limit,
                                                              si_options), cache_dir)
    return MoveShaperResult(
        shaper=si.shaper,
        ranges=list(ranges),
        contributions=r,
        raw_contributions=raw,
        tolerances=tol,
        omega_min=omega.min(axis=0),
        omega_max=omega.max(axis=0),
        margin=margin,
        si=si,
    )


def _si_design(ranges, n_impulses, time_limit, si_options):
    """The SI design of :func:`shaper_for_move` (``n_impulses="auto"``: the smaller start
    first, the full one if that fails within the time limit)."""
    active = sum(1 for x in ranges if x.vtol < 1.0)
    if isinstance(n_impulses, str):
        limit = 4 * active
        guess_size = len(initial_si_guess(ranges)) if active else 1
        if active and guess_size > limit:
            started = time.perf_counter()
            try:
                si = si_shaper(ranges, limit, time_limit=time_limit, **si_options)
            except SolverError:
                left = (None if time_limit is None
                        else time_limit - (time.perf_counter() - started))
                if left is not None and left <= 0.0:
                    raise
                si = si_shaper(ranges, None, time_limit=left, **si_options)
        else:
            si = si_shaper(ranges, None, time_limit=time_limit, **si_options)
    else:
        si = si_shaper(ranges, n_impulses, time_limit=time_limit, **si_options)
    return si


def shaper_for_robot_move(robot: Robot, move: Move, n_modes: int = 3, *, vtol: float = 0.05,
                          margin: float = 0.20, step: float | None = None,
                          cache_dir: str | os.PathLike | None = None,
                          processes: int | None = None, progress: bool = False,
                          log: Callable[[str], None] | None = None,
                          time_limit: float | None = DEFAULT_TIME_LIMIT
                          ) -> tuple[FlexibleModel, MoveShaperResult]:
    """Build the modal model of a robot and design the SI shaper of a planned move.

    The model is :func:`casflex.model.build_model` without gravity, as in the
    dissertation's moves, so that the deflection it simulates is vibration only; its modal
    tables are cached. The shaper is :func:`shaper_for_move` on that model (tip deflection,
    default options).

    Parameters
    ----------
    robot : casflex.robot.Robot
    move : casflex.moves.Move
        The planned move; one joint value per joint of the robot (rad).
    n_modes : int, optional
        Number of modes of the model.
    vtol : float, optional
        Tolerable residual vibration of the dominant mode, 0 < vtol <= 1.
    margin : float, optional
        Relative widening of every frequency span, 0 <= margin < 1.
    step : float, optional
        Grid step of the modal tables, rad (default of :func:`casflex.model.default_grid`).
    cache_dir : str or os.PathLike, optional
        Cache directory of the modal tables (default: casflex's cache).
    processes : int, optional
        Worker processes for the tables (default: all CPUs; 1 = no pool).
    progress : bool, optional
        Show a progress bar while tabulating.
    log : callable, optional
        ``log(message)`` receives one line before each of the two steps.
    time_limit : float or None, optional
        Wall-clock limit of the shaper design, s (see :func:`shaper_for_move`).

    Returns
    -------
    model : casflex.model.FlexibleModel
        The gravity-free model.
    result : MoveShaperResult

    Raises
    ------
    ModelError
        If the move does not have one value per joint of the robot (checked before the
        model is built).

    Examples
    --------
    >>> import tempfile
    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> model, res = shaper_for_robot_move(load("problems/arm2link.toml"),
    ...                                    load_move("problems/moves.toml:move3"), n_modes=1,
    ...                                    margin=0.0, step=np.radians(30.0), processes=1,
    ...                                    cache_dir=tempfile.mkdtemp())
    >>> model.m, res.tolerances.tolist(), round(res.duration, 3)
    (1, [0.05], 0.366)
    """
    from casflex.model import build_model

    if move.n_joints != robot.n_joints:
        raise fail("move", move.name, f"has {move.n_joints} joint(s) but robot "
                   f"'{robot.name}' has {robot.n_joints}")
    for end in ("q0", "qf"):  # bang-bang moves are monotone: the ends bound the path
        robot.within_limits(getattr(move, end), f"move '{move.name}' {end}")
    say = log or (lambda message: None)
    say(f"building the {n_modes}-mode model of '{robot.name}' (tables cached)")
    model, _ = build_model(robot, n_modes=n_modes, step=step, gravity=None,
                           cache_dir=cache_dir, processes=processes, progress=progress)
    say(f"designing the shaper for {move.name} (margin ±{100 * margin:g} %, "
        f"Vtol {100 * vtol:g} %)")
    return model, shaper_for_move(model, move, vtol=vtol, margin=margin,
                                  time_limit=time_limit)


def shaped_reference(shaper: Shaper, move: Move, dt: float = 1e-3, t_end: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample a move and shape it: the reference for a shaped simulation.

    The move is sampled every ``dt`` from 0 to ``t_end`` (default ``move.t_end``, the
    move plus its settle time) and convolved with the shaper (:func:`apply_shaper`), which
    extends it by the shaper's duration: the shaped move ends at
    ``move.duration + shaper.duration`` and is followed by the same settle time.

    Parameters
    ----------
    shaper : Shaper
    move : casflex.moves.Move
    dt : float, optional
        Sample step, s.
    t_end : float, optional
        End of the unshaped samples, s.

    Returns
    -------
    tuple (t, q, dq, ddq)
        s, rad, rad/s, rad/s²; arrays of shape (N,) and (N, n).

    Examples
    --------
    >>> from casflex.moves import Move
    >>> from casflex.shaping import zv
    >>> t, q, dq, ddq = shaped_reference(zv(10.0), Move(q0=[0.0], qf=[1.0], duration=1.0,
    ...                                                settle=0.5), dt=0.01)
    >>> round(float(t[-1]), 2), round(float(q[-1, 0]), 6)
    (1.82, 1.0)
    """
    shaper = as_shaper(shaper)
    if not isinstance(move, Move):
        raise ProblemFileError(None, "move", type(move).__name__, "must be a casflex.moves.Move")
    dt = number(dt, "dt", low=0.0, low_open=True, error=ProblemFileError)
    t_end = move.t_end if t_end is None else number(t_end, "t_end", error=ProblemFileError)
    if t_end <= dt:
        raise ProblemFileError(None, "t_end", t_end, f"must exceed the step dt = {dt} s")
    t = np.arange(int(round(t_end / dt)) + 1) * dt
    q, dq, ddq = move.sample(t)
    return apply_shaper(shaper, t, q, dq, ddq)


def residual_amplitude(t: ArrayLike, deflection: ArrayLike, t_from: float) -> float:
    """Largest deflection (vector norm) from ``t_from`` on: the residual vibration.

    Parameters
    ----------
    t : array_like, shape (N,)
        Times, s.
    deflection : array_like, shape (N,) or (N, 3)
        Deflection of a point (e.g. ``SimulationResult.tip_deflection``), m.
    t_from : float
        Start of the residual phase (end of the — shaped — move), s.

    Returns
    -------
    float
        ``max ‖deflection(t)‖`` for ``t >= t_from``, m.

    Examples
    --------
    >>> t = np.linspace(0.0, 2.0, 201)
    >>> d = np.column_stack([np.exp(-t) * np.sin(20 * t), 0 * t, 0 * t])
    >>> round(residual_amplitude(t, d, 1.0), 3)   # about exp(-1)
    0.361
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    d = np.asarray(deflection, dtype=float)
    d = d.reshape(t.size, -1) if d.size else d
    if d.shape[0] != t.size:
        raise ProblemFileError(None, "deflection", d.shape, f"needs {t.size} rows (one per time)")
    t_from = number(t_from, "t_from", error=ProblemFileError)
    sel = t >= t_from - 1e-12
    if not np.any(sel):
        raise ProblemFileError(None, "t_from", t_from,
                               f"no sample at or after it (last time {t[-1]:.6g} s)")
    return float(np.max(np.linalg.norm(d[sel], axis=1)))
