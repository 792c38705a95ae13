"""Fidelity of the modal model on fast planar moves against a nonlinear beam model (issue 19).

The reference is the planar ANCF Euler–Bernoulli model of ``tests/reference_beam_dynamics.py``
(written without casflex) of the Table 8 arm, q1 held, gravity off, no damping, joints
prescribed along the same bang-bang paths as casflex's :func:`simulate_prescribed`
(``tests/fidelity_cases.py`` maps the arm and moves into the plane and defines the tip
deflection — tip minus rigid tip, in the plane — identically on both sides).

Tables printed (one per model variant): for every move, the peak tip deflection and the
residual (after the move), as signed differences from the reference in % of the
reference's value, and the worst gap ``max_t |d_model − d_ref|`` in % of the reference's
peak, also split into its components along the rigid link 2 and normal to it. ``--moves``
takes the names of ``MOVES`` and ``DIAGNOSTIC_MOVES`` of ``tests/fidelity_cases.py``.
The reference's own convergence (16 → 32 elements per link, 1 ms → 0.5 ms) is printed
first.

Usage::

    python benchmarks/bench_fidelity.py [--json] [--variants base,rates] [--modes 5,8]
        [--cache DIR] [--no-convergence]
    python benchmarks/bench_fidelity.py --cost [--jit] [--json]
    python benchmarks/bench_fidelity.py --spatial [--variants base,rates,rates_short]
        [--modes 5,8] [--store] [--no-convergence] [--stiffness 4] [--json]
    python benchmarks/bench_fidelity.py --spatial-static [--variants base,short]
        [--fields 0.5,4,8,12,16] [--json]
    python benchmarks/bench_fidelity.py --stiffening [--fields 0.5,4,8,12,16]
        [--modes 5,8] [--json]
    python benchmarks/bench_fidelity.py --stiffening-move3 [--modes 5] [--steps 25,50]
        [--json]

``--cost`` instead measures what the options cost (:func:`cost`): ``bench_model.py``'s
``simulate_move1_s`` (move 1, 5 modes, ``poly`` + ``jit``, median of warm calls), the
modal rows of RK4 and the EKF step, every variant alternated in one process, and the
CasADi instruction counts.

``--spatial`` instead compares Table 9 move 3 (q1 turns by −π in 2 s, q2 and q3 held)
with the 3-D geometrically exact beam reference of ``tests/reference_beam_3d.py``
(Exudyn, ``tests/fidelity_spatial.py``): the same three figures on the 3-D tip
deflection, and the reference's convergence (32 → 64 elements, 1 → 0.5 ms). Its
converged run is test data (``tests/data/reference_beam_3d``, keyed by the reference's
source); ``--store`` writes it there. ``--stiffness k`` runs both arms with E and G
times k (the same move, a k times smaller deflection; the reference is then computed
and cached in ``--cache``).

``--spatial-static`` instead loads the arm at q = 0 with a uniform static field across
the joints' plane (along y0: the swing's inertial load in static form, no velocity) and
compares the model's tip (5 modes; ``∂V/∂δ = 0`` with the field as its gravity) with the
3-D reference's (32 elements), per field strength: the tangential tip deflection and the
3-D gap in % of the reference's.

``--stiffening`` instead splits ``--spatial-static``'s excess into its parts (session 8):
the same static loads, the 3-D reference against casflex's model (5 modes,
``foreshortening``) alone and with the quartic terms of ``tests/exact_ritz.py`` added one
after the other (the inextensible beam's nonlinear curvature, the twist–bending term,
link 2's third-order rotation about the elbow), and against the exact-kinematics Ritz
model in the same TMM modes (``--modes``), with its field potential exact and truncated to
δ³ and δ²: tangential, radial and vertical tip parts in % of the reference's.

``--stiffening-move3`` runs the exact-kinematics Ritz model on Table 9 move 3 (only q1
turns; ``exact_ritz.turning_run``: RK4, 1 ms, ``--steps`` integration steps per link) and
compares it with the stored 3-D reference run like ``--spatial``.

Reference runs are cached as ``.npz`` in ``--cache`` (default: a folder in the system's
temporary directory), keyed by the reference's source, the move, the elements and step.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from fidelity_cases import (  # noqa: E402
    DIAGNOSTIC_MOVES,
    MOVES,
    casflex_run,
    compare,
    on_grid,
    reference_run,
)

VARIANTS = {
    "base": {},                                   # the default model
    "rates": {"shape_rates": True},               # + the ∂w/∂q q̇ δ velocity terms
    "fine_grid": {"step": np.radians(0.5)},       # table every 0.5° instead of 1.5°
    "rates_fine_grid": {"shape_rates": True, "step": np.radians(0.5)},
    "order0": {"delta_order": 0},                 # M(q) only (the dissertation's M)
    "short": {"foreshortening": True},            # + the beams' shortening, M_qq to δ²
    "rates_short": {"shape_rates": True, "foreshortening": True},  # both
}


def convergence(cache):
    rows = {}
    for name, move in MOVES.items():
        base = reference_run(move, 16, 1e-3, cache)
        peak = np.linalg.norm(base["d"], axis=1).max()
        row = {}
        for label, (ne, dt) in {"32_elements": (32, 1e-3), "dt_0.5ms": (16, 5e-4)}.items():
            other = reference_run(move, ne, dt, cache)
            gap = np.linalg.norm(on_grid(other, base["t"]) - base["d"], axis=1).max()
            row[label] = 100 * gap / peak
        rows[name] = row
    return rows


def cost(repeats=3, calls=1000, jit=False):
    """What the options cost, every variant in one process, timed calls alternated so that
    all see the same machine load:

    * with ``jit``: ``bench_model.py``'s ``simulate_move1_s`` (Table 9 move 1, 5 modes,
      ``poly`` with ``jit=True``, the library compiled once — minutes per variant; median
      of warm calls) with ``shape_rates`` off, on, and with ``foreshortening`` too;
    * the modal rows RK4 integrates (``dddelta``, CasADi's virtual machine): median time
      of ``calls`` evaluations, every variant, and the instruction counts;
    * the EKF step of an estimator like the design study's (3 modes, the two tip
      accelerometers, plant tabulated from each model on a 15° table — the grid changes
      the tabulation time, not the cost of a step): median time of ``calls`` evaluations
      and its instruction count.
    """
    import os

    from casflex.estimation import ekf_step_function, tabulate_plant
    from casflex.model import build_model
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.sensors import load_sensors
    from casflex.simulate import simulate_prescribed

    robot = load(ROOT / "problems" / "arm2link.toml")
    sensors = load_sensors(ROOT / "problems" / "sensors" / "arm2link_accel.toml", robot)
    move = load_move(ROOT / "problems/moves.toml:move1")
    variants = {"off": {}, "rates": {"shape_rates": True},
                "rates_short": {"shape_rates": True, "foreshortening": True}}
    out = {"loadavg_start": os.getloadavg()[0]}
    models, rows, ekf = {}, {}, {}
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as jit_cache:
        for label, options in variants.items():
            t0 = time.perf_counter()
            model, _ = build_model(robot, 5, gravity=None, **options)
            f = model.functions()
            models[label], rows[label] = model, f["dddelta"]
            out[label] = {"model_build_s": time.perf_counter() - t0,
                          "instructions": {k: int(f[k].n_instructions())
                                           for k in ("mass", "dddelta", "prescribed", "ode")}}
            print(f"cost: {label}: model built, tabulating the plant", file=sys.stderr,
                  flush=True)
            small, _ = build_model(robot, 3, step=np.radians(15.0), gravity=None,
                                   points=sensors.points, processes=1, **options)
            t0 = time.perf_counter()
            plant = tabulate_plant(small)
            out[label]["plant_build_s"] = time.perf_counter() - t0
            ekf[label] = ekf_step_function(plant, sensors, 5e-6, 1e-4, 1e-3)
            out[label]["ekf_step_instructions"] = int(ekf[label].n_instructions())
            if jit:
                t0 = time.perf_counter()
                simulate_prescribed(model, move, dt=1e-3, method="poly", jit=True,
                                    cache_dir=jit_cache)
                out[label]["jit_compile_call_s"] = time.perf_counter() - t0
            for key in ("warm_s", "dddelta_us", "ekf_step_us"):
                out[label][key] = []
        args = [(rng.uniform(-1, 1, 3), rng.uniform(-2, 2, 3), rng.uniform(-3, 3, 3),
                 rng.normal(0, 0.01, 5), rng.normal(0, 0.1, 5)) for _ in range(calls)]
        ny = sensors.n_outputs
        ekf_args = [(rng.normal(0, 0.01, 6), 1e-4 * np.eye(6),
                     np.r_[rng.uniform(-1, 1, 3), rng.uniform(-2, 2, 6)],
                     rng.normal(0, 0.1, ny), np.ones(ny)) for _ in range(calls)]
        for _ in range(repeats):
            for label in variants:
                if jit:
                    t0 = time.perf_counter()
                    simulate_prescribed(models[label], move, dt=1e-3, method="poly",
                                        jit=True, cache_dir=jit_cache)
                    out[label]["warm_s"].append(time.perf_counter() - t0)
                f = rows[label]
                t0 = time.perf_counter()
                for a in args:
                    f(*a)
                out[label]["dddelta_us"].append(1e6 * (time.perf_counter() - t0) / calls)
                g = ekf[label]
                t0 = time.perf_counter()
                for a in ekf_args:
                    g(*a)
                out[label]["ekf_step_us"].append(1e6 * (time.perf_counter() - t0) / calls)
    for label in variants:
        for key, med in (("warm_s", "simulate_move1_s"), ("dddelta_us", "dddelta_us_median"),
                         ("ekf_step_us", "ekf_step_us_median")):
            if out[label][key]:
                out[label][med] = float(np.median(out[label][key]))
    if jit:
        for label in ("rates", "rates_short"):
            out[f"ratio_simulate_move1_{label}_off"] = (out[label]["simulate_move1_s"]
                                                        / out["off"]["simulate_move1_s"])
    for label in ("rates", "rates_short"):
        out[f"ratio_dddelta_{label}_off"] = (out[label]["dddelta_us_median"]
                                             / out["off"]["dddelta_us_median"])
        out[f"ratio_ekf_step_{label}_off"] = (out[label]["ekf_step_us_median"]
                                              / out["off"]["ekf_step_us_median"])
    out["loadavg_end"] = os.getloadavg()[0]
    return out


def _scaled_robot_and_beam(factor):
    """The Table 8 arm and the reference's beam with E and G times ``factor``."""
    import dataclasses

    from reference_beam_3d import TABLE8

    from casflex.robot import loads

    text = (ROOT / "problems" / "arm2link.toml").read_text()
    if factor != 1.0:
        text = text.replace("E = 69.0e9", f"E = {69.0e9 * factor!r}").replace(
            "G = 26.9e9", f"G = {26.9e9 * factor!r}")
    beam = dataclasses.replace(TABLE8, E=TABLE8.E * factor, G=TABLE8.G * factor)
    return loads(text), beam


