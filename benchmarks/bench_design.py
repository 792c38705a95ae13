"""Benchmark of the design job's second run (issue 17, target 4).

``casflex design problems/studies/arm2link_move1.toml --out DIR`` run once to fill the
caches and ``DIR`` (its C bundle is then reused), then again ``--repeat`` times, each in a
fresh process (the user's command). With ``--code DIR`` (another checkout of casflex, for
instance main before a change), its runs alternate with this checkout's, on their own
output directories and the same cache, so that both see the same machine load.

Keys of ``--json`` (per checkout, ``new`` and with ``--code`` also ``old``; one value per
run):

``wall_s``
    wall time of the process [s] (interpreter start to exit).
``cpu_s``
    CPU time [s] of the process, ``main`` (the job itself) and ``workers`` (its child
    processes: the figures' workers, a compiler).
``timings_s``
    the job's ``summary.json`` ``timings_s`` of each run (stage wall times [s]).
``load``
    the 1-minute load average before each run.

and, for the whole run, ``nproc``, ``bytecode`` and ``stage_clock`` (what ``timings_s``
measures: ``"wall"``, or CPU with ``--stage-cpu``/``--stage-cpu-pool``).

With ``--bytecode`` the runs compile casflex's modules to bytecode once and read it back
(``PYTHONPYCACHEPREFIX`` in the temporary directory, ``PYTHONDONTWRITEBYTECODE`` unset), as
a user's second run does; without it they inherit the environment (this machine's sets
``PYTHONDONTWRITEBYTECODE``: every run compiles the ~100 casflex modules it imports again,
0.3-0.6 s of CPU in the job's process).

With ``--stage-cpu`` every run is ``--processes 1`` (figures drawn in the job's process)
and ``timings_s`` holds the CPU seconds of each stage instead of its wall time (the job's
stage clock, ``time.perf_counter``, replaced by the process's CPU clock): the figure that
holds when the machine is loaded. ``--stage-cpu-pool`` is the same clock with the job's
two worker processes as a user runs it: each stage's CPU of the job's own process (a
wait for the workers costs none), what the stage's wall time would be on two free cores
if the job never waited for them.

Usage::

    python benchmarks/bench_design.py [--json] [--repeat 3] [--code DIR] [--study FILE]
                                      [--stage-cpu | --stage-cpu-pool] [--bytecode]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"

#: the CLI in a fresh process, reporting its own and its children's CPU on stderr's last
#: line (the job's JSON summary on stdout)
RUNNER = """
import json, resource, sys, time
if sys.argv[1] == "--stage-cpu":  # the stages' clock: this process's CPU time
    time.perf_counter = time.process_time
    del sys.argv[1]
from casflex.cli import main
code = main(sys.argv[1:])
own, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF,
                                              resource.RUSAGE_CHILDREN))
print(json.dumps({"main": own.ru_utime + own.ru_stime,
                  "workers": kids.ru_utime + kids.ru_stime}), file=sys.stderr)
sys.exit(code)
"""


def run_once(code_root, study, out, stage_cpu=False, pycache=None, pool=False):
    """One ``casflex design`` process on ``code_root``'s casflex: wall, CPU, timings
    (``stage_cpu``: the stages' CPU seconds, in one process or, with ``pool``, the job's
    own beside its workers; ``pycache``: the bytecode written to and read from that
    directory)."""
    env = dict(os.environ, PYTHONPATH=str(code_root), MPLBACKEND="Agg")
    if pycache is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(pycache)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    flags = ["--stage-cpu"] if stage_cpu else []
    extra = ["--processes", "1"] if stage_cpu and not pool else []
    proc = subprocess.run([sys.executable, "-c", RUNNER, *flags, "design", str(study),
                           "--out", str(out), "--json", *extra], env=env,
                          capture_output=True, text=True, cwd=code_root)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"design failed ({code_root}):\n{proc.stderr[-2000:]}")
    cpu = json.loads(proc.stderr.strip().splitlines()[-1])
    return {"wall_s": wall, "cpu_s": cpu, "timings_s": json.loads(proc.stdout)["timings_s"],
            "load": load}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=3, help="second runs per checkout")
    parser.add_argument("--code", type=Path, help="another checkout, measured alternately")
    parser.add_argument("--study", type=Path, default=STUDY)
    clock = parser.add_mutually_exclusive_group()
    clock.add_argument("--stage-cpu", action="store_true",
                       help="one process per run; timings_s in CPU seconds per stage")
    clock.add_argument("--stage-cpu-pool", action="store_true",
                       help="timings_s in CPU seconds of the job's process per stage, "
                            "its workers as usual")
    parser.add_argument("--bytecode", action="store_true",
                        help="compiled bytecode kept between runs (as a user's install)")
    args = parser.parse_args(argv)

    stage_cpu = args.stage_cpu or args.stage_cpu_pool
    trees = {"new": ROOT}
    if args.code is not None:
        trees = {"old": args.code.resolve(), "new": ROOT}
    result = {key: {"wall_s": [], "cpu_s": [], "timings_s": [], "load": []}
              for key in trees}
    with tempfile.TemporaryDirectory() as tmp:
        def pycache(key):  # one per checkout: their sources differ
            return Path(tmp) / f"pycache-{key}" if args.bytecode else None

        for key, root in trees.items():  # the first runs: caches and output filled
            run_once(root, args.study.resolve(), Path(tmp) / key, stage_cpu,
                     pycache(key), args.stage_cpu_pool)
        for _ in range(args.repeat):
            for key, root in trees.items():
                run = run_once(root, args.study.resolve(), Path(tmp) / key, stage_cpu,
                               pycache(key), args.stage_cpu_pool)
                for name, value in run.items():
                    result[key][name].append(value)
    result["nproc"] = os.cpu_count()
    result["bytecode"] = args.bytecode
    result["stage_clock"] = ("cpu, one process" if args.stage_cpu else
                             "cpu of the job's process" if args.stage_cpu_pool else "wall")
    if args.json:
        print(json.dumps(result))
    else:
        for key in trees:
            r = result[key]
            print(f"{key}: wall {[round(v, 2) for v in r['wall_s']]} s, CPU main "
                  f"{[round(c['main'], 2) for c in r['cpu_s']]} s + workers "
                  f"{[round(c['workers'], 2) for c in r['cpu_s']]} s, load "
                  f"{[round(v, 1) for v in r['load']]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
