"""Slow (rigid) tracking gains chosen from a move and the arm's lowest natural frequency.

The slow law of the composite controller (eq. 248) and the inversion-based law (eq. 210)
impose ``ë + K_d ė + K_p e = 0`` on the joint error ``e = q_d − q``. With
``K_p = ω_c²`` and ``K_d = 2 ζ ω_c`` that is a second-order loop of natural frequency
(bandwidth) ``ω_c`` and damping ``ζ``. The singular-perturbation design (§6.2.3) needs the
slow loop to be slower than the flexible modes it treats as fast: ``ω_c`` is chosen as a
stated fraction of ``ω_min``, the lowest natural frequency along the move, and the
*separation* ``ω_min / ω_c`` is reported. The dissertation's case study (§6.2.2.2) takes
``K_p = 1``, ``K_d = 2`` (``ω_c = 1`` rad/s) as given; :func:`dissertation_gains` keeps
them.

Examples
--------
>>> g = slow_gains_for_move(6.6, 3.2, fraction=0.5)
>>> round(g.bandwidth, 3), round(g.Kp, 4), round(g.Kd, 3), round(g.separation, 3)
(3.3, 10.89, 6.6, 2.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from casflex._validate import number

__all__ = ["SlowGains", "slow_gains_for_move", "dissertation_gains"]


@dataclass(frozen=True)
class SlowGains:
    """Slow tracking gains and where they come from.

    Attributes
    ----------
    Kp : float
        Position gain [1/s²] (``ω_c²``).
    Kd : float
        Rate gain [1/s] (``2 ζ ω_c``).
    bandwidth : float
        ``ω_c = √K_p`` [rad/s], the natural frequency of the joint-error loop.
    damping : float
        ``ζ = K_d / (2 ω_c)``.
    omega_min : float
        Lowest natural frequency along the move [rad/s].
    separation : float
        ``ω_min / ω_c``: how much faster the slowest flexible mode is than the slow loop.
    move_frequency : float
        ``2π / T`` of the move of duration ``T`` [rad/s]: the lowest frequency of the
        reference the loop has to follow.
    source : str
        ``"move"`` (:func:`slow_gains_for_move`), ``"dissertation"`` or ``"given"``.

    Examples
    --------
    >>> g = dissertation_gains(6.6, 3.2)
    >>> g.Kp, g.Kd, g.bandwidth, g.damping, g.source
    (1.0, 2.0, 1.0, 1.0, 'dissertation')
    """

    Kp: float
    Kd: float
    bandwidth: float
    damping: float
    omega_min: float
    separation: float
    move_frequency: float
    source: str


def _gains(Kp, Kd, omega_min, duration, source):
    omega_min = number(omega_min, "omega_min", low=0.0, low_open=True)
    duration = number(duration, "duration", low=0.0, low_open=True)
    wc = math.sqrt(Kp)
    return SlowGains(Kp=float(Kp), Kd=float(Kd), bandwidth=wc, damping=Kd / (2.0 * wc),
                     omega_min=float(omega_min), separation=omega_min / wc,
                     move_frequency=2.0 * math.pi / duration, source=source)


def slow_gains_for_move(omega_min: float, duration: float, *, fraction: float = 0.3,
                        damping: float = 1.0) -> SlowGains:
    """Slow gains whose bandwidth is ``fraction`` of the lowest natural frequency.

    ``ω_c = fraction · ω_min``, ``K_p = ω_c²``, ``K_d = 2 ζ ω_c`` (module docstring).

    Parameters
    ----------
    omega_min : float
        Lowest natural frequency along the move [rad/s]
        (:func:`casflex.shaping.frequencies_along`).
    duration : float
        Duration of the (shaped) move [s]; gives ``move_frequency`` = 2π/T [rad/s].
    fraction : float
        ``ω_c / ω_min``, in (0, 1): the smaller, the better the time-scale separation the
        singular-perturbation design assumes, the softer the tracking.
    damping : float
        ``ζ`` of the joint-error loop (1: critically damped, no overshoot).

    Returns
    -------
    SlowGains

    Examples
    --------
    >>> g = slow_gains_for_move(6.0, 3.0, fraction=0.25)
    >>> g.Kp, g.Kd, g.separation, g.source
    (2.25, 3.0, 4.0, 'move')
    """
    fraction = number(fraction, "fraction", low=0.0, high=1.0, low_open=True,
                      high_open=True)
    damping = number(damping, "damping", low=0.0, low_open=True)
    omega_min = number(omega_min, "omega_min", low=0.0, low_open=True)
    wc = fraction * omega_min
    return _gains(wc * wc, 2.0 * damping * wc, omega_min, duration, "move")


def dissertation_gains(omega_min: float, duration: float, Kp: float = 1.0,
                       Kd: float = 2.0, *, source: str = "dissertation") -> SlowGains:
    """Fixed slow gains (the dissertation's ``K_p = 1``, ``K_d = 2`` by default), with the
    same separation figures as :func:`slow_gains_for_move`.

    Parameters
    ----------
    omega_min : float
        Lowest natural frequency along the move [rad/s].
    duration : float
        Duration of the (shaped) move [s].
    Kp, Kd : float
        Gains [1/s², 1/s].
    source : str
        Recorded in :attr:`SlowGains.source` (``"given"`` for a study's own gains).

    Returns
    -------
    SlowGains

    Examples
    --------
    >>> g = dissertation_gains(6.6, 3.2)
    >>> round(g.separation, 2), round(g.move_frequency, 3)
    (6.6, 1.963)
    """
    Kp = number(Kp, "Kp", low=0.0, low_open=True)
    Kd = number(Kd, "Kd", low=0.0, low_open=True)
    return _gains(Kp, Kd, omega_min, duration, source)
