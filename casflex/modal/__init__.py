"""Modal quantities over the configuration space: normalisation, tracking, tables.

The transfer-matrix modes of one configuration (:mod:`casflex.tmm`) are mass-normalised
(:mod:`casflex.modal.normalize`), turned into the quantities of the rigid–flexible model
(:mod:`casflex.modal.integrals`), followed in identity and sign from one configuration to
the next (:mod:`casflex.modal.tracking`) and tabulated over a grid of the shape joints
with interpolants for the dynamics (:mod:`casflex.modal.tables`).

Mass normalisation
==================

   mass_normalize          -- scale the modes so that the modal mass matrix is the identity
   modal_mass_matrix       -- modal mass matrix of sampled modes
   modal_stiffness_matrix  -- modal stiffness matrix from the strain energy of the modes
   local_state             -- exact local state [u, θ, M, F] of every mode along one beam
   gauss_legendre          -- cached Gauss–Legendre nodes and weights on [−1, 1]
   SHAPE_FIELDS            -- the ModeShapes fields a change of mode basis transforms

Model quantities
================

   configuration_quantities  -- every configuration-dependent quantity at one configuration
   quantity_shapes           -- array shape of every key of configuration_quantities
   pseudo_inertia            -- 4 × 4 pseudo-inertia of a rigid body about a frame origin
   section_pseudo_inertia    -- pseudo-inertia per unit length of a beam section
   rigid_pseudo_inertias     -- constant pseudo-inertias of every rigid piece of a robot
   QUANTITY_KEYS             -- keys of configuration_quantities without sensor points
   POINT_KEYS                -- keys added when sensor points are requested
   RATE_KEYS                 -- keys of the shapes sampled inside each link (shape rates)
   RATE_SAMPLES              -- Gauss–Legendre points per beam of the sampled shapes
   rate_samples              -- sample points of a beam and their pseudo-inertias

Mode tracking
=============

   track           -- follow the modes along a path of configurations
   Tracking        -- result of track: order, sign and MAC per step
   track_grid      -- follow the modes over an N-D grid along a spanning tree
   GridTracking    -- result of track_grid, with the correlation across every grid edge
   track_grid_features -- track_grid from per-point tracking data (no mode shapes kept)
   point_tracking_data -- what track_grid_features needs of one point (features, groups)
   track_path_features -- track one path off the spanning tree from its points' data
   tracked_unit_features -- unit feature rows of tracked modes (the grid's edge correlation)
   mac             -- modified modal assurance criterion of every pair of modes
   correlation     -- signed normalised correlation of every pair of modes
   shape_features  -- feature vectors whose dot products are the MAC inner product
   combine         -- apply a linear recombination of the modes to every per-mode field

Smooth bases of close modes
===========================

   track_grid_smooth  -- a smooth mode basis over a grid: clusters of close modes as subspaces
   smooth_basis       -- the same on feature arrays (neighbourhood Procrustes per cluster)
   point_features     -- feature rows and exact modal mass of one point's raw modes
   track_features_smooth -- track_grid_smooth from per-point features (no mode shapes kept)
   reference_basis    -- each cluster's basis closest to one fixed reference (analytic gauge)
   reference_rows     -- mass-orthonormal feature rows of the reference point's modes
   MIN_OVERLAP        -- smallest overlap with the reference the gauge accepts
   SmoothBasis        -- result: transforms, block-diagonal stiffness, Rayleigh ω, neighbour MAC
   mode_clusters      -- groups of sorted modes that come close somewhere on a grid
   DEFAULT_GAP        -- relative frequency gap below which sorted modes form one cluster
   rotated_quantities -- model quantities of a rotated basis: on the eigenmodes, then rotated
   rotate_quantities  -- transform eigenmode quantities (linear: R, bilinear: R · Rᵀ)
   normalized_quantities -- quantities of the mass-normalised raw modes, and the map back
   stiffness_values   -- K̃ and its square root Ω̃ over a smooth basis' grid
   MODE_AXES          -- the mode axes of every model quantity

Smooth fits
===========

   fit_chebyshev           -- tensor-product Chebyshev fit of ω and the stiffness over the box
   ChebyshevFit            -- the fit, with casadi functions like ModalTable.function
   held_out_error          -- relative error of the fitted frequencies against direct TMM
   lobatto_points          -- Chebyshev–Lobatto points of a degree on an interval
   chebyshev_coefficients  -- tensor Chebyshev coefficients from samples at Lobatto points
   OMEGA_TARGET            -- default relative error target on ω
   joint_box               -- the interval fitted per shape joint (box, limits or a full turn)
   periodic_axis_kind      -- whether a grid axis spans a full turn ("closed", "open", None)
   fit_model_terms         -- Chebyshev fits of every model term, checked against direct TMM
   TERM_TARGET             -- default relative error target of the model terms
   TERM_FLOOR              -- floor of a term's error scale, relative to its family's peak
   TERM_FAMILIES           -- the families of terms that share a scale floor
   term_scales             -- the scale each term's error is measured against

Modal tables
============

   build_table         -- tabulate tracked modes and model quantities over a grid (cached)
   ModalTable          -- the tabulated quantities, with casadi interpolants
   shape_joints        -- the joints that change the shape of the structure
   compute_modes       -- raw TMM modes at many configurations, in parallel
   default_quantities  -- mass-normalise tracked shapes and evaluate the model quantities
   robot_fingerprint   -- canonical description of what changes a robot's dynamics
   canonical           -- exact JSON-able canonical form of a value (for cache keys)
   tmm_digest          -- digest of the TMM's source (part of the cached modes' key)
   function_identity   -- what identifies a quantity function in a cache key
   local_bspline_function -- a table's cubic B-spline evaluated locally (lean generated C)
   grid_function      -- casadi.Function interpolating gridded values (a table's lookup)
   tabulate_by_lines  -- a table's modes, tracking and quantities by grid lines on Dask
   line_blocks        -- the blocks of grid lines of tabulate_by_lines' tasks
   BLOCKS_PER_WORKER  -- blocks of grid lines per Dask worker thread
   MAX_BLOCK_POINTS   -- most grid points in one block of tabulate_by_lines (progress)
   interpolant_cache  -- within it, grid_function's B-spline fits are kept on disk

Frequency sweeps
================

   frequency_sweep   -- natural frequencies along a path of configurations, sorted or tracked
   FrequencySweep    -- result of frequency_sweep
"""

