"""The point function's derivatives without differentiating through its table lookups.

The planner's point function ``φ(w)`` (:func:`casflex.planning.implicit_point_function`)
reads the model's tables by call nodes of one lookup ``L(q_s)`` of the shape joint, and of
its derivative functions (``fwd1_L``, ``adj1_L``: the Christoffel terms use ``∂L/∂q_s``).
CasADi differentiates a call node by a derivative call for every direction at once, with
zero seeds in all but the shape joint's: its outputs are not structurally zero, so in the
point Jacobian's 16 directions (and the Hessian's) every product with a table entry gets a
tangent. On move 1's model the compiled Jacobian and Hessian took 18 and 34 ms a solver
iteration (459 points), of which most is that work.

Here the calls are replaced, on a replay of ``φ``'s algorithm
(:func:`casflex.codegen.segments.replay`), by the cubic Taylor polynomial of ``L`` about
a base point ``c``,

    ``L(q) ≈ V + V' d + V'' d²/2 + V''' d³/6``,  ``d = q − c``,

and ``fwd1_L``, ``adj1_L`` by its derivative ``V' + V'' d + V''' d²/2`` times their seeds,
with ``c`` and ``P = [V; V'; V''; V''']`` inputs: ``φ_T(w, c, P)``. ``φ_T`` is a
polynomial in ``q`` wherever ``φ`` reads a table, so CasADi's derivatives of it are plain
products; evaluated at ``c = q_s(w)`` and ``P`` the lookup's value and first three
derivatives there (:attr:`TaylorTables.lookup`), its value, Jacobian and Hessian in ``w``
are ``φ``'s — exactly in exact arithmetic: a cubic B-spline is its own cubic Taylor
polynomial on a knot interval, and ``φ``'s second derivatives need ``L`` to its third.
Differences are rounding only.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from casflex.codegen.segments import replay

__all__ = ["TaylorTables", "taylor_tables"]


@dataclass(frozen=True)
class TaylorTables:
    """``φ`` with its table lookups as Taylor polynomials (module docstring).

    Attributes
    ----------
    function : casadi.Function
        ``φ_T(w, c, P)``: ``φ``'s inputs, the base point ``c`` [rad] and ``P`` (``4 k``:
        the lookup's ``k`` values and their first three derivatives at ``c``).
    argument : casadi.Function
        ``w -> q_s``: the lookups' argument (the shape joint) [rad].
    lookup : casadi.Function
        ``c -> P`` (the lookup and its derivatives by CasADi's differentiation).
    """

    function: ca.Function
    argument: ca.Function
    lookup: ca.Function

    def bind(self, expr: ca.SX, c: ca.SX, P: ca.SX, w: ca.SX) -> ca.SX:
        """``expr`` (of ``w``, ``c``, ``P``) at ``c = q_s(w)`` and ``P`` the lookup
        there (one call node).

        Parameters
        ----------
        expr : casadi.SX
            E.g. a derivative of ``function(w, c, P)`` in ``w``.
        c, P, w : casadi.SX
            The symbols ``expr`` is written in.

        Returns
        -------
        casadi.SX
            ``expr`` in ``w`` alone.

        Examples
        --------
        >>> q = ca.MX.sym("q")
        >>> L = ca.Function("L", [q], [ca.vertcat(ca.sin(q), q * q)])
        >>> w = ca.SX.sym("w", 2)
        >>> phi = ca.Function("phi", [w], [L.call([w[0]], False, True)[0] * w[1]])
        >>> t = taylor_tables(phi)
        >>> c, P = ca.SX.sym("c"), ca.SX.sym("P", t.lookup.nnz_out(0))
        >>> J = ca.jacobian(t.function(w, c, P), w)
        >>> f = ca.Function("f", [w], [t.bind(J, c, P, w)])
        >>> import numpy as np
        >>> np.allclose(f([0.3, 2.0]), [[2 * np.cos(0.3), np.sin(0.3)], [2 * 0.6, 0.09]])
        True
        """
        s = self.argument(w)
        return ca.substitute(expr, ca.vertcat(c, P),
                             ca.vertcat(s, self.lookup.call([s], False, True)[0]))


def taylor_tables(phi: ca.Function) -> TaylorTables | None:
    """``φ``'s table lookups as Taylor polynomials (module docstring), or None when ``φ``
    has no call node or one that is not a scalar lookup ``L(q)`` or its ``fwd1_L`` /
    ``adj1_L`` at one common argument (then ``φ`` is differentiated as it is).

    Parameters
    ----------
    phi : casadi.Function
        An SX function of one input ``w``.

    Returns
    -------
    TaylorTables or None

    Examples
    --------
    >>> w = ca.SX.sym("w", 2)
    >>> taylor_tables(ca.Function("phi", [w], [ca.sin(w[0]) * w[1]])) is None   # no table
    True
    """
    if phi.class_name() != "SXFunction" or phi.n_in() != 1:
        return None
    nodes = phi.instructions_sx()
    called = [nodes[k].which_function() for k in range(phi.n_instructions())
              if phi.instruction_id(k) == ca.OP_CALL]
    base = [fn for fn in called if fn.n_in() == 1]
    if not called or len({fn.name() for fn in base}) != 1:
        return None
    L = base[0]
    if L.nnz_in(0) != 1 or L.n_out() != 1:
        return None
    k = L.nnz_out(0)
    kinds = {L.name(): "value", "fwd1_" + L.name(): "fwd", "adj1_" + L.name(): "adj"}
    if any(fn.name() not in kinds for fn in called):
        return None
    w = ca.SX.sym("w", phi.sparsity_in(0))
    c, P = ca.SX.sym("c"), ca.SX.sym("P", 4 * k)
    V, V1, V2, V3 = (P[i * k:(i + 1) * k] for i in range(4))
    args_seen = []

    def call(fn, args):
        q = args[0]
        args_seen.append(q)
        d = q - c
        slope = V1 + d * (V2 + d / 2 * V3)
        kind = kinds[fn.name()]
        if kind == "value":
            return [V + d * (V1 + d / 2 * (V2 + d / 3 * V3))]
        if kind == "fwd":  # (q, out, seed) -> L'(q) seed
            return [slope * args[-1]]
        return [ca.dot(slope, args[-1])]  # adj: (q, out, seed) -> L'(q)ᵀ seed

    out = replay(phi, [w], call)
    q0 = args_seen[0]
    if not all(ca.is_equal(q, q0, 64) for q in args_seen):
        return None
    qs = ca.MX.sym("q")
    ders = [L(qs)]
    for _ in range(3):
        ders.append(ca.densify(ca.jacobian(ders[-1], qs)))
    return TaylorTables(
        ca.Function(phi.name() + "_taylor", [w, c, P], out, ["w", "c", "P"], phi.name_out()),
        ca.Function(phi.name() + "_argument", [w], [q0], ["w"], ["q"]),
        ca.Function(L.name() + "_taylor", [qs], [ca.vertcat(*ders)], ["c"], ["P"]))
