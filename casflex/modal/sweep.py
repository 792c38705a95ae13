"""Natural frequencies along a path of configurations, sorted or tracked by MAC.

:func:`frequency_sweep` is the computation behind ``casflex sweep`` (dissertation Fig. 25
sorted, Fig. 26 tracked): the TMM at every configuration, in parallel, and, when asked,
the modes followed from one configuration to the next by
:func:`casflex.modal.tracking.track`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from casflex._parallel import parallel_map
from casflex._validate import BOUNDS
from casflex.errors import ModelError

if TYPE_CHECKING:
    from casflex.robot import Robot

__all__ = ["FrequencySweep", "frequency_sweep"]

#: modes computed beyond the requested count when tracking, so that modes crossing in
#: from above are seen
TRACKING_EXTRA_MODES = 2


@dataclass(frozen=True)
class FrequencySweep:
    """Natural frequencies along a path of configurations.

    Attributes
    ----------
    q : numpy.ndarray
        (k, n_joints) configurations [rad].
    omega : numpy.ndarray
        (k, count) natural frequencies [rad/s]: ascending per configuration, or, when
        ``tracked``, column ``j`` follows one mode along the path.
    tracked : bool
        Whether the columns follow modes (MAC tracking) or are sorted.
    min_mac : float or None
        Lowest MAC between tracked neighbours (``None`` when not tracked); below about
        0.9 a mode changes fast between neighbours and the path should be finer.

    Examples
    --------
    >>> s = FrequencySweep(np.zeros((2, 3)), np.ones((2, 1)), False, None)
    >>> s.omega_hz.shape
    (2, 1)
    """

    q: np.ndarray
    omega: np.ndarray
    tracked: bool
    min_mac: float | None

    @property
    def omega_hz(self) -> np.ndarray:
        """The frequencies in Hz."""
        return self.omega / (2.0 * np.pi)


def point_frequencies(robot: Robot, q: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` lowest natural frequencies at one configuration [rad/s] (the
    per-point task of an untracked sweep; module level so that it pickles).

    Parameters
    ----------
    robot : casflex.robot.Robot
        The structure.
    q : numpy.ndarray
        Joint values [rad].
    count : int
        Number of frequencies.

    Examples
    --------
    >>> from casflex.robot import load
    >>> point_frequencies(load("problems/arm2link.toml"), np.zeros(3), 1).round(2)
    array([8.31])
    """
    from casflex.tmm import natural_frequencies

    return natural_frequencies(robot, q, count=count)


def frequency_sweep(robot: Robot, qs: ArrayLike, count: int, *, track: bool = False,
                    joint: int | None = None, processes: int | None = None,
                    progress: bool = False) -> FrequencySweep:
    """Natural frequencies at every configuration of a path, sorted or tracked.

    Parameters
    ----------
    robot : casflex.robot.Robot
        The structure.
    qs : array_like
        (k, n_joints) configurations along the path [rad], in order.
    count : int
        Number of frequencies (modes) per configuration, ``>= 1``.
    track : bool
        Follow the modes by MAC with continuous sign instead of sorting the frequencies.
    joint : int, optional
        0-based joint that changes along the path; when tracking, a configuration with a
        multiple root is stepped off along it.
    processes : int, optional
        Local process pool size (default ``os.cpu_count()``; ``1`` runs in this process).
    progress : bool
        Progress bar on stderr.

    Returns
    -------
    FrequencySweep

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> qs = np.zeros((3, 3)); qs[:, 2] = [-0.2, -0.1, 0.0]
    >>> s = frequency_sweep(robot, qs, 2, processes=1)
    >>> s.omega[-1].round(2).tolist(), s.min_mac is None
    ([8.31, 11.97], True)
    >>> frequency_sweep(robot, qs, 2, track=True, joint=2, processes=1).min_mac > 0.99
    True
    """
    from casflex.modal.tables import compute_modes
    from casflex.modal.tracking import track as track_modes

    qs = np.atleast_2d(np.asarray(qs, dtype=float))
    if not track:
        omega = np.empty((len(qs), count))
        jobs = [(i, (robot, q, count)) for i, q in enumerate(qs)]
        for i, w in parallel_map(point_frequencies, jobs, processes=processes,
                                 progress=progress, desc="TMM"):
            omega[i] = w
        _check_frequencies(robot, qs, omega)
        return FrequencySweep(qs, omega, False, None)
    directions = None
    if joint is not None:
        along = np.zeros(qs.shape[1])
        along[joint] = 1.0
        directions = [along, -along]
    seq = compute_modes(robot, qs, count + TRACKING_EXTRA_MODES, processes=processes,
                        progress=progress, directions=directions)
    tracked = track_modes(seq, count=count, robot=robot)
    mac = np.asarray(tracked.mac, dtype=float)
    min_mac = float(np.nanmin(mac)) if np.isfinite(mac).any() else 1.0
    omega = tracked.omega(seq)
    _check_frequencies(robot, qs, omega)
    return FrequencySweep(qs, omega, True, min_mac)


def _check_frequencies(robot, qs, omega):
    """Natural frequencies of a constrained flexible arm are finite, > 0 and plausible
    (``BOUNDS["natural_frequency"]``): anything else is a numerical breakdown of the modal
    analysis (E = 1e40 gave 8e-16 rad/s), not a result."""
    bound = BOUNDS["natural_frequency"]
    with np.errstate(invalid="ignore"):
        bad = ~(np.isfinite(omega) & (omega >= bound.low) & (omega <= bound.high))
    if np.any(bad):
        i, k = map(int, np.argwhere(bad)[0])
        raise ModelError(f"robot '{robot.name}': natural frequency {k + 1} at configuration "
                         f"{i + 1} of the sweep, q = {np.round(qs[i], 6).tolist()} rad, came "
                         f"back as {float(omega[i, k])!r} rad/s; it {bound.rule} (check the "
                         "robot's stiffness and mass values)")
