# %% [markdown]
# # 6. Generated C for the real-time loop
#
# The dissertation ran its estimator in Simulink on a desktop PC: "over 90 % of one core at
# 1 kHz", about 1 ms per step (§5.5). casflex writes the same computations as plain C from
# the CasADi functions used everywhere else in the course (`casflex.codegen`,
# `casflex.codegen`): one header per bundle, fixed-size workspaces given by generated
# macros, no allocation inside a step, and a README of the call signatures.
#
# This notebook
#
# 1. generates the EKF bundle for the Table 8 arm with its two accelerometers (notebook 3),
#    compiles it with the system C compiler and loads it back;
# 2. checks it against the Python evaluation on random inputs, and runs it over a recorded
#    move in the generated C harness;
# 3. times one step inside C;
# 4. runs a long covariance check (10⁵ steps in C: P stays symmetric positive definite);
# 5. generates `rt_step`, the EKF and the controller in one call, and
# 6. runs the whole closed loop in C against the generated plant.

# %%
import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from casflex import codegen
from casflex.codegen import covariance_run, ekf_bundle
from casflex.estimation import ekf_step_function, run_ekf, simulate_data, tabulate_plant
from casflex.model import build_model
from casflex.moves import load_move
from casflex.robot import load
from casflex.sensors import load_sensors

ROOT = Path.cwd().parent if Path.cwd().name == "notebooks" else Path.cwd()
robot = load(ROOT / "problems" / "arm2link.toml")
sensors = load_sensors(ROOT / "problems" / "sensors" / "arm2link_accel.toml", robot)
model, table = build_model(robot, n_modes=3, step=np.radians(15), points=sensors.points,
                           gravity=None, processes=1)
plant = tabulate_plant(model)
Q, R, DT = 5e-6, sensors.noise_std**2, 1e-3
print(f"{model.m} modes, signals {sensors.output_names}")

# %% [markdown]
# ## 6.1 Generate, compile, load back
#
# `ekf_bundle` writes `ekf_step (x, P, u, y, mask) -> (x_next, P_next, x_post)` with the
# plant, the measurement model and the rigid-motion part of the signals, all from the
# same CasADi graphs the Python studies use (B-spline tables included).

# %%
out = Path(tempfile.mkdtemp(prefix="casflex_rt_"))
bundle = ekf_bundle(model, sensors, out / "ekf", Q, R, DT, plant=plant, name="arm2link_ekf")
lib = codegen.build(bundle)
print("generated and compiled:",
      sorted(p.name for p in bundle.out_dir.iterdir()))
print("reentrant (no mutable static data):", bundle.reentrant)
header = bundle.header.read_text().splitlines()
print("\n".join(line for line in header
                if line.startswith("int ekf_step(") or line.startswith("#define ekf_step_SZ")))

# %% [markdown]
# ## 6.2 C against Python
#
# Random states, covariances, inputs and signals: the compiled step and the CasADi
# evaluation agree to the last digits (the test suite asserts 1e-10 relative).

