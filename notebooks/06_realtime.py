# %% [markdown]
# # 6. Generated C for the real-time loop
#
# The dissertation ran its estimator in Simulink on a desktop PC: "over 90 % of one core at
# 1 kHz", about 1 ms per step (§5.5). casflex writes the same computations as plain C from
# the CasADi functions used everywhere else in the course (`casflex.codegen`,
# `casflex.rtcode`): one header per bundle, fixed-size workspaces given by generated
# macros, no allocation inside a step, and a README of the call signatures.
#
# This notebook
#
# 1. generates the EKF bundle for the Table 8 arm with its two accelerometers (notebook 3),
#    compiles it with the system C compiler and loads it back;
# 2. checks it against the Python evaluation on random inputs, and runs it over a recorded
#    move in the generated C harness;
# 3. times one step inside C;
# 4. runs a long covariance check (10⁵ steps in C: P stays symmetric positive definite).

# %%
import json
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from casflex import codegen
from casflex.estimation import ekf_step_function, run_ekf, simulate_data, tabulate_plant
from casflex.model import build_model
from casflex.moves import load_move
from casflex.robot import load
from casflex.rtcode import covariance_run, ekf_bundle
from casflex.sensors import load_sensors

ROOT = Path.cwd().parent if Path.cwd().name == "notebooks" else Path.cwd()
robot = load(ROOT / "problems" / "arm2link.toml")
sensors = load_sensors(ROOT / "problems" / "sensors" / "arm2link_accel.toml", robot)
model, table = build_model(robot, n_modes=3, step=np.radians(7.5), points=sensors.points,
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
t0 = time.perf_counter()
bundle = ekf_bundle(model, sensors, out / "ekf", Q, R, DT, plant=plant, name="arm2link_ekf")
lib = codegen.build(bundle)
print(f"generated and compiled in {time.perf_counter() - t0:.1f} s:",
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
axs[0].plot(t, data.x[:, :3], "k", lw=0.8)
axs[0].plot(t, res.outputs["x_post"][:, :3], "--")
axs[0].set_title("δ: truth (black) and C estimate")
axs[1].plot(t, res.outputs["x_post"][:, :3] - data.x[:, :3])
axs[1].set_title("estimation error of δ")
for ax in axs:
    ax.set_xlabel("t [s]")
plt.show()

# %% [markdown]
# One step takes a few microseconds in C against about 1 ms for the dissertation's
# Simulink estimator, and ~0.2 ms through CasADi's virtual machine from Python
# (`benchmarks/bench_ekf.py` measures all three side by side).
#
# ## 6.4 Long-run covariance check
#
# `covariance_run` cycles the recorded data through the C step and checks after every
# step that `P` is finite, symmetric and positive definite (an unrolled Cholesky).

# %%
check = covariance_run(bundle, data.u, data.y, np.zeros(6), 1e-6 * np.eye(6), 100_000)
print({k: check[k] for k in ("steps", "not_positive_definite", "not_finite",
                             "max_rel_asymmetry", "min_rel_cholesky_pivot")})
