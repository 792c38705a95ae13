"""The design job's EKF step, kept in the cache between runs.

Building the step of the loop (:func:`casflex.estimation.ekf_step_function`: the plant's
lookups, whose B-spline coefficients import :mod:`scipy.interpolate`, the measurement
model, Jacobians and common-subexpression elimination) is a large part of a second run
of a study that nothing has changed. :func:`loop_ekf_step` keeps the step's serialised
graph in casflex's cache (:mod:`casflex._cache`), keyed on everything it is built from;
the graph read back is the one stored, so the loop, its compiled library and the C
bundle's key (:func:`casflex.design.c_bundle_key`) are those of the first run.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex._cache import (
    cache_root,
    content_digest,
    digest,
    load_verified,
    make_cache_directory,
    save_verified,
)
from casflex._json import jsonable

if TYPE_CHECKING:
    from casflex.design.study import Study
    from casflex.estimation import FlexiblePlant

__all__ = ["loop_ekf_step"]

#: the code an EKF step is built by, as paths under the casflex package: every file of a
#: directory (the plant, the filter, the model and its modal tables), or one module
_BUILT_BY = ("estimation", "model", "modal", "sensors.py", "robot.py",
             "simulate/integrators.py")


def loop_ekf_step(plant: FlexiblePlant, study: Study, table: object, dt: float,
                  cache_dir: str | os.PathLike | bool | None = None) -> ca.Function:
    """``ekf_step_function(plant, study.sensors, Q, R, dt)`` of the study's estimator, read
    from the cache when it was built from the same inputs before.

    Parameters
    ----------
    plant : casflex.estimation.FlexiblePlant
        The tabulated plant of the study's model (:func:`casflex.estimation.tabulate_plant`).
    study : casflex.design.Study
        Its ``estimator`` ``Q`` and ``R``, its sensors and its ``[model]`` settings.
    table : casflex.modal.ModalTable
        The model's modal table; its cache key (``table.info["key"]``) and the model's
        settings identify the model. Without one (a robot without a shape joint, a
        fitted model) the step is built without the cache.
    dt : float
        Sample time [s].
    cache_dir : str or pathlib.Path or bool, optional
        Cache root (default the casflex cache directory); ``False``: no cache.

    Returns
    -------
    casadi.Function
        The EKF step ``(x, P, u, y, mask) -> (x_next, P_next, x_post)``.

    Examples
    --------
    A robot without a shape joint has no modal table: the step is built, not cached.

    >>> from casflex.design import load_study
    >>> from casflex.estimation import tabulate_plant
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> study = load_study("problems/studies/arm2link_move1.toml")
    >>> provider = PointwiseProvider(study.robot, [0, 0, 0], 1, study.sensors.points)
    >>> plant = tabulate_plant(FlexibleModel(study.robot, provider), cache_dir=False)
    >>> loop_ekf_step(plant, study, None, 1e-3).name_out()
    ['x_next', 'P_next', 'x_post']
    """
    from casflex.estimation import ekf_step_function

    e = study.estimator

    def build():
        return ekf_step_function(plant, study.sensors, e["Q"], e["R"], dt)

    info = getattr(table, "info", None)
    root = cache_root(cache_dir)
    if root is None or not isinstance(info, dict) or not info.get("key") or \
            study.model["fit"] != "grid":
        return build()
    key = _key(plant, study, info["key"], dt)
    path = root / "ekf" / f"ekf-{key[:32]}.npz"
    hit = load_verified(path, key)
    if hit is not None:
        return ca.Function.deserialize(str(hit["function"]))
    step = build()
    make_cache_directory(path.parent)
    save_verified(path, key, function=np.array(step.serialize()))
    return step


def _key(plant, study, table_key, dt):
    """SHA-256 of the step's inputs: the modal table's key and the model's settings (the
    model), the plant's arrays and settings, the sensors, ``Q``, ``R``, ``dt``, the
    CasADi version and the source files of the code that builds a step."""
    arrays = {"pattern": np.asarray(plant.pattern)}
    for name in ("keep", "constant"):
        if getattr(plant, name, None) is not None:
            arrays[name] = np.asarray(getattr(plant, name))
    if plant.table is not None:
        arrays.update({f"table_{k}": np.asarray(v) for k, v in plant.table.values.items()})
        arrays.update({f"grid{i}": np.asarray(a) for i, a in enumerate(plant.table.grid)})
    e = study.estimator
    return digest({
        "table": table_key, "model": jsonable(study.model),
        "plant": content_digest(arrays),
        "plant_settings": jsonable({"shape_joints": plant.shape_joints,
                                    "fourier_joints": plant.fourier_joints,
                                    "degree": plant.degree, "order": plant.order,
                                    "lookup": plant.lookup,
                                    "monomials": repr(plant.monomials),
                                    "periodic": None if plant.table is None
                                    else plant.table.periodic}),
        "sensors": [repr(s) for s in study.sensors.sensors],
        "points": repr(list(study.sensors.points)),
        "Q": jsonable(e["Q"]), "R": jsonable(e["R"]), "dt": float(dt),
        "casadi": ca.__version__, "numpy": np.__version__,
        "source": _source_files_digest(),
    })


def _source_files_digest():
    """SHA-256 of the source files of :data:`_BUILT_BY`, by path (the same files on every
    run, whatever this process has imported)."""
    package = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for entry in _BUILT_BY:
        path = package / entry
        for file in sorted(path.glob("*.py")) if path.is_dir() else [path]:
            h.update(str(file.relative_to(package)).encode())
            h.update(file.read_bytes())
    return h.hexdigest()
