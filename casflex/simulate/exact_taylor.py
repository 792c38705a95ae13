"""The exact-kinematics model truncated at a degree in δ: the error budget of a ``poly`` form.

``simulate_prescribed(method="poly")`` needs the modal rows as a polynomial in ``(δ, δ̇)``
whose coefficients depend on the configuration only. A model with
``kinematics="exact"`` has rows that are not polynomial in δ (the rods are rebuilt by
rotations). The polynomial form of degree ``p`` replaces every coefficient of the modal
rows that depends on ``(q, δ)`` by its Taylor polynomial of degree ``p`` in δ at δ = 0:
in ``M_δq(q, δ) q̈ + M_δδ(q, δ) δ̈ + h_δ(q, q̇, δ, δ̇) = 0`` the mass rows ``M_δq``,
``M_δδ``, the coefficients of the quadratic velocity terms of ``h_δ`` (in ``q̇ q̇``,
``q̇ δ̇`` and ``δ̇ δ̇``) and the gravity forces. (The stiffness ``Ω² δ`` and the damping
``2ζΩ δ̇`` are linear: exact at any ``p ≥ 1``.)

This module builds that truncated model's rows **without** forming the coefficients:
since ``q̇, q̈, δ̇`` enter the rows polynomially, the truncation in δ alone is the Taylor
polynomial along the ray through the state, ``Σ_{k≤p} g⁽ᵏ⁾(0) / k!`` with
``g(s) = rows(q, q̇, q̈, s δ, δ̇)`` (the degree-``k`` part of a polynomial in δ is
homogeneous, so its value at δ is the k-th derivative along ``s δ`` over ``k!``). CasADi
differentiates ``g`` ``p`` times in the scalar ``s`` (forward mode) and folds ``s = 0``.
This is the reference any ``poly`` form of the exact model must reproduce, and it
measures the order ``p`` the error budget needs (:func:`taylor_modal_rows`,
:func:`simulate_taylor`; ``benchmarks/bench_exact_poly.py --budget``). Measured with 5
modes on Table 9 move 3 (239 mm of tip deflection), the gap to the exact rows' run in %
of the peak: 4.3 (p = 1, about the default kinematics' miss), 0.10 (p = 2), 0.012
(p = 3); on the planar elbow move (2 rad in 1 s, 31 mm) 0.07, 4e-4, 3e-6. Degree 2 is
what the issue's 5 % budget needs. What the truncation neglects: the terms of degree
``p + 1`` and above in δ of the coefficients listed above (the stiffness and damping
are exact).

It is not a fast path: the rows along the ray cost several times the exact rows
(``p = 3``: ~5× the SX instructions). The ``poly`` form of degree 2,
:mod:`casflex.simulate.exact_poly`, reproduces it with coefficients interpolated in time
(measured: ``benchmarks/README_fidelity.md``, "poly for the exact kinematics").
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.errors import ModelError
from casflex.moves import reference_sampler
from casflex.simulate.integrators import LEFT_LIMIT, rk4_step, step_cache, time_grid

if TYPE_CHECKING:
    from casflex.model import FlexibleModel
    from casflex.moves import Move, ShapedMove

__all__ = ["taylor_modal_rows", "simulate_taylor"]

#: largest degree in δ offered (each degree multiplies the graph by ~2)
MAX_ORDER = 5


def taylor_modal_rows(model: FlexibleModel, order: int) -> ca.Function:
    """The modal accelerations of the model whose ``(q, δ)``-coefficients are truncated
    at degree ``order`` in δ (module docstring), memoised per model and order.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Any model with modes; for one with ``kinematics="truncated"`` and
        ``delta_order=1`` (M affine in δ, gravity to δ¹) ``order >= 1`` gives back its
        own rows.
    order : int
        Degree ``p`` in δ, 1 to 5.

    Returns
    -------
    casadi.Function
        ``dddelta_taylor (q, dq, ddq, delta, ddelta) -> dddelta``, the signature of the
        model's ``functions()["dddelta"]`` [rad, rad/s, rad/s², √kg m, √kg m/s].

    Examples
    --------
    The default kinematics keep M affine in δ: degree 1 is the model itself.

    >>> import numpy as np
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.5], count=2))
    >>> x = ([0.1, 0.3, 0.5], [0.5, -1.0, 2.0], [1.0, 0.0, -2.0], [0.02, -0.01], [0.3, 1.0])
    >>> a = taylor_modal_rows(model, 1)(*x).full()
    >>> b = model.functions()["dddelta"](*x).full()
    >>> bool(np.allclose(a, b, rtol=1e-12, atol=0.0))
    True
    """
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) \
            or not 1 <= order <= MAX_ORDER:
        raise ModelError(f"order must be an integer from 1 to {MAX_ORDER}; got {order!r}")
    if model.m == 0:
        raise ModelError("the truncation in delta needs a model with modes (m >= 1)")
    memo = step_cache(model)
    key = ("taylor_rows", int(order))
    hit = memo.get(key)
    if hit is not None:
        return hit
    n, m = model.n, model.m
    q, dq, d, dd, ddq = model.q, model.dq, model.delta, model.ddelta, model.ddq
    M, h = model.M, model.h
    # the modal rows' parts that depend on δ: M_δq q̈ + h_δ, and M_δδ (its upper triangle)
    iu = np.triu_indices(m)
    rows = ca.vertcat(M[n:, :n] @ ddq + h[n:],
                      *[M[n + int(i), n + int(k)] for i, k in zip(*iu, strict=True)])
    s = ca.SX.sym("s")
    ray = ca.substitute(rows, d, s * d)
    terms, derivative = [ray], ray
    for _ in range(int(order)):
        derivative = ca.jacobian(derivative, s)
        terms.append(derivative)
    polynomial = sum(t / math.factorial(k) for k, t in enumerate(terms))
    # folding s = 0 drops every product with a vanishing factor
    at_zero = ca.Function("ray", [q, dq, ddq, d, dd, s], [polynomial])(q, dq, ddq, d, dd, 0)
    r = at_zero[:m]
    Mdd = ca.SX.zeros(m, m)
    for idx, (i, k) in enumerate(zip(*iu, strict=True)):
        Mdd[int(i), int(k)] = Mdd[int(k), int(i)] = at_zero[m + idx]
    f = ca.Function("dddelta_taylor", [q, dq, ddq, d, dd], [ca.solve(Mdd, -r)],
                    ["q", "dq", "ddq", "delta", "ddelta"], ["dddelta"])
    memo[key] = f
    return f


def simulate_taylor(model: FlexibleModel, reference: Move | ShapedMove, order: int,
                    dt: float = 1e-3, t_end: float | None = None) -> dict[str, np.ndarray]:
    """Prescribed joint motion on the model truncated at degree ``order`` in δ, by the
    RK4 steps of :func:`casflex.simulate.simulate_prescribed` (``method="rk4"``: the same
    stages, the end stage with the left limit of q̈), from rest.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    reference : casflex.moves.Move or casflex.moves.ShapedMove
    order : int
        Degree in δ (:func:`taylor_modal_rows`).
    dt : float
        Step [s].
    t_end : float, optional
        End time [s] (default the move's ``t_end``).

    Returns
    -------
    dict of numpy.ndarray
        ``t`` [s], ``delta``, ``ddelta`` (len(t), m), ``tip_deflection`` (len(t), 3)
        [m] (the exact tip of the model at δ minus the rigid tip), and ``wall_s`` [s].

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.moves import Move
    >>> from casflex.robot import load
    >>> from casflex.simulate import simulate_prescribed
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.5], count=1),
    ...                       gravity=None)
    >>> move = Move([0, 0, 0], [-0.3, 0, 0], 0.3, settle=0.1)
    >>> r = simulate_taylor(model, move, 1, dt=0.01)  # degree 1: this model's own rows
    >>> e = simulate_prescribed(model, move, dt=0.01)
    >>> bool(np.abs(r["delta"] - e.delta).max() < 1e-12 * np.abs(e.delta).max())
    True
    """
    from casflex.simulate.results import tip_positions

    f = taylor_modal_rows(model, order)
    n, m = model.n, model.m
    sampler, t0, t_last, _ = reference_sampler(reference, n)
    t, _ = time_grid(t0, t_last if t_end is None else float(t_end), float(dt))
    q, dq, ddq = sampler(t)
    qh, dqh, ddqh = sampler(t[:-1] + 0.5 * dt)
    ddq_end = sampler(t[1:] - LEFT_LIMIT * dt)[2]  # the left limit, as method="rk4"
    P = np.hstack([q[:-1], dq[:-1], ddq[:-1], qh, dqh, ddqh, q[1:], dq[1:], ddq_end])
    z = ca.SX.sym("z", 2 * m)
    p = ca.SX.sym("p", 9 * n)

    def rhs(zz, k):
        a, b, c = (p[3 * n * k + n * i:3 * n * k + n * (i + 1)] for i in range(3))
        return ca.vertcat(zz[m:], f(a, b, c, zz[:m], zz[m:]))

    step = ca.Function("taylor_rk4", [z, p], [rk4_step(rhs, z, float(dt), 0, 1, 2)])
    start = time.perf_counter()
    zs = step.mapaccum("taylor_rk4_acc", t.size - 1)(np.zeros(2 * m), P.T)
    Z = np.vstack([np.zeros(2 * m), zs.full().T])
    wall = time.perf_counter() - start
    tip, rigid = tip_positions(model.functions()["tip"], q, Z[:, :m])
    return {"t": t, "delta": Z[:, :m], "ddelta": Z[:, m:], "tip_deflection": tip - rigid,
            "wall_s": wall}
