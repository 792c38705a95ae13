"""Spatial transfer-matrix modal analysis of serial beam structures (dissertation §3.2).

The robot at one configuration is posed as a chain of transfer elements
(:mod:`casflex.tmm.chain`), each a 12 × 12 transfer matrix (:mod:`casflex.tmm.elements`);
the natural frequencies are the roots of the clamped–free system matrix, counted by
Wittrick–Williams, and the mode shapes follow from its null space
(:mod:`casflex.tmm.solve`).

Chain assembly
==============

   Chain         -- a robot at one configuration, base (clamped) to tip (free)
   Element       -- one transfer element posed in the base frame
   build_chain   -- pose every element of a robot at joint variables q

Conditioning
============

   check_chain  -- refuse a chain the TMM cannot solve in double precision, saying where

Natural frequencies
===================

   natural_frequencies    -- natural frequencies of a chain or robot, with multiplicity
   sweep_frequencies      -- the lowest natural frequencies at many configurations at once
   count_below            -- Wittrick–Williams count of natural frequencies below ω
   frequency_determinant  -- scaled det subU(ω), zero at the natural frequencies
   system_matrix          -- system transfer matrix from the clamped base to the free tip

Mode shapes
===========

   ModeShapes   -- mode shapes sampled along every beam, with frequencies and resultants
   MODE_FIELDS  -- the ModeShapes fields indexed by mode first
   mode_shapes  -- mode shapes of a chain at given natural frequencies
   modes        -- natural frequencies and mode shapes of a robot at q

Transfer matrices (12 × 12, state ``[u, θ, M, F]``)
===================================================

   beam_field           -- field matrix of a uniform beam over a length s
   beam_matrix          -- a flexible link from its section and material
   point_body_matrix    -- a rigid body attached at a point
   rigid_body_matrix    -- a rigid link carrying a body
   offset_matrix        -- a massless rigid offset
   joint_spring_matrix  -- a torsional joint spring about an axis
   rotation_matrix      -- frame change blockdiag(R, R, R, R)
   rotation_x           -- frame rotated about x (eq. 58)
   rotation_y           -- frame rotated about y (eq. 57)
   rotation_z           -- frame rotated about z (eq. 56)
   body_mass_matrix     -- 6 × 6 rigid-body mass matrix about its attachment point
   skew                 -- cross-product matrix [v]×
   DISSERTATION_ORDER   -- state indices in the dissertation's order (eq. 14)
"""

from casflex.tmm.chain import Chain, Element, build_chain
from casflex.tmm.conditioning import check_chain
from casflex.tmm.elements import (
    DISSERTATION_ORDER,
    beam_field,
    beam_matrix,
    body_mass_matrix,
    joint_spring_matrix,
    offset_matrix,
    point_body_matrix,
    rigid_body_matrix,
    rotation_matrix,
    rotation_x,
    rotation_y,
    rotation_z,
    skew,
)
from casflex.tmm.solve import (
    MODE_FIELDS,
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
    # chain assembly
    "Chain",
    "Element",
    "build_chain",
    # conditioning
    "check_chain",
    # natural frequencies
    "natural_frequencies",
    "sweep_frequencies",
    "count_below",
    "frequency_determinant",
    "system_matrix",
    # mode shapes
    "ModeShapes",
    "MODE_FIELDS",
    "mode_shapes",
    "modes",
    # transfer matrices
    "beam_field",
    "beam_matrix",
    "point_body_matrix",
    "rigid_body_matrix",
    "offset_matrix",
    "joint_spring_matrix",
    "rotation_matrix",
    "rotation_x",
    "rotation_y",
    "rotation_z",
    "body_mass_matrix",
    "skew",
    "DISSERTATION_ORDER",
]
