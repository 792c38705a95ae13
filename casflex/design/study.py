"""Study files: what a design job is asked to do, validated before any heavy work.

A *study* names a robot, a planned move and a sensor set, plus the settings of each step
of the job (``problems/studies/arm2link_move1.toml`` is the bundled example;
``problems/README.md`` documents every key). :func:`load_study` reads one, checks every
rule and loads the files it names.

Examples
--------
>>> study = load_study("problems/studies/arm2link_move1.toml")
>>> study.move.name, study.model["modes"], study.controller["law"]
('move1', 3, 'composite')
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from casflex._problemfile import read_toml
from casflex._validate import choice, fail, identifier, number, plausible
from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.control import SlowGains
    from casflex.moves import Move
    from casflex.robot import Robot
    from casflex.sensors import SensorSet

__all__ = ["Study", "load_study"]

# every section of a study file, its keys and their defaults (None: required or "unset")
_SECTIONS = {
    "model": {"modes": 3, "grid_step": 3.0, "delta_order": 0, "gravity": False,
              "shape_rates": False, "foreshortening": False, "kinematics": "truncated",
              "interpolation": "bspline", "fit": "grid", "basis": "eigen"},
    "shaper": {"vtol": 0.05, "margin": 0.20, "n_samples": 200},
    "simulation": {"dt": 1e-3, "settle": None},
    "controller": {"law": "composite", "slow_gains": "move", "bandwidth_fraction": 0.3,
                   "damping": 1.0, "Kp": None, "Kd": None, "Q": 1.0, "R": 10.0,
                   "gains": "scheduled", "schedule_points": 30, "schedule_region": "limits",
                   "schedule_interpolation": "bspline"},
    "estimator": {"Q": 5e-6, "R": None, "P0": 1e-4, "seed": 0, "gate": None,
                  "plant_region": "limits"},
    "codegen": {"name": "casflex", "compile": True, "guard": True, "torque_limits": None},
    "planner": {"enabled": True, "objective": "time", "duration": None, "weight": 0.0,
                "robust": 0.0, "robust_steps": None, "robust_path": None, "end": "shaped",
                "intervals": None,
                "transcription": "collocation", "derivatives": None, "modes": None,
                "max_iter": 500, "verify_dt": 1e-4, "bound_corrections": None},
}
# sections that are off when the study file does not have them
_OPTIONAL = ("planner",)
# the top-level keys of a study file besides the sections
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
    planner : dict or None
        The optimal move planned next to the shaped one (``[planner]``, see
        :func:`casflex.planning.plan_move`), or ``None`` when the study has no such
        section or sets ``enabled = false``.

    Examples
    --------
    >>> s = load_study("problems/studies/arm2link_move1.toml")
    >>> s.robot_path.name, round(s.model["grid_step"], 6), s.estimator["Q"]
    ('arm2link_actuated.toml', 0.05236, 5e-09)
    >>> s.controller["slow_gains"], s.controller["bandwidth_fraction"]
    ('move', 0.7)
    """

    path: Path
    name: str
    description: str
    robot_path: Path
    sensors_path: Path
    robot: Robot
    move: Move
    sensors: SensorSet
    model: dict = field(default_factory=dict)
    shaper: dict = field(default_factory=dict)
    simulation: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)
    estimator: dict = field(default_factory=dict)
    codegen: dict = field(default_factory=dict)
    planner: dict | None = None

    def slow_gains(self, omega_min: float, duration: float) -> SlowGains:
        """The slow tracking gains of this study (``controller.slow_gains``).

        Parameters
        ----------
        omega_min : float
            Lowest natural frequency along the move [rad/s]
            (``casflex.shaping.shaper_for_move(...).omega_min.min()``).
        duration : float
            Duration of the shaped move [s].

        Returns
        -------
        casflex.control.SlowGains
            From the move (bandwidth ``bandwidth_fraction`` × ω_min), the dissertation's
            ``Kp = 1``, ``Kd = 2`` or the study's own.

        Examples
        --------
        >>> s = load_study("problems/studies/arm2link_move1.toml")
        >>> g = s.slow_gains(6.614, 3.209)
        >>> round(g.bandwidth, 4), round(g.Kp, 3), round(g.separation, 3)
        (4.6298, 21.435, 1.429)
        """
        from casflex import control

        c = self.controller
        if c["slow_gains"] == "move":
            return control.slow_gains_for_move(omega_min, duration,
                                               fraction=c["bandwidth_fraction"],
                                               damping=c["damping"])
        return control.dissertation_gains(omega_min, duration, c["Kp"], c["Kd"],
                                          source=c["slow_gains"])


