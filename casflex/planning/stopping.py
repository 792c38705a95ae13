"""A stop on the progress of the objective: the planner's end of an Ipopt solve.

On the flexible arm Ipopt's own tests serve a minimum-time solve badly at both ends:

* at a feasible start on its own limits (the shaped move at its peaks, what ``casflex
  plan`` starts from) the optimality error is already small (3.6e-3 on move 1 of the
  design study, against |∂f/∂T| = 3.2), so a loose acceptable test stops at the start;
* near the minimum the reduced Hessian is indefinite, the steps shrink and T creeps
  (1e-4 per iterate) while the dual infeasibility wanders between 1e-3 and 0.4, so a
  strict test (1e-8, or 15 acceptable iterates in a row) is not met for hundreds of
  iterates (a cold solve of move 1 ran > 10 min of CPU).

:class:`ProgressStop` watches what the planner cares about instead: the iterate must be
feasible (every constraint to ``feasibility``), the objective (T for a minimum-time
plan) must have fallen below its value at the first iterate (the guess) by ``leave``
(relative), and over the last ``window`` feasible iterates in a row it must have moved
by less than ``rtol`` (relative). Optionally (``settle``, what a warm start from a
neighbouring plan uses: :meth:`ProgressStop.near_solution`) it also stops when the last
``settle`` feasible iterates in a row agree to ``settle_rtol``. The plan is then judged by
the simulations of :func:`casflex.planning.verify_plan`, not by Ipopt's optimality
measure.

:meth:`ProgressStop.callback` makes it an Ipopt iteration callback (CasADi's
``iteration_callback``): Ipopt then ends with ``User_Requested_Stop`` and
:func:`casflex.planning.plan_move` reports the status ``Stopped_On_Progress``.

:class:`DurationCeiling` and :class:`ViolationCeiling` are listeners of the same kind that
give a solve up once an iterate has left what is worth following: a duration above a
ceiling, a constraint violation above one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from casflex._validate import number

__all__ = ["ProgressStop", "PROGRESS_STATUS", "INTERRUPTED_STATUS", "CEILING_STATUS",
           "DurationCeiling", "ViolationCeiling", "VIOLATION_CEILING_STATUS", "PlanInterrupted",
           "iteration_callback"]

#: ``stats["status"]`` of a plan that :class:`ProgressStop` ended
PROGRESS_STATUS = "Stopped_On_Progress"

#: ``stats["status"]`` of the feasible last iterate of a solve that Ctrl-C ended
INTERRUPTED_STATUS = "Interrupted_By_User"

#: the status in the ``SolverError`` of a solve that :class:`DurationCeiling` gave up
CEILING_STATUS = "Duration_Out_Of_Range"

#: the status in the ``SolverError`` of a solve that :class:`ViolationCeiling` gave up
VIOLATION_CEILING_STATUS = "Violation_Out_Of_Range"


class PlanInterrupted(KeyboardInterrupt):
    """Ctrl-C during a plan, with what the plan had reached (a ``KeyboardInterrupt``: code
    that knows nothing of it stops as on any interrupt).

    Parameters
    ----------
    plan : PlannedMove or None
        The best plan reached before the interrupt: the interrupted solve's last iterate
        if it was feasible (``stats["status"]`` :data:`INTERRUPTED_STATUS`), else the best
        pass a :func:`casflex.planning.plan_move` with ``restarts`` had finished, or the
        last problem a robust continuation had finished (``plan.stats["scenarios"]`` says
        at which frequency error); None if there was none. As a ``guess`` of a later
        ``plan_move`` it continues the work (``casflex plan --guess``).
    note : str
        Where ``plan`` comes from, in words.

    Examples
    --------
    >>> try:
    ...     raise PlanInterrupted(None, "nothing reached")
    ... except KeyboardInterrupt as exc:
    ...     print(exc.plan, exc.note)
    None nothing reached
    """

    def __init__(self, plan: Any = None, note: str = "") -> None:
        super().__init__(note)
        self.plan = plan
        self.note = note


@dataclass
class ProgressStop:
    """The stopping rule on the progress of the objective (module docstring).

    Parameters
    ----------
    window : int
        Feasible iterates in a row over which the objective is compared.
    rtol : float
        Largest relative spread ``(max − min) / |f|`` of the objective over the window
        that counts as no progress [-].
    leave : float
        Relative decrease of the objective below its value at the first iterate
        before the rule may stop [-] (0: none needed). An objective that has not
        fallen that far is left to Ipopt's own tests: on move 1 of the design study the
        false plateau at the start lay 0.8 % above the guess (3.233 s against
        3.208 s).
    feasibility : float
        Largest constraint violation of a feasible iterate (as the constraints are posed:
        the planner's rows are scaled by their magnitudes).
    settle : int, optional
        Also stop when this many feasible iterates in a row (>= 2) agree to
        ``settle_rtol`` (after ``leave``). Default: no such test.
    settle_rtol : float
        Largest relative spread of the objective over the ``settle`` iterates [-].

    Attributes
    ----------
    trace : list of (float, float)
        ``(objective, violation)`` of every iterate seen.

    Examples
    --------
    A descent that creeps: it stops at the 10th feasible iterate below 1e-3 of spread.

    >>> rule = ProgressStop()
    >>> T = [3.2, 2.9, 2.6, 2.45] + [2.4 - 1e-4 * k for k in range(20)]
    >>> [rule.update(t, 0.0) for t in T].index(True)
    13
    """

    window: int = 10
    rtol: float = 1e-3
    leave: float = 2e-2
    feasibility: float = 1e-6
    settle: int | None = None
    settle_rtol: float = 1e-5
    start: float | None = field(default=None, init=False)
    history: list[float] = field(default_factory=list, init=False)
    trace: list[tuple[float, float]] = field(default_factory=list, init=False)
    stopped: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        self.window = number(self.window, "window", low=2, integer=True)
        self.rtol = number(self.rtol, "rtol", low=0.0)
        self.leave = number(self.leave, "leave", low=0.0)
        self.feasibility = number(self.feasibility, "feasibility", low=0.0)
        if self.settle is not None:
            self.settle = number(self.settle, "settle", low=2, integer=True)
        self.settle_rtol = number(self.settle_rtol, "settle_rtol", low=0.0)

    @classmethod
    def near_solution(cls) -> ProgressStop:
        """The rule for a warm start from a neighbouring plan (its iterate and
        multipliers), what :func:`casflex.planning.plan_move` takes there with
        ``progress_stop=True``: no decrease needed (``leave = 0``), and besides the
        default window a stop once 3 feasible iterates in a row agree to 1e-5.

        From a neighbour's solution Ipopt takes Newton steps to this problem's optimum:
        on move 1 of the design study, with the end bound 5 % tighter, T settles within
        3 iterates of the first feasible one (2.1348156, 2.1348149, 2.1348150 s) and
        Ipopt spends 30 more on its optimality test (the iterates leave feasibility and
        come back) to end at 2.1348019 s, 6e-6 below (benchmarks/README_planning.md,
        session 19). The default window (10 feasible iterates in a row) is broken by
        those excursions. A solve that creeps (a restart from a plan the rule stopped)
        still ends on the default window: 3 iterates agree to 1e-5 only when T moves by
        less than 5e-6 an iterate, where 10 agree to 1e-3 already.

        Examples
        --------
        >>> rule = ProgressStop.near_solution()
        >>> (rule.window, rule.rtol, rule.leave, rule.settle, rule.settle_rtol)
        (10, 0.001, 0.0, 3, 1e-05)
        """
        return cls(leave=0.0, settle=3)

    def update(self, objective: float, violation: float) -> bool:
        """Take one iterate; ``True`` when the solve should stop there.

        Parameters
        ----------
        objective : float
            The objective at the iterate (T [s] for a minimum-time plan).
        violation : float
            Its largest constraint violation.

        Returns
        -------
        bool

        Examples
        --------
        An infeasible iterate restarts the window:

        >>> rule = ProgressStop(window=3, leave=0.0)
        >>> [rule.update(1.0, v) for v in (0.0, 0.0, 1.0, 0.0, 0.0, 0.0)]
        [False, False, False, False, False, True]
        """
        f = float(objective)
        self.trace.append((f, float(violation)))
        if self.start is None:  # the first iterate: the guess
            self.start = f
        if not np.isfinite(f) or not violation <= self.feasibility:
            self.history.clear()
            return False
        self.history.append(f)
        scale = max(abs(f), 1e-12)

        def agree(count, rtol):  # the last `count` feasible iterates within rtol
            last = self.history[-count:]
            return len(last) == count and (max(last) - min(last)) <= rtol * scale

        # progress is a decrease: a solve that wanders above its start (move 1 of the
        # design study, cold: T up to 8.3 s from the shaped 3.2 s) is not stopped there
        left = self.leave == 0.0 or self.start - f >= self.leave * abs(self.start)
        self.stopped = left and (agree(self.window, self.rtol) or (
            self.settle is not None and agree(self.settle, self.settle_rtol)))
        return self.stopped

    def callback(self, lbg: ArrayLike, ubg: ArrayLike, nx: int) -> Any:
        """This rule as CasADi's ``iteration_callback`` of an ``nlpsol`` (Ipopt):
        :func:`iteration_callback` with this rule's :meth:`update` as its one listener.

        Parameters
        ----------
        lbg, ubg, nx : array_like, array_like, int
            The NLP's constraint bounds and number of variables, as
            :func:`iteration_callback` takes them.

        Returns
        -------
        casadi.Callback
            Keep a reference to it for as long as the solver lives.

        Examples
        --------
        The rule stops the descent of ``x²`` from 3 once ``x`` has settled within 10 %:

        >>> import casadi as ca
        >>> x = ca.SX.sym("x")
        >>> rule = ProgressStop(window=2, rtol=1e-1, leave=0.5)
        >>> opts = {"iteration_callback": rule.callback([1.0], [np.inf], 1),
        ...         "print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}}
        >>> s = ca.nlpsol("s", "ipopt", {"x": x, "f": x**2, "g": x}, opts)
        >>> float(s(x0=3.0, lbg=1.0, ubg=np.inf)["x"]) < 3.0, rule.stopped
        (True, True)
        """
        return iteration_callback(lbg, ubg, nx, [self.update])


@dataclass
class _Ceiling:
    """What :class:`DurationCeiling` and :class:`ViolationCeiling` share: a listener that
    remembers the first iterate whose watched value (``watched``) left its range
    (``left``); subclasses name their ``status`` and their ``option`` of ``plan_move``."""

    ceiling: float
    exceeded: tuple[int, float] | None = field(default=None, init=False)
    seen: int = field(default=0, init=False)
    option = "ceiling"

    def __post_init__(self) -> None:
        self.ceiling = number(self.ceiling, self.option, low=0.0, low_open=True)

    def update(self, objective: float, violation: float) -> bool:
        """Take one iterate; ``True`` once any iterate so far has left the range (the
        listener's answer: :func:`iteration_callback` then stops Ipopt).

        Parameters
        ----------
        objective : float
            The iterate's objective (T [s] for a minimum-time plan).
        violation : float
            Its largest constraint violation [1].

        Returns
        -------
        bool

        Examples
        --------
        >>> DurationCeiling(1.0).update(1.0, 5.0), ViolationCeiling(1.0).update(5.0, 1.0)
        (False, False)
        """
        value = self.watched(objective, violation)
        if self.exceeded is None and self.left(value):
            self.exceeded = (self.seen, value)
        self.seen += 1
        return self.exceeded is not None


@dataclass
class DurationCeiling(_Ceiling):
    """Give a minimum-time solve up once an iterate's duration rises above ``ceiling``.

    Where a plan longer than some reference is worth nothing — the robust problems of a
    continuation, whose every constraint the shaped move already meets at its own
    duration — an Ipopt path that has left for long durations is a failure, and usually
    a long one: on move 1 of the design study the first robust problem went from the
    2.133 s nominal plan to a 5.37 s plan in 372 iterations (665 s of CPU) in one run,
    and to 2.31 s in 35 in another (benchmarks/README_planning.md, session 19). A hard
    bound on T does not serve: held at it, Ipopt spent 500 iterations without a plan
    (session 21). This listener (:func:`iteration_callback`; ``plan_move``'s
    ``duration_ceiling``) stops Ipopt at the first iterate above the ceiling, feasible or
    not, and :func:`casflex.planning.plan_move` raises a ``SolverError``
    (:data:`CEILING_STATUS`), which a continuation answers with a shorter step.

    An iterate whose duration is zero or negative has left the problem as well (the
    duration's lower bound is a constraint, which Ipopt's iterates may violate): on move 1
    one robust problem jumped from T = 2.10 s to −98.9 s at iterate 70 and was still at
    −18 s, violation 18, 170 iterations later (benchmarks/README_planning.md,
    session 22). The listener gives up there too.

    Parameters
    ----------
    ceiling : float
        Largest duration an iterate may have [s] (> 0).

    Attributes
    ----------
    exceeded : tuple of (int, float) or None
        The first iterate (0: the start) whose duration [s] left ``(0, ceiling]``, and
        that duration.

    Examples
    --------
    >>> rule = DurationCeiling(3.2)
    >>> [rule.update(t, 1.0) for t in (2.1, 2.6, 3.3, 3.1)], rule.exceeded
    ([False, False, True, True], (2, 3.3))
    >>> rule = DurationCeiling(3.2)
    >>> [rule.update(t, 1.0) for t in (2.1, -98.9, 2.0)], rule.exceeded
    ([False, True, True], (1, -98.9))
    """

    status = CEILING_STATUS
    option = "duration_ceiling"

    def watched(self, objective: float, violation: float) -> float:
        """The iterate's duration [s] (its objective, for a minimum-time plan).

        Parameters
        ----------
        objective, violation : float
            The iterate's objective [s] and its constraint violation (not used).

        Returns
        -------
        float

        Examples
        --------
        >>> DurationCeiling(3.2).watched(2.5, 0.1)
        2.5
        """
        return float(objective)

    def left(self, value: float) -> bool:
        """Whether a duration [s] is out of ``(0, ceiling]``.

        Parameters
        ----------
        value : float

        Returns
        -------
        bool

        Examples
        --------
        >>> rule = DurationCeiling(3.2)
        >>> rule.left(3.2), rule.left(3.3), rule.left(0.0)
        (False, True, True)
        """
        return value > self.ceiling or value <= 0.0

    def reason(self) -> str:
        """Where the solve left, in words (for the ``SolverError``; after an escape).

        Returns
        -------
        str

        Examples
        --------
        >>> rule = DurationCeiling(3.2)
        >>> rule.update(3.3, 0.0), rule.reason()
        (True, 'the duration rose to 3.3 s at iterate 0, above duration_ceiling = 3.2 s')
        """
        at, T = self.exceeded
        return (f"the duration rose to {T:.6g} s at iterate {at}, above duration_ceiling = "
                f"{self.ceiling:.6g} s" if T > 0.0 else
                f"the duration fell to {T:.6g} s at iterate {at}, not a duration")


@dataclass
class ViolationCeiling(_Ceiling):
    """Give a solve up once an iterate's largest constraint violation rises above
    ``ceiling``.

    For a solve that starts at a feasible point of its own problem — a restart of
    :func:`casflex.planning.solve_with_restarts` from the plan just found — an iterate
    far outside the constraints is a path that has left, and on the planner's problems
    such a path rarely comes back: on move 1 of the design study (153 intervals, the
    derivatives perturbed by one part in 10⁹ to draw other paths) the restarts from a
    plan's multipliers that reached a plan stayed below a violation of 1.2, and none of
    those that rose above 2 (8 of the 10 that found no plan, all within 40 iterates)
    came back to a plan in 500 iterations (benchmarks/README_planning.md, session 27).
    This listener (:func:`iteration_callback`; ``plan_move``'s ``violation_ceiling``)
    stops Ipopt at the first iterate above the ceiling, and
    :func:`casflex.planning.plan_move` raises a ``SolverError``
    (:data:`VIOLATION_CEILING_STATUS`).

    Parameters
    ----------
    ceiling : float
        Largest constraint violation an iterate may have (> 0), as Ipopt sees the rows:
        the planner's rows scaled by their magnitudes [1].

    Attributes
    ----------
    exceeded : tuple of (int, float) or None
        The first iterate (0: the start) whose violation was above the ceiling, and that
        violation.

    Examples
    --------
    >>> rule = ViolationCeiling(1.0)
    >>> [rule.update(2.1, v) for v in (1e-8, 0.3, 1.7, 0.2)], rule.exceeded
    ([False, False, True, True], (2, 1.7))
    >>> rule.reason()
    'the constraint violation rose to 1.7 at iterate 2, above violation_ceiling = 1'
    """

    status = VIOLATION_CEILING_STATUS
    option = "violation_ceiling"

    def watched(self, objective: float, violation: float) -> float:
        """The iterate's largest constraint violation [1].

        Parameters
        ----------
        objective, violation : float
            The iterate's objective (not used) and its constraint violation.

        Returns
        -------
        float

        Examples
        --------
        >>> ViolationCeiling(2.0).watched(2.5, 0.1)
        0.1
        """
        return float(violation)

    def left(self, value: float) -> bool:
        """Whether a violation is above the ceiling (NaN counts as above).

        Parameters
        ----------
        value : float

        Returns
        -------
        bool

        Examples
        --------
        >>> rule = ViolationCeiling(2.0)
        >>> rule.left(2.0), rule.left(2.1), rule.left(float("nan"))
        (False, True, True)
        """
        return not value <= self.ceiling

    def reason(self) -> str:
        """Where the solve left, in words (for the ``SolverError``; after an escape).

        Returns
        -------
        str

        Examples
        --------
        >>> rule = ViolationCeiling(0.5)
        >>> rule.update(2.0, 0.75)
        True
        >>> print(rule.reason())
        the constraint violation rose to 0.75 at iterate 0, above violation_ceiling = 0.5
        """
        at, v = self.exceeded
        return (f"the constraint violation rose to {v:.6g} at iterate {at}, above "
                f"violation_ceiling = {self.ceiling:.6g}")


def iteration_callback(lbg: ArrayLike, ubg: ArrayLike, nx: int,
                       listeners: list[Callable[[float, float], bool | None]],
                       soft: tuple[ArrayLike, ArrayLike, float] | None = None) -> Any:
    """CasADi's ``iteration_callback`` of an ``nlpsol`` (Ipopt) that hands every iterate's
    objective and largest constraint violation to ``listeners``.

    Parameters
    ----------
    lbg, ubg : array_like
        Bounds of the NLP's constraints (``ng`` values each).
    nx : int
        Number of the NLP's variables.
    listeners : list of callable
        ``listener(objective, violation)``, called in order at every iterate (all of them,
        also after one asked to stop); Ipopt stops (``User_Requested_Stop``) when one
        returns ``True``. The violation is ``max(lbg − g, g − ubg, 0)`` over the finite
        bounds, as the constraints are posed.
    soft : (array_like of int, array_like, float), optional
        Indices of variables that measure how far a softened constraint is exceeded
        (``plan_move``'s elastic excesses, >= 0), their scales and an allowance:
        ``x_i / scale_i − allowance`` counts as a violation too, so that the listeners
        judge feasibility by the constraints as asked.

    Returns
    -------
    casadi.Callback
        Keep a reference to it for as long as the solver lives. An exception raised by a
        listener (``KeyboardInterrupt`` included: a Ctrl-C while Ipopt runs arrives at the
        next iterate's callback) stops Ipopt at that iterate and is kept as the
        callback's ``error`` (None otherwise); CasADi would otherwise turn it into a
        ``User_Requested_Stop``, so the caller re-raises it after the solve
        (:func:`casflex.planning.plan_move` does).

    Examples
    --------
    >>> import casadi as ca
    >>> x = ca.SX.sym("x")
    >>> seen = []
    >>> cb = iteration_callback([1.0], [np.inf], 1, [lambda f, v: seen.append((f, v))])
    >>> solver = ca.nlpsol("s", "ipopt", {"x": x, "f": x**2, "g": x},
    ...                    {"iteration_callback": cb, "print_time": False,
    ...                     "ipopt": {"print_level": 0, "sb": "yes"}})
    >>> round(float(solver(x0=3.0, lbg=1.0, ubg=np.inf)["x"]), 6), seen[0]
    (1.0, (9.0, 0.0))

    With ``x`` an excess of scale 2 and allowance 0.5 it counts as violation
    ``x / 2 − 0.5``:

    >>> seen.clear()
    >>> cb = iteration_callback([1.0], [np.inf], 1, [lambda f, v: seen.append((f, v))],
    ...                         soft=([0], [2.0], 0.5))
    >>> solver = ca.nlpsol("s", "ipopt", {"x": x, "f": x**2, "g": x},
    ...                    {"iteration_callback": cb, "print_time": False,
    ...                     "ipopt": {"print_level": 0, "sb": "yes"}})
    >>> _ = solver(x0=3.0, lbg=1.0, ubg=np.inf); seen[0]
    (9.0, 1.0)
    """
    import casadi as ca

    lower = np.asarray(lbg, dtype=float).ravel()
    upper = np.asarray(ubg, dtype=float).ravel()
    calls = list(listeners)
    names = ca.nlpsol_out()
    soft_at, soft_scale = (np.asarray(a).ravel() for a in (soft or ([], []))[:2])
    soft_at, allowance = soft_at.astype(int), float((soft or (0, 0, 0.0))[2])

    class _Callback(ca.Callback):
        def __init__(self) -> None:
            ca.Callback.__init__(self)
            self.error: BaseException | None = None
            self.construct("iteration_callback", {})

        def get_n_in(self) -> int:
            return ca.nlpsol_n_out()

        def get_n_out(self) -> int:
            return 1

        def get_name_in(self, i: int) -> str:
            return ca.nlpsol_out(i)

        def get_name_out(self, i: int) -> str:
            return "stop"

        def get_sparsity_in(self, i: int) -> Any:
            name = ca.nlpsol_out(i)
            if name == "f":
                return ca.Sparsity.scalar()
            if name in ("x", "lam_x"):
                return ca.Sparsity.dense(nx)
            if name in ("g", "lam_g"):
                return ca.Sparsity.dense(lower.size)
            return ca.Sparsity(0, 0)

        def eval(self, arg: list) -> list:
            g = np.asarray(arg[names.index("g")], dtype=float).ravel()
            excess = np.r_[lower - g, g - upper, 0.0]
            violation = float(np.max(excess[np.isfinite(excess)]))
            if soft_at.size:
                x = np.asarray(arg[names.index("x")], dtype=float).ravel()
                violation = max(violation,
                                float(np.max(x[soft_at] / soft_scale)) - allowance)
            f = float(arg[names.index("f")])
            try:
                stop = [bool(call(f, violation)) for call in calls]
            except BaseException as exc:  # noqa: BLE001  (kept and re-raised by the caller)
                self.error = exc
                return [1]
            return [1 if any(stop) else 0]

    return _Callback()
