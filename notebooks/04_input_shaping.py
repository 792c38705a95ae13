# %% [markdown]
# # 4. Input shaping for a flexible arm
#
# This notebook follows §6.1 of the dissertation: an open-loop command is convolved with a
# sequence of impulses (a *shaper*) so that the vibration it excites cancels itself. The
# percentage residual vibration (PRV, here a fraction: 0.05 = 5 %) of a shaper at a
# natural frequency ω measures how much of an unshaped command's residual vibration is
# left (eq. 187–189).
#
# The study goes from single-frequency shapers (ZV, ZVD, EI and its multi-hump variants) to
# specified-insensitivity (SI) shapers that keep the PRV under a tolerance on whole
# frequency ranges, and then to the dissertation's contribution: choosing the tolerances
# of every mode of a flexible arm from how much that mode contributes to the tip
# deflection during a *planned* move (eq. 196–198), with the frequency ranges swept by the
# configuration-dependent modes along the move. Last, the shaped moves are simulated with
# the modal model of the arm and compared with the unshaped ones.

# %%
import math

import matplotlib.pyplot as plt
import numpy as np

from casflex.model import build_model
from casflex.moves import load_move
from casflex.robot import load
from casflex.shaping import (
    FrequencyRange,
    convolve,
    ei,
    ei_three_hump,
    ei_two_hump,
    frequencies_along,
    residual_amplitude,
    residual_vibration,
    shaped_reference,
    shaper_for_move,
    si_shaper,
    tolerances_from_contributions,
    zv,
    zvd,
)

np.set_printoptions(precision=4, suppress=True)
HZ = 2.0 * math.pi


