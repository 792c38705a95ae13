"""Real-time C code of the estimator: EKF bundle, model bundle, long-run C harness.

The generic machinery is :mod:`casflex.codegen.bundle`; this module only chooses the
functions (:func:`casflex.estimation.ekf_functions`, the model's ``forward`` dynamics) and
their units, and adds :func:`covariance_run`, a C program that runs ``ekf_step`` for
millions of steps over a recorded data set (cycled) and checks after every step that ``P``
is finite, symmetric and positive definite (Cholesky), without writing the outputs.

Call signature of the generated step (see the bundle's README)::

    ekf_step(x[2m], P[2m x 2m], u[3n], y[r], mask[r] (, f[4r]))
        -> x_next[2m], P_next[2m x 2m], x_post[2m] (, f_next[4r])

with ``u = [q; q̇; q̈]`` and ``mask`` 1 for a valid sample, 0 for a missing one.

Examples
--------
>>> import tempfile
>>> from casflex.robot import load
>>> from casflex.model import FlexibleModel, PointwiseProvider
>>> from casflex.sensors import SensorSet, StrainPair
>>> robot = load("problems/arm2link.toml")
>>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
>>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points))
>>> b = ekf_bundle(model, ss, tempfile.mkdtemp(), Q=5e-6, R=9e-14, dt=1e-3)
>>> [f.name for f in b.functions]
['ekf_step', 'plant', 'measurement', 'rigid_signals']
"""

from __future__ import annotations

import json
import os
import subprocess
from collections.abc import Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from casflex.codegen.bundle import Bundle, generate
from casflex.codegen.compiler import find_compiler, run_compiler
from casflex.codegen.errors import BuildError
from casflex.codegen.model_reads import reading_model
from casflex.codegen.segments import MAX_INSTRUCTIONS, segmented
from casflex.codegen.templates import covariance_run_source, status_header_text
from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.estimation import FlexiblePlant, Guard
    from casflex.model import FlexibleModel
    from casflex.sensors import SensorSet

__all__ = ["ekf_units", "ekf_bundle", "model_bundle", "split_forward", "exact_forward",
           "covariance_run", "add_status_defines"]


def ekf_units(sensors: SensorSet, prefix: str = "") -> dict[str, dict[str, str]]:
    """Units of the EKF functions' ports for the README (``{function: {port: unit}}``).

    Parameters
    ----------
    sensors : casflex.sensors.SensorSet
        Decides the unit of the signals ``y``: m/s² (accelerometers only), strain (strain
        pairs only) or a per-signal note for a mixed set.
    prefix : str
        Prefix of the function names (as for :func:`ekf_bundle`).

    Returns
    -------
    dict of str to dict of str to str
        Keys ``<prefix>ekf_step``, ``<prefix>plant``, ``<prefix>measurement`` and
        ``<prefix>rigid_signals``; the ``units`` of :func:`casflex.codegen.generate`.

    Examples
    --------
    >>> from casflex.sensors import SensorSet, Accelerometer
    >>> ekf_units(SensorSet([Accelerometer(2, 1.0)]))["ekf_step"]["y"]
    'm/s^2'
    """
    kinds = {s.kind for s in sensors}
    yu = "m/s^2" if kinds == {"accelerometer"} else ("strain (-)" if kinds == {"strain"}
                                                     else "m/s^2 | strain (-), per signal")
    xu = "[delta: sqrt(kg) m; ddelta: sqrt(kg) m/s]"
    uu = "[q: rad; dq: rad/s; ddq: rad/s^2]"
    return {
        prefix + "ekf_step": {"x": xu, "u": uu, "y": yu, "mask": "1 valid / 0 missing",
                              "x_next": xu, "x_post": xu},
        prefix + "plant": {"u": uu, "r0": "sqrt(kg) m/s^2", "Jd": "1/s^2", "Jv": "1/s",
                           "W": "coefficients of x_a x_b (a <= b, row-major): "
                                "1/(sqrt(kg) m s^2) | 1/(sqrt(kg) m s) | 1/(sqrt(kg) m)"},
        prefix + "measurement": {"x": xu, "u": uu, "dddelta": "sqrt(kg) m/s^2", "y": yu},
        prefix + "rigid_signals": {"u": uu, "y_rigid": yu},
    }


