"""The on-disk cache of specified-insensitivity designs.

An SI design (:func:`~casflex.shaping.si_shaper`: grid LPs, Ipopt solves, dense-grid
verification) is a pure function of its frequency ranges and options, and the most
expensive step of a second design job that nothing else has changed. :func:`cached_si_design`
keeps its result (every field of :class:`~casflex.shaping.SIShaperResult`, to the last bit)
in casflex's cache (:mod:`casflex._cache`), keyed on the ranges, the options, the versions of
the solvers and the source of the code that designs; a failed design is not stored.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import casadi as ca
import numpy as np

from casflex._cache import (
    cache_root,
    digest,
    load_verified,
    make_cache_directory,
    save_verified,
    source_digest,
)
from casflex.shaping.ranges import FrequencyRange, as_ranges
from casflex.shaping.shapers import Shaper
from casflex.shaping.si import SISample, SIShaperResult

__all__ = ["cached_si_design"]

#: the modules whose code an SI design runs (their source is part of the key)
_DESIGN_MODULES = ("casflex.shaping.si", "casflex.shaping.si_start",
                   "casflex.shaping.si_hessian", "casflex.shaping.grid_lp",
                   "casflex.shaping.shapers", "casflex.shaping.ei_family",
                   "casflex.shaping.ei_fit_table", "casflex.shaping.family",
                   "casflex.shaping.ranges", "casflex.shaping.for_moves")


def cached_si_design(ranges: FrequencyRange | Iterable, options: Mapping,
                     design: Callable[[], SIShaperResult],
                     cache_dir: str | os.PathLike | bool | None = None) -> SIShaperResult:
    """The result of ``design()`` for ``ranges`` and ``options``, from the cache if there.

    Parameters
    ----------
    ranges : sequence of FrequencyRange
        The design's frequency ranges [rad/s] (with their damping ratios and tolerances).
    options : mapping
        Everything else the design depends on (impulse counts, time limit, solver
        options, sample time [s]), JSON-able; a value that is not (a start shaper, say)
        makes the design run uncached.
    design : callable
        ``design() -> SIShaperResult``, run on a miss; its result is stored (atomically,
        read back only if its digest verifies).
    cache_dir : str or pathlib.Path or bool, optional
        Cache root (default the casflex cache directory); ``False``: no cache.

    Returns
    -------
    SIShaperResult
        ``design()``'s result, or the stored one, equal to it in every field.

    Examples
    --------
    >>> import math, tempfile
    >>> from casflex.shaping import si_shaper
    >>> r = [FrequencyRange(0.9 * 2 * math.pi, 1.1 * 2 * math.pi, 0.0, 0.05)]
    >>> cache = tempfile.mkdtemp()
    >>> first = cached_si_design(r, {}, lambda: si_shaper(r), cache)
    >>> again = cached_si_design(r, {}, lambda: 1 / 0, cache)   # not designed again
    >>> again.shaper.times.tolist() == first.shaper.times.tolist(), again.start
    (True, 'lp')
    """
    ranges = as_ranges(ranges)
    root = cache_root(cache_dir)
    key = None
    if root is not None:
        try:
            key = _key(ranges, options)
        except TypeError:  # an option that is not JSON-able: no key, no cache
            key = None
    if key is None:
        return design()
    path = root / "shapers" / f"si-{key[:32]}.npz"
    hit = load_verified(path, key)
    if hit is not None:
        return _from_arrays(hit, ranges)
    result = design()
    make_cache_directory(path.parent)
    save_verified(path, key, **_to_arrays(result))
    return result


def _key(ranges, options):
    """SHA-256 of the ranges (exact: JSON keeps a float's shortest round-trip form), the
    options, the solvers' versions and the design code's source (``ei_fit_table``'s data
    file included)."""
    from importlib.metadata import version

    modules = [importlib.import_module(name) for name in _DESIGN_MODULES]
    fit_file = Path(modules[_DESIGN_MODULES.index("casflex.shaping.ei_fit_table")].__file__)
    fit_data = fit_file.with_suffix(".npz")
    return digest({
        "ranges": [[r.omega_min, r.omega_max, r.zeta, r.vtol] for r in ranges],
        "options": dict(options),
        "versions": {"casadi": ca.__version__, "numpy": np.__version__,
                     "scipy": version("scipy"), "highspy": version("highspy")},
        "source": source_digest(*modules),
        "fit_table": hashlib.sha256(fit_data.read_bytes()).hexdigest()
        if fit_data.is_file() else None,
    })


def _shaper_arrays(prefix, shaper):
    if shaper is None:
        return {}
    return {f"{prefix}_times": shaper.times, f"{prefix}_amplitudes": shaper.amplitudes}


def _to_arrays(result):
    """Every field of an :class:`SIShaperResult` as arrays (``meta``: the scalars and lists
    as JSON)."""
    arrays = {**_shaper_arrays("shaper", result.shaper),
              **_shaper_arrays("final_guess", result.final_guess),
              **_shaper_arrays("initial_guess", result.initial_guess),
              "max_prv": np.asarray(result.max_prv, dtype=float)}
    if result.max_prv_eq187 is not None:
        arrays["max_prv_eq187"] = np.asarray(result.max_prv_eq187, dtype=float)
    if result.samples is not None:
        for name in ("omega", "zeta", "vtol", "range_index"):
            arrays[f"samples_{name}"] = np.asarray(getattr(result.samples, name))
    meta = {"iterations": int(result.iterations), "statuses": list(result.statuses),
            "solver_iterations": [int(i) for i in result.solver_iterations],
            "start": result.start,
            **{name: None if getattr(result, name) is None else float(getattr(result, name))
               for name in ("lp_duration", "lp_lower_bound", "lp_step")}}
    arrays["meta"] = np.array(json.dumps(meta))
    return arrays


def _from_arrays(arrays, ranges):
    """The :class:`SIShaperResult` of :func:`_to_arrays`' arrays."""
    def shaper(prefix):
        if f"{prefix}_times" not in arrays:
            return None
        return Shaper(arrays[f"{prefix}_times"], arrays[f"{prefix}_amplitudes"])

    samples = None
    if "samples_omega" in arrays:
        samples = SISample(*(np.asarray(arrays[f"samples_{name}"])
                             for name in ("omega", "zeta", "vtol", "range_index")))
    meta = json.loads(str(arrays["meta"]))
    return SIShaperResult(
        shaper=shaper("shaper"), ranges=list(ranges),
        max_prv=np.asarray(arrays["max_prv"], dtype=float),
        iterations=meta["iterations"], statuses=meta["statuses"],
        solver_iterations=meta["solver_iterations"], samples=samples,
        final_guess=shaper("final_guess"), initial_guess=shaper("initial_guess"),
        max_prv_eq187=np.asarray(arrays["max_prv_eq187"], dtype=float)
        if "max_prv_eq187" in arrays else None,
        start=meta["start"], lp_duration=meta["lp_duration"],
        lp_lower_bound=meta["lp_lower_bound"], lp_step=meta["lp_step"])