def table(rows, header):
    """Print a small aligned table."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=True)]
    for row in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(str(x).rjust(w) for x, w in zip(row, widths, strict=True)))


def prv_plot(ax, shaper, f_max, label=None, zeta=0.0):
    """PRV in % against frequency in Hz."""
    f = np.linspace(0.01, f_max, 2000)
    ax.plot(f, 100 * residual_vibration(shaper, f * HZ, zeta), label=label)
    ax.set(xlabel="frequency [Hz]", ylabel="PRV [%]", ylim=(0, 105))
    ax.grid(alpha=0.3)


# %% [markdown]
# ## 4.1 Shapers for one frequency (Fig. 89)
#
# The zero-vibration (ZV) shaper (eq. 190–191) puts two impulses half a damped period
# apart: the PRV is exactly zero at the design frequency (and at its odd multiples) but
# rises steeply around it. ZVD (ZV convolved with itself), EI (extra-insensitive: PRV
# equal to Vtol at the design frequency, zero on either side) and the two- and three-hump
# EI shapers buy a wider band of low vibration with longer durations. All are designed
# here for 1 Hz, undamped, with Vtol = 5 % for the EI family.

# %%
w1 = 1.0 * HZ
family = {"ZV": zv(w1), "ZVD": zvd(w1), "EI": ei(w1, 0.0, 0.05),
          "EI two-hump": ei_two_hump(w1, 0.0, 0.05), "EI three-hump": ei_three_hump(w1, 0.0, 0.05)}
fig, ax = plt.subplots(figsize=(8, 4.5))
for name, s in family.items():
    prv_plot(ax, s, 3.5, f"{name} ({s.duration:.2f} s)")
ax.axhline(5, color="k", lw=0.8, ls=":", label="5 %")
ax.set_title("Single-frequency shapers designed for 1 Hz (ζ = 0)")
ax.legend(loc="best")


def band(shaper, vtol=0.05):
    """Width of the band around 1 Hz with PRV <= vtol, as a fraction of 1 Hz."""
    f = np.linspace(0.2, 1.8, 160001)
    ok = residual_vibration(shaper, f * HZ) <= vtol + 1e-12
    i = j = int(np.argmin(abs(f - 1.0)))
    while i > 0 and ok[i - 1]:
        i -= 1
    while j < f.size - 1 and ok[j + 1]:
        j += 1
    return f[j] - f[i]


table([[name, len(s), f"{s.duration:.3f}", f"{100 * band(s):.1f} %"]
       for name, s in family.items()],
      ["shaper", "impulses", "duration [s]", "band with PRV <= 5 %"])

# %% [markdown]
# The ZV shaper is the shortest (half a period, 0.5 s) and the least robust: only ±3 % of
# frequency error keeps the PRV under 5 %. EI keeps it under 5 % over ±20 % for the same
# duration as ZVD; the multi-hump shapers widen the band further at 1.5 and 2 periods.
#
# ## 4.2 Two modes: convolution (Fig. 90–91)
#
# Shapers for different modes are convolved: the PRV is the product of the two curves
# and the durations add. A ZV shaper for 1 Hz convolved with one for 2.5 Hz:

# %%
two = convolve(zv(1.0 * HZ), zv(2.5 * HZ))
fig, ax = plt.subplots(figsize=(8, 3.5))
prv_plot(ax, zv(1.0 * HZ), 4.0, "ZV 1 Hz")
prv_plot(ax, two, 4.0, f"ZV 1 Hz * ZV 2.5 Hz ({len(two)} impulses, {two.duration:.2f} s)")
ax.legend()
print("impulses:", two.times, "amplitudes:", two.amplitudes)

# %% [markdown]
# ## 4.3 Specified insensitivity on three ranges (Fig. 92–94)
#
# For a flexible arm the frequencies move with the configuration: a shaper has to hold
# the PRV under a tolerance on whole ranges. The SI shaper minimises the time of the last
# impulse subject to PRV <= Vtol at sample frequencies of every range (eq. 192), with
# positive amplitudes summing to 1, starting from convolved EI shapers at the range
# midpoints; small impulses are pruned, close ones merged, and casflex verifies every
# range on a dense grid refined at its local maxima, adding the worst frequencies as
# samples until every range holds. The dissertation's example: 3–4, 9–13 and 20–24 Hz,
# ζ = 0.

# %%
hz_ranges = [(3, 4), (9, 13), (20, 24)]


def ranges(vtols):
    return [FrequencyRange(a * HZ, b * HZ, 0.0, v) for (a, b), v in zip(hz_ranges, vtols,
                                                                        strict=True)]


si5 = si_shaper(ranges([0.05] * 3))
ei_mid = convolve(*[ei(0.5 * (a + b) * HZ, 0.0, 0.05) for a, b in hz_ranges])
si_opt = si_shaper(ranges(tolerances_from_contributions([4.0, 2.0, 0.3])))
si_skip = si_shaper(ranges([0.99, 0.05, 0.05]))
fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
for ax, s, title, vt in [
        (axes[0], si5, "SI, Vtol = 5 % on every range (Fig. 92)", [0.05] * 3),
        (axes[1], ei_mid, "EI shapers at the midpoints, convolved (Fig. 93)", [0.05] * 3),
        (axes[2], si_opt, "SI with Vtol from r = [4, 2, 0.3] (Fig. 94)",
         [r.vtol for r in si_opt.ranges])]:
    shaper = getattr(s, "shaper", s)
    prv_plot(ax, shaper, 30.0, "PRV")
    for i, ((a, b), v) in enumerate(zip(hz_ranges, vt, strict=True)):
        ax.plot([a, b], [100 * v] * 2, "r-", lw=3, label="Vtol on each range" if i == 0 else None)
    ax.set_title(f"{title}: {len(shaper)} impulses, {shaper.duration:.4f} s")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
fig.tight_layout()
print(f"SI design (Ipopt, prune and merge, dense verification): {si5.iterations} NLP solves")

# %% [markdown]
# Eq. 198 turns contributions into tolerances: the dominant mode gets Vtol, the others
# Vtol·r_max/r_s, at most 1. For r = [4, 2, 0.3] it gives [0.05, 0.10, 0.67]; the text
# prints 0.05 for mode 2 (a typo: its 0.30 s shaper is the one for 0.10).

# %%
table([
    ["Vtol 5 % on all ranges (Fig. 92)", "0.3192", f"{si5.duration:.4f}"],
    ["EI at the midpoints, convolved (Fig. 93)", "0.422", f"{ei_mid.duration:.4f}"],
    ["Vtol = [0.05, 0.10, 0.67] (Fig. 94)", "0.30", f"{si_opt.duration:.4f}"],
    ["Vtol = [0.99, 0.05, 0.05]", "0.11", f"{si_skip.duration:.4f}"],
    ["ZV at 3.5 Hz", "0.1429", f"{zv(3.5 * HZ).duration:.4f}"],
    ["EI at 3.5 Hz (the text says 3 Hz)", "0.286", f"{ei(3.5 * HZ).duration:.4f}"],
], ["shaper", "dissertation [s]", "casflex [s]"])
print("Vtol from r = [4, 2, 0.3]:", tolerances_from_contributions([4.0, 2.0, 0.3]))

# %% [markdown]
# casflex's SI shaper for the three ranges is 1 ms shorter than the dissertation's and
# meets every range on a dense, refined grid. The convolved EI shapers last 33 % longer
# (the dissertation's own durations give 32 %; its text says 38 %). Here they happen to
# hold every range too — each range lies within ±18 % of its midpoint, inside one EI
# shaper's ±20 % band — but nothing in their construction guarantees it. Relaxing the
# tolerances of the less important modes shortens the shaper — by 65 % when mode 1 is
# not excited at all.
#
# ## 4.4 Contributions, tolerances and shapers for moves 1–3 (§6.1.5.1)
#
# The Table 8 arm (two flexible 1 m aluminium links) with three modes; the moves of
# Table 9 take 2 s with bang-bang accelerations. Only q3 changes the shape of the arm, so
# the modal tables run over q3 — here over the interval the moves visit, −75° to 15° in
# 7.5° steps, which is all the moves need. Gravity is left out, as in the dissertation's
# moves, so that every deflection is vibration.
#
# Eq. 194 says the joints drive the modes through M_qδ: `δ̈ + Ω² δ = −M_qδᵀ q̈`. The
# contribution of mode j to the deflection of the tip is approximated by
# `r_j = ∫ (|M_qδᵀ(q_d)| |q̈_d|)_j dt · w_j(tip)` (eq. 196), with w_j the total modal
# displacement of the tip at the end configuration (eq. 197), here the norm of the
# CasADi Jacobian ∂tip/∂δ_j.

# %%
robot = load("../problems/arm2link.toml")
model, tab = build_model(robot, n_modes=3, grid=[np.radians(np.arange(-75.0, 15.1, 7.5))],
                         processes=1, gravity=None, cache_dir=False)
moves = {name: load_move(f"../problems/moves.toml:{name}") for name in
         ("move1", "move2", "move3")}
for name, mv in moves.items():
    print(f"{name}: {mv.description}")

# %%
fig, ax = plt.subplots(figsize=(7, 4))
t, w = frequencies_along(model, moves["move1"])
q3 = moves["move1"].sample(t)[0][:, 2]
for j, (lo, hi) in enumerate([(6.64, 8.26), (9.36, 11.9), (23.36, 35.21)]):
    line, = ax.plot(np.degrees(q3), w[:, j], label=f"mode {j + 1}")
    ax.plot([np.degrees(-1.0), 0.0], [lo, hi], "o", color=line.get_color(), mfc="none",
            label="Table 14 limits" if j == 2 else None)
ax.set(xlabel="q3 [deg]", ylabel="natural frequency ω [rad/s]",
       title="Tracked frequencies along moves 1 and 2 (circles: Table 14 limits)")
ax.grid(alpha=0.3)
ax.legend()

# %% [markdown]
# Mode 1 bends link 2 out of the arm's plane (it is driven by q1), mode 2 bends both
# links in the plane (driven by q2 and q3), mode 3 is the second out-of-plane mode. So the
# planar move 2 excites mode 2 only and move 3 (q1 alone) modes 1 and 3.
#
# The shapers are designed twice: with the frequency spans along the move as they are
# (the dissertation's Table 14 spans — this reproduces its durations) and widened by ±20 %
# (the robustness margin the dissertation recommends and uses on the testbed).

# %%
DIS = {"move1": ([0.647, 1, 0.13], [0.078, 0.05, 0.36], 0.87),
       "move2": ([0, 1, 0], [1, 0.05, 1], 0.53),
       "move3": ([1, 0, 0.38], [0.05, 1, 0.13], 0.39)}
designs = {}
for name, mv in moves.items():
    for margin in (0.0, 0.2):
        designs[name, margin] = shaper_for_move(model, mv, margin=margin)


def fmt(x):
    return "[" + ", ".join(f"{abs(round(v, 3)):g}" for v in x) + "]"


rows = []
for name in moves:
    d0, d2 = designs[name, 0.0], designs[name, 0.2]
    r, v, dur = DIS[name]
    rows.append([name, fmt(r), fmt(d0.contributions), fmt(v), fmt(d0.tolerances),
                 f"{dur:.2f}", f"{d0.duration:.3f}", f"{d2.duration:.3f}"])
table(rows, ["move", "r (diss.)", "r (casflex)", "Vtol (diss.)", "Vtol (casflex)",
             "T (diss.) [s]", "T spans [s]", "T ±20 % [s]"])
print()
d0 = designs["move1", 0.0]
table([[j + 1, f"{lo}–{hi}", f"{a:.2f}–{b:.2f}"]
       for j, ((lo, hi), a, b) in enumerate(zip([(6.64, 8.26), (9.36, 11.9), (23.36, 35.21)],
                                               d0.omega_min, d0.omega_max, strict=True))],
      ["mode", "Table 14 [rad/s]", "casflex [rad/s]"])

# %%
# checked: contributions and tolerances within 0.005 of the dissertation's (the rounding
# of its two-decimal figures; mode 3 of move 1 against eq. 198 with its rounded r = 0.13,
# i.e. 0.05 / [0.135, 0.125], see below), the spans' shaper durations 0-3 % longer than
# its (equal for move 3), and the ±20 % durations quoted below
for name in moves:
    d0, d2 = designs[name, 0.0], designs[name, 0.2]
    r, v, dur = DIS[name]
    assert np.allclose(np.abs(d0.contributions), r, rtol=0, atol=0.005), (name, r)
    tol = np.array(d0.tolerances)
    if name == "move1":
        assert 0.05 / 0.135 <= tol[2] <= 0.05 / 0.125, tol
        tol[2], v = v[2], list(v)  # the text's 0.36 is 0.05/0.139, compared above instead
    assert np.allclose(tol, v, rtol=0, atol=0.005), (name, d0.tolerances)
    assert 1.0 - 0.005 / dur <= d0.duration / dur <= 1.03, (name, d0.duration, dur)
    assert round(d2.duration, 2) == {"move1": 1.21, "move2": 0.81, "move3": 0.87}[name]
assert abs(designs["move3", 0.0].duration - 0.39) < 0.005

# %% [markdown]
# The contributions agree with the dissertation's figures within 0.005 (the rounding of
# its two-decimal figures; [0.650, 1, 0.132] for move 1 against its [0.647, 1, 0.13], [1,
# 0, 0.381] for move 3), and so do the tolerances (0.36 in the text for mode 3 of move 1
# is 0.05/0.139; eq. 198 with its own r = 0.13, 0.125–0.135 before rounding, gives
# 0.370–0.400, casflex 0.380). The frequency spans differ by 1–3 % because the models
# differ slightly (at q = 0 casflex has 8.31, 11.97, 22.75 rad/s, the dissertation 8.26,
# 11.93, 23.37); the shapers designed on them are 2 % longer for moves 1 and 2 and equal
# for move 3 (0.39 s).
#
# Move 3's 0.39 s is a shaper for the three single frequencies: move 3 does not change q3,
# so the spans have zero width. With the ±20 % the text suggests for move 3 the shaper
# needs 0.87 s, because holding 5 % over ±20 % of 8.3 rad/s takes about one period
# (0.76 s) whatever the other modes do. Moves 1 and 2 grow from 0.89 to 1.21 s and from
# 0.54 to 0.81 s with the margin.

# %%
fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
for ax, name in zip(axes, moves, strict=True):
    for margin, style in ((0.0, "-"), (0.2, "--")):
        res = designs[name, margin]
        w = np.linspace(0.5, 45.0, 3000)
        ax.plot(w, 100 * residual_vibration(res.shaper, w), style,
                label=f"margin {margin:.0%}: {res.duration:.3f} s")
        for i, r in enumerate(res.ranges):
            x = [r.omega_min, r.omega_max]
            ax.plot(x if x[0] < x[1] else x[:1], [100 * r.vtol] * (2 if x[0] < x[1] else 1),
                    "r" + ("-" if margin == 0 else ":") if x[0] < x[1] else "rv", lw=3,
                    label=f"Vtol, margin {margin:.0%}" if i == 0 else None)
    ax.set(ylabel="PRV [%]", ylim=(0, 105), title=name)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
axes[-1].set_xlabel("ω [rad/s]")
fig.tight_layout()

# %% [markdown]
# ## 4.5 Shaped versus unshaped moves
#
# The moves are simulated with the arm's modal model (`casflex.simulate.simulate_prescribed`:
# the joints follow the reference exactly, the modal row of eq. 118 — with its Coriolis and
# centrifugal terms — is integrated with RK4 at 2 ms), unshaped and shaped. The shaped
# reference is the move sampled and convolved with the shaper (`shaped_reference`): it
# ends later by the shaper's duration, and the residual vibration is the largest tip
# deflection after the (shaped) move ends, over the same 3 s of settling.
#
# For comparison the decoupled model of eq. 194, `δ̈ + Ω²(q) δ = −M_qδᵀ(q) q̈`, is
# integrated too: it is the model the shaper design assumes (no Coriolis or centrifugal
# coupling), integrated here by a plain RK4 that shares nothing with `casflex.simulate`.

# %%
import casadi as ca  # noqa: E402

from casflex.simulate import simulate_prescribed  # noqa: E402

f = model.functions()
n, m = model.n, model.m
qs_ = ca.SX.sym("q", n)
d_ = ca.SX.sym("d", m)
mqd_fun = ca.Function("mqd", [qs_], [f["mass"](qs_, ca.DM.zeros(m))[:n, n:]])
jac_fun = ca.Function("tip_jacobian", [qs_], [ca.substitute(
    ca.jacobian(f["tip"](qs_, d_), d_), d_, ca.DM.zeros(m))])


def decoupled(reference):
    """RK4 of eq. 194 on a sampled reference; returns the tip deflection (N, 3)."""
    t, q, _, ddq = reference
    N = t.size
    tm = np.concatenate([q, 0.5 * (q[:-1] + q[1:])])
    am = np.concatenate([ddq, 0.5 * (ddq[:-1] + ddq[1:])])
    B = mqd_fun.map(tm.shape[0])(tm.T).full().reshape(n, tm.shape[0], m)
    force = -np.einsum("ikj,ki->kj", B, am)
    K = f["stiffness"].map(tm.shape[0])(tm.T).full().reshape(m, tm.shape[0], m)
    w2 = K[np.arange(m), :, np.arange(m)].T
    x, v, out = np.zeros(m), np.zeros(m), np.zeros((N, m))
    for i in range(N - 1):
        h = t[i + 1] - t[i]
        fa, fb, fc = force[i], force[N + i], force[i + 1]
        wa, wb, wc = w2[i], w2[N + i], w2[i + 1]
        k1 = (v, fa - wa * x)
        k2 = (v + h / 2 * k1[1], fb - wb * (x + h / 2 * k1[0]))
        k3 = (v + h / 2 * k2[1], fb - wb * (x + h / 2 * k2[0]))
        k4 = (v + h * k3[1], fc - wc * (x + h * k3[0]))
        x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        out[i + 1] = x
    J = jac_fun.map(N)(q.T).full().reshape(3, N, m)
    return np.einsum("knj,nj->nk", J, out)


DT = 2e-3
results, rows = {}, []
for name, mv in moves.items():
    plain = simulate_prescribed(model, mv, dt=DT, t_end=mv.t_end)
    t0 = mv.time_grid(DT)
    lin0 = residual_amplitude(t0, decoupled((t0, *mv.sample(t0))), mv.duration)
    full0 = residual_amplitude(plain.t, plain.tip_deflection, mv.duration)
    results[name] = {"unshaped": plain}
    for margin in (0.0, 0.2):
        res = designs[name, margin]
        ref = shaped_reference(res.shaper, mv, dt=DT)
        end = mv.duration + res.duration
        sim = simulate_prescribed(model, ref, dt=DT, t_end=mv.t_end + res.duration)
        results[name][margin] = sim
        lin = residual_amplitude(ref[0], decoupled(ref), end)
        full = residual_amplitude(sim.t, sim.tip_deflection, end)
        rows.append([name, f"{margin:.0%}", f"{res.duration:.3f}",
                     f"{1e3 * lin0:.1f} → {1e3 * lin:.1f}", f"{1 - lin / lin0:.0%}",
                     f"{1e3 * full0:.1f} → {1e3 * full:.1f}", f"{1 - full / full0:.0%}"])
table(rows, ["move", "margin", "T [s]", "eq. 194 residual [mm]", "cut",
             "full model residual [mm]", "cut"])

# %%
fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
for ax, name in zip(axes, moves, strict=True):
    for key, label in (("unshaped", "unshaped"), (0.0, "shaped, spans"),
                       (0.2, "shaped, spans ±20 %")):
        sim = results[name][key]
        ax.plot(sim.t, 1e3 * np.linalg.norm(sim.tip_deflection, axis=1), label=label,
                lw=1.0)
    ax.axvline(moves[name].duration, color="k", lw=0.8, ls=":", label="end of the move")
    ax.set(ylabel="‖tip deflection‖₂ [mm]", title=name)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
axes[-1].set_xlabel("t [s]")
fig.tight_layout()

# %% [markdown]
# The unshaped 2 s moves leave 8–19 cm of residual tip vibration on this very flexible arm
# (5 × 7 mm links of 1 m). In the decoupled model of eq. 194 — the model the design
# assumes — every shaper cuts it by 92–95 %, the rest being the tolerances Vtol
# themselves. In the full model the Coriolis and centrifugal coupling, which input shaping
# cannot cancel (the method relies on superposition, §6.1.4), excites the modes too:
#
# * move 2 is planar and hardly affected (93–95 % less with either shaper);
# * move 1 turns the whole arm about the vertical while it bends: the shaper designed on the
#   bare spans leaves a quarter of the residual (75 % less), the ±20 % shaper 15 % (85 %
#   less) — the dissertation also notes "a small amount of residual oscillation … due to
#   non-linear effects" for move 1;
# * move 3 swings the arm half a turn at up to π rad/s: the centrifugal load drives mode 2,
#   which its tolerances leave unconstrained (r₂ = 0, Vtol = 1), and the shaper for the
#   single frequencies cuts the residual by 82 %; the ±20 % shaper, longer and smoother,
#   cuts it by 97 %.
#
# So the contributions of eq. 196 choose the right modes and tolerances for the linear
# part of the response, and the ±20 % margin — more than the model error — is what covers
# the non-linear coupling on the spatial moves, at the price of longer shapers.

# %% [markdown]
# ## 4.6 How far from optimal, and on the loop's sample grid
#
# With damping, eq. 187 divides the residual vibration by the unshaped response one
# shaper duration earlier: a tiny impulse placed late lowers it through `exp(-ζωt_n)`
# while the vibration actually left stays large. The SI design therefore constrains the
# vibration left *at the same instant* (`residual_vibration(..., definition="same_instant")`,
# never below eq. 187's value, equal when undamped) and reports eq. 187's number beside it.
#
# With the impulse times fixed on a grid the design is a linear program per duration;
# a search on the duration (one HiGHS model kept across durations, a secant search on the
# smallest reachable V/Vtol) gives the shortest grid shaper (`grid_optimum`), which
# starts the Ipopt polish and bounds it. Below: random problems (1–3 ranges in 1–30 Hz,
# widths 5–60 %, Vtol 2–20 %, ζ 0–0.05): the designed duration relative to the grid
# optimum. The polish, free to move the impulses off the grid, ends shorter. (The tests
# compare casflex on 30 such problems with an LP written independently in the test module;
# from the dissertation's convolved-EI start these problems mostly run out of the 60 s
# time limit on this machine, which is why they are not drawn.)

# %%
from casflex.plotting import plot_digital_shaper, plot_si_optimality  # noqa: E402

rng = np.random.default_rng(2014)
lp_opt, polished = [], []
for _ in range(6):
    problem = []
    for _ in range(int(rng.integers(1, 4))):
        centre, width = 2 * math.pi * rng.uniform(1, 30), rng.uniform(0.05, 0.6)
        problem.append(FrequencyRange(centre * (1 - width / 2), centre * (1 + width / 2),
                                      rng.uniform(0, 0.05), rng.uniform(0.02, 0.2)))
    res = si_shaper(problem)
    lp_opt.append(res.lp_duration)
    polished.append(res.duration)
plot_si_optimality(lp_opt, polished)

# %% [markdown]
# The design job's loop runs at `dt = 1 ms` (`problems/studies/arm2link_move1.toml`): its
# shaper must have its impulses on that grid, or the shaper the loop runs is not the one
# that was verified. `si_shaper(ranges, dt=...)` solves the grid LP on the sample grid
# itself and verifies the result; here for move 1 with the ±20 % margin.

# %%
analogue = designs["move1", 0.2]
digital = si_shaper(analogue.ranges, dt=1e-3)
print(f"analogue {analogue.duration:.4f} s, digital {digital.duration:.4f} s, "
      f"max V {np.round(digital.max_prv, 4).tolist()} <= Vtol "
      f"{np.round([r.vtol for r in analogue.ranges], 4).tolist()}")
plot_digital_shaper(analogue.shaper, digital.shaper, 1e-3)

# %% [markdown]
# **Next:** [5. Control](05_control.ipynb) closes the loop: which modes the joints can
# reach, and two controllers that use the estimated flexible states.
