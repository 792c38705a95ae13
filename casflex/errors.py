"""Exceptions raised by casflex.

Every input problem raises a :class:`CasflexError` subclass whose message names
the file (where there is one), the field, the offending value and the rule it broke.
"""

from __future__ import annotations

import os


class CasflexError(Exception):
    """Base class of every error casflex raises on purpose.

    Catch it to handle every deliberate casflex failure in one place (the CLI does).

    Examples
    --------
    >>> from casflex.robot import loads
    >>> try:
    ...     loads("name = 'empty'")
    ... except CasflexError as exc:
    ...     print(type(exc).__name__)
    ProblemFileError
    """


class ProblemFileError(CasflexError, ValueError):
    """A problem file (robot, move, shaper, study) is malformed or violates a rule.

    Parameters
    ----------
    path : str or None
        File the error was found in (``None`` for in-memory descriptions).
    field : str
        Dotted name of the offending key, e.g. ``"link[2].material.E"``.
    value : object
        The offending value.
    rule : str
        The rule the value broke, in words.

    Examples
    --------
    >>> err = ProblemFileError("arm.toml", "link[0].material.E", -1.0, "must be > 0")
    >>> str(err)
    "arm.toml: field 'link[0].material.E' = -1.0: must be > 0"
    >>> err.field, err.value, isinstance(err, ValueError)
    ('link[0].material.E', -1.0, True)
    """

    def __init__(self, path: str | os.PathLike[str] | None, field: str, value: object,
                 rule: str) -> None:
        self.path = None if path is None else str(path)
        self.field = field
        self.value = value
        self.rule = rule
        where = self.path if self.path is not None else "<in-memory description>"
        super().__init__(f"{where}: field '{field}' = {value!r}: {rule}")


class SolverError(CasflexError, RuntimeError):
    """A numerical solver (root search, Ipopt, integrator) failed or did not converge.

    Examples
    --------
    >>> try:
    ...     raise SolverError("Ipopt: Maximum_Iterations_Exceeded after 3000 iterations")
    ... except CasflexError as exc:
    ...     print(exc, isinstance(exc, RuntimeError))
    Ipopt: Maximum_Iterations_Exceeded after 3000 iterations True
    """


class ModelError(CasflexError, ValueError):
    """A request the model cannot answer (wrong sizes, unknown link, out-of-range point).

    Examples
    --------
    >>> from casflex.robot import load
    >>> load("problems/arm2link.toml").check_q([0.0, 0.0])
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: robot 'arm2link' has 3 joint variables; got q of shape (2,)
    """