def ekf_bundle(model: FlexibleModel, sensors: SensorSet, out_dir: str | os.PathLike,
               Q: ArrayLike, R: ArrayLike, dt: float, *, name: str = "casflex_ekf",
               plant: FlexiblePlant | None = None, sqrt: bool = False,
               prefilter: float | None = None, coriolis: bool = True,
               stiffness_scale: float = 1.0, prefix: str = "",
               jacobians: str = "exact", guard: Guard | None = None) -> Bundle:
    """Generate the EKF bundle (C source, header, README, Makefile, manifest).

    Parameters
    ----------
    model, sensors, Q, R, dt, plant, sqrt, coriolis, stiffness_scale, jacobians
        As for :func:`casflex.estimation.ekf_functions` (``jacobians="first_order"``: the
        leaner step for second-order plants, same accuracy on the Table 9 moves, see
        ``benchmarks/README_ekf.md``).
    out_dir : str or pathlib.Path
    name : str
        Bundle name.
    prefilter : float, optional
        High-pass cut-off [rad/s] (:func:`casflex.estimation.ekf_step_function`).
    prefix : str
        Prefix of the C function names.
    guard : casflex.estimation.Guard, optional
        Generate the guarded step (:mod:`casflex.estimation.guard`: inputs ``u_last``,
        outputs ``u_next``, ``status``); the header defines the status bits
        (``CASFLEX_STATUS_*``).

    Returns
    -------
    casflex.codegen.Bundle
        Functions ``ekf_step``, ``plant``, ``measurement``, ``rigid_signals`` (with
        ``prefix``), in that order.

    Examples
    --------
    >>> import tempfile
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.estimation import tabulate_plant
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> plant = tabulate_plant(model, cache_dir=False)
    >>> b = ekf_bundle(model, ss, tempfile.mkdtemp(), Q=5e-6, R=9e-14, dt=1e-3,
    ...                plant=plant, prefix="arm_")
    >>> b.header.name, [f.name for f in b.functions]
    ('casflex_ekf.h', ['arm_ekf_step', 'arm_plant', 'arm_measurement', 'arm_rigid_signals'])
    >>> [(p.name, p.rows) for p in b.function("arm_ekf_step").inputs]
    [('x', 2), ('P', 2), ('u', 9), ('y', 2), ('mask', 2)]
    """
    from casflex.estimation import ekf_functions, ekf_step_function, tabulate_plant

    if plant is None:
        plant = tabulate_plant(model)
    funcs = ekf_functions(model, sensors, Q, R, dt, plant=plant, sqrt=sqrt,
                          coriolis=coriolis, stiffness_scale=stiffness_scale, prefix=prefix,
                          jacobians=jacobians)
    if prefilter is not None or guard is not None:
        funcs["ekf_step"] = ekf_step_function(plant, sensors, Q, R, dt, sqrt=sqrt,
                                              coriolis=coriolis,
                                              stiffness_scale=stiffness_scale,
                                              prefilter=prefilter, name=prefix + "ekf_step",
                                              jacobians=jacobians, guard=guard)
    order = ["ekf_step", "plant", "measurement", "rigid_signals"]
    units = ekf_units(sensors, prefix)
    if sqrt:
        units[prefix + "ekf_step"].pop("x_next", None)
    if guard is not None:
        uu = units[prefix + "ekf_step"]["u"]
        units[prefix + "ekf_step"].update({"u_last": uu, "u_next": uu,
                                           "status": "status bits (CASFLEX_STATUS_*)"})
    bundle = generate([funcs[k] for k in order], out_dir, name=name, units=units)
    if guard is not None:
        add_status_defines(bundle)
    return bundle


