"""Simulation of the flexible-arm model: prescribed joint motion and torque-driven motion.

Two problems are solved on a :class:`casflex.model.FlexibleModel`:

* prescribed motion — the joints follow a planned trajectory exactly (perfect tracking,
  dissertation §3.3.7.1). The second (modal) row of eq. 118 gives the modal accelerations
  ``δ̈`` and is integrated for ``z = [δ; δ̇]`` only; the first row gives the torques that
  produce the motion (the model's ``prescribed`` function);
* torque-driven motion — forward dynamics of the full state ``x = [q; δ; q̇; δ̇]`` (the
  model's ``ode``) under a torque law: a controller ``τ = u(t, x)`` held over each step,
  or a tracking controller on a move, continuous or sampled, with disturbances and an
  optional estimator in the loop.

Prescribed motion (:mod:`casflex.simulate.prescribed`)
------------------------------------------------------
simulate_prescribed
    The joints follow a move, a shaped move or sampled arrays; ``method`` ``"rk4"``
    (one ``mapaccum`` call over all steps), ``"cvodes"``/``"idas"`` (adaptive) or
    ``"poly"`` (the same RK4 steps on the exact polynomial form of the modal rows,
    :mod:`casflex.simulate.poly`, interpolated in time by
    :mod:`casflex.simulate.chebyshev`, optionally compiled to C).
sample_reference
    A reference on the uniform grid of a simulation.
simulate_move
    Build the model of a robot and simulate one move (the ``casflex simulate`` command).

Torque-driven motion (:mod:`casflex.simulate.torque`)
-----------------------------------------------------
simulate_torque
    A torque law ``u(t, x)`` (callable, ``casadi.Function`` or constant) held over each
    step, with an optional generalized disturbance force.
simulate_closed_loop
    A tracking controller ``(qd, dqd, ddqd, x) -> τ`` on a move: continuous or sampled,
    impulsive tip force, EKF in the loop.
start_closed_loop
    The same with its sample steps in a worker process; the result is finished later.

Sensor data (:mod:`casflex.simulate.measurements`)
---------------------------------------------------
simulate_data
    A move simulated with its sensor signals (noise, offsets), the input of the
    estimators in :mod:`casflex.estimation`.
SimulatedData
    Its result.

Results (:mod:`casflex.simulate.results`)
-----------------------------------------
SimulationResult
    Time histories of :func:`simulate_prescribed` and :func:`simulate_torque`.
ClosedLoopResult
    Time histories of :func:`simulate_closed_loop`.
decay_time
    When a signal has decayed after a disturbance.
plot_result
    Joint angles, torques, modal amplitudes and tip deflection of a
    :class:`SimulationResult` (from :mod:`casflex.plotting`).

The exact kinematics truncated in δ (:mod:`casflex.simulate.exact_taylor`)
-------------------------------------------------------------------------
taylor_modal_rows
    The modal rows with every ``(q, δ)``-coefficient cut at a degree in δ: what the
    ``poly`` form of ``kinematics="exact"`` integrates (its error budget).
simulate_taylor
    Prescribed motion on those rows, by the RK4 steps of ``method="rk4"``.

:mod:`casflex.simulate.exact_poly` is that ``poly`` form at degree 2 (coefficients of
``(q, q̇)`` interpolated in time), used by ``simulate_prescribed(method="poly")``.

Integration (:mod:`casflex.simulate.integrators`)
-------------------------------------------------
rk4_step
    The one classical RK4 step of casflex, numeric and symbolic.

Units: s, rad, m, N m; modal amplitudes are those of the mass-normalised modes. The
references (moves, shaped moves, sampled arrays) are sampled by :mod:`casflex.moves`.
Measured costs of the methods: ``benchmarks/README_model.md``.
"""

from __future__ import annotations

from casflex.simulate.exact_taylor import simulate_taylor, taylor_modal_rows
from casflex.simulate.integrators import rk4_step
from casflex.simulate.measurements import SimulatedData, simulate_data
from casflex.simulate.prescribed import sample_reference, simulate_move, simulate_prescribed
from casflex.simulate.results import ClosedLoopResult, SimulationResult, decay_time
from casflex.simulate.torque import simulate_closed_loop, simulate_torque, start_closed_loop

__all__ = ["SimulationResult", "simulate_prescribed", "simulate_torque", "sample_reference",
           "plot_result", "simulate_move", "simulate_closed_loop", "ClosedLoopResult",
           "decay_time", "rk4_step", "simulate_data", "SimulatedData", "start_closed_loop",
           "taylor_modal_rows", "simulate_taylor"]


def __getattr__(name):
    # plot_result lives in casflex.plotting; matplotlib is imported when it is asked for
    if name == "plot_result":
        from casflex.plotting import plot_result

        return plot_result
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