from casflex.modal.fits import (
    OMEGA_TARGET,
    ChebyshevFit,
    chebyshev_coefficients,
    fit_chebyshev,
    held_out_error,
    joint_box,
    lobatto_points,
    periodic_axis_kind,
)
from casflex.modal.gauge import MIN_OVERLAP, reference_basis, reference_rows
from casflex.modal.gridlines import (
    BLOCKS_PER_WORKER,
    MAX_BLOCK_POINTS,
    line_blocks,
    tabulate_by_lines,
)
from casflex.modal.integrals import (
    POINT_KEYS,
    QUANTITY_KEYS,
    RATE_KEYS,
    RATE_SAMPLES,
    configuration_quantities,
    pseudo_inertia,
    quantity_shapes,
    rate_samples,
    rigid_pseudo_inertias,
    section_pseudo_inertia,
)
from casflex.modal.normalize import (
    SHAPE_FIELDS,
    gauss_legendre,
    local_state,
    mass_normalize,
    modal_mass_matrix,
    modal_stiffness_matrix,
)
from casflex.modal.rotated import (
    MODE_AXES,
    normalized_quantities,
    rotate_quantities,
    rotated_quantities,
    stiffness_values,
)
from casflex.modal.subspace import (
    DEFAULT_GAP,
    SmoothBasis,
    mode_clusters,
    point_features,
    smooth_basis,
    track_features_smooth,
    track_grid_smooth,
)
from casflex.modal.sweep import FrequencySweep, frequency_sweep
from casflex.modal.table_functions import (
    grid_function,
    interpolant_cache,
    local_bspline_function,
)
from casflex.modal.tablekeys import canonical, function_identity, robot_fingerprint, tmm_digest
from casflex.modal.tables import (
    ModalTable,
    build_table,
    compute_modes,
    default_quantities,
    shape_joints,
)
from casflex.modal.term_fits import (
    TERM_FAMILIES,
    TERM_FLOOR,
    TERM_TARGET,
    fit_model_terms,
    term_scales,
)
from casflex.modal.tracking import (
    GridTracking,
    Tracking,
    combine,
    correlation,
    mac,
    point_tracking_data,
    shape_features,
    track,
    track_grid,
    track_grid_features,
    track_path_features,
    tracked_unit_features,
)

__all__ = [
    # mass normalisation
    "mass_normalize",
    "modal_mass_matrix",
    "modal_stiffness_matrix",
    "local_state",
    "gauss_legendre",
    "SHAPE_FIELDS",
    # model quantities
    "configuration_quantities",
    "quantity_shapes",
    "pseudo_inertia",
    "section_pseudo_inertia",
    "rigid_pseudo_inertias",
    "QUANTITY_KEYS",
    "POINT_KEYS",
    "RATE_KEYS",
    "RATE_SAMPLES",
    "rate_samples",
    # mode tracking
    "track",
    "Tracking",
    "track_grid",
    "track_grid_features",
    "point_tracking_data",
    "track_path_features",
    "tracked_unit_features",
    "GridTracking",
    "mac",
    "correlation",
    "shape_features",
    "combine",
    # smooth bases of close modes
    "track_grid_smooth",
    "smooth_basis",
    "point_features",
    "track_features_smooth",
    "reference_basis",
    "reference_rows",
    "MIN_OVERLAP",
    "SmoothBasis",
    "mode_clusters",
    "DEFAULT_GAP",
    "rotated_quantities",
    "normalized_quantities",
    "rotate_quantities",
    "stiffness_values",
    "MODE_AXES",
    # smooth fits
    "fit_chebyshev",
    "ChebyshevFit",
    "held_out_error",
    "lobatto_points",
    "chebyshev_coefficients",
    "OMEGA_TARGET",
    "joint_box",
    "periodic_axis_kind",
    "fit_model_terms",
    "TERM_TARGET",
    "TERM_FLOOR",
    "TERM_FAMILIES",
    "term_scales",
    # modal tables
    "build_table",
    "ModalTable",
    "shape_joints",
    "compute_modes",
    "default_quantities",
    "robot_fingerprint",
    "canonical",
    "tmm_digest",
    "function_identity",
    "local_bspline_function",
    "grid_function",
    "tabulate_by_lines",
    "line_blocks",
    "BLOCKS_PER_WORKER",
    "MAX_BLOCK_POINTS",
    "interpolant_cache",
    # frequency sweeps
    "frequency_sweep",
    "FrequencySweep",
]
