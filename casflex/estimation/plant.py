"""The flexible plant of the estimator: the model's flexible rows expanded in Δ and
tabulated (dissertation §5.4, eq. 157–162).

The flexible rows of the model, ``M_δq q̈ + M_δδ δ̈ + (C Ẋ)_δ + G_δ + D δ̇ = 0``, solved
for ``δ̈`` (:attr:`casflex.model.FlexibleModel.prescribed_dddelta`,
:func:`exact_plant_function`), are a large expression. The filter uses its **expansion in
Δ about Δ = 0 to second order** (default; ``order=1`` gives the dissertation's linear
time-varying plant, eq. 159, 162):

``δ̈ = r₀(u) + J_δ(u) δ + J_δ̇(u) δ̇ + Σ_{a≤b} W_ab(u) x_a x_b``,  ``x = [δ; δ̇]``

with ``u = [q; q̇; q̈]`` the measured joint motion. The second-order terms (centripetal
terms of the flexible rates, the change of the mass matrix and of the Coriolis coupling
with δ) are small against δ̈ but matter for the velocity estimates of an arm whose tip
deflects by several cm (the Table 8 arm on the Table 9 moves).

Every coefficient is a polynomial of degree ≤ 2 in ``(q̇, q̈)`` — monomials ``1, q̈_a,
q̇_a, q̇_a q̇_b`` — whose coefficients depend on ``q`` only. :func:`tabulate_plant`
extracts them from the model (polynomial interpolation over 1 + 2n + n(n+1)/2 designs of
``(q̇, q̈)``; the terms in Δ from the rows' exact Jacobian and Hessian at Δ = 0, or from
central and even second differences), and stores them over
the model's shape joints as periodic cubic B-splines (the model's own modal tables are
B-splines on the same kind of grid) and as Fourier series of degree ``K`` in the other
joints they depend on (rigid-body kinematics make that dependence a trigonometric
polynomial; the degree is checked). Joints the coefficients do not depend on (e.g. a base
joint about the gravity axis) are detected and left out. The result
(:class:`FlexiblePlant`) is far smaller than the exact rows and their Jacobian.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> robot = load("problems/arm2link.toml")
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
>>> plant = tabulate_plant(model, cache_dir=False)
>>> plant.order, plant.n, plant.m
(2, 3, 1)
"""

from __future__ import annotations

import itertools
import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._cache import (
    cache_root,
    digest,
    load_verified,
    remove_stale_files,
    save_verified,
    source_digest,
)
from casflex._validate import choice
from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.modal.tables import ModalTable
    from casflex.model import FlexibleModel

__all__ = ["FlexiblePlant", "tabulate_plant", "exact_plant_function"]


def exact_plant_function(model: FlexibleModel) -> ca.Function:
    """``casadi.Function`` ``(u, x) -> dddelta``: the model's flexible rows solved for δ̈.

    Exact but large (the reference the tabulated plant is checked against).

    Parameters
    ----------
    model : casflex.model.FlexibleModel

    Returns
    -------
    casadi.Function
        ``flex_exact (u, x) -> dddelta`` with ``u = [q; q̇; q̈]`` (3n) and
        ``x = [δ; δ̇]`` (2m); the model's ``prescribed_dddelta`` (m).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> f = exact_plant_function(model)
    >>> round(float(f(np.zeros(9), [1e-3, 0.0])), 6)   # -ω₁² δ₁ at rest (ω₁ = 8.31 rad/s)
    -0.069012
    """
    u = ca.vertcat(model.q, model.dq, model.ddq)
    x = ca.vertcat(model.delta, model.ddelta)
    return ca.Function("flex_exact", [u, x], [model.prescribed_dddelta], ["u", "x"],
                       ["dddelta"])


def _monomials(n):
    """Monomial list of (q̇, q̈): ('1',), ('a', i) for q̈_i, ('v', i), ('vv', i, j)."""
    out = [("1",)]
    out += [("a", i) for i in range(n)]
    out += [("v", i) for i in range(n)]
    out += [("vv", i, j) for i in range(n) for j in range(i, n)]
    return out


def _designs(n):
    """(q̇, q̈) design points whose monomial matrix is square and invertible."""
    d = [(np.zeros(n), np.zeros(n))]
    eye = np.eye(n)
    d += [(np.zeros(n), eye[i]) for i in range(n)]
    d += [(eye[i], np.zeros(n)) for i in range(n)]
    d += [(-eye[i], np.zeros(n)) for i in range(n)]
    d += [(eye[i] + eye[j], np.zeros(n)) for i in range(n) for j in range(i + 1, n)]
    return d


def _monomial_values(mono, dq, ddq):
    out = []
    for mo in mono:
        if mo[0] == "1":
            out.append(1.0 + 0 * dq[0] if not isinstance(dq, np.ndarray) else 1.0)
        elif mo[0] == "a":
            out.append(ddq[mo[1]])
        elif mo[0] == "v":
            out.append(dq[mo[1]])
        else:
            out.append(dq[mo[1]] * dq[mo[2]])
    return out


def _fourier_basis(theta, K):
    out = [1.0 + 0 * theta]
    for k in range(1, K + 1):
        out += [ca.cos(k * theta) if not isinstance(theta, float) else np.cos(k * theta),
                ca.sin(k * theta) if not isinstance(theta, float) else np.sin(k * theta)]
    return out


