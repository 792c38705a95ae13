"""Fitting the model to the real arm: modal identification from test logs and model
updating (``casflex identify``, ``casflex calibrate``).

Test logs
=========

   TestLog              -- one recorded test: times, joint angles, accelerometer channels
   read_log             -- read a CSV or NPZ log
   uniform_sample_rate  -- the sample rate of a log from its time column

Modal identification
====================

   identify_modes   -- frequencies, damping ratios and standard errors from a free decay
   ModalEstimate    -- the modes of one record, which channels see them
   welch_spectrum   -- Welch spectra and the peak list (the first look)
   WelchSpectrum    -- spectra and peaks
"""

from casflex.identification.logs import TestLog, read_log, uniform_sample_rate
from casflex.identification.modal_fit import (
    ModalEstimate,
    WelchSpectrum,
    identify_modes,
    welch_spectrum,
)

__all__ = [
    # test logs
    "TestLog",
    "read_log",
    "uniform_sample_rate",
    # modal identification
    "identify_modes",
    "ModalEstimate",
    "welch_spectrum",
    "WelchSpectrum",
]
