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
    python benchmarks/bench_fidelity.py --cost [--json]

``--cost`` instead measures what ``shape_rates`` costs: ``bench_model.py``'s
``simulate_move1_s`` (move 1, 5 modes, ``poly`` + ``jit``, median of warm calls) off and
on, alternated in one process, and the CasADi instruction counts.

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


def cost(repeats=3):
    """``bench_model.py``'s ``simulate_move1_s`` (Table 9 move 1, 5 modes, ``poly`` with
    ``jit=True``, the library compiled once; median of warm calls) and the CasADi
    instruction counts, with ``shape_rates`` off and on in one process, warm calls
    alternated so that both see the same machine load."""
    import os

    from casflex.model import build_model
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.simulate import simulate_prescribed

    robot = load(ROOT / "problems" / "arm2link.toml")
    move = load_move(ROOT / "problems/moves.toml:move1")
    out = {"loadavg_start": os.getloadavg()[0]}
    models = {}
    with tempfile.TemporaryDirectory() as jit_cache:
        for label, rates in (("off", False), ("on", True)):
            t0 = time.perf_counter()
            model, _ = build_model(robot, 5, gravity=None, shape_rates=rates)
            f = model.functions()
            models[label] = model
            out[label] = {"model_build_s": time.perf_counter() - t0,
                          "instructions": {k: int(f[k].n_instructions())
                                           for k in ("mass", "dddelta", "prescribed", "ode")}}
            t0 = time.perf_counter()
            r = simulate_prescribed(model, move, dt=1e-3, method="poly", jit=True,
                                    cache_dir=jit_cache)
            out[label]["jit_compile_call_s"] = time.perf_counter() - t0
            out[label]["max_tip_deflection_m"] = r.max_tip_deflection
            out[label]["warm_s"] = []
        for _ in range(repeats):
            for label in ("off", "on"):
                t0 = time.perf_counter()
                simulate_prescribed(models[label], move, dt=1e-3, method="poly", jit=True,
                                    cache_dir=jit_cache)
                out[label]["warm_s"].append(time.perf_counter() - t0)
    for label in ("off", "on"):
        out[label]["simulate_move1_s"] = float(np.median(out[label]["warm_s"]))
    out["ratio_on_off"] = out["on"]["simulate_move1_s"] / out["off"]["simulate_move1_s"]
    out["ratio_per_repeat"] = [b / a for a, b in zip(out["off"]["warm_s"],
                                                     out["on"]["warm_s"], strict=True)]
    out["loadavg_end"] = os.getloadavg()[0]
    return out


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
                        help="only the cost of shape_rates (move 1, off vs on)")
    args = parser.parse_args(argv)
    if args.cost:
        print(json.dumps(cost(), default=float, indent=None if args.json else 1))
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
