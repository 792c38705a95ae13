"""Benchmark of the transfer-matrix modal analysis against a beam FE (issues 2 and 17).

* ``per_configuration_s``: median wall time of the first 5 natural frequencies and mode
  shapes (51 points per link) of the Table 8 arm at one configuration
  (``casflex.tmm.modes``), over 40 configurations spread along q3.
* ``frequencies_only_s``: the same for the 5 frequencies alone
  (``casflex.tmm.natural_frequencies``).
* ``sweep_s``: the q3 sweep at 1.5° over 360° (240 configurations, 5 frequencies each)
  with ``casflex.tmm.sweep_frequencies``, median of repeated runs; ``sweep_cpu_s`` its
  process CPU time (one call of ~0.1–1 s is preempted many times on a loaded machine: the
  CPU time is the steadier figure there).
* ``fe_equal_accuracy_s``: median wall time of the 3-D Euler–Bernoulli frame FE of
  ``tests/reference_fem.py`` (assembly, eigen-solution, mass-normalised shapes) at the
  smallest number of elements per link whose 5 frequencies are within 1e-4 (relative) of
  the TMM's on every configuration (``fe_elements_per_link``, ``fe_max_rel_error``); that
  the FE converges to the TMM's values is checked at 4× the elements
  (``fe_converged_rel_error``). Configurations where link 2 folds back onto link 1 are
  left out of the FE side (the FE merges coincident nodes).
* ``fe_eigensolve_s``: the FE's ``scipy.linalg.eigh`` alone on its assembled matrices
  (the 5 wanted eigenpairs of the ``M q = μ K q`` pencil, as ``reference_fem.modes``):
  the floor of any FE of that size, whatever its assembly.
* ``ratio_fe`` = FE time / TMM time with shapes (> 1: the TMM is faster);
  ``ratio_fe_frequencies`` the same for frequencies only.
* ``numpy_*``: the same TMM figures with the compiled kernels switched off
  (``casflex.tmm.kernels.AVAILABLE = False``, the numpy path), measured alternately with
  the compiled ones.

TMM and FE are timed alternately, configuration by configuration, so that both see the
same machine load; every figure is the fastest of ``--inner`` calls (5) of the same
configuration (or sweep), then the median over configurations (or sweep repetitions): on a
shared machine a call longer than a scheduler slice is often preempted, and the fastest of
a few calls is the estimate of its quiet time. ``load_average`` is the 1-minute load when
the run ended. ``--clock cpu`` times every call (TMM and FE alike) by the process's CPU
time instead of the wall clock (``clock`` in the JSON): on a loaded machine a call's wall
time includes the time other processes ran, its CPU time does not. ``--code DIR`` runs
the same script on the casflex package of another checkout (an older commit), to measure
old and new side by side. BLAS runs on one thread (``blas_threads``; the script sets
``OPENBLAS_NUM_THREADS=1`` unless it is set): the TMM runs on one, and the FE's
eigen-solution is no faster on two.

Targets (issue 17): ≤ 1 ms per configuration with shapes, ≤ 0.3 ms frequencies only,
sweep ≤ 0.2 s, ``ratio_fe`` ≥ 10.

Usage: ``python benchmarks/bench_tmm.py [--json] [--repeat N] [--inner N] [--clock wall|cpu]
[--code DIR]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

# The FE's LAPACK/BLAS on one thread, as the TMM runs (set before numpy loads OpenBLAS; an
# explicit OPENBLAS_NUM_THREADS wins). On its 96 × 96 pencil a second thread does not
# help (0.50 ms on one thread, 0.91 ms on two, wall and CPU alike), and on a loaded
# machine the waiting thread spins: the FE's CPU time then grew ~20-40× (fe_eigensolve_s
# 21 ms at load 10-15), which made ratio_fe > 100 there.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

import casflex  # noqa: E402
from casflex.robot import load  # noqa: E402
from casflex.tmm import build_chain, modes, natural_frequencies, sweep_frequencies  # noqa: E402

try:  # absent before the compiled kernels (to measure an older checkout side by side)
    from casflex.tmm import kernels
except ImportError:  # pragma: no cover
    kernels = None

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import reference_fem as fem  # noqa: E402  (the tests' independent FE model)

ACCURACY = 1e-4


def fe_segments(robot, q, n_elements):
    """The frame FE's segments at the chain's geometry, and the clamped point."""
    chain = build_chain(robot, q)
    segments = []
    for e in chain.beams:
        sec, mat = e.params["section"], e.params["material"]
        segments.append(fem.Segment(
            e.start, e.end, e.R[:, 0], E=mat.E, G=mat.G, rho=mat.rho, A=sec.A, Ix=sec.Ix,
            Iy=sec.Iy, J=sec.J, Ip=sec.Ip, n_elements=n_elements))
    return segments, chain.elements[0].start


def fe_modes(robot, q, n_elements, n_modes=5):
    """Frequencies [rad/s] and shapes of the frame FE at the chain's geometry."""
    segments, clamp = fe_segments(robot, q, n_elements)
    return fem.modes(segments, clamp=clamp, n_modes=n_modes)


