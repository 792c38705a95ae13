"""Extended Kalman filter for the modal states of a flexible arm (dissertation §5.4–5.5).

The joint motion ``u = [q; q̇; q̈]`` is measured (encoders, eq. 158); the filter estimates
``x = Δ = [δ; δ̇]`` from accelerometer or strain signals (:mod:`casflex.sensors`). The
package reads as the data flow: the model's flexible rows become a small tabulated plant
(:mod:`~casflex.estimation.plant`), the plant and the sensors one EKF step as a CasADi
function (:mod:`~casflex.estimation.ekf`, ready for C code generation), and the step is
run over recorded or simulated data (:mod:`~casflex.estimation.runs`).

Plant (:mod:`casflex.estimation.plant`)
---------------------------------------
.. autosummary::

   exact_plant_function -- the model's flexible rows solved for δ̈, ``(u, x) -> δ̈``
   tabulate_plant       -- expand them in Δ and tabulate the coefficients (disk cache)
   FlexiblePlant        -- the tabulated plant: coefficients, ``function``, ``rhs_function``

Filter steps (:mod:`casflex.estimation.ekf`)
--------------------------------------------
.. autosummary::

   ekf_step_function        -- one EKF step, ``(x, P, u, y, mask) -> (x_next, P_next, x_post)``
   full_state_step_function -- one step of the joints and modes from encoders and sensors
   ekf_functions            -- the named functions of a real-time estimator
   rigid_signal_function    -- ``u -> y_rigid``, the rigid-motion part of the signals

Guards of the real-time path (:mod:`casflex.estimation.guard`)
--------------------------------------------------------------
.. autosummary::

   Guard         -- options of a guarded step: innovation gate, covariance bounds, resets
   DEFAULT_GATE  -- the default gate, the χ²(1) quantile of 1 − 1e-9
   STATUS_BITS   -- the bits of the status word (``STATUS_*`` constants)
   status_names  -- the names of the bits set in a status word

Runs and prefilter (:mod:`casflex.estimation.runs`)
---------------------------------------------------
.. autosummary::

   run_ekf           -- run a step over recorded arrays (one ``mapaccum`` call)
   EKFResult         -- filtered estimates, priors and covariances of a run
   prefilter_initial -- the step's high-pass prefilter in steady state at the first sample
   highpass_cutoff   -- cut-off one decade below the lowest natural frequency
   highpass          -- first-order high-pass of sampled signals

Simulated data (re-exported from :mod:`casflex.simulate.measurements`)
-----------------------------------------------------------------------
.. autosummary::

   simulate_data -- integrate the exact flexible rows along a move and sample the sensors
   SimulatedData -- times, inputs, true states and signals of a simulation

Examples
--------
>>> import numpy as np
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> from casflex.moves import Move
>>> from casflex.sensors import SensorSet, StrainPair
>>> robot = load("problems/arm2link.toml")
>>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3), name="sg")])
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
...                       gravity=None)
>>> data = simulate_data(model, ss, Move([0, 0, 0], [-1, 0, 0], 0.2), t_end=0.05)
>>> step = ekf_step_function(tabulate_plant(model), ss, Q=5e-6, R=9e-14, dt=1e-3)
>>> run_ekf(step, data.u, data.y, np.zeros(2), 1e-6 * np.eye(2)).x.shape
(51, 2)
"""

from __future__ import annotations

from casflex.estimation.ekf import (
    ekf_functions,
    ekf_step_function,
    full_state_step_function,
    rigid_signal_function,
)
from casflex.estimation.guard import (
    DEFAULT_GATE,
    STATUS_BITS,
    STATUS_COVARIANCE_RESET,
    STATUS_INPUT_HELD,
    STATUS_SAMPLE_NONFINITE,
    STATUS_SAMPLE_REJECTED,
    STATUS_STATE_RESET,
    STATUS_TORQUE_CLIPPED,
    STATUS_TORQUE_HELD,
    Guard,
    status_names,
)
from casflex.estimation.plant import FlexiblePlant, exact_plant_function, tabulate_plant
from casflex.estimation.runs import (
    EKFResult,
    highpass,
    highpass_cutoff,
    prefilter_initial,
    run_ekf,
)
from casflex.simulate.measurements import SimulatedData, simulate_data

__all__ = [
    "FlexiblePlant",
    "tabulate_plant",
    "exact_plant_function",
    "ekf_step_function",
    "ekf_functions",
    "full_state_step_function",
    "EKFResult",
    "run_ekf",
    "highpass",
    "highpass_cutoff",
    "prefilter_initial",
    "rigid_signal_function",
    "Guard",
    "DEFAULT_GATE",
    "STATUS_BITS",
    "STATUS_SAMPLE_REJECTED",
    "STATUS_SAMPLE_NONFINITE",
    "STATUS_INPUT_HELD",
    "STATUS_COVARIANCE_RESET",
    "STATUS_STATE_RESET",
    "STATUS_TORQUE_CLIPPED",
    "STATUS_TORQUE_HELD",
    "status_names",
    "SimulatedData",
    "simulate_data",
]
