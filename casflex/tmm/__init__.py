"""Spatial transfer-matrix modal analysis of serial beam structures (dissertation §3.2)."""

from casflex.tmm.chain import Chain, Element, build_chain
from casflex.tmm.solve import (
    ModeShapes,
    count_below,
    frequency_determinant,
    mode_shapes,
    modes,
    natural_frequencies,
    sweep_frequencies,
    system_matrix,
)

__all__ = [
    "Chain",
    "Element",
    "ModeShapes",
    "build_chain",
    "count_below",
    "frequency_determinant",
    "mode_shapes",
    "modes",
    "natural_frequencies",
    "sweep_frequencies",
    "system_matrix",
]
