"""Providers: where a :class:`~casflex.model.equations.FlexibleModel` gets its modal
quantities from.

A provider has ``shape_joints`` (indices into ``q`` of the joints the modal quantities
depend on) and ``function(name) -> casadi.Function`` mapping the vector of those joint
values to the quantity ``name`` of :func:`casflex.modal.integrals.configuration_quantities`,
flattened in C (row-major) order as a column vector. It may also report the entries that
vanish everywhere (``zero_entries(name)``) and evaluate every quantity at once
(``evaluate(q_shape)``).

* :class:`ConstantProvider`: quantities that do not change with the configuration;
* :class:`PointwiseProvider`: the quantities of one configuration, computed with the TMM;
* :func:`rigid_provider`: no modes at all (the rigid-body model);
* :class:`TableProvider`: B-spline interpolants of a modal table over the shape joints
  (what :func:`casflex.model.build_model` uses);
* :class:`ChebyshevProvider`: tensor Chebyshev series of the model terms over the joint
  box (:func:`casflex.modal.term_fits.fit_model_terms`; ``build_model(fit="chebyshev")``);
* :func:`zero_entries`: the entries of a quantity that are zero wherever it is known.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.errors import ModelError
from casflex.modal.integrals import configuration_quantities, quantity_shapes

if TYPE_CHECKING:
    from casflex.modal.fits import ChebyshevFit
    from casflex.modal.tables import ModalTable
    from casflex.robot import Robot

__all__ = ["ConstantProvider", "PointwiseProvider", "TableProvider", "ChebyshevProvider",
           "rigid_provider", "zero_entries"]


ZERO_TOLERANCE = 1e-12


def zero_entries(values: ArrayLike, leading: int = 0) -> np.ndarray:
    """Entries of a quantity that are zero wherever it is known, as a flat C-order mask.

    An entry counts as zero when its magnitude never exceeds ``ZERO_TOLERANCE`` (1e-12)
    times the largest magnitude of the whole quantity: structural zeros (a planar mode's
    out-of-plane displacement, the translational row of a pseudo-inertia) come out of the
    transfer-matrix solution as round-off of that size. The model replaces them by
    constant zeros, which removes the products they feed from the symbolic expressions;
    the change this makes is below the tables' own accuracy.

    Parameters
    ----------
    values : array_like
        The quantity, with ``leading`` grid axes first.
    leading : int
        Number of leading axes (grid points) to reduce over.

    Examples
    --------
    >>> zero_entries([[1.0, 0.0], [2.0, 1e-15]], leading=1)
    array([False,  True])
    """
    v = np.abs(np.asarray(values, dtype=float))
    if v.size == 0:
        return np.zeros(int(np.prod(v.shape[leading:])), dtype=bool)
    peak = v.reshape(int(np.prod(v.shape[:leading])), -1).max(axis=0)
    return peak <= ZERO_TOLERANCE * v.max()


class ConstantProvider:
    """Modal quantities that do not change with the configuration.

    Parameters
    ----------
    quantities : dict of str to array_like
        As returned by :func:`casflex.modal.integrals.configuration_quantities`.
    shape_joints : sequence of int
        0-based joint indexes the (constant) functions take as input.

    Examples
    --------
    >>> p = ConstantProvider({"omega": [2.0, 3.0]}, shape_joints=(2,))
    >>> p.function("omega")([0.1])
    DM([2, 3])
    """

    def __init__(self, quantities: Mapping[str, ArrayLike],
                 shape_joints: Sequence[int] = ()) -> None:
        self.quantities = {k: np.asarray(v, dtype=float) for k, v in quantities.items()}
        self.shape_joints = tuple(int(j) for j in shape_joints)

    @property
    def names(self) -> list[str]:
        """Every quantity the provider holds (a model uses ``stiffness`` when present)."""
        return sorted(self.quantities)

    def zero_entries(self, name: str) -> np.ndarray:
        """Mask (C order) of the entries of ``name`` that vanish (see :func:`zero_entries`).

        Parameters
        ----------
        name : str
            A quantity of :func:`casflex.modal.integrals.configuration_quantities`.

        Examples
        --------
        >>> ConstantProvider({"omega": [2.0, 0.0]}).zero_entries("omega").tolist()
        [False, True]
        """
        return zero_entries(self.quantities[name])

    def function(self, name: str) -> ca.Function:
        """casadi.Function ``q_shape -> name`` (C-order flattened array, column vector).

        Parameters
        ----------
        name : str
            A quantity of :func:`casflex.modal.integrals.configuration_quantities`.

        Examples
        --------
        >>> p = ConstantProvider({"end_u": np.ones((1, 2, 3))}, shape_joints=(2,))
        >>> p.function("end_u").size1_out(0)
        6
        """
        if name not in self.quantities:
            raise ModelError(f"provider has no quantity {name!r}; it has "
                             f"{sorted(self.quantities)}")
        x = ca.SX.sym("q_shape", len(self.shape_joints))
        v = self.quantities[name].ravel()
        out = ca.DM(v) if v.size else ca.DM.zeros(0, 1)
        return ca.Function(name, [x], [out], ["q_shape"], [name])


class PointwiseProvider(ConstantProvider):
    """Quantities of one configuration, computed with the TMM (for tests and studies).

    Parameters
    ----------
    robot : casflex.robot.Robot
    q : array_like
        Configuration [rad] at which the structure's shape is frozen.
    count : int
        Number of modes.
    points : sequence of (int, float), optional
        Sensor points (see :func:`~casflex.modal.integrals.configuration_quantities`).
    shape_joints : sequence of int
        0-based joint indexes reported as inputs (the values do not depend on them).

    Examples
    --------
    >>> from casflex.robot import load
    >>> p = PointwiseProvider(load("problems/arm2link.toml"), [0.0, 0.0, 0.5], count=2)
    >>> np.asarray(p.function("omega")([])).ravel().round(2)
    array([10.42, 15.11])
    """

    def __init__(self, robot: Robot, q: ArrayLike, count: int = 5,
                 points: Sequence[tuple[int, float]] | None = None,
                 shape_joints: Sequence[int] = ()) -> None:
        from casflex.modal.normalize import mass_normalize
        from casflex.tmm import modes

        shapes = mass_normalize(robot, modes(robot, q, count=count))
        self.shapes = shapes
        super().__init__(configuration_quantities(robot, q, shapes, points=points),
                         shape_joints)


def rigid_provider(robot: Robot) -> ConstantProvider:
    """A provider with zero modes: the model reduces to the rigid-body dynamics.

    Parameters
    ----------
    robot : casflex.robot.Robot

    Examples
    --------
    >>> from casflex.robot import load
    >>> rigid_provider(load("problems/arm2link.toml")).function("C2").size1_out(0)
    0
    """
    return ConstantProvider({k: np.zeros(s) for k, s in quantity_shapes(robot, 0).items()})


class TableProvider:
    """The provider interface on top of a :class:`~casflex.modal.tables.ModalTable`.

    ``function(name)`` returns ``q_shape -> value`` with the value flattened in C order as
    a column vector (the contract of :class:`ConstantProvider`), by
    interpolating the table with ``method`` (B-splines by default, so that the model is
    differentiable and code-generates to C).

    Parameters
    ----------
    table : casflex.modal.tables.ModalTable
    method : {"bspline", "linear"}
    lookup : {"interpolant", "local", "static"}
        How a one-axis B-spline table is read (:meth:`casflex.modal.tables.ModalTable.
        function`): ``casadi.interpolant`` (default), or the same spline evaluated
        locally with one coefficient table shared by its derivatives
        (:func:`casflex.modal.local_bspline_function`; ``"static"`` keeps that table out
        of the declared work memory, what the model's C bundle uses).

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

    def __init__(self, table: ModalTable, method: str = "bspline",
                 lookup: str = "interpolant") -> None:
        if lookup not in ("interpolant", "local", "static"):
            raise ModelError(f"lookup must be 'interpolant', 'local' or 'static'; got "
                             f"{lookup!r}")
        self.table = table
        self.method = method
        self.lookup = lookup
        self.shape_joints = tuple(table.shape_joints)
        self._functions = {}
        self._combined = None

    def zero_entries(self, name: str) -> np.ndarray:
        """Mask (C order) of the entries of ``name`` that vanish over the whole grid.

        See :func:`zero_entries`.

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
        if name == "omega" and "omega" not in self.table.values:
            data = self.table.omega
        else:
            data = self.table.values[name]
        return zero_entries(data, leading=len(self.table.shape))

    @property
    def names(self) -> list[str]:
        """Every quantity the table provides (``"omega"`` included)."""
        return sorted(set(self.table.values) | {"omega"})

    def evaluate(self, q_shape: ca.SX, names: Sequence[str] | None = None
                 ) -> dict[str, ca.SX]:
        """Every quantity at the symbolic shape-joint values ``q_shape``, from ONE B-spline.

        The nonzero entries of all the quantities are interpolated by a single
        ``casadi.interpolant`` call, so a model (and the sensor models, and every
        derivative CasADi takes of them) evaluates the basis functions once instead of
        once per quantity: 21 lookups become 3 in the EKF step of the Table 8 arm.

        Parameters
        ----------
        q_shape : casadi.SX
            Column of the shape-joint values [rad] (``len(shape_joints)`` rows).
        names : sequence of str, optional
            The quantities to interpolate (default: all of :attr:`names`); the others
            stay out of the spline (the B-spline computes every output it holds).

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
        wanted = tuple(sorted(self.names if names is None else set(names)))
        unknown = set(wanted) - set(self.names)
        if unknown:
            raise ModelError(f"the table has no quantities {sorted(unknown)}; it has "
                             f"{self.names}")
        if self._combined is None or self._combined[2] != wanted:
            from casflex.modal.tables import ModalTable

            nd = len(self.table.shape)
            parts, layout, start = [], {}, 0
            for name in wanted:
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
            self._combined = (joined.function("all", method=self.method,
                                              lookup=self.lookup) if start else None,
                              layout, wanted)
        fun, layout, _ = self._combined
        return _scatter(fun(q_shape) if fun is not None else None, layout)

    def function(self, name: str) -> ca.Function:
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
            f = self.table.function(name, method=self.method, entries=keep,
                                    lookup=self.lookup)
            y[keep.tolist()] = f(x)
        self._functions[name] = ca.Function(name, [x], [y], ["q_shape"], [name])
        return self._functions[name]


class ChebyshevProvider:
    """The provider interface on top of a :class:`~casflex.modal.fits.ChebyshevFit` of the
    model terms (:func:`~casflex.modal.term_fits.fit_model_terms`).

    ``function(name)`` returns ``q_shape -> value`` flattened in C order as a column vector
    (the contract of :class:`ConstantProvider`): a polynomial in the shape joints, so the
    model stays a CasADi expression (derivatives, C code) without any table. Axes whose
    fit spans a full turn and closes up (``fit.info["periodic"]``) are wrapped into the
    box (``atan2(sin, cos)``); on the others the polynomial outside the box is an
    extrapolation, not a fit.

    Parameters
    ----------
    fit : casflex.modal.fits.ChebyshevFit
        With the model terms (``fit_model_terms``), not only ω.

    Examples
    --------
    >>> import dataclasses
    >>> from casflex.modal import fit_model_terms
    >>> from casflex.robot import load
    >>> arm = load("problems/arm2link.toml")
    >>> arm = dataclasses.replace(arm, joint_limits=(None, None, (0.2, 0.6)))
    >>> provider = ChebyshevProvider(fit_model_terms(arm, 1, processes=1))
    >>> provider.shape_joints, round(float(provider.function("omega")(0.4)), 3)   # rad/s
    ((2,), 9.886)
    """

    def __init__(self, fit: ChebyshevFit) -> None:
        missing = {"C1", "C2", "omega"} - set(fit.coefficients)
        if missing:
            raise ModelError(f"the fit has no model terms {sorted(missing)} (fit it with "
                             "casflex.modal.fit_model_terms)")
        self.fit = fit
        self.shape_joints = tuple(fit.shape_joints)
        self._functions = {}
        self._combined = None

    @property
    def names(self) -> list[str]:
        """Every quantity the fit provides."""
        return sorted(self.fit.coefficients)

    def zero_entries(self, name: str) -> np.ndarray:
        """Mask (C order) of the entries of ``name`` whose coefficients all vanish.

        Parameters
        ----------
        name : str
            A fitted quantity (``"omega"``, ``"C1"``, ...).

        Returns
        -------
        numpy.ndarray of bool

        Examples
        --------
        >>> from casflex.modal import ChebyshevFit
        >>> fit = ChebyshevFit(box=((0.0, 1.0),), shape_joints=(2,), degrees=(1,),
        ...                    clusters=((0,),), coefficients={
        ...                        "omega": np.ones((2, 1)), "C1": np.zeros((2, 1, 1, 4, 4)),
        ...                        "C2": np.zeros((2, 1, 1, 1, 4, 4))})
        >>> int(ChebyshevProvider(fit).zero_entries("C1").sum())
        16
        """
        return zero_entries(self._coefficients(name), leading=len(self.fit.box))

    def _coefficients(self, name):
        if name not in self.fit.coefficients:
            raise ModelError(f"the fit has no quantity {name!r}; it has {self.names}")
        return np.asarray(self.fit.coefficients[name], dtype=float)

    def _wrapped(self, q_shape):
        """The shape joints mapped into the box on periodic axes."""
        periodic = self.fit.info.get("periodic") or [False] * len(self.fit.box)
        parts = []
        for ax, (lo, hi) in enumerate(self.fit.box):
            x = q_shape[ax]
            if periodic[ax]:
                mid = 0.5 * (lo + hi)
                x = mid + ca.atan2(ca.sin(x - mid), ca.cos(x - mid))
            parts.append(x)
        return ca.vertcat(*parts)

    def _polynomial(self, names):
        """One Chebyshev series of the nonzero entries of ``names``, and their layout."""
        from casflex.modal.fits import ChebyshevFit

        nd = len(self.fit.box)
        parts, layout, start = [], {}, 0
        for name in names:
            coef = self._coefficients(name)
            size = int(np.prod(coef.shape[nd:]))
            keep = np.flatnonzero(~self.zero_entries(name))
            layout[name] = (size, keep, start)
            parts.append(coef.reshape(coef.shape[:nd] + (size,))[..., keep])
            start += keep.size
        if not start:
            return None, layout
        joined = ChebyshevFit(box=self.fit.box, shape_joints=self.fit.shape_joints,
                              degrees=self.fit.degrees, clusters=self.fit.clusters,
                              coefficients={"all": np.concatenate(parts, axis=-1)})
        return joined.function("all"), layout

    def evaluate(self, q_shape: ca.SX, names: Sequence[str] | None = None
                 ) -> dict[str, ca.SX]:
        """Every quantity at the symbolic shape-joint values, from ONE series evaluation.

        Parameters
        ----------
        q_shape : casadi.SX
            Column of the shape-joint values [rad].
        names : sequence of str, optional
            The quantities wanted (default all).

        Returns
        -------
        dict of str to casadi.SX
            Each quantity flattened in C order, equal to ``function(name)(q_shape)``.

        Examples
        --------
        >>> from casflex.modal import ChebyshevFit
        >>> fit = ChebyshevFit(box=((0.0, 1.0),), shape_joints=(2,), degrees=(1,),
        ...                    clusters=((0,),), coefficients={
        ...                        "omega": np.array([[5.0], [1.0]]),
        ...                        "C1": np.ones((2, 1, 1, 4, 4)),
        ...                        "C2": np.ones((2, 1, 1, 1, 4, 4))})
        >>> x = ca.SX.sym("x")
        >>> out = ChebyshevProvider(fit).evaluate(x, ["omega"])
        >>> float(ca.Function("f", [x], [out["omega"]])(1.0))
        6.0
        """
        wanted = tuple(sorted(self.names if names is None else set(names)))
        if self._combined is None or self._combined[2] != wanted:
            fun, layout = self._polynomial(wanted)
            self._combined = (fun, layout, wanted)
        fun, layout, _ = self._combined
        return _scatter(fun(self._wrapped(q_shape)) if fun is not None else None, layout)

    def function(self, name: str) -> ca.Function:
        """``casadi.Function`` of the shape-joint vector [rad] → quantity ``name``.

        Parameters
        ----------
        name : str
            A fitted quantity.

        Returns
        -------
        casadi.Function
            ``name(q_shape) -> value`` flattened in C order as a column vector; entries
            whose coefficients all vanish are exact zeros. Cached per name.

        Examples
        --------
        >>> from casflex.modal import ChebyshevFit
        >>> fit = ChebyshevFit(box=((0.0, 1.0),), shape_joints=(2,), degrees=(1,),
        ...                    clusters=((0,),), coefficients={
        ...                        "omega": np.array([[5.0], [1.0]]),
        ...                        "C1": np.ones((2, 1, 1, 4, 4)),
        ...                        "C2": np.ones((2, 1, 1, 1, 4, 4))})
        >>> ChebyshevProvider(fit).function("C1").size_out(0)
        (16, 1)
        """
        if name not in self._functions:
            x = ca.SX.sym("q_shape", len(self.shape_joints))
            value = self.evaluate(x, [name])[name]
            self._combined = None  # the next evaluate() builds its own joint series
            self._functions[name] = ca.Function(name, [x], [value], ["q_shape"], [name])
        return self._functions[name]


def _scatter(y, layout):
    """The quantities of one combined evaluation ``y``: ``layout[name] = (size, kept
    entries, start in y)``; entries left out (zero everywhere) are structural zeros."""
    out = {}
    for name, (size, keep, start) in layout.items():
        v = ca.SX.zeros(size)
        if keep.size:
            v[keep.tolist()] = y[start:start + keep.size]
        out[name] = v
    return out
