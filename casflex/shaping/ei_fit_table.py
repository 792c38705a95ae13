"""Chebyshev coefficients of the damped EI family: 2-D fits in ζ and vtol.

The coefficients are in ``ei_fit_table.npz`` next to this module, written by
``python tools/gen_ei_fit.py`` (do not edit): for each kind a tensor series in
``x = 2 ζ / zeta_max - 1`` and ``y = 2 (vtol**p - vtol_min**p) / (vtol_max**p -
vtol_min**p) - 1`` of every impulse amplitude and normalised time.
"""

from pathlib import Path

import numpy as np

__all__ = ["FIT_TABLE", "FIT_BOXES"]

with np.load(Path(__file__).with_name("ei_fit_table.npz")) as _data:
    #: kind -> coefficients, shape (nodes in ζ, nodes in vtol, 2 n - 1): the n amplitudes
    #: then the n - 1 times τ_2..τ_n (τ = ω t).
    FIT_TABLE = {name[:-len("_coefficients")]: np.array(_data[name])
                 for name in _data.files if name.endswith("_coefficients")}
    #: kind -> (zeta_max, vtol_min, vtol_max, power p of vtol in the fit's coordinate)
    FIT_BOXES = {kind: tuple(float(v) for v in _data[f"{kind}_box"]) for kind in FIT_TABLE}
