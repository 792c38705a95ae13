"""Real-time C code of the estimator: EKF bundle, model bundle, long-run C harness.

The generic machinery is :mod:`casflex.codegen`; this module only chooses the functions
(:func:`casflex.estimation.ekf_functions`, the model's ``forward`` dynamics), their units,
and adds :func:`covariance_run`, a C program that runs ``ekf_step`` for millions of steps
over a recorded data set (cycled) and checks after every step that ``P`` is finite,
symmetric and positive definite (Cholesky), without writing the outputs.

Call signature of the generated step (see the bundle's README)::

    ekf_step(x[2m], P[2m x 2m], u[3n], y[r], mask[r] (, f[4r]))
        -> x_next[2m], P_next[2m x 2m], x_post[2m] (, f_next[4r])

with ``u = [q; q̇; q̈]`` and ``mask`` 1 for a valid sample, 0 for a missing one.

Examples
--------
>>> import tempfile
>>> from casflex.robot import load
>>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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
import subprocess

import numpy as np

from casflex import codegen
from casflex.errors import ModelError

__all__ = ["ekf_units", "ekf_bundle", "model_bundle", "covariance_run"]


def ekf_units(sensors, prefix=""):
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


def ekf_bundle(model, sensors, out_dir, Q, R, dt, *, name="casflex_ekf", plant=None,
               sqrt=False, prefilter=None, coriolis=True, stiffness_scale=1.0, prefix="",
               jacobians="exact"):
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

    Returns
    -------
    casflex.codegen.Bundle
        Functions ``ekf_step``, ``plant``, ``measurement``, ``rigid_signals`` (with
        ``prefix``), in that order.

    Examples
    --------
    >>> import tempfile
    >>> from casflex.robot import load
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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
    if prefilter is not None:
        funcs["ekf_step"] = ekf_step_function(plant, sensors, Q, R, dt, sqrt=sqrt,
                                              coriolis=coriolis,
                                              stiffness_scale=stiffness_scale,
                                              prefilter=prefilter, name=prefix + "ekf_step",
                                              jacobians=jacobians)
    order = ["ekf_step", "plant", "measurement", "rigid_signals"]
    units = ekf_units(sensors, prefix)
    if sqrt:
        units[prefix + "ekf_step"].pop("x_next", None)
    return codegen.generate([funcs[k] for k in order], out_dir, name=name, units=units)


def model_bundle(model, out_dir, *, name="casflex_model", functions=("forward",)):
    """Generate a bundle with functions of the model (default its forward dynamics).

    The model's graph is large (the forward dynamics of the Table 8 arm with three modes
    has ~67 000 SX operations): compile it with ``-O1``/``-O0`` when build time matters.

    Parameters
    ----------
    model : casflex.dynamics.FlexibleModel
    out_dir : str or pathlib.Path
    name : str
        Bundle name.
    functions : sequence of str
        Keys of :meth:`casflex.dynamics.FlexibleModel.functions` to generate (``"ode"``,
        ``"mass"``, ...); units are written for ``"forward"``.

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
    >>> from casflex.dynamics import FlexibleModel, rigid_provider
    >>> robot = load("problems/arm2link.toml")
    >>> m = FlexibleModel(robot, rigid_provider(robot), gravity=None)
    >>> model_bundle(m, tempfile.mkdtemp()).functions[0].inputs[4].name
    'tau'
    """
    f = model.functions()
    units = {"forward": {"q": "rad", "dq": "rad/s", "delta": "sqrt(kg) m",
                         "ddelta": "sqrt(kg) m/s", "tau": "N m", "ddq": "rad/s^2",
                         "dddelta": "sqrt(kg) m/s^2"}}
    chosen = []
    for key in functions:
        if key not in f:
            raise ModelError(f"the model has no function {key!r}; it has {sorted(f)}")
        chosen.append(f[key])
    return codegen.generate(chosen, out_dir, name=name,
                            units={k: v for k, v in units.items() if k in functions})


_RUN_C = r"""/* Long EKF run generated by casflex.rtcode.covariance_run: cycles a recorded data set,
   feeds x and the covariance back, checks the covariance after every step. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "%(header)s"

#define NX %(nx)d
#define NU %(nu)d
#define NY %(ny)d
#define NF %(nf)d

static casadi_real u_data[%(k)d][NU], y_data[%(k)d][NY], m_data[%(k)d][NY];
static casadi_real x[NX], P[NX * NX], f[NF + 1], xn[NX], Pn[NX * NX], xp[NX], fn[NF + 1];
static casadi_real L[NX * NX];
static const casadi_real* arg[%(fn)s_SZ_ARG > 0 ? %(fn)s_SZ_ARG : 1];
static casadi_real* res[%(fn)s_SZ_RES > 0 ? %(fn)s_SZ_RES : 1];
static casadi_int iw[%(fn)s_SZ_IW > 0 ? %(fn)s_SZ_IW : 1];
static casadi_real w[%(fn)s_SZ_W > 0 ? %(fn)s_SZ_W : 1];

static double now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return 1e9 * (double)ts.tv_sec + (double)ts.tv_nsec;
}

/* the covariance P = S S^T for the square-root form */
static void covariance(const casadi_real* C, casadi_real* out) {
  int i, j, k;
  if (!%(sqrt)d) { for (i = 0; i < NX * NX; ++i) out[i] = C[i]; return; }
  for (i = 0; i < NX; ++i) for (j = 0; j < NX; ++j) {
    double s = 0;
    for (k = 0; k < NX; ++k) s += C[i + NX * k] * C[j + NX * k];
    out[i + NX * j] = s;
  }
}

