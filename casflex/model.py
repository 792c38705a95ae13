"""One call from a robot to its configuration-dependent symbolic model.

:func:`build_model` tabulates the tracked, mass-normalised modes over a grid of the joints
that change the structure's shape (:mod:`casflex.modal.tables`, cached on disk), wraps
the table in B-spline interpolants (:class:`TableProvider`) and builds the CasADi model
(:class:`casflex.dynamics.FlexibleModel`) on them.

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

import casadi as ca
import numpy as np

from casflex.dynamics import (
    ConstantProvider,
    FlexibleModel,
    PointwiseProvider,
    rigid_provider,
    zero_entries,
)
from casflex.errors import ModelError

__all__ = ["TableProvider", "default_grid", "build_model", "sensor_quantities",
           "ConstantProvider", "PointwiseProvider", "FlexibleModel", "rigid_provider",
           "zero_entries"]


class TableProvider:
    """The provider interface of :mod:`casflex.dynamics` on top of a :class:`ModalTable`.

    ``function(name)`` returns ``q_shape -> value`` with the value flattened in C order as
    a column vector (the contract of :class:`casflex.dynamics.ConstantProvider`), by
    interpolating the table with ``method`` (B-splines by default, so that the model is
    differentiable and code-generates to C).

    Parameters
    ----------
    table : casflex.modal.tables.ModalTable
    method : {"bspline", "linear"}

    Examples
    --------
    >>> from casflex.modal.tables import build_table
    >>> from casflex.robot import load
    >>> table = build_table(load("problems/arm2link.toml"), np.radians([0, 10, 20, 30]), 1,
    ...                     cache_dir=False, processes=1)
    >>> provider = TableProvider(table)
    >>> provider.shape_joints
    (2,)
    >>> float(provider.function("omega")(np.radians(10)).full().round(3)[0, 0])   # rad/s
    8.901
    """

    def __init__(self, table, method="bspline"):
        self.table = table
        self.method = method
        self.shape_joints = tuple(table.shape_joints)
        self._functions = {}
        self._combined = None

    def zero_entries(self, name):
        """Mask (C order) of the entries of ``name`` that vanish over the whole grid.

        See :func:`casflex.dynamics.zero_entries`.

        Parameters
        ----------
        name : str
            A tabulated quantity (``"omega"``, ``"C1"``, ...).

        Returns
        -------
        numpy.ndarray of bool
            One flag per entry of the value flattened in C order.

        Examples
        --------
        >>> from casflex.modal.tables import build_table
        >>> from casflex.robot import load
        >>> table = build_table(load("problems/arm2link.toml"), np.radians([0, 10, 20, 30]),
        ...                     1, cache_dir=False, processes=1)
        >>> mask = TableProvider(table).zero_entries("C1")   # (1 mode, 2 beams, 4, 4)
        >>> mask.shape, int(mask.sum())
        ((32,), 22)
        """
        from casflex.dynamics import zero_entries

        if name == "omega" and "omega" not in self.table.values:
            data = self.table.omega
        else:
            data = self.table.values[name]
        return zero_entries(data, leading=len(self.table.shape))

    @property
    def names(self):
        """Every quantity the table provides (``"omega"`` included)."""
        return sorted(set(self.table.values) | {"omega"})

    def evaluate(self, q_shape):
        """Every quantity at the symbolic shape-joint values ``q_shape``, from ONE B-spline.

        The nonzero entries of all the quantities are interpolated by a single
        ``casadi.interpolant`` call, so a model (and the sensor models, and every
        derivative CasADi takes of them) evaluates the basis functions once instead of
        once per quantity: 21 lookups become 3 in the EKF step of the Table 8 arm.

        Parameters
        ----------
        q_shape : casadi.SX
            Column of the shape-joint values [rad] (``len(shape_joints)`` rows).

        Returns
        -------
        dict of str to casadi.SX
            Each quantity flattened in C order as a column vector, equal to
            ``function(name)(q_shape)``.

        Examples
        --------
        >>> import casadi as ca
        >>> from casflex.modal.tables import build_table
        >>> from casflex.robot import load
        >>> table = build_table(load("problems/arm2link.toml"), np.radians([0, 10, 20, 30]),
        ...                     1, cache_dir=False, processes=1)
        >>> provider = TableProvider(table)
        >>> x = ca.SX.sym("x")
        >>> values = provider.evaluate(x)
        >>> f = ca.Function("f", [x], [values["C1"]])
        >>> bool(np.allclose(f(0.2).full(), provider.function("C1")(0.2).full(), atol=0))
        True
        """
        if self._combined is None:
            from casflex.modal.tables import ModalTable

            nd = len(self.table.shape)
            parts, layout, start = [], {}, 0
            for name in self.names:
                data = self.table.omega if name == "omega" and "omega" not in \
                    self.table.values else self.table.values[name]
                data = np.asarray(data, dtype=float)
                size = int(np.prod(data.shape[nd:]))
                keep = np.flatnonzero(~self.zero_entries(name))
                layout[name] = (size, keep, start)
                parts.append(data.reshape(self.table.shape + (size,))[..., keep])
                start += keep.size
            flat = np.concatenate(parts, axis=-1) if parts else np.zeros(self.table.shape
                                                                         + (0,))
            joined = ModalTable(grid=self.table.grid, shape_joints=self.table.shape_joints,
                                values={"all": flat}, omega=self.table.omega,
                                periodic=self.table.periodic)
            self._combined = (joined.function("all", method=self.method) if start else None,
                              layout)
        fun, layout = self._combined
        y = fun(q_shape) if fun is not None else None
        out = {}
        for name, (size, keep, start) in layout.items():
            v = ca.SX.zeros(size)
            if keep.size:
                v[keep.tolist()] = y[start:start + keep.size]
            out[name] = v
        return out

    def function(self, name):
        """``casadi.Function`` of the shape-joint vector [rad] → quantity ``name``.

        Parameters
        ----------
        name : str
            A tabulated quantity (``"omega"``, ``"C1"``, ...).

        Returns
        -------
        casadi.Function
            ``name(q_shape) -> value`` flattened in C order as a column vector; entries
            that vanish over the whole grid are exact zeros (not interpolated). Cached
            per name.

        Examples
        --------
        >>> from casflex.modal.tables import build_table
        >>> from casflex.robot import load
        >>> table = build_table(load("problems/arm2link.toml"), np.radians([0, 10, 20, 30]),
        ...                     1, cache_dir=False, processes=1)
        >>> f = TableProvider(table).function("C1")
        >>> f.name_in(), f.size_out(0)
        (['q_shape'], (32, 1))
        >>> int(np.count_nonzero(f(np.radians(15)).full()))   # 22 entries vanish everywhere
        10
        """
        if name in self._functions:
            return self._functions[name]
        x = ca.SX.sym("q_shape", len(self.shape_joints))
        zero = self.zero_entries(name)
        keep = np.flatnonzero(~zero)
        y = ca.SX.zeros(zero.size)
        if keep.size:  # only the entries that do not vanish everywhere are interpolated
            f = self.table.function(name, method=self.method, entries=keep)
            y[keep.tolist()] = f(x)
        self._functions[name] = ca.Function(name, [x], [y], ["q_shape"], [name])
        return self._functions[name]


def default_grid(robot, joints, step=None):
    """A full-turn grid per shape joint [rad]: 1.5° for one joint, 6° for more.

    Parameters
    ----------
    robot : casflex.robot.Robot or None
        Unused (kept for a uniform signature).
    joints : sequence of int
        The shape joints (0-based), one axis each.
    step : float, optional
        Grid step [rad]; a full turn needs at least 8 points.

    Returns
    -------
    list of numpy.ndarray
        One axis per shape joint, from −π (included) to π (excluded) [rad].

    Examples
    --------
    >>> len(default_grid(None, (2,))[0])
    240
    """
    if step is None:
        step = np.radians(1.5) if len(joints) == 1 else np.radians(6.0)
    n = int(round(2.0 * np.pi / step))
    if n < 8:
        raise ModelError(f"grid step {step} rad is too coarse: a full turn needs >= 8 points")
    axis = -np.pi + 2.0 * np.pi * np.arange(n) / n
    return [axis] * len(joints)


def sensor_quantities(robot, q, shapes, points=()):
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


def build_model(robot, n_modes=5, *, step=None, grid=None, points=(), gravity="robot",
                damping_ratio=None, method="bspline", cache_dir=None, client=None,
                processes=None, progress=False, **model_options):
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
        Passed to :class:`casflex.dynamics.FlexibleModel`.
    method : {"bspline", "linear"}
        Interpolation of the tables.
    cache_dir, client, processes, progress
        Passed to :func:`casflex.modal.tables.build_table`.

    Returns
    -------
    model : casflex.dynamics.FlexibleModel
    table : casflex.modal.tables.ModalTable

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
    from casflex.dynamics import FlexibleModel
    from casflex.modal.tables import build_table, shape_joints

    joints = shape_joints(robot)
    if grid is None:
        grid = default_grid(robot, joints, step)
    quantities = functools.partial(sensor_quantities, points=tuple(points)) if points \
        else None
    table = build_table(robot, grid if len(joints) != 1 else grid[0], n_modes,
                        quantities=quantities, cache_dir=cache_dir, client=client,
                        processes=processes, progress=progress, joints=joints)
    model = FlexibleModel(robot, TableProvider(table, method), gravity=gravity,
                          damping_ratio=damping_ratio, **model_options)
    return model, table
