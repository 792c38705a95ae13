"""The end-to-end design job: from a study to a shaper, a checked controller and C code.

:func:`run_design` takes a study (:mod:`casflex.design.study`) and

1. tabulates the modal model over the shape joints (or reuses the on-disk cache), with a
   progress bar;
2. computes the natural frequencies along the move and the modal contributions to the tip
   deflection, and from them the tolerances and frequency ranges (§6.1.4);
3. designs the minimum-duration specified-insensitivity shaper for those ranges (Ipopt);
4. simulates the move with the joints following the plan exactly, unshaped and shaped,
   and the shaped move under the closed-loop controller with the EKF in the loop
   (estimated δ, δ̇ from simulated, noisy sensor signals);
5. checks the stability of the controller along the shaped move;
6. generates and compiles the C bundle of the real-time loop;

and writes ``report.md``, PNG figures, ``summary.json`` and ``c/`` to an output directory
(:mod:`casflex.design.report`, :mod:`casflex.plotting`).
"""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from casflex._json import jsonable
from casflex._validate import output_directory
from casflex.design.report import write_report
from casflex.design.study import Study, load_study

__all__ = ["DesignResult", "run_design"]


@dataclass
class DesignResult:
    """What :func:`run_design` produced.

    Attributes
    ----------
    summary : dict
        The content of ``summary.json`` (SI units; see :func:`run_design`).
    out_dir : pathlib.Path
    files : list of pathlib.Path
        Every file written (report, figures, summary, C bundle).

    Examples
    --------
    >>> r = DesignResult(summary={"stable": True}, out_dir=Path("out"), files=[])
    >>> r.summary["stable"], r.out_dir.name
    (True, 'out')
    """

    summary: dict
    out_dir: Path
    files: list[Path]


