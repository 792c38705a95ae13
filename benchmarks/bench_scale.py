"""Benchmark of the tabulation's scaling in shape joints: uniform grid vs Chebyshev fit.

For each case, two ways to obtain the natural frequencies over the shape joints' box:

``grid``
    :func:`casflex.modal.build_table` at the default step of
    :func:`casflex.model.build.default_grid` (1.5° for one shape joint, 6° for more; inside
    the joint limits), ``quantities=False`` (ω and the shapes only), eigen basis, empty
    cache; the frequencies anywhere are the cubic B-spline of the tracked ω, sorted.
``fit``
    :func:`casflex.modal.fit_chebyshev` to the default target (1e-4 relative on ω),
    ``quantity="frequencies"``: the clusters' invariants of ω² from natural frequencies
    only; ``fit_stiffness`` (not run by default): the smooth-basis stiffness, frequencies
    = its eigenvalues.

``grid_terms``
    as ``grid`` with every model term (``quantities`` = the default
    :func:`casflex.modal.tables.default_quantities`: ``C1``, ``C2``, ``N``, ``eps``, end
    transforms, springs, sampled shapes), eigen basis for one shape joint, the smooth
    basis (:mod:`casflex.modal.rotated`) for more; held-out error of ω only (sorted
    spline of ω, or eigenvalues of the spline of ``K̃``).
``fit_terms``
    :func:`casflex.modal.fit_model_terms`: Chebyshev fits of every model term (targets
    1e-3 of each term's peak, 1e-4 on ω), the same basis rule; its held-out check
    against direct TMM covers every term in the eigen basis (``heldout_terms``: largest
    error relative to the term's peak) and, in the smooth basis, every entry of every term
    with ``--gauge reference`` (default; the basis is defined at any configuration) or the
    basis invariants with ``--gauge neighbour``. ``--refine worst`` doubles one axis per
    round (dimension-adaptive), ``--max-points`` caps the grid; ``axis_ratio`` reports
    each axis's estimate over its target, ``cpu_seconds`` the CPU of the process and its
    workers (``cpu_main_seconds``: the main process alone). ``--checkpoint DIR`` keeps
    the solved points in DIR (a file per 1024-point chunk): a run interrupted and started
    again resumes from them (``resumed_points``; ``checkpoint_mb`` its size on disk).

``tracking``
    the lowest neighbour MAC of the tracked modes with the eigen basis and with the smooth
    basis (:mod:`casflex.modal.subspace`), and the held-out error of each (eigen: sorted
    spline of ω; smooth: eigenvalues of the spline of the stiffness), at grid steps of
    30°, 15° and 6° (the default) inside the limits; not run by default
    (``--methods tracking``).

Reported per case and method: ``points`` (TMM solves), ``seconds`` (wall), ``rss_mb``
(peak resident memory of the process that holds the data; the workers' peak is
``rss_workers_mb``), ``cache_mb`` (the grid's on-disk cache; the fit keeps none),
``min_mac`` and ``heldout_max_rel`` (max over modes and configurations of
``|ω / ω_TMM − 1|`` at ``--heldout`` configurations drawn uniformly inside the limits,
seed 21), per mode in ``heldout_per_mode``.

Cases: ``arm2link`` (Table 8 arm, 1 shape joint, full turn, 4 modes: the lowest four
cross in pairs, one cluster), ``arm4_spatial`` (2 shape joints inside their limits,
4 modes: two clusters of two) and ``arm6_3flex`` (4 shape joints, 2 modes; fit only and
capped at degree 16 per axis; ``--max-degree 8`` for a 6 561-point run: its 6° grid has
4.9 million points; the fit to the target was not reached here, see README_scale.md).
Each (case, method) runs in a fresh subprocess so that its peak memory is its own.

Usage::

    python benchmarks/bench_scale.py [--json] [--cases arm2link arm4_spatial]
                                     [--methods grid fit] [--heldout N] [--processes P]
                                     [--max-degree D] [--refine worst]
                                     [--max-points N] [--checkpoint DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: case -> (robot file, modes, largest Chebyshev degree per axis, grid feasible, cluster
#: gap of the frequency fit: the Table 8 arm's modes 2 and 3 approach within 1.3 % without
#: meeting, and that fit takes clusters of two at most; the stiffness fit keeps 0.05)
CASES = {"arm2link": ("problems/arm2link.toml", 4, 64, True, 0.01),
         "arm4_spatial": ("problems/arm4_spatial.toml", 4, 64, True, 0.05),
         "arm6_3flex": ("problems/arm6_3flex.toml", 2, 16, False, 0.05)}


def _heldout_configurations(robot, count):
    rng = np.random.default_rng(21)
    qs = np.empty((count, robot.n_joints))
    for k, lim in enumerate(robot.joint_limits):
        lo, hi = lim if lim is not None else (-np.pi, np.pi)
        qs[:, k] = rng.uniform(lo, hi, count)
    return qs


def _dir_mb(path):
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file()) / 1e6


def _cpu_seconds():
    """CPU time of this process and its finished children [s] (user + system)."""
    own, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF,
                                                  resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_one(case, method, heldout, processes, max_degree_cap=None, fit_options=None):
    """One (case, method) in this process; returns the figures as a dict."""
    from casflex.modal import build_table, fit_chebyshev, shape_joints
    from casflex.model.build import default_grid
    from casflex.robot import load
    from casflex.tmm import natural_frequencies

    path, n_modes, max_degree, grid_ok, gap = CASES[case]
    if max_degree_cap is not None:
        max_degree = min(max_degree, int(max_degree_cap))
    if method == "grid" and not grid_ok:
        return {"case": case, "method": method, "skipped": "grid beyond MAX_GRID_POINTS"}
    robot = load(str(ROOT / path))
    joints = shape_joints(robot)
    qs = _heldout_configurations(robot, heldout)
    ref = np.array([natural_frequencies(robot, q, count=n_modes) for q in qs])
    out = {"case": case, "method": method, "shape_joints": [k + 1 for k in joints],
           "n_modes": n_modes}
    cpu0 = _cpu_seconds()
    with tempfile.TemporaryDirectory() as cache:
        t0 = time.perf_counter()
        if method == "tracking":
            return _tracking(out, robot, joints, n_modes, qs, ref, cache, processes)
        if method in ("grid_terms", "fit_terms"):
            got = _terms(out, method, robot, joints, n_modes, qs, cache, processes,
                         max_degree, fit_options or {})
            seconds = out.pop("seconds")
        elif method == "grid":
            grid = default_grid(robot, joints)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # low-MAC warning: reported
                table = build_table(robot, grid, n_modes, quantities=False, cache_dir=cache,
                                    processes=processes)
            seconds = time.perf_counter() - t0
            f = table.function("omega")
            got = np.array([np.sort(f(q[list(joints)]).full().ravel()) for q in qs])
            out.update(points=int(np.prod(table.shape)), grid_shape=list(table.shape),
                       min_mac=table.info["min_mac"], cache_mb=_dir_mb(cache))
        else:
            quantity = "stiffness" if method == "fit_stiffness" else "frequencies"
            fit = fit_chebyshev(robot, n_modes, processes=processes,
                                gap=gap if quantity == "frequencies" else 0.05,
                                start_degree=min(8, max_degree), max_degree=max_degree,
                                quantity=quantity)
            seconds = time.perf_counter() - t0
            got = np.array([fit.evaluate("omega", q[list(joints)]) for q in qs])
            if quantity == "stiffness":  # Rayleigh ω: the frequencies are K̃'s eigenvalues
                got = []
                for q in qs:
                    K = fit.evaluate("stiffness", q[list(joints)])
                    got.append(np.sqrt(np.clip(np.linalg.eigvalsh(K), 0.0, None)))
                got = np.array(got)
            out.update(points=fit.info["points"], degrees=list(fit.degrees),
                       estimate=fit.info["estimate"], converged=fit.info["converged"],
                       min_mac=fit.info["min_mac"], cache_mb=0.0)
    err = np.abs(got / ref - 1.0)
    main_cpu = resource.getrusage(resource.RUSAGE_SELF)
    out.update(seconds=seconds, cpu_seconds=_cpu_seconds() - cpu0,
               cpu_main_seconds=main_cpu.ru_utime + main_cpu.ru_stime, heldout=int(heldout),
               heldout_max_rel=float(err.max()),
               heldout_per_mode=err.max(axis=0).tolist(),
               rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
               rss_workers_mb=resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0)
    return out


def _terms(out, method, robot, joints, n_modes, qs, cache, processes, max_degree,
           fit_options):
    """Grid or fit of every model term; fills ``out`` and returns ω at ``qs`` (sorted)."""
    from casflex.modal import build_table, fit_model_terms
    from casflex.model.build import default_grid

    basis = "eigen" if len(joints) == 1 else "smooth"
    t0 = time.perf_counter()
    if method == "grid_terms":
        grid = default_grid(robot, joints)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # low-MAC warning: reported
            table = build_table(robot, grid if len(joints) > 1 else grid[0], n_modes,
                                cache_dir=cache, processes=processes, basis=basis)
        out["seconds"] = time.perf_counter() - t0
        f = table.function("omega" if basis == "eigen" else "stiffness")
        out.update(points=int(np.prod(table.shape)), grid_shape=list(table.shape),
                   min_mac=table.info["min_mac"], cache_mb=_dir_mb(cache), basis=basis,
                   values_mb=sum(v.nbytes for v in table.values.values()) / 1e6)
    else:
        fit = fit_model_terms(robot, n_modes, basis=basis, processes=processes,
                              start_degree=min(8, max_degree), max_degree=max_degree,
                              held_out=qs, **(fit_options if basis == "smooth" else {}))
        out["seconds"] = time.perf_counter() - t0
        out.update(points=fit.info["points"], degrees=list(fit.degrees), basis=basis,
                   estimate=fit.info["estimate"], converged=fit.info["converged"],
                   min_mac=fit.info["min_mac"], cache_mb=0.0,
                   heldout_terms=fit.info["held_out"], gauge=fit.info["gauge"],
                   axis_ratio=fit.info["axis_ratio"],
                   min_overlap=fit.info.get("min_overlap"),
                   resumed_points=fit.info.get("resumed_points"),
                   checkpoint_mb=(_dir_mb(fit_options["checkpoint"])
                                  if fit_options.get("checkpoint") else None),
                   values_mb=sum(c.nbytes for c in fit.coefficients.values()) / 1e6)

        def f(x, name="omega" if basis == "eigen" else "stiffness"):
            return np.atleast_1d(fit.evaluate(name, x))
    got = []
    for q in qs:
        v = f(q[list(joints)])
        v = v.full() if hasattr(v, "full") else np.asarray(v)
        got.append(np.sort(v.ravel()) if basis == "eigen"
                   else np.sqrt(np.clip(np.linalg.eigvalsh(0.5 * (v + v.T)), 0.0, None)))
    return np.array(got)


def _tracking(out, robot, joints, n_modes, qs, ref, cache, processes):
    from casflex.modal import build_table
    from casflex.model.build import default_grid

    rows = []
    for step in (30.0, 15.0, 6.0):
        grid = default_grid(robot, joints, np.radians(step))
        row = {"step_deg": step, "points": int(np.prod([a.size for a in grid]))}
        for basis in ("eigen", "smooth"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                table = build_table(robot, grid, n_modes, quantities=False, cache_dir=cache,
                                    processes=processes, basis=basis)
            if basis == "eigen":
                f = table.function("omega")
                got = [np.sort(f(q[list(joints)]).full().ravel()) for q in qs]
            else:
                f = table.function("stiffness")
                got = [np.sqrt(np.linalg.eigvalsh(f(q[list(joints)]).full())) for q in qs]
            row[f"min_mac_{basis}"] = table.info["min_mac"]
            row[f"heldout_max_rel_{basis}"] = float(np.max(np.abs(np.array(got) / ref - 1)))
        rows.append(row)
    out.update(tracking=rows)
    return out


def main(argv=None):
    """Run the cases in subprocesses and print a table or one JSON object."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--cases", nargs="+", default=["arm2link", "arm4_spatial"],
                    choices=list(CASES))
    ap.add_argument("--methods", nargs="+", default=["grid", "fit"],
                    choices=["grid", "fit", "fit_stiffness", "grid_terms", "fit_terms",
                             "tracking"])
    ap.add_argument("--heldout", type=int, default=12, help="held-out configurations")
    ap.add_argument("--processes", type=int, default=None, help="TMM worker processes")
    ap.add_argument("--max-degree", type=int, default=None,
                    help="cap the fits' degree per axis (reduced runs)")
    ap.add_argument("--gauge", choices=["neighbour", "reference"], default="reference",
                    help="smooth-basis gauge of fit_terms (two or more shape joints)")
    ap.add_argument("--reference-degree", type=int, default=4,
                    help="degree of the reference field (gauge 'reference')")
    ap.add_argument("--refine", choices=["all", "worst"], default="all",
                    help="fit_terms: double every axis over target, or the worst one")
    ap.add_argument("--max-points", type=int, default=None,
                    help="fit_terms: stop refining before a grid of more points")
    ap.add_argument("--checkpoint", default=None,
                    help="fit_terms: directory keeping the solved points (resumes from it)")
    ap.add_argument("--one", nargs=2, metavar=("CASE", "METHOD"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    fit_options = {"gauge": args.gauge, "reference_degree": args.reference_degree,
                   "refine": args.refine, "max_points": args.max_points,
                   "checkpoint": args.checkpoint}
    if args.one:
        print(json.dumps(run_one(args.one[0], args.one[1], args.heldout, args.processes,
                                 args.max_degree, fit_options)))
        return 0
    results = []
    load_before = os.getloadavg()
    for case in args.cases:
        for method in args.methods:
            cmd = [sys.executable, __file__, "--one", case, method,
                   "--heldout", str(args.heldout)]
            if args.processes is not None:
                cmd += ["--processes", str(args.processes)]
            if args.max_degree is not None:
                cmd += ["--max-degree", str(args.max_degree)]
            if args.max_points is not None:
                cmd += ["--max-points", str(args.max_points)]
            if args.checkpoint is not None:
                cmd += ["--checkpoint", args.checkpoint]
            cmd += ["--gauge", args.gauge, "--reference-degree", str(args.reference_degree),
                    "--refine", args.refine]
            done = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if done.returncode != 0:
                sys.stderr.write(done.stderr)
                return 1
            results.append(json.loads(done.stdout.strip().splitlines()[-1]))
            if not args.json and "tracking" in results[-1]:
                for r in results[-1]["tracking"]:
                    print(f"{case:13s} step {r['step_deg']:4.0f}° points {r['points']:5d}  "
                          f"min MAC eigen {r['min_mac_eigen']:.3f} smooth "
                          f"{r['min_mac_smooth']:.3f}  held-out eigen "
                          f"{r['heldout_max_rel_eigen']:.1e} smooth "
                          f"{r['heldout_max_rel_smooth']:.1e}", flush=True)
            elif not args.json and "skipped" not in results[-1]:
                r = results[-1]
                print(f"{case:13s} {method:10s} points {r['points']:6d}  "
                      f"{r['seconds']:7.1f} s  rss {r['rss_mb']:6.0f} MB  "
                      f"cache {r['cache_mb']:7.1f} MB  min MAC {r['min_mac']:.3f}  "
                      f"held-out max {r['heldout_max_rel']:.2e}", flush=True)
    report = {"results": results, "load_before": list(load_before),
              "load_after": list(os.getloadavg()), "cpus": os.cpu_count()}
    if args.json:
        print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
