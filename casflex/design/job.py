"""The end-to-end design job: from a study file to a shaper, a checked controller and C code.

A *study* names a robot, a planned move and a sensor set, plus the settings of each step
(``problems/studies/arm2link_move1.toml`` is the bundled example; ``problems/README.md``
documents every key). :func:`run_design` then

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

and writes ``report.md``, PNG figures, ``summary.json`` and ``c/`` to an output directory.
Everything is validated before any heavy work starts (:func:`load_study`).

Examples
--------
>>> study = load_study("problems/studies/arm2link_move1.toml")
>>> study.move.name, study.model["modes"], study.controller["law"]
('move1', 3, 'composite')
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from casflex._json import jsonable
from casflex.errors import ProblemFileError

__all__ = ["Study", "load_study", "run_design", "DesignResult"]

# every section of a study file, its keys and their defaults (None: required or "unset")
_SECTIONS = {
    "model": {"modes": 3, "grid_step": 3.0, "delta_order": 0, "gravity": False},
    "shaper": {"vtol": 0.05, "margin": 0.20, "n_samples": 200},
    "simulation": {"dt": 1e-3, "settle": None},
    "controller": {"law": "composite", "Kp": 1.0, "Kd": 2.0, "Q": 1.0, "R": 10.0,
                   "gains": "scheduled", "schedule_points": 30},
    "estimator": {"Q": 5e-6, "R": None, "P0": 1e-4, "seed": 0},
    "codegen": {"name": "casflex", "compile": True},
}
_TOP = ("name", "description", "robot", "move", "sensors")


@dataclass
class Study:
    """A validated design study (see :func:`load_study`).

    Attributes
    ----------
    path : pathlib.Path
        The study file.
    name, description : str
    robot_path, sensors_path : pathlib.Path
    robot : casflex.robot.Robot
    move : casflex.moves.Move
    sensors : casflex.sensors.SensorSet
    model, shaper, simulation, controller, estimator, codegen : dict
        The settings of every step, defaults filled in (units as in ``problems/README.md``;
        ``model["grid_step"]`` is converted to rad).

    Examples
    --------
    >>> s = load_study("problems/studies/arm2link_move1.toml")
    >>> s.robot_path.name, round(s.model["grid_step"], 6), s.estimator["Q"]
    ('arm2link_actuated.toml', 0.05236, 5e-06)
    """

    path: Path
    name: str
    description: str
    robot_path: Path
    sensors_path: Path
    robot: object
    move: object
    sensors: object
    model: dict = field(default_factory=dict)
    shaper: dict = field(default_factory=dict)
    simulation: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)
    codegen: dict = field(default_factory=dict)


def _number(path, key, value, *, low=None, high=None, low_open=False, high_open=False,
            integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProblemFileError(path, key, value, "must be a number")
    if integer and (not float(value).is_integer()):
        raise ProblemFileError(path, key, value, "must be an integer")
    v = float(value)
    if not math.isfinite(v):
        raise ProblemFileError(path, key, value, "must be finite")
    if low is not None and (v <= low if low_open else v < low):
        raise ProblemFileError(path, key, value, f"must be {'>' if low_open else '>='} {low}")
    if high is not None and (v >= high if high_open else v > high):
        raise ProblemFileError(path, key, value,
                               f"must be {'<' if high_open else '<='} {high}")
    return int(v) if integer else v


def _choice(path, key, value, choices):
    if value not in choices:
        raise ProblemFileError(path, key, value, f"must be one of {', '.join(map(str, choices))}")
    return value


def _file(path, key, value):
    if not isinstance(value, str) or not value:
        raise ProblemFileError(path, key, value, "must be a file path (string)")
    p = Path(value)
    if not p.is_absolute():
        p = path.parent / p
    return p


def load_study(path):
    """Read and validate a study file; load the robot, move and sensors it names.

    Every rule is checked here, before any heavy work: a missing file, an unknown key, a
    sensor on a link the robot does not have, a tolerance outside ``(0, 1]`` — each
    raises :class:`casflex.errors.ProblemFileError` naming the file, the field, the value
    and the rule. Relative paths are relative to the study file.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    Study

    Examples
    --------
    >>> s = load_study("problems/studies/arm2link_move1.toml")
    >>> s.robot.name, s.sensors.output_names[:2], s.shaper["vtol"]
    ('arm2link_actuated', ('tip1_x', 'tip1_y'), 0.05)
    """
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.sensors import load_sensors

    path = Path(path)
    if not path.is_file():
        raise ProblemFileError(path, "-", str(path), "the study file must exist")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(path, "-", None, f"must be valid TOML ({exc})") from None
    for key, value in raw.items():
        if key not in _TOP and key not in _SECTIONS:
            raise ProblemFileError(path, key, value, "unknown key; allowed: "
                                   + ", ".join(_TOP + tuple(_SECTIONS)))
    for key in ("robot", "move", "sensors"):
        if key not in raw:
            raise ProblemFileError(path, key, None, "is required")
    settings = {}
    for section, defaults in _SECTIONS.items():
        given = raw.get(section, {})
        if not isinstance(given, dict):
            raise ProblemFileError(path, section, given, "must be a table [section]")
        for key, value in given.items():
            if key not in defaults:
                raise ProblemFileError(path, f"{section}.{key}", value, "unknown key; allowed: "
                                       + ", ".join(defaults))
        settings[section] = {**defaults, **given}

    robot_path = _file(path, "robot", raw["robot"])
    if not robot_path.is_file():
        raise ProblemFileError(path, "robot", raw["robot"], f"file {robot_path} must exist")
    move_ref = raw["move"]
    if not isinstance(move_ref, str) or ":" not in move_ref:
        raise ProblemFileError(path, "move", move_ref, "must be 'FILE:NAME' (e.g. "
                               "'../moves.toml:move1')")
    move_file, _, move_name = move_ref.rpartition(":")
    move_path = _file(path, "move", move_file)
    if not move_path.is_file():
        raise ProblemFileError(path, "move", move_ref, f"file {move_path} must exist")
    sensors_path = _file(path, "sensors", raw["sensors"])
    if not sensors_path.is_file():
        raise ProblemFileError(path, "sensors", raw["sensors"],
                               f"file {sensors_path} must exist")
    robot = load(robot_path)
    move = load_move(f"{move_path}:{move_name}")
    if move.n_joints != robot.n_joints:
        raise ProblemFileError(path, "move", move_ref, f"has {move.n_joints} joints; robot "
                               f"'{robot.name}' has {robot.n_joints}")
    sensors = load_sensors(sensors_path, robot)

    m = settings["model"]
    m["modes"] = _number(path, "model.modes", m["modes"], low=1, high=12, integer=True)
    m["grid_step"] = math.radians(_number(path, "model.grid_step", m["grid_step"], low=0.0,
                                          high=45.0, low_open=True))
    m["delta_order"] = _choice(path, "model.delta_order", m["delta_order"], (0, 1))
    if not isinstance(m["gravity"], bool):
        raise ProblemFileError(path, "model.gravity", m["gravity"], "must be true or false")
    s = settings["shaper"]
    s["vtol"] = _number(path, "shaper.vtol", s["vtol"], low=0.0, high=1.0, low_open=True)
    s["margin"] = _number(path, "shaper.margin", s["margin"], low=0.0, high=1.0,
                          high_open=True)
    s["n_samples"] = _number(path, "shaper.n_samples", s["n_samples"], low=10, high=5000,
                             integer=True)
    sim = settings["simulation"]
    sim["dt"] = _number(path, "simulation.dt", sim["dt"], low=1e-5, high=1e-2)
    if sim["settle"] is not None:
        sim["settle"] = _number(path, "simulation.settle", sim["settle"], low=0.0, high=60.0)
    c = settings["controller"]
    c["law"] = _choice(path, "controller.law", c["law"], ("composite", "inversion"))
    for key in ("Kp", "Kd", "Q", "R"):
        c[key] = _number(path, f"controller.{key}", c[key], low=0.0, low_open=True)
    c["gains"] = _choice(path, "controller.gains", c["gains"], ("scheduled", "end"))
    c["schedule_points"] = _number(path, "controller.schedule_points", c["schedule_points"],
                                   low=8, high=360, integer=True)
    e = settings["estimator"]
    e["Q"] = _number(path, "estimator.Q", e["Q"], low=0.0, low_open=True)
    e["P0"] = _number(path, "estimator.P0", e["P0"], low=0.0, low_open=True)
    e["seed"] = _number(path, "estimator.seed", e["seed"], low=0, integer=True)
    if e["R"] is None:
        std = np.asarray(sensors.noise_std, dtype=float)
        if not np.all(np.isfinite(std) & (std > 0)):
            raise ProblemFileError(path, "estimator.R", None, "is required when the sensor "
                                   f"file {sensors_path} gives no 'noise' for every sensor")
        e["R"] = std**2
    else:
        e["R"] = np.full(sensors.n_outputs, _number(path, "estimator.R", e["R"], low=0.0,
                                                    low_open=True))
    g = settings["codegen"]
    if not (isinstance(g["name"], str) and g["name"].isidentifier()):
        raise ProblemFileError(path, "codegen.name", g["name"], "must be a C identifier")
    if not isinstance(g["compile"], bool):
        raise ProblemFileError(path, "codegen.compile", g["compile"], "must be true or false")
    name = raw.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise ProblemFileError(path, "name", name, "must be a non-empty string")
    return Study(path=path, name=name, description=str(raw.get("description", "")),
                 robot_path=robot_path, sensors_path=sensors_path, robot=robot, move=move,
                 sensors=sensors, **settings)


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
    files: list


def _rms(a, axis=0):
    return np.sqrt(np.mean(np.asarray(a, dtype=float) ** 2, axis=axis))


def run_design(study, out_dir, *, progress=False, log=None, cache_dir=None, processes=None):
    """Run the whole design job of a study and write its report.

    Parameters
    ----------
    study : Study or str or pathlib.Path
        A study, or the path of a study file (:func:`load_study`).
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
    controller, C generated but not compiled) so that it runs in seconds:

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
    from casflex.estimation import ekf_step_function, tabulate_plant
    from casflex.model import build_model
    from casflex.moves import Move, ShapedMove
    from casflex.simulate import simulate_prescribed

    if not isinstance(study, Study):
        study = load_study(study)
    say = log or (lambda message: None)
    out = Path(out_dir)
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
                               processes=processes, progress=progress)
    timings["model_s"] = time.perf_counter() - t0
    table_cached = bool(table.info.get("from_cache", False))

    # 2.-3. frequencies, contributions, shaper ---------------------------------------------
    t0 = time.perf_counter()
    say("frequencies and modal contributions along the move; SI shaper (Ipopt) ...")
    design = shaping.shaper_for_move(model, move, vtol=study.shaper["vtol"],
                                     margin=study.shaper["margin"],
                                     n_samples=study.shaper["n_samples"])
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
    residual_unshaped = unshaped_run.residual_tip_deflection
    residual_shaped = shaped_run.residual_tip_deflection
    reduction = 1.0 - residual_shaped / residual_unshaped if residual_unshaped > 0 else 0.0

    t0 = time.perf_counter()
    c = study.controller
    eps = control.perturbation_parameter(model, table=table)
    if c["law"] == "composite":
        if c["gains"] == "scheduled":
            say("fast LQR gains over the configuration grid ...")
            axis = -np.pi + 2.0 * np.pi * np.arange(c["schedule_points"]) / c["schedule_points"]
            gain = _schedule(control, model, c, eps, table, axis, cache_dir)
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
        gain = None
        controller = control.inversion_controller(model, Kp=c["Kp"], Kd=c["Kd"])
        say("zero-dynamics condition (eq. 226) along the shaped move ...")
        stab = control.inversion_stability(model, shaped, Kp=c["Kp"])
        stability = {"check": "eq. 226 zero dynamics", "stable": bool(stab["stable"]),
                     "worst_margin": stab["worst_margin"], "worst_time": stab["worst_time"],
                     "unit": "1/s^3"}
    timings["controller_s"] = time.perf_counter() - t0

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
    loop = control.simulate_closed_loop(model, controller, shaped, t_end=t_end, dt=dt,
                                        estimator=estimator, sampled=True)
    timings["closed_loop_s"] = time.perf_counter() - t0
    n = model.n
    delta_true = loop.x[:, n:n + m]
    ddelta_true = loop.x[:, 2 * n + m:]
    err_delta = loop.x_hat[:, :m] - delta_true
    err_ddelta = loop.x_hat[:, m:] - ddelta_true
    loop_defl = np.linalg.norm(loop.tip_deflection, axis=1)
    loop_finite = bool(np.all(np.isfinite(loop.x)) and np.all(np.isfinite(loop.x_hat)))
    if not loop_finite:
        bad = int(np.argmax(~np.isfinite(loop.x).all(axis=1) | ~np.isfinite(
            loop.x_hat).all(axis=1)))
        say(f"WARNING: the closed loop with the EKF diverged at t = {loop.t[bad]:.3f} s")
    loop_residual = float(loop_defl[loop.t >= shaped.duration - 1e-12].max()) \
        if loop_finite else math.nan

    # 6. C bundle -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    say("generating the C bundle ...")
    c_files, c_functions, compiled = _c_bundle(study, model, plant, ekf, controller,
                                               out / "c", dt)
    timings["codegen_s"] = time.perf_counter() - t0

    # 7. figures and report ---------------------------------------------------------------------
    t_acc = np.linspace(0.0, shaped.duration, 201)
    acc = control.accessibility_along(model, shaped, t_acc)
    figures = _figures(out, study, design, t_f, omega_along, unshaped_run, shaped_run, loop,
                       err_delta, t_acc, acc, shaped)
    ranges = [[float(r.omega_min), float(r.omega_max)] for r in design.ranges]
    summary = {
        "study": study.name,
        "robot": study.robot.name,
        "move": study.move.name,
        "modes": m,
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
        "controller": c["law"],
        "epsilon": float(eps),
        "c_files": c_files,
        "c_functions": c_functions,
        "c_compiled": compiled,
        "table_from_cache": table_cached,
        "timings_s": timings,
        "figures": [p.name for p in figures],
    }
    summary_path = out / "summary.json"
    summary_path.write_text(json.dumps(jsonable(summary), indent=2) + "\n")
    report = out / "report.md"
    report.write_text(_report(study, summary, design))
    files = [report, summary_path, *figures] + [out / "c" / f for f in c_files]
    return DesignResult(summary=jsonable(summary), out_dir=out, files=files)