def run_design(study: Study | str | os.PathLike, out_dir: str | os.PathLike, *,
               progress: bool = False, log: Callable[[str], None] | None = None,
               cache_dir: str | os.PathLike | None = None,
               processes: int | None = None) -> DesignResult:
    """Run the whole design job of a study and write its report.

    Parameters
    ----------
    study : Study or str or pathlib.Path
        A study, or the path of a study file (:func:`~casflex.design.load_study`, which
        checks every rule before any heavy work starts).
    out_dir : str or pathlib.Path
        Output directory (created). It receives ``report.md``, ``summary.json``, the PNG
        figures ``frequencies.png``, ``prv.png``, ``tip_deflection.png``,
        ``estimation.png``, ``accessibility.png`` and the C bundle under ``c/``.
    progress : bool
        Progress bar of the tabulation on stderr.
    log : callable, optional
        ``log(message)`` for one-line progress messages (the CLI prints them to stderr).
    cache_dir : str or pathlib.Path, optional
        Modal-table cache (default the casflex cache directory): a second run with the
        same robot and grid reads the table instead of recomputing it.
    processes : int, optional
        Worker processes of the tabulation.

    Returns
    -------
    DesignResult
        ``summary`` holds at least ``shaper_duration`` [s], ``frequency_ranges`` [rad/s,
        ``[[lo, hi], ...]`` per mode, margin included], ``contributions`` (normalised, max
        1), ``residual_reduction`` (fraction of the unshaped residual tip deflection that
        shaping removes, 0–1), ``stable`` and ``c_files``.

    Examples
    --------
    The bundled study made small (one mode, a 30° grid, a 5 ms step, the inversion-based
    controller, C generated but not compiled):

    >>> import tempfile
    >>> tmp = Path(tempfile.mkdtemp())
    >>> text = Path("problems/studies/arm2link_move1.toml").read_text()
    >>> for old, new in [('"../', f'"{Path.cwd()}/problems/'), ("modes = 3 ", "modes = 1 "),
    ...                  ("grid_step = 3.0", "grid_step = 30.0"), ("dt = 0.001", "dt = 0.005"),
    ...                  ("settle = 3.0", "settle = 0.5"), ('"composite"', '"inversion"'),
    ...                  ("compile = true", "compile = false")]:
    ...     text = text.replace(old, new)
    >>> _ = (tmp / "small.toml").write_text(text)
    >>> r = run_design(tmp / "small.toml", tmp / "out", cache_dir=tmp / "cache", processes=1)
    >>> 0.5 < r.summary["residual_reduction"] < 1.0, r.summary["stable"]
    (True, True)
    >>> sorted(p.name for p in r.files if p.suffix == ".png")[:2]
    ['accessibility.png', 'estimation.png']
    """
    from casflex import control, shaping
    from casflex.estimation import DEFAULT_GATE, Guard, ekf_step_function, tabulate_plant
    from casflex.model import build_model
    from casflex.moves import Move, ShapedMove
    from casflex.simulate import simulate_closed_loop, simulate_prescribed

    if not isinstance(study, Study):
        study = load_study(study)
    out = output_directory(out_dir, "out_dir")  # before any heavy work
    say = log or (lambda message: None)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    move = study.move
    if study.simulation["settle"] is not None:
        move = Move(move.q0, move.qf, move.duration, study.simulation["settle"], move.name,
                    move.description)
    dt = study.simulation["dt"]

    # 1. model ------------------------------------------------------------------------------
    t0 = time.perf_counter()
    say(f"modal model of '{study.robot.name}': {study.model['modes']} modes, grid "
        f"{math.degrees(study.model['grid_step']):.3g} deg ...")
    model, table = build_model(study.robot, study.model["modes"],
                               step=study.model["grid_step"], points=study.sensors.points,
                               gravity="robot" if study.model["gravity"] else None,
                               delta_order=study.model["delta_order"], cache_dir=cache_dir,
                               shape_rates=study.model["shape_rates"],
                               processes=processes, progress=progress)
    timings["model_s"] = time.perf_counter() - t0

    # 2.-3. frequencies, contributions, shaper ---------------------------------------------
    t0 = time.perf_counter()
    say("frequencies and modal contributions along the move; SI shaper (Ipopt) ...")
    design = shaping.shaper_for_move(model, move, vtol=study.shaper["vtol"],
                                     margin=study.shaper["margin"],
                                     n_samples=study.shaper["n_samples"],
                                     dt=dt)  # impulses on the loop's sample grid
    t_f, omega_along = shaping.frequencies_along(model, move,
                                                 n_samples=study.shaper["n_samples"])
    timings["shaper_s"] = time.perf_counter() - t0
    shaped = ShapedMove(move, design.shaper)

    # 4. simulations --------------------------------------------------------------------------
    t0 = time.perf_counter()
    say("simulating the move unshaped and shaped (joints on the plan) ...")
    t_end = shaped.t_end
    # the exact fast path (casflex.simulate, method="poly"): equal to RK4 on the model
    unshaped_run = simulate_prescribed(model, move, dt=dt, t_end=t_end, method="poly")
    shaped_run = simulate_prescribed(model, shaped, dt=dt, t_end=t_end, method="poly")
    timings["simulate_s"] = time.perf_counter() - t0

    # 5. controller and its stability along the shaped move ---------------------------------
    t0 = time.perf_counter()
    eps, controller, stability = _controller(study, model, table, move, shaped, say,
                                             cache_dir)
    timings["controller_s"] = time.perf_counter() - t0

    # closed loop with the EKF in the loop ----------------------------------------------------
    t0 = time.perf_counter()
    say("EKF plant tables; closed loop with the EKF in the loop ...")
    e = study.estimator
    plant = tabulate_plant(model)
    ekf = ekf_step_function(plant, study.sensors, e["Q"], e["R"], dt)
    m = model.m
    # as in the generated rt_step: q̈ for the EKF from the backward difference of q̇
    estimator = {"step": ekf, "sensors": study.sensors, "P0": np.eye(2 * m) * e["P0"],
                 "x0": np.zeros(2 * m), "R": np.diag(e["R"]), "seed": e["seed"],
                 "ddq": "difference"}
    loop = simulate_closed_loop(model, controller, shaped, t_end=t_end, dt=dt,
                                estimator=estimator, sampled=True,  # compiled when C is wanted
                                jit=study.codegen["compile"], cache_dir=cache_dir)
    timings["closed_loop_s"] = time.perf_counter() - t0
    loop_finite = bool(np.all(np.isfinite(loop.x)) and np.all(np.isfinite(loop.x_hat)))
    if not loop_finite:
        bad = int(np.argmax(~np.isfinite(loop.x).all(axis=1) | ~np.isfinite(
            loop.x_hat).all(axis=1)))
        say(f"WARNING: the closed loop with the EKF diverged at t = {loop.t[bad]:.3f} s")

    # 6. C bundle -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    say("generating the C bundle ...")
    limits = _torque_limits(study, shaped_run, loop) if study.codegen["guard"] else None
    c_ekf = ekf
    gate = None
    if study.codegen["guard"]:
        gate = DEFAULT_GATE if e["gate"] is None else e["gate"]
        c_ekf = ekf_step_function(plant, study.sensors, e["Q"], e["R"], dt,
                                  guard=Guard(np.eye(2 * m) * e["P0"], gate=gate))
    c_bundle = _c_bundle(study, model, plant, c_ekf, controller, out / "c", dt, limits)
    timings["codegen_s"] = time.perf_counter() - t0

    # 7. figures and report ---------------------------------------------------------------------
    t_acc = np.linspace(0.0, shaped.duration, 201)
    acc = control.accessibility_along(model, shaped, t_acc)
    err_delta = _estimation_errors(model, loop)[2]
    figures = _save_figures(out, study, design, t_f, omega_along, unshaped_run, shaped_run,
                            loop, err_delta, t_acc, acc, shaped.duration)
    summary = _summary(study, model, table, design, unshaped_run, shaped_run, loop,
                       shaped.duration, loop_finite, stability, eps, c_bundle, timings,
                       figures)
    summary["c_guard"] = {"guarded": bool(study.codegen["guard"]),
                          "torque_limits": None if limits is None else limits.tolist(),
                          "gate": gate}
    c_files = c_bundle[0]
    files = [*write_report(out, study, summary), *figures] + [out / "c" / f for f in c_files]
    return DesignResult(summary=jsonable(summary), out_dir=out, files=files)