#: exact-row evaluations per chunk of tabulate_plant (memory ~ 200 bytes per evaluation)
CHUNK_EVALUATIONS = 1 << 17


@dataclass
class FlexiblePlant:
    """The flexible rows to first or second order in Δ,
    ``δ̈ = r₀(u) + J_δ(u) δ + J_δ̇(u) δ̇ [+ W(u) (x_a x_b)_{a≤b}]``.

    Built by :func:`tabulate_plant`. Coefficient array layout: ``coef[k, i, c]`` for
    monomial ``k`` of ``(q̇, q̈)`` (:attr:`monomials`), mode row ``i`` and column ``c``
    (0: r₀, 1..m: J_δ, m+1..2m: J_δ̇, then one column per pair of :attr:`pairs`).

    Attributes
    ----------
    model : casflex.model.FlexibleModel
    monomials : list of tuple
    shape_joints, fourier_joints : tuple of int
        Joints tabulated with B-splines, joints expanded in Fourier series (0-based).
    degree : int
        Fourier degree K.
    table : casflex.modal.tables.ModalTable or None
        The spline table (``None`` without shape joints).
    constant : numpy.ndarray or None
        ``(L, nnz)`` Fourier coefficients when there is no shape joint.
    pattern : numpy.ndarray of bool
        Structurally non-zero entries of ``coef`` (the only ones evaluated).
    info : dict
        Build statistics: ``samples``, ``evaluations``, ``seconds``, ``check_rel_error``,
        ``from_cache``.
    order : int
        1: first order in Δ; 2: with the products ``x_a x_b`` (:attr:`pairs`). A
        second-order plant replaced with ``order=1`` (``dataclasses.replace``) is its
        first-order part.
    keep : numpy.ndarray of bool or None
        ``(L, nnz)``: the Fourier coefficients (rows: the ``L`` products of the Fourier
        basis, columns: the structurally non-zero entries) that :meth:`coefficients`
        evaluates; ``None``: all of them. Set by ``tabulate_plant(prune=...)``.
    lookup : {"local", "interpolant"}
        How :meth:`coefficients` evaluates the spline table
        (:meth:`casflex.modal.tables.ModalTable.function`): ``"local"`` (default) the lean
        local evaluation of one-axis tables, ``"interpolant"`` CasADi's de Boor routine
        (the same spline; the C code before, kept for comparisons).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> plant = tabulate_plant(model, cache_dir=False)
    >>> plant.order, plant.pairs          # one mode: x = [δ₁, δ̇₁]
    (2, [(0, 0), (0, 1), (1, 1)])
    >>> plant.shape_joints, plant.fourier_joints, plant.table is None
    ((), (1, 2), True)
    >>> len(plant.monomials), plant.pattern.shape   # 1 + 2n + n(n+1)/2 monomials
    (13, (13, 1, 6))
    """

    model: FlexibleModel
    monomials: list[tuple]
    shape_joints: tuple[int, ...]
    fourier_joints: tuple[int, ...]
    degree: int
    table: ModalTable | None
    constant: np.ndarray | None
    pattern: np.ndarray
    info: dict = field(default_factory=dict)
    order: int = 1
    keep: np.ndarray | None = None
    lookup: str = "local"

    @property
    def pairs(self) -> list[tuple[int, int]]:
        """Index pairs ``(a, b)``, ``a ≤ b``, of the quadratic terms ``x_a x_b`` (columns
        ``2m+1 ...`` of the coefficient layout); empty for a first-order plant."""
        if self.order < 2:
            return []
        nx = 2 * self.m
        return [(a, b) for a in range(nx) for b in range(a, nx)]

    @property
    def n(self) -> int:
        """Number of joints."""
        return self.model.n

    @property
    def m(self) -> int:
        """Number of modes."""
        return self.model.m

    def coefficients(self, q: ArrayLike | ca.SX, dq: ArrayLike | ca.SX,
                     ddq: ArrayLike | ca.SX, coriolis: bool = True,
                     stiffness_scale: float = 1.0, quadratic: bool = False,
                     spline_values: ca.SX | None = None) -> tuple[ca.SX, ...]:
        """SX coefficients ``(r0, Jd, Jv[, W])`` at ``(q, q̇, q̈)`` (SX or numbers).

        Parameters
        ----------
        q, dq, ddq : casadi.SX or array_like
            Joint angles [rad], rates [rad/s] and accelerations [rad/s²] (n each).
        coriolis : bool
            ``False`` drops every term with ``q̇`` (Coriolis and centrifugal forcing,
            gyroscopic coupling and centrifugal stiffening).
        stiffness_scale : float
            Multiplies the modal stiffness ``K = Ω²`` inside ``J_δ`` (robustness studies;
            the second-order terms are left as tabulated).
        quadratic : bool
            Also return ``W`` (m × len(:attr:`pairs`)), the coefficients of the products
            ``x_a x_b`` (zero columns for a first-order plant).
        spline_values : casadi.SX, optional
            The spline table at the shape joints of ``q``, looked up by the caller (the
            entries of :meth:`spline_columns`, e.g. from one lookup shared with other
            tables: :mod:`casflex.estimation.lookup`); default: looked up here.

        Returns
        -------
        r0 : casadi.SX
            (m × 1) δ̈ at Δ = 0.
        Jd, Jv : casadi.SX
            (m × m) ``∂δ̈/∂δ`` and ``∂δ̈/∂δ̇`` at Δ = 0.
        W : casadi.SX
            Only with ``quadratic=True``.

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.model import FlexibleModel, PointwiseProvider
        >>> robot = load("problems/arm2link.toml")
        >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
        >>> plant = tabulate_plant(model, cache_dir=False)
        >>> r0, Jd, Jv = plant.coefficients(np.zeros(3), np.zeros(3), np.zeros(3))
        >>> round(float(r0), 6), round(float(Jd), 3), round(float(Jv), 6)   # J_δ = -ω₁²
        (0.0, -69.012, 0.0)
        >>> _, Jd2, _ = plant.coefficients(np.zeros(3), np.zeros(3), np.zeros(3),
        ...                                stiffness_scale=2.0)
        >>> round(float(Jd2), 3)
        -138.025
        >>> plant.coefficients([0, 0, 0], [0, 0, 0], [0, 0, 0], quadratic=True)[3].shape
        (1, 3)
        """
        m = self.m
        ncol = 2 * m + 1 + len(self.pairs)
        # interpolate the grid as the model's own tables are (B-splines or multilinear)
        method = getattr(self.model.provider, "method", "bspline")
        q = ca.SX(ca.vertcat(*[q[i] for i in range(self.n)]))
        L = (2 * self.degree + 1) ** len(self.fourier_joints)
        nnz = int(self.pattern.sum())
        phi = ca.SX.ones(1)
        for j in self.fourier_joints:
            phi = ca.vec(ca.vertcat(*_fourier_basis(q[j], self.degree)) @ phi.T)
        if spline_values is None and self.table is not None:
            qs = ca.vertcat(*[q[j] for j in self.shape_joints])
            spline_values = ca.SX(self.table.function(
                "coef", method=method, lookup=self.lookup,
                entries=None if self.keep is None else self._kept())(qs))
        if self.keep is None:
            if self.table is not None:
                A = ca.reshape(spline_values, nnz, L)  # stored column-major: nnz fastest
            else:
                A = ca.SX(ca.DM(self.constant.T))
            entries = A @ phi if L > 1 else A[:, 0]
        else:  # only the kept Fourier coefficients (tabulate_plant, prune)
            flat = self._kept()  # index l * nnz + e of the stored layout
            if self.table is not None:
                vals = spline_values
            else:
                vals = ca.SX(ca.DM(np.asarray(self.constant, dtype=float).ravel()[flat]))
            terms = [[] for _ in range(nnz)]
            for pos, fi in enumerate(flat):  # increasing l for every entry
                terms[fi % nnz].append(vals[pos] * phi[fi // nnz] if L > 1 else vals[pos])
            entries = ca.vertcat(*[sum(t[1:], t[0]) if t else ca.SX(0) for t in terms])
        mono = _monomial_values(self.monomials, [dq[i] for i in range(self.n)],
                                [ddq[i] for i in range(self.n)])
        out = [[ca.SX(0) for _ in range(ncol)] for _ in range(m)]
        idx = 0
        for k, i, c in zip(*np.nonzero(self.pattern), strict=True):
            mo = self.monomials[k]
            if (not coriolis and mo[0] in ("v", "vv")) or c >= ncol:
                idx += 1  # dropped: Coriolis terms, or products x_a x_b with order = 1
                continue
            out[i][c] = out[i][c] + mono[k] * entries[idx]
            idx += 1
        C = ca.SX(m, ncol)
        for i in range(m):
            for c in range(ncol):
                C[i, c] = out[i][c]
        r0, Jd, Jv = C[:, 0], C[:, 1:m + 1], C[:, m + 1:2 * m + 1]
        if stiffness_scale != 1.0:
            K = ca.substitute(self.model.K, self.model.q, q)
            Jd = Jd - (float(stiffness_scale) - 1.0) * K
        if quadratic:
            W = C[:, 2 * m + 1:] if self.pairs else ca.SX(m, 0)
            return r0, Jd, Jv, W
        return r0, Jd, Jv

    def _kept(self) -> np.ndarray:
        """Indices ``l * nnz + e`` (stored layout) of the kept Fourier coefficients."""
        return np.flatnonzero(np.asarray(self.keep, dtype=bool).ravel())

    def spline_columns(self) -> np.ndarray | None:
        """The entries of the spline table that :meth:`coefficients` looks up, on the grid.

        Returns
        -------
        numpy.ndarray or None
            ``grid shape + (k,)``: the table's coefficient entries that
            :meth:`coefficients` evaluates (the kept ones of a pruned plant, all of them
            otherwise), in the order of its ``spline_values``; None without shape joints.

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.model import FlexibleModel, PointwiseProvider
        >>> robot = load("problems/arm2link.toml")
        >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
        >>> tabulate_plant(model, cache_dir=False).spline_columns() is None   # no table
        True
        """
        if self.table is None:
            return None
        data = np.asarray(self.table.values["coef"], dtype=float)
        data = data.reshape(self.table.shape + (-1,))
        return data if self.keep is None else data[..., self._kept()]

    def quadratic_terms(self, x: ArrayLike | ca.SX) -> ca.SX:
        """The products ``x_a x_b`` of :attr:`pairs` (SX column).

        Parameters
        ----------
        x : casadi.SX or array_like
            ``[δ; δ̇]`` (2m).

        Returns
        -------
        casadi.SX
            ``len(pairs) × 1``; empty (0 × 1) for a first-order plant.

        Examples
        --------
        >>> import dataclasses
        >>> from casflex.robot import load
        >>> from casflex.model import FlexibleModel, PointwiseProvider
        >>> robot = load("problems/arm2link.toml")
        >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
        >>> plant = tabulate_plant(model, cache_dir=False)
        >>> print(plant.quadratic_terms(ca.SX.sym("x", 2)))
        [sq(x_0), (x_0*x_1), sq(x_1)]
        >>> dataclasses.replace(plant, order=1).quadratic_terms(ca.SX.sym("x", 2)).shape
        (0, 1)
        """
        return ca.vertcat(*[x[a] * x[b] for a, b in self.pairs]) if self.pairs else \
            ca.SX(0, 1)

    def function(self, coriolis: bool = True, stiffness_scale: float = 1.0) -> ca.Function:
        """``casadi.Function`` ``u -> (r0, Jd, Jv[, W])``; ``W`` (second-order plants only)
        holds the coefficients of the products ``x_a x_b`` of :attr:`pairs`.

        Parameters
        ----------
        coriolis, stiffness_scale
            Estimator-model variations (:meth:`coefficients`).

        Returns
        -------
        casadi.Function
            ``flex_coefficients (u) -> (r0, Jd, Jv[, W])`` with ``u = [q; q̇; q̈]`` (3n).

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.model import FlexibleModel, PointwiseProvider
        >>> robot = load("problems/arm2link.toml")
        >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
        >>> f = tabulate_plant(model).function()
        >>> round(float(f(np.zeros(9))[1]), 3)   # J_δ = -ω₁² at rest
        -69.012
        """
        n = self.n
        u = ca.SX.sym("u", 3 * n)
        r0, Jd, Jv, W = self.coefficients(u[:n], u[n:2 * n], u[2 * n:], coriolis,
                                          stiffness_scale, quadratic=True)
        if self.pairs:
            return ca.Function("flex_coefficients", [u], [r0, Jd, Jv, W], ["u"],
                               ["r0", "Jd", "Jv", "W"])
        return ca.Function("flex_coefficients", [u], [r0, Jd, Jv], ["u"],
                           ["r0", "Jd", "Jv"])

    def rhs_function(self, coriolis: bool = True, stiffness_scale: float = 1.0,
                     quadratic: bool = True) -> ca.Function:
        """``casadi.Function`` ``(u, x) -> dddelta`` of the tabulated plant.

        ``quadratic=False`` drops the second-order terms (the first-order plant).

        Parameters
        ----------
        coriolis, stiffness_scale
            Estimator-model variations (:meth:`coefficients`).
        quadratic : bool
            Include the products ``x_a x_b`` (second-order plants only).

        Returns
        -------
        casadi.Function
            ``flex_lean (u, x) -> dddelta`` with ``u = [q; q̇; q̈]`` (3n), ``x = [δ; δ̇]``.

        Examples
        --------
        >>> from casflex.robot import load
        >>> from casflex.model import FlexibleModel, PointwiseProvider
        >>> robot = load("problems/arm2link.toml")
        >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
        >>> f = tabulate_plant(model).rhs_function()
        >>> round(float(f(np.zeros(9), [1e-3, 0.0])), 6)   # -ω₁² δ₁ at rest
        -0.069012
        """
        n, m = self.n, self.m
        u = ca.SX.sym("u", 3 * n)
        x = ca.SX.sym("x", 2 * m)
        r0, Jd, Jv, W = self.coefficients(u[:n], u[n:2 * n], u[2 * n:], coriolis,
                                          stiffness_scale, quadratic=True)
        rhs = r0 + Jd @ x[:m] + Jv @ x[m:]
        if quadratic and self.pairs:
            rhs = rhs + W @ self.quadratic_terms(x)
        return ca.Function("flex_lean", [u, x], [rhs], ["u", "x"], ["dddelta"])


def _depends(fexact, n, m, joints, rng):
    """Joints among ``joints`` whose value changes the exact plant (numerically)."""
    out = []
    for j in joints:
        diffs, scale = 0.0, 0.0
        for _ in range(3):
            u = rng.normal(size=3 * n)
            x = 1e-3 * rng.normal(size=2 * m)
            u2 = u.copy()
            u2[j] += rng.uniform(0.5, 2.5)
            a = np.asarray(fexact(u, x)).ravel()
            b = np.asarray(fexact(u2, x)).ravel()
            diffs = max(diffs, float(np.max(np.abs(a - b))))
            scale = max(scale, float(np.max(np.abs(a))))
        if diffs > 1e-10 * max(scale, 1e-300):
            out.append(j)
    return tuple(out)


def _check_modal_block(model, joints, seed):
    """Refuse a model whose modal mass block at δ = 0 changes with a joint the plant
    expands in a Fourier series (any joint but the shape joints): the rows then depend
    on it through ``M_δδ(q, 0)⁻¹``, which no trigonometric polynomial holds
    (``kinematics="exact"`` with its own modal block, ``modal_mass="kinematic"``, on a
    provider without that joint as a shape joint). The default truncated model has
    ``M_δδ(q, 0) = I``."""
    n, m = model.n, model.m
    if not m or not joints:
        return
    block = ca.Function("modal_block", [model.q], [ca.substitute(
        model.M[n:, n:], model.delta, ca.DM.zeros(m))])
    rng = np.random.default_rng([seed, 19])  # not the tabulation's stream
    for j in joints:
        for _ in range(2):
            q = rng.uniform(-np.pi, np.pi, n)
            q2 = q.copy()
            q2[j] += rng.uniform(0.5, 2.5)
            a, b = block(q).full(), block(q2).full()
            if np.abs(a - b).max() > 1e-9 * max(np.abs(a).max(), 1e-300):
                raise ModelError(
                    f"the model's modal mass block M_δδ(q, 0) changes with q{j + 1} "
                    f"(by {np.abs(a - b).max():.2g}), which is not a shape joint of its "
                    f"provider: the plant's Fourier series in q{j + 1} cannot hold its "
                    "inverse. Build the model with modal_mass='first_order' (M_δδ(q, 0) = I) "
                    f"or on a provider with q{j + 1} among its shape joints (kinematics="
                    f"{getattr(model, 'kinematics', 'truncated')!r}, modal_mass="
                    f"{getattr(model, 'modal_mass', None)!r})")


def tabulate_plant(model: FlexibleModel, *, grid: Sequence[ArrayLike] | None = None,
                   step: float | None = None, degree: int = 2, eps: float = 1e-4,
                   check: bool = True, seed: int = 0, order: int = 2, eps2: float = 1e-3,
                   cache_dir: str | os.PathLike | bool | None = None,
                   prune: float | None = 1e-6,
                   derivatives: str = "exact") -> FlexiblePlant:
    """Tabulate the flexible plant of ``model`` to first or second order in Δ (module
    docstring).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    grid : sequence of array_like, optional
        Axes over the shape joints [rad]; default the model's table grid when the provider
        is a :class:`casflex.model.TableProvider`, else :func:`casflex.model.default_grid`
        with ``step``.
    step : float, optional
        Grid step [rad] when no grid is known.
    degree : int
        Fourier degree in the other joints (2 is exact for rigid-body kinematics).
    eps : float
        Central-difference step in Δ for the first-order terms [√kg m, √kg m/s]
        (``derivatives="differences"`` only).
    order : {1, 2}
        Order of the expansion in Δ. 2 (default) adds the products ``x_a x_b`` (the
        centripetal and gyroscopic terms of the flexible rates, the change of the mass
        matrix with δ): small against δ̈, but without them the velocity estimates of an
        arm that deflects by several cm (Table 8 arm, Table 9 moves) fall short.
    eps2 : float
        Step of the second differences for the second-order terms [√kg m, √kg m/s]
        (``derivatives="differences"`` only).
    check : bool
        Compare with the exact plant at random points; the largest relative error goes to
        ``info["check_rel_error"]``.
    seed : int
        Random seed of the dependence detection and the check.
    cache_dir : str or pathlib.Path or False, optional
        Disk cache directory (default ``$CASFLEX_CACHE``, else ``~/.cache/casflex``;
        ``False`` disables it). The file ``plant-<key>.npz`` is keyed on the SHA-256 of the model's
        exact flexible rows (their serialised CasADi graph, modal tables included), the
        grid, every option above, the casflex and CasADi versions and the source of the
        tabulation code; it is written atomically and carries its key and a digest of its
        content, so a stale, foreign or altered file is never read (it is recomputed and
        overwritten).
        ``info["from_cache"]`` tells which happened.
    prune : float or None
        Leave out of the evaluation (:attr:`FlexiblePlant.keep`) every Fourier coefficient
        whose largest magnitude over the grid is below ``prune`` times that of the
        largest Fourier coefficient of the same entry (``None`` or 0: keep all). The
        dropped ones are the harmonics an entry does not have, tabulated as round-off of
        the differences, orders of magnitude below the harmonics it has (the default 1e-6
        sits in this gap): the coefficients change only by round-off, and the table
        lookup and the Fourier sum shrink. Applied after the cache (the stored table is
        complete); ``info["pruned"]`` counts the dropped values.
    derivatives : {"exact", "differences"}
        How the terms in Δ are obtained at each design of ``(q, q̇, q̈)``. ``"exact"``
        (default): one evaluation of the rows' value, Jacobian and Hessian in Δ at Δ = 0
        (CasADi's algorithmic differentiation of the rows, one SX function with shared
        subexpressions). ``"differences"``: central and second differences of the exact
        rows with steps ``eps``, ``eps2`` (1 + 4·2m + 2m(2m − 1) evaluations per design:
        55 for three modes, with truncation errors ~``eps²``, ``eps2²``). Both give the
        same plant to the differences' truncation error; ``"exact"`` is about 8× cheaper
        (the Table 8 arm with three modes: 23 000 SX instructions per row evaluation, 150 000
        for the value, Jacobian and Hessian together, against 55 evaluations).

    Returns
    -------
    FlexiblePlant

    Raises
    ------
    casflex.errors.ModelError
        When the model's modal mass block ``M_δδ(q, 0)`` changes with a joint the plant
        would expand in a Fourier series (``kinematics="exact"`` with
        ``modal_mass="kinematic"`` on a provider without that shape joint).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> plant = tabulate_plant(model)
    >>> plant.fourier_joints, plant.info["check_rel_error"] < 1e-6
    ((1, 2), True)
    >>> full = tabulate_plant(model, prune=None)   # every Fourier coefficient evaluated
    >>> full.keep is None, plant.keep.shape, plant.info["pruned"] > 300
    (True, (25, 15), True)

    With exact derivatives an entry that is zero by structure comes out as an exact zero
    (or round-off of the rows, far below the pattern's threshold): 15 entries here. With
    ``derivatives="differences"`` the differences' round-off makes 31 of them, and the
    Fourier coefficients kept depend on whether the TMM's compiled kernels or numpy made the
    table (435 of 775 with numpy, 455 with the kernels; 73 of 375 with exact derivatives).

    >>> differences = tabulate_plant(model, derivatives="differences", cache_dir=False)
    >>> Jd_differences = differences.function()(np.zeros(9))[1]
    >>> bool(abs(float(Jd_differences - plant.function()(np.zeros(9))[1])) < 1e-6)  # -69.0
    True
    """
    from casflex.modal.tables import ModalTable
    from casflex.model import default_grid

    t0 = time.perf_counter()
    choice(order, "order", (1, 2))
    choice(derivatives, "derivatives", ("exact", "differences"))
    n, m = model.n, model.m
    rng = np.random.default_rng(seed)
    shape = tuple(model.provider.shape_joints)
    others = [j for j in range(n) if j not in shape]
    _check_modal_block(model, others, seed)
    fexact = exact_plant_function(model)
    fourier = _depends(fexact, n, m, others, rng)
    mono = _monomials(n)
    designs = _designs(n)
    Dm = np.array([_monomial_values(mono, dq, ddq) for dq, ddq in designs])
    Dinv = np.linalg.inv(Dm)
    L1 = 2 * degree + 1
    thetas = 2.0 * np.pi * np.arange(L1) / L1
    B1 = np.array([[float(v) for v in _fourier_basis(float(t), degree)] for t in thetas])
    Bf = np.ones((1, 1))
    for _ in fourier:
        Bf = np.kron(Bf, B1)  # rows: sample combos (first joint slowest)
    Binv = np.linalg.inv(Bf)

    table_grid, periodic = None, ()
    if shape:
        if grid is None and hasattr(model.provider, "table"):
            table_grid = tuple(np.asarray(a, dtype=float) for a in model.provider.table.grid)
            periodic = tuple(model.provider.table.periodic)
        else:
            table_grid = tuple(np.asarray(a, dtype=float) for a in (
                grid if grid is not None else default_grid(model.robot, shape, step)))
            periodic = (True,) * len(shape)
    gpoints = list(itertools.product(*[range(a.size) for a in table_grid])) if shape else [()]
    fsamples = list(itertools.product(range(L1), repeat=len(fourier)))

    path = key = None
    root = cache_root(cache_dir)
    if root is not None:
        key = _plant_key(fexact, table_grid, periodic, fourier, degree=degree, eps=eps,
                         eps2=eps2, order=order, check=check, seed=seed,
                         derivatives=derivatives)
        path = root / f"plant-{key[:32]}.npz"
        hit = load_verified(path, key)
        if hit is not None:
            return _pruned(_plant_from_arrays(model, mono, shape, fourier, degree, order, hit,
                                              time.perf_counter() - t0), prune)
        remove_stale_files(root)  # leftovers of killed builds

    # all (q, u, x) evaluation points
    nx = 2 * m
    pairs = [(a, b) for a in range(nx) for b in range(a, nx)] if order == 2 else []
    ncol = 1 + nx + len(pairs)
    if derivatives == "exact":
        xdes = [np.zeros(nx)]  # value, Jacobian and Hessian at Δ = 0 in one evaluation
        rows = _taylor_function(model, order)
    else:
        xdes = _difference_designs(nx, pairs, eps, eps2, order)
        rows = fexact
    # The designs are evaluated a chunk of grid points at a time: all of them at once are
    # grid points × Fourier samples × (q̇, q̈) designs × Δ designs columns (75 million on
    # two shape joints at 3°: tens of GB), while the coefficients kept are per grid point.
    nd, ndes, nf = len(designs), len(xdes), len(fsamples)
    Q = np.zeros((len(gpoints), nf, n))  # q of every (grid point, Fourier sample)
    for gi, gp in enumerate(gpoints):
        for ax, j in enumerate(shape):
            Q[gi, :, j] = table_grid[ax][gp[ax]]
    for fi, fs in enumerate(fsamples):
        for a, j in enumerate(fourier):
            Q[:, fi, j] = thetas[fs[a]]
    DQ = np.array([dq for dq, _ in designs]).reshape(nd, n)
    DDQ = np.array([ddq for _, ddq in designs]).reshape(nd, n)
    XD = np.array(xdes)
    N = len(gpoints) * nf * nd * ndes
    chunk = max(1, CHUNK_EVALUATIONS // (nf * nd * ndes))
    coef = np.empty((len(gpoints), nf, len(mono), m, ncol))
    maps = {}
    for g0 in range(0, len(gpoints), chunk):
        g1 = min(g0 + chunk, len(gpoints))
        block = (g1 - g0, nf, nd, ndes)
        U = np.concatenate([np.broadcast_to(Q[g0:g1, :, None, None, :], block + (n,)),
                            np.broadcast_to(DQ[None, None, :, None, :], block + (n,)),
                            np.broadcast_to(DDQ[None, None, :, None, :], block + (n,))],
                           axis=-1).reshape(-1, 3 * n).T
        if U.shape[1] not in maps:
            maps[U.shape[1]] = rows.map(U.shape[1])
        if derivatives == "exact":
            # column-major (m, ncol) per evaluation: row c * m + i is column c of mode i
            R = np.asarray(maps[U.shape[1]](U)).reshape((ncol, m) + block[:3])
            cols = np.moveaxis(R, 0, -1)  # (m, G, F, D, ncol)
        else:
            X = np.broadcast_to(XD[None, None, None], block + (nx,)).reshape(-1, nx).T
            R = np.asarray(maps[U.shape[1]](U, X)).reshape((m,) + block)
            cols = _difference_columns(R, nx, pairs, eps, eps2, order)
            del X
        coef[g0:g1] = _chunk_coefficients(cols, Dinv, Binv)
        del U, R, cols
    scale = np.max(np.abs(coef), axis=(0, 1), keepdims=True)
    big = np.max(np.abs(coef))
    pattern = (scale[0, 0] > 1e-11 * big)
    if order == 2:  # second differences carry round-off ~1e-16 |f| / eps2^2: drop it
        quad = scale[0, 0][..., 1 + nx:]
        pattern[..., 1 + nx:] = quad > 1e-7 * max(float(quad.max()), 1e-300)
    nnz_idx = np.nonzero(pattern)
    vals = coef[:, :, nnz_idx[0], nnz_idx[1], nnz_idx[2]]  # (G, L, nnz)
    table, constant = None, None
    if shape:
        gshape = tuple(a.size for a in table_grid)
        # per grid point the (nnz, L) matrix, column-major (nnz fastest) = vals[g] in C order
        flat = vals.reshape((len(gpoints), -1)).reshape(gshape + (-1,))
        table = ModalTable(grid=table_grid, shape_joints=shape, values={"coef": flat},
                           omega=np.zeros(gshape + (1,)), periodic=periodic)
    else:
        constant = vals[0]  # (L, nnz)
    plant = FlexiblePlant(model=model, monomials=mono, shape_joints=shape,
                          fourier_joints=fourier, degree=degree, table=table,
                          constant=constant, pattern=pattern,
                          info={"samples": len(gpoints) * len(fsamples), "evaluations": N,
                                "nonzeros": int(pattern.sum())}, order=order)
    plant = _pruned(plant, prune)
    if check:
        plant.info["check_rel_error"] = _check_plant(plant, fexact, rng)
    plant.info["seconds"] = time.perf_counter() - t0
    plant.info["from_cache"] = False
    if path is not None:
        info = {k: v for k, v in plant.info.items() if k != "pruned"}
        arrays = {"pattern": pattern, "info": np.array(json.dumps(info))}
        if table is not None:
            arrays["coef"] = table.values["coef"]
            arrays["periodic"] = np.array(periodic, dtype=bool)
            for ax, a in enumerate(table_grid):
                arrays[f"grid{ax}"] = a
        else:
            arrays["constant"] = constant
        save_verified(path, key, **arrays)
    return plant


def _difference_designs(nx, pairs, eps, eps2, order):
    """The Δ designs of ``derivatives="differences"``: 0, ±eps e_i, then (order 2) ±eps2
    e_i and ±eps2 (e_a + e_b) for the pairs a < b."""
    xdes = [np.zeros(nx)]
    for i in range(nx):
        e = np.zeros(nx)
        e[i] = eps
        xdes += [e, -e]
    if order == 2:
        for i in range(nx):  # second differences: x_i^2 terms
            e = np.zeros(nx)
            e[i] = eps2
            xdes += [e, -e]
        for a, b in pairs:  # and x_a x_b from the even part along e_a + e_b
            if a != b:
                e = np.zeros(nx)
                e[a] = e[b] = eps2
                xdes += [e, -e]
    return xdes


def _difference_columns(R, nx, pairs, eps, eps2, order):
    """Value, first and second-order terms in Δ from the exact rows ``R`` (m, grid points,
    Fourier samples, (q̇, q̈) designs, Δ designs of :func:`_difference_designs`): (m, grid
    points, Fourier samples, designs, 1 + nx + pairs)."""
    cols = np.empty(R.shape[:-1] + (nx + 1 + len(pairs),))
    cols[..., 0] = R[..., 0]
    for i in range(nx):
        cols[..., 1 + i] = (R[..., 1 + 2 * i] - R[..., 2 + 2 * i]) / (2.0 * eps)
    if order == 2:
        base = 1 + 2 * nx

        def even(k):  # (f(+e) + f(-e) - 2 f(0)) / (2 eps2^2) for design pair k
            return (R[..., base + 2 * k] + R[..., base + 2 * k + 1] - 2.0 * R[..., 0]) / (
                2.0 * eps2**2)

        diag = [even(i) for i in range(nx)]
        k = nx
        for c, (a, b) in enumerate(pairs):
            if a == b:
                cols[..., 1 + nx + c] = diag[a]
            else:
                cols[..., 1 + nx + c] = even(k) - diag[a] - diag[b]
                k += 1
    return cols


def _taylor_function(model, order):
    """``u -> vec([f, ∂f/∂x, W])`` at ``x = 0``: the exact rows ``f`` (m), their Jacobian in
    ``x = [δ; δ̇]`` (m × 2m) and, for ``order = 2``, the coefficients ``W`` of the products
    ``x_a x_b`` of the pairs ``a ≤ b`` (``H_aa / 2`` and ``H_ab``, ``H`` the Hessian of a
    row), column-major (m × (1 + 2m + pairs)). One SX function with common subexpressions
    merged: the parts that depend on ``u`` only are computed once for all the terms."""
    u = ca.vertcat(model.q, model.dq, model.ddq)
    x = ca.vertcat(model.delta, model.ddelta)
    f = model.prescribed_dddelta
    nx = x.numel()
    cols = [f, ca.jacobian(f, x)]
    if order == 2:
        pairs = [(a, b) for a in range(nx) for b in range(a, nx)]
        rows = []
        for i in range(model.m):
            H = ca.hessian(f[i], x)[0]
            rows.append(ca.horzcat(*[H[a, b] / 2 if a == b else H[a, b] for a, b in pairs]))
        cols.append(ca.vertcat(*rows))
    out = ca.substitute(ca.vec(ca.horzcat(*cols)), x, ca.DM.zeros(nx))
    return ca.Function("flex_taylor", [u], [out], ["u"], ["terms"], {"cse": True})


def _chunk_coefficients(cols, Dinv, Binv):
    """Fourier coefficients of the monomial coefficients of the Δ expansion, from its
    terms ``cols`` (m, grid points, Fourier samples, (q̇, q̈) designs, 1 + nx + pairs) at
    a chunk of grid points: (grid points, L, monomials, m, 1 + nx + pairs)."""
    coef = np.einsum("kd,igfdc->gfkic", Dinv, cols)  # (G, F, mono, m, ncol)
    return np.einsum("lf,gfkic->glkic", Binv, coef)  # (G, L, mono, m, ncol)


def _pruned(plant, prune):
    """The plant with :attr:`FlexiblePlant.keep` set by the relative threshold ``prune``
    (see :func:`tabulate_plant`)."""
    if not prune:
        plant.info["pruned"] = 0
        return plant
    if plant.table is not None:
        vals = np.asarray(plant.table.values["coef"], dtype=float)
        vals = vals.reshape((-1, vals.shape[-1]))  # (grid points, L * nnz)
    else:
        vals = np.asarray(plant.constant, dtype=float).reshape((1, -1))
    nnz = int(plant.pattern.sum())
    size = np.max(np.abs(vals), axis=0).reshape(-1, nnz)  # (L, nnz)
    keep = size >= float(prune) * np.max(size, axis=0, keepdims=True)
    keep &= size > 0
    plant.keep = keep
    plant.info["pruned"] = int(keep.size - keep.sum())
    return plant


def _plant_key(fexact, grid, periodic, fourier, **options):
    """SHA-256 identifying a tabulated plant (see :func:`tabulate_plant`, ``cache_dir``):
    the exact rows' serialised graph, the grid, the options, the versions and the source
    of the code that tabulates."""
    from casflex import __version__

    return digest({
        "exact_plant": digest(fexact.serialize()), "casflex": __version__,
        "casadi": ca.__version__, "fourier": list(fourier),
        "periodic": [bool(p) for p in periodic], "options": options,
        "grid": [np.asarray(a, dtype=float).tolist() for a in (grid or ())],
        "source": source_digest(tabulate_plant, _depends, _monomials, _designs,
                                _monomial_values, _fourier_basis, _check_plant,
                                _plant_from_arrays, FlexiblePlant, _chunk_coefficients,
                                _difference_designs, _difference_columns,
                                _taylor_function),
    })


def _plant_from_arrays(model, mono, shape, fourier, degree, order, arrays, seconds):
    from casflex.modal.tables import ModalTable

    table, constant = None, None
    if "coef" in arrays:
        table_grid = tuple(arrays[f"grid{ax}"] for ax in range(len(shape)))
        flat = arrays["coef"]
        table = ModalTable(grid=table_grid, shape_joints=shape, values={"coef": flat},
                           omega=np.zeros(flat.shape[:-1] + (1,)),
                           periodic=tuple(bool(p) for p in arrays["periodic"]))
    else:
        constant = arrays["constant"]
    info = json.loads(str(arrays["info"]))
    info.update(from_cache=True, seconds=seconds)
    return FlexiblePlant(model=model, monomials=mono, shape_joints=shape,
                         fourier_joints=fourier, degree=degree, table=table,
                         constant=constant, pattern=arrays["pattern"].astype(bool),
                         info=info, order=order)


def _check_plant(plant, fexact, rng, count=6):
    """Largest relative error of the tabulated plant at random points (Δ small)."""
    n, m = plant.n, plant.m
    lean = plant.rhs_function()
    worst = 0.0
    for _ in range(count):
        u = np.r_[rng.uniform(-np.pi, np.pi, n), rng.normal(size=n), rng.normal(size=n)]
        x = 1e-4 * rng.normal(size=2 * m)
        a = np.asarray(fexact(u, x)).ravel()
        b = np.asarray(lean(u, x)).ravel()
        worst = max(worst, float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300)))
    return worst


