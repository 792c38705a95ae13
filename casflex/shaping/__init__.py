"""Input shaping (§6.1 of the reference dissertation).

The package reads as its data flow: impulse sequences and their residual vibration
(:mod:`~casflex.shaping.shapers`, nothing of robots), frequency ranges and problem files
(:mod:`~casflex.shaping.ranges`), specified-insensitivity design over them
(:mod:`~casflex.shaping.si`), and the shaper of a planned move of an arm
(:mod:`~casflex.shaping.for_moves`). Residual vibration is a *fraction* (0.05 = 5 %);
units are SI (s, rad, rad/s, m).

Shapers and residual vibration (:mod:`casflex.shaping.shapers`)
----------------------------------------------------------------
Shaper                      impulse times (s) and amplitudes (sum 1)
convolve                    multi-mode shaper from several shapers
merge_closest               closest impulses merged down to a number of impulses
residual_vibration          PRV fraction V(ω, ζ) of a shaper (eq. 187–189, or same instant)
DEFINITIONS                 the two definitions of V: "eq187", "same_instant"
residual_vibration_casadi   the same as a CasADi expression (for NLPs)
sensitivity_curve           V over a band of frequencies
band_maximum                largest V over a band (grid refined at its maxima)

Closed-form shapers (:mod:`casflex.shaping.shapers`)
----------------------------------------------------
zv                          zero vibration (eq. 190–191)
zvd                         zero vibration and derivative
ei                          extra-insensitive
ei_two_hump                 two-hump extra-insensitive
ei_three_hump               three-hump extra-insensitive

EI family in normalised time (:mod:`casflex.shaping.ei_family`)
---------------------------------------------------------------
ei_family_normalised        EI-family times (ω t) and amplitudes: closed form, fit or solve
EI_KINDS                    the kinds: "ei", "ei2", "ei3"
EI_FIT_BOXES                the (ζ, vtol) box of each kind's 2-D Chebyshev fit

More closed-form shapers (:mod:`casflex.shaping.family`)
--------------------------------------------------------
mzv                         modified ZV: three impulses 3/8 of a damped period apart
um_zv                       unity-magnitude (negative) ZV: impulses +1, -1, +1
UM_ZV_PEAK_FACTOR           bound of a UM-ZV-shaped command's peak over the unshaped one
um_zvd                      unity-magnitude (negative) ZVD: impulses +1, -1, +1, -1, +1
UM_ZVD_PEAK_FACTOR          bound of a UM-ZVD/UM-EI-shaped command's peak over the unshaped one (5)
um_ei                       unity-magnitude (negative) EI: five unit impulses, a hump vtol
sna_zv                      specified-negative-amplitude ZV: impulses A1, -N, A3 (peak 1+2N)

Shaping a reference (:mod:`casflex.shaping.shapers`)
----------------------------------------------------
apply_shaper                convolve sampled joint references with a shaper

Frequency ranges (:mod:`casflex.shaping.ranges`)
------------------------------------------------
FrequencyRange              band of frequencies with a damping ratio and a tolerance
ranges_from_mapping         ranges of a parsed shaper problem
load_shaper_problem         ranges of a shaper problem file (TOML ``[[range]]`` tables)

Specified-insensitivity shapers (:mod:`casflex.shaping.si`)
-----------------------------------------------------------
SISample                    sample frequencies of the SI constraints
NLPSolution                 outcome of one SI NLP solve
solve_si_nlp                one minimum-duration NLP (Ipopt or SLSQP)
SIShaperResult              result of the SI design
DEFAULT_TIME_LIMIT          default wall-clock limit of an SI design, s
HESSIAN_TERMS_PER_SECOND    NLP size allowed per second of the time limit left
si_shaper                   SI design: solves, prune-and-merge, dense-grid verification
si_shaper_slsqp             the same with SciPy's SLSQP
si_nlp_with_hessian         the SI NLP in MX with its exact Hessian as matrix products
LP_GRID_STEPS               steps of the grid LP's time grid up to its horizon
LP_MAX_SAMPLES              most samples for which the grid LP start is tried

Shapers on a time grid (:mod:`casflex.shaping.grid_lp`)
-------------------------------------------------------
GridOptimum                 the shortest shaper on a time grid, with its lower bound
grid_optimum                secant search on the duration, one cutting-plane LP per duration
LP_MAX_SOLVES               budget of LP solves of one grid search (deterministic)
grid_near                   the grid shaper nearest an analogue one (digital shapers)
grid_feasible               one feasibility LP on a given grid

The cache of SI designs (:mod:`casflex.shaping.si_cache`)
--------------------------------------------------------
cached_si_design            an SI design kept in casflex's cache, keyed on ranges and options

The convolved EI start (:mod:`casflex.shaping.si_start`)
--------------------------------------------------------
initial_si_guess            convolved EI shapers at the range midpoints
GUESS_MAX_IMPULSES          most impulses the initial guess keeps

Shapers for planned moves (:mod:`casflex.shaping.for_moves`)
------------------------------------------------------------
modal_displacements         displacement of a point per unit modal amplitude (eq. 197)
modal_contributions         contribution of every mode along a move (eq. 196)
tolerances_from_contributions  Vtol of every mode (eq. 198)
frequencies_along           natural frequencies along a move
frequency_ranges_along      frequency ranges swept along a move, with a margin
MoveShaperResult            result of the design for a move
shaper_for_move             SI shaper of a move for a model
shaper_for_robot_move       the same, building the gravity-free model of a robot
shaped_reference            sampled, shaped reference of a move
residual_amplitude          largest deflection after the move
"""

