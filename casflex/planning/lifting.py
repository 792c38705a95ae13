"""A nominal plan's NLP iterate and multipliers as the start of the robust problem.

The robust OCP of :func:`casflex.planning.plan_move` is the nominal one with the modal
rows of the frequency-shifted models appended to every state block (the node and
collocation states, their dynamics, gaps and initial values) and an end condition per
scenario. A nominal plan is therefore a point of the robust NLP once its scenario rows are
filled in: its own values and multipliers on the shared rows, the scenarios' modal
motion under its joint motion (:func:`casflex.planning.collocated_modal_guess`) and zero
multipliers on their rows (where the scenarios' end bounds are loose, that is the
robust problem's solution). Ipopt's default start from that iterate walks away from it
(a barrier restarted at 0.1: on move 1 of the design study no plan in 300 iterations);
the lifted start keeps it there. It is what lets a robust problem at the full frequency
error start from the nominal plan, the first problem of the bound path of
:func:`casflex.planning.solve_by_continuation` (benchmarks/README_planning.md, session 29).

The blocks are found by name: :class:`BlockLayout` records, as ``plan_move`` declares
them, where each named block of variables and of constraints lies in the NLP, and the
plan keeps that record (``PlannedMove.solution["layout"]``, saved with it).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

__all__ = ["BlockLayout", "lifted_scales", "lifted_start", "LIFTED_OPTIONS"]

#: Ipopt options of a solve from a lifted start (with :data:`WARM_START_OPTIONS`). MUMPS
#: cannot factorise the lifted start of move 1 of the design study: the scenarios' modal
#: rows have no Hessian there (zero multipliers, dynamics linear in δ), and its first
#: factorisation needed 19.3 M doubles where its analysis planned 2.7 M, with wrong
#: inertia and its pivot tolerance raised: more than 5 min in iteration 0. SPRAL (in
#: CasADi's Ipopt) factorises it at ~0.8 s per iteration (benchmarks/README_planning.md,
#: session 29). Elsewhere MUMPS stays: SPRAL made one-link plans 4 times slower
LIFTED_OPTIONS = {"linear_solver": "spral"}


class BlockLayout:
    """Where the named blocks of an ``Opti``'s variables and constraints lie.

    Declare every variable and constraint through it; ``x`` and ``g`` then list
    ``(name, offset, rows, columns)`` of each block in ``opti.x`` and ``opti.g``
    (column-major, as CasADi vectorises a matrix).

    Examples
    --------
    >>> opti = ca.Opti()
    >>> layout = BlockLayout()
    >>> X = layout.variable(opti, "X", 2, 3)
    >>> T = layout.variable(opti, "T")
    >>> layout.subject_to(opti, "gaps", X[:, 1:] - X[:, :2] == 0, rows=2)
    >>> layout.subject_to(opti, "duration", opti.bounded(0.1, T, 5.0))
    >>> layout.x, layout.g
    ([('X', 0, 2, 3), ('T', 6, 1, 1)], [('gaps', 0, 2, 2), ('duration', 4, 1, 1)])
    """

    def __init__(self) -> None:
        self.x: list[tuple[str, int, int, int]] = []
        self.g: list[tuple[str, int, int, int]] = []

    def variable(self, opti: ca.Opti, name: str, rows: int = 1, columns: int = 1) -> ca.MX:
        """Declare the variable block ``name`` of ``rows`` × ``columns``.

        Parameters
        ----------
        opti : casadi.Opti
        name : str
            Unique among the variable blocks.
        rows, columns : int

        Returns
        -------
        casadi.MX
            ``opti.variable(rows, columns)``.

        Examples
        --------
        >>> opti, layout = ca.Opti(), BlockLayout()
        >>> layout.variable(opti, "U", 1, 4).shape
        (1, 4)
        """
        # opti.nx counts no variable before the problem is first evaluated
        offset = self.x[-1][1] + self.x[-1][2] * self.x[-1][3] if self.x else 0
        self.x.append((name, offset, rows, columns))
        return opti.variable(rows, columns)

    def subject_to(self, opti: ca.Opti, name: str, constraint: Any,
                   rows: int | None = None) -> None:
        """Add the constraint block ``name``.

        Parameters
        ----------
        opti : casadi.Opti
        name : str
            Unique among the constraint blocks.
        constraint : casadi.MX
            As ``opti.subject_to`` takes it.
        rows : int, optional
            Rows per column of the block (the state rows of a block of dynamics;
            default: one column).

        Examples
        --------
        >>> opti, layout = ca.Opti(), BlockLayout()
        >>> X = layout.variable(opti, "X", 2, 3)
        >>> layout.subject_to(opti, "start", X[:, 0] == 0)
        >>> layout.g
        [('start', 0, 2, 1)]
        """
        offset = opti.ng
        opti.subject_to(constraint)
        count = opti.ng - offset
        rows = count if rows is None else rows
        if rows <= 0 or count % rows:
            raise ValueError(f"BlockLayout: constraint block {name!r} has {count} rows, not "
                             f"a multiple of {rows}")
        self.g.append((name, offset, rows, count // rows))

    def to_dict(self) -> dict:
        """The record, as ``PlannedMove.solution["layout"]`` keeps it (JSON-able).

        Returns
        -------
        dict
            ``{"x": [[name, offset, rows, columns], ...], "g": [...]}``.

        Examples
        --------
        >>> opti, layout = ca.Opti(), BlockLayout()
        >>> _ = layout.variable(opti, "T")
        >>> layout.to_dict()
        {'x': [['T', 0, 1, 1]], 'g': []}
        """
        return {"x": [list(b) for b in self.x], "g": [list(b) for b in self.g]}


def lifted_scales(solution: dict | None, sx: np.ndarray, n: int,
                  implicit: bool) -> tuple | None:
    """The scales of a robust NLP lifted from a nominal plan's: the plan's on its rows.

    The dynamics rows are divided by the state scales, so the plan's multipliers hold in
    its scales only (:func:`casflex.planning.kept_scales`); the scenario rows, which the
    plan has not, keep the new NLP's.

    Parameters
    ----------
    solution : dict or None
        ``PlannedMove.solution`` of the nominal plan (with its ``layout``).
    sx : ndarray
        The new NLP's state scales (nominal rows, then the scenarios').
    n : int
        Joints.
    implicit : bool
        Whether the new NLP has collocated accelerations.

    Returns
    -------
    (ndarray, ndarray, ndarray or None, float) or None
        Scales of the states, torques [N m], accelerations and T [s]; ``None`` when the
        plan has no layout, is not nominal (as many state rows as ``sx``, or more), or
        its scales do not fit.

    Examples
    --------
    >>> scales = {"x": np.full(4, 2.0), "tau": np.ones(1), "ddq": np.ones(1), "T": 1.5}
    >>> lifted_scales({"scales": scales, "layout": {}}, np.ones(6), 1, True)[0]
    array([2., 2., 2., 2., 1., 1.])
    >>> lifted_scales({"scales": scales, "layout": {}}, np.ones(4), 1, True) is None
    True
    """
    if not solution or solution.get("layout") is None:
        return None
    scales = solution["scales"]
    rows = scales["x"].size
    if rows >= sx.size or scales["tau"].size != n or (scales["ddq"] is None) == implicit:
        return None
    return np.r_[scales["x"], sx[rows:]], scales["tau"], scales["ddq"], scales["T"]


def lifted_start(solution: dict, layout: BlockLayout, x_initial: np.ndarray,
                 ng: int) -> dict | None:
    """The NLP start of a robust problem from a nominal plan's iterate and multipliers.

    Every block of the plan's layout must be in the new one, with the same columns and
    at most as many rows (the scenario rows follow the nominal ones); its values and
    multipliers go to its first rows. The rest keeps ``x_initial`` (the scenario rows'
    guess) and zero multipliers.

    Parameters
    ----------
    solution : dict
        ``PlannedMove.solution`` of the nominal plan: ``x``, ``lam_g``, ``layout``.
    layout : BlockLayout
        The new NLP's.
    x_initial : ndarray
        The new NLP's initial iterate (all its variables).
    ng : int
        Its constraints.

    Returns
    -------
    dict or None
        ``x`` and ``lam_g`` of the new NLP, ``lifted`` True; ``None`` when the blocks do
        not fit (another problem) or the layout does not cover the new NLP.

    Examples
    --------
    A nominal NLP with one state row, lifted into one with a scenario row:

    >>> def problem(rows):
    ...     opti, layout = ca.Opti(), BlockLayout()
    ...     X = layout.variable(opti, "X", rows, 3)
    ...     layout.subject_to(opti, "gaps", X[:, 1:] - 0.5 * X[:, :2] == 0, rows=rows)
    ...     return layout
    >>> old = {"x": np.arange(3.0), "lam_g": np.array([7.0, 8.0]),
    ...        "layout": problem(1).to_dict()}
    >>> start = lifted_start(old, problem(2), np.full(6, -1.0), 4)
    >>> start["x"], start["lam_g"]
    (array([ 0., -1.,  1., -1.,  2., -1.]), array([7., 0., 8., 0.]))
    """
    x_old, lam_old = np.asarray(solution["x"]), np.asarray(solution["lam_g"])
    x0 = np.array(x_initial, dtype=float).ravel()
    if sum(r * c for _, _, r, c in layout.x) != x0.size or \
            sum(r * c for _, _, r, c in layout.g) != ng:
        return None  # a variable or constraint declared outside the layout
    lam0 = np.zeros(ng)
    for kind, old_values, new_values in (("x", x_old, x0), ("g", lam_old, lam0)):
        new_blocks = {b[0]: b[1:] for b in getattr(layout, kind)}
        for name, offset, rows, cols in solution["layout"][kind]:
            if name not in new_blocks:
                return None
            new_offset, new_rows, new_cols = new_blocks[name]
            if new_cols != cols or new_rows < rows:
                return None
            block = old_values[offset:offset + rows * cols].reshape((rows, cols), order="F")
            target = new_values[new_offset:new_offset + new_rows * new_cols]
            shaped = target.reshape((new_rows, new_cols), order="F")
            shaped[:rows] = block
            new_values[new_offset:new_offset + new_rows * new_cols] = shaped.ravel(order="F")
    return {"x": x0, "lam_g": lam0, "lifted": True}
