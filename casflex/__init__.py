"""casflex: modeling, estimation and control of flexible serial robot arms.

Units are SI and angles are radians everywhere inside the library; frequencies are
rad/s unless a name ends in ``_hz``.
"""

__version__ = "0.1.0"

from casflex.errors import CasflexError, ModelError, ProblemFileError, SolverError

__all__ = ["CasflexError", "ModelError", "ProblemFileError", "SolverError", "__version__"]