def _controller(study, model, table, move, shaped, say, cache_dir):
    """ε, the controller of the study and its stability check along the shaped move."""
    from casflex import control

    c = study.controller
    eps = control.perturbation_parameter(model, table=table)
    if c["law"] == "composite":
        if c["gains"] == "scheduled":
            say("fast LQR gains over the configuration grid ...")
            axis = -np.pi + 2.0 * np.pi * np.arange(c["schedule_points"]) / c["schedule_points"]
            gain = control.cached_gain_schedule(model, c["Q"], c["R"], eps, table, axis, cache_dir)
        else:
            gain, _, _ = control.fast_gain(model, move.qf, Q=c["Q"], R=c["R"], epsilon=eps)
        controller = control.composite_controller(model, Kp=c["Kp"], Kd=c["Kd"], gain=gain,
                                                  epsilon=eps)
        say("stability of the fast loop along the shaped move ...")
        stab = control.composite_stability(model, shaped, gain=gain, epsilon=eps)
        stability = {"check": "fast loop Hurwitz (§6.2.3.1)", "stable": stab["stable"],
                     "worst_margin": stab["worst_margin"], "worst_time": stab["worst_time"],
                     "unit": "1/s"}
    else:
        controller = control.inversion_controller(model, Kp=c["Kp"], Kd=c["Kd"])
        say("zero-dynamics condition (eq. 226) along the shaped move ...")
        stab = control.inversion_stability(model, shaped, Kp=c["Kp"])
        stability = {"check": "eq. 226 zero dynamics", "stable": bool(stab["stable"]),
                     "worst_margin": stab["worst_margin"], "worst_time": stab["worst_time"],
                     "unit": "1/s^3"}
    return eps, controller, stability


