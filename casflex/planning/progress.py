"""The live display of a planner's Ipopt solve: one counter per solve on stderr.

A cold plan of move 1 of the design study takes 100–300 Ipopt iterations and minutes of
CPU; a robust continuation, several such solves. :class:`SolveProgress` is a listener of
:func:`casflex.planning.stopping.iteration_callback`: it counts the iterates on a tqdm
counter (no total: Ipopt's end is not known in advance) with the objective (T for a
minimum-time plan) and the largest constraint violation of the last one, so that a user
sees the solve move, creep or wander while it runs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from casflex._validate import fail

__all__ = ["SolveProgress", "check_progress", "progress_listener"]


class SolveProgress:
    """A tqdm counter of Ipopt iterates on stderr, closed by :meth:`close`.

    Parameters
    ----------
    desc : str
        Label of the counter.
    objective : str
        The plan's objective (``"time"`` labels the value ``T`` in s).
    enabled : bool
        Show the counter (a disabled one counts silently).

    Examples
    --------
    >>> p = SolveProgress("move1", "time", enabled=False)
    >>> p(2.5173, 3e-7), p(2.5172, 1e-9)
    (False, False)
    >>> p.iterations, p.postfix
    (2, 'T 2.51720 s, violation 1.0e-09')
    >>> p.close()
    """

    def __init__(self, desc: str, objective: str, enabled: bool = True) -> None:
        from casflex._parallel import progress_bar

        self.label = "T" if objective == "time" else "objective"
        self.unit = " s" if objective == "time" else ""
        self.iterations = 0
        self.postfix = ""
        self._bar = progress_bar(None, desc=desc, enabled=enabled)

    def __call__(self, objective: float, violation: float) -> bool:
        """Take one iterate; never asks Ipopt to stop (``False``)."""
        self.iterations += 1
        self.postfix = f"{self.label} {objective:.5f}{self.unit}, violation {violation:.1e}"
        self._bar.set_postfix_str(self.postfix, refresh=False)
        self._bar.update(1)
        return False

    def close(self) -> None:
        """Remove the counter from the terminal.

        Examples
        --------
        >>> p = SolveProgress("move1", "energy", enabled=False)
        >>> p(0.31, 0.0)
        False
        >>> p.close(); p.postfix
        'objective 0.31000, violation 0.0e+00'
        """
        self._bar.close()


def check_progress(progress: Any) -> bool:
    """Whether ``plan_move(progress=...)`` asks for a display.

    Parameters
    ----------
    progress : object
        ``plan_move``'s ``progress``.

    Returns
    -------
    bool

    Raises
    ------
    casflex.errors.ModelError
        For a value that is neither a bool (or None) nor a callable.

    Examples
    --------
    >>> check_progress(False), check_progress(print)
    (False, True)
    """
    if progress is None or progress is False:
        return False
    if progress is True or callable(progress):
        return True
    raise fail("progress", progress, "must be a bool or a callable "
               "progress(iteration, objective, violation)")


def progress_listener(progress: bool | Callable[..., Any], desc: str,
                      objective: str) -> tuple[Callable[[float, float], bool] | None,
                                               Callable[[], None]]:
    """The listener ``plan_move(progress=...)`` asks for, and how to end it.

    Parameters
    ----------
    progress : bool or callable
        ``True``: a :class:`SolveProgress` counter on stderr; ``False``: none; a callable:
        ``progress(iteration, objective, violation)`` at every iterate (iteration 0 is the
        guess).
    desc : str
        Label of the counter.
    objective : str
        The plan's objective.

    Returns
    -------
    (callable or None, callable)
        The listener for :func:`casflex.planning.stopping.iteration_callback` (None for
        ``False``) and a function that closes the display (call it when the solve ends).

    Examples
    --------
    >>> seen = []
    >>> listen, close = progress_listener(lambda *a: seen.append(a), "m", "time")
    >>> listen(3.2, 0.1), listen(3.1, 0.0)
    (False, False)
    >>> close(); seen
    [(0, 3.2, 0.1), (1, 3.1, 0.0)]
    """
    if not check_progress(progress):
        return None, lambda: None
    if progress is True:
        counter = SolveProgress(desc, objective)
        return counter, counter.close
    count = [0]

    def listen(objective_value: float, violation: float) -> bool:
        progress(count[0], objective_value, violation)
        count[0] += 1
        return False
    return listen, lambda: None
