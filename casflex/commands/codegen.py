"""``casflex codegen``: C code of the real-time estimator (EKF) and of the model.

Writes two bundles (:mod:`casflex.codegen`), each in its own directory with its header,
README and Makefile: ``DIR/<name>_ekf`` with ``ekf_step``, ``plant``, ``measurement``,
``rigid_signals`` (:func:`casflex.rtcode.ekf_bundle`) and, unless ``--no-model``,
``DIR/<name>_model`` with the model's ``forward`` dynamics.

The EKF step is the one ``benchmarks/bench_ekf.py`` times: ``--jacobians first_order``
(default; ``exact`` and ``linearized`` are the alternatives of
:func:`casflex.estimation.ekf_step_function`), sequential scalar updates when ``R`` is
diagonal.

With ``--controller composite|inversion`` the EKF bundle also gets ``rt_step``
(:func:`casflex.rtloop.rt_step_function`): encoder readings, reference and accelerometer
sample to the joint torques and the updated estimator state in one call. The model is then
built as in the control studies (``delta_order=0``, the dissertation's ``M(q)``); the
composite law uses fast gains scheduled over the configuration grid.

Extending the verb: :func:`rt_functions` returns the named CasADi functions of the bundle;
add yours to that dict (and their units) before :func:`run` generates it.
"""

from __future__ import annotations

import numpy as np

from casflex.errors import ModelError

HELP = "generate C code of the EKF (and the forward dynamics) for a robot and its sensors"