from __future__ import annotations

from casflex.shaping.ei_family import (
    EI_FIT_BOXES,
    EI_KINDS,
    ei_family_normalised,
)
from casflex.shaping.family import (
    UM_ZV_PEAK_FACTOR,
    UM_ZVD_PEAK_FACTOR,
    mzv,
    sna_zv,
    um_ei,
    um_zv,
    um_zvd,
)
from casflex.shaping.for_moves import (
    MoveShaperResult,
    frequencies_along,
    frequency_ranges_along,
    modal_contributions,
    modal_displacements,
    residual_amplitude,
    shaped_reference,
    shaper_for_move,
    shaper_for_robot_move,
    tolerances_from_contributions,
)
from casflex.shaping.grid_lp import (
    LP_MAX_SOLVES,
    GridOptimum,
    grid_feasible,
    grid_near,
    grid_optimum,
)
from casflex.shaping.ranges import FrequencyRange, load_shaper_problem, ranges_from_mapping
from casflex.shaping.shapers import (
    DEFINITIONS,
    Shaper,
    apply_shaper,
    band_maximum,
    convolve,
    ei,
    ei_three_hump,
    ei_two_hump,
    merge_closest,
    residual_vibration,
    residual_vibration_casadi,
    sensitivity_curve,
    zv,
    zvd,
)
from casflex.shaping.si import (
    DEFAULT_TIME_LIMIT,
    HESSIAN_TERMS_PER_SECOND,
    LP_GRID_STEPS,
    LP_MAX_SAMPLES,
    NLPSolution,
    SISample,
    SIShaperResult,
    si_shaper,
    si_shaper_slsqp,
    solve_si_nlp,
)
from casflex.shaping.si_cache import cached_si_design
from casflex.shaping.si_hessian import si_nlp_with_hessian
from casflex.shaping.si_start import GUESS_MAX_IMPULSES, initial_si_guess

__all__ = [
    # shapers and residual vibration
    "Shaper",
    "convolve",
    "merge_closest",
    "residual_vibration",
    "DEFINITIONS",
    "residual_vibration_casadi",
    "sensitivity_curve",
    "band_maximum",
    # closed-form shapers
    "zv",
    "zvd",
    "ei",
    "ei_two_hump",
    "ei_three_hump",
    "ei_family_normalised",
    "EI_KINDS",
    "EI_FIT_BOXES",
    "mzv",
    "um_zv",
    "UM_ZV_PEAK_FACTOR",
    "um_zvd",
    "UM_ZVD_PEAK_FACTOR",
    "um_ei",
    "sna_zv",
    # shaping a reference
    "apply_shaper",
    # specified-insensitivity shapers
    "FrequencyRange",
    "ranges_from_mapping",
    "load_shaper_problem",
    "SISample",
    "NLPSolution",
    "SIShaperResult",
    "solve_si_nlp",
    "initial_si_guess",
    "GUESS_MAX_IMPULSES",
    "DEFAULT_TIME_LIMIT",
    "HESSIAN_TERMS_PER_SECOND",
    "si_shaper",
    "si_shaper_slsqp",
    "si_nlp_with_hessian",
    "cached_si_design",
    "LP_GRID_STEPS",
    "LP_MAX_SAMPLES",
    "LP_MAX_SOLVES",
    # shapers on a time grid
    "GridOptimum",
    "grid_optimum",
    "grid_near",
    "grid_feasible",
    # shapers for planned moves
    "modal_displacements",
    "modal_contributions",
    "tolerances_from_contributions",
    "frequencies_along",
    "frequency_ranges_along",
    "MoveShaperResult",
    "shaper_for_move",
    "shaper_for_robot_move",
    "shaped_reference",
    "residual_amplitude",
]
