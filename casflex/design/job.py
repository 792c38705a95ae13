"""The end-to-end design job: from a study to a shaper, a checked controller and C code.

:func:`run_design` takes a study (:mod:`casflex.design.study`) and

1. tabulates the modal model over the shape joints (or reuses the on-disk cache), with a
   progress bar (a robot without a shape joint: the modes of one configuration);
2. computes the natural frequencies along the move and the modal contributions to the tip
   deflection, and from them the tolerances and frequency ranges (§6.1.4);
3. designs the minimum-duration specified-insensitivity shaper for those ranges (Ipopt);
4. simulates the move with the joints following the plan exactly, unshaped and shaped;
   with a ``[planner]`` section, plans the optimal move at the shaped move's limits and
   verifies it by simulation (:mod:`casflex.design.planner`);
5. chooses the slow tracking gains (from the lowest natural frequency along the move,
   :mod:`casflex.control.gains`), builds the controller and checks its stability along
   the shaped move;
6. simulates the shaped move under the controller with the EKF in the loop (estimated δ,
   δ̇ from simulated, noisy sensor signals), and with the true state fed back to tell
   where the tracking error comes from;
7. generates and compiles the C bundle of the real-time loop;

and writes ``report.md``, PNG figures, ``summary.json`` and ``c/`` to an output directory
(:mod:`casflex.design.report`, :mod:`casflex.plotting`).
"""

from __future__ import annotations

import contextlib
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
from casflex._parallel import worker_pool
from casflex._validate import fail, output_directory
from casflex.design.ekf_cache import loop_ekf_step
from casflex.design.planner import plan_next_to_shaped, planner_summary
from casflex.design.report import write_report
from casflex.design.study import Study, load_study
from casflex.errors import SolverError

__all__ = ["DesignResult", "run_design", "c_bundle_key"]

