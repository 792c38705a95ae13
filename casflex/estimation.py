"""Extended Kalman filter for the modal states of a flexible arm (dissertation §5.4–5.5).

The joint motion ``u = [q; q̇; q̈]`` is measured (encoders, eq. 158); the filter estimates
``x = Δ = [δ; δ̇]`` from accelerometer or strain signals (:mod:`casflex.sensors`).

The flexible plant (eq. 157–162)
--------------------------------
The flexible rows of the model, ``M_δq q̈ + M_δδ δ̈ + (C Ẋ)_δ + G_δ + D δ̇ = 0``, solved
for ``δ̈`` (:attr:`casflex.dynamics.FlexibleModel.prescribed_dddelta`), are a large
expression (~45 000 SX operations for the Table 8 arm with three modes; its Jacobian
~160 000). The filter uses its **expansion in Δ about Δ = 0 to second order** (default;
``order=1`` gives the dissertation's linear time-varying plant, eq. 159, 162):

``δ̈ = r₀(u) + J_δ(u) δ + J_δ̇(u) δ̇ + Σ_{a≤b} W_ab(u) x_a x_b``,  ``x = [δ; δ̇]``

The second-order terms (centripetal terms of the flexible rates, the change of the mass
matrix and of the Coriolis coupling with δ) are ~1 % of δ̈ for the Table 8 arm on the
Table 9 moves, whose tip deflects by several cm; without them the modal velocity errors
stay only 25–200× below the velocities (the issue asks for 100×), with them 200–500×.

Every coefficient is a polynomial of degree ≤ 2 in ``(q̇, q̈)`` — monomials ``1, q̈_a,
q̇_a, q̇_a q̇_b`` — whose coefficients depend on ``q`` only. :func:`tabulate_plant`
extracts them from the model (polynomial interpolation over 1 + 2n + n(n+1)/2 designs of
``(q̇, q̈)``, central differences and even second differences in Δ), and stores them over
the model's
shape joints as periodic cubic B-splines (the model's own modal tables are B-splines on
the same kind of grid) and as Fourier series of degree ``K`` in the other joints they
depend on (rigid-body kinematics make that dependence a trigonometric polynomial; the
degree is checked). Joints the coefficients do not depend on (e.g. a base joint about
the gravity axis) are detected and left out. The result (:class:`FlexiblePlant`) costs a
few thousand flops instead of ~200 000.

Discretisation and filter
-------------------------
One step of :func:`ekf_step_function` takes the prior ``x̂_{k|k−1}``, ``P_{k|k−1}``, the
inputs ``u_k`` and the signals ``y_k`` and

1. evaluates the plant coefficients at ``u_k`` (held over the step; evaluating them at
   the RK4 stage times changes nothing measurable);
2. **update** with ``y_k``: ``h(x, u_k)`` is the kinematic measurement model with ``δ̈``
   from the plant; ``H = ∂h/∂x`` by CasADi differentiation; ``S = H P Hᵀ + R`` is
   factored by an unrolled Cholesky; ``K = P Hᵀ S⁻¹``; ``x̂⁺ = x̂ + K (y − h)``; Joseph
   form ``P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ``, symmetrised. With a diagonal ``R`` the
   same update is done channel by channel (scalar Joseph updates, ``H`` linearised at
   the prior; ``update`` of :func:`ekf_step_function`);
3. **prediction** over ``dt`` by one classical RK4 step of the plant;
   ``Φ = ∂x_{k+1}/∂x̂⁺`` by CasADi differentiation through that RK4 step;
   ``P_{k+1|k} = Φ P⁺ Φᵀ + Q dt``, symmetrised.

``Q`` is the continuous-time process-noise intensity of eq. 179 (``Ṗ = AP + PAᵀ + Q``),
applied as ``Q·dt`` per step; ``R`` is the covariance of one sample of the signals (eq.
185–186). Sensor dropouts: the ``mask`` input (1 valid, 0 missing) zeroes that channel's
row of ``H`` and its innovation (NaN-safe: the masked ``y`` is never used in arithmetic)
and replaces its variance by 1 with no correlation, so the gain column of that channel is
exactly zero — the update of that channel is skipped without branches, in Python and in C.

The square-root form (§5.4.4.1, ``sqrt=True``) carries ``S`` with ``P = S Sᵀ`` and
replaces both covariance steps by triangularisations of the array algorithms,
``[√R, H S; 0, S] → [S_e, 0; K̄, S⁺]`` and ``[Φ S⁺, √(Q dt)] → [S_{k+1}, 0]`` (QR of the
transposed arrays); ``P`` stays symmetric positive semi-definite by construction.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.dynamics import FlexibleModel, PointwiseProvider
>>> from casflex.sensors import SensorSet, StrainPair
>>> robot = load("problems/arm2link.toml")
>>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3), name="sg")])
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
>>> plant = tabulate_plant(model)
>>> step = ekf_step_function(plant, ss, Q=5e-6, R=9e-14, dt=1e-3)
>>> step.name_in(), step.name_out()
(['x', 'P', 'u', 'y', 'mask'], ['x_next', 'P_next', 'x_post'])
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from casflex.errors import ModelError

__all__ = [
    "FlexiblePlant",
    "tabulate_plant",
    "exact_plant_function",
    "ekf_step_function",
    "ekf_functions",
    "full_state_step_function",
    "EKFResult",
    "run_ekf",
    "highpass",
    "highpass_cutoff",
    "prefilter_initial",
    "rigid_signal_function",
    "SimulatedData",
    "simulate_data",
]


# ----------------------------------------------------------------------------- plant


def exact_plant_function(model):
    """``casadi.Function`` ``(u, x) -> dddelta``: the model's flexible rows solved for δ̈.

    Exact but large (the reference the tabulated plant is checked against).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel

    Returns
    -------
    casadi.Function
        ``flex_exact (u, x) -> dddelta`` with ``u = [q; q̇; q̈]`` (3n) and
        ``x = [δ; δ̇]`` (2m); the model's ``prescribed_dddelta`` (m).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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