def add_status_defines(bundle: Bundle, torque_limits: ArrayLike | None = None) -> None:
    """Append the status bits (and torque limits) of the guarded steps to a bundle's
    header (:func:`casflex.codegen.templates.status_header_text`).

    Parameters
    ----------
    bundle : casflex.codegen.Bundle
        With a header.
    torque_limits : array_like, optional
        Per-joint torque limits [N·m] of its ``rt_step``.

    Examples
    --------
    >>> import tempfile
    >>> import casadi as ca
    >>> x = ca.SX.sym("x")
    >>> b = generate([ca.Function("f", [x], [x])], tempfile.mkdtemp())
    >>> add_status_defines(b, [5.0])
    >>> "#define CASFLEX_STATUS_COVARIANCE_RESET 8" in b.header.read_text()
    True
    """
    from casflex.estimation.guard import STATUS_BITS

    with open(bundle.header, "a") as fh:
        fh.write(status_header_text(STATUS_BITS, None if torque_limits is None
                                    else [float(v) for v in np.ravel(torque_limits)]))


def split_forward(model: FlexibleModel, max_instructions: int = MAX_INSTRUCTIONS
                  ) -> ca.Function:
    """The model's forward dynamics as C-friendly calls: ``M`` and ``h`` in pieces, a solve.

    ``forward`` of :meth:`casflex.model.FlexibleModel.functions` is one SX graph: with
    ``delta_order=1`` its ``C(q, q̇) q̇`` term, differentiated through ``M(q, δ)``, makes it
    ~35 000 instructions on the Table 8 arm (3 modes), one C function of as many lines,
    and gcc's time grows faster than linearly with a function's length. Here
    ``M Ẍ = [τ; 0] − h`` is an MX graph of two calls: ``forward_terms(q, δ, q̇, δ̇) ->
    (M, h)``, the model's own ``M`` and ``h`` (bias, potential and damping forces:
    :attr:`FlexibleModel.h`) in ONE SX function with common subexpressions merged (the
    derivatives of ``M`` that ``h`` takes share their pieces with ``M``: 29 500
    instructions instead of 33 900 for ``M``, ``Ṁ Ẋ`` and ``∂T/∂X`` as three functions;
    with the exact kinematics 103 000 instead of 145 000 for ``M`` and ``h`` apart), cut
    into consecutive pieces of at most ``max_instructions``
    (:func:`casflex.codegen.segments.segmented`: the same operations, bit-identical), and
    a small linear solve (``forward_solve``; with ``modal_mass="identity"`` the model's
    block solve, ``M_δδ ≡ I``). It equals the model's ``forward`` to rounding of the solve.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Any kinematics.
    max_instructions : int
        Longest piece of ``forward_terms`` [SX instructions].

    Returns
    -------
    casadi.Function
        ``forward(q, dq, delta, ddelta, tau) -> (ddq, dddelta)`` [rad/s², √kg·m/s²], the
        ports of the model's ``forward``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1), gravity=None)
    >>> args = ([0.1, 0.2, 0.3], [0.5, -0.4, 0.3], [1e-3], [0.02], [1.0, 0.5, 0.2])
    >>> a = np.vstack([o.full() for o in model.functions()["forward"](*args)])
    >>> b = np.vstack([o.full() for o in split_forward(model)(*args)])
    >>> bool(np.allclose(a, b, rtol=1e-13, atol=0))
    True
    """
    n, m = model.n, model.m
    names = ["q", "delta", "dq", "ddelta"]
    terms = segmented(ca.Function("forward_terms", [model.q, model.delta, model.dq,
                                                    model.ddelta], [model.M, model.h],
                                  names, ["M", "h"], {"cse": True}), max_instructions)
    N = n + m
    Ms, rs = ca.SX.sym("M", N, N), ca.SX.sym("rhs", N)
    if model.modal_mass == "identity" and m:
        Mqq, Mqd = Ms[:n, :n], Ms[:n, n:]
        ddq = ca.solve(Mqq - Mqd @ Mqd.T, rs[:n] - Mqd @ rs[n:])
        sol = ca.vertcat(ddq, rs[n:] - Mqd.T @ ddq)
    else:
        sol = ca.solve(Ms, rs)
    solve = ca.Function("forward_solve", [Ms, rs], [sol], ["M", "rhs"], ["ddX"])
    q, dq, tau = ca.MX.sym("q", n), ca.MX.sym("dq", n), ca.MX.sym("tau", n)
    d, dd = ca.MX.sym("delta", m), ca.MX.sym("ddelta", m)
    M, h = terms(q, d, dq, dd)
    ddX = solve(M, ca.vertcat(tau, ca.MX.zeros(m)) - h)
    return ca.Function("forward", [q, dq, d, dd, tau], [ddX[:n], ddX[n:]],
                       ["q", "dq", "delta", "ddelta", "tau"], ["ddq", "dddelta"])


