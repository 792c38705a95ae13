"""Benchmark of the specified-insensitivity shaper design (casflex.shaping).

Measures, on the three-range example of dissertation §6.1.3 (3–4, 9–13, 20–24 Hz, ζ = 0,
Vtol = 5 %):

``si_design_s``
    the whole SI design: every Ipopt solve, prune-and-merge, dense-grid verification;
``si_solve_s``
    one Ipopt solve (problem build + solve) of the final formulation (final sample set)
    from the start point of the design's last solve;
``slsqp_solve_s``
    SciPy SLSQP on the identical formulation (same CasADi functions, same start);
``duration_ipopt`` / ``duration_slsqp``
    the shaper durations those two solves reach, s.

Also reported (single run, not medians): both solvers on the final formulation started
from the convolved-EI initial guess (``*_from_ei_*`` keys).

Usage::

    python benchmarks/bench_shaping.py [--json] [--repeat N]

Timings are medians of ``--repeat`` repetitions (default 7).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time

from casflex.shaping import FrequencyRange, si_shaper, solve_si_nlp

HZ = 2.0 * math.pi
RANGES = [
    FrequencyRange(3 * HZ, 4 * HZ, 0.0, 0.05),
    FrequencyRange(9 * HZ, 13 * HZ, 0.0, 0.05),
    FrequencyRange(20 * HZ, 24 * HZ, 0.0, 0.05),
]


def _median_time(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def run(repeat=7):
    """Run the benchmark and return the figures as a dict (s)."""
    si_shaper(RANGES)  # warm-up: loads the Ipopt plugin
    design_s, res = _median_time(lambda: si_shaper(RANGES), repeat)
    ipopt_s, ip = _median_time(lambda: solve_si_nlp(res.samples, res.final_guess, "ipopt"), repeat)
    slsqp_s, sq = _median_time(lambda: solve_si_nlp(res.samples, res.final_guess, "slsqp"), repeat)
    t0 = time.perf_counter()
    ip_ei = solve_si_nlp(res.samples, res.initial_guess, "ipopt")
    ip_ei_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    sq_ei = solve_si_nlp(res.samples, res.initial_guess, "slsqp")
    sq_ei_s = time.perf_counter() - t0
    return {
        "si_design_s": design_s,
        "si_solve_s": ipopt_s,
        "slsqp_solve_s": slsqp_s,
        "duration_ipopt": ip.shaper.duration,
        "duration_slsqp": sq.shaper.duration,
        "design_duration": res.duration,
        "design_nlp_solves": res.iterations,
        "n_impulses": len(res.shaper),
        "n_samples": len(res.samples),
        "ipopt_build_s": ip.build_time,
        "ipopt_solver_only_s": ip.solve_time,
        "ipopt_iterations": ip.iterations,
        "slsqp_build_s": sq.build_time,
        "slsqp_solver_only_s": sq.solve_time,
        "slsqp_iterations": sq.iterations,
        "si_solve_from_ei_s": ip_ei_s,
        "slsqp_solve_from_ei_s": sq_ei_s,
        "duration_ipopt_from_ei": ip_ei.shaper.duration,
        "duration_slsqp_from_ei": sq_ei.shaper.duration,
        "ipopt_iterations_from_ei": ip_ei.iterations,
        "slsqp_iterations_from_ei": sq_ei.iterations,
        "repeat": repeat,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=7, help="repetitions (median)")
    args = parser.parse_args(argv)
    out = run(args.repeat)
    if args.json:
        sys.stdout.write(json.dumps(out) + "\n")
        return 0
    print(f"SI shaper benchmark, three-range example (median of {out['repeat']})")
    rows = [
        ("whole SI design (all solves, pruning, verification)", out["si_design_s"], "<= 1 s"),
        ("one Ipopt solve of the final formulation", out["si_solve_s"], "<= 0.1 s"),
        ("  of which problem build", out["ipopt_build_s"], ""),
        ("one SLSQP solve, same formulation and start", out["slsqp_solve_s"], ""),
        ("Ipopt from the convolved-EI start (1 run)", out["si_solve_from_ei_s"], ""),
        ("SLSQP from the convolved-EI start (1 run)", out["slsqp_solve_from_ei_s"], ""),
    ]
    for name, val, target in rows:
        print(f"  {name:<55s} {1e3 * val:9.1f} ms  {target}")
    print(
        f"  shaper duration: design {out['design_duration']:.6f} s "
        f"({out['n_impulses']} impulses, {out['design_nlp_solves']} solves, "
        f"{out['n_samples']} samples)"
    )
    print(
        f"  final formulation: Ipopt {out['duration_ipopt']:.6f} s "
        f"({out['ipopt_iterations']} it), SLSQP {out['duration_slsqp']:.6f} s "
        f"({out['slsqp_iterations']} it)"
    )
    print(
        f"  from EI start: Ipopt {out['duration_ipopt_from_ei']:.6f} s "
        f"({out['ipopt_iterations_from_ei']} it), SLSQP {out['duration_slsqp_from_ei']:.6f} s "
        f"({out['slsqp_iterations_from_ei']} it)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
