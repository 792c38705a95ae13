"""Fitting the model to the real arm: modal identification from test logs and model
updating (``casflex identify``, ``casflex calibrate``).

Test logs
=========

   VibrationLog              -- one recorded test: times, joint angles, accelerometer channels
   read_log             -- read a CSV or NPZ log
   uniform_sample_rate  -- the sample rate of a log from its time column
   split_configurations -- cut a log into segments of constant joint angles

Modal identification
====================

   identify_modes   -- frequencies, damping ratios and standard errors from a free decay
   ModalEstimate    -- the modes of one record, which channels see them
   welch_spectrum   -- Welch spectra and the peak list (the first look)
   WelchSpectrum    -- spectra and peaks

Model updating
==============

   calibrate              -- fit robot parameters to measured natural frequencies
   CalibrationResult      -- fitted values, standard deviations, residuals, identifiability
   Measurements           -- measured frequencies at configurations
   read_measurements      -- read a measurement CSV
   FitParameter           -- a free parameter with bounds
   read_fit               -- read a fit file ([[parameter]] tables)
   model_frequencies      -- TMM frequencies at many configurations [Hz]
   calibrated_text        -- the robot file's text with fitted values put in
   measurements_from_logs -- identify every log and tabulate the frequencies

Mode matching
=============

   Channel               -- one accelerometer axis at a point of a flexible link
   read_channels         -- the accelerometer channels of a sensor file (plain data)
   model_channel_shapes  -- modelled frequencies and mode shapes at the channels
   mac_matrix            -- Modal Assurance Criterion between two sets of shapes
   match_modes           -- pair measured with modelled modes (MAC, then frequency order)

Parameter paths
===============

   ParameterPath          -- a parsed ``<link>.<table>.<key>`` path
   parse_parameter_path   -- parse and check a path against a robot
   parameter_value        -- current value of a parameter
   with_parameters        -- a robot with parameters changed
"""

from casflex.identification.logs import (
    VibrationLog,
    read_log,
    split_configurations,
    uniform_sample_rate,
)
from casflex.identification.matching import (
    Channel,
    mac_matrix,
    match_modes,
    model_channel_shapes,
    read_channels,
)
from casflex.identification.modal_fit import (
    ModalEstimate,
    WelchSpectrum,
    identify_modes,
    welch_spectrum,
)
from casflex.identification.parameters import (
    ParameterPath,
    parameter_value,
    parse_parameter_path,
    with_parameters,
)
from casflex.identification.robotfile import calibrated_text
from casflex.identification.updating import (
    CalibrationResult,
    FitParameter,
    Measurements,
    calibrate,
    measurements_from_logs,
    model_frequencies,
    read_fit,
    read_measurements,
)

__all__ = [
    # test logs
    "VibrationLog",
    "read_log",
    "uniform_sample_rate",
    "split_configurations",
    # modal identification
    "identify_modes",
    "ModalEstimate",
    "welch_spectrum",
    "WelchSpectrum",
    # model updating
    "calibrate",
    "CalibrationResult",
    "Measurements",
    "read_measurements",
    "FitParameter",
    "read_fit",
    "model_frequencies",
    "calibrated_text",
    "measurements_from_logs",
    # mode matching
    "Channel",
    "read_channels",
    "model_channel_shapes",
    "mac_matrix",
    "match_modes",
    # parameter paths
    "ParameterPath",
    "parse_parameter_path",
    "parameter_value",
    "with_parameters",
]
