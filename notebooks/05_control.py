# %% [markdown]
# # 5. Modal controllability and feedback control (§6.2)
#
# The Table 8 arm (`problems/arm2link.toml`) with three tabulated modes. Following §6.2 the
# control studies neglect gravity and use the dissertation's mass matrix `M(q)` (eq. 199,
# 233: `delta_order=0`). Everything below comes from `casflex.control`:
#
# * accessibility indexes `a_i(q) = ‖M_qδ[:, i](q)‖` (eq. 204) and the rank of the
#   controllability matrix (eq. 203);
# * the inversion-based tracking law (eq. 210, 213) against the classical computed-torque
#   law (eq. 232), `K_p = I`, `K_d = 2I`;
# * stability checks along the moves: eq. 226 for the inversion law, a Hurwitz fast loop
#   for the composite law;
# * the singular-perturbation composite controller (eq. 248 + LQR on eq. 251, `Q = I`,
#   `R = 10 I`, `ε = 1/ω_min`).

# %%
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from casflex import control
from casflex.model import build_model
from casflex.moves import Move, load_move
from casflex.robot import load
from casflex.simulate import decay_time, simulate_closed_loop

np.set_printoptions(precision=4, suppress=True)
ROOT = Path.cwd().parent if Path.cwd().name == "notebooks" else Path.cwd()
MOVES = ROOT / "problems" / "moves.toml"
robot = load(ROOT / "problems" / "arm2link.toml")
model, table = build_model(robot, n_modes=3, step=np.radians(6), gravity=None,
                           delta_order=0, processes=1)
eps = control.perturbation_parameter(model, table=table)
print(f"lowest natural frequency over the table: {1 / eps:.3f} rad/s  (dissertation: 6.35)")

# %% [markdown]
# ## 5.1 Accessibility (Fig. 108–110 and 120)
#
# `a_i` does not depend on `q1`. Modes 1 and 3 lose all coupling to the joints at the
# vertical configuration `q2 = 90°, q3 = 270°` (= −90°); mode 2 stays accessible and its
# index does not depend on `q2`.

# %%
axes, index = control.accessibility_map(model, joints=(1, 2), step=np.radians(5))
control.plot_accessibility(axes, index, joints=(1, 2))  # 0-based: q2, q3
plt.show()
q2 = np.linspace(-np.pi, np.pi, 73)
_, a = control.accessibility_map(model, joints=(1, 2), axes=(q2, [-np.pi / 2]))
plt.figure(figsize=(6, 3.5))
for k in range(3):
    plt.plot(np.degrees(q2), a[k, :, 0], label=f"a{k + 1}")
plt.xlabel("q2 [deg] (q3 = -90 deg)")
plt.ylabel("accessibility [√kg·m]")
plt.legend()
plt.show()
print("spread of a2 over q2:", np.ptp(a[1, :, 0]))
for q in ([0, 0, -np.pi / 2], [0, 1, -np.pi / 2], [0, np.pi / 2, -np.pi / 2]):
    print(f"q = {np.round(q, 3)}: a = {control.accessibility(model, q)}, "
          f"rank Gc = {control.controllability(model, q)[1]} of 6")

# %% [markdown]
# ## 5.2 Inversion-based control against the classical law (moves of §6.2.2.2)

# %%
rows = []
runs = {}
for name in ("control_move1", "control_move2", "control_move3"):
    move = load_move(f"{MOVES}:{name}")
    for law in (control.inversion_controller, control.feedforward_controller):
        ctrl = law(model, Kp=1.0, Kd=2.0)
        r = simulate_closed_loop(model, ctrl, move, dt=5e-3)
        runs[name, ctrl.name()] = r
        e = r.tracking_error
        rows.append((name, ctrl.name(), np.abs(e).max(), np.sqrt(np.mean(e**2)),
                     np.linalg.norm(r.tip_deflection, axis=1).max(), np.abs(r.tau).max()))
print(f"{'move':15s} {'law':12s} {'max|q-qd|':>10s} {'rms':>10s} {'max defl':>9s} "
      f"{'max|tau|':>9s}")
for row in rows:
    print(f"{row[0]:15s} {row[1]:12s} {row[2]:10.2e} {row[3]:10.2e} {row[4]:9.4f} "
          f"{row[5]:9.3f}")