int main(int argc, char** argv) {
  long long steps, s, k, nbad = 0, nnan = 0;
  int i, j, kk;
  double max_asym = 0, min_pivot = 1e300, max_diag = 0, min_diag = 1e300, t0, t1;
  casadi_real Pc[NX * NX];
  FILE* in;
  if (argc < 3) { fprintf(stderr, "usage: %%s data.txt steps\n", argv[0]); return 2; }
  in = fopen(argv[1], "r");
  if (!in) { fprintf(stderr, "cannot open %%s\n", argv[1]); return 2; }
  steps = atoll(argv[2]);
  for (i = 0; i < NX; ++i) if (fscanf(in, "%%lf", &x[i]) != 1) return 3;
  for (i = 0; i < NX * NX; ++i) if (fscanf(in, "%%lf", &P[i]) != 1) return 3;
  for (i = 0; i < NF; ++i) if (fscanf(in, "%%lf", &f[i]) != 1) return 3;
  for (k = 0; k < %(k)d; ++k) {
    for (i = 0; i < NU; ++i) if (fscanf(in, "%%lf", &u_data[k][i]) != 1) return 3;
    for (i = 0; i < NY; ++i) if (fscanf(in, "%%lf", &y_data[k][i]) != 1) return 3;
    for (i = 0; i < NY; ++i) if (fscanf(in, "%%lf", &m_data[k][i]) != 1) return 3;
  }
  fclose(in);
  t0 = now_ns();
  for (s = 0; s < steps; ++s) {
    k = s %% %(k)d;
    arg[0] = x; arg[1] = P; arg[2] = u_data[k]; arg[3] = y_data[k]; arg[4] = m_data[k];
    arg[5] = f;
    res[0] = xn; res[1] = Pn; res[2] = xp; res[3] = fn;
    if (%(fn)s(arg, res, iw, w, 0)) return 4;
    for (i = 0; i < NX; ++i) x[i] = xn[i];
    for (i = 0; i < NX * NX; ++i) P[i] = Pn[i];
    for (i = 0; i < NF; ++i) f[i] = fn[i];
    covariance(P, Pc);
    /* checks: finite, symmetric, Cholesky pivots > 0 */
    for (i = 0; i < NX * NX; ++i) if (!isfinite(Pc[i])) { ++nnan; break; }
    for (i = 0; i < NX; ++i) {
      double d = Pc[i + NX * i];
      if (d > max_diag) max_diag = d;
      if (d < min_diag) min_diag = d;
      for (j = 0; j < i; ++j) {
        double a = fabs(Pc[i + NX * j] - Pc[j + NX * i])
                   / sqrt(fabs(Pc[i + NX * i] * Pc[j + NX * j]) + 1e-300);
        if (a > max_asym) max_asym = a;
      }
    }
    for (j = 0; j < NX; ++j) {
      double d = Pc[j + NX * j];
      for (kk = 0; kk < j; ++kk) d -= L[j + NX * kk] * L[j + NX * kk];
      if (d / (Pc[j + NX * j] + 1e-300) < min_pivot) min_pivot = d / (Pc[j + NX * j] + 1e-300);
      if (!(d > 0)) { ++nbad; break; }
      L[j + NX * j] = sqrt(d);
      for (i = j + 1; i < NX; ++i) {
        double t = Pc[i + NX * j];
        for (kk = 0; kk < j; ++kk) t -= L[i + NX * kk] * L[j + NX * kk];
        L[i + NX * j] = t / L[j + NX * j];
      }
    }
  }
  t1 = now_ns();
  printf("{\"steps\": %%lld, \"not_positive_definite\": %%lld, \"not_finite\": %%lld, "
         "\"max_rel_asymmetry\": %%.17g, \"min_rel_cholesky_pivot\": %%.17g, "
         "\"min_diag\": %%.17g, \"max_diag\": %%.17g, \"mean_step_ns\": %%.6g, "
         "\"x_final\": [", steps, nbad, nnan, max_asym, min_pivot, min_diag, max_diag,
         (t1 - t0) / (double)steps);
  for (i = 0; i < NX; ++i) printf("%%s%%.17g", i ? ", " : "", x[i]);
  printf("]}\n");
  return 0;
}
"""


def covariance_run(bundle, u, y, x0, P0, steps, *, mask=None, f0=None, function="ekf_step",
                   compiler=None, flags=("-O2",)):
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
    >>> from casflex.dynamics import FlexibleModel, PointwiseProvider
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
    src.write_text(_RUN_C % {"header": bundle.header.name, "nx": nx, "nu": nu, "ny": ny,
                             "nf": nf, "k": K, "fn": function, "sqrt": int(sqrt)})
    exe = bundle.out_dir / f"covrun_{function}"
    cc = codegen._compiler(compiler)
    codegen._run_compiler([*cc, *flags, "-I", str(bundle.out_dir), "-o", str(exe), str(src),
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
        raise codegen.BuildError(f"covariance_run: '{exe.name}' exited with status "
                                 f"{proc.returncode}: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout)