def exact_forward(model: FlexibleModel, max_instructions: int = MAX_INSTRUCTIONS
                  ) -> ca.Function:
    """:func:`split_forward` under the name the exact kinematics' bundle had (issue 19):
    the same calls for every kinematics since both use the model's own ``M`` and ``h``.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    max_instructions : int
        As for :func:`split_forward`.

    Returns
    -------
    casadi.Function
        :func:`split_forward` ``(model, max_instructions)``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0.4], 1),
    ...                       kinematics="exact")
    >>> args = ([0.1, 0.2, 0.3], [0.5, -0.4, 0.3], [0.1], [0.8], [1.0, 0.5, 0.2])
    >>> a = np.vstack([o.full() for o in model.functions()["forward"](*args)])
    >>> b = np.vstack([o.full() for o in exact_forward(model)(*args)])
    >>> bool(np.allclose(a, b, rtol=1e-12, atol=0))
    True
    """
    return split_forward(model, max_instructions)


def model_bundle(model: FlexibleModel, out_dir: str | os.PathLike, *,
                 name: str = "casflex_model",
                 functions: Sequence[str] = ("forward",), split: bool = True) -> Bundle:
    """Generate a bundle with functions of the model (default its forward dynamics).

    ``forward`` is generated as :func:`split_forward` (unless ``split=False``): the same
    dynamics in several C functions of moderate length, which gcc compiles several times
    faster than the model's single graph. The model is first rebuilt with its combined
    table lookup limited to the quantities ``M`` and ``h`` read
    (:func:`casflex.codegen.model_reads.reading_model`), so the C holds no table that
    the dynamics do not read.

    Parameters
    ----------
    model : casflex.model.FlexibleModel
    out_dir : str or pathlib.Path
    name : str
        Bundle name.
    functions : sequence of str
        Keys of :meth:`casflex.model.FlexibleModel.functions` to generate (``"ode"``,
        ``"mass"``, ...); units are written for ``"forward"``.
    split : bool
        ``forward`` as :func:`split_forward` (default), else the model's own graph.

    Returns
    -------
    casflex.codegen.Bundle

    Raises
    ------
    casflex.errors.ModelError
        For a name the model has no function for.

    Examples
    --------
    >>> import tempfile
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> m = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> model_bundle(m, tempfile.mkdtemp()).functions[0].inputs[4].name
    'tau'
    """
    model = reading_model(model)  # the tables of the quantities M and h read, no others
    f = model.functions()
    units = {"forward": {"q": "rad", "dq": "rad/s", "delta": "sqrt(kg) m",
                         "ddelta": "sqrt(kg) m/s", "tau": "N m", "ddq": "rad/s^2",
                         "dddelta": "sqrt(kg) m/s^2"}}
    chosen = []
    for key in functions:
        if key not in f:
            raise ModelError(f"the model has no function {key!r}; it has {sorted(f)}")
        chosen.append(split_forward(model) if key == "forward" and split else f[key])
    return generate(chosen, out_dir, name=name,
                    units={k: v for k, v in units.items() if k in functions})


