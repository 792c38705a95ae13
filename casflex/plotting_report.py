"""The figures of a design job's report (:func:`casflex.design.run_design`), drawn from
plain arrays, and the layout helpers every casflex figure uses; part of
:mod:`casflex.plotting`, which re-exports them.

Every function returns a :class:`matplotlib.figure.Figure` and never shows it. Figures
whose layout depends only on their panels (:func:`plot_estimation_error`,
:func:`plot_joint_tracking`) place them with margins fixed in inches
(:func:`margins_in_inches`): no layout engine, so saving draws them once. The others have
none either; the job calls ``fig.tight_layout()`` before saving them (legends outside the
axes are included in its bounding box).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from casflex.errors import ModelError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = ["plot_frequencies_along", "plot_tip_deflection", "plot_estimation_error",
           "plot_accessibility_along", "plot_joint_tracking", "margins_in_inches",
           "outside_legend"]


def margins_in_inches(fig: Figure, rows: int, cols: int, *, left: float, right: float,
                      bottom: float, top: float, wgap: float, hgap: float) -> None:
    """Place a ``rows`` × ``cols`` grid of subplots with fixed margins and gaps: no layout
    engine, so saving the figure draws it once (a layout engine measures every tick label
    in passes of its own, and draws the figure once more before saving).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    rows, cols : int
        The grid of subplots.
    left, right, bottom, top : float
        Margins [in] between the grid and the figure's edges.
    wgap, hgap : float
        Gaps [in] between the columns and between the rows.

    Examples
    --------
    >>> fig = Figure(figsize=(6.0, 4.0))
    >>> axes = fig.subplots(2, 2)
    >>> margins_in_inches(fig, 2, 2, left=1.0, right=0.5, bottom=0.5, top=0.5, wgap=0.5,
    ...                   hgap=1.0)
    >>> [round(float(v), 6) for v in axes[1, 0].get_position().bounds]  # 1 in left, 0.5 up
    [0.166667, 0.125, 0.333333, 0.25]
    """
    width, height = fig.get_size_inches()
    panel_w = (width - left - right - (cols - 1) * wgap) / cols
    panel_h = (height - bottom - top - (rows - 1) * hgap) / rows
    fig.subplots_adjust(left=left / width, right=1.0 - right / width,
                        bottom=bottom / height, top=1.0 - top / height,
                        wspace=wgap / panel_w, hspace=hgap / panel_h)


def outside_legend(ax, **kwargs):
    """A legend to the right of the axes, where it cannot cover data.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    **kwargs
        Further keywords of ``ax.legend`` (``handles=`` ...).

    Returns
    -------
    matplotlib.legend.Legend

    Examples
    --------
    >>> ax = Figure().add_subplot()
    >>> _ = ax.plot([0, 1], [0, 1], label="a")
    >>> outside_legend(ax).get_texts()[0].get_text()
    'a'
    """
    return ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0,
                     fontsize="small", **kwargs)


def plot_frequencies_along(t: ArrayLike, omega: ArrayLike, move_name: str, *,
                           ranges: Sequence[tuple[float, float]] | None = None,
                           events: Mapping[str, float] | None = None) -> Figure:
    """Natural frequencies of every mode along a move, with the shaper's design ranges.

    Parameters
    ----------
    t : array_like
        (k,) times [s], e.g. the whole simulated interval of the move.
    omega : array_like
        (k, m) natural frequencies [rad/s].
    move_name : str
        Name of the move, for the title.
    ranges : sequence of (float, float), optional
        ``(omega_min, omega_max)`` [rad/s] of every mode's design range, shaded in the
        mode's colour.
    events : mapping of str to float, optional
        Label -> time [s] of instants marked by vertical lines (e.g. the end of the move).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> fig = plot_frequencies_along([0.0, 1.0], [[8.3, 12.0], [8.9, 12.4]], "move1",
    ...                              ranges=[(8.0, 9.2), (11.8, 12.6)],
    ...                              events={"end of the move": 0.8})
    >>> fig.axes[0].get_ylabel(), fig.axes[0].get_title()
    ('natural frequency [rad/s]', 'natural frequencies along move1')
    """
    from matplotlib.patches import Patch

    omega = np.asarray(omega, dtype=float)
    fig = Figure(figsize=(7.4, 3.8))
    ax = fig.add_subplot()
    for j in range(omega.shape[1]):
        ax.plot(t, omega[:, j], color=f"C{j}", label=f"mode {j + 1}")
    for j, (lo, hi) in enumerate(ranges or ()):
        ax.axhspan(lo, hi, color=f"C{j}", alpha=0.15, lw=0)
    for (label, time), style in zip((events or {}).items(), (":", "--", "-."), strict=False):
        ax.axvline(time, color="0.35", ls=style, lw=1, label=f"{label} ({time:.3g} s)")
    handles, _ = ax.get_legend_handles_labels()
    if ranges:
        handles.append(Patch(color="0.5", alpha=0.3,
                             label="design range of the shaper\n(shaded in the mode's colour)"))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("natural frequency [rad/s]")
    ax.set_title(f"natural frequencies along {move_name}")
    ax.grid(True, alpha=0.3)
    outside_legend(ax, handles=handles)
    return fig


def plot_tip_deflection(runs: Sequence[tuple[str, ArrayLike, ArrayLike]], move_end: float, *,
                        tip: str = "end effector (origin of the last DH frame)",
                        move_label: str = "end of the shaped move") -> Figure:
    """Euclidean norm of the tip deflection of several runs of a move.

    The tip deflection is the position of the tip of the flexible arm minus that of the
    rigid arm at the same joint angles.

    Parameters
    ----------
    runs : sequence of (str, array_like, array_like)
        ``(label, t, tip_deflection)``: times (k,) [s] and tip deflection vectors (k, 3)
        [m] of every run.
    move_end : float
        Time the (shaped) move ends [s], marked by a dotted line.
    tip : str, optional
        Which point is the tip, for the title.
    move_label : str, optional
        Legend label of the dotted line.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> fig = plot_tip_deflection([("unshaped", [0.0, 1.0], [[0, 0, 0], [0.01, 0, 0]])], 0.5)
    >>> fig.axes[0].lines[0].get_ydata().tolist()   # mm
    [0.0, 10.0]
    >>> fig.axes[0].lines[1].get_label()
    'end of the shaped move (0.5 s)'
    """
    fig = Figure(figsize=(7.4, 3.8))
    ax = fig.add_subplot()
    for label, t, deflection in runs:
        ax.plot(t, 1e3 * np.linalg.norm(np.asarray(deflection, dtype=float), axis=1),
                lw=1.0, label=label)
    ax.axvline(move_end, color="0.35", ls=":", lw=1, label=f"{move_label} ({move_end:.3g} s)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("‖tip deflection‖₂ [mm]")
    ax.set_title(f"tip deflection (flexible − rigid arm at the same joints)\n"
                 f"tip: {tip}", fontsize="medium")
    ax.grid(True, alpha=0.3)
    outside_legend(ax)
    return fig


def plot_estimation_error(t: ArrayLike, delta: ArrayLike, ddelta: ArrayLike,
                          delta_error: ArrayLike, ddelta_error: ArrayLike) -> Figure:
    """True modal states, their estimates and the estimation errors, mode by mode.

    One row per mode; the left column shows δ, the right δ̇. Each panel draws the true
    state, the estimate and the error ``estimate − true`` on the same axis, so the error
    is seen against the scale of the state; its title gives the ratio of the RMS of the
    state to the RMS of the error.

    Parameters
    ----------
    t : array_like
        (k,) times [s].
    delta, ddelta : array_like
        (k, m) true modal amplitudes [√kg·m] and their rates [√kg·m/s].
    delta_error, ddelta_error : array_like
        (k, m) estimation errors (estimate − true) of the same [√kg·m, √kg·m/s].

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> t = np.linspace(0.0, 1.0, 5)
    >>> x = np.column_stack([np.sin(t), np.cos(t)])
    >>> fig = plot_estimation_error(t, x, x, 0.01 * x, 0.1 * x)
    >>> len(fig.axes), fig.axes[1].get_title()
    (4, 'δ̇1: RMS state / RMS error = 10')
    """
    t = np.asarray(t, dtype=float)
    m = np.asarray(delta).shape[1]
    fig = Figure(figsize=(9.0, 1.2 + 2.0 * m))
    axes = fig.subplots(m, 2, sharex=True, squeeze=False)
    # margins fixed in inches (as tight_layout chose them for three modes; the right one
    # holds the key): saving then draws once, 0.2-0.3 s less CPU for the design job
    margins_in_inches(fig, m, 2, left=1.06, right=1.16, bottom=0.59, top=0.64, wgap=1.0,
                      hgap=0.4)
    columns = (("δ", "√kg·m", delta, delta_error), ("δ̇", "√kg·m/s", ddelta, ddelta_error))
    for c, (name, unit, true, error) in enumerate(columns):
        true = np.asarray(true, dtype=float)
        error = np.asarray(error, dtype=float)
        for j in range(m):
            ax = axes[j, c]
            ax.plot(t, true[:, j], color="k", lw=1.4, label="true")
            ax.plot(t, true[:, j] + error[:, j], color="C1", lw=0.8, ls="--",
                    label="estimate")
            ax.plot(t, error[:, j], color="C3", lw=0.8, label="error")
            rms_error = np.sqrt(np.mean(error[:, j] ** 2))
            ratio = np.sqrt(np.mean(true[:, j] ** 2)) / rms_error if rms_error > 0 else np.inf
            ax.set_title(f"{name}{j + 1}: RMS state / RMS error = {ratio:.3g}",
                         fontsize="small", color="C3" if ratio < 10.0 else "k")
            ax.set_ylabel(f"{name}{j + 1} [{unit}]")
            ax.grid(True, alpha=0.3)
        axes[-1, c].set_xlabel("t [s]")
    outside_legend(axes[0, -1])   # one key for every panel
    fig.suptitle("EKF in the closed loop: true state, estimate and error "
                 "(ratios below 10 in red)", fontsize="medium")
    return fig


def plot_accessibility_along(t: ArrayLike, accessibility: ArrayLike) -> Figure:
    """Modal accessibility along a move (dissertation eq. 204).

    Parameters
    ----------
    t : array_like
        (k,) times [s].
    accessibility : array_like
        (k, m) accessibility of every mode [√kg·m].

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> fig = plot_accessibility_along([0.0, 1.0], [[0.2, 0.1], [0.3, 0.1]])
    >>> [line.get_label() for line in fig.axes[0].lines]
    ['a1', 'a2']
    """
    accessibility = np.asarray(accessibility)
    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    for j in range(accessibility.shape[1]):
        ax.plot(t, accessibility[:, j], label=f"a{j + 1}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("accessibility [√kg·m]")
    ax.set_title("modal accessibility along the shaped move (eq. 204)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    return fig


# ------------------------------------------- joint tracking of every run (issue 18, the
# closed loop explained)


def plot_joint_tracking(runs: Sequence[tuple[str, ArrayLike, ArrayLike, ArrayLike,
                                             ArrayLike]],
                        move_end: float | Sequence[float] | None = None) -> Figure:
    """Joint angles against their plan, tracking errors and torques of several runs.

    One row per run, three panels: the joint angles ``q`` (solid) over the planned
    ``q_d`` (dashed), the tracking error ``q − q_d`` and the joint torques ``τ``; one
    colour per joint (q1, q2, … are 1-based, as in the dissertation).

    Parameters
    ----------
    runs : sequence of (str, array_like, array_like, array_like, array_like)
        ``(label, t, q, qd, tau)``: times (k,) [s], joint angles and their plan (k, n)
        [rad], torques (k, n) [N m].
    move_end : float or sequence of float, optional
        End of the move [s], marked by a dotted line: one for every run, or one per run.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> t = np.linspace(0.0, 1.0, 5)
    >>> q = np.column_stack([t, -t])
    >>> fig = plot_joint_tracking([("run", t, q, q + 0.01, 0.1 * q)], move_end=0.8)
    >>> len(fig.axes), fig.axes[1].get_ylabel(), fig.axes[0].get_ylabel().split()
    (3, 'q − q_d [rad]', ['run', 'q', '[rad]'])
    """
    if not runs:
        raise ModelError("plot_joint_tracking: give at least one run")
    # margins fixed in inches instead of a layout engine: constrained layout measured every
    # tick label twice more than the drawing does (its passes and a draw before the one
    # saved), the largest part of the design job's figures (issue 17)
    fig = Figure(figsize=(12, 2.6 * len(runs) + 0.6))
    axes = np.atleast_2d(fig.subplots(len(runs), 3, sharex=True))
    margins_in_inches(fig, len(runs), 3, left=1.0, right=0.1, bottom=0.55, top=0.3,
                       wgap=0.95, hgap=0.38)
    ends = [move_end] * len(runs) if move_end is None or np.ndim(move_end) == 0 \
        else list(move_end)
    if len(ends) != len(runs):
        raise ModelError(f"plot_joint_tracking: {len(ends)} move ends for {len(runs)} runs")
    for row, (label, t, q, qd, tau), end in zip(axes, runs, ends, strict=True):
        q, qd, tau = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, tau))
        error = q - qd
        for j in range(q.shape[1]):
            row[0].plot(t, q[:, j], color=f"C{j}", lw=1.0, label=f"q{j + 1}")
            row[0].plot(t, qd[:, j], "--", color=f"C{j}", lw=0.9, alpha=0.8)
            row[1].plot(t, error[:, j], color=f"C{j}", lw=1.0, label=f"q{j + 1}")
            row[2].plot(t, tau[:, j], color=f"C{j}", lw=0.8, label=f"τ{j + 1}")
        peak = float(np.max(np.abs(error))) if error.size else 0.0
        # at the top of the axes (y given: not moved over tick labels or an offset text,
        # which these panels do not have there; the error panel's may have an offset)
        row[0].set_title("joint angles (dashed: plan)", fontsize=9, y=1.0)
        row[1].set_title(f"tracking error, max |q − q_d| = {peak:.3g} rad", fontsize=9)
        if peak == 0.0:
            row[1].text(0.5, 0.7, "q = q_d: joints on the plan", transform=row[1].transAxes,
                        ha="center", va="center", fontsize=9, color="0.3")
        row[2].set_title("joint torques", fontsize=9, y=1.0)
        for ax, ylabel in zip(row, (f"{label}\nq [rad]", "q − q_d [rad]", "τ [N m]"),
                              strict=True):
            ax.set_ylabel(ylabel)
            ax.grid(True, alpha=0.3)
            if end is not None:
                ax.axvline(end, color="0.4", lw=0.8, ls=":")
        row[0].legend(fontsize="small", loc="best")
        row[2].legend(fontsize="small", loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]" + ("" if move_end is None else " (dotted: end of the move)"))
    return fig
