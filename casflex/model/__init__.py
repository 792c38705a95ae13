"""The low-order symbolic model of a flexible arm: joints plus tracked modal amplitudes.

A :class:`FlexibleModel` holds the CasADi equations of motion (mass matrix, Coriolis,
potential forces, damping, forward and prescribed-motion dynamics) of a robot whose
configuration-dependent modal quantities come from a *provider*; :func:`build_model`
tabulates those quantities over the shape joints and builds the model in one call.

Building a model
----------------
build_model
    Tabulate the modes of a robot (cached on disk) and build its model on B-spline
    interpolants of the tables.
default_grid
    The default full-turn grid of the shape joints [rad].
sensor_quantities
    Modal quantities plus mode values at sensor points, for the tabulation.

The equations of motion (:mod:`casflex.model.equations`)
--------------------------------------------------------
FlexibleModel
    Symbolic rigid–flexible model; ``functions()`` gives its casadi Functions.

Exact kinematics in strain coordinates (:mod:`casflex.model.strain_kinematics`)
-------------------------------------------------------------------------------
KINEMATICS
    The kinematics a model can use: ``"truncated"`` (default) or ``"exact"``.
ROD_POINTS
    Gauss–Legendre points per flexible link of the exact rods.
node_interpolation
    The rod's nodes along a link and the map from the tabulated samples.
rod_nodes
    One link rebuilt exactly from the modal strains (SX).
rod_point
    The section of a rod at an arc length between its nodes (the sensors' points).
point_mass_terms
    Mass matrix, bias forces and gravity of the exact rods (assembled per link).

A beam's base pose as factors (:mod:`casflex.model.pose_factors`)
-----------------------------------------------------------------
pose_factors
    One factor per rotation, translation and beam end, checked against the model's pose
    (the accelerometers' recursive pass).

Providers of the modal quantities (:mod:`casflex.model.providers`)
------------------------------------------------------------------
TableProvider
    Interpolants of a modal table over the shape joints.
ChebyshevProvider
    Tensor Chebyshev series of the model terms over the joint box (no grid).
ConstantProvider
    Quantities that do not change with the configuration.
PointwiseProvider
    Quantities of one configuration, computed with the TMM.
rigid_provider
    No modes: the rigid-body model.
zero_entries
    Entries of a quantity that vanish wherever it is known.

Examples
--------
>>> from casflex.model import FlexibleModel, rigid_provider
>>> from casflex.robot import load
>>> robot = load("problems/arm2link.toml")
>>> FlexibleModel(robot, rigid_provider(robot), gravity=None).m
0
"""

from __future__ import annotations

from casflex.model.build import build_model, default_grid, sensor_quantities
from casflex.model.equations import FlexibleModel
from casflex.model.pose_factors import pose_factors
from casflex.model.providers import (
    ChebyshevProvider,
    ConstantProvider,
    PointwiseProvider,
    TableProvider,
    rigid_provider,
    zero_entries,
)
from casflex.model.strain_kinematics import (
    KINEMATICS,
    ROD_POINTS,
    node_interpolation,
    point_mass_terms,
    rod_nodes,
    rod_point,
)

__all__ = [
    # building a model
    "build_model",
    "default_grid",
    "sensor_quantities",
    # the equations of motion
    "FlexibleModel",
    # exact kinematics
    "KINEMATICS",
    "ROD_POINTS",
    "node_interpolation",
    "point_mass_terms",
    "rod_nodes",
    "rod_point",
    # a beam's base pose as factors
    "pose_factors",
    # providers
    "TableProvider",
    "ChebyshevProvider",
    "ConstantProvider",
    "PointwiseProvider",
    "rigid_provider",
    "zero_entries",
]
