"""One call from a robot to its configuration-dependent symbolic model.

:func:`build_model` tabulates the tracked, mass-normalised modes over a grid of the joints
that change the structure's shape (:mod:`casflex.modal.tables`, cached on disk), wraps
the table in B-spline interpolants (:class:`~casflex.model.providers.TableProvider`) and
builds the CasADi model (:class:`~casflex.model.equations.FlexibleModel`) on them.

Examples
--------
>>> from casflex.robot import load
>>> robot = load("problems/arm2link.toml")
>>> model, table = build_model(robot, n_modes=3, step=np.radians(15), cache_dir=False,
...                            processes=1)
>>> table.shape_joints, model.m
((2,), 3)
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.model.equations import FlexibleModel
from casflex.model.providers import TableProvider

if TYPE_CHECKING:
    from casflex.modal.fits import ChebyshevFit
    from casflex.modal.tables import ModalTable
    from casflex.robot import Robot
    from casflex.tmm import ModeShapes

__all__ = ["build_model", "default_grid", "sensor_quantities"]


def default_grid(robot: Robot | None, joints: Sequence[int],
                 step: float | None = None) -> list[np.ndarray]:
    """A grid per shape joint [rad]: 1.5° for one joint, 6° for more; inside joint limits.

    A joint without limits (or whose limits span a full turn or more) gets the full-turn
    axis from −π (included) to π (excluded), which the tables wrap periodically. A limited
    joint gets a uniform axis from its lower to its upper limit, both included, with the
    largest step not above ``step`` (at least 4 points, for the cubic splines).

    Parameters
    ----------
    robot : casflex.robot.Robot or None
        Its ``joint_limits`` bound the axes; ``None``: full turns.
    joints : sequence of int
        The shape joints (0-based), one axis each.
    step : float, optional
        Grid step [rad]; a full turn needs at least 8 points.

    Returns
    -------
    list of numpy.ndarray
        One strictly increasing axis per shape joint [rad].

    Examples
    --------
    >>> len(default_grid(None, (2,))[0])
    240
    >>> import dataclasses
    >>> from casflex.robot import load
    >>> arm = load("problems/arm2link.toml")
    >>> limited = dataclasses.replace(arm, joint_limits=(None, None, (-1.0, 1.0)))
    >>> axis = default_grid(limited, (2,), step=np.radians(6.0))[0]
    >>> axis.size, float(axis[0]), float(axis[-1])
    (21, -1.0, 1.0)
    """
    if step is None:
        step = np.radians(1.5) if len(joints) == 1 else np.radians(6.0)
    n = int(round(2.0 * np.pi / step))
    if n < 8:
        raise ModelError(f"grid step {step} rad is too coarse: a full turn needs >= 8 points")
    full_turn = -np.pi + 2.0 * np.pi * np.arange(n) / n
    limits = (None,) * (max(joints, default=-1) + 1) if robot is None else robot.joint_limits
    axes = []
    for k in joints:
        bounds = limits[k]
        if bounds is None or bounds[1] - bounds[0] >= 2.0 * np.pi:
            axes.append(full_turn)
            continue
        low, high = bounds
        points = max(int(np.ceil((high - low) / step * (1.0 - 1e-12))) + 1, 4)
        axis = np.linspace(low, high, points)
        axis[-1] = high  # the limit itself, not low + (points - 1) * step rounded
        axes.append(axis)
    return axes


def sensor_quantities(robot: Robot, q: ArrayLike, shapes: ModeShapes,
                      points: Sequence[tuple[int, float]] = ()) -> dict[str, np.ndarray]:
    """Model quantities plus mode values at sensor ``points`` (picklable for the pool).

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Joint variables the shapes were computed at [rad].
    shapes : casflex.tmm.ModeShapes
        Tracked, sign-corrected modes (not yet mass-normalised).
    points : sequence of (int, float)
        Sensor points ``(row, s)``: DH row of a flexible link, arc length [m].

    Returns
    -------
    dict of str to numpy.ndarray
        As :func:`casflex.modal.integrals.configuration_quantities`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import modes
    >>> robot = load("problems/arm2link.toml")
    >>> q = [0.0, 0.0, 0.5]
    >>> values = sensor_quantities(robot, q, modes(robot, q, count=1), points=[(3, 1.0)])
    >>> values["point_u"].shape   # (points, modes, 3)
    (1, 1, 3)
    """
    from casflex.modal.integrals import configuration_quantities
    from casflex.modal.normalize import mass_normalize

    return configuration_quantities(robot, q, mass_normalize(robot, shapes),
                                    points=list(points) or None)


def build_model(robot: Robot, n_modes: int = 5, *, step: float | None = None,
                grid: Sequence[ArrayLike] | None = None,
                points: Sequence[tuple[int, float]] = (),
                gravity: ArrayLike | str | None = "robot",
                damping_ratio: float | None = None, method: str = "bspline",
                cache_dir: str | os.PathLike | bool | None = None, client: Any = None,
                processes: int | None = None, progress: bool = False,
                basis: str = "eigen", fit: str | None = None,
                fit_options: dict[str, Any] | None = None,
                **model_options: Any) -> tuple[FlexibleModel, ModalTable | ChebyshevFit]:
    """Tabulate the modes of ``robot`` and build its symbolic model.

    Parameters
    ----------
    robot : casflex.robot.Robot
    n_modes : int
        Number of tracked modes in the model.
    step : float, optional
        Grid step of the shape joints [rad] (see :func:`default_grid`).
    grid : sequence of array_like, optional
        Explicit axes [rad], one per shape joint (overrides ``step``).
    points : sequence of (int, float)
        Sensor points ``(row, s)`` whose mode values are tabulated too (row: DH row index
        of a flexible link, s: arc length from the link's start [m]).
    gravity, damping_ratio, **model_options
        Passed to :class:`~casflex.model.equations.FlexibleModel`.
    method : {"bspline", "linear"}
        Interpolation of the tables.
    cache_dir, client, processes, progress
        Passed to :func:`casflex.modal.tables.build_table`.
    basis : {"eigen", "smooth"}
        Tracked eigenmodes (default), or the smooth basis of clusters of close modes
        (:mod:`casflex.modal.subspace`; the model then uses the full modal stiffness
        block, :class:`~casflex.model.equations.FlexibleModel`).
    fit : {None, "chebyshev"}
        ``None`` (default): the grid and its B-splines. ``"chebyshev"``: tensor Chebyshev
        series of every model term over the joint box instead
        (:func:`casflex.modal.term_fits.fit_model_terms`,
        :class:`~casflex.model.providers.ChebyshevProvider`); ``step``, ``grid``,
        ``method`` and the cache do not apply (the fit is not cached).
    fit_options : dict, optional
        Keywords of :func:`~casflex.modal.term_fits.fit_model_terms` (``box``,
        ``basis``, ``target``, ``omega_target``, ``max_degree``, ``held_out``...).

    Returns
    -------
    model : casflex.model.FlexibleModel
    table : casflex.modal.tables.ModalTable or casflex.modal.fits.ChebyshevFit
        The grid's table, or the fit with ``fit="chebyshev"``.

    Examples
    --------
    A one-mode model tabulated over a small range of the elbow joint (no cache):

    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model, table = build_model(robot, n_modes=1, grid=[np.radians([0, 10, 20, 30])],
    ...                            cache_dir=False, processes=1)
    >>> model.m, table.shape_joints, table.omega.ravel().round(3).tolist()
    (1, (2,), [8.307, 8.901, 9.639, 10.553])
    """
    from casflex.modal.tables import build_table, shape_joints

    joints = shape_joints(robot)
    if grid is None:
        grid = default_grid(robot, joints, step)
    quantities = functools.partial(sensor_quantities, points=tuple(points)) if points \
        else None
    if fit is not None:
        if fit != "chebyshev":
            raise ModelError(f"fit must be None (the grid) or 'chebyshev'; got {fit!r}")
        from casflex.modal.term_fits import fit_model_terms
        from casflex.model.providers import ChebyshevProvider

        options = {"basis": basis, **(fit_options or {})}
        fitted = fit_model_terms(robot, n_modes, quantities=quantities, joints=joints,
                                 processes=processes, progress=progress, **options)
        model = FlexibleModel(robot, ChebyshevProvider(fitted), gravity=gravity,
                              damping_ratio=damping_ratio, **model_options)
        return model, fitted
    table = build_table(robot, grid if len(joints) != 1 else grid[0], n_modes,
                        quantities=quantities, cache_dir=cache_dir, client=client,
                        processes=processes, progress=progress, joints=joints,
                        basis=basis)
    model = FlexibleModel(robot, TableProvider(table, method), gravity=gravity,
                          damping_ratio=damping_ratio, **model_options)
    return model, table
