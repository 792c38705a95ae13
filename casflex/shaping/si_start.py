"""The start of the SI design from closed-form shapers: EI-family shapers at the range
midpoints, convolved (§6.1.3), with the closest impulses merged so that the start stays
bounded for many ranges.

Units are SI: times in s, frequencies in rad/s.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from casflex.errors import ProblemFileError, SolverError
from casflex.shaping.ranges import FrequencyRange, as_ranges
from casflex.shaping.shapers import (
    Shaper,
    ei,
    ei_three_hump,
    ei_two_hump,
    merge_closest,
    residual_vibration,
)

__all__ = ["GUESS_MAX_IMPULSES", "initial_si_guess"]


def _guess_component(r):
    """Shaper of the EI family at the range midpoint for the initial guess.

    The EI shaper is used when it keeps V below vtol over the whole range (always the case
    for ranges narrower than about ±20 % at 5 %); otherwise the two-hump, then the
    three-hump EI shaper, and finally three-hump convolved with EI (so that the NLP has enough
    impulses to be feasible). A damped form that cannot be solved falls back to the undamped
    form at the damped midpoint frequency.
    """
    vtol = min(r.vtol, 0.999)
    w = np.linspace(r.omega_min, r.omega_max, 201)

    def build(fun):
        try:
            return fun(r.omega_mid, r.zeta, vtol)
        except SolverError:
            return fun(r.omega_mid * math.sqrt(1.0 - r.zeta**2), 0.0, vtol)

    candidates = [build(ei), build(ei_two_hump), build(ei_three_hump)]
    for cand in candidates:
        if np.max(residual_vibration(cand, w, r.zeta, definition="same_instant")) <= r.vtol * (
                1.0 + 1e-9):
            return cand
    return candidates[-1].convolve(candidates[0])


#: Most impulses the initial guess keeps while the ranges' shapers are convolved one by one
#: (4³: three two-hump EI shapers convolve unmerged); beyond it the closest impulses are
#: merged after each convolution, so that the guess and its NLP stay bounded (3^n else).
GUESS_MAX_IMPULSES = 64

def initial_si_guess(ranges: FrequencyRange | Iterable, n_impulses: int | None = None
                     ) -> Shaper:
    """Start point of the SI design: EI shapers at the range midpoints convolved (§6.1.3).

    Ranges with ``vtol >= 1`` impose nothing and are skipped. The shapers are convolved one
    by one; whenever a convolution has more than :data:`GUESS_MAX_IMPULSES` impulses, the
    closest adjacent impulses are merged (amplitude-weighted time, summed amplitude) down to
    that number, so that the guess stays bounded for many ranges. With ``n_impulses`` the
    closest impulses of the result are then merged until at most that many remain.

    Parameters
    ----------
    ranges : list of FrequencyRange
    n_impulses : int, optional
        Maximum number of impulses of the guess.

    Returns
    -------
    Shaper

    Raises
    ------
    ProblemFileError
        ``n_impulses < 1``.

    Examples
    --------
    >>> hz = 2 * math.pi
    >>> g = initial_si_guess([FrequencyRange(3 * hz, 4 * hz, 0.0, 0.05),
    ...                       FrequencyRange(9 * hz, 13 * hz, 0.0, 0.05),
    ...                       FrequencyRange(20 * hz, 24 * hz, 0.0, 0.05)])
    >>> round(g.duration, 3)
    0.422

    Ten ranges would convolve to 3^10 = 59049 impulses:

    >>> many = [FrequencyRange(f * hz, 1.1 * f * hz, 0.0, 0.05) for f in range(1, 11)]
    >>> len(initial_si_guess(many)) == GUESS_MAX_IMPULSES
    True
    """
    ranges = as_ranges(ranges)
    if n_impulses is not None:
        n_impulses = int(n_impulses)
        if n_impulses < 1:
            raise ProblemFileError(None, "n_impulses", n_impulses, "must be >= 1")
    parts = [_guess_component(r) for r in ranges if r.vtol < 1.0]
    if not parts:
        return Shaper([0.0], [1.0])
    guess = parts[0]
    for part in parts[1:]:
        guess = guess.convolve(part)
        if len(guess) > GUESS_MAX_IMPULSES:
            guess = merge_closest(guess, GUESS_MAX_IMPULSES)
    if n_impulses is not None:
        guess = merge_closest(guess, n_impulses)
    return guess