def _named_file(path, key, name, value=None):
    """The existing file ``name`` (relative to the study file ``path``) that the study's
    ``key`` names; ``value`` is the field's value reported when the file is missing
    (default ``name``)."""
    if not isinstance(name, str) or not name:
        raise fail(key, name, "must be a file path (string)", path=path)
    p = Path(name)
    if not p.is_absolute():
        p = path.parent / p
    if not p.is_file():
        raise fail(key, name if value is None else value, f"file {p} must exist", path=path)
    return p


def _settings(path, raw):
    """Every section of ``raw`` with its defaults filled in, unknown keys rejected."""
    for key, value in raw.items():
        if key not in _TOP and key not in _SECTIONS:
            raise fail(key, value, "unknown key; allowed: " + ", ".join(_TOP + tuple(
                _SECTIONS)), path=path)
    for key in ("robot", "move", "sensors"):
        if key not in raw:
            raise fail(key, None, "is required", path=path)
    settings = {}
    for section, defaults in _SECTIONS.items():
        if section in _OPTIONAL and section not in raw:
            settings[section] = None
            continue
        given = raw.get(section, {})
        if not isinstance(given, dict):
            raise fail(section, given, "must be a table [section]", path=path)
        for key, value in given.items():
            if key not in defaults:
                raise fail(f"{section}.{key}", value, "unknown key; allowed: "
                           + ", ".join(defaults), path=path)
        settings[section] = {**defaults, **given}
    return settings


def _flag(path, key, value):
    if not isinstance(value, bool):
        raise fail(key, value, "must be true or false", path=path)
    return value


def _check_settings(path, settings, sensors, sensors_path, n_joints):
    """Convert and check the values of every section in place."""
    def num(key, value, **bounds):
        return number(value, key, path=path, **bounds)

    def one_of(key, value, choices):
        return choice(value, key, choices, path=path)

    m = settings["model"]
    m["modes"] = num("model.modes", m["modes"], low=1, high=12, integer=True)
    m["grid_step"] = math.radians(num("model.grid_step", m["grid_step"], low=0.0, high=45.0,
                                      low_open=True))
    m["delta_order"] = one_of("model.delta_order", m["delta_order"], (0, 1))
    _flag(path, "model.gravity", m["gravity"])
    m["interpolation"] = one_of("model.interpolation", m["interpolation"], ("bspline", "linear"))
    m["fit"] = one_of("model.fit", m["fit"], ("grid", "chebyshev"))
    m["basis"] = one_of("model.basis", m["basis"], ("eigen", "smooth"))
    if m["fit"] == "chebyshev" and m["interpolation"] != "bspline":
        raise fail("model.interpolation", m["interpolation"], "interpolates the grid's "
                   "tables; model.fit = 'chebyshev' has none (leave it unset)", path=path)
    if _flag(path, "model.shape_rates", m["shape_rates"]) and m["delta_order"] != 1:
        raise fail("model.shape_rates", True, "needs model.delta_order = 1", path=path)
    if _flag(path, "model.foreshortening", m["foreshortening"]) and m["delta_order"] != 1:
        raise fail("model.foreshortening", True, "needs model.delta_order = 1", path=path)
    m["kinematics"] = one_of("model.kinematics", m["kinematics"], ("truncated", "exact"))
    if m["kinematics"] == "exact" and m["delta_order"] != 1:
        # the exact rods keep M exact in delta: a zeroth-order M contradicts them
        raise fail("model.kinematics", "exact", "needs model.delta_order = 1", path=path)
    s = settings["shaper"]
    s["vtol"] = plausible(num("shaper.vtol", s["vtol"], low=0.0, high=1.0, low_open=True),
                          "vtol", "shaper.vtol", path=path)
    s["margin"] = num("shaper.margin", s["margin"], low=0.0, high=1.0, high_open=True)
    s["n_samples"] = num("shaper.n_samples", s["n_samples"], low=10, high=5000, integer=True)
    sim = settings["simulation"]
    sim["dt"] = num("simulation.dt", sim["dt"], low=1e-5, high=1e-2)
    if sim["settle"] is not None:
        sim["settle"] = num("simulation.settle", sim["settle"], low=0.0, high=60.0)
    c = settings["controller"]
    c["law"] = one_of("controller.law", c["law"], ("composite", "inversion"))
    _check_slow_gains(path, c)
    for key in ("Q", "R"):
        c[key] = num(f"controller.{key}", c[key], low=0.0, low_open=True)
    c["gains"] = one_of("controller.gains", c["gains"], ("scheduled", "end"))
    c["schedule_points"] = num("controller.schedule_points", c["schedule_points"], low=8,
                               high=360, integer=True)
    c["schedule_region"] = one_of("controller.schedule_region", c["schedule_region"],
                                  ("limits", "move"))
    c["schedule_interpolation"] = one_of("controller.schedule_interpolation",
                                         c["schedule_interpolation"], ("bspline", "linear"))
    e = settings["estimator"]
    e["Q"] = num("estimator.Q", e["Q"], low=0.0, low_open=True)
    e["P0"] = num("estimator.P0", e["P0"], low=0.0, low_open=True)
    e["seed"] = num("estimator.seed", e["seed"], low=0, integer=True)
    e["plant_region"] = one_of("estimator.plant_region", e["plant_region"], ("limits", "move"))
    if e["R"] is None:
        std = np.asarray(sensors.noise_std, dtype=float)
        if not np.all(np.isfinite(std) & (std > 0)):
            raise fail("estimator.R", None, "is required when the sensor file "
                       f"{sensors_path} gives no 'noise' for every sensor", path=path)
        e["R"] = std**2
    else:
        e["R"] = np.full(sensors.n_outputs, num("estimator.R", e["R"], low=0.0,
                                                low_open=True))
    if e["gate"] is not None:  # ν²/S per channel above which a sample is rejected
        e["gate"] = num("estimator.gate", e["gate"], low=1.0)
    g = settings["codegen"]
    identifier(g["name"], "codegen.name", path=path)
    if _flag(path, "codegen.compile", g["compile"]) and m["kinematics"] == "exact":
        # measured: cc -O1 of the exact model's closed-loop step ran > 8 min at 3.8 GB
        raise fail("codegen.compile", True, "cannot go with model.kinematics = 'exact': the "
                   "exact model's C does not compile in reasonable time; set codegen.compile "
                   "= false (benchmarks/README_fidelity.md)", path=path)
    _flag(path, "codegen.guard", g["guard"])
    if g["torque_limits"] is not None:
        limits = np.atleast_1d(np.asarray(g["torque_limits"], dtype=object))
        if limits.ndim != 1 or limits.size not in (1, n_joints):
            raise fail("codegen.torque_limits", g["torque_limits"],
                       f"must be one number or {n_joints} (one per joint) [N m]", path=path)
        g["torque_limits"] = np.broadcast_to(np.array([
            num(f"codegen.torque_limits[{k + 1}]", v, low=0.0, low_open=True)
            for k, v in enumerate(limits)]), (n_joints,)).copy()
        if not g["guard"]:
            raise fail("codegen.torque_limits", g["torque_limits"].tolist(),
                       "needs codegen.guard = true (the limits are applied by the guarded "
                       "rt_step)", path=path)
    if settings["planner"] is not None:
        settings["planner"] = _check_planner(path, settings["planner"], m["modes"])
    if settings["planner"] is not None and m["basis"] == "smooth":
        # planning's end conditions assume decoupled free vibration (a diagonal K)
        raise fail("model.basis", "smooth", "has a full modal stiffness K, which the "
                   "[planner] cannot take: use model.basis = 'eigen' or planner.enabled = "
                   "false", path=path)


