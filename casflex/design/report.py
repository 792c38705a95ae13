"""What a design job leaves behind: ``summary.json`` and the text of ``report.md``.

The summary is the dict :func:`casflex.design.run_design` computes (SI units); the report
is a Markdown page that tabulates it and shows the job's figures (drawn by
:mod:`casflex.plotting`, saved next to it: ``frequencies.png``, ``prv.png``,
``tip_deflection.png``, ``joint_tracking.png``, ``estimation.png``,
``accessibility.png``). Its sections: frequencies and modal contributions, the shaper, tip
deflection, the planned move (with a ``[planner]`` section: ``planned.png``), the closed
loop's joint tracking (the slow gains, their time-scale separation,
the tracking error and where it comes from), the EKF in the loop (weak estimates
flagged), stability, modal accessibility, the C code, timings and the dissertation
references the text uses.
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


#: the estimates whose RMS ratio of state to error is below this are flagged in the report
WEAK_ESTIMATE_RATIO = 10.0

#: the report's labels of the job's timings (``summary["timings_s"]``)
TIMING_LABELS = {
    "model_s": "modal model",
    "shaper_s": "frequencies and shaper",
    "simulate_s": "prescribed-joint runs",
    "controller_s": "controller and stability",
    "closed_loop_s": "closed loop with the EKF",
    "codegen_s": "C code",
    "planner_s": "planned move",
    "figures_s": "figures (drawn alongside the C code)",
    "total_s": "total",
}

#: what the dissertation references of the report mean (the References section)
REFERENCES = [
    ("eq. 118", "the mass matrix M(q) of the model, expanded to order 0 in δ (§3.3)"),
    ("eq. 198", "tolerable residual vibration Vtol of each mode from its modal "
                "contribution to the tip deflection (§6.1.4)"),
    ("eq. 204", "the modal accessibility index: how strongly the joint torques reach each "
                "mode (§6.2.1)"),
    ("eq. 210, 213", "the inversion-based tracking law (§6.2.2)"),
    ("eq. 225", "the modal-damping condition of the inversion-based law: the zero "
                "dynamics are exponentially stable only if the modes are damped (§6.2.2.1)"),
    ("eq. 226", "the zero-dynamics stability condition of the inversion-based law "
                "(§6.2.2.1)"),
    ("eq. 244–256", "the singular-perturbation split: ε = 1/ω_min, the slow (rigid) law "
                    "eq. 248, the fast (boundary-layer) subsystem eq. 251 and its LQR "
                    "(§6.2.3)"),
    ("§5.5.1", "the EKF with accelerometer feedback and its noise values"),
    ("§6.1.4, §6.1.5", "optimal specified-insensitivity shaping of a flexible arm and its "
                       "case study (±20 % frequency ranges)"),
    ("§6.2.2.2", "the case study of the tracking laws (slow gains Kp = 1, Kd = 2)"),
    ("§6.2.3.1", "the composite (slow + fast) controller and the check that its fast loop "
                 "is Hurwitz along the move"),
]


def _fmt(value, digits=3):
    """A positive number with ``digits`` significant digits, trailing zeros kept (``1.40``
    next to ``5.19``), integers from ``10**(digits-1)`` on."""
    if not value == value:
        return "nan"
    if abs(value) >= 10 ** (digits - 1):
        return f"{value:.0f}"
    return f"{value:#.{digits}g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.2e}"


def _markdown(study, s):
    """The text of ``report.md`` for the summary ``s`` of ``study``."""
    lines = [f"# Design report: {s['study']}", ""]
    if study.description:
        lines += [study.description, ""]
    lines += [
        f"Robot `{study.robot_path.name}` ('{s['robot']}'), move `{s['move']}` "
        f"({study.move.description or 'no description'}), sensors "
        f"`{study.sensors_path.name}` ({', '.join(study.sensors.output_names)}). "
        f"{s['modes']} modes, controller: {s['controller']}. References such as "
        "“eq. 198” and “§6.2.3.1” point into the dissertation this toolkit implements "
        "(see [References](#references)).",
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
                     f"{s['contributions'][j]:.3f} | {s['tolerances'][j]:.3f} |")
    lines += [
        "",
        f"Design ranges: the spans widened by ±{100 * study.shaper['margin']:.0f} %; "
        "contributions are each mode's share of the tip deflection, normalised to the "
        "largest; tolerances from the contributions (eq. 198).",
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
        *_planner_lines(s.get("planner")),
        *_closed_loop_lines(s),
        "## Estimation (EKF in the loop)",
        "",
        *_estimator_lines(s.get("estimator")),
        "RMS of the true state over RMS of the estimation error, per mode, over the whole "
        f"closed-loop run (an estimate below {WEAK_ESTIMATE_RATIO:.0f} is flagged: its error "
        f"is more than {100 / WEAK_ESTIMATE_RATIO:.0f} % of the signal):",
        "",
        "| mode | δ | δ̇ |",
        "|---|---|---|",
    ]
    ratios = s["estimation_rms_ratio"]
    for j in range(s["modes"]):
        lines.append(f"| {j + 1} | {_ratio(ratios['delta'][j])} | "
                     f"{_ratio(ratios['ddelta'][j])} |")
    weak = [f"δ{j + 1}" for j in range(s["modes"])
            if not ratios["delta"][j] >= WEAK_ESTIMATE_RATIO] + \
        [f"δ̇{j + 1}" for j in range(s["modes"]) if not ratios["ddelta"][j] >= WEAK_ESTIMATE_RATIO]
    lines += ["", (f"**Weak estimates: {', '.join(weak)}** (ratio below "
                   f"{WEAK_ESTIMATE_RATIO:.0f}): the controller acts on estimates whose "
                   "error is a large part of the signal." if weak else
                   f"Every estimate has a ratio of at least {WEAK_ESTIMATE_RATIO:.0f}."), ""]
    st = s["stability"]
    lines += [
        "![estimation](estimation.png)",
        "",
        "## Stability along the shaped move",
        "",
        f"Check: {st['check']}. **{'Passed' if st['stable'] else 'FAILED'}**: worst margin "
        f"{st['worst_margin']:.4g} {st['unit']} at t = {st['worst_time']:.3f} s.",
        "",
        *_condition_lines(st.get("conditions", {})),
        *_schedule_cell_lines(st.get("schedule_cells")),
        ("The sampled closed loop with the EKF stays bounded." if s["closed_loop_finite"] else
         _divergence_sentence(s)),
        "",
        f"Overall: **{'stable' if s['stable'] else 'NOT stable'}**.",
        "",
        "## Modal accessibility along the move",
        "",
        "How strongly the joint torques reach each mode at every instant of the shaped move "
        "(accessibility index, eq. 204): a mode whose index falls towards zero cannot be "
        "damped by the joints there, whatever the controller; the fast feedback relies on "
        "it." + _lowest_accessibility(s.get("accessibility_min")),
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
        "## Timings",
        "",
        " · ".join(f"{TIMING_LABELS.get(k, k.removesuffix('_s'))} {v:.2f} s"
                   for k, v in s["timings_s"].items()),
        "",
        "## References",
        "",
        "*Modeling, estimation and control of flexible serial manipulators.* PhD "
        "dissertation (the text casflex implements; the author, institution and year are "
        "not part of the text the project works from). Equations (eq.) and sections (§) "
        "of the report:",
        "",
        *[f"- **{ref}**: {meaning}." for ref, meaning in REFERENCES],
        "",
    ]
    return "\n".join(lines)


def _estimator_lines(est):
    """How the EKF in the loop is fed (``summary["estimator"]``)."""
    if not est:
        return []
    return [f"The EKF (§5.5.1) estimates δ and δ̇ from the accelerometers with the joint "
            "motion from the encoders: q, q̇ and q̈ as the backward difference of q̇, as the "
            f"generated `rt_step` computes it; process noise Q = {est['Q']:.3g}, "
            f"P0 = {est['P0']:.3g} I, R = the sensors' noise². Within a sample of the loop "
            "q̈ jumps with every new torque, which the differenced q̈ misses; the EKF sees "
            "that as process noise, so a large Q passes it to the rate estimates.", ""]


def _condition_lines(conditions):
    """One line per stability condition (its verdict, value and rule); the headline above
    is true only when every one holds."""
    if not conditions:
        return []
    lines = ["| condition | verdict | value | rule |", "|---|---|---|---|"]
    for name, c in conditions.items():
        lines.append(f"| {name.replace('_', ' ')} | {'holds' if c['holds'] else '**fails**'} "
                     f"| {c['value']:.4g} {c['unit']} | {c['rule']} |")
    return [*lines, ""]


def _schedule_cell_lines(cells):
    """The gain schedule checked between its points (informative, not in the verdict)."""
    if not cells:
        return []
    return [f"Over the whole gain schedule, at the centres of its {cells['points']} cells "
            "(between the points the gains were computed at; not part of the verdict):", "",
            *_condition_lines(cells["conditions"])]


def _lowest_accessibility(low):
    """The sentence on the least accessible mode (``summary["accessibility_min"]``)."""
    if not low:
        return ""
    return (f" The lowest index along this move is mode {low['mode']}'s, "
            f"{low['value']:.3g} √kg·m at t = {low['time']:.2f} s.")


def _ratio(value):
    """An RMS ratio, flagged (bold, ⚠) below :data:`WEAK_ESTIMATE_RATIO`."""
    text = _fmt(value)
    return text if value >= WEAK_ESTIMATE_RATIO else f"**{text} ⚠**"


def _mm(value):
    return "–" if value is None else f"{1e3 * value:.4g}"


def _peaks(values):
    return ", ".join(f"{v:.4g}" for v in values)


def _planner_lines(p):
    """The "Planned move" section (``[planner]``), or nothing when the study has none."""
    if p is None:
        return []
    lines = ["## Planned move", ""]
    shaped = p["shaped"]
    if not p["success"]:
        return lines + [
            f"**The planner found no plan** for `{p['move']}` at the shaped move's limits "
            f"(end condition {p['end']!r}): {p['error']}", "",
            f"The shaped move ({shaped['duration']:.4f} s, residual "
            f"{_mm(shaped['residual_tip_deflection'])} mm) stands.", ""]
    bound = p["end_bound"]
    bound_text = (f"residual tip deflection ≤ {_mm(bound)} mm" if isinstance(bound, float)
                  else {"rest": "modes at rest", "free": "no end condition"}.get(bound, bound))
    if p.get("end_bounds"):
        bound_text = ("residual tip deflection ≤ " + " / ".join(_mm(b) for b in p["end_bounds"])
                      + " mm at the nominal, −, + frequency error")
    lines += [
        f"The {p['objective']}-optimal move (`casflex plan`, Ipopt {p['status']} in "
        f"{p['iterations']} iterations, {p['intervals']} intervals) at the torque and "
        f"velocity peaks of the shaped move, with the end condition {bound_text}"
        + (" (the shaped move's residual)" if p["end"] == "shaped" else "") + ". Residuals "
        f"are verified by simulation at {p['verify_dt']:g} s, not taken from the optimiser: "
        "with the joints on the plan (prescribed motion) and under the planned torques (open "
        "loop).",
        "",
        "| | duration [s] | residual, joints on the move [mm] | residual, torque-driven "
        "[mm] | torque peak [N m] | velocity peak [rad/s] |",
        "|---|---|---|---|---|---|",
        f"| shaped | {shaped['duration']:.4f} | {_mm(shaped['residual_tip_deflection'])} | – "
        f"| {_peaks(shaped['torque_peak'])} | {_peaks(shaped['velocity_peak'])} |",
        f"| planned | {p['duration']:.4f} | {_mm(p['residual_tip_deflection'])} | "
        f"{_mm(p['residual_torque_driven'])} | {_peaks(p['torque_peak'])} | "
        f"{_peaks(p['velocity_peak'])} |",
        "",
        f"The planned move is **{100 * p['shortening']:.1f} %** shorter than the shaped "
        f"one; the optimiser's own prediction of its residual is {_mm(p['residual_ocp'])} mm."
        " (The torque peak of the planned move with the joints on it may exceed the limit "
        "by the optimiser's discretisation error: the limit holds at its nodes.)",
        "",
    ]
    again = [r for r in p.get("bound_corrections") or [] if "duration" in r]
    if again:
        lines += ["The first plan's verified residual exceeded the end bound (the "
                  "optimiser's discretisation), so it was solved again with the bound "
                  + ", then ".join(f"{_mm(r['end_bounds'][0])} mm" for r in again)
                  + " (`bound_corrections`); the figures above are of the plan kept.", ""]
    if isinstance(bound, float) and p["residual_tip_deflection"] > bound:
        lines += [f"**The verified residual exceeds the end bound by "
                  f"{100 * (p['residual_tip_deflection'] / bound - 1):.1f} %**: the "
                  "optimiser's discretisation error at this bound.", ""]
    if p["robust"]:
        lines += ["At frequency errors (the model's stiffness scaled):", "",
                  "| error | planned [mm] | shaped [mm] |", "|---|---|---|"]
        lines += [f"| {100 * r['error']:+.0f} % | {_mm(r['residual_tip_deflection'])} | "
                  f"{_mm(r['shaped_residual_tip_deflection'])} |" for r in p["robust"]]
        lines.append("")
    saved = (f"; the whole plan: `{p['plan_file']}` (`casflex.planning.PlannedMove.load`, "
             "`casflex plan --guess`)") if p.get("plan_file") else ""
    lines += [f"Trajectory: `{p['trajectory_csv']}`{saved}; C reference table: "
              f"`c/{p['c_table']['header']}`, `c/{p['c_table']['source']}`.", "",
              "![planned vs shaped](planned.png)", ""]
    return lines


def _closed_loop_lines(s):
    """The closed-loop section: the slow gains, how they were chosen, the time-scale
    separation, and the tracking error with where it comes from."""
    g, tr = s.get("slow_gains"), s.get("tracking")
    lines = ["## Closed loop: joint tracking", ""]
    if g is None or tr is None:  # a summary from before the gains were chosen
        return lines + [f"Largest joint tracking error {s['tracking_error_max']:.3g} rad.", ""]
    how = {"move": f"chosen from the move: bandwidth ω_c = {g['fraction']:.2f} × ω_min, the "
                   "lowest natural frequency along it",
           "dissertation": "taken from the dissertation's case study (§6.2.2.2)",
           "given": "given by the study"}[g["source"]]
    lines += [
        f"Slow (rigid) tracking gains {how}: **Kp = {g['Kp']:.4g} 1/s², Kd = {g['Kd']:.4g} "
        f"1/s** (joint-error loop ë + Kd ė + Kp e = 0 of bandwidth ω_c = "
        f"{g['bandwidth']:.3f} rad/s, damping {g['damping']:.2f}; ω_min = "
        f"{g['omega_min']:.3f} rad/s; the move's own frequency 2π/T = "
        f"{g['move_frequency']:.3f} rad/s).",
        "",
        f"Time-scale separation ω_min / ω_c = **{g['separation']:.2f}** "
        + (f"(≥ {g['separation_required']:.0f}: the flexible modes are well faster than the "
           "slow loop, as the singular-perturbation design assumes)." if
           g["separation_holds"] else
           f"(below {g['separation_required']:.0f}: the separation the singular-perturbation "
           "design assumes is weak; the fast-loop check below and the simulation of the "
           "full model are what show the loop works)."),
        "",
    ]
    if tr.get("worst_joint") is None:  # the loop with the EKF diverged: no tracking error
        whole = tr.get("true_state")
        cause = ("The same sampled loop with the true state fed back diverges too: the law "
                 "itself, at this sample time, is unstable." if whole is None or whole != whole
                 else "The same sampled loop with the true state fed back stays bounded "
                 f"(largest tracking error {whole:.3g} rad): feeding back the EKF's "
                 "estimates makes it diverge.")
        return lines + [_divergence_sentence(s), "", cause, ""]
    lines += [
        f"Largest joint tracking error with the EKF in the loop: **{tr['max']:.3g} rad** "
        f"(q{tr['worst_joint']}, at t = {tr['worst_time']:.2f} s; per joint "
        + ", ".join(f"q{j + 1} {v:.3g}" for j, v in enumerate(tr["per_joint"]))
        + f" rad), {'within' if tr['max'] <= tr['limit'] else '**above**'} the "
        f"{tr['limit']:.2g} rad aimed at.",
        "",
    ]
    lines += [_tracking_comment(s, g, tr), ""]
    lines += [
        "No torque limit acts in these simulations (the guarded C step clips at twice the "
        "peak torques, below). The figure shows the joint angles over their plan, the "
        "tracking error and the torques of every run: the two prescribed-joint runs follow "
        "their plan exactly (their torques are the model's inverse dynamics); the closed "
        "loop is the shaped move under the controller with the EKF's estimates fed back.",
        "",
        "![joint tracking](joint_tracking.png)",
        "",
    ]
    return lines


def _divergence_sentence(s):
    """Where and how the sampled loop with the EKF diverged (``closed_loop_divergence``)."""
    d = s.get("closed_loop_divergence") or {}
    where = ""
    if d.get("time") is not None:
        where = f" at t = {d['time']:.4g} s ({d['quantity']})"
    return (f"**The sampled closed loop with the EKF diverged{where}**: the design is not "
            "realizable at this sample time with these gains (its figures are empty "
            "where the loop has no finite values)."
            + (f" The simulation reported: {d['message']}" if d.get("message") else ""))


def _tracking_comment(s, g, tr):
    """Where the tracking error comes from, from the loops with the true state fed back."""
    whole = tr.get("true_state")
    slow = tr.get("slow_law_true_state")
    if whole is None or whole != whole:
        return "(The loop with the true state fed back was not simulated or diverged.)"
    parts = [f"Where it comes from — the same sampled loop with the true state fed back "
             f"instead of the EKF's estimates: {whole:.3g} rad"]
    if slow is not None and slow == slow:
        parts[0] += f"; with the slow (rigid) law alone {slow:.3g} rad"
    parts[0] += "."
    causes = {"estimation": tr["max"] - whole}
    if slow is not None and slow == slow:
        causes["fast feedback"] = whole - slow
        causes["rigid model"] = slow
    else:
        causes["law"] = whole
    main = max(causes, key=causes.get)
    explain = {
        "fast feedback": "the fast (boundary-layer) feedback: its torques damp the modes "
                         "through the joints and push them off the plan, and the slow loop "
                         f"pulls them back only at its bandwidth ω_c = {g['bandwidth']:.3g} "
                         "rad/s (the error scales roughly as 1/ω_c)",
        "rigid model": "the slow law's rigid model: it ignores the coupling of the joints "
                       "with the deflections, which the slow loop rejects only at its "
                       f"bandwidth ω_c = {g['bandwidth']:.3g} rad/s",
        "estimation": "the EKF's estimation errors fed back through the fast gains",
        "law": "the tracking law itself (the error with the true state fed back)",
    }[main]
    added = causes["estimation"]
    parts.append(f"The largest share ({causes[main]:.3g} rad) comes from {explain}"
                 + (f"; the EKF's estimates add {added:.3g} rad." if added >= 0.05 * tr["max"]
                    else f"; feeding back the EKF's estimates instead of the true state "
                         f"changes it by {abs(added):.2g} rad, less than 5 % of it."))
    return " ".join(parts)


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