def _stiff_reference(move, beam, n_elements, dt, cache):
    """The reference run of an arm with scaled stiffness (its Newton tolerance above the
    round-off of the larger axial forces), cached like ``cached_run``."""
    from reference_beam_3d import SpatialArm, run_file

    path = Path(cache) / ("stiff-" + run_file(move, n_elements, dt, beams=(beam, beam)))
    if path.exists():
        with np.load(path) as z:
            return {"t": z["t"], "d": z["d"]}
    run = SpatialArm((beam, beam), n_elements).simulate(move, dt, newton_tol=1e-6)
    out = {"t": run["t"], "d": run["tip"] - run["tip_rigid"]}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **out)
    return out


def spatial_static(args):
    """The arm at q = 0 under a uniform field across the joints' plane (along y0), static:
    the model's tip (5 modes, ``foreshortening``: potential to δ²) against the 3-D
    reference's (32 elements), per field strength."""
    import casadi as ca
    from reference_beam_3d import SpatialArm

    from casflex.model import build_model
    from casflex.robot import load

    robot = load(ROOT / "problems" / "arm2link.toml")
    rows = {}
    for variant in args.variants.split(","):
        model, _ = build_model(robot, n_modes=5, gravity=[0.0, 1.0, 0.0], processes=1,
                               **VARIANTS[variant])
        f = model.functions()
        q = np.zeros(model.n)
        delta = ca.SX.sym("delta", model.m)
        for accel in (float(a) for a in args.fields.split(",")):
            # ∂V_g/∂X is linear in the field: K δ + a g_δ(δ) = 0 (Newton)
            r = f["stiffness"](q) @ delta + accel * f["gravity"](q, delta)[model.n:]
            newton = ca.Function("newton", [delta], [r, ca.jacobian(r, delta)])
            x = np.zeros(model.m)
            for _ in range(30):
                res, jac = (v.full() for v in newton(x))
                x -= np.linalg.solve(jac, res.ravel())
            tip = (f["tip"](q, x) - f["tip"](q, np.zeros(model.m))).full().ravel()
            ref = SpatialArm(n_elements=32).static((0.0, 0.0, 0.0), (0.0, accel, 0.0))
            rows[f"{variant}_{accel:g}"] = row = {
                "field_m_s2": accel, "ref_tip_mm": 1e3 * ref["tip"], "tip_mm": 1e3 * tip,
                "tangential_pct": 100 * (tip[1] / ref["tip"][1] - 1),
                "gap_pct": 100 * np.linalg.norm(tip - ref["tip"])
                / np.linalg.norm(ref["tip"])}
            if not args.json:
                print(f"{variant:12s} {accel:5.1f} m/s²: reference tip "
                      f"{np.round(row['ref_tip_mm'], 2)} mm, model "
                      f"{np.round(row['tip_mm'], 2)} mm, across the plane "
                      f"{row['tangential_pct']:+.2f} %, 3-D gap {row['gap_pct']:.2f} %",
                      flush=True)
    if args.json:
        print(json.dumps(rows, default=lambda v: np.asarray(v).tolist()))


