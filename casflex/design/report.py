"""What a design job leaves behind: ``summary.json`` and the text of ``report.md``.

The summary is the dict :func:`casflex.design.run_design` computes (SI units); the report
is a Markdown page that tabulates it and shows the job's figures (drawn by
:mod:`casflex.plotting`, saved next to it: ``frequencies.png``, ``prv.png``,
``tip_deflection.png``, ``estimation.png``, ``accessibility.png``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

from casflex._json import jsonable

if TYPE_CHECKING:
    from casflex.design.study import Study

__all__ = ["write_report"]


def write_report(out_dir: str | os.PathLike, study: Study, summary: dict) -> list[Path]:
    """Write ``summary.json`` and ``report.md`` of a design job to ``out_dir``.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        An existing directory (the figures the report shows are expected beside it).
    study : casflex.design.Study
        The study the job ran.
    summary : dict
        The job's summary (see :func:`casflex.design.run_design`), written as JSON.

    Returns
    -------
    list of pathlib.Path
        ``[report.md, summary.json]``.

    Examples
    --------
    A one-mode summary with made-up numbers:

    >>> import tempfile
    >>> from casflex.design import load_study
    >>> study = load_study("problems/studies/arm2link_move1.toml")
    >>> summary = {
    ...     "study": "demo", "robot": "arm", "move": "move1", "modes": 1,
    ...     "controller": "inversion", "frequency_span": [[8.3, 10.5]],
    ...     "frequency_ranges": [[6.6, 12.6]], "contributions": [1.0], "tolerances": [0.05],
    ...     "shaper": {"times": [0.0, 0.35], "amplitudes": [0.5, 0.5]},
    ...     "shaper_duration": 0.35, "residual_unshaped": 0.08, "residual_shaped": 0.002,
    ...     "residual_closed_loop": 0.003, "residual_reduction": 0.975,
    ...     "max_tip_deflection": {"unshaped": 0.1, "shaped": 0.05, "closed_loop": 0.05},
    ...     "estimation_rms_ratio": {"delta": [120.0], "ddelta": [80.0]},
    ...     "stability": {"check": "eq. 226 zero dynamics", "stable": True,
    ...                   "worst_margin": 0.5, "unit": "1/s^3", "worst_time": 1.0},
    ...     "closed_loop_finite": True, "tracking_error_max": 0.01, "stable": True,
    ...     "c_compiled": False, "c_functions": ["rt_step"], "c_files": ["arm.c"],
    ...     "timings_s": {"model_s": 1.0}}
    >>> out = Path(tempfile.mkdtemp())
    >>> report, _ = write_report(out, study, summary)
    >>> text = report.read_text()
    >>> "**97.5 %**" in text, "(tip_deflection.png)" in text
    (True, True)
    """
    out = Path(out_dir)
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(jsonable(summary), indent=2) + "\n")
    report = out / "report.md"
    report.write_text(_markdown(study, summary))
    return [report, summary_path]


def _markdown(study, s):
    """The text of ``report.md`` for the summary ``s`` of ``study``."""
    lines = [f"# Design report: {s['study']}", ""]
    if study.description:
        lines += [study.description, ""]
    lines += [
        f"Robot `{study.robot_path.name}` ('{s['robot']}'), move `{s['move']}` "
        f"({study.move.description or 'no description'}), sensors "
        f"`{study.sensors_path.name}` ({', '.join(study.sensors.output_names)}). "
        f"{s['modes']} modes, controller: {s['controller']}.",
        "",
        "## Frequencies and modal contributions along the move",
        "",
        "| mode | ω span along the move [rad/s] | design range [rad/s] | contribution | Vtol |",
        "|---|---|---|---|---|",
    ]
    for j in range(s["modes"]):
        a, b = s["frequency_span"][j]
        lo, hi = s["frequency_ranges"][j]
        lines.append(f"| {j + 1} | {a:.3f} – {b:.3f} | {lo:.3f} – {hi:.3f} | "
                     f"{s['contributions'][j]:.3g} | {s['tolerances'][j]:.3g} |")
    lines += [
        "",
        f"Design ranges: the spans widened by ±{100 * study.shaper['margin']:.0f} %; "
        "tolerances from the contributions (eq. 198).",
        "",
        "![frequencies](frequencies.png)",
        "",
        "## Shaper",
        "",
        f"Specified-insensitivity shaper, {len(s['shaper']['times'])} impulses, duration "
        f"**{s['shaper_duration']:.4f} s**.",
        "",
        "| t [s] | A |",
        "|---|---|",
    ]
    for t, a in zip(s["shaper"]["times"], s["shaper"]["amplitudes"], strict=True):
        lines.append(f"| {t:.5f} | {a:.5f} |")
    lines += [
        "",
        "![PRV](prv.png)",
        "",
        "## Tip deflection",
        "",
        "| run | max [mm] | residual after the shaped move [mm] |",
        "|---|---|---|",
        f"| unshaped | {1e3 * s['max_tip_deflection']['unshaped']:.3f} | "
        f"{1e3 * s['residual_unshaped']:.3f} |",
        f"| shaped | {1e3 * s['max_tip_deflection']['shaped']:.3f} | "
        f"{1e3 * s['residual_shaped']:.3f} |",
        f"| shaped + {s['controller']} + EKF | {1e3 * s['max_tip_deflection']['closed_loop']:.3f}"
        f" | {1e3 * s['residual_closed_loop']:.3f} |",
        "",
        f"Shaping removes **{100 * s['residual_reduction']:.1f} %** of the unshaped residual "
        "tip deflection (joints following the plan exactly; residual = largest deflection "
        "after the move ends).",
        "",
        "![tip deflection](tip_deflection.png)",
        "",
        "## Estimation (EKF in the loop)",
        "",
        "RMS of the true state over RMS of the estimation error, per mode:",
        "",
        "| mode | δ | δ̇ |",
        "|---|---|---|",
    ]
    for j in range(s["modes"]):
        lines.append(f"| {j + 1} | {s['estimation_rms_ratio']['delta'][j]:.3g} | "
                     f"{s['estimation_rms_ratio']['ddelta'][j]:.3g} |")
    st = s["stability"]
    lines += [
        "",
        "![estimation](estimation.png)",
        "",
        "## Stability along the shaped move",
        "",
        f"Check: {st['check']}. **{'Passed' if st['stable'] else 'FAILED'}**: worst margin "
        f"{st['worst_margin']:.4g} {st['unit']} at t = {st['worst_time']:.3f} s.",
        "",
        ("The sampled closed loop with the EKF stays bounded; largest joint tracking error "
         f"{s['tracking_error_max']:.3g} rad." if s["closed_loop_finite"] else
         "**The sampled closed loop with the EKF diverged** (see the tip-deflection and "
         "estimation figures): the design is not realizable at this sample time."),
        "",
        f"Overall: **{'stable' if s['stable'] else 'NOT stable'}**.",
        "",
        "![accessibility](accessibility.png)",
        "",
        "## C code",
        "",
        f"`c/` ({'compiled' if s['c_compiled'] is True else s['c_compiled'] or 'not compiled'})"
        f": functions {', '.join(f'`{f}`' for f in s['c_functions'])}; files "
        f"{', '.join(f'`{f}`' for f in s['c_files'])}. The bundle's README gives the call "
        "signatures and the build command.",
        "",
        *_guard_lines(s.get("c_guard")),
        "## Timings [s]",
        "",
        " | ".join(f"{k} {v:.2f}" for k, v in s["timings_s"].items()),
        "",
    ]
    return "\n".join(lines)


def _guard_lines(guard):
    """The report's sentence on the guarded real-time step (``summary["c_guard"]``)."""
    if not guard or not guard.get("guarded"):
        return ["`rt_step` is not guarded: a NaN or outlier sample reaches the estimate and "
                "the torques (`codegen.guard = false`).", ""]
    limits = ", ".join(f"{v:.3g}" for v in guard["torque_limits"])
    return [f"`rt_step` is guarded: a sample whose normalised innovation ν²/S exceeds "
            f"{guard['gate']:.3g} is rejected as a dropout, non-finite inputs are skipped "
            "or held, P is kept positive definite, the step returns a status word "
            f"(`CASFLEX_STATUS_*`) and the torques are clipped to ±[{limits}] N m.", ""]