# %%
step_py = ekf_step_function(plant, sensors, Q, R, DT)
step_c = codegen.load(lib, "ekf_step")
rng = np.random.default_rng(0)
worst = 0.0
for _ in range(20):
    A = rng.normal(size=(6, 6))
    args = [1e-3 * rng.normal(size=6), 1e-4 * (A @ A.T + np.eye(6)),
            np.r_[rng.uniform(-3, 3, 3), rng.normal(size=6)], rng.normal(size=6),
            np.ones(6)]
    for a, b in zip(step_c(*args), step_py(*args), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        worst = max(worst, float(np.abs(a - b).max() / np.abs(b).max()))
print(f"largest relative difference C vs Python over 20 random steps: {worst:.1e}")
assert worst < 1e-10  # checked: "agree to the last digits", the suite's 1e-10

# %% [markdown]
# ## 6.3 The C harness over a recorded move
#
# Move 1 with the dissertation's sensor noise, recorded by `simulate_data`; the generated
# harness (`main` reading a data file) runs the filter over it in C, feeding `x_next` and
# `P_next` back, and times every step.

# %%
move = load_move(f"{ROOT / 'problems' / 'moves.toml'}:move1")
data = simulate_data(model, sensors, move, dt=DT, t_end=3.0)
res = codegen.run_harness(bundle, "ekf_step", {"u": data.u, "y": data.y,
                                               "mask": np.ones_like(data.y)},
                          {"x": np.zeros(6), "P": 1e-4 * np.eye(6)},
                          feedback={"x_next": "x", "P_next": "P"}, repeat=3)
py = run_ekf(step_py, data.u, data.y, np.zeros(6), 1e-4 * np.eye(6))
dev = np.abs(res.outputs["x_post"] - py.x).max() / np.abs(py.x).max()
print(f"C harness vs Python run: max relative deviation {dev:.1e}")
print("timing inside C:", json.dumps(res.timing))
fig, axs = plt.subplots(1, 2, figsize=(11, 3.5))
t = data.t
axs[0].plot(t, data.x[:, :3], "k", lw=0.8, label=["true δ"] + ["_nolegend_"] * 2)
axs[0].plot(t, res.outputs["x_post"][:, :3], "--", label=[f"δ̂{j + 1} (C)" for j in range(3)])
axs[0].set_title("δ: truth and C estimate")
axs[0].set_ylabel("δ [√kg·m]")
axs[1].plot(t, res.outputs["x_post"][:, :3] - data.x[:, :3],
            label=[f"δ̂{j + 1} − δ{j + 1}" for j in range(3)])
axs[1].set_title("estimation error of δ")
axs[1].set_ylabel("δ̂ − δ [√kg·m]")
for ax in axs:
    ax.set_xlabel("t [s]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
fig.tight_layout()
plt.show()

# %% [markdown]
# One step takes 5–10 µs in C here (default `-O2` build, exact Jacobians, on a shared
# machine) against about 1 ms for the dissertation's Simulink estimator, and ~0.15 ms
# through CasADi's virtual machine from Python. `benchmarks/bench_ekf.py` measures the three
# side by side, and the fastest configuration (first-order Jacobians for the covariance,
# `-O3 -march=native -ffp-contract=off`: 4.7–7.7 µs).
#
# ## 6.4 Long-run covariance check
#
# `covariance_run` cycles the recorded data through the C step and checks after every
# step that `P` is finite, symmetric and positive definite (an unrolled Cholesky).

# %%
check = covariance_run(bundle, data.u, data.y, np.zeros(6), 1e-6 * np.eye(6), 100_000)
print({k: check[k] for k in ("steps", "not_positive_definite", "not_finite",
                             "max_rel_asymmetry", "min_rel_cholesky_pivot")})

# %% [markdown]
# ## 6.5 One call for the whole loop: `rt_step`
#
# The real-time loop needs more than the estimator: at every sample the encoders give
# `q, q̇`, the planner gives the reference `q_d, q̇_d, q̈_d`, the accelerometers give `y`,
# and the motors need torques. `casflex.codegen.rt_step_function` puts the EKF and a
# controller into one SX function — `q̈` for the filter from the backward difference of the
# joint rates, the filter update and prediction, and the torque of the controller on the
# filtered estimate — and `casflex codegen --controller composite|inversion` writes it to C.
#
# As in the design study (`problems/studies/arm2link_move1.toml`) the arm carries the
# gear-reflected inertias of the testbed's actuators (`problems/arm2link_actuated.toml`):
# without them the residual joint inertia of this very light arm falls so low during large
# moves that no loop sampled at 1 kHz can control it (notebook 5). The controller is the
# composite law of §6.2.3 with fast gains scheduled over the configuration (B-splines, so
# they code-generate), on the dissertation's `M(q)` (`delta_order=0`).

# %%
from casflex.codegen import rtloop
from casflex.simulate import simulate_closed_loop

arm = load(ROOT / "problems" / "arm2link_actuated.toml")
model0, _ = build_model(arm, n_modes=3, step=np.radians(15), points=sensors.points,
                        gravity=None, delta_order=0, processes=1)
ekf0 = ekf_step_function(tabulate_plant(model0), sensors, Q, R, DT)
ctrl = rtloop.make_controller(model0, "composite")
rt = rtloop.rt_step_function(ekf0, ctrl, DT)
rt_dir = out / "rt"
rt_bundle = rtloop.rt_bundle(ekf0, ctrl, sensors, DT, rt_dir, name="arm2link_rt")
rt_c = codegen.load(codegen.build(rt_bundle), "rt_step")
print("rt_step inputs:", rt.name_in())
print("rt_step outputs:", rt.name_out())
print("SX instructions: rt_step", rt.n_instructions(), "= EKF", ekf0.n_instructions(),
      "+ controller and glue")
worst = 0.0
for _ in range(10):
    A = rng.normal(size=(6, 6))
    q = rng.uniform(-3, 3, 3)
    args = [1e-3 * rng.normal(size=6), 1e-4 * (A @ A.T + np.eye(6)), rng.normal(size=3), q,
            rng.normal(size=3), q + 0.1 * rng.normal(size=3), rng.normal(size=3),
            rng.normal(size=3), rng.normal(size=6), np.ones(6)]
    for a, b in zip(rt_c(*args), rt(*args), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        worst = max(worst, float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)))
print(f"C vs Python, 10 random calls: largest relative difference {worst:.1e}")

# %% [markdown]
# ## 6.6 The closed loop in C
#
# `closed_loop_bundle` adds a plant to the same C bundle — RK4 of the model's equations of
# motion, the exact accelerometer model and given noise — and the generated harness runs
# plant and `rt_step` sample by sample in C. The Python simulation of the same loop
# (`casflex.simulate.simulate_closed_loop` with the EKF) is an independent reference: a
# Python loop calling the pieces one by one.

# %%
move3 = load_move(f"{ROOT / 'problems' / 'moves.toml'}:control_move3")
N = 3000
noise = np.random.default_rng(7).normal(size=(N + 1, 6)) * np.sqrt(R)
loop = rtloop.closed_loop_bundle(model0, sensors, rt, DT, out / "loop")
c_run = rtloop.run_closed_loop_c(loop, move3, N, DT, noise=noise[:N])
est = {"step": ekf0, "sensors": sensors, "P0": 1e-4 * np.eye(6), "x0": np.zeros(6),
       "noise": noise, "ddq": "difference"}
py_run = simulate_closed_loop(model0, ctrl, move3, t_end=N * DT, dt=DT,
                              estimator=est)
scale = np.abs(py_run.x).max(axis=0) + 1e-12
print(f"C loop vs Python loop over {N} samples: largest deviation "
      f"{np.max(np.abs(c_run['x'] - py_run.x) / scale):.1e} of each state's range")
print(f"one closed-loop sample in C (plant included): "
      f"{c_run['timing']['median_step_ns'] / 1e3:.1f} µs")
fig, axs = plt.subplots(1, 2, figsize=(11, 3.5))
axs[0].plot(c_run["t"], c_run["x"][:, :3], label=[f"q{j + 1}" for j in range(3)])
axs[0].plot(py_run.t, py_run.qd, "k:", lw=0.8, label=["reference"] + ["_nolegend_"] * 2)
axs[0].set_title("joints in the C loop")
axs[0].set_ylabel("joint angle [rad]")
axs[1].plot(c_run["t"][:N], c_run["x_hat"][:, :3] - c_run["x"][:N, 3:6],
            label=[f"δ̂{j + 1} − δ{j + 1}" for j in range(3)])
axs[1].set_title("estimation error in the C loop")
axs[1].set_ylabel("δ̂ − δ [√kg·m]")
for ax in axs:
    ax.set_xlabel("t [s]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
fig.tight_layout()
plt.show()

# %% [markdown]
# **End of the course.** The design job (`casflex design
# problems/studies/arm2link_move1.toml --out DIR`) runs every step of notebooks 1–6 for
# one robot, move and sensor set and writes a report; `problems/README.md` documents the
# study file.