def _static_solve(rows, d, tip, n):
    """Newton on the modal rows ``rows(d) = 0``; the tip [m] at the solution."""
    import casadi as ca

    newton = ca.Function("newton", [d], [rows, ca.jacobian(rows, d), tip])
    x = np.zeros(n)
    for _ in range(50):
        r, J, _ = newton(x)
        if np.abs(r.full()).max() < 1e-13:
            break
        x -= np.linalg.solve(J.full(), r.full().ravel())
    else:
        raise RuntimeError("the static Newton did not converge")
    return newton(x)[2].full().ravel()


def stiffening(args):
    """The static excess across the plane split into its parts (``--stiffening``)."""
    import casadi as ca
    from exact_ritz import ExactRitz, quartic_terms
    from reference_beam_3d import SpatialArm

    from casflex.model import build_model
    from casflex.robot import load

    robot = load(ROOT / "problems" / "arm2link.toml")
    fields = [float(a) for a in args.fields.split(",")]
    t0 = time.perf_counter()
    refs = {a: SpatialArm(n_elements=32).static((0.0, 0.0, 0.0), (0.0, a, 0.0))["tip"]
            for a in fields}
    out = {"reference_s": time.perf_counter() - t0, "rows": {}}
    model, _ = build_model(robot, n_modes=5, gravity=[0.0, 1.0, 0.0], processes=1,
                           foreshortening=True)
    f, q0 = model.functions(), np.zeros(model.n)
    d = ca.SX.sym("delta", model.m)
    terms = quartic_terms(robot, d, [0.0, 1.0, 0.0])
    tip = f["tip"](q0, d) - f["tip"](q0, np.zeros(model.m))
    variants = {"casflex_short": lambda a: 0,
                "+curvature": lambda a: terms["curvature"],
                "+curvature+twist": lambda a: terms["curvature"] + terms["twist"],
                "+curvature+twist+rigid3": lambda a: (terms["curvature"] + terms["twist"]
                                                      + a * terms["rigid3"])}
    tips = {}
    for label, V4 in variants.items():
        for a in fields:
            extra = V4(a)
            rows = f["stiffness"](q0) @ d + a * f["gravity"](q0, d)[model.n:]
            if not isinstance(extra, int):
                rows = rows + ca.gradient(extra, d)
            tips[label, a] = _static_solve(rows, d, tip, model.m)
    for m in (int(k) for k in args.modes.split(",")):
        ritz = ExactRitz(robot, n_modes=m)
        for order in (None, 3, 2):
            for a in fields:
                tips[f"ritz_{m}modes_" + ("exact" if order is None else f"order{order}"),
                     a] = ritz.static([0.0, a, 0.0], load_order=order)["tip"]
    for (label, a), x in tips.items():
        ref = refs[a]
        out["rows"][f"{label}_{a:g}"] = row = {
            "field_m_s2": a, "ref_tip_mm": 1e3 * ref, "tip_mm": 1e3 * x,
            "tangential_pct": 100 * (x[1] / ref[1] - 1),
            "radial_pct": 100 * (x[0] / ref[0] - 1), "vertical_pct": 100 * (x[2] / ref[2] - 1),
            "gap_pct": 100 * np.linalg.norm(x - ref) / np.linalg.norm(ref)}
        if not args.json:
            print(f"{label:26s} {a:5.1f} m/s² (ref {1e3 * ref[1]:7.2f} mm across): across "
                  f"{row['tangential_pct']:+6.3f} %, radial {row['radial_pct']:+7.2f} %, "
                  f"vertical {row['vertical_pct']:+6.2f} %, 3-D gap {row['gap_pct']:.3f} %",
                  flush=True)
    if args.json:
        print(json.dumps(out, default=lambda v: np.asarray(v).tolist()))


