"""Modal controllability and feedback control of flexible arms (dissertation §6.2).

Everything here works on a :class:`casflex.model.FlexibleModel` (usually from
:func:`casflex.model.build_model`) and returns plain numpy data or ``casadi.Function``
objects that can be simulated (:func:`casflex.simulate.simulate_closed_loop`, or
:func:`casflex.simulate.simulate_torque` through :func:`tracking`) and code-generated.
Each module documents how it reads the dissertation's equations.

Controllability and accessibility (:mod:`casflex.control.accessibility`, eq. 201–204)
-------------------------------------------------------------------------------------
modal_system              ``q -> (A, B)`` of the flexible subsystem (eq. 201)
controllability           controllability matrix ``G_c(q)`` and its rank (eq. 203)
accessibility_function    ``q -> a``, the accessibility indexes as a CasADi function
accessibility             accessibility indexes at one or many configurations (eq. 204)
accessibility_map         indexes over a grid of two joints (Fig. 108–110, 120)
accessibility_along       indexes along the planned trajectory of a move
robot_accessibility_map   tabulate a robot's modes and map its indexes (``casflex
                          accessibility``)
plot_accessibility        maps of the indexes, one panel per mode (in
                          :mod:`casflex.plotting`)

Tracking laws (:mod:`casflex.control.laws`, eq. 210–213, 232, 248)
-----------------------------------------------------------------
reference_function        the reference of a move as ``t -> (qd, dqd, ddqd)`` (from
                          :mod:`casflex.moves`, which owns every way of sampling one)
inversion_controller      inversion-based law (eq. 210 with eq. 213)
feedforward_controller    computed torque on the rigid model (eq. 232, slow law eq. 248)
composite_controller      slow law plus fast LQR feedback (eq. 248 + 251)
tracking                  a law closed over a move's reference: ``(t, x) -> tau``
closed_loop               the model's ``ode`` under a law: ``(t, x) -> xdot``

Singular perturbation (:mod:`casflex.control.perturbation`, eq. 244–256)
-----------------------------------------------------------------------
perturbation_parameter    ``ε = 1/ω_min`` [s] (eq. 244)
boundary_layer            ``q -> (A_f, B_f)`` of the fast subsystem (eq. 251)
lqr                       continuous-time LQR (python-control, errors as SolverError)
fast_gain                 LQR gain of the boundary layer at one configuration
GainSchedule              fast gains tabulated over joints and interpolated
dependent_joints          joints a numeric function of ``q`` depends on
gain_schedule             fast gains over the configuration grid
cached_gain_schedule      :func:`gain_schedule` on a coarse axis, cached on disk

Slow tracking gains (:mod:`casflex.control.gains`, §6.2.2.2, §6.2.3)
--------------------------------------------------------------------
SlowGains                 ``K_p``, ``K_d``, their bandwidth and its separation from ω_min
slow_gains_for_move       bandwidth a stated fraction of the lowest frequency along a move
dissertation_gains        fixed gains (the dissertation's ``K_p = 1``, ``K_d = 2``)

Stability checks (:mod:`casflex.control.stability`, eq. 225–230, §6.2.3.1)
-------------------------------------------------------------------------
inversion_stability       zero-dynamics condition (eq. 226) and rate (eq. 230)
composite_stability       is the fast closed loop Hurwitz along a move?
mass_matrix_condition     is the model's M(q, 0) positive definite along a move?
mass_matrix_over_box      is it positive definite over the joint box (grid and cell centres)?
schedule_stability        fast loop Hurwitz and M positive definite over a schedule's cells
check_stability           either check for a robot and a move (``casflex check``)
slow_loop_condition       is the slow (rigid) loop under Kp, Kd exponentially stable?

Closed-loop simulation is time response, not design: :func:`casflex.simulate.simulate_closed_loop`
runs the model under these laws (with impulses and the EKF in the loop) and
:func:`casflex.simulate.decay_time` measures how fast the vibration dies out.

Examples
--------
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> robot = load("problems/arm2link.toml")
>>> q = [0.0, 0.0, -np.pi / 2]
>>> model = FlexibleModel(robot, PointwiseProvider(robot, q, count=3), gravity=None)
>>> accessibility(model, q).round(3).tolist()
[0.495, 0.522, 0.079]
"""

from __future__ import annotations

import numpy as np  # noqa: F401  (the examples use np)

from casflex.control.accessibility import (
    accessibility,
    accessibility_along,
    accessibility_function,
    accessibility_map,
    controllability,
    modal_system,
    robot_accessibility_map,
)
from casflex.control.gains import SlowGains, dissertation_gains, slow_gains_for_move
from casflex.control.laws import (
    closed_loop,
    composite_controller,
    feedforward_controller,
    inversion_controller,
    tracking,
)
from casflex.control.perturbation import (
    GainSchedule,
    boundary_layer,
    cached_gain_schedule,
    dependent_joints,
    fast_gain,
    gain_schedule,
    lqr,
    perturbation_parameter,
    schedule_axes,
)
from casflex.control.stability import (
    check_stability,
    composite_stability,
    inversion_stability,
    mass_matrix_condition,
    mass_matrix_over_box,
    schedule_stability,
    slow_loop_condition,
)
from casflex.moves import reference_function

__all__ = [
    "modal_system",
    "controllability",
    "accessibility_function",
    "accessibility",
    "accessibility_map",
    "accessibility_along",
    "robot_accessibility_map",
    "plot_accessibility",
    "reference_function",
    "inversion_controller",
    "feedforward_controller",
    "composite_controller",
    "tracking",
    "closed_loop",
    "perturbation_parameter",
    "boundary_layer",
    "lqr",
    "fast_gain",
    "GainSchedule",
    "schedule_axes",
    "dependent_joints",
    "gain_schedule",
    "cached_gain_schedule",
    "SlowGains",
    "slow_gains_for_move",
    "dissertation_gains",
    "inversion_stability",
    "composite_stability",
    "mass_matrix_condition",
    "mass_matrix_over_box",
    "schedule_stability",
    "check_stability",
    "slow_loop_condition",
]


def __getattr__(name: str):
    # plot_accessibility lives with the other figures; importing it lazily keeps
    # matplotlib out of `import casflex.control`
    if name == "plot_accessibility":
        from casflex.plotting import plot_accessibility

        return plot_accessibility
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