def _schedule(control, model, c, eps, table, axis, cache_dir=None):
    """Fast gains scheduled on the full-turn grid ``axis`` of every joint the boundary
    layer depends on (the model table's own grid would be needlessly fine: one LQR per
    point), cached on disk next to the modal tables under a key made of everything the
    gains depend on (the robot, the table, the weights, ε, the grid and the source of the
    functions that compute them)."""
    from casflex import __version__
    from casflex._cache import (
        default_cache_dir,
        digest,
        load_verified,
        save_verified,
        source_digest,
    )

    bl = control.boundary_layer(model, eps)
    joints = control._dependent_joints(lambda qq: [x.full() for x in bl(qq)], model.n,
                                       np.random.default_rng(0))
    if cache_dir is False:
        return control.gain_schedule(model, Q=c["Q"], R=c["R"], epsilon=eps, table=table,
                                     joints=joints, grid=[axis] * len(joints))
    ident = {
        "version": __version__, "robot": repr(model.robot), "table": table.info.get("key"),
        "modes": model.m, "delta_order": model.delta_order, "modal_mass": model.modal_mass,
        "Q": c["Q"], "R": c["R"], "epsilon": float(eps), "axis": np.asarray(axis).tolist(),
        "joints": list(joints),
        "source": source_digest(control.gain_schedule, control.boundary_layer,
                                 control._lqr, control.GainSchedule),
    }
    key = digest(ident)
    path = Path(default_cache_dir() if cache_dir is None else cache_dir) / f"gains-{key[:32]}.npz"
    hit = load_verified(path, key)
    if hit is not None:
        return control.GainSchedule.from_gains(
            joints, [axis] * len(joints), hit["gains"], eps, model.n,
            filled=int(hit["filled"]), info={"from_cache": True})
    sched = control.gain_schedule(model, Q=c["Q"], R=c["R"], epsilon=eps, table=table,
                                  joints=joints, grid=[axis] * len(joints))
    save_verified(path, key, gains=sched.gains, filled=np.array(sched.filled))
    return sched