def stiffening_move3(args):
    """Table 9 move 3: the exact-kinematics Ritz model against the stored 3-D reference."""
    from exact_ritz import turning_run
    from fidelity_spatial import MOVE3, compare, reference_run

    from casflex.robot import load

    robot = load(ROOT / "problems" / "arm2link.toml")
    ref, out = reference_run(), {}
    for m in (int(k) for k in args.modes.split(",")):
        for n in (int(k) for k in args.steps.split(",")):
            t0 = time.perf_counter()
            c = compare(turning_run(robot, MOVE3, n_modes=m, n_steps=n), ref, MOVE3.duration)
            out[f"ritz_{m}modes_{n}steps"] = c = {**c, "wall_s": time.perf_counter() - t0}
            if not args.json:
                print(f"move3 exact Ritz {m} modes, {n} steps per link: peak ref "
                      f"{c['peak_ref_mm']:.2f} mm, peak {c['peak_pct']:+.3f} %, residual "
                      f"{c['residual_pct']:+.3f} %, gap {c['gap_pct']:.3f} % (at "
                      f"{c['gap_at_s']:.2f} s), {c['wall_s']:.0f} s", flush=True)
    if args.json:
        print(json.dumps(out, default=float))


def spatial(args):
    """Table 9 move 3 against the 3-D reference: convergence and one table per variant."""
    from fidelity_spatial import DATA, MOVE3, REFERENCE
    from fidelity_spatial import casflex_run as casflex_run_3d
    from fidelity_spatial import compare as compare_3d
    from fidelity_spatial import on_grid as on_grid_3d
    from reference_beam_3d import cached_run, run_file

    from casflex.model import build_model

    ne, dt = REFERENCE["n_elements"], REFERENCE["dt"]
    robot, beam = _scaled_robot_and_beam(args.stiffness)
    if args.stiffness != 1.0:
        ref = _stiff_reference(MOVE3, beam, ne, dt, args.cache)
    else:
        stored = (DATA / run_file(MOVE3, ne, dt)).exists()
        ref = cached_run(MOVE3, ne, dt, cache=DATA if stored or args.store else args.cache)
    out = {"reference": {"elements": ne, "dt_s": dt, "stiffness": args.stiffness},
           "variants": {}}
    if not args.no_convergence and args.stiffness == 1.0:
        peak = np.linalg.norm(ref["d"], axis=1).max()
        rows = {}
        for label, (n, step) in {"elements_x2": (2 * ne, dt),
                                 "elements_half": (ne // 2, dt),
                                 "dt_half": (ne, 0.5 * dt)}.items():
            other = cached_run(MOVE3, n, step, cache=args.cache)
            gap = np.linalg.norm(on_grid_3d(other, ref["t"]) - ref["d"], axis=1).max()
            rows[label] = 100 * gap / peak
        out["reference_convergence_gap_pct"] = rows
    for variant in args.variants.split(","):
        for m in (int(k) for k in args.modes.split(",")):
            t0 = time.perf_counter()
            model, _ = build_model(robot, n_modes=m, gravity=None, processes=1,
                                   **VARIANTS[variant])
            c = compare_3d(casflex_run_3d(model, MOVE3), ref, MOVE3.duration)
            out["variants"][f"{variant}_{m}modes"] = {**c, "wall_s": time.perf_counter() - t0}
            if not args.json:
                print(f"move3 {variant:12s} {m} modes: peak ref {c['peak_ref_mm']:.2f} mm, "
                      f"peak {c['peak_pct']:+.2f} %, residual {c['residual_pct']:+.2f} %, "
                      f"gap {c['gap_pct']:.2f} % (at {c['gap_at_s']:.2f} s)", flush=True)
    if args.json:
        print(json.dumps(out, default=float))
    elif "reference_convergence_gap_pct" in out:
        print("\nreference convergence, gap in % of peak:",
              out["reference_convergence_gap_pct"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--variants", default="base,rates")
    parser.add_argument("--modes", default="5,8")
    parser.add_argument("--moves", default=",".join(MOVES))
    parser.add_argument("--cache", default=str(Path(tempfile.gettempdir())
                                               / "casflex_fidelity_reference"))
    parser.add_argument("--no-convergence", action="store_true")
    parser.add_argument("--cost", action="store_true",
                        help="only the cost of the options (off, shape_rates, both)")
    parser.add_argument("--jit", action="store_true",
                        help="with --cost: also move 1 with poly + jit (compiles twice)")
    parser.add_argument("--spatial", action="store_true",
                        help="Table 9 move 3 against the 3-D beam reference (Exudyn)")
    parser.add_argument("--store", action="store_true",
                        help="with --spatial: store the converged reference run as test "
                             "data (tests/data/reference_beam_3d)")
    parser.add_argument("--stiffness", type=float, default=1.0,
                        help="with --spatial: E and G of both arms times this factor")
    parser.add_argument("--spatial-static", action="store_true",
                        help="the arm at q = 0 under a static field across the joints' "
                             "plane, against the 3-D reference")
    parser.add_argument("--fields", default="0.5,4,8,12,16",
                        help="with --spatial-static, --stiffening: field strengths [m/s^2]")
    parser.add_argument("--stiffening", action="store_true",
                        help="the static excess split into its parts: casflex + quartic "
                             "terms, an exact-kinematics Ritz model (tests/exact_ritz.py)")
    parser.add_argument("--stiffening-move3", action="store_true",
                        help="Table 9 move 3 with the exact-kinematics Ritz model")
    parser.add_argument("--steps", default="25,50",
                        help="with --stiffening-move3: integration steps per link")
    args = parser.parse_args(argv)
    if args.stiffening_move3:
        stiffening_move3(args)
        return
    if args.stiffening:
        stiffening(args)
        return
    if args.spatial_static:
        spatial_static(args)
        return
    if args.spatial:
        spatial(args)
        return
    if args.cost:
        print(json.dumps(cost(jit=args.jit), default=float,
                         indent=None if args.json else 1))
        return

    from casflex.model import build_model
    from casflex.robot import load

    robot = load(ROOT / "problems" / "arm2link.toml")
    known = {**MOVES, **DIAGNOSTIC_MOVES}
    moves = [known[k] for k in args.moves.split(",")]
    out = {"reference": {"elements": 16, "dt_s": 1e-3}, "variants": {}}
    if not args.no_convergence:
        out["reference_convergence_gap_pct"] = convergence(args.cache)
    for variant in args.variants.split(","):
        for m in (int(k) for k in args.modes.split(",")):
            t0 = time.perf_counter()
            model, _ = build_model(robot, n_modes=m, gravity=None, processes=1,
                                   **VARIANTS[variant])
            rows = {}
            for move in moves:
                ref = reference_run(move, 16, 1e-3, args.cache)
                rows[move.name] = compare(casflex_run(model, move), ref, move.duration, move)
            out["variants"][f"{variant}_{m}modes"] = {
                "options": {k: float(v) if isinstance(v, float) else v
                            for k, v in VARIANTS[variant].items()},
                "wall_s": time.perf_counter() - t0, "moves": rows}
            if not args.json:
                print(f"\n{variant}, {m} modes")
                print(f"{'move':12s} {'peak ref mm':>11s} {'peak %':>7s} {'resid %':>8s} "
                      f"{'gap %':>6s} {'along':>6s} {'normal':>6s}")
                for name, c in rows.items():
                    print(f"{name:12s} {c['peak_ref_mm']:11.2f} {c['peak_pct']:+7.2f} "
                          f"{c['residual_pct']:+8.2f} {c['gap_pct']:6.2f} "
                          f"{c['gap_along_pct']:6.2f} "
                          f"{c['gap_normal_pct']:6.2f}", flush=True)
    if args.json:
        print(json.dumps(out, default=float))
    elif "reference_convergence_gap_pct" in out:
        print("\nreference convergence, gap in % of peak:",
              out["reference_convergence_gap_pct"])


if __name__ == "__main__":
    main()