def _estimation_errors(model, loop):
    """True δ and δ̇ of the closed loop and the EKF's errors on them, each (k, m)."""
    n, m = model.n, model.m
    delta_true = loop.x[:, n:n + m]
    ddelta_true = loop.x[:, 2 * n + m:]
    return delta_true, ddelta_true, loop.x_hat[:, :m] - delta_true, \
        loop.x_hat[:, m:] - ddelta_true


def _rms(a, axis=0):
    return np.sqrt(np.mean(np.asarray(a, dtype=float) ** 2, axis=axis))


def _summary(study, model, table, design, unshaped_run, shaped_run, loop, move_end,
             loop_finite, stability, eps, c_bundle, timings, figures):
    """The content of ``summary.json`` (see :func:`run_design`)."""
    residual_unshaped = unshaped_run.residual_tip_deflection
    residual_shaped = shaped_run.residual_tip_deflection
    reduction = 1.0 - residual_shaped / residual_unshaped if residual_unshaped > 0 else 0.0
    delta_true, ddelta_true, err_delta, err_ddelta = _estimation_errors(model, loop)
    loop_defl = np.linalg.norm(loop.tip_deflection, axis=1)
    loop_residual = float(loop_defl[loop.t >= move_end - 1e-12].max()) \
        if loop_finite else math.nan
    c_files, c_functions, compiled = c_bundle
    ranges = [[float(r.omega_min), float(r.omega_max)] for r in design.ranges]
    return {
        "study": study.name,
        "robot": study.robot.name,
        "move": study.move.name,
        "modes": model.m,
        "shaper_duration": float(design.duration),
        "shaper": {"times": design.shaper.times.tolist(),
                   "amplitudes": design.shaper.amplitudes.tolist(),
                   "max_prv": [float(v) for v in design.max_prv]},
        "frequency_ranges": ranges,
        "frequency_span": [[float(a), float(b)] for a, b in
                           zip(design.omega_min, design.omega_max, strict=True)],
        "contributions": design.contributions.tolist(),
        "tolerances": design.tolerances.tolist(),
        "residual_unshaped": residual_unshaped,
        "residual_shaped": residual_shaped,
        "residual_reduction": float(reduction),
        "residual_closed_loop": loop_residual,
        "max_tip_deflection": {"unshaped": unshaped_run.max_tip_deflection,
                               "shaped": shaped_run.max_tip_deflection,
                               "closed_loop": float(loop_defl.max())},
        "closed_loop_finite": loop_finite,
        "tracking_error_max": float(np.abs(loop.tracking_error).max()),
        "estimation_rms_ratio": {
            "delta": (_rms(delta_true) / np.maximum(_rms(err_delta), 1e-300)).tolist(),
            "ddelta": (_rms(ddelta_true) / np.maximum(_rms(err_ddelta), 1e-300)).tolist()},
        "stable": bool(stability["stable"]) and loop_finite,
        "stability": stability,
        "controller": study.controller["law"],
        "epsilon": float(eps),
        "c_files": c_files,
        "c_functions": c_functions,
        "c_compiled": compiled,
        "table_from_cache": bool(table.info.get("from_cache", False)),
        "timings_s": timings,
        "figures": [p.name for p in figures],
    }