@dataclass
class FlexiblePlant:
    """The flexible rows to first or second order in Δ,
    ``δ̈ = r₀(u) + J_δ(u) δ + J_δ̇(u) δ̇ [+ W(u) (x_a x_b)_{a≤b}]``.

    Built by :func:`tabulate_plant`. Coefficient array layout: ``coef[k, i, c]`` for
    monomial ``k`` of ``(q̇, q̈)`` (:attr:`monomials`), mode row ``i`` and column ``c``
    (0: r₀, 1..m: J_δ, m+1..2m: J_δ̇, then one column per pair of :attr:`pairs`).

    Attributes
    ----------
    model : casflex.dynamics.FlexibleModel
    monomials : list of tuple
    shape_joints, fourier_joints : tuple of int
        Joints tabulated with B-splines, joints expanded in Fourier series.
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

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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

    model: object
    monomials: list
    shape_joints: tuple
    fourier_joints: tuple
    degree: int
    table: object
    constant: object
    pattern: np.ndarray
    info: dict = field(default_factory=dict)
    order: int = 1
    keep: object = None

    @property
    def pairs(self):
        """Index pairs ``(a, b)``, ``a ≤ b``, of the quadratic terms ``x_a x_b`` (columns
        ``2m+1 ...`` of the coefficient layout); empty for a first-order plant."""
        if self.order < 2:
            return []
        nx = 2 * self.m
        return [(a, b) for a in range(nx) for b in range(a, nx)]

    @property
    def n(self):
        """Number of joints."""
        return self.model.n

    @property
    def m(self):
        """Number of modes."""
        return self.model.m

    def coefficients(self, q, dq, ddq, coriolis=True, stiffness_scale=1.0, quadratic=False):
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
        >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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
        q = ca.SX(ca.vertcat(*[q[i] for i in range(self.n)]))
        L = (2 * self.degree + 1) ** len(self.fourier_joints)
        nnz = int(self.pattern.sum())
        phi = ca.SX.ones(1)
        for j in self.fourier_joints:
            phi = ca.vec(ca.vertcat(*_fourier_basis(q[j], self.degree)) @ phi.T)
        if self.keep is None:
            if self.table is not None:
                qs = ca.vertcat(*[q[j] for j in self.shape_joints])
                vals = ca.SX(self.table.function("coef")(qs))
                A = ca.reshape(vals, nnz, L)  # stored column-major: nnz fastest
            else:
                A = ca.SX(ca.DM(self.constant.T))
            entries = A @ phi if L > 1 else A[:, 0]
        else:  # only the kept Fourier coefficients (tabulate_plant, prune)
            keep = np.asarray(self.keep, dtype=bool).reshape(L, nnz)
            flat = np.flatnonzero(keep.ravel())  # index l * nnz + e of the stored layout
            if self.table is not None:
                qs = ca.vertcat(*[q[j] for j in self.shape_joints])
                vals = ca.SX(self.table.function("coef", entries=flat)(qs))
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

    def quadratic_terms(self, x):
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
        >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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

    def function(self, coriolis=True, stiffness_scale=1.0):
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
        >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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

    def rhs_function(self, coriolis=True, stiffness_scale=1.0, quadratic=True):
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
        >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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


def tabulate_plant(model, *, grid=None, step=None, degree=2, eps=1e-4, check=True,
                   seed=0, order=2, eps2=1e-3, cache_dir=None, prune=1e-6):
    """Tabulate the flexible plant of ``model`` to first or second order in Δ (module
    docstring).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    grid : sequence of array_like, optional
        Axes over the shape joints [rad]; default the model's table grid when the provider
        is a :class:`casflex.model.TableProvider`, else :func:`casflex.model.default_grid`
        with ``step``.
    step : float, optional
        Grid step [rad] when no grid is known.
    degree : int
        Fourier degree in the other joints (2 is exact for rigid-body kinematics).
    eps : float
        Central-difference step in Δ for the first-order terms [√kg m, √kg m/s].
    order : {1, 2}
        Order of the expansion in Δ. 2 (default) adds the products ``x_a x_b`` (the
        centripetal and gyroscopic terms of the flexible rates, the change of the mass
        matrix with δ): for the Table 8 arm on the Table 9 moves they are ~1 % of δ̈ and
        limit the velocity estimates of a first-order plant to ~25–100× below the states.
    eps2 : float
        Step of the second differences for the second-order terms [√kg m, √kg m/s].
    check : bool
        Compare with the exact plant at random points; the largest relative error goes to
        ``info["check_rel_error"]``.
    seed : int
        Random seed of the dependence detection and the check.
    cache_dir : str or pathlib.Path or False, optional
        Disk cache (default :func:`casflex.modal.tables.default_cache_dir`; ``False``
        disables it). The file ``plant-<key>.npz`` is keyed on the SHA-256 of the model's
        exact flexible rows (their serialised CasADi graph, modal tables included), the
        grid, every option above and the casflex and CasADi versions; it is written
        atomically and carries its key, so a stale or foreign file is never read (it is
        recomputed and overwritten). ``info["from_cache"]`` tells which happened.
    prune : float or None
        Leave out of the evaluation (:attr:`FlexiblePlant.keep`) every Fourier coefficient
        whose largest magnitude over the grid is below ``prune`` times that of the
        largest Fourier coefficient of the same entry (``None`` or 0: keep all). The
        dropped ones are the harmonics an entry does not have, tabulated as round-off of
        the differences: for the Table 8 arm with three modes 666 of 950 lie below 4e-10
        of their entry's largest and the others above 0.18 (the default 1e-6 sits in this
        gap); the coefficients change by less than 1e-9 relative and the lookup and the
        Fourier sum shrink 3×. Applied after the cache (the stored table is complete);
        ``info["pruned"]`` counts the dropped values.

    Returns
    -------
    FlexiblePlant

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> plant = tabulate_plant(model)
    >>> plant.fourier_joints, plant.info["check_rel_error"] < 1e-6
    ((1, 2), True)
    >>> full = tabulate_plant(model, prune=None)   # every Fourier coefficient evaluated
    >>> full.keep is None, plant.keep.shape, int(plant.keep.sum()), plant.info["pruned"]
    (True, (25, 31), 435, 340)
    """
    import time

    from casflex._cache import default_cache_dir, load_verified, save_verified
    from casflex.modal.tables import ModalTable
    from casflex.model import default_grid

    t0 = time.perf_counter()
    if order not in (1, 2):
        raise ModelError(f"order must be 1 or 2 (expansion in Δ); got {order!r}")
    n, m = model.n, model.m
    rng = np.random.default_rng(seed)
    fexact = exact_plant_function(model)
    shape = tuple(model.provider.shape_joints)
    others = [j for j in range(n) if j not in shape]
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
    if cache_dir is not False:
        key = _plant_key(fexact, table_grid, periodic, fourier, degree=degree, eps=eps,
                         eps2=eps2, order=order, check=check, seed=seed)
        path = Path(default_cache_dir() if cache_dir is None else cache_dir) / (
            f"plant-{key[:32]}.npz")
        hit = load_verified(path, key)
        if hit is not None:
            return _pruned(_plant_from_arrays(model, mono, shape, fourier, degree, order, hit,
                                              time.perf_counter() - t0), prune)

    # all (q, u, x) evaluation points
    nx = 2 * m
    xdes = [np.zeros(nx)]
    for i in range(nx):
        e = np.zeros(nx)
        e[i] = eps
        xdes += [e, -e]
    pairs = [(a, b) for a in range(nx) for b in range(a, nx)] if order == 2 else []
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
    Us, Xs = [], []
    for gp in gpoints:
        for fs in fsamples:
            q = np.zeros(n)
            for ax, j in enumerate(shape):
                q[j] = table_grid[ax][gp[ax]]
            for a, j in enumerate(fourier):
                q[j] = thetas[fs[a]]
            for dq, ddq in designs:
                for x in xdes:
                    Us.append(np.r_[q, dq, ddq])
                    Xs.append(x)
    U = np.array(Us).T
    X = np.array(Xs).T
    N = U.shape[1]
    R = np.asarray(fexact.map(N)(U, X))  # (m, N)
    nd, ndes = len(designs), len(xdes)
    R = R.reshape(m, len(gpoints), len(fsamples), nd, ndes)
    cols = np.empty((m, len(gpoints), len(fsamples), nd, 2 * m + 1 + len(pairs)))
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
    # monomial coefficients, then Fourier coefficients
    coef = np.einsum("kd,igfdc->gfkic", Dinv, cols)  # (G, F, mono, m, 2m+1)
    coef = np.einsum("lf,gfkic->glkic", Binv, coef)  # (G, L, mono, m, 2m+1)
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
    """SHA-256 identifying a tabulated plant (see :func:`tabulate_plant`, ``cache_dir``)."""
    from casflex import __version__

    h = hashlib.sha256()
    h.update(fexact.serialize().encode())
    meta = {"casflex": __version__, "casadi": ca.__version__, "fourier": list(fourier),
            "periodic": [bool(p) for p in periodic], "options": options,
            "grid": [np.asarray(a, dtype=float).tolist() for a in (grid or ())]}
    h.update(json.dumps(meta, sort_keys=True).encode())
    return h.hexdigest()


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


# ----------------------------------------------------------------------------- filter


def _chol(S):
    """Unrolled Cholesky factor (lower) of a symmetric positive definite SX matrix."""
    r = S.shape[0]
    L = ca.SX(r, r)
    for j in range(r):
        s = S[j, j]
        for k in range(j):
            s = s - L[j, k] ** 2
        L[j, j] = ca.sqrt(s)
        for i in range(j + 1, r):
            t = S[i, j]
            for k in range(j):
                t = t - L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    return L


def _lower_solve(L, B):
    """Solve L X = B by forward substitution (L lower triangular)."""
    r = L.shape[0]
    rows = []
    for i in range(r):
        t = B[i, :]
        for k in range(i):
            t = t - L[i, k] * rows[k]
        rows.append(t / L[i, i])
    return ca.vertcat(*rows)


def _upper_solve(U, B):
    """Solve U X = B by back substitution (U upper triangular)."""
    r = U.shape[0]
    rows = [None] * r
    for i in reversed(range(r)):
        t = B[i, :]
        for k in range(i + 1, r):
            t = t - U[i, k] * rows[k]
        rows[i] = t / U[i, i]
    return ca.vertcat(*rows)


def _tria(A):
    """Lower-triangular L with L Lᵀ = A Aᵀ (QR of Aᵀ), shape rows(A) × rows(A)."""
    _, R = ca.qr(A.T)
    return R.T[:, :A.shape[0]]


def _as_cov(value, size, what):
    a = np.asarray(value, dtype=float)
    if a.ndim == 0:
        a = a * np.eye(size)
    elif a.ndim == 1:
        a = np.diag(a)
    if a.shape != (size, size) or not np.all(np.isfinite(a)):
        raise ModelError(f"{what} must be a scalar, a vector of {size} variances or a "
                         f"{size} x {size} matrix; got shape {np.shape(value)}")
    if not np.allclose(a, a.T) or np.min(np.linalg.eigvalsh(0.5 * (a + a.T))) < 0:
        raise ModelError(f"{what} must be symmetric positive semi-definite")
    return a


def ekf_step_function(plant, sensors, Q, R, dt, *, sqrt=False, coriolis=True,
                      stiffness_scale=1.0, rigid_removed=False, linear_measurement=False,
                      prefilter=None, name="ekf_step", jacobians="exact", cse=True,
                      update="auto", lean=True):
    """One EKF step as an SX ``casadi.Function`` (module docstring).

    Parameters
    ----------
    plant : FlexiblePlant
    sensors : casflex.sensors.SensorSet
        The model of ``plant`` must tabulate ``sensors.points``.
    Q : float, array_like
        Continuous process-noise intensity on ``[δ; δ̇]`` (scalar × I, diagonal or
        matrix), applied as ``Q dt`` per step.
    R : float, array_like
        Covariance of one sample of the signals.
    dt : float
        Sample time [s].
    sqrt : bool
        Square-root form: the covariance input/outputs are ``S`` (``P = S Sᵀ``), named
        ``S``, ``S_next``.
    coriolis, stiffness_scale
        Estimator-model variations (:meth:`FlexiblePlant.coefficients`).
    rigid_removed : bool
        The signals given are ``y − y_rigid(u)`` (rigid-motion part of the accelerometers
        removed, e.g. before a high-pass prefilter); the model subtracts it as well.
    linear_measurement : bool
        Use the measurement model linearised at Δ = 0 (eq. 164–167) instead of the full
        kinematic one (default). Cheaper, but the neglected second-order terms (e.g. the
        centripetal acceleration of the flexible rotation rates) reach 0.5 m/s² for the
        Table 8 arm, whose tip deflects by several cm: the velocity estimates fail.
    prefilter : float, optional
        Cut-off ω_c [rad/s] of a first-order high-pass applied to the signals against
        offsets (§5.5.1.1; :func:`highpass_cutoff` gives one decade below the lowest
        natural frequency). The same filter is applied to the predicted signals
        ``h(x̂⁻, u)`` and the innovation is the difference of the two filtered signals:
        filtering the measurements alone (the dissertation's set-up) also removes the
        low-frequency part of the flexible signals during a move, which biases the
        velocity estimates. Adds the input ``f`` and output ``f_next`` (filter state,
        4 r numbers, start at 0: the filter at rest).
    name : str
    jacobians : {"exact", "first_order", "linearized"}
        ``"exact"``: ``Φ`` by CasADi differentiation through the RK4 step and ``H`` through
        ``h`` and the plant at the estimate. ``"first_order"`` (second-order plants): the
        means use the full plant, but ``Φ`` and the plant's share of ``H`` are those of
        its first-order part (``∂δ̈/∂x = [J_δ, J_δ̇]``, i.e. the second-order terms, ~1 % of
        δ̈, are left out of the covariance propagation): ~30 % fewer operations. The same
        as ``"exact"`` for first-order plants. ``"linearized"``: as ``"first_order"``,
        and ``∂h/∂[x; δ̈]`` taken at ``Δ = 0`` (``δ̈ = r₀``), i.e. ``H`` is that of the
        expansion of the measurement to first order in Δ, a function of ``u`` only; ``h``
        itself stays the full kinematic model. ~9 % fewer operations than
        ``"first_order"``; on the Table 9 studies with accelerometers the δ̇ errors change
        by −60 … +30 % (all still > 100× below the states).
    cse : bool
        Common-subexpression elimination of the SX graph (CasADi option ``cse``; same
        operations, so the same results, fewer instructions).
    update : {"auto", "batch", "sequential"}
        Measurement update. ``"batch"``: all channels at once (``S = H P Hᵀ + R``,
        unrolled Cholesky, ``K = P Hᵀ S⁻¹``, Joseph form). ``"sequential"`` (diagonal
        ``R``, not with ``sqrt``): one scalar update per channel, each in Joseph form
        ``(I − k h) P (I − k h)ᵀ + k r kᵀ`` evaluated in closed form for the rank-one
        ``k h`` on one triangle and mirrored (exactly symmetric), with ``H`` linearised at
        the prior for every channel, so the same update as ``"batch"`` up to rounding
        (no square roots, no triangular solves; ~1 000 fewer operations for 6 channels).
        ``"auto"``: ``"sequential"`` when ``R`` is diagonal and ``sqrt`` is false.
    lean : bool
        Evaluate in the measurement model only the modal-table entries it uses, from one
        small B-spline (:func:`casflex.sensors.kinematic_measurement`, ``lean``): the
        same expressions to rounding; ``False``: the model's spline of every quantity.

    Returns
    -------
    casadi.Function
        ``(x, P, u, y, mask[, f]) -> (x_next, P_next, x_post[, f_next])``: the prior of the
        next step, its covariance, and the filtered estimate ``x̂_{k|k}``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> f = ekf_step_function(tabulate_plant(model), ss, 5e-6, 9e-14, 1e-3)
    >>> x1, P1, xp = f([1e-3, 0], np.eye(2) * 1e-4, np.zeros(9), [0, 0], [1, 1])
    >>> bool(abs(float(xp[0])) < 1e-4)   # strain zero: the estimate moves toward δ = 0
    True
    >>> g = ekf_step_function(tabulate_plant(model), ss, 5e-6, 9e-14, 1e-3, update="batch",
    ...                       jacobians="linearized")
    >>> xb = g([1e-3, 0], np.eye(2) * 1e-4, np.zeros(9), [0, 0], [1, 1])[2]
    >>> bool(np.allclose(xb, xp, rtol=1e-9, atol=1e-15))   # strain is linear in δ: same H
    True
    """
    from casflex.sensors import kinematic_measurement

    model = plant.model
    n, m = model.n, model.m
    nx = 2 * m
    ny = sensors.n_outputs
    dt = float(dt)
    if not dt > 0:
        raise ModelError(f"dt must be > 0 [s]; got {dt}")
    if jacobians not in ("exact", "first_order", "linearized"):
        raise ModelError("jacobians must be 'exact', 'first_order' or 'linearized'; got "
                         f"{jacobians!r}")
    Qc = _as_cov(Q, nx, "Q")
    Rm_ = _as_cov(R, ny, "R")
    hkin = kinematic_measurement(model, sensors, lean=lean)
    x = ca.SX.sym("x", nx)
    Pin = ca.SX.sym("S" if sqrt else "P", nx, nx)
    u = ca.SX.sym("u", 3 * n)
    y = ca.SX.sym("y", ny)
    mask = ca.SX.sym("mask", ny)
    filt = ca.SX.sym("f", 4 * ny)
    q, dq, ddq = u[:n], u[n:2 * n], u[2 * n:]
    # placeholders: no derivative ever flows into the coefficient tables (AD through the
    # spline call nodes would evaluate their derivative splines for nothing)
    coef = plant.coefficients(q, dq, ddq, coriolis, stiffness_scale, quadratic=True)
    r0, Jd, Jv = ca.SX.sym("r0", m), ca.SX.sym("Jd", m, m), ca.SX.sym("Jv", m, m)
    W = ca.SX.sym("W", coef[3].shape)
    holders = ca.vertcat(r0, ca.vec(Jd), ca.vec(Jv), ca.vec(W))
    values = ca.vertcat(coef[0], ca.vec(coef[1]), ca.vec(coef[2]), ca.vec(coef[3]))

    def accel(xx):
        out = r0 + Jd @ xx[:m] + Jv @ xx[m:]
        return out + W @ plant.quadratic_terms(xx) if plant.pairs else out

    def f(xx):
        return ca.vertcat(xx[m:], accel(xx))

    def accel_lin(xx):
        return r0 + Jd @ xx[:m] + Jv @ xx[m:]

    exact_jac = jacobians == "exact" or not plant.pairs

    if linear_measurement:
        # eq. 164: y = h0(u) + ∂h/∂x x + ∂h/∂δ̈ δ̈ at Δ = 0, δ̈ from the plant
        xs, acs = ca.SX.sym("xs", nx), ca.SX.sym("acs", m)
        hs = hkin(xs, u, acs)
        zero = ca.DM.zeros(nx + m)
        Jx = ca.substitute(ca.jacobian(hs, ca.vertcat(xs, acs)), ca.vertcat(xs, acs), zero)
        h0 = ca.substitute(hs, ca.vertcat(xs, acs), zero)
        hx = h0 + Jx @ ca.vertcat(x, accel(x))
        H = ca.jacobian(hx, x)
    else:
        # ∂h/∂[x; δ̈] in reverse mode (ny adjoint sweeps: much leaner than forward mode
        # here), then the chain rule through δ̈ = r0 + Jd δ + Jv δ̇
        xs, acs = ca.SX.sym("xs", nx), ca.SX.sym("acs", m)
        hs = hkin(xs, u, acs)
        Js = ca.jtimes(hs, ca.vertcat(xs, acs), ca.SX.eye(ny), True).T
        sub = ca.vertcat(xs, acs)
        val = ca.vertcat(x, accel(x))
        hx = ca.substitute(hs, sub, val)
        Jxa = ca.substitute(Js, sub, val)
        if jacobians == "linearized":
            # ∂h/∂[x; δ̈] at Δ = 0 (δ̈ = r0 there): H of the expansion of h to first order
            Jxa = ca.substitute(Js, sub, ca.vertcat(ca.DM.zeros(nx), r0))
        dacc = ca.jacobian(accel(x), x) if exact_jac else ca.horzcat(Jd, Jv)
        H = Jxa[:, :nx] + Jxa[:, nx:] @ dacc
    if rigid_removed:
        hx = hx - rigid_signal_function(model, sensors)(u)
    valid = ca.vertcat(*[mask[i] > 0.5 for i in range(ny)])
    if prefilter is not None:
        # the same first-order high-pass (Tustin) on the signals and on the predicted
        # signals; the innovation compares the two (offsets and the low-frequency part
        # drop out of both). State f = [y_prev, hp_y, h_prev, hp_h]; a missing sample
        # holds the filter of its channel.
        wc = float(prefilter)
        if not wc > 0:
            raise ModelError(f"prefilter cut-off must be > 0 [rad/s]; got {prefilter}")
        fa = (2.0 - wc * dt) / (2.0 + wc * dt)
        fb = 2.0 / (2.0 + wc * dt)
        yprev, hpy, hprev, hph = (filt[i * ny:(i + 1) * ny] for i in range(4))
        yin = ca.vertcat(*[ca.if_else(valid[i], y[i], yprev[i]) for i in range(ny)])
        hin = ca.vertcat(*[ca.if_else(valid[i], hx[i], hprev[i]) for i in range(ny)])
        hpy_n = fa * hpy + fb * (yin - yprev)
        hph_n = fa * hph + fb * (hin - hprev)
        f_next = ca.vertcat(yin, hpy_n, hin, hph_n)
        e = ca.vertcat(*[ca.if_else(valid[i], hpy_n[i] - hph_n[i], 0) for i in range(ny)])
    else:
        e = ca.vertcat(*[ca.if_else(valid[i], y[i] - hx[i], 0) for i in range(ny)])
    Mv = ca.diag(valid)
    Hm = Mv @ H
    Rm = Mv @ ca.DM(Rm_) @ Mv + ca.diag(1 - valid)
    diagonal_r = not np.any(Rm_ - np.diag(np.diag(Rm_)))
    if update not in ("auto", "batch", "sequential"):
        raise ModelError(f"update must be 'auto', 'batch' or 'sequential'; got {update!r}")
    if update == "sequential" and (sqrt or not diagonal_r):
        raise ModelError("update='sequential' needs a diagonal R and sqrt=False")
    sequential = update == "sequential" or (update == "auto" and diagonal_r and not sqrt)
    I = ca.SX.eye(nx)
    if sequential:
        # one scalar Joseph update per channel (diagonal R: the same update as the batch
        # one, H linearised at the prior); a masked channel has h_j = 0, r_j = 1: k = 0
        P = 0.5 * (Pin + Pin.T)
        xp = x
        for j in range(ny):
            hj = Hm[j, :]
            ej = e[j] - hj @ (xp - x)  # innovation of the linearised model at the prior
            xp, P = _scalar_joseph(P, xp, hj, ej, Rm[j, j])
        Pp = P
    elif not sqrt:
        P = 0.5 * (Pin + Pin.T)
        PHt = P @ Hm.T
        Sinn = Hm @ PHt + Rm
        Ls = _chol(Sinn)
        Kt = _upper_solve(Ls.T, _lower_solve(Ls, PHt.T))  # K^T = S^-1 H P
        K = Kt.T
        xp = x + K @ e
        IKH = I - K @ Hm
        # Joseph form, each symmetric product evaluated on one triangle and mirrored
        Pp = _sandwich(IKH, P) + _sandwich(K, Rm)
    else:
        S = Pin
        sqR = _chol(Rm)
        pre = ca.blockcat([[sqR, Hm @ S], [ca.SX(nx, ny), S]])
        post = _tria(pre)
        Se, Kbar, Sp = post[:ny, :ny], post[ny:, :ny], post[ny:, ny:]
        xp = x + Kbar @ _lower_solve(Se, e)
    # prediction: one RK4 step of the (affine) plant, coefficients held at u_k
    xs = ca.SX.sym("xs", nx)
    k1 = f(xs)
    k2 = f(xs + 0.5 * dt * k1)
    k3 = f(xs + 0.5 * dt * k2)
    k4 = f(xs + dt * k3)
    xn_s = xs + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    if exact_jac:
        Phi_s = ca.jacobian(xn_s, xs)
    else:  # the RK4 Jacobian of the first-order part (independent of the state)
        ks = [None] * 4

        def flin(xx):
            return ca.vertcat(xx[m:], accel_lin(xx))

        ks[0] = flin(xs)
        ks[1] = flin(xs + 0.5 * dt * ks[0])
        ks[2] = flin(xs + 0.5 * dt * ks[1])
        ks[3] = flin(xs + dt * ks[2])
        Phi_s = ca.jacobian(xs + dt / 6.0 * (ks[0] + 2 * ks[1] + 2 * ks[2] + ks[3]), xs)
    xn = ca.substitute(xn_s, xs, xp)
    Phi = ca.substitute(Phi_s, xs, xp)
    Qd = Qc * dt
    if not sqrt:
        Pn = _sandwich(Phi, Pp) + ca.DM(Qd)
    else:
        sqQ = ca.DM(np.linalg.cholesky(Qd) if np.all(np.linalg.eigvalsh(Qd) > 0)
                    else _psd_sqrt(Qd))
        Pn = _tria(ca.horzcat(Phi @ Sp, sqQ))
    cov = "S" if sqrt else "P"
    ins, names_in = [x, Pin, u, y, mask], ["x", cov, "u", "y", "mask"]
    outs, names_out = [xn, Pn, xp], ["x_next", cov + "_next", "x_post"]
    if prefilter is not None:
        ins.append(filt)
        names_in.append("f")
        outs.append(f_next)
        names_out.append("f_next")
    outs = ca.substitute(outs, [holders], [values])
    return ca.Function(name, ins, outs, names_in, names_out, {"cse": bool(cse)})


def _scalar_joseph(P, x, h, e, r):
    """Update of ``(x, P)`` (P symmetric) with one scalar measurement: row ``h``,
    innovation ``e``, variance ``r``; Joseph form ``(I − k h) P (I − k h)ᵀ + k r kᵀ`` in
    closed form for the rank-one ``k h`` (valid for any gain ``k``), its lower triangle
    evaluated and mirrored (exactly symmetric).

    With ``b = P hᵀ``: ``(I − k h) P = P − k bᵀ``, and times ``(I − k h)ᵀ`` it is
    ``P − k bᵀ − c kᵀ`` with ``c = b − k (h b)``."""
    nx = P.shape[0]
    b = P @ h.T
    hb = ca.dot(h.T, b)
    inv = 1.0 / (hb + r)
    k = b * inv
    c = b - k * hb
    rk = r * k
    out = ca.SX(nx, nx)
    for i in range(nx):
        for l in range(i + 1):
            v = P[i, l] - k[i] * b[l] - c[i] * k[l] + rk[i] * k[l]
            out[i, l] = v
            if i != l:
                out[l, i] = v
    return x + k * e, out


def _sandwich(A, P):
    """``A P Aᵀ`` for symmetric ``P``: the lower triangle evaluated, the upper mirrored
    (exactly symmetric, ~40 % fewer operations than the full product)."""
    B = A @ P
    r = A.shape[0]
    out = ca.SX(r, r)
    for i in range(r):
        for j in range(i + 1):
            v = ca.dot(B[i, :].T, A[j, :].T)
            out[i, j] = v
            if i != j:
                out[j, i] = v
    return out


def full_state_step_function(plant, sensors, Q, R, dt, *, Q_jerk, R_encoder,
                             coriolis=True, name="ekf_full_step"):
    """One step of the full-state EKF: joints and modes from encoders and sensors.

    For set-ups with encoders and accelerometers but no measured ``q̇``, ``q̈``: the state is
    ``z = [q; q̇; q̈; δ; δ̇]`` (3n + 2m). The joints follow a kinematic model driven by
    white jerk (``d q̈/dt = w``, intensity ``Q_jerk``; no torques or joint dynamics needed),
    the modes the tabulated plant at the joint states of ``z``. The measurements are the
    encoder angles ``q`` and the signals of ``sensors``, ``y = [q_enc; y_sensors]``.

    The step is that of :func:`ekf_step_function` (update with Joseph form, then one RK4
    step; Jacobians by CasADi differentiation, through the plant's spline tables as well):
    the plant coefficients are evaluated at the posterior joint state and held over the
    step (the joints move by ``q̇ dt`` in it), the RK4 step integrates the joint chain and
    the modes together.

    Parameters
    ----------
    plant : FlexiblePlant
    sensors : casflex.sensors.SensorSet
    Q : float or array_like
        Continuous process-noise intensity on ``[δ; δ̇]`` (as in :func:`ekf_step_function`).
    R : float or array_like
        Covariance of one sample of the sensor signals.
    dt : float
        Sample time [s].
    Q_jerk : float or array_like
        Continuous intensity of the joint jerk [rad²/s⁵] (scalar, n variances or n × n).
    R_encoder : float or array_like
        Covariance of one encoder sample [rad²].
    coriolis : bool
        As in :func:`ekf_step_function`.
    name : str

    Returns
    -------
    casadi.Function
        ``(x, P, u, y, mask) -> (x_next, P_next, x_post)`` with ``x`` the full state
        ``z``, ``u`` empty (0 × 1, the joint motion is estimated) and ``y``, ``mask`` of
        ``n + r`` rows (encoders first). Runs with :func:`run_ekf` (``u=None``).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, axes="xy")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> f = full_state_step_function(tabulate_plant(model, cache_dir=False), ss, 5e-6,
    ...                              6e-6, 1e-3, Q_jerk=1e2, R_encoder=1e-8)
    >>> f.size1_in("x"), f.size1_in("y")
    (11, 5)
    """
    from casflex.sensors import kinematic_measurement

    model = plant.model
    n, m = model.n, model.m
    nx = 3 * n + 2 * m
    ns = sensors.n_outputs
    ny = n + ns
    dt = float(dt)
    if not dt > 0:
        raise ModelError(f"dt must be > 0 [s]; got {dt}")
    Qf = _as_cov(Q, 2 * m, "Q")
    Qj = _as_cov(Q_jerk, n, "Q_jerk")
    Rs = _as_cov(R, ns, "R")
    Re = _as_cov(R_encoder, n, "R_encoder")
    Rall = np.zeros((ny, ny))
    Rall[:n, :n], Rall[n:, n:] = Re, Rs
    Qc = np.zeros((nx, nx))
    Qc[2 * n:3 * n, 2 * n:3 * n] = Qj
    Qc[3 * n:, 3 * n:] = Qf
    hkin = kinematic_measurement(model, sensors)
    x = ca.SX.sym("x", nx)
    Pin = ca.SX.sym("P", nx, nx)
    u = ca.SX.sym("u", 0, 1)
    y = ca.SX.sym("y", ny)
    mask = ca.SX.sym("mask", ny)

    def parts(z):
        return z[:n], z[n:2 * n], z[2 * n:3 * n], z[3 * n:]

    def coefs(z):
        q, dq, ddq, _ = parts(z)
        return plant.coefficients(q, dq, ddq, coriolis, quadratic=True)

    def accel(c, xf):
        r0, Jd, Jv, W = c
        out = r0 + Jd @ xf[:m] + Jv @ xf[m:]
        return out + W @ plant.quadratic_terms(xf) if plant.pairs else out

    def meas(z):
        q, dq, ddq, xf = parts(z)
        uu = ca.vertcat(q, dq, ddq)
        return ca.vertcat(q, hkin(xf, uu, accel(coefs(z), xf)))

    # update
    hx = meas(x)
    H = ca.jacobian(hx, x)
    valid = ca.vertcat(*[mask[i] > 0.5 for i in range(ny)])
    e = ca.vertcat(*[ca.if_else(valid[i], y[i] - hx[i], 0) for i in range(ny)])
    Mv = ca.diag(valid)
    Hm = Mv @ H
    Rm = Mv @ ca.DM(Rall) @ Mv + ca.diag(1 - valid)
    P = 0.5 * (Pin + Pin.T)
    PHt = P @ Hm.T
    Ls = _chol(Hm @ PHt + Rm)
    K = _upper_solve(Ls.T, _lower_solve(Ls, PHt.T)).T
    xp = x + K @ e
    Pp = _sandwich(ca.SX.eye(nx) - K @ Hm, P) + _sandwich(K, Rm)
    # prediction: RK4 of the joint chain and the modes, coefficients held at the posterior
    xs = ca.SX.sym("xs", nx)
    c = coefs(xs)

    def f(z):
        _, dq, ddq, xf = parts(z)
        return ca.vertcat(dq, ddq, ca.SX.zeros(n), xf[m:], accel(c, xf))

    k1 = f(xs)
    k2 = f(xs + 0.5 * dt * k1)
    k3 = f(xs + 0.5 * dt * k2)
    k4 = f(xs + dt * k3)
    xn_s = xs + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    Phi_s = ca.jacobian(xn_s, xs)
    xn = ca.substitute(xn_s, xs, xp)
    Phi = ca.substitute(Phi_s, xs, xp)
    Pn = _sandwich(Phi, Pp) + ca.DM(Qc * dt)
    return ca.Function(name, [x, Pin, u, y, mask], [xn, Pn, xp],
                       ["x", "P", "u", "y", "mask"], ["x_next", "P_next", "x_post"],
                       {"cse": True})


def _psd_sqrt(A):
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    return V @ np.diag(np.sqrt(np.clip(w, 0, None)))


def rigid_signal_function(model, sensors):
    """``u -> y_rigid``: the rigid-motion part contained in the signals (zero for strain
    gauges and for accelerometers declared with ``rigid = false``).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
        Must tabulate ``sensors.points``.
    sensors : casflex.sensors.SensorSet

    Returns
    -------
    casadi.Function
        ``y_rigid (u) -> y`` with ``u = [q; q̇; q̈]`` (3n), ``sensors.n_outputs`` signals.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([Accelerometer(3, 1.0, axes="z")])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> float(rigid_signal_function(model, ss)(np.zeros(9)))  # local z points down
    -9.81
    """
    from casflex.sensors import kinematic_measurement

    return kinematic_measurement(model, sensors, name="y_rigid", rigid_part=True)


def ekf_functions(model, sensors, Q, R, dt, *, plant=None, sqrt=False, coriolis=True,
                  stiffness_scale=1.0, rigid_removed=False, prefix="", jacobians="exact"):
    """The named functions of a real-time estimator, ready to combine or generate.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
        Must tabulate ``sensors.points``.
    sensors : casflex.sensors.SensorSet
    Q, R, dt
        Process-noise intensity, signal covariance and sample time [s]
        (:func:`ekf_step_function`).
    plant : FlexiblePlant, optional
        Default :func:`tabulate_plant` of ``model``.
    sqrt, coriolis, stiffness_scale, rigid_removed, jacobians
        Passed on to :func:`ekf_step_function` (``coriolis`` and ``stiffness_scale`` to
        the ``plant`` function as well).
    prefix : str
        Prepended to every function name (several estimators in one C bundle).

    Returns
    -------
    dict of str to casadi.Function
        ``ekf_step`` (:func:`ekf_step_function`, ``jacobians`` passed on), ``measurement``
        ``(x, u, dddelta) -> y`` (kinematic model), ``plant`` ``u -> (r0, Jd, Jv[, W])``
        (:meth:`FlexiblePlant.function`), ``rigid_signals`` ``u -> y_rigid``. Names get
        ``prefix``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> sorted(ekf_functions(model, ss, 5e-6, 9e-14, 1e-3))
    ['ekf_step', 'measurement', 'plant', 'rigid_signals']
    """
    from casflex.sensors import kinematic_measurement

    if plant is None:
        plant = tabulate_plant(model)
    step = ekf_step_function(plant, sensors, Q, R, dt, sqrt=sqrt, coriolis=coriolis,
                             stiffness_scale=stiffness_scale, rigid_removed=rigid_removed,
                             name=prefix + "ekf_step", jacobians=jacobians)

    def rename(f, new):
        return ca.Function(new, f.sx_in(), f.call(f.sx_in()), f.name_in(), f.name_out())

    return {
        "ekf_step": step,
        "measurement": rename(kinematic_measurement(model, sensors), prefix + "measurement"),
        "plant": rename(plant.function(coriolis, stiffness_scale), prefix + "plant"),
        "rigid_signals": rename(rigid_signal_function(model, sensors),
                                prefix + "rigid_signals"),
    }


# ----------------------------------------------------------------------------- runs


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


def prefilter_initial(plant, sensors, x0, u0, y0):
    """Prefilter state in steady state at the first sample: ``[y0, 0, h(x̂0, u0), 0]``.

    The difference between the first signals and their prediction is taken as an offset
    and removed from the start (a filter started at rest would let it decay with
    ``1/ω_c`` instead).

    Parameters
    ----------
    plant : FlexiblePlant
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
        (:func:`ekf_step_function`; ``f0`` of :func:`run_ekf`).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
    >>> prefilter_initial(tabulate_plant(model), ss, [0, 0], np.zeros(9), [1e-6, 0]).size
    8
    """
    from casflex.sensors import kinematic_measurement

    u0 = np.asarray(u0, dtype=float)
    x0 = np.asarray(x0, dtype=float)
    acc = np.asarray(plant.rhs_function()(u0, x0)).ravel()
    h0 = np.asarray(kinematic_measurement(plant.model, sensors)(x0, u0, acc)).ravel()
    y0 = np.asarray(y0, dtype=float).ravel()
    y0 = np.where(np.isfinite(y0), y0, h0)
    return np.concatenate([y0, np.zeros_like(y0), h0, np.zeros_like(h0)])


def highpass_cutoff(model, q):
    """Cut-off one decade below the lowest natural frequency at ``q`` [rad/s] (§5.5.1.1).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    q : array_like
        Configuration [rad] (n).

    Returns
    -------
    float
        ``min ω(q) / 10`` [rad/s], the ``prefilter`` of :func:`ekf_step_function`.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> round(highpass_cutoff(model, [0, 0, 0]), 3)
    0.831
    """
    w = ca.Function("w", [model.q], [model.omega])(np.asarray(q, dtype=float))
    return float(np.min(np.asarray(w))) / 10.0


def highpass(signal, dt, omega_c, start="rest"):
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
    if start not in ("rest", "first"):
        raise ModelError(f"start must be 'rest' or 'first'; got {start!r}")
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


def run_ekf(step, u, y, x0, P0, mask=None, f0=None):
    """Run an EKF step function over recorded arrays (one CasADi ``mapaccum`` call).

    Parameters
    ----------
    step : casadi.Function
        From :func:`ekf_step_function` (plain or square-root form; give ``P0`` as ``S0``
        for the latter).
    u : array_like or None
        (N, 3n) measured ``[q, q̇, q̈]``; ``None`` for steps without inputs
        (:func:`full_state_step_function`).
    y : array_like
        (N, r) signals; NaN marks a missing sample.
    x0, P0 : array_like
        Initial guess and its covariance (or square root).
    mask : array_like, optional
        (N, r) 1/0 validity; default ``isfinite(y)``.
    f0 : array_like, optional
        Initial prefilter state (steps with ``prefilter``); default 0, the filter at rest.
        :func:`prefilter_initial` starts it in steady state on the first samples.

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
        raise ModelError(f"u has {N} samples but y has {y.shape[0]}")
    valid = np.isfinite(y)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    yc = np.where(valid, y, 0.0)
    nx = step.size1_in(0)
    args = [np.asarray(x0, dtype=float).reshape(nx, 1), np.asarray(P0, dtype=float),
            u.T, yc.T, valid.astype(float).T]
    if step.n_in() == 6:  # prefilter state
        F = step.mapaccum("ekf_run", N, [0, 1, 5], [0, 1, 3])
        args.append(np.zeros(step.size1_in(5)) if f0 is None else np.asarray(f0, float))
    else:
        F = step.mapaccum("ekf_run", N, [0, 1], [0, 1])
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
    return EKFResult(x=xp, x_prior=np.vstack([np.asarray(x0, dtype=float).ravel(), xn]),
                     P=np.concatenate([P0m[None], Pn]))


# ----------------------------------------------------------------------------- data


@dataclass
class SimulatedData:
    """Simulated sensor data of a prescribed joint motion (:func:`simulate_data`).

    Attributes
    ----------
    t : numpy.ndarray
        (N,) sample times [s].
    u : numpy.ndarray
        (N, 3n) exact ``[q, q̇, q̈]``.
    x : numpy.ndarray
        (N, 2m) true ``[δ, δ̇]``.
    y_clean, y : numpy.ndarray
        (N, r) exact signals and signals with noise (and offset).

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> d = simulate_data(model, ss, Move([0, 0, 0], [-1, 0, 0], 0.2), t_end=0.01,
    ...                   noise=0.0, offset=1e-6)
    >>> d.t.shape, d.u.shape, d.x.shape, d.y.shape
    ((11,), (11, 9), (11, 2), (11, 2))
    >>> (d.y - d.y_clean).round(12).max().item()    # the sensor bias, no noise
    1e-06
    """

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    y_clean: np.ndarray
    y: np.ndarray


def simulate_data(model, sensors, move, dt=1e-3, t_end=None, noise=None, offset=0.0,
                  seed=0, x0=None):
    """Integrate the model's flexible rows along a move and sample the sensors.

    The truth uses the exact (nonlinear) flexible rows of the model
    (:func:`exact_plant_function`) with classical RK4 at step ``dt``, the joint motion
    evaluated at the RK4 stage times, and the exact measurement model
    (:func:`casflex.sensors.measurement_function`).

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    sensors : casflex.sensors.SensorSet
    move : casflex.moves.Move
    dt : float
        Sample and integration step [s].
    t_end : float, optional
        Default ``move.t_end``.
    noise : float or array_like, optional
        Standard deviation(s) of white noise added per sample (default the sensors'
        ``noise``, 0 where none is given).
    offset : float or array_like
        Constant offset added to every signal (sensor bias).
    seed : int
    x0 : array_like, optional
        Initial flexible state (default 0).

    Returns
    -------
    SimulatedData

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.moves import Move
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> d = simulate_data(model, ss, Move([0, 0, 0], [0, -1, 0], 0.2), t_end=0.05)
    >>> d.x.shape, d.y.shape
    ((51, 2), (51, 2))
    """
    from casflex.sensors import measurement_function

    n, m = model.n, model.m
    t_end = move.t_end if t_end is None else float(t_end)
    N = int(round(t_end / dt)) + 1
    t = np.arange(N) * dt
    fex = exact_plant_function(model)
    ut = ca.SX.sym("ut", 3 * n, 3)  # inputs at t, t + dt/2, t + dt
    xs = ca.SX.sym("x", 2 * m)

    def f(xx, uu):
        return ca.vertcat(xx[m:], fex(uu, xx))

    k1 = f(xs, ut[:, 0])
    k2 = f(xs + 0.5 * dt * k1, ut[:, 1])
    k3 = f(xs + 0.5 * dt * k2, ut[:, 1])
    k4 = f(xs + dt * k3, ut[:, 2])
    step = ca.Function("rk4", [xs, ut], [xs + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)])

    def sample(times):
        q, qd, qdd = move.sample(times)
        return np.hstack([q, qd, qdd])

    u0 = sample(t[:-1])
    uh = sample(t[:-1] + 0.5 * dt)
    u1 = sample(t[1:])
    U = np.stack([u0, uh, u1], axis=2)  # (N-1, 3n, 3)
    # mapaccum takes the per-step (3n x 3) inputs side by side
    Ucat = np.hstack([U[k] for k in range(N - 1)]) if N > 1 else np.zeros((3 * n, 0))
    xinit = np.zeros(2 * m) if x0 is None else np.asarray(x0, dtype=float)
    if N > 1:
        X = np.asarray(step.mapaccum("sim", N - 1)(xinit, Ucat)).T
        X = np.vstack([xinit, X])
    else:
        X = xinit[None]
    u = sample(t)
    h = measurement_function(model, sensors)
    Y = np.asarray(h.map(N)(X.T, u.T)[len(sensors)]).T
    rng = np.random.default_rng(seed)
    std = sensors.noise_std if noise is None else np.broadcast_to(
        np.asarray(noise, dtype=float), (sensors.n_outputs,))
    std = np.nan_to_num(std, nan=0.0)
    Yn = Y + rng.normal(size=Y.shape) * std + np.asarray(offset, dtype=float)
    return SimulatedData(t=t, u=u, x=X, y_clean=Y, y=Yn)
