"""Cache keys of the modal tables: a robot's canonical description and the TMM's code.

The keys of :func:`casflex.modal.build_table` (and of :func:`casflex.modal.fit_model_terms`'s
checkpoints) hash what changes a table's values: the robot (:func:`robot_fingerprint`),
the grid and settings in an exact canonical form (:func:`canonical`), the source of the
code that computes them (:func:`tmm_digest`) and the quantity function
(:func:`function_identity`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
from typing import TYPE_CHECKING, Any

import numpy as np

from casflex._cache import source_digest

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = ["canonical", "function_identity", "robot_fingerprint", "tmm_digest"]


def canonical(obj: Any) -> Any:
    """JSON-able canonical form of a value, for cache keys (floats exact via ``float.hex``).

    Parameters
    ----------
    obj : dataclass, dict, list, tuple, numpy.ndarray, bool, int, float, str or None
        Nested in any way.

    Returns
    -------
    object
        Dicts with sorted string keys, lists, bools, ints, hexadecimal float strings,
        strings and None.

    Raises
    ------
    TypeError
        For any other type.

    Examples
    --------
    >>> canonical({"b": np.array([0.5]), "a": (1, None)})
    {'a': [1, None], 'b': ['0x1.0000000000000p-1']}
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in sorted(obj.items())}
    if isinstance(obj, (list, tuple)):
        return [canonical(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [canonical(v) for v in obj.tolist()]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj).hex()
    if obj is None or isinstance(obj, str):
        return obj
    raise TypeError(f"cannot fingerprint {type(obj)}")


def robot_fingerprint(robot: Robot) -> str:
    """Canonical description of everything in ``robot`` that changes its dynamics.

    Every field of every link (DH row, joint type, section, material, section angle,
    tip body, motor inertia, joint stiffness), the gravity vector and the damping ratio;
    not the name, description or source file.

    Parameters
    ----------
    robot : casflex.robot.Robot

    Returns
    -------
    str
        Canonical JSON text (part of the cache key of the modal tables).

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> import dataclasses
    >>> other = dataclasses.replace(robot, name="renamed", source=None)
    >>> robot_fingerprint(robot) == robot_fingerprint(other)
    True
    """
    return json.dumps({
        "links": canonical(robot.links),
        "gravity": canonical(np.asarray(robot.gravity, dtype=float)),
        "damping_ratio": canonical(robot.damping_ratio),
    }, sort_keys=True)


def tmm_digest() -> str:
    """SHA-256 (hex) of the source of the TMM (with its compiled kernels) and of the robot
    model: part of the key of cached raw modes, so that a change to the code that computes
    them invalidates them.

    Returns
    -------
    str

    Examples
    --------
    >>> len(tmm_digest())
    64
    """
    import casflex.robot
    import casflex.tmm.chain
    import casflex.tmm.conditioning
    import casflex.tmm.elements
    import casflex.tmm.fast
    import casflex.tmm.kernels
    import casflex.tmm.one_call
    import casflex.tmm.shape_kernel
    import casflex.tmm.solve

    # the compiled path (fast, one_call, shape_kernel) computes the tables' modes as well
    return source_digest(casflex.tmm.elements, casflex.tmm.chain, casflex.tmm.solve,
                          casflex.tmm.kernels, casflex.tmm.conditioning, casflex.robot,
                          casflex.tmm.fast, casflex.tmm.one_call, casflex.tmm.shape_kernel)


def function_identity(func: Any) -> Any:
    """What identifies a quantity function in a cache key: its name, version and source.

    Parameters
    ----------
    func : callable or None
        A quantity function (``(robot, q, shapes) -> dict``), a ``functools.partial`` of
        one, or None. :func:`casflex.modal.default_quantities` also stands for the mass
        normalisation and the mode integrals it calls.

    Returns
    -------
    object
        A JSON-able description: name, version and a digest of the source; for a partial,
        the identity of its function with its arguments in canonical form.

    Examples
    --------
    >>> from casflex.modal import default_quantities
    >>> function_identity(default_quantities)["name"]
    'casflex.modal.tables.default_quantities'
    >>> sorted(function_identity(functools.partial(max, default=0)))
    ['args', 'keywords', 'partial']
    """
    from casflex.modal.tables import default_quantities

    if func is default_quantities:
        import casflex.modal.integrals
        import casflex.modal.normalize

        return {"name": "casflex.modal.tables.default_quantities",
                "digest": source_digest(default_quantities, casflex.modal.normalize,
                                         casflex.modal.integrals)}
    if func is None:
        return None
    if isinstance(func, functools.partial):
        return {"partial": function_identity(func.func),
                "args": canonical(list(func.args)),
                "keywords": canonical(dict(func.keywords))}
    return {
        "name": f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', '?')}",
        "version": str(getattr(func, "version", getattr(func, "__version__", ""))),
        "digest": source_digest(func),
    }
