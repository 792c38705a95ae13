"""The end-to-end design job: from a study file to a shaper, a checked controller and C code.

A *study* names a robot, a planned move and a sensor set, plus the settings of each step
(``problems/studies/arm2link_move1.toml`` is the bundled example; ``problems/README.md``
documents every key). :func:`run_design` tabulates the modal model, designs the
specified-insensitivity shaper of the move from its frequency ranges and modal
contributions, simulates the move unshaped, shaped and under the closed-loop controller
with the EKF in the loop, checks stability along the move, generates and compiles the C
bundle of the real-time loop, and writes ``report.md``, PNG figures, ``summary.json`` and
``c/`` to an output directory. Everything is validated before any heavy work starts
(:func:`load_study`).

Study files (:mod:`casflex.design.study`)
-----------------------------------------
Study
    A validated study: the loaded robot, move and sensors and the settings of every step.
load_study
    Read and validate a study file.

The job (:mod:`casflex.design.job`)
-----------------------------------
run_design
    Run the whole job of a study and write its report.
DesignResult
    What a job produced: the summary, the output directory, the files written.
c_bundle_key
    The digest of everything the job's C bundle is generated from (a second run with the
    same key keeps the bundle and its build).

The loop's EKF step, cached (:mod:`casflex.design.ekf_cache`)
-------------------------------------------------------------
loop_ekf_step
    The study's EKF step, read from the cache when built from the same inputs before.

The planned move (:mod:`casflex.design.planner`)
------------------------------------------------
plan_next_to_shaped
    The optimal move at the shaped move's limits, verified by simulation (``[planner]``).
planner_summary
    Its ``planner`` object of ``summary.json``.

The report itself (``summary.json``, ``report.md``) is written by
:mod:`casflex.design.report`; its figures are drawn by :mod:`casflex.plotting`.

Examples
--------
>>> study = load_study("problems/studies/arm2link_move1.toml")
>>> study.move.name, study.model["modes"], study.controller["law"]
('move1', 3, 'composite')
"""

from __future__ import annotations

from casflex.design.ekf_cache import loop_ekf_step
from casflex.design.job import DesignResult, c_bundle_key, run_design
from casflex.design.planner import plan_next_to_shaped, planner_summary
from casflex.design.study import Study, load_study

__all__ = [
    # study files
    "Study",
    "load_study",
    # the job
    "run_design",
    "DesignResult",
    "c_bundle_key",
    # the loop's EKF step, cached
    "loop_ekf_step",
    # the planned move
    "plan_next_to_shaped",
    "planner_summary",
]
