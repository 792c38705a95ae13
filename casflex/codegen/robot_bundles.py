"""The real-time bundles of a robot and its sensors: what ``casflex codegen`` writes.

:func:`realtime_bundles` builds the model of a robot for its sensors and writes two
bundles, each in its own directory with its header, README and Makefile:
``<out_dir>/<name>_ekf`` with ``ekf_step``, ``plant``, ``measurement``, ``rigid_signals``
(and, with a controller, ``rt_step``: :func:`casflex.codegen.rt_step_function`) and,
unless ``model=False``, ``<out_dir>/<name>_model`` with the model's ``forward`` dynamics
(:func:`casflex.codegen.model_bundle`).

The EKF step is the one ``benchmarks/bench_ekf.py`` times: ``jacobians="first_order"``
(default; ``"exact"`` and ``"linearized"`` are the alternatives of
:func:`casflex.estimation.ekf_step_function`), sequential scalar updates when ``R`` is
diagonal. The composite law uses fast gains scheduled on a 30-point full-turn axis per
scheduled joint, cached on disk (:func:`casflex.codegen.make_controller`).

Which model each part uses:

* **the estimator, one plant with and without a controller**: the EKF plant is tabulated
  (:func:`casflex.estimation.tabulate_plant`) from the model built as in the control
  studies and the design job's default (``delta_order=0``, the dissertation's ``M(q)``),
  so ``ekf_step`` does not change when ``rt_step`` is added. Until session 9 the plain
  command tabulated it from the ``delta_order=1`` model instead: a different estimator
  than the one next to the controller, and ~3/4 of the command's cold time (that plant's
  tabulation).
* **the controller**: the same ``M(q)`` model (the composite law's singular perturbation
  is derived for it).
* **the forward-dynamics bundle** (the simulation model): ``M`` to first order in ``δ``
  (``delta_order=1``, :class:`casflex.model.FlexibleModel`'s default) without a
  controller; with one, the controller's ``M(q)`` model. Its tables are read by local
  B-splines from one static coefficient table each (:class:`casflex.model.TableProvider`
  ``lookup="static"``) and ``forward`` is split into the model's smaller functions
  (:func:`casflex.codegen.split_forward`): C a little over half the size, compiled
  several times faster.
* **the exact kinematics** (``kinematics="exact"``, ``casflex codegen --kinematics
  exact``): the forward-dynamics bundle is :class:`casflex.model.FlexibleModel` with
  ``kinematics="exact"`` (``M`` and the bias forces exact in ``δ``; ``delta_order=1``,
  with or without a controller), its ``forward`` split by
  :func:`casflex.codegen.exact_forward`. The estimator and the controller keep their
  ``M(q)`` model.

Extending the bundle: :func:`rt_functions` returns its named CasADi functions and their
units; add yours to both before generating them with :func:`casflex.codegen.generate`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex._parallel import progress_bar
from casflex._validate import choice, fail, number, output_directory
from casflex.codegen.bundle import Bundle, generate
from casflex.codegen.estimator import add_status_defines, ekf_units, model_bundle
from casflex.codegen.rtloop import make_controller, rt_step_function, rt_units
from casflex.errors import ModelError
from casflex.model import KINEMATICS

if TYPE_CHECKING:
    from casflex.estimation import FlexiblePlant, Guard
    from casflex.model import FlexibleModel
    from casflex.robot import Robot
    from casflex.sensors import SensorSet

__all__ = ["rt_functions", "realtime_bundles"]

#: order of the estimator bundle's functions (others follow in their dict order)
_EKF_ORDER = ("ekf_step", "plant", "measurement", "rigid_signals", "rt_step")


def rt_functions(model: FlexibleModel, sensors: SensorSet, *, Q: ArrayLike = 5e-6,
                 R: ArrayLike | None = None, dt: float = 1e-3, sqrt: bool = False,
                 prefilter: bool = False, jacobians: str = "first_order",
                 controller: str | None = None, kp: ArrayLike = 1.0, kd: ArrayLike = 2.0,
                 q_weight: ArrayLike = 1.0, r_weight: ArrayLike = 10.0,
                 plant: FlexiblePlant | None = None, guard: Guard | None = None,
                 torque_limits: ArrayLike | None = None,
                 controller_function: ca.Function | None = None
                 ) -> tuple[dict[str, ca.Function], dict[str, dict[str, str]]]:
    """The named functions and units of the estimator bundle.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Built with ``points=sensors.points``.
    sensors : casflex.sensors.SensorSet
    Q : float or array_like
        Process-noise intensity on ``[δ; δ̇]``.
    R : float or array_like, optional
        Signal variance; default the sensors' ``noise²``.
    dt : float
        Sample time [s].
    sqrt : bool
        Square-root covariance form.
    prefilter : bool
        High-pass prefilter one decade below the lowest frequency at ``q = 0``
        (:func:`casflex.estimation.highpass_cutoff`).
    jacobians : {"first_order", "exact", "linearized"}
        Jacobians of the EKF step (:func:`casflex.estimation.ekf_step_function`).
    controller : {"composite", "inversion"}, optional
        Also ``rt_step``: the EKF and this controller in one call
        (:func:`casflex.codegen.make_controller`).
    kp, kd : float or array_like
        Joint gains of the controller [1/s², 1/s].
    q_weight, r_weight : float or array_like
        LQR weights ``Q``, ``R`` of the composite controller's fast part.
    plant : casflex.estimation.FlexiblePlant, optional
        Default :func:`casflex.estimation.tabulate_plant` of ``model``.
    guard : casflex.estimation.Guard, optional
        Guarded ``ekf_step`` and ``rt_step`` (:mod:`casflex.estimation.guard`; not with
        ``sqrt``).
    torque_limits : float or array_like, optional
        Per-joint torque limits [N·m] of the guarded ``rt_step`` (required with ``guard``
        and ``controller``).
    controller_function : casadi.Function, optional
        The ``controller`` already built (:func:`casflex.codegen.make_controller` with
        these arguments); default: built here.

    Returns
    -------
    functions : dict of str to casadi.Function
        ``ekf_step``, ``plant``, ``measurement``, ``rigid_signals`` and, with a
        controller, ``rt_step``. ``measurement`` is the sensors' kinematic model from a
        B-spline of just the table entries they use
        (:func:`casflex.sensors.kinematic_measurement`, ``lean=True``: what ``ekf_step``
        evaluates; the same as the model's to rounding).
    units : dict
        ``{function: {port: unit}}`` for the README.

    Raises
    ------
    casflex.errors.ModelError
        ``R`` not given and a sensor without ``noise``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.estimation import tabulate_plant
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3), noise=3e-7)])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> plant = tabulate_plant(model, cache_dir=False)
    >>> funcs, units = rt_functions(model, ss, Q=5e-6, dt=1e-3, plant=plant)
    >>> sorted(funcs), units["ekf_step"]["y"]
    (['ekf_step', 'measurement', 'plant', 'rigid_signals'], 'strain (-)')
    >>> quiet = SensorSet([StrainPair(2, 0.05)])     # no noise given, and no R
    >>> rt_functions(model, quiet, plant=plant)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --R not given and the sensor file gives no noise for ...
    """
    from casflex.estimation import (
        ekf_functions,
        ekf_step_function,
        highpass_cutoff,
        tabulate_plant,
    )
    from casflex.sensors import kinematic_measurement

    if R is None:
        std = sensors.noise_std
        if not np.all(np.isfinite(std)):
            missing = [n for n, s in zip(sensors.output_names, std, strict=True)
                       if not np.isfinite(s)]
            # worded for the command line, this function's main caller
            raise ModelError(f"--R not given and the sensor file gives no noise for "
                             f"{missing}; set 'noise' in the file or pass --R")
        R = std**2
    if plant is None:
        plant = tabulate_plant(model)
    funcs = ekf_functions(model, sensors, Q, R, dt, plant=plant, sqrt=sqrt,
                          jacobians=jacobians)
    # the measurement from the B-spline of just the table entries the sensors use (what
    # ekf_step evaluates inside), not the model's spline of all of them and its first and
    # second derivatives: three tables of every entry were 2.9 MB of the C source
    lean = kinematic_measurement(model, sensors, lean=True)
    funcs["measurement"] = ca.Function("measurement", lean.sx_in(), lean.call(lean.sx_in()),
                                       lean.name_in(), lean.name_out())
    if prefilter or guard is not None:
        wc = highpass_cutoff(model, np.zeros(model.n)) if prefilter else None
        funcs["ekf_step"] = ekf_step_function(plant, sensors, Q, R, dt, sqrt=sqrt,
                                              prefilter=wc, jacobians=jacobians, guard=guard)
    units = ekf_units(sensors)
    if guard is not None:
        units["ekf_step"].update({"u_last": units["ekf_step"]["u"],
                                  "u_next": units["ekf_step"]["u"],
                                  "status": "status bits (CASFLEX_STATUS_*)"})
        if controller and torque_limits is None:
            raise ModelError("torque_limits (--torque-limit) must be given for the guarded "
                             "rt_step")
    if controller:
        ctrl = controller_function
        if ctrl is None:
            ctrl = make_controller(model, controller, Kp=kp, Kd=kd, Q=q_weight, R=r_weight)
        step = funcs["ekf_step"]
        funcs["rt_step"] = rt_step_function(
            step, ctrl, dt, torque_limits=torque_limits if guard is not None else None)
        rt = rt_units(sensors, cov=step.name_in(1), guarded=guard is not None)
        if "f" in step.name_in():
            rt["rt_step"].update({"f": "prefilter state", "f_next": "prefilter state"})
        units.update(rt)
    return funcs, units


def realtime_bundles(robot: str | os.PathLike | Robot, sensors: str | os.PathLike | SensorSet,
                     out_dir: str | os.PathLike, *, n_modes: int = 3, name: str = "casflex",
                     step: float | None = None, gravity: bool = True, model: bool = True,
                     Q: ArrayLike = 5e-6, R: ArrayLike | None = None, dt: float = 1e-3,
                     sqrt: bool = False, prefilter: bool = False,
                     jacobians: str = "first_order", controller: str | None = None,
                     kp: ArrayLike = 1.0, kd: ArrayLike = 2.0, q_weight: ArrayLike = 1.0,
                     r_weight: ArrayLike = 10.0, guard: Guard | None = None,
                     torque_limits: ArrayLike | None = None,
                     fit: str = "grid", basis: str = "eigen", kinematics: str = "truncated",
                     log: Callable[[str], object] | None = None,
                     progress: bool = False,
                     cache_dir: str | os.PathLike | bool | None = None) -> list[Bundle]:
    """Build the model of a robot for its sensors and write its real-time bundles.

    Building the model tabulates modes over a grid (seconds to minutes), so the example
    below only shows an argument check; see the module docstring for what is written.

    Parameters
    ----------
    robot : str, os.PathLike or casflex.robot.Robot
        The robot, or its TOML file.
    sensors : str, os.PathLike or casflex.sensors.SensorSet
        The sensors, or a file with ``[[sensor]]`` tables.
    out_dir : str or os.PathLike
        Directory of the bundle directories ``<name>_ekf`` and ``<name>_model``.
    n_modes : int
        Number of modes.
    name : str
        Prefix of the bundle names.
    step : float, optional
        Grid step of the modal tables [rad] (default: :func:`casflex.model.build_model`'s).
    gravity : bool
        Model with the robot's gravity.
    model : bool
        Also write the forward-dynamics bundle.
    Q, R, dt, sqrt, prefilter, jacobians, controller, kp, kd, q_weight, r_weight, guard
        As for :func:`rt_functions`.
    torque_limits : float or array_like, optional
        As for :func:`rt_functions`; also written to the estimator bundle's header
        (``CASFLEX_TORQUE_LIMIT_<j>``, with the status bits ``CASFLEX_STATUS_*``).
    fit : {"grid", "chebyshev"}
        The model's terms interpolated over a grid of the shape joints (default), or
        Chebyshev series over the joint box (:func:`casflex.model.build_model`'s ``fit``;
        no grid, so no ``step``).
    basis : {"eigen", "smooth"}
        Tracked eigenmodes (default) or the smooth basis of clusters of close modes
        (:func:`casflex.model.build_model`'s ``basis``).
    kinematics : {"truncated", "exact"}
        The kinematics of the forward-dynamics bundle's model (module docstring;
        :class:`casflex.model.FlexibleModel`'s option). ``"exact"`` needs ``model``.
    log : callable, optional
        ``log(message)`` receives one line per stage.
    progress : bool
        Progress bars on stderr: one over the stages (naming the current one), and the
        modal tables' own.
    cache_dir : path, None or False
        Cache of the modal tables, the tabulated plant and the gain schedule (a path,
        ``None`` for the default, ``False`` for none).

    Returns
    -------
    list of casflex.codegen.Bundle
        The estimator bundle, then (with ``model``) the model bundle.

    Raises
    ------
    casflex.errors.ModelError
        ``n_modes < 1``, ``dt <= 0``, ``R`` missing for sensors without noise, an unknown
        ``fit``, ``basis`` or ``kinematics``, a ``step`` with ``fit="chebyshev"``, or
        ``kinematics="exact"`` without ``model``.
    casflex.errors.ProblemFileError
        An invalid robot or sensor file.

    Examples
    --------
    >>> realtime_bundles("problems/arm2link.toml", "problems/sensors/arm2link_strain.toml",
    ...                  "d", n_modes=0)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: n_modes = 0: must be >= 1
    >>> realtime_bundles("problems/arm2link.toml", "problems/sensors/arm2link_strain.toml",
    ...                  "d", fit="chebyshev", step=0.05)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: step = 0.05: is the grid step ... has no grid (leave it unset)
    """
    from casflex.estimation import tabulate_plant
    from casflex.model import build_model
    from casflex.robot import load
    from casflex.sensors import load_sensors

    n_modes = number(n_modes, "n_modes", low=1, integer=True)
    dt = number(dt, "dt", low=0.0, low_open=True)
    fit = choice(fit, "fit", ("grid", "chebyshev"))
    basis = choice(basis, "basis", ("eigen", "smooth"))
    kinematics = choice(kinematics, "kinematics", KINEMATICS)
    if kinematics == "exact" and not model:
        raise fail("kinematics", kinematics, "applies to the forward-dynamics bundle, which "
                   "model=False leaves out")
    if fit == "chebyshev" and step is not None:
        raise fail("step", step, "is the grid step of the modal tables; fit = 'chebyshev' "
                   "has no grid (leave it unset)")
    out = output_directory(out_dir, "out_dir")  # before any heavy work
    if log is None:
        def log(message):
            pass
    if isinstance(robot, (str, os.PathLike)):
        robot = load(robot)
    if isinstance(sensors, (str, os.PathLike)):
        sensors = load_sensors(sensors, robot)
    stages = progress_bar(4 + bool(controller) + bool(model), desc="codegen",
                          enabled=progress)

    def stage(message):  # the log line, and its short form on the stage bar
        log(message)
        stages.set_postfix_str(message.rstrip(" .").split(" (")[0], refresh=True)

    with stages:
        stage(f"building the model of '{robot.name}' with {n_modes} modes ...")
        # the estimator's (and the controller's) model, with or without a controller:
        # M(q), as in the control studies and the design job (module docstring)
        options = {"delta_order": 0, "gravity": "robot" if gravity else None}
        flexible, table = build_model(robot, n_modes=n_modes, step=step,
                                      points=sensors.points, progress=progress,
                                      cache_dir=cache_dir, basis=basis,
                                      fit=None if fit == "grid" else fit, **options)
        stages.update()
        stage("tabulating the flexible plant for the EKF ...")
        plant = tabulate_plant(flexible, cache_dir=cache_dir)  # cached on disk
        stages.update()
        ctrl = None
        if controller:
            stage(f"building the {controller} controller ...")
            ctrl = make_controller(flexible, controller, Kp=kp, Kd=kd, Q=q_weight,
                                   R=r_weight, cache_dir=cache_dir)  # schedule cached
            stages.update()
        stage("building the estimator's functions ...")
        funcs, units = rt_functions(flexible, sensors, Q=Q, R=R, dt=dt, sqrt=sqrt,
                                    prefilter=prefilter, jacobians=jacobians,
                                    controller=controller, kp=kp, kd=kd, q_weight=q_weight,
                                    r_weight=r_weight, plant=plant, guard=guard,
                                    torque_limits=torque_limits, controller_function=ctrl)
        stages.update()
        stage("generating C of the estimator ...")
        names = [k for k in _EKF_ORDER if k in funcs] + [k for k in funcs
                                                         if k not in _EKF_ORDER]
        bundles = [generate([funcs[k] for k in names], out / f"{name}_ekf",
                            name=f"{name}_ekf",
                            units={k: v for k, v in units.items() if k in names})]
        if guard is not None:
            limits = None
            if controller:
                limits = np.broadcast_to(np.asarray(torque_limits, float), (flexible.n,))
            add_status_defines(bundles[0], limits)
        stages.update()
        if model:
            stage("generating C of the forward dynamics ...")
            # the simulation model: M to first order in δ, or the controller's M(q); the
            # exact kinematics whenever asked for (module docstring)
            options["delta_order"] = 0 if controller and kinematics != "exact" else 1
            simulation = _bundle_model(flexible, table, {**options, "kinematics": kinematics})
            bundles.append(model_bundle(simulation, out / f"{name}_model",
                                        name=f"{name}_model"))
            stages.update()
    return bundles


def _bundle_model(flexible, table, options):
    """The model of the forward-dynamics bundle: ``flexible``'s tables and ``options``
    (:class:`~casflex.model.equations.FlexibleModel` keywords), the tables read by local
    B-splines whose one coefficient table (shared by the derivatives ``forward`` takes) is
    static data, not work memory (:class:`casflex.model.TableProvider` ``lookup="static"``):
    the C holds each table once instead of three times. The same model to rounding of
    the spline fits (≈ 1e-14); a fitted model (no table) keeps its provider."""
    from casflex.model import FlexibleModel, TableProvider

    provider = flexible.provider
    if isinstance(provider, TableProvider):
        provider = TableProvider(table, provider.method, lookup="static")
    return FlexibleModel(flexible.robot, provider, **options)
