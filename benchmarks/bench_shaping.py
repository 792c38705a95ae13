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

Issue 14 figures:

``si_design_ei_start_s`` / ``si_design_cpu_s`` / ``si_design_ei_start_cpu_s``
    the design from the convolved EI start (the dissertation's algorithm) next to the
    default grid-LP start, wall and CPU (``time.process_time``) medians;
``lp_gap``
    optimality gap of the design: duration / grid-LP lower bound - 1;
``digital_1khz_duration``
    duration of the digital shaper on a 1 kHz loop's sample grid, s;
``closed_form_us``
    one damped EI shaper (ζ = 0.05, ``ei(2π, 0.05, 0.05)``: the Chebyshev fit), µs
    (median; ``closed_form_cpu_us`` its CPU time); ``closed_form_ei2_us`` /
    ``closed_form_ei3_us`` the two- and three-hump EI;
    ``closed_form_solve_us`` the same EI from the exact numerical solve (the old path,
    ``ei_family_normalised("ei", 0.05, 0.05, method="solve")``);
``family``
    duration (periods) and the contiguous ≤ 5 % band (relative frequency) of ZV, ZVD, MZV,
    EI, two- and three-hump EI, UM-ZV and SNA-ZV (N = 0.5), undamped.

``--many`` adds ``many_ranges_10_s`` / ``many_ranges_10_cpu_s``: the design of ten ±5 %
ranges at 1 Hz · 1.37^k, wall and CPU (single run), with its duration and ``lp_gap``.

Usage::

    python benchmarks/bench_shaping.py [--json] [--repeat N] [--many]

Timings are medians of ``--repeat`` repetitions (default 7).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time

import numpy as np

from casflex.shaping import (
    FrequencyRange,
    ei,
    ei_family_normalised,
    ei_three_hump,
    ei_two_hump,
    mzv,
    residual_vibration,
    si_shaper,
    sna_zv,
    solve_si_nlp,
    um_ei,
    um_zv,
    um_zvd,
    zv,
    zvd,
)

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


def _cpu_median(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return statistics.median(times)


def family_table():
    """Duration in periods and the ≤ 5 % band around the design frequency, undamped."""
    nu = np.linspace(0.2, 1.8, 160001)
    out = {}
    for name, fun in [("ZV", zv), ("ZVD", zvd), ("MZV", mzv),
                      ("EI", lambda w: ei(w, 0.0, 0.05)),
                      ("EI2", lambda w: ei_two_hump(w, 0.0, 0.05)),
                      ("EI3", lambda w: ei_three_hump(w, 0.0, 0.05)), ("UM-ZV", um_zv),
                      ("UM-ZVD", um_zvd), ("UM-EI", lambda w: um_ei(w, 0.0, 0.05)),
                      ("SNA-ZV", lambda w: sna_zv(w, 0.0, 0.5))]:
        s = fun(HZ)
        v = residual_vibration(s, nu * HZ)
        lo = hi = int(np.argmin(np.abs(nu - 1.0)))
        while lo > 0 and v[lo - 1] <= 0.05:
            lo -= 1
        while hi < nu.size - 1 and v[hi + 1] <= 0.05:
            hi += 1
        out[name] = {"periods": s.duration, "band": [nu[lo] - 1.0, nu[hi] - 1.0]}
    return out


def many_ranges(n):
    return [FrequencyRange(0.95 * f * HZ, 1.05 * f * HZ, 0.0, 0.05)
            for f in (1.37**k for k in range(n))]


def run(repeat=7, many=False):
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
    ei_design_s, _ = _median_time(lambda: si_shaper(RANGES, start="ei"), repeat)
    design_cpu_s = _cpu_median(lambda: si_shaper(RANGES), repeat)
    ei_design_cpu_s = _cpu_median(lambda: si_shaper(RANGES, start="ei"), repeat)
    digital = si_shaper(RANGES, dt=1e-3)
    ei(HZ, 0.05, 0.05)
    closed = {}
    for key, fn in (("closed_form_us", ei), ("closed_form_ei2_us", ei_two_hump),
                    ("closed_form_ei3_us", ei_three_hump)):
        # one call is microseconds: time batches of 200 calls
        per_call, _ = _median_time(lambda fn=fn: [fn(HZ, 0.05, 0.05) for _ in range(200)],
                                   repeat)
        closed[key] = 1e6 * per_call / 200
    closed["closed_form_cpu_us"] = 1e6 * _cpu_median(
        lambda: [ei(HZ, 0.05, 0.05) for _ in range(200)], repeat) / 200
    solve_s, _ = _median_time(lambda: ei_family_normalised("ei", 0.05, 0.05, "solve"), repeat)
    closed["closed_form_solve_us"] = 1e6 * solve_s
    extra = {}
    if many:
        t0, c0 = time.perf_counter(), time.process_time()
        res10 = si_shaper(many_ranges(10))
        extra = {"many_ranges_10_s": time.perf_counter() - t0,
                 "many_ranges_10_cpu_s": time.process_time() - c0,
                 "many_ranges_10_duration": res10.duration,
                 "many_ranges_10_lp_gap": res10.lp_gap,
                 "many_ranges_10_start": res10.start}
    return {
        **extra,
        "si_design_ei_start_s": ei_design_s,
        "si_design_cpu_s": design_cpu_s,
        "si_design_ei_start_cpu_s": ei_design_cpu_s,
        "lp_gap": res.lp_gap,
        "lp_duration": res.lp_duration,
        "lp_lower_bound": res.lp_lower_bound,
        "digital_1khz_duration": digital.duration,
        "digital_1khz_impulses": len(digital.shaper),
        **closed,
        "family": family_table(),
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
    parser.add_argument("--many", action="store_true", help="also time ten ranges (slow)")
    args = parser.parse_args(argv)
    out = run(args.repeat, args.many)
    if args.json:
        sys.stdout.write(json.dumps(out) + "\n")
        return 0
    print(f"SI shaper benchmark, three-range example (median of {out['repeat']})")
    rows = [
        ("whole SI design (all solves, pruning, verification)", out["si_design_s"], "<= 1 s"),
        ("  its CPU time", out["si_design_cpu_s"], ""),
        ("the same from the convolved-EI start", out["si_design_ei_start_s"], ""),
        ("  its CPU time", out["si_design_ei_start_cpu_s"], ""),
        ("one damped EI shaper (closed_form_us, in ms here)", 1e-6 * out["closed_form_us"],
         "<= 50 us"),
        ("  two-hump EI (fit)", 1e-6 * out["closed_form_ei2_us"], "<= 50 us"),
        ("  three-hump EI (fit)", 1e-6 * out["closed_form_ei3_us"], "<= 50 us"),
        ("  EI by the exact solve (the old path)", 1e-6 * out["closed_form_solve_us"], ""),
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
    print(f"  grid LP: optimum {out['lp_duration']:.6f} s, lower bound "
          f"{out['lp_lower_bound']:.6f} s, gap {100 * out['lp_gap']:.2f} %; 1 kHz digital "
          f"shaper {out['digital_1khz_duration']:.6f} s ({out['digital_1khz_impulses']} "
          "impulses)")
    for name, row in out["family"].items():
        lo, hi = row["band"]
        print(f"  {name:<6s} {row['periods']:.3f} periods, <= 5 % on {100 * lo:+.1f} .. "
              f"{100 * hi:+.1f} %")
    if "many_ranges_10_s" in out:
        print(f"  ten ranges: {out['many_ranges_10_s']:.1f} s wall, "
              f"{out['many_ranges_10_cpu_s']:.1f} s CPU, gap "
              f"{100 * out['many_ranges_10_lp_gap']:.2f} %, duration "
              f"{out['many_ranges_10_duration']:.4f} s ({out['many_ranges_10_start']} start)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
