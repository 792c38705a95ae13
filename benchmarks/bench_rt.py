"""Time one ``rt_step`` (EKF + controller in one generated C call) for the Table 8 arm.

The arm of ``problems/arm2link.toml`` with 3 modes (``delta_order=0``, no gravity, as in
the control studies), two three-axis accelerometers
(``problems/sensors/arm2link_accel.toml``), EKF with Q = 5e-6 I, R = (250e-6 g)² I,
dt = 1 ms, and the composite controller (slow computed torque + fast LQR gains scheduled
over the configuration grid; ``--controller inversion`` for the inversion law).

The inputs are those of a real closed loop: first the whole loop (plant RK4, sensors with
noise, ``rt_step``) runs in C over move 3 (``casflex.codegen.run_closed_loop_c``); then
``rt_step`` alone runs in the ``casflex.codegen`` harness over the recorded encoder,
reference and accelerometer samples, with ``x``, ``P`` and ``dq_prev`` fed back, each call
timed inside C (``clock_gettime``); ``rt_step_us`` is the median over all calls.

``--guarded`` also times the guarded ``rt_step`` (``casflex.estimation.Guard``, torque
limits) on the same samples, alternating plain and guarded builds (``--rounds`` each) in
one run: ``rt_step_guarded_us`` and ``guard_cost_ratio`` (median guarded / median plain).

``rt_step_us`` is of the build a user gets from the bundle's Makefile (``--flags``,
default ``-O3 -ffp-contract=off``; ``-O2`` before session 14).

``--callgrind`` also counts the machine instructions of one ``rt_step`` (valgrind's
callgrind over one pass of the recorded samples, as ``bench_ekf.py --callgrind``: an AVX2
build, ``-O3 -march=x86-64-v3 -ffp-contract=off`` unless ``--callgrind-flags``):
``instructions_per_step``, a figure the machine's load does not change.

Usage: ``python benchmarks/bench_rt.py [--json] [--steps 3000] [--repeat 5] [--step-deg 7.5]
[--controller composite|inversion] [--guarded] [--rounds 2] [--callgrind]
[--callgrind-flags FLAGS] [--flags FLAGS] [--jacobians exact|first_order|linearized]``

``--jacobians`` chooses the EKF's Jacobians (:func:`casflex.estimation.ekf_step_function`;
default ``exact``, the step ``casflex codegen`` builds; ``first_order`` is the EKF
benchmark's, ``bench_ekf.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from casflex.codegen.templates import BUNDLE_CFLAGS

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--step-deg", type=float, default=7.5,
                        help="grid step of the modal tables, deg")
    parser.add_argument("--controller", choices=("composite", "inversion"),
                        default="composite")
    parser.add_argument("--flags", default=BUNDLE_CFLAGS,
                        help="C compiler flags of the timed step (default: the bundle "
                        "Makefile's, casflex.codegen.templates.BUNDLE_CFLAGS)")
    parser.add_argument("--guarded", action="store_true",
                        help="also time the guarded rt_step, alternating with the plain one")
    parser.add_argument("--rounds", type=int, default=2,
                        help="alternations of plain and guarded timings (--guarded)")
    parser.add_argument("--jacobians", default="exact",
                        choices=("exact", "first_order", "linearized"),
                        help="ekf_step_function's jacobians (exact: as casflex codegen ships)")
    parser.add_argument("--callgrind", action="store_true",
                        help="count the machine instructions per rt_step (valgrind)")
    parser.add_argument("--callgrind-flags", default="-O3 -march=x86-64-v3 -ffp-contract=off",
                        help="compiler flags of the counted build (valgrind has no AVX-512)")
    args = parser.parse_args(argv)

    import warnings

    from casflex import codegen
    from casflex.codegen import rtloop
    from casflex.estimation import Guard, ekf_step_function, tabulate_plant
    from casflex.model import build_model
    from casflex.moves import load_move
    from casflex.robot import load
    from casflex.sensors import load_sensors

    warnings.filterwarnings("ignore", message="modal table of")

    def log(msg):
        print(msg, file=sys.stderr)

    dt, Q, R = 1e-3, 5e-6, (250e-6 * 9.8) ** 2
    robot = load(ROOT / "problems/arm2link.toml")
    sensors = load_sensors(ROOT / "problems/sensors/arm2link_accel.toml", robot)
    t0 = time.perf_counter()
    model, _ = build_model(robot, n_modes=3, step=np.radians(args.step_deg), processes=1,
                           points=sensors.points, gravity=None, delta_order=0)
    plant = tabulate_plant(model, check=False)
    ekf = ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians)
    ctrl = rtloop.make_controller(model, args.controller)
    rt = rtloop.rt_step_function(ekf, ctrl, dt)
    log(f"model, plant, controller in {time.perf_counter() - t0:.1f} s; rt_step: "
        f"{rt.n_instructions()} SX instructions (ekf_step {ekf.n_instructions()}, "
        f"controller {ctrl.n_instructions()})")
    move = load_move(str(ROOT / "problems/moves.toml") + ":control_move3")
    N = args.steps
    noise = np.random.default_rng(0).normal(size=(N, sensors.n_outputs)) * np.sqrt(R)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        loop = rtloop.closed_loop_bundle(model, sensors, rt, dt, Path(tmp) / "loop")
        run = rtloop.run_closed_loop_c(loop, move, N, dt, noise=noise, flags=("-O1",))
        log(f"closed loop in C ({N} samples, plant included) in "
            f"{time.perf_counter() - t0:.1f} s (build and run)")
        x = run["x"]
        n, m = model.n, model.m
        t = run["t"][:-1]
        qd, dqd, ddqd = move.sample(t)
        inputs = {"q": x[:-1, :n], "dq": x[:-1, n + m:2 * n + m], "qd": qd, "dqd": dqd,
                  "ddqd": ddqd, "y": run["y"], "mask": np.ones_like(run["y"])}
        bundle = rtloop.rt_bundle(ekf, ctrl, sensors, dt, Path(tmp) / "rt")
        t0 = time.perf_counter()
        res = codegen.run_harness(
            bundle, "rt_step", inputs,
            {"x": np.zeros(2 * m), "P": 1e-4 * np.eye(2 * m), "dq_prev": x[0, n + m:2 * n + m]},
            feedback={"x_next": "x", "P_next": "P", "dq_next": "dq_prev"},
            repeat=args.repeat, flags=tuple(args.flags.split()))
        log(f"rt_step harness built and run in {time.perf_counter() - t0:.1f} s")
        dev = float(np.max(np.abs(res.outputs["tau"] - run["tau"]))
                    / np.max(np.abs(run["tau"])))
        info = bundle.function("rt_step")
        counted = {}
        if args.callgrind:  # machine instructions per call: independent of the load
            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from bench_ekf import callgrind_instructions

            init = {"x": np.zeros(2 * m), "P": 1e-4 * np.eye(2 * m),
                    "dq_prev": x[0, n + m:2 * n + m]}
            cg = codegen.run_harness(bundle, "rt_step", inputs, init,
                                     feedback={"x_next": "x", "P_next": "P",
                                               "dq_next": "dq_prev"},
                                     repeat=1, flags=tuple(args.callgrind_flags.split()))
            inp = Path(tmp) / "rt" / "harness_rt_step_input.txt"
            counted = {"instructions_per_step": callgrind_instructions(
                cg.executable, inp, Path(tmp), N, function="rt_step"),
                "callgrind_flags": args.callgrind_flags}
        guarded = {}
        if args.guarded:
            P0 = 1e-4 * np.eye(2 * m)
            ekf_g = ekf_step_function(plant, sensors, Q, R, dt, jacobians=args.jacobians,
                                      guard=Guard(P0))
            limits = 10 * np.nanmax(np.abs(run["tau"]), axis=0) + 1.0  # never reached
            bundle_g = rtloop.rt_bundle(ekf_g, ctrl, sensors, dt, Path(tmp) / "rtg",
                                        torque_limits=limits)
            init = {"x": np.zeros(2 * m), "P": P0, "dq_prev": x[0, n + m:2 * n + m]}
            plain_us, guard_us, statuses = [], [], None
            for rnd in range(args.rounds):
                for b, extra, fb, sink in (
                        (bundle, {}, {}, plain_us),
                        (bundle_g, {"q_prev": x[0, :n], "tau_prev": np.zeros(n)},
                         {"q_next": "q_prev", "tau": "tau_prev"}, guard_us)):
                    r = codegen.run_harness(
                        b, "rt_step", inputs, {**init, **extra},
                        feedback={"x_next": "x", "P_next": "P", "dq_next": "dq_prev", **fb},
                        repeat=args.repeat, flags=tuple(args.flags.split()))
                    sink.append(r.timing["median_step_ns"] / 1e3)
                    if b is bundle_g:
                        statuses = r.outputs["status"]
                        dev_g = float(np.max(np.abs(r.outputs["tau"] - res.outputs["tau"]))
                                      / np.max(np.abs(res.outputs["tau"])))
                log(f"[{rnd}] plain {plain_us[-1]:.2f} us, guarded {guard_us[-1]:.2f} us")
            rt_g = rtloop.rt_step_function(ekf_g, ctrl, dt, torque_limits=limits)
            guarded = {"rt_step_plain_rounds_us": plain_us, "rt_step_guarded_rounds_us": guard_us,
                       "rt_step_guarded_us": float(np.median(guard_us)),
                       "guard_cost_ratio": float(np.median(guard_us) / np.median(plain_us)),
                       "guarded_instructions": rt_g.n_instructions(),
                       "guarded_nonzero_status": int(np.count_nonzero(statuses)),
                       "guarded_tau_rel_deviation_vs_plain": dev_g}
    out = {
        "rt_step_us": res.timing["median_step_ns"] / 1e3,
        "rt_step_mean_us": res.timing["mean_step_ns"] / 1e3,
        "rt_step_min_us": res.timing["min_step_ns"] / 1e3,
        "loop_sample_us": run["timing"]["median_step_ns"] / 1e3,
        "controller": args.controller,
        "steps": N,
        "repeat": args.repeat,
        "flags": args.flags,
        "jacobians": args.jacobians,
        "instructions": {"rt_step": rt.n_instructions(), "ekf_step": ekf.n_instructions(),
                         "controller": ctrl.n_instructions()},
        "sz_w": info.sz_w,
        "tau_rel_deviation_vs_loop": dev,
        "load_average": os.getloadavg()[0],
        "timer_overhead_ns": res.timing["timer_overhead_ns"],
        **guarded,
        **counted,
    }
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:28s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
