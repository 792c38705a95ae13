"""Exceptions raised by casflex.

Every input problem raises a :class:`CasflexError` subclass whose message names
the file (where there is one), the field, the offending value and the rule it broke.
"""


class CasflexError(Exception):
    """Base class of every error casflex raises on purpose."""


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
    """

    def __init__(self, path, field, value, rule):
        self.path = None if path is None else str(path)
        self.field = field
        self.value = value
        self.rule = rule
        where = self.path if self.path is not None else "<in-memory description>"
        super().__init__(f"{where}: field '{field}' = {value!r}: {rule}")


class SolverError(CasflexError, RuntimeError):
    """A numerical solver (root search, Ipopt, integrator) failed or did not converge."""


class ModelError(CasflexError, ValueError):
    """A request the model cannot answer (wrong sizes, unknown link, out-of-range point)."""