def _save_figures(out, study, design, t_f, omega, unshaped, shaped_run, loop, err_delta,
                  t_acc, acc, move_end):
    """Draw the report's figures (:mod:`casflex.plotting`) and save them as PNG in ``out``."""
    from casflex import plotting
    from casflex.shaping import sensitivity_curve

    lo = min(r.omega_min for r in design.ranges)
    hi = max(r.omega_max for r in design.ranges)
    w, v = sensitivity_curve(design.shaper, 0.5 * lo, 1.3 * hi, n=800)
    runs = [("unshaped", unshaped.t, unshaped.tip_deflection),
            ("shaped", shaped_run.t, shaped_run.tip_deflection),
            (f"shaped + {study.controller['law']} + EKF", loop.t, loop.tip_deflection)]
    figures = {
        "frequencies.png": plotting.plot_frequencies_along(t_f, omega, study.move.name),
        "prv.png": plotting.plot_shaper_sensitivity(
            w, v, [(r.omega_min, r.omega_max, r.vtol) for r in design.ranges],
            len(design.shaper.times), design.duration),
        "tip_deflection.png": plotting.plot_tip_deflection(runs, move_end),
        "estimation.png": plotting.plot_estimation_error(loop.t, err_delta),
        "accessibility.png": plotting.plot_accessibility_along(t_acc, acc),
    }
    paths = []
    for name, fig in figures.items():
        fig.tight_layout()
        p = out / name
        fig.savefig(p, dpi=110)
        paths.append(p)
    return paths


# ------------------------------------------------------------------------------ C bundle


def _torque_limits(study, shaped_run, loop):
    """Per-joint torque limits of the guarded ``rt_step`` [N m]: the study's, or twice the
    peak |τ| of the shaped move (prescribed joints and closed loop, whichever is larger),
    so that the designed motion is never clipped; a joint that never needs torque gets the
    largest joint's limit."""
    given = study.codegen["torque_limits"]
    if given is not None:
        return np.asarray(given, dtype=float)
    peaks = [shaped_run.torque_peak]
    if np.all(np.isfinite(loop.tau)):
        peaks.append(np.max(np.abs(loop.tau), axis=0))
    limits = 2.0 * np.max(peaks, axis=0)
    return np.where(limits > 0, limits, np.max(limits))


def _c_bundle(study, model, plant, ekf, controller, c_dir, dt, torque_limits=None):
    """Generate (and compile, unless unchanged or switched off) the real-time C bundle:
    ``rt_step`` (:mod:`casflex.codegen.rtloop`: encoders, reference and sensor sample to torques and
    the updated estimator), plus ``ekf_step`` and the controller alone. A guarded ``ekf``
    (``codegen.guard``) makes ``rt_step`` skip bad samples, hold non-finite inputs, keep P
    positive definite, return a status word and clip the torques to ``torque_limits``."""
    from casflex import codegen
    from casflex.codegen import rt_bundle

    name = study.codegen["name"]
    staging = c_dir.parent / (c_dir.name + ".new")
    if staging.exists():
        shutil.rmtree(staging)

    def generate(directory):
        return rt_bundle(ekf, controller, study.sensors, dt, directory, name=name,
                         extra=(ekf, controller), torque_limits=torque_limits)

    bundle = generate(staging)
    digest = _digest(staging)
    functions = [f.name for f in bundle.functions]
    library_name = bundle.library.name
    if c_dir.is_dir() and (c_dir / ".digest").is_file() and \
            (c_dir / ".digest").read_text() == digest and (c_dir / library_name).is_file():
        shutil.rmtree(staging)  # same sources as the last run: keep its build
        compiled = "reused"
    else:
        if c_dir.exists():
            shutil.rmtree(c_dir)
        shutil.rmtree(staging)
        bundle = generate(c_dir)  # generated in place: the README names its own directory
        compiled = False
        if study.codegen["compile"]:
            codegen.build(bundle)
            compiled = True
        (c_dir / ".digest").write_text(digest)
    files = sorted(p.name for p in c_dir.iterdir() if not p.name.startswith("."))
    return files, functions, compiled


def _digest(directory):
    h = hashlib.sha256()
    for p in sorted(Path(directory).iterdir()):
        if p.is_file():
            h.update(p.name.encode())
            h.update(p.read_bytes())
    return h.hexdigest()
