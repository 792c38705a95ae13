"""Benchmark: what a ``poly`` form of ``kinematics="exact"`` would cost and how far it is off.

``--budget`` (the error budget of the degree in δ)
    The exact model's modal rows with every ``(q, δ)``-coefficient cut at degree ``p`` in
    δ (:func:`casflex.simulate.taylor_modal_rows`), simulated by the RK4 steps of
    ``method="rk4"`` (:func:`casflex.simulate.simulate_taylor`), against RK4 on the exact
    rows themselves (same model, same step), for ``p = 1, 2, 3``: Table 9 move 3 (q1 by
    π in 2 s, ``kinematics="exact"``) and the planar elbow move (q2 → −0.8, q3 → +1.2 rad
    in 1 s, ``kinematics="exact"`` with ``shape_rates=True``, the variant that meets the
    ANCF reference); 5 modes, the 1.5° table, gravity off, 3 s settle, RK4 at 5 ms (the
    step of the exact fidelity tests). Figures per move and degree: ``peak`` and
    ``residual`` (max |tip deflection| during / after the move, % difference from the
    exact run) and ``gap`` (max over time of |d_p − d_exact| in % of the exact peak);
    wall time of each run [s].
``--coefficients`` (the cost of configuration-only coefficients)
    SX instructions of the exact model's mass matrix ``M(q, δ)`` (upper triangle) and of
    its Taylor coefficients at δ = 0 of degree 1 and 2 in δ by nested CasADi Jacobians
    (what ``F(q)`` of :func:`casflex.simulate.poly.configuration_function` would hold),
    and the build time of each; 5 modes frozen at one configuration
    (``PointwiseProvider``, so that no table lookup is counted).

Usage::

    python benchmarks/bench_exact_poly.py [--budget] [--coefficients] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _figures(run, exact, t_move_end):
    d = np.linalg.norm(run["tip_deflection"], axis=1)
    e = np.linalg.norm(exact["tip_deflection"], axis=1)
    after = run["t"] > t_move_end
    peak, residual = np.abs(e).max(), np.abs(e[after]).max()
    return {"peak_pct": 100.0 * (np.abs(d).max() - peak) / peak,
            "residual_pct": 100.0 * (np.abs(d[after]).max() - residual) / residual,
            "gap_pct": 100.0 * float(np.abs(run["tip_deflection"]
                                            - exact["tip_deflection"]).max()) / peak,
            "exact_peak_m": float(peak), "exact_residual_m": float(residual),
            "delta_max": float(np.abs(exact["delta"]).max())}


def budget(degrees=(1, 2, 3), dt=5e-3):
    """Degree-p rows against the exact rows (module docstring)."""
    from casflex.model import build_model
    from casflex.moves import Move
    from casflex.robot import load
    from casflex.simulate import simulate_prescribed, simulate_taylor

    robot = load(ROOT / "problems/arm2link.toml")
    moves = {"move3": (Move(np.zeros(3), [-np.pi, 0.0, 0.0], 2.0, settle=3.0), {}),
             "elbow2_1s": (Move(np.zeros(3), [0.0, -0.8, 1.2], 1.0, settle=3.0),
                           {"shape_rates": True})}
    out = {}
    cache = os.environ.get("CASFLEX_CACHE") or tempfile.mkdtemp()
    for name, (move, options) in moves.items():
        model, _ = build_model(robot, 5, step=np.radians(1.5), cache_dir=cache,
                               gravity=None, kinematics="exact", progress=False, **options)
        t0 = time.perf_counter()
        ref = simulate_prescribed(model, move, dt=dt)
        exact = {"t": ref.t, "delta": ref.delta, "tip_deflection": ref.tip_deflection}
        out[f"{name}_exact_rk4_s"] = time.perf_counter() - t0
        for p in degrees:
            t0 = time.perf_counter()
            run = simulate_taylor(model, move, p, dt=dt)
            out[f"{name}_p{p}"] = {**_figures(run, exact, move.duration),
                                   "seconds": time.perf_counter() - t0,
                                   "integrate_s": run["wall_s"]}
            print(name, p, out[f"{name}_p{p}"], file=sys.stderr, flush=True)
    return out


def coefficients(orders=(1, 2)):
    """Instructions of nested-Jacobian Taylor coefficients of the exact M (docstring)."""
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load

    robot = load(ROOT / "problems/arm2link.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.1, 0.3, -0.8], count=5),
                          gravity=None, kinematics="exact")
    q, d = model.q, model.delta
    N = model.n + model.m
    iu = np.triu_indices(N)
    D = ca.vertcat(*[model.M[int(i), int(k)] for i, k in zip(*iu, strict=True)])
    out = {"mass_instructions": int(ca.Function("M", [q, d], [D]).n_instructions())}
    for k in orders:
        t0 = time.perf_counter()
        D = ca.vec(ca.jacobian(D, d))
        at_zero = ca.Function("D", [q, d], [D])(q, ca.DM.zeros(model.m))
        out[f"taylor_degree{k}_instructions"] = int(
            ca.Function("F", [q], [at_zero]).n_instructions())
        out[f"taylor_degree{k}_build_s"] = time.perf_counter() - t0
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", action="store_true", help="error of degree p in delta")
    parser.add_argument("--coefficients", action="store_true",
                        help="instructions of the Taylor coefficients of the exact M")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    result = {"loadavg_start": list(os.getloadavg())}
    if args.coefficients:
        result.update(coefficients())
    if args.budget:
        result.update(budget())
    result["loadavg_end"] = list(os.getloadavg())
    if args.json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:32s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
