"""The one JSON encoding of casflex results (CLI ``--json`` output, ``summary.json``).

Values are SI units and radians. numpy arrays become lists, numpy scalars plain numbers,
and a non-finite number becomes ``null`` (JSON has no NaN or infinity).
"""

from __future__ import annotations

import math
from pathlib import PurePath

import numpy as np

__all__ = ["jsonable"]


def jsonable(obj: object) -> object:
    """``obj`` with every numpy array, numpy scalar, path and non-finite float replaced by
    plain JSON values (dict keys become strings).

    Parameters
    ----------
    obj : object
        Result to encode: nested dicts, lists, tuples, numpy arrays and scalars.

    Examples
    --------
    >>> jsonable({"w": np.array([1.5, np.inf]), 2: (np.int64(3), np.bool_(True))})
    {'w': [1.5, None], '2': [3, True]}
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, PurePath):
        return str(obj)
    return obj
