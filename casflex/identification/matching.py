"""Mode matching: measured modes paired with modelled ones by MAC at the sensors.

Where a measurement row carries identified mode shapes at accelerometer channels (the
``f<j>_<channel>`` columns of a measurement file, or the signed amplitudes of
:attr:`ModalEstimate.shape` for logs), the model's mode shapes are evaluated at the same
channels and measured mode ``j`` is paired with the modelled mode that maximises the
Modal Assurance Criterion

    MAC(φ, ψ) = (φᵀψ)² / ((φᵀφ)(ψᵀψ))

over a one-to-one assignment (:func:`scipy.optimize.linear_sum_assignment` on
``1 − MAC + TIE_BREAK · |f_model − f_meas| / f_meas``: between modes of nearly equal MAC the
nearer frequency wins). Measured modes without shapes take the remaining modelled modes in
frequency order. A pair whose MAC is below ``MAC_MIN`` is refused (:class:`ModelError`):
the measured shape matches no modelled mode, and fitting its frequency would be fitting the
wrong mode.

Channel geometry
================
The channels are described by a casflex sensor file (``problems/sensors/*.toml``, format in
``problems/README.md``), read here as plain data: every ``[[sensor]]`` of type
``accelerometer`` gives the channels ``<name>_<axis>`` for its ``axes`` (default ``xyz``)
at arc length ``s`` on ``link`` (a link name or a 0-based DH row), with the sensing
element's ``offset`` from the neutral axis and its ``frame``; other sensors are skipped.
A channel's modal value is the linearised displacement of the sensing element, ``w(s) +
ϑ(s) × offset``, along the local beam axis (``frame = "sensor"``: the deflected link's axes
at the sensor, which to first order in the deflection are the undeformed beam's) or along
the base frame's axis (``"inertial"``). The acceleration shape is ``−ω²`` times it, the same
vector up to scale, which MAC ignores.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from casflex._problemfile import TableReader, read_toml
from casflex.errors import ModelError, ProblemFileError
from casflex.robot import Robot

__all__ = ["Channel", "read_channels", "model_channel_shapes", "mac_matrix", "match_modes"]

#: lowest MAC accepted for a measured-modelled pair
MAC_MIN = 0.7
#: weight of the relative frequency distance in the assignment cost
TIE_BREAK = 0.01
#: modelled modes offered to the matching beyond the measured ones
EXTRA_MODES = 2

_AXES = "xyz"


@dataclass(frozen=True)
class Channel:
    """One accelerometer axis at a point of a flexible link.

    Attributes
    ----------
    name : str
        Channel name (``<sensor>_<axis>``), as in the measurement file and the logs.
    row : int
        0-based DH row of the link.
    s : float
        Arc length from the link's start [m].
    axis : int
        0, 1, 2 for x, y, z.
    offset : tuple of float
        Sensing element from the neutral axis, local beam frame [m].
    frame : str
        ``"sensor"`` (local beam axes) or ``"inertial"`` (base-frame axes).

    Examples
    --------
    >>> Channel("tip_y", 3, 1.0, 1, (0.0, 0.0, 0.0), "sensor").axis
    1
    """

    name: str
    row: int
    s: float
    axis: int
    offset: tuple[float, float, float]
    frame: str


def read_channels(path: str | os.PathLike, robot: Robot) -> list[Channel]:
    """The accelerometer channels of a sensor file (format in the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        Sensor file (TOML, ``[[sensor]]`` tables).
    robot : casflex.robot.Robot
        The robot the links refer to.

    Returns
    -------
    list of Channel

    Raises
    ------
    ProblemFileError
        Naming the file, the field, the value and the rule.

    Examples
    --------
    >>> from casflex.robot import load
    >>> chans = read_channels("problems/sensors/arm2link_accel.toml",
    ...                       load("problems/arm2link.toml"))
    >>> [c.name for c in chans][:4], chans[3].row
    (['tip1_x', 'tip1_y', 'tip1_z', 'tip2_x'], 3)
    """
    data = read_toml(path)
    tables = data.get("sensor")
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ProblemFileError(path, "sensor", tables, "give [[sensor]] tables")
    names = [link.name for link in robot.links]
    out = []
    for i, table in enumerate(tables):
        r = TableReader(path, table, f"sensor[{i}]")
        if table.get("type", "accelerometer") != "accelerometer":
            continue
        name = r.string("name", f"acc{i + 1}")
        link = table.get("link")
        if isinstance(link, str) and link in names:
            row = names.index(link)
        elif isinstance(link, int) and not isinstance(link, bool) and 0 <= link < len(names):
            row = link
        else:
            raise r.error("link", link, "must name a link of the robot: " + ", ".join(names))
        if robot.links[row].section is None:
            raise r.error("link", link, "must be a flexible link (one with a section)")
        s = r.number("s", required=True)
        if not 0.0 <= s <= robot.links[row].length * (1 + 1e-12):
            raise r.error("s", s, f"must lie on the link: 0 <= s <= {robot.links[row].length}")
        axes = table.get("axes", _AXES)
        if not isinstance(axes, str) or not axes or any(a not in _AXES for a in axes) or len(
                set(axes)) != len(axes):
            raise r.error("axes", axes, "must be distinct letters of 'xyz'")
        offset = r.vector("offset", 3, (0.0, 0.0, 0.0))
        frame = r.string("frame", "sensor", choices=("sensor", "inertial"))
        for a in axes:
            out.append(Channel(f"{name}_{a}", row, float(s), _AXES.index(a),
                               tuple(float(v) for v in offset), frame))
    if not out:
        raise ProblemFileError(path, "sensor", None, "holds no accelerometer")
    return out


def model_channel_shapes(robot: Robot, q: np.ndarray, channels: list[Channel], count: int
                         ) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` lowest modelled modes at ``q`` and their shapes at the channels.

    Parameters
    ----------
    robot : casflex.robot.Robot
        The model.
    q : numpy.ndarray
        (n_joints,) configuration [rad].
    channels : list of Channel
        Where the shapes are read.
    count : int
        Number of modes.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Frequencies (count,) [Hz] and shapes (count, C) [m per unit peak displacement].

    Examples
    --------
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> chans = read_channels("problems/sensors/arm2link_accel.toml", robot)
    >>> f, phi = model_channel_shapes(robot, np.zeros(3), chans, 2)
    >>> f.round(3), phi.shape
    (array([1.322, 1.905]), (2, 6))
    """
    from casflex.tmm import modes

    shapes = modes(robot, np.asarray(q, dtype=float), count=count, n_points=201)
    out = np.empty((shapes.omega.size, len(channels)))
    for c, ch in enumerate(channels):
        b = shapes.rows.index(ch.row)
        s = shapes.s[b]
        u = np.array([[np.interp(ch.s, s, shapes.displacement[k, b, :, i]) for i in range(3)]
                      for k in range(shapes.omega.size)])
        th = np.array([[np.interp(ch.s, s, shapes.rotation[k, b, :, i]) for i in range(3)]
                       for k in range(shapes.omega.size)])
        local = u + np.cross(th, np.asarray(ch.offset))
        vec = local if ch.frame == "sensor" else local @ shapes.R[b].T
        out[:, c] = vec[:, ch.axis]
    return shapes.omega / (2.0 * np.pi), out


def mac_matrix(measured: np.ndarray, modelled: np.ndarray) -> np.ndarray:
    """Modal Assurance Criterion between two sets of shapes.

    Parameters
    ----------
    measured : numpy.ndarray
        (J, C) shapes [any unit].
    modelled : numpy.ndarray
        (K, C) shapes [any unit].

    Returns
    -------
    numpy.ndarray
        (J, K) MAC values in [0, 1] (0 for a zero shape).

    Examples
    --------
    >>> mac_matrix(np.array([[1.0, 0.0]]), np.array([[2.0, 0.0], [1.0, 1.0]])).round(3)
    array([[1. , 0.5]])
    """
    a, b = np.atleast_2d(measured), np.atleast_2d(modelled)
    num = (a @ b.T) ** 2
    den = np.outer(np.sum(a * a, axis=1), np.sum(b * b, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), 0.0)


def match_modes(measured_hz: np.ndarray, measured_shapes: np.ndarray | None,
                model_hz: np.ndarray, model_shapes: np.ndarray | None, *,
                mac_min: float = MAC_MIN, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Pair the measured modes of one configuration with modelled modes.

    Parameters
    ----------
    measured_hz : numpy.ndarray
        (m,) measured frequencies [Hz], NaN where not seen.
    measured_shapes : numpy.ndarray or None
        (m, C) identified shapes at the channels, a row of NaN where a mode has none.
    model_hz : numpy.ndarray
        (K,) modelled frequencies [Hz], ascending, K >= m.
    model_shapes : numpy.ndarray or None
        (K, C) modelled shapes at the same channels.
    mac_min : float
        Lowest MAC accepted for a pair.
    where : str
        Named in errors (the measurement row).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        (m,) index of the modelled mode paired with each measured one (0-based; measured
        modes not seen get -1) and (m,) the MAC of each pair (NaN without shapes).

    Raises
    ------
    ModelError
        A pair with MAC below ``mac_min``.

    Examples
    --------
    >>> phi = np.array([[0.0, 1.0], [1.0, 0.0], [1.0, 1.0]])
    >>> idx, mac = match_modes(np.array([2.0, 3.0]), phi[[0, 2]],
    ...                        np.array([1.9, 2.1, 3.1]), phi)
    >>> idx.tolist(), mac.round(3).tolist()
    ([0, 2], [1.0, 1.0])
    """
    from scipy.optimize import linear_sum_assignment

    mac_min = _check_mac_min(mac_min)
    m, k = measured_hz.size, model_hz.size
    pair = np.full(m, -1)
    mac = np.full(m, np.nan)
    seen = np.isfinite(measured_hz)
    with_shape = np.zeros(m, dtype=bool)
    if measured_shapes is not None and model_shapes is not None:
        with_shape = seen & np.all(np.isfinite(measured_shapes), axis=1) & np.any(
            measured_shapes != 0.0, axis=1)
    taken = np.zeros(k, dtype=bool)
    js = np.flatnonzero(with_shape)
    if js.size:
        macs = mac_matrix(measured_shapes[js], model_shapes)
        cost = 1.0 - macs + TIE_BREAK * np.abs(model_hz[None, :] - measured_hz[js, None]
                                               ) / measured_hz[js, None]
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols, strict=True):
            pair[js[r]], mac[js[r]] = c, macs[r, c]
            taken[c] = True
            if macs[r, c] < mac_min:
                best = int(np.argmax(macs[r]))
                raise ModelError(
                    f"{where}mode f{js[r] + 1} ({measured_hz[js[r]]:.6g} Hz): its measured "
                    f"shape matches no modelled mode (MAC {macs[r, c]:.3f} with modelled mode "
                    f"{c + 1} at {model_hz[c]:.6g} Hz, best {macs[r, best]:.3f} with mode "
                    f"{best + 1}; at least {mac_min:g} is required): check the channel "
                    "geometry, or drop this mode's shape columns to match it by frequency order")
    free = iter(np.flatnonzero(~taken))
    for j in np.flatnonzero(seen & ~with_shape):
        c = next(free, None)
        if c is None:
            raise ModelError(f"{where}more measured modes than the {k} modelled ones offered")
        pair[j] = c
    return pair, mac


def _check_mac_min(mac_min: float) -> float:
    if not (isinstance(mac_min, (int, float)) and math.isfinite(mac_min) and 0 < mac_min <= 1):
        raise ModelError(f"mac_min: must lie in (0, 1]; got {mac_min}")
    return float(mac_min)