def _check_planner(path, p, n_modes):
    """The ``[planner]`` section: checked in place; ``None`` when it is switched off."""
    from casflex.planning import (
        BOUND_CORRECTIONS,
        DERIVATIVES,
        OBJECTIVES,
        ROBUST_PATHS,
        ROBUST_STEPS,
        TRANSCRIPTIONS,
        default_derivatives,
    )

    if not _flag(path, "planner.enabled", p["enabled"]):
        return None
    p["objective"] = choice(p["objective"], "planner.objective", OBJECTIVES, path=path)
    if p["duration"] is not None:
        if p["objective"] == "time":
            raise fail("planner.duration", p["duration"], "is the duration of an 'energy' "
                       "or 'weighted' plan; a 'time' plan finds its own", path=path)
        p["duration"] = number(p["duration"], "planner.duration", low=0.0, low_open=True,
                               high=600.0, path=path)
    p["weight"] = number(p["weight"], "planner.weight", low=0.0, path=path)
    if p["objective"] == "weighted" and p["weight"] == 0.0:
        raise fail("planner.weight", 0.0, "must be > 0 with objective = 'weighted' "
                   "[1/(N^2 m^2)]", path=path)
    p["robust"] = number(p["robust"], "planner.robust", low=0.0, high=0.5, path=path)
    p["robust_steps"] = ROBUST_STEPS if p["robust_steps"] is None else number(
        p["robust_steps"], "planner.robust_steps", low=1, high=100, integer=True, path=path)
    if p["robust_path"] is not None:
        p["robust_path"] = choice(p["robust_path"], "planner.robust_path", ROBUST_PATHS,
                                  path=path)
    end = p["end"]
    if isinstance(end, str):
        p["end"] = choice(end, "planner.end", ("shaped", "rest", "free"), path=path)
    else:  # a bound on the residual tip deflection [m]; no arm reaches 100 m (BOUNDS)
        p["end"] = number(end, "planner.end", low=0.0, low_open=True, high=100.0, path=path)
    if p["intervals"] is not None:
        p["intervals"] = number(p["intervals"], "planner.intervals", low=4, high=2000,
                                integer=True, path=path)
    p["transcription"] = choice(p["transcription"], "planner.transcription",
                                TRANSCRIPTIONS, path=path)
    if p["derivatives"] is None:  # as casflex plan: the fastest the transcription takes
        p["derivatives"] = default_derivatives(p["transcription"])
    p["derivatives"] = choice(p["derivatives"], "planner.derivatives", DERIVATIVES, path=path)
    if p["derivatives"] != "casadi" and p["transcription"] != "collocation":
        raise fail("planner.derivatives", p["derivatives"], "needs transcription = "
                   "'collocation' (per-interval blocks); use 'casadi' with "
                   f"'{p['transcription']}'", path=path)
    if p["modes"] is not None:
        p["modes"] = number(p["modes"], "planner.modes", low=1, high=n_modes, integer=True,
                            path=path)
    p["max_iter"] = number(p["max_iter"], "planner.max_iter", low=1, high=100000,
                           integer=True, path=path)
    p["verify_dt"] = number(p["verify_dt"], "planner.verify_dt", low=1e-6, high=1e-2,
                            path=path)
    p["bound_corrections"] = BOUND_CORRECTIONS if p["bound_corrections"] is None else number(
        p["bound_corrections"], "planner.bound_corrections", low=0, high=10, integer=True,
        path=path)
    return p


