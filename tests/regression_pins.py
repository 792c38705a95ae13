"""Regression pins: numbers that casflex itself produced, kept to notice a change.

A pin is not a reference. It says "this is what casflex computed when the value was
checked", not "this is right": the independent checks of the same quantities are named
next to each pin. A pin that moves after a deliberate change of the physics or of a
solver is updated here, with the reason in the commit message; a pin that moves without
one is a bug report. Tests import the values from here so that every golden number
produced by casflex lives in this one file.

Each entry: the value, the tolerance it is held to (the reproducibility of the
computation, not its accuracy) and where it came from.
"""

from __future__ import annotations

#: TMM natural frequencies of the Table 8 arm (problems/arm2link.toml) at q = 0 [rad/s],
#: casflex.tmm.natural_frequencies, count=3, rounded to 0.01 rad/s. Independent checks:
#: the dissertation's 8.26, 11.93, 23.37 rad/s (§3.3.7, 3 %, tests/tmm/test_tmm.py) and
#: the FE reference built from the problem file (1e-6, tests/tmm/test_tmm.py).
ARM2LINK_Q0_OMEGA = (8.31, 11.97, 22.75)
ARM2LINK_Q0_OMEGA_ATOL = 0.005  # half the last printed digit

#: SI shaper durations [s] for moves 1-3 with ±20 % frequency ranges and the
#: dissertation's tolerances, casflex.shaping.shaper_for_move (Ipopt), session 4
#: (tests/shaping/test_shaping_moves.py, test_margin_makes_shapers_longer). Independent
#: checks: each shaper's residual vibration is verified below its tolerance on every
#: range by casflex.shaping.residual_vibration (itself checked against solve_ivp), and
#: the ±0 % durations against the dissertation's (3 %).
SHAPER_DURATION_MARGIN_20 = {"move1": 1.208, "move2": 0.807, "move3": 0.867}
SHAPER_DURATION_ATOL = 0.01  # the optimiser's tolerance on the duration

#: Peak and residual tip deflection [m] of the Table 9 moves on the Table 8 arm, prescribed
#: joints, 2 tracked modes on a 7.5° grid, no gravity, RK4 at 2 ms
#: (tests/simulate/test_simulate.py, fixture ``moves``), computed with casflex on
#: 2026-12-01 (session 5). Independent checks of the same simulation: RK4 against scipy's
#: DOP853 on the model's equations and the held-joint oscillation at the TMM frequencies
#: (tests/simulate/test_simulate.py); the model's equations against the references of
#: tests/model. Held to 1e-4 relative: reproducibility across BLAS builds and platforms.
TABLE9_TIP_DEFLECTION = {  # name: (max_tip_deflection, residual_tip_deflection)
    "move1": (0.17682076635467792, 0.12116201160907117),
    "move2": (0.08392494741679155, 0.08243648214513442),
    "move3": (0.23983389813336195, 0.18105640464781997),
}
TABLE9_TIP_DEFLECTION_RTOL = 1e-4