def add_arguments(parser):
    """Arguments of ``casflex codegen``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's sub-parser (the CLI adds ``--json`` itself).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["r.toml", "--sensors", "s.toml", "--out", "d"]).modes
    3
    """
    parser.add_argument("robot", metavar="ROBOT.toml", help="robot description (TOML)")
    parser.add_argument("--sensors", required=True, metavar="SENSORS.toml",
                        help="sensor file with [[sensor]] tables (or a robot file with them)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    parser.add_argument("--modes", type=int, default=3, help="number of modes (default 3)")
    parser.add_argument("--name", default="casflex", help="bundle name prefix")
    parser.add_argument("--dt", type=float, default=1e-3, help="sample time, s (default 1e-3)")
    parser.add_argument("--Q", type=float, default=5e-6,
                        help="process-noise intensity on [delta; ddelta] (default 5e-6)")
    parser.add_argument("--R", type=float, default=None,
                        help="signal variance (default: the sensors' noise^2)")
    parser.add_argument("--step", type=float, default=None, metavar="DEG",
                        help="grid step of the modal tables, deg (default: casflex default)")
    parser.add_argument("--prefilter", action="store_true",
                        help="high-pass prefilter one decade below the lowest frequency")
    parser.add_argument("--sqrt", action="store_true", help="square-root covariance form")
    parser.add_argument("--jacobians", choices=("first_order", "exact", "linearized"),
                        default="first_order",
                        help="Jacobians of the EKF step (default first_order: those of the "
                             "plant's first-order part, the benchmarked real-time step, "
                             "same accuracy as exact on the studies; exact: through the "
                             "full plant; linearized: also the measurement's at zero "
                             "deflection, leanest)")
    parser.add_argument("--no-model", action="store_true",
                        help="skip the forward-dynamics bundle")
    parser.add_argument("--no-gravity", action="store_true", help="model without gravity")
    parser.add_argument("--controller", choices=("composite", "inversion"), default=None,
                        help="add rt_step: EKF and this controller in one call")
    parser.add_argument("--kp", type=float, default=1.0, help="K_p [1/s^2] (default 1)")
    parser.add_argument("--kd", type=float, default=2.0, help="K_d [1/s] (default 2)")
    parser.add_argument("--q-weight", type=float, default=1.0,
                        help="composite: LQR Q = w I (default 1)")
    parser.add_argument("--r-weight", type=float, default=10.0,
                        help="composite: LQR R = w I (default 10)")


def rt_functions(model, sensors, args, plant=None):
    """The named functions and units of the estimator bundle for ``args``.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
        Built with ``points=sensors.points``.
    sensors : casflex.sensors.SensorSet
    args : argparse.Namespace
        Uses ``Q``, ``R`` (``None``: the sensors' ``noise²``), ``dt``, ``sqrt``,
        ``prefilter`` and, when ``controller`` is set, ``kp``, ``kd``, ``q_weight``,
        ``r_weight`` (see :func:`add_arguments`).
    plant : casflex.estimation.FlexiblePlant, optional
        Default :func:`casflex.estimation.tabulate_plant` of ``model``.

    Returns
    -------
    functions : dict of str to casadi.Function
        ``ekf_step``, ``plant``, ``measurement``, ``rigid_signals`` and, with a
        controller, ``rt_step``.
    units : dict
        ``{function: {port: unit}}`` for the README.

    Raises
    ------
    casflex.errors.ModelError
        ``R`` not given and a sensor without ``noise``.

    Examples
    --------
    >>> import argparse
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
    >>> from casflex.estimation import tabulate_plant
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3), noise=3e-7)])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> plant = tabulate_plant(model, cache_dir=False)
    >>> args = argparse.Namespace(Q=5e-6, R=None, dt=1e-3, sqrt=False, prefilter=False,
    ...                           controller=None)
    >>> funcs, units = rt_functions(model, ss, args, plant=plant)
    >>> sorted(funcs), units["ekf_step"]["y"]
    (['ekf_step', 'measurement', 'plant', 'rigid_signals'], 'strain (-)')
    >>> quiet = SensorSet([StrainPair(2, 0.05)])     # no noise given, and no --R
    >>> rt_functions(model, quiet, args, plant=plant)  # doctest: +ELLIPSIS
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
    from casflex.rtcode import ekf_units

    R = args.R
    if R is None:
        std = sensors.noise_std
        if not np.all(np.isfinite(std)):
            missing = [n for n, s in zip(sensors.output_names, std, strict=True)
                       if not np.isfinite(s)]
            raise ModelError(f"--R not given and the sensor file gives no noise for "
                             f"{missing}; set 'noise' in the file or pass --R")
        R = std**2
    if plant is None:
        plant = tabulate_plant(model)
    jac = getattr(args, "jacobians", "first_order")
    funcs = ekf_functions(model, sensors, args.Q, R, args.dt, plant=plant, sqrt=args.sqrt,
                          jacobians=jac)
    if args.prefilter:
        wc = highpass_cutoff(model, np.zeros(model.n))
        funcs["ekf_step"] = ekf_step_function(plant, sensors, args.Q, R, args.dt,
                                              sqrt=args.sqrt, prefilter=wc, jacobians=jac)
    units = ekf_units(sensors)
    if getattr(args, "controller", None):
        from casflex import rtloop

        ctrl = rtloop.make_controller(model, args.controller, Kp=args.kp, Kd=args.kd,
                                      Q=args.q_weight, R=args.r_weight)
        step = funcs["ekf_step"]
        funcs["rt_step"] = rtloop.rt_step_function(step, ctrl, args.dt)
        rt = rtloop.rt_units(sensors, cov=step.name_in(1))
        if step.n_in() > 5:
            rt["rt_step"].update({"f": "prefilter state", "f_next": "prefilter state"})
        units.update(rt)
    return funcs, units


def run(args, log):
    """Generate the bundles; return ``{"files": [...], "functions": [...]}``.

    Building the model tabulates modes over a grid (seconds to minutes), so the example
    below only shows an argument check; see the module docstring for what is written.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments (see :func:`add_arguments`).
    log : callable
        ``log(message)`` writes one human-readable line (to stderr in the CLI).

    Returns
    -------
    dict
        ``{"files": [paths of source, header, README, Makefile, manifest per bundle],
        "functions": [C function names]}``.

    Raises
    ------
    casflex.errors.ModelError
        ``--modes < 1``, ``--dt <= 0`` or ``--R`` missing for sensors without noise.

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> args = p.parse_args(["problems/arm2link.toml", "--sensors",
    ...                      "problems/sensors/arm2link_strain.toml", "--out", "d",
    ...                      "--modes", "0"])
    >>> run(args, print)
    Traceback (most recent call last):
        ...
    casflex.errors.ModelError: --modes: must be >= 1; got 0
    """
    from casflex import codegen
    from casflex.model import build_model
    from casflex.robot import load
    from casflex.rtcode import model_bundle
    from casflex.sensors import load_sensors

    if args.modes < 1:
        raise ModelError(f"--modes: must be >= 1; got {args.modes}")
    if not args.dt > 0:
        raise ModelError(f"--dt: must be > 0 s; got {args.dt}")
    robot = load(args.robot)
    sensors = load_sensors(args.sensors, robot)
    step = None if args.step is None else np.radians(args.step)
    log(f"building the model of '{robot.name}' with {args.modes} modes ...")
    options = {"delta_order": 0} if args.controller else {}
    model, _ = build_model(robot, n_modes=args.modes, step=step, points=sensors.points,
                           gravity=None if args.no_gravity else "robot", **options)
    log("tabulating the flexible plant for the EKF"
        + (f" and building the {args.controller} controller ..." if args.controller
           else " ..."))
    funcs, units = rt_functions(model, sensors, args)
    order = ["ekf_step", "plant", "measurement", "rigid_signals"]
    order += ["rt_step"] if "rt_step" in funcs else []
    names = order + [k for k in funcs if k not in order]
    from pathlib import Path

    out = Path(args.out)
    bundle = codegen.generate([funcs[k] for k in names], out / f"{args.name}_ekf",
                              name=f"{args.name}_ekf",
                              units={k: v for k, v in units.items() if k in names})
    bundles = [bundle]
    if not args.no_model:
        bundles.append(model_bundle(model, out / f"{args.name}_model",
                                    name=f"{args.name}_model"))
    files, functions = [], []
    for b in bundles:
        files += [str(p) for p in (b.source, b.header, b.readme, b.makefile, b.manifest)
                  if p is not None]
        functions += [f.name for f in b.functions]
        log(f"wrote {b.source} and {b.header}")
    return {"files": files, "functions": functions}
