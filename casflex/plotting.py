"""Matplotlib figures for casflex results.

Every function returns a :class:`matplotlib.figure.Figure` and never shows it; save it
with ``fig.savefig(path)``. Figures are built with the object-oriented API so they work
under any backend (the CLI uses Agg).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

__all__ = ["plot_modes", "plot_sweep", "skeleton"]


def skeleton(robot, q):
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


def plot_modes(robot, q, shapes, n_modes=None, scale=None):
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


def plot_sweep(q, omega, joint, tracked=False):
    """Natural frequencies versus one joint angle (dissertation Fig. 25/26).

    Parameters
    ----------
    q : array_like
        (k,) joint values [rad].
    omega : array_like
        (k, m) frequencies [rad/s].
    joint : int
        1-based joint number, for the label.
    tracked : bool
        Whether the columns follow modes (lines) or sorted order (markers).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> fig = plot_sweep([0.0, 0.1], [[1.0, 2.0], [1.1, 2.1]], joint=3)
    >>> fig.axes[0].get_xlabel()
    'q3 [deg]'
    """
    q = np.asarray(q, dtype=float)
    omega = np.asarray(omega, dtype=float)
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for j in range(omega.shape[1]):
        style = dict(lw=1.5) if tracked else dict(ls="none", marker=".", ms=3)
        ax.plot(np.degrees(q), omega[:, j], label=f"mode {j + 1}", **style)
    ax.set_xlabel(f"q{joint} [deg]")
    ax.set_ylabel("natural frequency [rad/s]")
    ax.set_title("tracked modes" if tracked else "sorted natural frequencies")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    return fig


# ---------------------------------------------------------------------------- simulation

__all__ += ["plot_result"]


def plot_result(result, title: str | None = None) -> Figure:
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
                    label="|·|")
    labels = [("joint angle [rad]", axes[0, 0]), ("torque [N m]", axes[0, 1]),
              ("modal amplitude δ [√kg m]", axes[1, 0]),
              ("tip deflection [mm]", axes[1, 1])]
    for label, ax in labels:
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small", ncol=2)
        if math.isfinite(result.t_move_end):
            ax.axvline(result.t_move_end, color="0.6", lw=0.8, ls=":")
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    if title:
        fig.suptitle(title)
    return fig