# ------------------------------------------------------------------------------ C bundle


def _c_bundle(study, model, plant, ekf, controller, c_dir, dt):
    """Generate (and compile, unless unchanged or switched off) the real-time C bundle:
    ``rt_step`` (:mod:`casflex.rtloop`: encoders, reference and sensor sample to torques and
    the updated estimator), plus ``ekf_step`` and the controller alone."""
    from casflex import codegen
    from casflex.rtloop import rt_bundle

    name = study.codegen["name"]
    staging = c_dir.parent / (c_dir.name + ".new")
    if staging.exists():
        shutil.rmtree(staging)

    def generate(directory):
        return rt_bundle(ekf, controller, study.sensors, dt, directory, name=name,
                         extra=(ekf, controller))

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


# ------------------------------------------------------------------------------ figures


def _figures(out, study, design, t_f, omega, unshaped, shaped_run, loop, err_delta, t_acc,
             acc, shaped):
    from matplotlib.figure import Figure

    from casflex.shaping import sensitivity_curve

    paths = []

    def save(fig, name):
        fig.tight_layout()
        p = out / name
        fig.savefig(p, dpi=110)
        paths.append(p)

    m = omega.shape[1]
    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    for j in range(m):
        ax.plot(t_f, omega[:, j], label=f"mode {j + 1}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("ω [rad/s]")
    ax.set_title(f"natural frequencies along {study.move.name}")
    ax.legend()
    save(fig, "frequencies.png")

    lo = min(r.omega_min for r in design.ranges)
    hi = max(r.omega_max for r in design.ranges)
    w, v = sensitivity_curve(design.shaper, 0.5 * lo, 1.3 * hi, n=800)
    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    ax.plot(w, v, "k", lw=1.2)
    for j, r in enumerate(design.ranges):
        ax.axvspan(r.omega_min, r.omega_max, alpha=0.15, color=f"C{j}")
        ax.hlines(r.vtol, r.omega_min, r.omega_max, colors=f"C{j}",
                  label=f"mode {j + 1}: Vtol {r.vtol:.3g}")
    ax.set_xlabel("ω [rad/s]")
    ax.set_ylabel("residual vibration V")
    ax.set_title(f"SI shaper, {len(design.shaper.times)} impulses, "
                 f"{design.duration:.3f} s")
    ax.legend(fontsize=8)
    save(fig, "prv.png")

    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    for run, label in ((unshaped, "unshaped"), (shaped_run, "shaped"),
                       (loop, f"shaped + {study.controller['law']} + EKF")):
        ax.plot(run.t, 1e3 * np.linalg.norm(run.tip_deflection, axis=1), label=label)
    ax.axvline(shaped.duration, color="0.6", ls=":", lw=1)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("‖tip deflection‖ [mm]")
    ax.legend()
    save(fig, "tip_deflection.png")

    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    for j in range(err_delta.shape[1]):
        ax.plot(loop.t, err_delta[:, j], lw=0.8, label=f"δ̂{j + 1} − δ{j + 1}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("estimation error [√kg·m]")
    ax.set_title("EKF in the loop")
    ax.legend(fontsize=8)
    save(fig, "estimation.png")

    fig = Figure(figsize=(6.4, 3.6))
    ax = fig.add_subplot()
    for j in range(acc.shape[1]):
        ax.plot(t_acc, acc[:, j], label=f"a{j + 1}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("accessibility [√kg·m]")
    ax.set_title("modal accessibility along the shaped move (eq. 204)")
    ax.legend()
    save(fig, "accessibility.png")
    return paths


def _report(study, s, design):
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
        "## Timings [s]",
        "",
        " | ".join(f"{k} {v:.2f}" for k, v in s["timings_s"].items()),
        "",
    ]
    return "\n".join(lines)