def covariance_run(bundle: Bundle, u: ArrayLike, y: ArrayLike, x0: ArrayLike, P0: ArrayLike,
                   steps: int, *, mask: ArrayLike | None = None, f0: ArrayLike | None = None,
                   function: str = "ekf_step", compiler: str | Sequence[str] | None = None,
                   flags: Sequence[str] = ("-O2",)) -> dict:
    """Run ``ekf_step`` in C for ``steps`` steps over recorded data (cycled); check ``P``.

    After every step the covariance (``S Sᵀ`` for the square-root form) is checked to be
    finite, symmetric and positive definite (an unrolled Cholesky). Nothing is written
    during the run; a JSON summary is returned.

    Parameters
    ----------
    bundle : casflex.codegen.Bundle
        With an EKF step function (:func:`ekf_bundle`).
    u, y : array_like
        (K, 3n), (K, r) recorded inputs and signals (cycled; NaN entries of ``y`` are
        masked).
    x0, P0 : array_like
        Initial estimate and covariance (or square root).
    steps : int
    mask : array_like, optional
    f0 : array_like, optional
        Initial prefilter state when the step has one.
    function : str
    compiler, flags
        As for :func:`casflex.codegen.build`.

    Returns
    -------
    dict
        ``steps``, ``not_positive_definite``, ``not_finite`` (step counts),
        ``max_rel_asymmetry`` (max |P_ij − P_ji| / √(P_ii P_jj)),
        ``min_rel_cholesky_pivot``, ``min_diag``, ``max_diag``, ``mean_step_ns`` (including
        the checks), ``x_final``.

    Notes
    -----
    The program, its data file and the executable are written to ``bundle.out_dir``
    (``covrun_<function>.c``, ``covrun_<function>_data.txt``, ``covrun_<function>``).

    Examples
    --------
    A one-mode strain-gauge EKF, 1000 steps over one recorded sample at rest (``-O0``: the
    build, not the run, takes the time here):

    >>> import tempfile
    >>> from casflex.robot import load
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.estimation import tabulate_plant
    >>> from casflex.sensors import SensorSet, StrainPair
    >>> robot = load("problems/arm2link.toml")
    >>> ss = SensorSet([StrainPair(2, 0.05, (3.5e-3, 2.5e-3))])
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], 1, ss.points),
    ...                       gravity=None)
    >>> plant = tabulate_plant(model, cache_dir=False)
    >>> b = ekf_bundle(model, ss, tempfile.mkdtemp(), Q=5e-6, R=9e-14, dt=1e-3, plant=plant)
    >>> r = covariance_run(b, np.zeros((1, 9)), np.zeros((1, 2)), [0, 0], np.eye(2) * 1e-4,
    ...                    1000, flags=("-O0",))
    >>> r["steps"], r["not_positive_definite"], r["not_finite"]
    (1000, 0, 0)
    >>> bool(r["max_diag"] <= 1e-4)   # the covariance shrinks from P0
    True
    """
    info = bundle.function(function)
    if any(p.name == "u_last" for p in info.inputs):
        raise ModelError(f"covariance_run: '{function}' is a guarded step (input u_last); "
                         "the long-run harness runs the unguarded step only")
    nx = info.inputs[0].rows
    nu = info.inputs[2].rows
    ny = info.inputs[3].rows
    nf = info.inputs[5].rows if len(info.inputs) > 5 else 0
    sqrt = info.inputs[1].name == "S"
    u = np.atleast_2d(np.asarray(u, dtype=float))
    y = np.asarray(y, dtype=float).reshape(u.shape[0], ny)
    valid = np.isfinite(y) if mask is None else (np.isfinite(y) & np.asarray(mask, bool))
    y = np.where(valid, y, 0.0)
    K = u.shape[0]
    src = bundle.out_dir / f"covrun_{function}.c"
    src.write_text(covariance_run_source(bundle.header.name, function, nx=nx, nu=nu, ny=ny,
                                         nf=nf, samples=K, sqrt=sqrt))
    exe = bundle.out_dir / f"covrun_{function}"
    cc = find_compiler(compiler)
    run_compiler([*cc, *flags, "-I", str(bundle.out_dir), "-o", str(exe), str(src),
                  str(bundle.source), "-lm"], bundle.out_dir)
    data = bundle.out_dir / f"covrun_{function}_data.txt"
    P0 = np.asarray(P0, dtype=float)
    head = [np.asarray(x0, float).ravel(), P0.T.ravel(),
            np.zeros(nf) if f0 is None else np.asarray(f0, float).ravel()]
    with open(data, "w") as fh:
        fh.write(" ".join(repr(float(v)) for v in np.concatenate(head)) + "\n")
        for k in range(K):
            fh.write(" ".join(repr(float(v)) for v in np.r_[u[k], y[k],
                                                             valid[k].astype(float)]) + "\n")
    proc = subprocess.run([str(exe), str(data), str(int(steps))], capture_output=True,
                          text=True, timeout=3600)
    if proc.returncode != 0:
        raise BuildError(f"covariance_run: '{exe.name}' exited with status "
                         f"{proc.returncode}: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout)