def _check_slow_gains(path, c):
    """The slow gains: chosen from the move (``"move"``: bandwidth ``bandwidth_fraction``
    of the lowest natural frequency along it), the dissertation's ``Kp = 1``, ``Kd = 2``
    (``"dissertation"``), or the study's own ``Kp`` and ``Kd`` (``"given"``, then
    required; refused otherwise, so that no given gain is silently ignored)."""
    c["slow_gains"] = choice(c["slow_gains"], "controller.slow_gains",
                             ("move", "dissertation", "given"), path=path)
    c["bandwidth_fraction"] = number(c["bandwidth_fraction"], "controller.bandwidth_fraction",
                                     low=0.0, high=1.0, low_open=True, high_open=True,
                                     path=path)
    c["damping"] = number(c["damping"], "controller.damping", low=0.0, low_open=True,
                          path=path)
    for key in ("Kp", "Kd"):
        if c["slow_gains"] == "given":
            if c[key] is None:
                raise fail(f"controller.{key}", None, "is required with slow_gains = "
                           "'given'", path=path)
            c[key] = number(c[key], f"controller.{key}", low=0.0, low_open=True, path=path)
        elif c[key] is not None:
            raise fail(f"controller.{key}", c[key], "is used only with slow_gains = 'given' "
                       f"(slow_gains is '{c['slow_gains']}')", path=path)
    if c["slow_gains"] == "dissertation":  # §6.2.2.2
        c["Kp"], c["Kd"] = 1.0, 2.0


def load_study(path: str | os.PathLike) -> Study:
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
        raise fail("-", str(path), "the study file must exist", path=path)
    raw = read_toml(path)
    settings = _settings(path, raw)

    robot_path = _named_file(path, "robot", raw["robot"])
    move_ref = raw["move"]
    if not isinstance(move_ref, str) or ":" not in move_ref:
        raise fail("move", move_ref, "must be 'FILE:NAME' (e.g. '../moves.toml:move1')",
                   path=path)
    move_file, _, move_name = move_ref.rpartition(":")
    move_path = _named_file(path, "move", move_file, value=move_ref)
    sensors_path = _named_file(path, "sensors", raw["sensors"])
    robot = load(robot_path)
    move = load_move(f"{move_path}:{move_name}")
    if move.n_joints != robot.n_joints:
        raise fail("move", move_ref, f"has {move.n_joints} joints; robot '{robot.name}' "
                   f"has {robot.n_joints}", path=path)
    for end in ("q0", "qf"):  # bang-bang moves are monotone: the ends bound the path
        try:
            robot.within_limits(getattr(move, end), f"move '{move.name}' {end}")
        except ModelError as exc:
            raise fail("move", move_ref, f"leaves the robot's joint limits ({exc})",
                       path=path) from None
    sensors = load_sensors(sensors_path, robot)

    _check_settings(path, settings, sensors, sensors_path, robot.n_joints)
    name = raw.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise fail("name", name, "must be a non-empty string", path=path)
    return Study(path=path, name=name, description=str(raw.get("description", "")),
                 robot_path=robot_path, sensors_path=sensors_path, robot=robot, move=move,
                 sensors=sensors, **settings)
