"""Matplotlib figures for casflex results.

Every function returns a :class:`matplotlib.figure.Figure` and never shows it; save it
with ``fig.savefig(path)``. Figures are built with the object-oriented API so they work
under any backend (the CLI uses Agg).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.plotting_report import (
    outside_legend as _outside_legend,
)
from casflex.plotting_report import (
    plot_accessibility_along,
    plot_estimation_error,
    plot_frequencies_along,
    plot_joint_tracking,
    plot_tip_deflection,
)

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from casflex.identification import CalibrationResult, ModalEstimate
    from casflex.robot import Robot
    from casflex.shaping import FrequencyRange, MoveShaperResult, Shaper
    from casflex.simulate import SimulationResult
    from casflex.tmm import ModeShapes

__all__ = [
    # structures and modes
    "skeleton", "plot_modes", "plot_sweep",
    # simulation
    "plot_result",
    # input shaping
    "plot_prv", "plot_move_shaper", "plot_si_optimality", "plot_digital_shaper",
    # planning
    "plot_plan",
    # control
    "plot_accessibility",
    # design report
    "plot_frequencies_along", "plot_tip_deflection",
    "plot_estimation_error", "plot_accessibility_along",
    "plot_joint_tracking",
    # identification
    "plot_identification", "plot_calibration",
]


def skeleton(robot: Robot, q: ArrayLike) -> np.ndarray:
    """Points of the undeformed arm in the base frame, base to tip [m], shape (k, 3).

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Joint variables [rad].

    Returns
    -------
    numpy.ndarray, shape (k, 3)
        The base, then the end of every beam or rigid offset (repeated points dropped).

    Examples
    --------
    >>> from casflex.robot import load
    >>> skeleton(load("problems/arm2link.toml"), [0, 0, 0]).round(3).tolist()
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, -1.0]]
    """
    from casflex.tmm.chain import build_chain

    chain = build_chain(robot, q)
    pts = [np.zeros(3)]
    for element in chain.elements:
        if element.kind in ("beam", "offset"):
            pts.append(element.end)
    pts = np.array(pts)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 0.0])
    return pts[keep]


def _equal_axes(ax, pts):
    centre = 0.5 * (pts.max(axis=0) + pts.min(axis=0))
    half = 0.5 * max(np.ptp(pts, axis=0).max(), 1e-3) * 1.1
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)


def plot_modes(robot: Robot, q: ArrayLike, shapes: ModeShapes, n_modes: int | None = None,
               scale: float | None = None) -> Figure:
    """The undeformed arm and its first mode shapes, one 3-D panel per mode.

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Configuration [rad].
    shapes : casflex.tmm.ModeShapes
    n_modes : int, optional
        Number of modes drawn (all by default, at most 6).
    scale : float, optional
        Peak drawn displacement [m]; 15 % of the arm's size by default.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> fig = plot_modes(robot, [0, 0, 0], modes(robot, [0, 0, 0], count=2))
    >>> len(fig.axes)
    2
    """
    n = shapes.omega.size if n_modes is None else min(n_modes, shapes.omega.size)
    n = min(n, 6)
    base = skeleton(robot, q)
    size = max(np.ptp(base, axis=0).max(), 1e-3)
    scale = 0.15 * size if scale is None else scale
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    fig = Figure(figsize=(4.2 * cols, 4.0 * rows), layout="constrained")
    disp = shapes.displacement_global
    for j in range(n):
        ax = fig.add_subplot(rows, cols, j + 1, projection="3d")
        ax.plot(*base.T, color="0.6", lw=2, marker="o", ms=3, label="undeformed")
        peak = np.max(np.abs(disp[j])) or 1.0
        for b in range(shapes.position.shape[0]):
            p = shapes.position[b] + scale / peak * disp[j, b]
            ax.plot(*p.T, color="C0", lw=2, label="mode" if b == 0 else None)
        f_hz = shapes.omega[j] / (2.0 * np.pi)
        ax.set_title(f"mode {j + 1}: {shapes.omega[j]:.3f} rad/s ({f_hz:.3f} Hz)")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        _equal_axes(ax, np.vstack([base, shapes.position.reshape(-1, 3)]))
        if j == 0:
            ax.legend(loc="upper left", fontsize="small")
    return fig


def plot_sweep(q: ArrayLike, omega: ArrayLike, joint: int, tracked: bool = False, *,
               unit: str = "rad/s", title: str | None = None) -> Figure:
    """Natural frequencies versus one joint angle (dissertation Fig. 25/26).

    Parameters
    ----------
    q : array_like
        (k,) joint values [rad].
    omega : array_like
        (k, m) frequencies [rad/s].
    joint : int
        0-based index of the swept joint (``2`` is q3), for the label.
    tracked : bool
        Whether the columns follow modes (lines) or sorted order (markers).
    unit : {"rad/s", "Hz"}
        Unit of the frequency axis.
    title : str, optional
        Figure title (default: which kind of sweep it is).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> fig = plot_sweep([0.0, 0.1], [[1.0, 2.0], [1.1, 2.1]], joint=2)
    >>> fig.axes[0].get_xlabel()
    'q3 [deg]'
    """
    q = np.asarray(q, dtype=float)
    omega = np.asarray(omega, dtype=float)
    omega = _frequency_scale(unit) * omega
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for j in range(omega.shape[1]):
        style = dict(lw=1.5) if tracked else dict(ls="none", marker=".", ms=3)
        ax.plot(np.degrees(q), omega[:, j], label=f"mode {j + 1}", **style)
    ax.set_xlabel(f"q{joint + 1} [deg]")
    ax.set_ylabel(f"natural frequency [{unit}]")
    ax.set_title(title or ("tracked modes" if tracked else "sorted natural frequencies"))
    ax.grid(True, alpha=0.3)
    _outside_legend(ax)
    return fig


# ------------------------------------------------------------------------- input shaping

_FREQUENCY_UNITS = {"rad/s": 1.0, "Hz": 1.0 / (2.0 * np.pi)}


def _frequency_scale(unit):
    if unit not in _FREQUENCY_UNITS:
        raise ModelError(f"unit = {unit!r}: must be 'rad/s' or 'Hz'")
    return _FREQUENCY_UNITS[unit]


def _draw_prv(ax, shaper, ranges, names, unit):
    """Residual vibration [%] of ``shaper`` from 0 to 1.2 × the highest range, per damping
    ratio; every range a coloured strip above the curve (one row per range, so overlapping
    ranges stay apart) and its tolerance a bar in the same colour."""
    from casflex.shaping import residual_vibration

    scale = _frequency_scale(unit)
    hi = max(r.omega_max for r in ranges)
    w = np.linspace(0.0, 1.2 * hi, 3000)
    zetas = sorted({r.zeta for r in ranges})
    top = 100.0
    for k, z in enumerate(zetas):
        label = "V(ω)" if len(zetas) == 1 else f"V(ω), ζ = {z:g}"
        v = 100.0 * residual_vibration(shaper, w, z)
        top = max(top, float(v.max()))
        ax.plot(scale * w, v, color="k", lw=1.2, ls=("-", "--", ":", "-.")[k % 4], label=label)
    names = names or [f"range {i + 1}" for i in range(len(ranges))]
    row = 0.06 * top   # height of one strip's row, in % of the vibration axis
    for i, (r, name) in enumerate(zip(ranges, names, strict=True)):
        c = f"C{i % 10}"
        lo, up = scale * r.omega_min, scale * r.omega_max
        tol = "no tolerance" if r.vtol >= 1.0 else f"Vtol {100.0 * r.vtol:.3g} %"
        label = f"{name}: {lo:.3g}–{up:.3g} {unit}, {tol}"
        y = top + (i + 0.6) * row
        if lo == up:
            ax.plot([lo], [y], "v", color=c, ms=7)
            if r.vtol < 1.0:
                ax.plot([lo], [100.0 * r.vtol], "_", color=c, ms=14, mew=3)
            ax.plot([], [], "v", color=c, label=label)
            continue
        ax.fill_between([lo, up], y - 0.4 * row, y + 0.4 * row, color=c, alpha=0.6, lw=0)
        if r.vtol < 1.0:
            ax.plot([lo, up], [100.0 * r.vtol] * 2, "-", color=c, lw=3, label=label)
        else:
            ax.plot([], [], "s", color=c, alpha=0.6, label=label)
    ax.set_xlim(0.0, scale * 1.2 * hi)
    ax.set_ylim(0.0, top + (len(ranges) + 0.3) * row)
    ax.text(0.995, top + 0.5 * len(ranges) * row, "design ranges", color="0.3", va="center",
            ha="right", fontsize="x-small", transform=ax.get_yaxis_transform())
    ax.set_yticks([t for t in ax.get_yticks() if 0.0 <= t <= top])
    ax.set_xlabel(f"natural frequency [{unit}]")
    ax.set_ylabel("residual vibration [%]")
    ax.grid(True, alpha=0.3)
    _outside_legend(ax)


def plot_prv(shaper: Shaper, ranges: Sequence[FrequencyRange], *,
             names: Sequence[str] | None = None, title: str | None = None,
             unit: str = "rad/s") -> Figure:
    """Residual vibration of a shaper against natural frequency, with its design ranges.

    The curve runs from 0 (where every shaper lets the motion through, V = 100 %) to 1.2
    times the highest range, one curve per damping ratio of the ranges. Each range is a
    coloured strip above the curve (one row per range, so overlapping ranges stay
    distinguishable; a marker for a single frequency) and its tolerance a bar in the same
    colour at the height of the tolerance; the legend names every range. Residual
    vibration is drawn in %.

    Parameters
    ----------
    shaper : casflex.shaping.Shaper
    ranges : sequence of casflex.shaping.FrequencyRange
        Design ranges [rad/s].
    names : sequence of str, optional
        Legend name of every range (default ``range 1``, ``range 2``, ...).
    title : str, optional
        Title (default the number of impulses and the duration of the shaper).
    unit : {"rad/s", "Hz"}
        Unit of the frequency axis.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.shaping import FrequencyRange, zv
    >>> fig = plot_prv(zv(10.0), [FrequencyRange(9.0, 11.0, 0.0, 0.05)])
    >>> fig.axes[0].get_xlabel(), fig.axes[0].get_title()
    ('natural frequency [rad/s]', 'shaper: 2 impulses, 0.3142 s')
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(8.0, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    _draw_prv(ax, shaper, ranges, names, unit)
    ax.set_title(title or f"shaper: {len(shaper)} impulses, {shaper.duration:.4f} s")
    fig.tight_layout()
    return fig


def plot_move_shaper(result: MoveShaperResult, move_name: str,
                     deflections: Mapping[str, tuple[ArrayLike, ArrayLike]] | None = None,
                     *, unit: str = "rad/s") -> Figure:
    """The shaper of a planned move: its residual vibration over the design ranges and,
    when given, simulated tip deflections.

    Parameters
    ----------
    result : casflex.shaping.MoveShaperResult
        The design (:func:`casflex.shaping.shaper_for_move`); ranges in rad/s.
    move_name : str
        Name of the move, for the title.
    deflections : mapping of str to (t, deflection), optional
        Label -> times [s] and deflection of the tip (shape (N,) or (N, 3), m), drawn as
        its Euclidean norm in mm in a second panel (e.g. ``{"unshaped": ..., "shaped": ...}``).
    unit : {"rad/s", "Hz"}
        Unit of the frequency axis (as :func:`plot_prv`, which draws the first panel).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import load_move
    >>> from casflex.robot import load
    >>> from casflex.shaping import shaper_for_move
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=2),
    ...                       gravity=None)
    >>> res = shaper_for_move(model, load_move("problems/moves.toml:move3"), margin=0.0,
    ...                       n_samples=50)
    >>> t = np.linspace(0.0, 1.0, 11)
    >>> fig = plot_move_shaper(res, "move3", {"unshaped": (t, 0.1 * t), "shaped": (t, 0 * t)})
    >>> len(fig.axes), fig.axes[1].get_ylabel()
    (2, '‖tip deflection‖₂ [mm]')
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(9.0, 7.0 if deflections else 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(2 if deflections else 1, 1, 1)
    _draw_prv(ax, result.shaper, result.ranges,
              [f"mode {j + 1}" for j in range(len(result.ranges))], unit)
    ax.set_title(f"{move_name}: contributions r = {np.round(result.contributions, 3).tolist()},"
                 f" {len(result.shaper)} impulses, {result.duration:.3f} s", fontsize="medium")
    if deflections:
        ax2 = fig.add_subplot(2, 1, 2)
        for label, (t, deflection) in deflections.items():
            d = np.asarray(deflection, dtype=float).reshape(len(t), -1)
            ax2.plot(t, 1e3 * np.linalg.norm(d, axis=1), label=label)
        ax2.set_xlabel("t [s]")
        ax2.set_ylabel("‖tip deflection‖₂ [mm]")
        ax2.grid(True, alpha=0.3)
        _outside_legend(ax2)
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------- control (§6.2)

def plot_accessibility(axes: tuple[ArrayLike, ArrayLike], index: ArrayLike,
                       joints: tuple[int, int] = (1, 2), fig: Figure | None = None) -> Figure:
    """Maps of the accessibility indexes, one panel per mode (Fig. 108–110).

    Parameters
    ----------
    axes : (array_like, array_like)
        Grid values [rad] of the two joints.
    index : array_like
        ``(m, len(axes[0]), len(axes[1]))`` from
        :func:`casflex.control.accessibility_map`.
    joints : (int, int)
        0-based indexes of the two joints, as given to
        :func:`casflex.control.accessibility_map` (``(1, 2)``, the default, labels the
        axes q2 and q3).
    fig : matplotlib.figure.Figure, optional
        Figure to draw in (default a new pyplot figure).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> ax = [np.linspace(-3, 3, 4)] * 2
    >>> fig = plot_accessibility(ax, np.ones((2, 4, 4)), joints=(1, 2))
    >>> len(fig.axes), fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()
    (4, 'q3 [deg]', 'q2 [deg]')
    """
    import matplotlib.pyplot as plt

    index = np.asarray(index, dtype=float)
    m = index.shape[0]
    if fig is None:
        # a pyplot figure (unlike the others here): notebooks show it with plt.show()
        fig = plt.figure(figsize=(4.2 * m, 3.6))
    for k in range(m):
        ax = fig.add_subplot(1, m, k + 1)
        mesh = ax.pcolormesh(np.degrees(axes[1]), np.degrees(axes[0]), index[k],
                             shading="auto", cmap="viridis")
        fig.colorbar(mesh, ax=ax)
        ax.set_title(f"a{k + 1} [√kg·m]")
        ax.set_xlabel(f"q{joints[1] + 1} [deg]")
        ax.set_ylabel(f"q{joints[0] + 1} [deg]")
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------- simulation

def plot_result(result: SimulationResult, title: str | None = None) -> Figure:
    """Joint angles, torques, modal amplitudes and tip deflection, one panel each.

    Parameters
    ----------
    result : casflex.simulate.SimulationResult
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.simulate import SimulationResult
    >>> r = SimulationResult(t=np.arange(3.0), q=np.zeros((3, 1)), dq=np.zeros((3, 1)),
    ...                      ddq=np.zeros((3, 1)), tau=np.zeros((3, 1)),
    ...                      delta=np.zeros((3, 2)), ddelta=np.zeros((3, 2)),
    ...                      tip=np.zeros((3, 3)), tip_rigid=np.zeros((3, 3)))
    >>> len(plot_result(r).axes)
    4
    """
    import math

    fig = Figure(figsize=(10, 7), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    t = result.t
    for j in range(result.q.shape[1]):
        axes[0, 0].plot(t, result.q[:, j], label=f"q{j + 1}")
        axes[0, 1].plot(t, result.tau[:, j], label=f"τ{j + 1}")
    for j in range(result.delta.shape[1]):
        axes[1, 0].plot(t, result.delta[:, j], label=f"δ{j + 1}")
    for k, c in enumerate("xyz"):
        axes[1, 1].plot(t, 1e3 * result.tip_deflection[:, k], label=c)
    axes[1, 1].plot(t, 1e3 * np.linalg.norm(result.tip_deflection, axis=1), "k--", lw=0.8,
                    label="‖·‖₂")
    labels = [("joint angle [rad]", axes[0, 0]), ("torque [N m]", axes[0, 1]),
              ("modal amplitude δ [√kg·m]", axes[1, 0]),
              ("tip deflection [mm]", axes[1, 1])]
    for label, ax in labels:
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        if math.isfinite(result.t_move_end):
            ax.axvline(result.t_move_end, color="0.6", lw=0.8, ls=":", label="end of the move")
        ax.legend(loc="best", fontsize="small", ncol=2)
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    if title:
        fig.suptitle(title)
    return fig


# ---------------------------------------------------------------------------- identification

def plot_identification(estimate: ModalEstimate, title: str | None = None) -> Figure:
    """Welch spectrum with the identified modes, and the stabilisation diagram.

    Parameters
    ----------
    estimate : casflex.identification.ModalEstimate
        From :func:`casflex.identification.identify_modes`.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.identification import identify_modes
    >>> t = np.arange(2000) / 200.0
    >>> y = np.exp(-0.3 * t) * np.cos(2 * np.pi * 4.0 * t) + 1e-3 * np.sin(311 * t)
    >>> len(plot_identification(identify_modes(t, y)).axes)
    2
    """
    fig = Figure(figsize=(9, 6), layout="constrained")
    ax, ax2 = fig.subplots(2, 1, sharex=True)
    top = 1.2 * max(estimate.frequency_hz.max(initial=0.0),
                    max((f.max(initial=0.0) for _, f, _, _ in estimate.stabilisation),
                        default=0.0))
    spec = estimate.spectrum
    if spec is not None:
        band = spec.f_hz <= max(top, 1e-9)
        for c, name in enumerate(estimate.channels):
            ax.semilogy(spec.f_hz[band], spec.psd[band, c], lw=0.8, label=name)
    for f in estimate.frequency_hz:
        ax.axvline(f, color="k", lw=0.6, ls="--")
        ax2.axvline(f, color="k", lw=0.6, ls="--")
    ax.set_ylabel("PSD [(m/s²)²/Hz]")
    ax.legend(loc="best", fontsize="small")
    ax.grid(True, alpha=0.3)
    for k, (order, f, _, stable) in enumerate(estimate.stabilisation):
        ax2.plot(f[~stable], np.full((~stable).sum(), order), "x", color="0.6", ms=3,
                 label="not stable" if k == 0 else None)
        ax2.plot(f[stable], np.full(stable.sum(), order), "o", color="C3", ms=3,
                 label="stable" if k == 0 else None)
    if estimate.stabilisation:
        ax2.legend(loc="best", fontsize="small")
    ax2.set_ylabel("model order [–]")
    ax2.set_xlabel("frequency [Hz]")
    ax2.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    return fig


def plot_calibration(result: CalibrationResult, title: str | None = None) -> Figure:
    """Measured and modelled natural frequencies per configuration, before and after a fit.

    Parameters
    ----------
    result : casflex.identification.CalibrationResult
        From :func:`casflex.identification.calibrate`.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.identification import CalibrationResult
    >>> r = CalibrationResult(["a"], np.ones(1), np.ones(1), np.zeros(1), np.eye(1),
    ...                       [True], [""], np.ones((2, 1)), np.full((2, 1), 1.1),
    ...                       np.ones((2, 1)), np.ones(1), 0.0, 3, None)
    >>> len(plot_calibration(r).axes)
    2
    """
    fig = Figure(figsize=(9, 6), layout="constrained")
    ax, ax2 = fig.subplots(2, 1, sharex=True)
    rows = np.arange(1, result.measured_hz.shape[0] + 1)
    for j in range(result.measured_hz.shape[1]):
        c = f"C{j % 10}"
        ax.plot(rows, result.measured_hz[:, j], "o", color=c, label=f"f{j + 1} measured")
        ax.plot(rows, result.before_hz[:, j], "x", color=c, alpha=0.5)
        ax.plot(rows, result.after_hz[:, j], "+", color=c, ms=10)
        ax2.plot(rows, result.residual_before_hz[:, j], "x", color=c, alpha=0.5,
                 label=f"f{j + 1} before the fit")
        ax2.plot(rows, result.residual_hz[:, j], "+-", color=c, ms=10,
                 label=f"f{j + 1} after the fit")
    ax.set_ylabel("frequency [Hz]")
    ax.set_title("o measured, x model before, + model after the fit", fontsize="small")
    ax.legend(loc="best", fontsize="small", ncol=2)
    ax2.axhline(0.0, color="k", lw=0.6)
    ax2.set_ylabel("model − measured [Hz]")
    ax2.legend(loc="best", fontsize="small", ncol=2)
    ax2.set_xlabel("configuration [row of the measurements]")
    ax2.set_xticks(rows)
    for a in (ax, ax2):
        a.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    return fig


# ------------------------------------------------- input shaping: optimality and sampling

def plot_si_optimality(grid_optimum: ArrayLike, polished: ArrayLike,
                       ei_start: ArrayLike | None = None) -> Figure:
    """SI shaper durations of several problems against their grid-LP optimum.

    Parameters
    ----------
    grid_optimum : array_like, shape (p,)
        Duration of the shortest shaper on the LP's time grid of every problem, s.
    polished : array_like, shape (p,)
        Duration of the designed (polished) shaper, s.
    ei_start : array_like, shape (p,), optional
        Duration reached from the convolved EI start, s (NaN where that design failed).

    Returns
    -------
    matplotlib.figure.Figure
        Durations relative to the grid optimum (%), problem by problem, with the ±1 % band.

    Examples
    --------
    >>> fig = plot_si_optimality([0.3, 0.5], [0.299, 0.498], [0.31, float("nan")])
    >>> fig.axes[0].get_ylabel()
    'duration / grid optimum − 1 [%]'
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    ref = np.asarray(grid_optimum, float)
    idx = np.arange(ref.size)
    fig = Figure(figsize=(7.0, 3.8))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.axhspan(-1.0, 1.0, color="0.9", label="±1 %")
    ax.plot(idx, 100.0 * (np.asarray(polished, float) / ref - 1.0), "o",
            label="grid-LP start, polished")
    if ei_start is not None:
        ax.plot(idx, 100.0 * (np.asarray(ei_start, float) / ref - 1.0), "x",
                label="convolved-EI start (§6.1.3)")
    ax.set_xlabel("problem [index]")
    ax.set_ylabel("duration / grid optimum − 1 [%]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    fig.tight_layout()
    return fig


def plot_digital_shaper(analogue: Shaper, digital: Shaper, dt: float) -> Figure:
    """Impulses of an analogue shaper and of its digital twin on a loop's sample grid.

    Parameters
    ----------
    analogue, digital : casflex.shaping.Shaper
        Free impulse times, and impulses on ``k dt``.
    dt : float
        Sample time of the loop, s.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from casflex.shaping import zv
    >>> fig = plot_digital_shaper(zv(10.0), zv(10.0), 1e-3)
    >>> fig.axes[0].get_xlabel()
    't [s]'
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(7.0, 3.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.vlines(analogue.times, 0.0, analogue.amplitudes, colors="C0", lw=3, alpha=0.6,
              label=f"analogue: {len(analogue)} impulses, {analogue.duration:.4f} s")
    ax.vlines(digital.times, 0.0, digital.amplitudes, colors="C1", lw=1.5,
              label=f"on the {1e3 * dt:g} ms grid: {len(digital)} impulses, "
              f"{digital.duration:.4f} s")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("impulse amplitude [–]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------- planning


def plot_plan(comparison: object) -> Figure:
    """Shaped vs planned move: joint angles, torques and tip deflection over time.

    Parameters
    ----------
    comparison : casflex.planning.PlanComparison
        Its ``verification["runs"]["prescribed"]`` and
        ``shaped_verification["run"]`` are the two simulations with the joints on the
        moves (``SimulationResult``).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> from casflex.simulate import SimulationResult
    >>> r = SimulationResult(t=np.arange(3.0), q=np.zeros((3, 1)), dq=np.zeros((3, 1)),
    ...                      ddq=np.zeros((3, 1)), tau=np.zeros((3, 1)),
    ...                      delta=np.zeros((3, 1)), ddelta=np.zeros((3, 1)),
    ...                      tip=np.zeros((3, 3)), tip_rigid=np.zeros((3, 3)))
    >>> c = SimpleNamespace(verification={"runs": {"prescribed": r}},
    ...                     shaped_verification={"run": r},
    ...                     plan=SimpleNamespace(duration=1.0, name="p"),
    ...                     shaped=SimpleNamespace(duration=2.0))
    >>> len(plot_plan(c).axes)
    3
    """
    planned = comparison.verification["runs"]["prescribed"]
    shaped = comparison.shaped_verification["run"]
    fig = Figure(figsize=(10, 8), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for run, style, label, T in ((shaped, "--", "shaped", comparison.shaped.duration),
                                 (planned, "-", "planned", comparison.plan.duration)):
        for j in range(run.q.shape[1]):
            axes[0].plot(run.t, run.q[:, j], style, color=f"C{j}",
                         label=f"q{j + 1} {label}")
            axes[1].plot(run.t, run.tau[:, j], style, color=f"C{j}", lw=0.9,
                         label=f"τ{j + 1} {label}")
        axes[2].plot(run.t, 1e3 * np.linalg.norm(run.tip_deflection, axis=1), style,
                     color="k" if label == "planned" else "0.5", label=f"{label} ({T:.3f} s)")
        for ax in axes:
            ax.axvline(T, color="0.6" if label == "shaped" else "0.2", lw=0.8, ls=":",
                       label=f"end of the {label} move" if ax is axes[2] else None)
    for ax, ylabel in zip(axes, ("joint angle [rad]", "torque [N m]",
                                 "‖tip deflection‖₂ [mm]"), strict=True):
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small", ncol=2)
    axes[2].set_xlabel("t [s] (joints on the move)")
    fig.suptitle(f"{getattr(comparison.plan, 'name', 'plan')}: shaped vs planned")
    return fig
