"""Mutation testing of casflex: does the test suite catch a small physics or logic bug?

Each mutant is one small change of casflex's source (a sign, a factor 1.0005 on an
inertia, a rotated tip body, a dropped Coriolis term, an off-by-one, ...): the file, the
exact original snippet (it must occur exactly once), its replacement and the tests that
should catch it. The mutants are applied ONE AT A TIME to a COPY of the repository (the
files git tracks plus untracked, non-ignored ones, so uncommitted tests count), never in
place; the tests run in the copy with ``PYTHONPATH`` set to it, a fresh temporary
``CASFLEX_CACHE`` and a timeout. A mutant is *killed* when a test fails (or errors), it
*survives* when all of its tests pass.

Before the mutants, the unmutated copy runs the union of their tests once (the baseline):
a mutant can only count as killed if its tests pass without it.

Usage (from the repository root)::

    python tools/mutate.py                    # every mutant, a text report
    python tools/mutate.py --list             # the list, nothing run
    python tools/mutate.py --only chain_rx_transposed model_coriolis_transpose
    python tools/mutate.py --json > mutants.json
    python tools/mutate.py --timeout 300 --no-baseline --report mutants.txt

To keep editing while it runs, run it from a snapshot (``git archive HEAD | tar -x -C
/tmp/snap && python /tmp/snap/tools/mutate.py``): the copies are taken from the tree the
script sits in.

Exit status 0 when the killed fraction reaches ``--target`` (default 0.9), else 1; 2 on a
stale mutant (its original snippet is not found exactly once).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

TMM = ["tests/tmm/test_tmm.py", "tests/tmm/test_tmm_fixtures.py",
       "tests/tmm/test_reference_fem.py"]
ROBOT = ["tests/test_robot.py"]
MODEL = ["tests/model/test_model_equations.py"]
MODAL = ["tests/modal/test_normalize.py", "tests/modal/test_tracking.py"]


@dataclass(frozen=True)
class Mutant:
    """One source change and the tests that should catch it."""

    name: str
    file: str
    original: str
    replacement: str
    tests: tuple[str, ...]
    what: str


def mutant(name, file, original, replacement, tests, what):
    return Mutant(name, file, original, replacement, tuple(tests), what)


MUTANTS = [
    # ------------------------------------------------------------------ robot: sections, DH
    mutant("robot_rect_J_series", "casflex/robot.py",
           "192.0 * t / (np.pi**5 * h)", "192.2 * t / (np.pi**5 * h)",
           ROBOT + ["tests/tmm/test_reference_fem.py", "tests/tmm/test_tmm.py"],
           "rectangle torsion constant off by ~0.2 % (series coefficient)"),
    mutant("robot_rect_Ix_factor", "casflex/robot.py",
           "Ix=b * a**3 / 12.0,", "Ix=b * a**3 / 12.0 * 1.0005,",
           ROBOT + TMM, "second moment Ix of a rectangle × 1.0005"),
    mutant("robot_tube_area_factor", "casflex/robot.py",
           "section = cls(A=math.pi * (ro**2 - ri**2),",
           "section = cls(A=math.pi * (ro**2 - ri**2) * 1.0005,",
           ROBOT + TMM, "area of a tube × 1.0005 (mass per length)"),
    mutant("robot_mass_per_length", "casflex/robot.py",
           "return self.material.rho * self.section.A if self.flexible",
           "return 1.0005 * self.material.rho * self.section.A if self.flexible",
           ROBOT + MODEL, "Link.mass_per_length × 1.0005 (the rigid-body model's beam mass)"),
    mutant("robot_dh_sign", "casflex/robot.py",
           "[st * ca, ct * ca, -sa, -sa * d + 0.0],", "[st * ca, ct * ca, -sa, sa * d + 0.0],",
           ROBOT + MODEL, "sign of the d offset in the DH transform (robot.frames)"),
    mutant("robot_dh_transposed", "casflex/robot.py",
           "[ct, -st, 0.0, a],\n            [st * ca, ct * ca,",
           "[ct, st, 0.0, a],\n            [-st * ca, ct * ca,",
           ROBOT + MODEL, "Rz(θ) transposed in the DH transform (robot.frames)"),
    # ------------------------------------------------------------------ tmm chain
    mutant("chain_rx_transposed", "casflex/tmm/chain.py",
           "return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])",
           "return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])",
           TMM, "Rx(α) transposed in the TMM's DH walk"),
    mutant("chain_section_angle_sign", "casflex/tmm/chain.py",
           "R[:, 0]]) @ _rz(link.section_angle)", "R[:, 0]]) @ _rz(-link.section_angle)",
           TMM, "section angle of an 'a' beam turned the wrong way"),
    mutant("chain_tip_body_rotated", "casflex/tmm/chain.py",
           "p = p + R[:, 0] * link.a\n            add_body(link, row, Rl)",
           "p = p + R[:, 0] * link.a\n            add_body(link, row, R.copy())",
           TMM, "tip body of an 'a' beam posed in the DH frame instead of the beam frame"),
    mutant("chain_spring_axis", "casflex/tmm/chain.py",
           '"stiffness": link.joint_stiffness, "axis": R[:, 2].copy()',
           '"stiffness": link.joint_stiffness, "axis": R[:, 0].copy()',
           TMM + ["tests/modal/test_normalize.py"],
           "joint spring about x instead of the joint axis"),
    # ------------------------------------------------------------------ tmm elements
    mutant("elements_parallel_axis_sign", "casflex/tmm/elements.py",
           "[mass * C, Ic - mass * C @ C]", "[mass * C, Ic + mass * C @ C]",
           TMM, "parallel-axis term of a body with the wrong sign"),
    mutant("elements_body_inertia_factor", "casflex/tmm/elements.py",
           "[mass * C, Ic - mass * C @ C]", "[mass * C, 1.0005 * Ic - mass * C @ C]",
           TMM, "rotary inertia of a tip body × 1.0005 in the TMM"),
    mutant("elements_body_rotary_missing", "casflex/tmm/elements.py",
           "out[:, 6:9, 0:6] = -w2[:, None, None] * M[:, 3:6]",
           "out[:, 6:9, 0:3] = -w2[:, None, None] * M[:, 3:6, 0:3]",
           TMM, "rotary inertia of a body missing from the moment jump"),
    mutant("elements_torsion_inertia_factor", "casflex/tmm/elements.py",
           "G * section.J, rho * section.A, rho * section.Ip,",
           "G * section.J, rho * section.A, 1.0005 * rho * section.Ip,",
           TMM, "torsional inertia ρIp of a beam × 1.0005"),
    # ------------------------------------------------------------------ modal
    mutant("integrals_beam_inertia_factor", "casflex/modal/integrals.py",
           "J[2, 2] += rA * L**3 / 3.0", "J[2, 2] += rA * L**3 / 3.0 * 1.0005",
           MODEL, "beam's second moment of mass ∫ρA s² ds × 1.0005 (rigid pseudo-inertia)"),
    mutant("integrals_torsion_sign", "casflex/modal/integrals.py",
           "0.5 * rIp, 0.5 * rIp, -0.5 * rIp, link.mass_per_length",
           "0.5 * rIp, 0.5 * rIp, 0.5 * rIp, link.mass_per_length",
           MODEL, "sign of the torsional term of the section pseudo-inertia"),
    mutant("tracking_group_off_by_one", "casflex/modal/tracking.py",
           "j < i + mult[i]", "j < i + mult[i] + 1",
           MODAL, "a k-fold root's group takes one mode too many (off-by-one)"),
    mutant("tracking_stale_reference", "casflex/modal/tracking.py",
           "last, last_pos = cur, k", "last_pos = k",
           MODAL, "tracking compares with the anchor instead of the previous step"),
    mutant("normalize_skips_cholesky", "casflex/modal/normalize.py",
           "S[np.ix_(idx, idx)] = np.linalg.inv(Lc)",
           "S[np.ix_(idx, idx)] = np.diag(1.0 / np.sqrt(np.diag(G)))",
           MODAL, "k-fold roots scaled, not mass-orthonormalised"),
    # ------------------------------------------------------------------ model
    mutant("model_coriolis_transpose", "casflex/model/equations.py",
           "self.C = 0.5 * (Mdot + Jac - Jac.T)", "self.C = 0.5 * (Mdot + Jac)",
           MODEL, "Coriolis matrix without the −∂(MẊ)/∂X ᵀ term"),
    mutant("model_centrifugal_dropped", "casflex/model/equations.py",
           "Cdx = ca.jtimes(M @ dX, X, dX) - ca.gradient(self.kinetic, X)",
           "Cdx = ca.jtimes(M @ dX, X, dX)",
           MODEL, "∂T/∂X dropped from the velocity terms of the dynamics"),
    mutant("model_gravity_sign", "casflex/model/equations.py",
           "Vg -= gh.T @ T @ Psi[:, 3]", "Vg += gh.T @ T @ Psi[:, 3]",
           MODEL, "sign of the gravitational potential"),
    mutant("model_damping_exponent", "casflex/model/equations.py",
           "ca.diag(2.0 * self.damping_ratio * self.omega)",
           "ca.diag(2.0 * self.damping_ratio * self.omega**2)",
           MODEL, "modal damping 2ζω² instead of 2ζω"),
    mutant("model_spring_phi_sign", "casflex/model/equations.py",
           "theta = theta + phi", "theta = theta - phi",
           MODEL, "joint-spring rotation of the modes with the wrong sign"),
    mutant("model_motor_inertia_factor", "casflex/model/equations.py",
           "M[k, k] += self.robot.links[row].motor_inertia",
           "M[k, k] += 1.0005 * self.robot.links[row].motor_inertia",
           MODEL, "motor inertia × 1.0005"),
    # ------------------------------------------------------------------ shaping
    mutant("shaping_prv_damping_exponent", "casflex/shaping/shapers.py",
           "decay = np.exp(-z * w * (tn - t))", "decay = np.exp(-z * wd * (tn - t))",
           ["tests/shaping/test_shaping_shapers.py"],
           "residual vibration decays with the damped frequency ζω_d instead of ζω"),
    mutant("shaping_zv_root", "casflex/shaping/shapers.py",
           "k = math.exp(-zeta * math.pi / root)\n    return Shaper([0.0, math.pi / (omega * "
           "root)]",
           "k = math.exp(-zeta * math.pi)\n    return Shaper([0.0, math.pi / (omega * root)]",
           ["tests/shaping/test_shaping_shapers.py"],
           "ZV amplitude ratio without √(1−ζ²)"),
    # ------------------------------------------------------------------ simulate, moves
    mutant("rk4_stage", "casflex/simulate/integrators.py",
           "k3 = f(x + 0.5 * h * k2, u_half)", "k3 = f(x + 0.5 * h * k1, u_half)",
           ["tests/simulate/test_integration_order.py",
            "tests/simulate/test_simulate.py::test_torque_rk4_matches_scipy_dop853"],
           "third RK4 stage from k1 (a second-order scheme)"),
    mutant("moves_hermite_off_by_one", "casflex/moves.py",
           'np.searchsorted(t_ref, t, side="right") - 1, 0',
           'np.searchsorted(t_ref, t, side="right"), 0',
           ["tests/test_moves.py", "tests/simulate/test_integration_order.py"],
           "reference interpolation in the next interval (off-by-one)"),
    # ------------------------------------------------------------------ sensors
    mutant("sensors_strain_distance_swapped", "casflex/sensors.py",
           "return (math.sqrt(3.0 * section.Iy / section.A), "
           "math.sqrt(3.0 * section.Ix / section.A))",
           "return (math.sqrt(3.0 * section.Ix / section.A), "
           "math.sqrt(3.0 * section.Iy / section.A))",
           ["tests/sensors/test_sensors.py"], "strain-gauge distances of the two axes swapped"),
    # ------------------------------------------------------------------ estimation
    mutant("ekf_joseph_term_sequential", "casflex/estimation/ekf.py",
           "- c[i] * k[l] + rk[i] * k[l]", "- c[i] * k[l]",
           ["tests/estimation/test_ekf_structure.py::test_standard_form_equals_joseph"],
           "the K R Kᵀ term of the sequential Joseph update (joseph=True) skipped"),
    mutant("ekf_standard_form_gain", "casflex/estimation/ekf.py",
           "            else:\n                v = P[i, l] - k[i] * b[l]\n",
           "            else:\n                v = P[i, l] - 1.0005 * k[i] * b[l]\n",
           ["tests/estimation/test_ekf_structure.py::test_standard_form_equals_joseph"],
           "the standard-form scalar covariance update (the default) off by 0.05 %"),
    mutant("ekf_joseph_term_batch", "casflex/estimation/ekf.py",
           "Pp = _sandwich(IKH, P) + _sandwich(K, Rm)", "Pp = _sandwich(IKH, P)",
           ["tests/estimation/test_estimation.py::test_pruned_plant_and_update_forms"],
           "the K R Kᵀ term of the batch Joseph update skipped"),
    # ------------------------------------------------------------------ session 5 code
    mutant("guard_gate_flipped", "casflex/estimation/ekf.py",
           "e[i] * e[i] > guard.gate * Sii", "e[i] * e[i] < guard.gate * Sii",
           ["tests/estimation/test_ekf_faults.py"],
           "innovation gate comparison flipped (rejects the good samples, keeps the outliers)"),
    mutant("guard_hold_not_applied", "casflex/estimation/guard.py",
           "out = ca.vertcat(*[ca.if_else(ok[i], v[i], fallback[i]) for i in range(v.numel())])",
           "out = ca.vertcat(*[v[i] for i in range(v.numel())])",
           ["tests/estimation/test_ekf_faults.py", "casflex/estimation/guard.py"],
           "a non-finite input not held at its last valid value"),
    mutant("bounds_E_lower_factor", "casflex/_validate.py",
           '"E": Bound(1e5, 1.5e12,', '"E": Bound(1e6, 1.5e12,',
           ["tests/test_plausibility_bounds.py", "tests/test_faults.py",
            "tests/test_bad_input.py"],
           "plausibility bound: lowest Young's modulus × 10 (soft elastomers refused)"),
    mutant("bounds_tip_mass_factor", "casflex/_validate.py",
           '"tip_mass": Bound(0.0, 1e4,', '"tip_mass": Bound(0.0, 1e3,',
           ["tests/test_plausibility_bounds.py", "tests/test_faults.py",
            "tests/test_bad_input.py"],
           "plausibility bound: heaviest tip mass / 10 (a 10 t payload refused)"),
    mutant("grid_lp_cut_sign", "casflex/shaping/grid_lp.py",
           "rows.append((np.cos(th) * re[s] + np.sin(th) * im[s]) / vtol[s])",
           "rows.append((np.cos(th) * re[s] - np.sin(th) * im[s]) / vtol[s])",
           ["tests/shaping/test_shaping_reference_lp.py", "casflex/shaping/grid_lp.py"],
           "cutting plane of the grid LP at the mirrored angle (sign of the sine term)"),
    mutant("modal_fit_damping_formula", "casflex/identification/modal_fit.py",
           "    z = sigma / wn\n", "    z = sigma / wd\n",
           ["tests/identification/test_modal_fit_exact.py",
            "tests/identification/test_modal_fit.py",
            "tests/identification/test_simulated_impulse.py"],
           "damping ratio σ/ω_d instead of σ/ω_n"),
    mutant("conditioning_ratio_not_squared", "casflex/tmm/conditioning.py",
           "ratio = (hi / lo) ** 2", "ratio = hi / lo",
           ["tests/tmm/test_tmm_breakdown.py"],
           "stiffness spread taken as the frequency ratio, not its square"),
    mutant("conditioning_zero_stiffness_accepted", "casflex/tmm/conditioning.py",
           "(value >= 0.0 if body else value > 0.0)", "(value >= 0.0)",
           ["tests/tmm/test_tmm_breakdown.py"],
           "a zero beam or spring stiffness not refused"),
]


# ------------------------------------------------------------------ running


def source_files(root: Path) -> list[str]:
    """Files of the working tree: tracked and untracked-but-not-ignored (every file but
    caches when ``root`` is not a git checkout, e.g. a ``git archive`` snapshot)."""
    proc = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=root,
                          capture_output=True)
    if proc.returncode == 0 and (root / ".git").exists():
        return [f for f in proc.stdout.decode().split("\0") if f and (root / f).is_file()]
    skip = {"__pycache__", ".pytest_cache", ".ruff_cache", ".git"}
    return [str(p.relative_to(root)) for p in root.rglob("*")
            if p.is_file() and not skip & set(p.relative_to(root).parts)]


def make_copy(root: Path, files: list[str], dest: Path) -> None:
    for f in files:
        target = dest / f
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / f, target)


def check_mutant(m: Mutant, root: Path) -> str | None:
    """None if ``m`` applies to the tree at ``root``, else the reason it does not."""
    path = root / m.file
    if not path.is_file():
        return f"{m.file}: no such file"
    count = path.read_text().count(m.original)
    if count != 1:
        return f"{m.file}: the original snippet occurs {count} times (must be once)"
    if not any((root / t.split("::")[0]).exists() for t in m.tests):
        return f"none of its tests exists: {list(m.tests)}"
    return None


def existing_tests(m: Mutant, root: Path) -> list[str]:
    """The mutant's tests that exist in the tree (a list may name a test file that a
    later change adds)."""
    return [t for t in m.tests if (root / t.split("::")[0]).exists()]


FAILED = re.compile(r"^(FAILED|ERROR) (\S+)", re.MULTILINE)


def run_tests(copy: Path, tests: list[str], timeout: float) -> dict:
    """Run ``tests`` in ``copy``: status 'passed', 'failed' (with the failing test) or
    'timeout'."""
    env = dict(os.environ)
    cache = tempfile.mkdtemp(prefix="casflex-mutant-cache-")
    env.update(PYTHONPATH=str(copy), CASFLEX_CACHE=cache, MPLBACKEND="Agg",
               OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-n", "0", "-x", "-q", "-rfE", "-p", "no:cacheprovider",
           "-p", "no:randomly", *tests]
    start = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=copy, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        stdout, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"status": "timeout", "killer": None, "seconds": time.monotonic() - start}
    finally:
        if proc.poll() is None:  # timeout, or this script stopped: its pytest goes too
            proc.kill()
            proc.communicate()
        shutil.rmtree(cache, ignore_errors=True)
    seconds = time.monotonic() - start
    if proc.returncode == 0:
        return {"status": "passed", "killer": None, "seconds": seconds}
    hits = FAILED.findall(stdout)
    killer = hits[0][1] if hits else f"pytest exit {proc.returncode}"
    tail = "\n".join(stdout.strip().splitlines()[-15:])
    return {"status": "failed", "killer": killer, "seconds": seconds, "tail": tail}


def run_mutant(m: Mutant, root: Path, files: list[str], timeout: float) -> dict:
    with tempfile.TemporaryDirectory(prefix=f"casflex-mutant-{m.name}-") as tmp:
        copy = Path(tmp)
        make_copy(root, files, copy)
        path = copy / m.file
        text = path.read_text()
        path.write_text(text.replace(m.original, m.replacement, 1))
        result = run_tests(copy, existing_tests(m, root), timeout)
    status = {"failed": "killed", "passed": "survived", "timeout": "timeout"}[result["status"]]
    return {"name": m.name, "file": m.file, "what": m.what, "status": status,
            "killer": result["killer"], "seconds": round(result["seconds"], 1),
            "tests": existing_tests(m, root), "tail": result.get("tail")}


def report_text(results: list[dict], baseline: dict | None) -> str:
    lines = []
    if baseline is not None:
        lines.append(f"baseline (unmutated copy, {len(baseline['tests'])} test files): "
                     f"{baseline['status']} in {baseline['seconds']:.0f} s")
    width = max(len(r["name"]) for r in results)
    for r in results:
        killer = r["killer"] or ""
        lines.append(f"{r['name']:<{width}}  {r['status']:<8}  {r['seconds']:6.1f} s  {killer}")
    killed = sum(r["status"] == "killed" for r in results)
    lines.append(f"killed {killed} / {len(results)} = {killed / len(results):.0%} "
                 f"(survived {sum(r['status'] == 'survived' for r in results)}, "
                 f"timeout {sum(r['status'] == 'timeout' for r in results)})")
    for r in results:
        if r["status"] == "survived":
            lines.append(f"  survivor {r['name']}: {r['what']} ({r['file']})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run these mutants only")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    parser.add_argument("--report", type=Path, help="also write the text report here")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds per mutant's test run (default 900)")
    parser.add_argument("--no-baseline", action="store_true",
                        help="skip the run of the unmutated copy")
    parser.add_argument("--target", type=float, default=0.9,
                        help="killed fraction for exit status 0 (default 0.9)")
    args = parser.parse_args(argv)

    chosen = MUTANTS
    if args.only:
        unknown = set(args.only) - {m.name for m in MUTANTS}
        if unknown:
            parser.error(f"unknown mutants: {sorted(unknown)}")
        chosen = [m for m in MUTANTS if m.name in args.only]
    stale = {m.name: why for m in chosen if (why := check_mutant(m, ROOT))}
    if args.list:
        for m in chosen:
            flag = f"  STALE: {stale[m.name]}" if m.name in stale else ""
            print(f"{m.name:<34} {m.file:<32} {m.what}{flag}")
        return 2 if stale else 0
    if stale:
        for name, why in stale.items():
            print(f"stale mutant {name}: {why}", file=sys.stderr)
        return 2

    files = source_files(ROOT)
    baseline = None
    if not args.no_baseline:
        tests = sorted({t for m in chosen for t in existing_tests(m, ROOT)})
        with tempfile.TemporaryDirectory(prefix="casflex-mutant-baseline-") as tmp:
            make_copy(ROOT, files, Path(tmp))
            result = run_tests(Path(tmp), tests, args.timeout * 2)
        baseline = {"tests": tests, **result}
        print(f"baseline: {result['status']} in {result['seconds']:.0f} s", file=sys.stderr)
        if result["status"] != "passed":
            print(f"the unmutated tests do not pass ({result['killer']}); fix them first",
                  file=sys.stderr)
            if result.get("tail"):
                print(result["tail"], file=sys.stderr)
            return 2
    results = []
    for i, m in enumerate(chosen, 1):
        r = run_mutant(m, ROOT, files, args.timeout)
        results.append(r)
        print(f"[{i}/{len(chosen)}] {m.name}: {r['status']} ({r['seconds']:.0f} s) "
              f"{r['killer'] or ''}", file=sys.stderr)
    text = report_text(results, baseline)
    if args.report:
        args.report.write_text(text + "\n")
    killed = sum(r["status"] == "killed" for r in results)
    fraction = killed / len(results)
    if args.json:
        for r in results:
            r.pop("tail", None)
        print(json.dumps({"killed": killed, "total": len(results), "fraction": fraction,
                          "baseline": None if baseline is None else
                          {k: baseline[k] for k in ("status", "seconds", "tests")},
                          "mutants": results}))
    else:
        print(text)
    return 0 if fraction >= args.target else 1


def _stop(signum, frame):
    raise KeyboardInterrupt  # unwinds through run_tests, which kills its pytest


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _stop)
    sys.exit(main())