#: ω_min / ω_c below which the report says the time-scale separation is weak
SEPARATION_REQUIRED = 3.0
#: the largest joint tracking error [rad] the report calls acceptable (issue 18)
TRACKING_TARGET = 0.05
#: the report's figures, in the order of ``summary["figures"]``
FIGURES = ("frequencies.png", "prv.png", "tip_deflection.png", "estimation.png",
           "accessibility.png", "joint_tracking.png")


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
        ``estimation.png``, ``accessibility.png``, ``joint_tracking.png`` and the C
        bundle under ``c/``; with a ``[planner]`` section also ``planned.png``,
        ``planned_trajectory.csv``, ``planned.npz`` (the whole plan,
        :meth:`casflex.planning.PlannedMove.load` reads it; e.g. ``casflex plan --guess``)
        and the plan's C reference table (:func:`casflex.codegen.plan_table_bundle`) under
        ``c/``.
    progress : bool
        Progress bar of the tabulation on stderr.
    log : callable, optional
        ``log(message)`` for one-line progress messages (the CLI prints them to stderr).
    cache_dir : str or pathlib.Path, optional
        The job's cache (default the casflex cache directory): a second run with the same
        inputs reads the modal table, the SI design
        (:func:`casflex.shaping.cached_si_design`), the EKF plant and step
        (:func:`casflex.design.loop_ekf_step`), the gain schedule and the compiled loops
        instead of computing them again, and keeps ``c/`` when its inputs are unchanged
        (:func:`casflex.design.c_bundle_key`).
    processes : int, optional
        Worker processes of the tabulation; ``1`` also draws the figures and runs the
        loops with the true state fed back in this process (otherwise two worker
        processes do, alongside the job).

    Returns
    -------
    DesignResult
        ``summary`` holds at least ``shaper_duration`` [s], ``frequency_ranges`` [rad/s,
        ``[[lo, hi], ...]`` per mode, margin included], ``contributions`` (normalised, max
        1), ``residual_reduction`` (fraction of the unshaped residual tip deflection that
        shaping removes, 0–1), ``stable``, ``c_files``, ``slow_gains`` (the slow gains,
        their bandwidth ω_c [rad/s], ω_min [rad/s] and the separation ω_min/ω_c) and
        ``tracking`` (largest joint tracking error [rad] of the loop with the EKF, per
        joint, and of the loop with the true state fed back), ``c_shaper_table`` (the
        shaper's C delay/amplitude table files), ``stability`` (one verdict per
        condition, ``mass_matrix`` among them: ``M(q, 0)`` positive definite along the
        move; ``stable`` holds only when all do; with a gain schedule also
        ``schedule_cells``, the fast loop and the mass matrix at the centres of the
        schedule's cells, informative) and ``planner``
        (:func:`casflex.design.planner_summary`: the planned move next to the shaped one;
        ``None`` without a ``[planner]`` section), ``model_terms`` (``model.fit`` and
        ``model.basis``; a fit's degrees, convergence and error estimate per term),
        ``closed_loop_divergence`` (``None``, or ``time`` [s], ``quantity`` and
        ``message`` where the sampled loop with the EKF diverged: reported, not raised,
        its loop figures and numbers then NaN), ``status`` (``"stable"``, ``"not
        stable"`` or ``"closed loop diverged"``) and ``timings_s`` (wall time of each
        stage [s]; ``figures_s``, drawn by worker processes, overlaps ``codegen_s``;
        ``total_s`` the whole call but the report's writing).

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
    >>> failing = [k for k, v in r.summary["stability"]["conditions"].items() if not v["holds"]]
    >>> 0.5 < r.summary["residual_reduction"] < 1.0, r.summary["stable"], failing
    (True, False, ['modal_damping'])
    >>> sorted(p.name for p in r.files if p.suffix == ".png")[:2]
    ['accessibility.png', 'estimation.png']
    """
    # the figures are drawn by worker processes alongside the job's own work (the largest
    # part of a second run otherwise), and the loops with the true state fed back run
    # there; imported before the workers fork, so that they need not import it again.
    # processes=1: all here
    import casflex.simulate  # noqa: F401
    from casflex.modal import interpolant_cache

    # (the B-spline lookups rebuilt from cached tables, the gain schedule's among them,
    # read back instead of fitted again)
    with worker_pool(min(2, processes or os.cpu_count() or 1)) as figure_pool, \
            _workers_ended_on_exit(), interpolant_cache(cache_dir):
        return _run_design(study, out_dir, progress, log, cache_dir, processes, figure_pool)


@contextlib.contextmanager
def _workers_ended_on_exit():
    """End the worker processes the job started when it stops early: on an exception
    (``KeyboardInterrupt`` included) they are terminated instead of finishing their
    figures; on ``SIGTERM`` (default handling, main thread) too, and then the job ends
    by the signal as it would have. Without this a killed job's workers ran on after it
    (a busy one finished its figures; started from a shell's background job, both were
    seen alive, running and sleeping, seconds later)."""
    import multiprocessing
    import signal
    import threading

    before = set(multiprocessing.active_children())  # a caller's own: not the job's

    def end_workers():
        for child in set(multiprocessing.active_children()) - before:
            child.terminate()

    def on_sigterm(signum, frame):
        end_workers()
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)

    watch = (threading.current_thread() is threading.main_thread()
             and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL)
    if watch:
        signal.signal(signal.SIGTERM, on_sigterm)
    try:
        yield
    except BaseException:
        end_workers()
        raise
    finally:
        if watch:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _run_design(study, out_dir, progress, log, cache_dir, processes, figure_pool):
    """:func:`run_design`, its figures drawn by ``figure_pool`` (``None``: here)."""
    t_start = time.perf_counter()
    from casflex import control, shaping
    from casflex.estimation import DEFAULT_GATE, Guard, ekf_step_function, tabulate_plant
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
    model, table = _study_model(study, cache_dir, processes, progress)
    timings["model_s"] = time.perf_counter() - t0

    # 2.-3. frequencies, contributions, shaper ---------------------------------------------
    t0 = time.perf_counter()
    say("frequencies and modal contributions along the move; SI shaper (Ipopt) ...")
    design = shaping.shaper_for_move(model, move, vtol=study.shaper["vtol"],
                                     margin=study.shaper["margin"],
                                     n_samples=study.shaper["n_samples"],
                                     dt=dt,  # impulses on the loop's sample grid
                                     cache_dir=cache_dir)  # a second run reads it
    timings["shaper_s"] = time.perf_counter() - t0
    shaped = ShapedMove(move, design.shaper)
    t_f = np.linspace(0.0, shaped.t_end, 2 * study.shaper["n_samples"] + 1)  # all simulated
    t_f, omega_along = shaping.frequencies_along(model, (t_f, *shaped.sample(t_f)))
    t_acc = np.linspace(0.0, shaped.duration, 201)
    acc = control.accessibility_along(model, shaped, t_acc)
    early_figures = [_shaper_figure_specs(study, design, t_f, omega_along, shaped.duration),
                     [_accessibility_figure_spec(t_acc, acc)]]

    # 4. controller and its stability along the shaped move (before the simulations, which
    # it does not need, so that the loops with the true state fed back start sooner) ----
    t0 = time.perf_counter()
    gains = study.slow_gains(float(np.min(design.omega_min)), shaped.duration)
    say(f"slow gains ({gains.source}): Kp = {gains.Kp:.4g} 1/s^2, Kd = {gains.Kd:.4g} 1/s, "
        f"bandwidth {gains.bandwidth:.3g} rad/s = omega_min / {gains.separation:.3g}")
    eps, controller, slow, stability = _controller(study, model, table, move, shaped, gains,
                                                   say, cache_dir)
    timings["controller_s"] = time.perf_counter() - t0
    t_end = shaped.t_end

    def start_workers():
        """The loops with the true state fed back, then the figures known before the loops,
        to the two workers (here without them): the loops first, so that their results
        are there when the loop with the EKF is done (waiting behind the figures, they
        made the job wait 0.3-0.5 s); the figures (each worker imports matplotlib first)
        while this process simulates. Returns the loops' ``finish``, this process's time
        on starting them [s] and the figures' futures."""
        t0 = time.perf_counter()
        say("where the tracking error comes from: the loops with the true state fed back ...")
        sources = _start_tracking_sources(figure_pool, model, controller, slow, shaped,
                                          t_end, dt, jit=study.codegen["compile"],
                                          cache_dir=cache_dir)
        return sources, time.perf_counter() - t0, _start_figures(figure_pool, out,
                                                                 early_figures)

    started = None
    if study.planner is None:  # no table left that a forked process pool may compute
        started = start_workers()

    # 4. simulations --------------------------------------------------------------------------
    t0 = time.perf_counter()
    say("simulating the move unshaped and shaped (joints on the plan) ...")
    # the exact fast path (casflex.simulate, method="poly"): equal to RK4 on the model;
    # its Chebyshev pieces do not converge on linearly interpolated tables: RK4 there
    # and its rows take a diagonal stiffness: a smooth basis' full K̃ needs RK4 as well;
    # the exact kinematics' rows are not a polynomial in δ (issue 19): RK4 on them
    sim_method = "poly" if (study.model["interpolation"] == "bspline"
                            and study.model["basis"] == "eigen"
                            and study.model["kinematics"] != "exact") else "rk4"
    unshaped_run = simulate_prescribed(model, move, dt=dt, t_end=t_end, method=sim_method)
    shaped_run = simulate_prescribed(model, shaped, dt=dt, t_end=t_end, method=sim_method)
    timings["simulate_s"] = time.perf_counter() - t0

    # the planned move next to the shaped one (optional [planner]) --------------------------
    comparison = None
    if study.planner is not None:
        t0 = time.perf_counter()
        p_model, p_run = model, shaped_run
        if study.planner["modes"] not in (None, model.m):
            p_model, _ = _study_model(study, cache_dir, processes, progress,
                                      n_modes=study.planner["modes"])
            p_run = simulate_prescribed(p_model, shaped, dt=dt, t_end=t_end, method=sim_method)
        comparison = plan_next_to_shaped(p_model, move, shaped, p_run, study.planner, dt=dt,
                                         log=say, progress=progress, cache_dir=cache_dir)
        timings["planner_s"] = time.perf_counter() - t0

    if started is None:  # the workers start after the planner's tables (forked while this
        # process has no other thread)
        started = start_workers()
    sources_started, sources_s, figures_started = started

    # closed loop with the EKF in the loop ----------------------------------------------------
    t0 = time.perf_counter()
    say("EKF plant tables; closed loop with the EKF in the loop ...")
    e = study.estimator
    plant_grid = None  # the model table's grid
    if table is not None and e["plant_region"] == "move":
        plant_grid = _plant_grid(_grid_axes(study, table), move)
    elif table is not None and study.model["fit"] != "grid":
        plant_grid = _grid_axes(study, table)[0]
    # built once, then read from the job's cache (with the plant it is built from)
    ekf = loop_ekf_step(model, table, study, dt, plant_grid, cache_dir)
    m = model.m
    # as in the generated rt_step: q̈ for the EKF from the backward difference of q̇
    estimator = {"step": ekf, "sensors": study.sensors, "P0": np.eye(2 * m) * e["P0"],
                 "x0": np.zeros(2 * m), "R": np.diag(e["R"]), "seed": e["seed"],
                 "ddq": "difference"}
    divergence = None
    try:
        loop = simulate_closed_loop(model, controller, shaped, t_end=t_end, dt=dt,
                                    estimator=estimator, sampled=True,  # compiled for C
                                    jit=study.codegen["compile"], cache_dir=cache_dir)
    except SolverError as exc:  # reported, not raised: a diverging loop is a verdict
        divergence = _divergence(exc)
        say(f"WARNING: the closed loop with the EKF diverged: {exc}")
        loop = _diverged_loop(model, t_end, dt)
    sources = {key: _tracking_error(finish) for key, finish in sources_started.items()}
    # this process's time on the three loops: the loop with the EKF, and starting and
    # finishing the loops with the true state fed back (their steps, before the
    # simulations, and any wait for their results; not the workers' own time)
    timings["closed_loop_s"] = time.perf_counter() - t0 + sources_s
    loop_finite = bool(np.all(np.isfinite(loop.x)) and np.all(np.isfinite(loop.x_hat)))
    if not loop_finite and divergence is None:  # the state bounded, the estimate not
        bad = int(np.argmax(~np.isfinite(loop.x).all(axis=1) | ~np.isfinite(
            loop.x_hat).all(axis=1)))
        divergence = {"time": float(loop.t[bad]), "quantity": "x_hat (the EKF's estimate)",
                      "message": "the EKF's estimate became non-finite"}
        say(f"WARNING: the closed loop with the EKF diverged at t = {loop.t[bad]:.3f} s")

    # the figures of the runs, drawn by the workers while the C bundle is generated --------
    t_figures = time.perf_counter()
    estimation = _estimation_errors(model, loop)
    run_figures = _run_figure_specs(study, unshaped_run, shaped_run, loop, estimation,
                                    shaped.duration)
    # joint_tracking.png (nine panels) costs about what the other two do together
    figures_started += _start_figures(figure_pool, out, [run_figures[:-1], run_figures[-1:]])

    # 6. C bundle -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    say("generating the C bundle ...")
    limits = _torque_limits(study, shaped_run, loop) if study.codegen["guard"] else None
    gate = None
    if study.codegen["guard"]:
        gate = DEFAULT_GATE if e["gate"] is None else e["gate"]

    def c_ekf():  # the guarded step: built only when the bundle is generated
        if not study.codegen["guard"]:
            return ekf
        plant = tabulate_plant(model, grid=plant_grid, cache_dir=cache_dir)
        return ekf_step_function(plant, study.sensors, e["Q"], e["R"], dt,
                                 guard=Guard(np.eye(2 * m) * e["P0"], gate=gate))

    c_bundle = _c_bundle(study, c_ekf, c_bundle_key(study, ekf, controller, dt, limits, gate),
                         controller, out / "c", dt, limits)
    # the loop's shaper as a delay/amplitude table (its impulses are on the dt grid)
    from casflex.codegen import shaper_table_bundle
    shaper_c = shaper_table_bundle(design.shaper, dt, f"{study.codegen['name']}_shaper",
                                   out / "c")
    extra = [path.name for path in shaper_c.values()]
    if comparison is not None and comparison.plan is not None:
        # the planned move as the loop's reference table, and its trajectory as CSV
        from casflex.codegen import plan_table_bundle
        plan_c = plan_table_bundle(comparison.plan, dt, f"{study.codegen['name']}_plan",
                                   out / "c")
        extra += [plan_c["header"].name, plan_c["source"].name]
        comparison.plan.to_csv(out / "planned_trajectory.csv")
        comparison.plan.save(out / "planned.npz")
    c_bundle = (sorted({*c_bundle[0], *extra}), *c_bundle[1:])
    timings["codegen_s"] = time.perf_counter() - t0

    # 7. figures and report ---------------------------------------------------------------------
    figures = sorted(_finish_figures(figures_started), key=lambda p: FIGURES.index(p.name))
    if comparison is not None and comparison.plan is not None:
        figures.append(_save_plan_figure(out, comparison))
    timings["figures_s"] = time.perf_counter() - t_figures  # overlaps codegen_s
    timings["total_s"] = time.perf_counter() - t_start  # all but writing the report
    summary = _summary(study, model, table, design, unshaped_run, shaped_run, loop,
                       shaped.duration, loop_finite, stability, eps, c_bundle, timings,
                       figures)
    summary["slow_gains"] = _gains_summary(gains, study)
    summary["tracking"] = _tracking_summary(loop, sources)
    # how the loop with the EKF ended: its state and estimate bounded, or where it diverged
    summary["closed_loop_divergence"] = divergence
    summary["status"] = ("closed loop diverged" if divergence is not None else
                         "stable" if summary["stable"] else "not stable")
    low = np.unravel_index(np.argmin(acc), np.shape(acc))
    summary["accessibility_min"] = {"value": float(np.min(acc)), "mode": int(low[1]) + 1,
                                    "time": float(t_acc[low[0]])}
    summary["estimator"] = {"Q": float(e["Q"]), "P0": float(e["P0"]), "ddq": "difference"}
    summary["model_terms"] = {"fit": study.model["fit"], "basis": study.model["basis"]}
    if study.model["fit"] != "grid":  # the fit's degrees and its own error estimate
        summary["model_terms"].update(degrees=list(table.degrees),
                                      converged=table.info.get("converged"),
                                      estimate=table.info.get("estimate"))
    summary["c_guard"] = {"guarded": bool(study.codegen["guard"]),
                          "torque_limits": None if limits is None else limits.tolist(),
                          "gate": gate}
    summary["c_shaper_table"] = {kind: path.name for kind, path in shaper_c.items()}
    summary["planner"] = None
    if comparison is not None:
        summary["planner"] = planner_summary(comparison, study.planner["end"])
        summary["planner"]["verify_dt"] = study.planner["verify_dt"]
        if comparison.plan is not None:
            summary["planner"]["figure"] = "planned.png"
            summary["planner"]["trajectory_csv"] = "planned_trajectory.csv"
            summary["planner"]["plan_file"] = "planned.npz"
            summary["planner"]["c_table"] = {
                "header": f"{study.codegen['name']}_plan.h",
                "source": f"{study.codegen['name']}_plan.c"}
            # files written, not drawn
            figures += [out / "planned_trajectory.csv", out / "planned.npz"]
    c_files = c_bundle[0]
    files = [*write_report(out, study, summary), *figures] + [out / "c" / f for f in c_files]
    return DesignResult(summary=jsonable(summary), out_dir=out, files=files)


def _study_model(study, cache_dir, processes, progress, n_modes=None):
    """The study's model (``n_modes`` modes, default the study's) and its modal table
    (``None`` for a robot without a shape joint: its modes are those of one configuration,
    :class:`casflex.model.PointwiseProvider`)."""
    from casflex.modal.tables import shape_joints
    from casflex.model import FlexibleModel, PointwiseProvider, build_model

    gravity = "robot" if study.model["gravity"] else None
    if not shape_joints(study.robot):
        provider = PointwiseProvider(study.robot, np.zeros(study.robot.n_joints),
                                     count=n_modes or study.model["modes"],
                                     points=study.sensors.points)
        model = FlexibleModel(study.robot, provider,
                              gravity=gravity,
                              delta_order=study.model["delta_order"],
                              shape_rates=study.model["shape_rates"],
                              foreshortening=study.model["foreshortening"],
                              kinematics=study.model["kinematics"])
        return model, None
    return build_model(study.robot, n_modes or study.model["modes"],
                       step=study.model["grid_step"],
                       points=study.sensors.points, gravity=gravity,
                       delta_order=study.model["delta_order"], cache_dir=cache_dir,
                       shape_rates=study.model["shape_rates"],
                       foreshortening=study.model["foreshortening"],
                       kinematics=study.model["kinematics"],
                       method=study.model["interpolation"], processes=processes,
                       progress=progress, basis=study.model["basis"],
                       fit=None if study.model["fit"] == "grid" else study.model["fit"])


def _grid_axes(study, table):
    """``(axes, periodic)`` of the shape joints: the modal table's, or for a model fitted
    without a grid (``model.fit``) :func:`casflex.model.default_grid` at the study's
    ``model.grid_step`` (the grid of the EKF plant and of ε)."""
    from casflex.modal import ModalTable, periodic_axis_kind
    from casflex.model import default_grid

    if isinstance(table, ModalTable):
        return tuple(table.grid), tuple(table.shape_joints), tuple(table.periodic)
    axes = tuple(default_grid(study.robot, table.shape_joints, study.model["grid_step"]))
    return axes, tuple(table.shape_joints), tuple(
        periodic_axis_kind(a) is not None for a in axes)


# ------------------------------------------------------------------------------ controller


def _controller(study, model, table, move, shaped, gains, say, cache_dir):
    """ε, the controller of the study and its stability check along the shaped move."""
    from casflex import control

    c = dict(study.controller, Kp=gains.Kp, Kd=gains.Kd)
    if table is None:  # no shape joint: the modes of every configuration are those of q = 0
        eps = control.perturbation_parameter(model, q=np.zeros((1, model.n)))
    elif study.model["fit"] == "grid":
        eps = control.perturbation_parameter(model, table=table)
    else:  # a fitted model: ω_min over the points of the grid_step grid
        axes, joints, _ = _grid_axes(study, table)
        q = np.zeros((int(np.prod([a.size for a in axes])), model.n))
        q[:, list(joints)] = np.array(np.meshgrid(*axes, indexing="ij")).reshape(
            len(axes), -1).T
        eps = control.perturbation_parameter(model, q=q)
    if c["law"] == "composite":
        if c["gains"] == "scheduled":
            if table is None:
                raise fail("controller.gains", "scheduled", f"needs a robot with a shape "
                           f"joint ('{study.robot.name}' has none: use gains = 'end')",
                           path=study.path)
            axis = -np.pi + 2.0 * np.pi * np.arange(c["schedule_points"]) / c["schedule_points"]
            box = None
            if c["schedule_region"] == "move":  # the box the move spans (monotone moves)
                box = (np.minimum(move.q0, move.qf), np.maximum(move.q0, move.qf))
            gain = control.cached_gain_schedule(
                model, c["Q"], c["R"], eps, table, axis,
                # a fit has no table key for the schedule's cache key: not cached
                cache_dir if study.model["fit"] == "grid" else False, limits=True, box=box,
                method=c["schedule_interpolation"])
            say(f"fast LQR gains over q{[j + 1 for j in gain.joints]}: "
                f"{' x '.join(str(a.size) for a in gain.grid)} points "
                f"({c['schedule_region']}) ...")
        else:
            gain, _, _ = control.fast_gain(model, move.qf, Q=c["Q"], R=c["R"], epsilon=eps)
        controller = control.composite_controller(model, Kp=c["Kp"], Kd=c["Kd"], gain=gain,
                                                  epsilon=eps)
        slow = control.composite_controller(model, Kp=c["Kp"], Kd=c["Kd"], fast=False)
        say("stability of the fast loop along the shaped move ...")
        stab = control.composite_stability(model, shaped, gain=gain, epsilon=eps)
        mass = control.mass_matrix_condition(model, shaped)
        conditions = {"slow_loop": control.slow_loop_condition(c["Kp"], c["Kd"]),
                      "mass_matrix": {k: mass[k] for k in ("holds", "value", "unit", "rule")},
                      **stab["conditions"]}
        stability = {"check": "fast loop Hurwitz (§6.2.3.1)",
                     "stable": all(v["holds"] for v in conditions.values()),
                     "conditions": conditions,
                     "worst_margin": stab["worst_margin"], "worst_time": stab["worst_time"],
                     "unit": "1/s"}
        if isinstance(gain, control.GainSchedule):
            # over the whole schedule, between its points (not part of the verdict: a
            # full-turn schedule also covers configurations where a mode is inaccessible)
            say("fast loop and mass matrix at the centres of the schedule's cells ...")
            cells = control.schedule_stability(model, gain, q=move.q0)
            stability["schedule_cells"] = {"points": cells["points"],
                                           "conditions": cells["conditions"],
                                           "worst_q": cells["worst_q"]}
    else:
        controller = control.inversion_controller(model, Kp=c["Kp"], Kd=c["Kd"])
        slow = None
        say("zero-dynamics condition (eq. 226) along the shaped move ...")
        stab = control.inversion_stability(model, shaped, Kp=c["Kp"])
        mass = control.mass_matrix_condition(model, shaped)
        conditions = {"mass_matrix": {k: mass[k] for k in ("holds", "value", "unit", "rule")},
                      **stab["conditions"]}
        stability = {"check": "eq. 226 zero dynamics and eq. 225 modal damping",
                     "stable": all(v["holds"] for v in conditions.values()),
                     "conditions": conditions,
                     "worst_margin": stab["worst_margin"], "worst_time": stab["worst_time"],
                     "unit": "1/s^3"}
    return eps, controller, slow, stability


def _plant_grid(grid_axes, move, pad=1):
    """The model's grid axes (:func:`_grid_axes`) cut to the box the move spans, ``pad``
    grid points wider on each side (the EKF plant's points are then the table's own; at
    least four per axis, as B-splines need); a full-turn axis is kept whole."""
    low, high = np.minimum(move.q0, move.qf), np.maximum(move.q0, move.qf)
    axes = []
    for axis, joint, periodic in zip(*grid_axes, strict=True):
        a = np.asarray(axis, dtype=float)
        if periodic:
            axes.append(a)
            continue
        i0 = max(int(np.searchsorted(a, low[joint], side="right")) - 1 - pad, 0)
        i1 = min(int(np.searchsorted(a, high[joint], side="left")) + pad, a.size - 1)
        while i1 - i0 < 3 and (i0 > 0 or i1 < a.size - 1):
            i0, i1 = max(i0 - 1, 0), min(i1 + 1, a.size - 1)
        axes.append(a[i0:i1 + 1])
    return axes


def _divergence(exc):
    """``{"time", "quantity", "message"}`` of a diverged closed loop, from the
    ``divergence`` attribute :func:`casflex.simulate.results.check_divergence` gives its
    error (``time``/``quantity`` None for another solver failure; the message is kept)."""
    found = getattr(exc, "divergence", None) or {"time": None, "quantity": None}
    return {**found, "message": str(exc)}


def _diverged_loop(model, t_end, dt):
    """A closed-loop result of not-a-numbers on the loop's time grid: what a diverged
    loop leaves for the figures and the summary (every loop figure NaN, never a number)."""
    from casflex.simulate.results import ClosedLoopResult

    n, m = model.n, model.m
    t = np.arange(int(round(t_end / dt)) + 1) * dt

    def nans(columns):
        return np.full((t.size, columns), np.nan)

    return ClosedLoopResult(t=t, x=nans(2 * (n + m)), tau=nans(n), qd=nans(n), tip=nans(3),
                            tip_rigid=nans(3), n=n, m=m, x_hat=nans(2 * m))


def _start_tracking_sources(pool, model, controller, slow, shaped, t_end, dt, jit=False,
                            cache_dir=None):
    """Start the sampled loops with the true state fed back, under the whole law and under
    its slow (rigid) part alone, in ``pool``'s workers (here without a pool): ``{key:
    finish}`` (:func:`casflex.simulate.start_closed_loop`). Their largest joint tracking
    errors (:func:`_tracking_error`), against the loop with the EKF, say where its tracking
    error comes from (the report's comment). ``jit``: the loops' steps compiled (cached),
    as the loop with the EKF."""
    from casflex.simulate import start_closed_loop

    laws = {"true_state": controller}
    if slow is not None:
        laws["slow_law_true_state"] = slow
    executor = None if pool is None else pool.executor
    return {key: start_closed_loop(executor, model, law, shaped, t_end=t_end, dt=dt,
                                   sampled=True, method="rk4", jit=jit, cache_dir=cache_dir)
            for key, law in laws.items()}


def _tracking_error(finish):
    """Largest joint tracking error [rad] of a started loop (NaN if it diverged: the
    report says so)."""
    try:
        return float(np.abs(finish().tracking_error).max())
    except SolverError:
        return math.nan


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
        "table_from_cache": bool(table is not None and table.info.get("from_cache", False)),
        "timings_s": timings,
        "figures": [p.name for p in figures],
    }


# ------------------------------------------------------------------ the closed loop explained


def _gains_summary(gains, study):
    """``summary["slow_gains"]``: the gains, their bandwidth and its separation from ω_min."""
    c = study.controller
    return {"source": gains.source, "Kp": gains.Kp, "Kd": gains.Kd,
            "bandwidth": gains.bandwidth, "damping": gains.damping,
            "fraction": gains.bandwidth / gains.omega_min,
            "requested_fraction": c["bandwidth_fraction"] if gains.source == "move" else None,
            "omega_min": gains.omega_min, "separation": gains.separation,
            "separation_holds": bool(gains.separation >= SEPARATION_REQUIRED),
            "separation_required": SEPARATION_REQUIRED,
            "move_frequency": gains.move_frequency}


def _tracking_summary(loop, sources):
    """``summary["tracking"]``: the loop's largest error per joint [rad] and its sources."""
    per_joint = np.abs(loop.tracking_error).max(axis=0)
    if not np.all(np.isfinite(per_joint)):  # a diverged loop: no worst joint or time
        return {"max": math.nan, "per_joint": per_joint.tolist(), "worst_joint": None,
                "worst_time": None, "limit": TRACKING_TARGET, **sources}
    return {"max": float(per_joint.max()), "per_joint": per_joint.tolist(),
            "worst_joint": int(np.argmax(per_joint)) + 1,
            "worst_time": float(loop.t[np.abs(loop.tracking_error).max(axis=1).argmax()]),
            "limit": TRACKING_TARGET, **sources}


def _save_plan_figure(out, comparison):
    """``planned.png``: shaped vs planned joint motion, torques and tip deflection."""
    from casflex import plotting

    path = out / "planned.png"
    plotting.plot_plan(comparison).savefig(path, dpi=110)
    return path


def _shaper_figure_specs(study, design, t_f, omega, move_end):
    """The report's figures of the shaper (``frequencies.png``, ``prv.png``) as ``(file
    name, casflex.plotting function name, args, keywords, tight)``: plain data, so that a
    worker process can draw them (:func:`_draw_figures`); ``tight``: the figure has no
    layout engine of its own and gets ``tight_layout``."""
    modes = [f"mode {j + 1}" for j in range(len(design.ranges))]
    ranges = [(r.omega_min, r.omega_max) for r in design.ranges]
    events = {"end of the planned move": study.move.duration,
              "end of the shaped move": move_end}
    return [
        ("frequencies.png", "plot_frequencies_along",
         (t_f, omega, f"{study.move.name}, shaped"), {"events": events, "ranges": ranges},
         True),
        ("prv.png", "plot_prv", (design.shaper, design.ranges), {"names": modes}, True),
    ]


def _accessibility_figure_spec(t_acc, acc):
    """``accessibility.png`` (the accessibility along the shaped move), as
    :func:`_shaper_figure_specs`."""
    return ("accessibility.png", "plot_accessibility_along", (t_acc, acc), {}, True)


def _run_figure_specs(study, unshaped, shaped_run, loop, estimation, move_end):
    """The report's figures of the runs (``tip_deflection.png``, ``estimation.png``,
    ``joint_tracking.png``), as :func:`_shaper_figure_specs`."""
    law = study.controller["law"]
    deflections = [("unshaped", unshaped.t, unshaped.tip_deflection),
                   ("shaped", shaped_run.t, shaped_run.tip_deflection),
                   (f"shaped + {law} + EKF", loop.t, loop.tip_deflection)]
    # joint_tracking.png: the prescribed runs follow their plan exactly; their torques are
    # the model's inverse dynamics
    tracking = [("unshaped, joints prescribed", unshaped.t, unshaped.q, unshaped.q,
                 unshaped.tau),
                ("shaped, joints prescribed", shaped_run.t, shaped_run.q, shaped_run.q,
                 shaped_run.tau),
                (f"shaped, {law} law + EKF", loop.t, loop.q, loop.qd, loop.tau)]
    return [
        ("tip_deflection.png", "plot_tip_deflection", (deflections, move_end), {}, True),
        ("estimation.png", "plot_estimation_error", (loop.t, *estimation), {},
         False),  # its own fixed layout
        ("joint_tracking.png", "plot_joint_tracking",  # its own fixed layout
         (tracking, [study.move.duration, move_end, move_end]), {}, False),
    ]


def _draw_figures(out, specs):
    """Draw figures of :func:`_shaper_figure_specs` or :func:`_run_figure_specs` and save
    them as PNG in ``out``; returns their paths."""
    from casflex import plotting

    paths = []
    for name, function, args, kwargs, tight in specs:
        fig = getattr(plotting, function)(*args, **kwargs)
        if tight:
            fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        paths.append(out / name)
    return paths


def _start_figures(pool, out, groups):
    """Submit each group of figure specs to ``pool`` (a
    :func:`casflex._parallel.worker_pool`) as one task and return their futures, or draw
    them here and return their paths when there is no pool.

    Drawing (importing matplotlib, its layout and rasterisation) is the largest part of a
    second run; in workers it overlaps the job's own work. The figures known before the
    loops go to both workers as soon as they are known (each imports matplotlib then, while
    the job simulates and builds the controller); after the closed loop, two groups of
    about equal cost share the two workers while the C bundle is generated."""
    if pool is None:
        return [_draw_figures(out, group) for group in groups]
    return [pool.executor.submit(_draw_figures, out, group) for group in groups]


def _finish_figures(started):
    """The paths of :func:`_start_figures`' figures, in their order (a failed drawing
    raises here)."""
    return [path for item in started
            for path in (item if isinstance(item, list) else item.result())]


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


def c_bundle_key(study: Study, ekf, controller, dt: float, torque_limits=None,
                 gate: float | None = None) -> str:
    """SHA-256 of everything the design job's C bundle (``c/``) is generated from.

    A second run whose key equals the one recorded next to the bundle keeps the bundle and
    its build instead of generating it again: the key covers the EKF step of the loop
    (its serialised graph: the plant, the model's sensor tables, the sensors, ``Q``, ``R``
    and ``dt``), the guard's settings (the guarded step is built from the same inputs),
    the controller's serialised graph, the sensors, ``dt``, the torque limits, the
    ``[codegen]`` settings, the CasADi version and the source of the code that builds the
    guarded step and generates the bundle.

    Parameters
    ----------
    study : Study
    ekf : casadi.Function
        The (unguarded) EKF step of the loop (:func:`casflex.estimation.ekf_step_function`).
    controller : casadi.Function
        The controller ``(qd, dqd, ddqd, x) -> tau``.
    dt : float
        Sample time [s].
    torque_limits : array_like, optional
        Torque limits of the guarded ``rt_step`` [N m] (``None``: unguarded).
    gate : float, optional
        The guard's innovation gate (``None``: unguarded).

    Returns
    -------
    str
        64 hexadecimal digits.

    Examples
    --------
    >>> import casadi as ca
    >>> study = load_study("problems/studies/arm2link_move1.toml")
    >>> x = ca.SX.sym("x")
    >>> f, g = ca.Function("f", [x], [2 * x]), ca.Function("f", [x], [3 * x])
    >>> a = c_bundle_key(study, f, f, 1e-3, [1.0, 2.0, 3.0], 5.0)
    >>> a == c_bundle_key(study, f, f, 1e-3, [1.0, 2.0, 3.0], 5.0)
    True
    >>> a == c_bundle_key(study, f, g, 1e-3, [1.0, 2.0, 3.0], 5.0)   # another controller
    False
    >>> a == c_bundle_key(study, f, f, 1e-3, [1.0, 2.0, 3.5], 5.0)   # another limit
    False
    """
    import casadi as ca

    from casflex import codegen
    from casflex._cache import digest, source_digest
    from casflex.codegen import bundle, compiler, estimator, rtloop, templates
    from casflex.estimation import ekf as ekf_module
    from casflex.estimation import guard

    def graph(function):
        return hashlib.sha256(function.serialize().encode()).hexdigest()

    sensors = study.sensors
    return digest({
        "ekf": graph(ekf), "controller": graph(controller), "dt": float(dt),
        "guard": None if gate is None else {"P0": float(study.estimator["P0"]),
                                             "gate": float(gate)},
        "torque_limits": None if torque_limits is None else
        np.asarray(torque_limits, dtype=float).tolist(),
        "sensors": [repr(s) for s in sensors.sensors], "points": repr(list(sensors.points)),
        "codegen": {k: jsonable(v) for k, v in study.codegen.items()},
        "casadi": ca.__version__,
        "source": source_digest(ekf_module, guard, codegen, bundle, compiler, estimator,
                                rtloop, templates, _c_bundle),
    })


def _c_bundle(study, c_ekf, key, controller, c_dir, dt, torque_limits=None):
    """Generate (and compile, unless switched off) the real-time C bundle, or keep the one
    in ``c_dir`` if it was generated from the same inputs (``key``, :func:`c_bundle_key`,
    recorded in ``c/.digest``) and its library is there: ``rt_step``
    (:mod:`casflex.codegen.rtloop`: encoders, reference and sensor sample to torques and
    the updated estimator), plus ``ekf_step`` and the controller alone. ``c_ekf()`` builds
    the EKF step of the bundle; a guarded one (``codegen.guard``) makes ``rt_step`` skip
    bad samples, hold non-finite inputs, keep P positive definite, return a status word
    and clip the torques to ``torque_limits``."""
    import json

    from casflex import codegen
    from casflex.codegen import rt_bundle

    name = study.codegen["name"]
    record_path = c_dir / ".digest"
    try:
        record = json.loads(record_path.read_text())
    except (OSError, ValueError):  # none, or an older job's plain digest
        record = None
    if isinstance(record, dict) and record.get("key") == key and \
            (c_dir / str(record.get("library"))).is_file():
        compiled = "reused"  # same inputs as the last run: keep its sources and build
        functions = list(record["functions"])
    else:
        if c_dir.exists():
            shutil.rmtree(c_dir)
        ekf = c_ekf()
        bundle = rt_bundle(ekf, controller, study.sensors, dt, c_dir, name=name,
                           extra=(ekf, controller), torque_limits=torque_limits)
        functions = [f.name for f in bundle.functions]
        compiled = False
        if study.codegen["compile"]:
            codegen.build(bundle)
            compiled = True
        record_path.write_text(json.dumps({"key": key, "functions": functions,
                                           "library": bundle.library.name}))
    files = sorted(p.name for p in c_dir.iterdir() if not p.name.startswith("."))
    return files, functions, compiled