# %%
fig, axs = plt.subplots(1, 2, figsize=(11, 3.5))
for ax, law in zip(axs, ("inversion", "feedforward"), strict=True):
    r = runs["control_move1", law]
    ax.plot(r.t, r.tracking_error, label=[f"q{j + 1}" for j in range(r.tracking_error.shape[1])])
    ax.set_title(f"move 1, {law}: tracking error")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("q − q_d [rad]")
    ax.grid(True, alpha=0.3)
axs[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
fig.tight_layout()
plt.show()

# %% [markdown]
# The inversion law makes `q̈ = v` exactly, so the joints follow the plan to the
# integrator's accuracy while the tip keeps oscillating (nothing damps the zero dynamics:
# Table 8 has no modal damping). The computed-torque law of eq. 232 ignores the flexible
# coupling and its joints are pushed off the plan by the vibration.
#
# ## 5.3 Stability along the moves

# %%
for name in ("control_move1", "control_move2", "control_move3"):
    move = load_move(f"{MOVES}:{name}")
    r = control.inversion_stability(model, move, alpha=1.0)
    print(f"{name}: eq. 226 margin min {r['worst_margin']:.3g} 1/s^3 at t = "
          f"{r['worst_time']:.2f} s, move may run {r['time_scale_max']:.3g}x faster; "
          f"gamma = {r['gamma']:.3g} 1/s (no damping: D - alpha I not > 0)")
schedule = control.gain_schedule(model, Q=1.0, R=10.0, epsilon=eps, table=table)
print(f"gain schedule over joints {[j + 1 for j in schedule.joints]}, "
      f"{schedule.gains.shape[:2]} points, {schedule.filled} filled")
for name in ("control_move1", "control_move2", "control_move3"):
    move = load_move(f"{MOVES}:{name}")
    end = control.composite_stability(model, move, epsilon=eps)
    sch = control.composite_stability(model, move, gain=schedule)
    print(f"{name}: fast loop, end gains: worst Re {end['worst_real']:+.3g} 1/s at t = "
          f"{end['worst_time']:.2f} s; scheduled: {sch['worst_real']:+.3g} 1/s at t = "
          f"{sch['worst_time']:.2f} s")

# %% [markdown]
# Is the unstable fast loop with end-of-move gains a bug of the boundary-layer formula? An
# independent check: the full 12-state linearisation of the model under the composite law
# (finite differences of `control.closed_loop`, no use of `boundary_layer`), frozen at
# `q_d(t)` along move 1. The end gains leave a real eigenvalue in the right half-plane over
# the first half second, the scheduled gains do not. The cause is the small residual joint
# inertia `M_qq − M_qδ M_qδᵀ` of this arm: the fast input matrix is large and turns with
# the configuration, and the LQR at the end of the move is high-gain (details in the
# docstring of `control.composite_stability`).

# %%
move = load_move(f"{MOVES}:control_move1")
K_end, _, _ = control.fast_gain(model, move.qf, epsilon=eps)
fmass = model.functions()["mass"]
for label, gain in (("end gains", K_end), ("scheduled", schedule)):
    ctrl = control.composite_controller(model, gain=gain, epsilon=eps)
    row = []
    for tk in (0.0, 0.2, 0.4, 0.6, 1.0, 2.0):
        q = move.sample(tk)[0]
        cl = control.closed_loop(model, ctrl, Move(q, q, 1.0))
        x0 = np.r_[q, np.zeros(9)]
        J = np.column_stack([(cl(5.0, x0 + e) - cl(5.0, x0 - e)).full().ravel() / 2e-7
                             for e in np.eye(12) * 1e-7])
        row.append(round(float(np.linalg.eigvals(J).real.max()), 2))
    print(f"{label}: max Re of the full closed loop at t = 0, .2, .4, .6, 1, 2 s: {row} 1/s")
for tk in (0.0, 1.0, 2.0):
    q = move.sample(tk)[0]
    M = fmass(q, np.zeros(3)).full()
    res = M[:3, :3] - M[:3, 3:] @ M[:3, 3:].T
    print(f"t = {tk} s: eigenvalues of M_qq {np.linalg.eigvalsh(M[:3, :3]).round(5)}, of the "
          f"residual M_qq - M_qd M_qd^T {np.linalg.eigvalsh(res).round(6)} kg m^2")

# %% [markdown]
# ## 5.4 Composite controller: impulse disturbance
#
# With the gains fixed at the end of move 1 the fast loop is unstable at the start of the
# move (above), so the impulse study runs on move 3 (q1 only), whose fast loop stays
# Hurwitz, with an impulsive tip force of 0.02 N·s per axis at t = 3 s.

# %%
move = load_move(f"{MOVES}:control_move3")
K, _, _ = control.fast_gain(model, move.qf, epsilon=eps)
print("fast loop along move 3:",
      control.composite_stability(model, move, gain=K, epsilon=eps)["worst_real"], "1/s")
imp = {}
for fast in (True, False):
    ctrl = control.composite_controller(model, gain=K, epsilon=eps, fast=fast)
    r = simulate_closed_loop(model, ctrl, move, dt=5e-3, t_end=8.0,
                             impulse=(3.0, [0.02, 0.02, 0.02]))
    imp[fast] = r
    d = np.linalg.norm(r.tip_deflection, axis=1)
    print(f"fast part {'on ' if fast else 'off'}: peak deflection after the impulse "
          f"{d[r.t >= 3].max():.4f} m, 5% decay time "
          f"{decay_time(r.t, r.tip_deflection, 3.0):.2f} s, "
          f"max |q - qd| {np.abs(r.tracking_error).max():.3f} rad")
fig, axs = plt.subplots(1, 2, figsize=(11, 3.5), sharey=True)
for ax, fast in zip(axs, (False, True), strict=True):
    ax.plot(imp[fast].t, imp[fast].tip_deflection, label=["x", "y", "z"])
    ax.set_title(f"fast part {'on' if fast else 'off'}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tip deflection (flexible − rigid) [m]")
    ax.grid(True, alpha=0.3)
axs[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## 5.5 Initial deflection at q2 = 0, 1 rad and π/2 (q3 = −π/2; Fig. 121–123)
#
# Gains computed at the horizontal configuration and kept for all three.

# %%
K0, _, _ = control.fast_gain(model, [0, 0, -np.pi / 2], epsilon=eps)
ctrl = control.composite_controller(model, gain=K0, epsilon=eps)
x_delta = np.array([0.01, 0.01, 0.01])
for q2 in (0.0, 1.0, np.pi / 2):
    q = np.array([0.0, q2, -np.pi / 2])
    cl = control.closed_loop(model, ctrl, Move(q, q, 1.0))
    x0 = np.r_[q, np.zeros(9)]
    J = np.column_stack([((cl(5.0, x0 + e) - cl(5.0, x0 - e)).full().ravel()) / 2e-6
                         for e in np.eye(12) * 1e-6])
    ev = np.linalg.eigvals(J)
    osc = ev[ev.imag > 1.0]
    print(f"q2 = {q2:.3f}: a = {control.accessibility(model, q)}, oscillatory closed-loop "
          "poles (Re, Im) =", [(round(float(v.real), 4), round(float(v.imag), 2))
                               for v in sorted(osc, key=lambda v: v.imag)])
    if q2 < 1.5:
        r = simulate_closed_loop(model, ctrl, Move(q, q, 1.0),
                                 x0=np.r_[q, x_delta, np.zeros(6)], t_end=6.0,
                                 dt=5e-3)
        print("   5% decay times of the tip deflection and of δ1, δ2, δ3:",
              round(decay_time(r.t, r.tip_deflection), 2),
              [round(decay_time(r.t, r.delta[:, k]), 2) for k in range(3)], "s")

# %% [markdown]
# ## 5.6 EKF in the loop
#
# The composite law (scheduled gains) sampled at 1 kHz on move 3, fed by the EKF of
# chapter 5 instead of the true `δ, δ̇`: two three-axis accelerometers
# (`problems/sensors/arm2link_accel.toml`) with noise `R = (250e-6 g)² I`, `Q = 5e-6 I`,
# and `q̈` from the backward difference of the joint rates — exactly what the generated
# `rt_step` computes (`casflex codegen ... --controller composite`, `casflex.codegen.rtloop`).
# References: the same law on the true states, and the slow law alone. (Move 1 cannot be
# run sampled at 1 ms on this model, see `simulate_closed_loop`.)

# %%
from casflex.estimation import ekf_step_function, tabulate_plant
from casflex.sensors import load_sensors

sensors = load_sensors(ROOT / "problems" / "sensors" / "arm2link_accel.toml", robot)
smodel, stable_ = build_model(robot, n_modes=3, step=np.radians(15), gravity=None,
                              delta_order=0, processes=1, points=sensors.points)
dt_s, R_s = 1e-3, (250e-6 * 9.8) ** 2
ekf = ekf_step_function(tabulate_plant(smodel, check=False), sensors, 5e-6, R_s, dt_s)
eps_s = control.perturbation_parameter(smodel, table=stable_)
sched_s = control.gain_schedule(smodel, epsilon=eps_s, table=stable_)
move = load_move(f"{MOVES}:control_move3")
est = {"step": ekf, "sensors": sensors, "P0": 1e-4 * np.eye(6), "x0": np.zeros(6),
       "R": R_s * np.eye(6), "seed": 1, "ddq": "difference"}
loops = {}
for label, fast, e in (("true states", True, None), ("EKF", True, est),
                       ("slow law only", False, None)):
    ctrl = control.composite_controller(smodel, gain=sched_s, fast=fast)
    loops[label] = simulate_closed_loop(smodel, ctrl, move, dt=dt_s, t_end=3.5,
                                        sampled=True, method="rk4", estimator=e)
for label, r in loops.items():
    w = (r.t >= 2.5) & (r.t <= 3.5)
    resid = np.sqrt(np.mean(np.sum(r.tip_deflection[w] ** 2, axis=1)))
    print(f"{label:14s}: max |q - qd| {np.abs(r.tracking_error).max():.3f} rad, "
          f"|q - qd| at 3.5 s {np.abs(r.tracking_error[-1]).max():.3f} rad, rms tip "
          f"deflection 0.5-1.5 s after the move {resid * 1e3:.3f} mm")
r = loops["EKF"]
truth = np.c_[r.delta, r.ddelta]
for lo, hi in ((0.2, 2.0), (2.0, 3.5)):
    w = (r.t >= lo) & (r.t < hi)
    print(f"t in [{lo}, {hi}) s: rms estimation error / rms true value, [δ1 δ2 δ3 δ̇1 δ̇2 δ̇3]:",
          (np.sqrt(np.mean((r.x_hat[w] - truth[w]) ** 2, axis=0))
           / np.sqrt(np.mean(truth[w] ** 2, axis=0))).round(2))
fig, axs = plt.subplots(1, 2, figsize=(11, 3.5))
axs[0].plot(r.t, r.delta[:, 0], label="δ1 true")
axs[0].plot(r.t, r.x_hat[:, 0], "--", label="δ1 EKF")
axs[0].legend(loc="best", fontsize="small")
axs[0].set_xlabel("t [s]")
axs[0].set_ylabel("δ1 [√kg·m]")
for label, run in loops.items():
    axs[1].plot(run.t, np.linalg.norm(run.tip_deflection, axis=1), label=label)
axs[1].set_ylabel("‖tip deflection‖₂ [m]")
axs[1].set_xlabel("t [s]")
axs[1].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
for ax in axs:
    ax.grid(True, alpha=0.3)
fig.tight_layout()
plt.show()

# %% [markdown]
# The EKF follows the deflections (δ1, which carries most of the tip motion, within a few
# per cent rms); its velocity estimates are noisier (the accelerometer noise and the
# differenced `q̈` enter `δ̂̇` directly). Fed with them, the fast part still damps the
# residual vibration almost as well as with true states and about ten times better than
# the slow law alone, at the price of joint motion: the fast part moves the joints to damp
# the modes, and the estimation noise doubles the peak joint error.

# %% [markdown]
# **Next:** [6. Real-time code](06_realtime.ipynb) turns the estimator and the controller
# into C for the 1 kHz loop. The whole chain — model, shaper, simulations, stability check
# and C — runs as one job with `casflex design problems/studies/arm2link_move1.toml --out
# DIR`.