def fe_eigensolve(matrices, n_modes=5):
    """The FE's eigen-solution alone (as in ``reference_fem.modes``): its floor."""
    K, M = matrices
    n = K.shape[0]
    return scipy.linalg.eigh(M, K, subset_by_index=[n - n_modes, n - 1])


def folded(robot, q):
    """True when the two links' sample points come within 1 mm (the FE would merge them)."""
    beams = build_chain(robot, q).beams
    s = np.linspace(0.0, 1.0, 21)[1:]
    a = [b.start + np.outer(s, b.end - b.start) for b in beams]
    return bool(np.min(np.linalg.norm(a[0][:, None] - a[1][None], axis=2)) < 1e-3)


def fe_elements(robot, qs, reference):
    """Smallest elements per link reaching ACCURACY on every configuration, its error."""
    for n in range(2, 16):
        err = max(np.max(np.abs(fe_modes(robot, q, n)[0] / w - 1.0))
                  for q, w in zip(qs, reference, strict=True))
        if err <= ACCURACY:
            return n, float(err)
    raise RuntimeError("the FE does not reach the accuracy with 15 elements per link")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=5, help="sweep repetitions")
    parser.add_argument("--inner", type=int, default=5,
                        help="calls per configuration (and per sweep); the fastest is kept")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="time every call by the wall clock (default) or by the "
                             "process's CPU time (steadier on a loaded machine)")
    parser.add_argument("--code", type=Path,
                        help="time the casflex package of this checkout instead (an older "
                             "commit, side by side): the script reruns itself on it")
    args = parser.parse_args()
    if args.code is not None:
        env = dict(os.environ, PYTHONPATH=str(args.code.resolve()))
        argv = [a for a in sys.argv[1:] if a != "--code" and a != str(args.code)]
        return subprocess.run([sys.executable, __file__, *argv], env=env, check=True).returncode

    robot = load(ROOT / "problems" / "arm2link.toml")
    q3 = np.linspace(-np.pi, np.pi, 40, endpoint=False)
    configurations = [np.array([0.0, 0.0, v]) for v in q3]
    fe_configurations = [q for q in configurations if not folded(robot, q)]
    modes(robot, [0.0, 0.0, 0.0], count=5)  # warm-up (imports, caches)

    reference = [natural_frequencies(robot, q, count=5) for q in fe_configurations]
    n_fe, fe_error = fe_elements(robot, fe_configurations, reference)
    converged = max(np.max(np.abs(fe_modes(robot, q, 4 * n_fe)[0] / w - 1.0))
                    for q, w in zip(fe_configurations, reference, strict=True))

    compiled = kernels is not None and kernels.AVAILABLE
    paths = (True, False) if compiled else (False,)
    single = {p: [] for p in paths}
    frequencies = {p: [] for p in paths}
    fe_times, eigen_times = [], []

    clock = time.perf_counter if args.clock == "wall" else time.process_time

    def best(call):
        """Fastest of ``--inner`` calls (a loaded machine preempts long calls)."""
        times = []
        for _ in range(args.inner):
            t = clock()
            call()
            times.append(clock() - t)
        return min(times)

    for q in configurations:
        for path in paths:
            if kernels is not None:
                kernels.AVAILABLE = path
            single[path].append(best(lambda q=q: modes(robot, q, count=5)))
            frequencies[path].append(best(lambda q=q: natural_frequencies(robot, q, count=5)))
        if not folded(robot, q):
            fe_times.append(best(lambda q=q: fe_modes(robot, q, n_fe)))
            segments, clamp = fe_segments(robot, q, n_fe)
            matrices = fem.assemble(segments, (), (), clamp)[:2]
            eigen_times.append(best(lambda m=matrices: fe_eigensolve(m)))

    qs = np.zeros((240, 3))
    qs[:, 2] = np.radians(np.arange(240) * 1.5 - 180.0)
    sweeps = {p: [] for p in paths}
    sweep_cpu = []
    for _ in range(args.repeat):
        for path in paths:
            if kernels is not None:
                kernels.AVAILABLE = path
            sweeps[path].append(best(lambda: sweep_frequencies(robot, qs, 5)))
            if path == compiled:
                t = time.process_time()
                sweep_frequencies(robot, qs, 5)
                sweep_cpu.append(time.process_time() - t)
    if kernels is not None:
        kernels.AVAILABLE = compiled

    per_configuration = statistics.median(single[compiled])
    frequencies_only = statistics.median(frequencies[compiled])
    fe_time = statistics.median(fe_times)
    result = {
        "compiled_kernels": compiled,
        "per_configuration_s": per_configuration,
        "frequencies_only_s": frequencies_only,
        "sweep_s": statistics.median(sweeps[compiled]),
        "sweep_cpu_s": statistics.median(sweep_cpu),
        "numpy_per_configuration_s": statistics.median(single[False]),
        "numpy_frequencies_only_s": statistics.median(frequencies[False]),
        "numpy_sweep_s": statistics.median(sweeps[False]),
        "configurations": int(qs.shape[0]),
        "fe_equal_accuracy_s": fe_time,
        "fe_elements_per_link": n_fe,
        "fe_max_rel_error": fe_error,
        "fe_converged_rel_error": float(converged),
        "fe_eigensolve_s": statistics.median(eigen_times),
        "ratio_fe": fe_time / per_configuration,
        "ratio_fe_frequencies": fe_time / frequencies_only,
        "inner": args.inner,
        "clock": args.clock,
        "code": str(Path(casflex.__file__).resolve().parents[1]),
        "load_average": os.getloadavg()[0],
        "blas_threads": os.environ["OPENBLAS_NUM_THREADS"],
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"machine: {platform.processor() or platform.machine()}, "
              f"{os.cpu_count()} cores, Python {platform.python_version()}, "
              f"load {result['load_average']:.2f}")
        print(f"per configuration (5 modes + shapes): {1e3 * per_configuration:.2f} ms"
              " (target ≤ 1 ms)")
        print(f"frequencies only: {1e3 * frequencies_only:.2f} ms (target ≤ 0.3 ms)")
        print(f"q3 sweep, {result['configurations']} configurations: "
              f"{result['sweep_s']:.3f} s (target ≤ 0.2 s)")
        print(f"numpy path: {1e3 * result['numpy_per_configuration_s']:.2f} ms with shapes, "
              f"{1e3 * result['numpy_frequencies_only_s']:.2f} ms frequencies only, sweep "
              f"{result['numpy_sweep_s']:.3f} s (compiled kernels: {compiled})")
        print(f"beam FE, {n_fe} elements per link (max error {fe_error:.1e}; "
              f"{4 * n_fe} elements: {converged:.1e}): {1e3 * fe_time:.2f} ms")
        print(f"the FE's eigen-solution alone: {1e3 * result['fe_eigensolve_s']:.3f} ms")
        print(f"FE / TMM: {result['ratio_fe']:.2f} with shapes, "
              f"{result['ratio_fe_frequencies']:.2f} frequencies only (target ≥ 10)")


if __name__ == "__main__":
    sys.exit(main())
