"""Benchmark of the design job on the 4-joint spatial arm (issue 21): time, peak memory and
the stability verdict of ``casflex design`` on ``problems/studies/arm4_spatial_all_joints.toml``.

The job runs in a fresh subprocess (``python -m casflex.cli design``) on an empty cache
directory (cold: tables, schedule and EKF plant computed) and then again on the same cache
(warm), so that each run's peak resident memory is its own: ``rss_mb`` is the job's
process, ``rss_workers_mb`` its largest table worker (``resource.RUSAGE_CHILDREN`` of the
runner, which starts nothing else). ``--set SECTION.KEY=VALUE`` overrides study keys (e.g.
``--set model.grid_step=30``, ``--set codegen.compile=false``) in a copy of the study.

Reported per run: ``seconds`` (wall), ``rss_mb``, ``rss_workers_mb``, the job's own
``timings_s`` per step, ``stable``, every stability condition's verdict and value,
``closed_loop_finite``, ``tracking_error_max`` [rad] and ``residual_reduction``.

Usage::

    python benchmarks/bench_design_arm4.py [--json] [--processes P] [--warm]
                                           [--set model.grid_step=30 ...]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "problems" / "studies" / "arm4_spatial_all_joints.toml"


def study_copy(overrides, directory):
    """The study with ``SECTION.KEY=VALUE`` overrides, written to ``directory`` (its paths
    made absolute)."""
    lines = STUDY.read_text().replace('"../', f'"{STUDY.parent.parent}/').splitlines()
    for item in overrides:
        key, _, value = item.partition("=")
        section, _, name = key.partition(".")
        if f"[{section}]" not in lines:
            lines += ["", f"[{section}]"]
        start = lines.index(f"[{section}]")
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")),
                   len(lines))
        same = [i for i in range(start + 1, end) if lines[i].split("=")[0].strip() == name]
        if same:
            lines[same[0]] = f"{name} = {value}"
        else:
            lines.insert(start + 1, f"{name} = {value}")
    path = Path(directory) / "study.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def run_once(study, out, cache, processes):
    """One ``casflex design`` in a subprocess: wall time, peak memory and its summary."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "casflex.cli", "design", str(study), "--out", str(out),
           "--cache-dir", str(cache), "--json"]
    if processes:
        cmd += ["--processes", str(processes)]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    result = {"seconds": seconds, "rss_mb": peak / 1024.0,
              "rss_grew": peak > before, "returncode": proc.returncode}
    if proc.returncode != 0:
        result["error"] = proc.stderr.strip().splitlines()[-1:] or [""]
        return result
    summary = json.loads((Path(out) / "summary.json").read_text())
    stability = summary.get("stability", {})
    result.update(
        stable=summary["stable"], closed_loop_finite=summary["closed_loop_finite"],
        conditions={k: {"holds": v["holds"], "value": v["value"], "unit": v["unit"]}
                    for k, v in stability.get("conditions", {}).items()},
        tracking_error_max=summary["tracking_error_max"],
        residual_reduction=summary["residual_reduction"],
        timings_s=summary["timings_s"], table_from_cache=summary["table_from_cache"])
    return result


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--processes", type=int, default=2, help="table workers (default 2)")
    ap.add_argument("--warm", action="store_true", help="also run again on the warm cache")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a study key (repeatable)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        study = study_copy(args.set, tmp)
        runs = {"cold": run_once(study, tmp / "out", tmp / "cache", args.processes)}
        if args.warm:
            runs["warm"] = run_once(study, tmp / "out", tmp / "cache", args.processes)
    result = {"study": STUDY.name, "overrides": args.set, "processes": args.processes,
              "runs": runs}
    if args.json:
        print(json.dumps(result))
    else:
        for name, r in runs.items():
            print(f"{name}: {r['seconds']:.1f} s, peak {r['rss_mb']:.0f} MB, "
                  f"stable {r.get('stable')}, conditions "
                  + ", ".join(f"{k} {'holds' if v['holds'] else 'FAILS'} ({v['value']:.3g} "
                              f"{v['unit']})" for k, v in r.get("conditions", {}).items())
                  + (f"; error {r['error']}" if "error" in r else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
