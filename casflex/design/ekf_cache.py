"""The design job's EKF step, kept in the cache between runs.

Building the step of the loop (:func:`casflex.estimation.ekf_step_function`: the plant's
lookups, whose B-spline coefficients import :mod:`scipy.interpolate`, the measurement
model, Jacobians and common-subexpression elimination) is a large part of a second run
of a study that nothing has changed. :func:`loop_ekf_step` keeps the step's serialised
graph in casflex's cache (:mod:`casflex._cache`), keyed on everything it is built from
(a hit neither tabulates nor reads the plant);
the graph read back is the one stored, so the loop, its compiled library and the C
bundle's key (:func:`casflex.design.c_bundle_key`) are those of the first run.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._cache import (
    cache_root,
    digest,
    load_verified,
    make_cache_directory,
    save_verified,
)
from casflex._json import jsonable

if TYPE_CHECKING:
    from casflex.design.study import Study
    from casflex.model import FlexibleModel

__all__ = ["loop_ekf_step"]

#: the code an EKF step is built by, as paths under the casflex package: every file of a
#: directory (the plant, the filter, the model and its modal tables), or one module
_BUILT_BY = ("estimation", "model", "modal", "sensors.py", "robot.py",
             "simulate/integrators.py")


def loop_ekf_step(model: FlexibleModel, table: object, study: Study, dt: float,
                  plant_grid: Sequence[ArrayLike] | None = None,
                  cache_dir: str | os.PathLike | bool | None = None) -> ca.Function:
    """The EKF step of the study's loop, read from the cache when it was built from the same
    inputs before: ``ekf_step_function(tabulate_plant(model, grid=plant_grid), sensors,
    Q, R, dt)``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        The study's model (:func:`casflex.model.build_model` with the study's settings).
    table : casflex.modal.ModalTable
        Its modal table; the table's cache key (``table.info["key"]``) and the study's
        ``[model]`` settings identify the model. Without one (a robot without a shape
        joint, a fitted model) the step is built without the cache.
    study : casflex.design.Study
        Its ``estimator`` ``Q`` and ``R``, its sensors and its ``[model]`` settings.
    dt : float
        Sample time [s].
    plant_grid : sequence of array_like, optional
        Grid axes of the plant's table [rad] (:func:`casflex.estimation.tabulate_plant`'s
        ``grid``; default the model table's grid).
    cache_dir : str or pathlib.Path or bool, optional
        Cache root (default the casflex cache directory), also the plant's; ``False``: no
        cache.

    Returns
    -------
    casadi.Function
        The EKF step ``(x, P, u, y, mask) -> (x_next, P_next, x_post)``.

    Examples
    --------
    A robot without a shape joint has no modal table: the step is built, not cached.

    >>> from casflex.design import load_study
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> study = load_study("problems/studies/arm2link_move1.toml")
    >>> provider = PointwiseProvider(study.robot, [0, 0, 0], 1, study.sensors.points)
    >>> step = loop_ekf_step(FlexibleModel(study.robot, provider), None, study, 1e-3,
    ...                      cache_dir=False)
    >>> step.name_out()
    ['x_next', 'P_next', 'x_post']
    """
    from casflex.estimation import ekf_step_function, tabulate_plant

    e = study.estimator

    def build():
        plant = tabulate_plant(model, grid=plant_grid, cache_dir=cache_dir)
        return ekf_step_function(plant, study.sensors, e["Q"], e["R"], dt)

    info = getattr(table, "info", None)
    root = cache_root(cache_dir)
    if root is None or not isinstance(info, dict) or not info.get("key") or \
            study.model["fit"] != "grid":
        return build()
    key = _key(study, info["key"], plant_grid, dt)
    path = root / "ekf" / f"ekf-{key[:32]}.npz"
    hit = load_verified(path, key)
    if hit is not None:
        return ca.Function.deserialize(str(hit["function"]))
    step = build()
    make_cache_directory(path.parent)
    save_verified(path, key, function=np.array(step.serialize()))
    return step


def _key(study, table_key, plant_grid, dt):
    """SHA-256 of the step's inputs: the modal table's key and the study's model settings
    (the model), the plant's grid, the sensors, ``Q``, ``R``, ``dt``, the versions and the
    source files of the code that tabulates the plant and builds the step."""
    e = study.estimator
    return digest({
        "table": table_key, "model": jsonable(study.model),
        "plant_grid": None if plant_grid is None else
        [np.asarray(a, dtype=float).tolist() for a in plant_grid],
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
