"""More closed-form shapers: modified ZV (MZV), unity-magnitude (negative) ZV and ZVD.

* :func:`mzv`: three positive impulses 3/8 of a damped period apart with zero residual
  vibration at the design frequency; shorter than ZVD (3/4 of a period instead of one)
  and less sensitive than ZV.
* :func:`sna_zv`: the specified-negative-amplitude ZV shaper, impulses ``A, -N, A'`` with
  the negative one chosen (``N = 1``: UM-ZV undamped; ``N = 0``: ZV);
* :func:`um_zvd`: the unity-magnitude ZVD shaper, impulses ``+1, -1, +1, -1, +1``: zero
  vibration and zero slope of the residual vector at the design frequency in 0.7325 of a
  period (ZVD: 1), peak input up to 5 times the command's;
* :func:`um_ei`: the unity-magnitude EI shaper, the same five unit impulses with V = vtol
  at the design frequency (a hump) and zeros on both sides;
* :func:`um_zv`: the unity-magnitude ZV shaper, impulses ``+1, -1, +1``: a step command
  shaped by it switches between the full command and zero (an on-off actuator can run it),
  and it is the shortest shaper with zero vibration whose partial sums stay in [0, 1]
  (one third of a period undamped).

**Peak-input limit of negative shapers.** A shaper with negative impulses applied to a
command ``u(t)`` gives ``Σ A_i u(t - t_i)``, bounded by ``Σ |A_i|`` times the peak of
``|u|`` (3 for UM-ZV, 5 for UM-ZVD and UM-EI, ``1 + 2N`` for SNA-ZV): only for a step
(or a command that is constant over the shaper's duration) do the partial sums (``1, 0,
1`` for UM-ZV) bound it by the command itself. Shaping a
planned joint move with UM-ZV can therefore demand up to three times the move's peak
velocity and acceleration; positive shapers never exceed the unshaped peaks.

The multi-mode shaper of several of these is their convolution
(:func:`~casflex.shaping.convolve`). Units: rad/s, s; damping ratios dimensionless.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from casflex._validate import fail
from casflex.errors import ProblemFileError, SolverError
from casflex.shaping.shapers import Shaper, check_omega, check_zeta

__all__ = ["mzv", "um_zv", "UM_ZV_PEAK_FACTOR", "sna_zv", "um_zvd", "UM_ZVD_PEAK_FACTOR",
           "um_ei"]

#: Bound of the shaped command's peak over the unshaped one for UM-ZV (Σ |A_i|).
UM_ZV_PEAK_FACTOR = 3.0

#: Bound of the shaped command's peak over the unshaped one for UM-ZVD and UM-EI (Σ |A_i|,
#: 1 + 2N with N = 2 negative unit impulses).
UM_ZVD_PEAK_FACTOR = 5.0

#: Largest damping ratio for which :func:`um_zvd` is solved.
_UM_ZVD_ZETA_MAX = 0.3


def mzv(omega: float, zeta: float = 0.0) -> Shaper:
    """Modified zero-vibration (MZV) shaper: three impulses 3/8 of a damped period apart.

    Amplitudes ``[1 - 1/√2, (√2 - 1) K, (1 - 1/√2) K²]`` normalised to sum 1, with
    ``K = exp(-0.75 ζ π / sqrt(1-ζ²))``, at ``0, 3T_d/8, 3T_d/4``
    (``T_d = 2π / (ω sqrt(1-ζ²))``): the residual vector ``Σ A_i exp(ζω t_i + iω_d t_i)``
    vanishes at ω (the phases 0°, 135°, 270° with amplitudes 1 : √2 : 1 close a triangle).

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = mzv(2 * math.pi)
    >>> s.times.tolist(), s.amplitudes.round(4).tolist()
    ([0.0, 0.375, 0.75], [0.2929, 0.4142, 0.2929])
    """
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    root = math.sqrt(1.0 - zeta**2)
    k = math.exp(-0.75 * zeta * math.pi / root)
    a1 = 1.0 - 1.0 / math.sqrt(2.0)
    amps = [a1, (math.sqrt(2.0) - 1.0) * k, a1 * k * k]
    total = sum(amps)
    step = 0.75 * math.pi / (omega * root)
    return Shaper([0.0, step, 2.0 * step], [a / total for a in amps])


def um_zv(omega: float, zeta: float = 0.0) -> Shaper:
    """Unity-magnitude zero-vibration shaper: impulses ``+1, -1, +1`` (sum 1).

    Undamped the impulses are at ``0, T/6, T/3``. With damping the amplitudes stay
    ``±1`` and the times solve ``1 - exp(s t2) + exp(s t3) = 0`` (``s = ζω + iω_d``): for
    a real ``t3 = log(exp(s t2) - 1) / s`` the imaginary part must vanish, a scalar root
    in ``t2`` found by Brent's method between the undamped value and half a period. See the
    module docstring for the peak-input limit (:data:`UM_ZV_PEAK_FACTOR`).

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 0.5.

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = um_zv(2 * math.pi)
    >>> s.times.round(6).tolist(), s.amplitudes.tolist()
    ([0.0, 0.166667, 0.333333], [1.0, -1.0, 1.0])
    """
    from scipy import optimize  # here: importing it costs ~0.5 s
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    if zeta == 0.0:
        period = 2.0 * math.pi / omega
        return Shaper([0.0, period / 6.0, period / 3.0], [1.0, -1.0, 1.0])
    if zeta >= 0.5:
        raise fail("zeta", zeta, "must be < 0.5 for the unity-magnitude ZV shaper",
                   error=ProblemFileError)
    wd = omega * math.sqrt(1.0 - zeta**2)
    s = complex(zeta * omega, wd)

    def t3_of(t2):
        return cmath.log(cmath.exp(s * t2) - 1.0) / s

    t2 = optimize.brentq(lambda x: t3_of(x).imag, 1e-3 * math.pi / wd, math.pi / wd,
                         xtol=1e-15, rtol=1e-15)
    return Shaper([0.0, t2, t3_of(t2).real], [1.0, -1.0, 1.0])


def sna_zv(omega: float, zeta: float = 0.0, negative: float = 1.0) -> Shaper:
    """Specified-negative-amplitude zero-vibration (SNA-ZV) shaper: impulses ``A1, -N, A3``.

    Undamped: ``A1 = A3 = (1+N)/2`` at ``0, θ/ω, 2θ/ω`` with ``cos θ = N/(1+N)``, zero
    vibration at ω (``A2 + 2 A1 cos θ = 0`` about the middle impulse); among three-impulse
    zero-vibration shapers with middle amplitude ``-N`` this is the shortest (for a fixed
    ``A1 + A3`` the largest product ``A1 A3`` allows the smallest angle). ``N = 0`` is ZV
    (two impulses), ``N = 1`` is UM-ZV. Damped, the same decay compensation as ZV, ZVD and MZV: the
    impulse phases of the undamped form with a parameter ``N'`` at the damped frequency
    ``ω_d``, amplitudes ``Ā_i exp(-ζω t_i)`` normalised to sum 1, and ``N'`` found (Brent)
    so that the middle amplitude is exactly ``-N`` (with damping and ``N = 1`` this is not
    :func:`um_zv`, whose outer impulses stay exactly +1).

    **Peak-input limit**: the shaped command is bounded by ``Σ|A_i| = 1 + 2N`` times the
    peak of the command (a step stays within ``[A1 - N, 1]``).

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta < 1.
    negative : float, optional
        ``N >= 0``, the magnitude of the negative impulse (dimensionless).

    Returns
    -------
    Shaper

    Examples
    --------
    >>> s = sna_zv(2 * math.pi, 0.0, 0.5)
    >>> s.amplitudes.tolist(), round(s.duration, 6)
    ([0.75, -0.5, 0.75], 0.391827)
    >>> float(abs(sna_zv(2 * math.pi, 0.1, 0.5).amplitudes[1]))
    0.5
    """
    from scipy import optimize  # here: importing it costs ~0.5 s
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    if not isinstance(negative, (int, float)) or not math.isfinite(negative) or negative < 0:
        raise fail("negative", negative, "must be a finite number >= 0", error=ProblemFileError)
    n = float(negative)
    root = math.sqrt(1.0 - zeta**2)

    def form(n_bar):
        theta = math.acos(n_bar / (1.0 + n_bar))
        k = math.exp(-zeta * theta / root)
        amps = [0.5 * (1.0 + n_bar), -n_bar * k, 0.5 * (1.0 + n_bar) * k * k]
        total = sum(amps)
        return theta, [a / total for a in amps]

    n_bar = n
    if zeta > 0.0 and n > 0.0:
        # the middle amplitude grows from 0 without bound with N' (k -> 1 as θ -> 0)
        hi = max(1.0, n)
        while -form(hi)[1][1] < n:
            hi *= 2.0
        n_bar = optimize.brentq(lambda x: -form(x)[1][1] - n, 0.0, hi, xtol=1e-15,
                                rtol=1e-15)
    theta, amps = form(n_bar)
    amps[1] = -n if zeta > 0.0 else amps[1]  # exact by construction (to the root's 1e-15)
    amps[0] = 1.0 - amps[1] - amps[2]
    step = theta / (omega * root)
    if n == 0.0:  # ZV: no middle impulse
        return Shaper([0.0, 2.0 * step], [amps[0], amps[2]])
    return Shaper([0.0, step, 2.0 * step], amps)


def um_zvd(omega: float, zeta: float = 0.0) -> Shaper:
    """Unity-magnitude zero-vibration-derivative shaper: impulses ``+1, -1, +1, -1, +1``.

    The residual vector ``G(ω) = Σ A_i exp(s t_i)`` (``s = ζω + iω_d``) and its derivative
    in ω, ``Σ A_i t_i exp(s t_i)`` times a constant, both vanish at the design frequency:
    the negative counterpart of ZVD (vibration zero with a double root, so robust like
    ZVD), one step of the command switching sign four times. Undamped the impulses are
    symmetric about the middle one, at ``0, b - a, b, b + a, 2b`` with
    ``1 - 2 cos(ωa) + 2 cos(ωb) = 0`` and ``a sin(ωa) = b sin(ωb)``: ``ωa = 1.738691``,
    ``ωb = 2.301115``, a duration of 0.732468 of a period (ZVD: 1). With damping the four
    times solve the four real conditions (:func:`scipy.optimize.fsolve`, continuation in
    ζ from the undamped form). A step shaped by it stays within ``[0, 1]`` of the command;
    any other command can be amplified up to ``Σ|A_i| = 5`` (:data:`UM_ZVD_PEAK_FACTOR`,
    the peak-input limit ``1 + 2N`` with N = 2 negative unit impulses).

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta <= 0.3.

    Returns
    -------
    Shaper

    Raises
    ------
    ProblemFileError
        ``zeta > 0.3``.
    SolverError
        If the damped conditions cannot be solved.

    Examples
    --------
    >>> s = um_zvd(2 * math.pi)
    >>> s.times.round(6).tolist(), s.amplitudes.tolist()
    ([0.0, 0.089513, 0.366234, 0.642955, 0.732468], [1.0, -1.0, 1.0, -1.0, 1.0])
    """
    from scipy import optimize  # here: importing it costs ~0.5 s
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    if zeta > _UM_ZVD_ZETA_MAX:
        raise fail("zeta", zeta, f"must be <= {_UM_ZVD_ZETA_MAX} for the unity-magnitude "
                   "ZVD shaper", error=ProblemFileError)
    signs = np.array([1.0, -1.0, 1.0, -1.0, 1.0])

    def undamped(x):
        a, b = x
        return [1.0 - 2.0 * math.cos(a) + 2.0 * math.cos(b), a * math.sin(a) - b * math.sin(b)]

    a, b = optimize.fsolve(undamped, [1.7, 2.3], xtol=1e-13)
    tau = np.array([b - a, b, b + a, 2.0 * b])  # ω t of impulses 2..5, undamped

    def conditions(x, z):
        t = np.concatenate([[0.0], x])
        e = signs * np.exp(complex(z, math.sqrt(1.0 - z * z)) * t)
        g, dg = e.sum(), (e * t).sum()
        return [g.real, g.imag, dg.real, dg.imag]

    steps = int(math.ceil(zeta / 0.01))
    for z in np.linspace(0.0, zeta, steps + 1)[1:]:
        sol, info, ier, msg = optimize.fsolve(conditions, tau, args=(z,), full_output=True,
                                              xtol=1e-14)
        if np.max(np.abs(info["fvec"])) > 1e-12 or np.any(np.diff(sol) <= 0.0) or sol[0] <= 0:
            raise SolverError(f"unity-magnitude ZVD shaper: the conditions could not be "
                              f"solved at zeta={z:.4g}: {str(msg).strip()}")
        tau = sol
    return Shaper(np.concatenate([[0.0], tau]) / omega, signs)


def um_ei(omega: float, zeta: float = 0.0, vtol: float = 0.05) -> Shaper:
    """Unity-magnitude extra-insensitive shaper: impulses ``+1, -1, +1, -1, +1``.

    Defined like EI (:func:`casflex.shaping.ei`) with the amplitudes fixed at ``±1``: the
    residual vibration of eq. 187, ``V(ν) = |G(ν)|`` with ``G(ν) = Σ A_i exp(ν(ζ(τ_i -
    τ_n) + i sqrt(1-ζ²) τ_i))`` (``ν = ω/ω0``, ``τ = ω0 t``), equals ``vtol`` with zero
    slope at the design frequency (``ν = 1``, a hump) and vanishes at one frequency on
    each side. Undamped the impulses are symmetric about the middle one, at ``0, b - a, b,
    b + a, 2b`` with ``1 - 2 cos(ωa) + 2 cos(ωb) = -vtol`` and ``a sin(ωa) = b sin(ωb)``
    (0.7367 of a period at vtol = 0.05). With damping the four times and the two zeros
    solve the six real conditions (:func:`scipy.optimize.fsolve`, continuation in ζ). A
    step shaped by it stays within ``[0, 1]`` of the command; any other command can be
    amplified up to ``Σ|A_i| = 5`` (:data:`UM_ZVD_PEAK_FACTOR`).

    Parameters
    ----------
    omega : float
        Natural frequency, rad/s.
    zeta : float, optional
        Damping ratio, 0 <= zeta <= 0.3.
    vtol : float, optional
        Hump height at the design frequency (fraction), 0 < vtol <= 0.2.

    Returns
    -------
    Shaper

    Raises
    ------
    ProblemFileError
        ``zeta > 0.3`` or ``vtol`` outside (0, 0.2].
    SolverError
        If the damped conditions cannot be solved.

    Examples
    --------
    >>> s = um_ei(2 * math.pi)
    >>> s.times.round(5).tolist(), s.amplitudes.tolist()
    ([0.0, 0.09408, 0.36837, 0.64266, 0.73673], [1.0, -1.0, 1.0, -1.0, 1.0])
    """
    from scipy import optimize  # here: importing it costs ~0.5 s
    omega = check_omega(omega)
    zeta = check_zeta(zeta)
    if zeta > _UM_ZVD_ZETA_MAX:
        raise fail("zeta", zeta, f"must be <= {_UM_ZVD_ZETA_MAX} for the unity-magnitude "
                   "EI shaper", error=ProblemFileError)
    if not isinstance(vtol, (int, float)) or not 0.0 < vtol <= 0.2:
        raise fail("vtol", vtol, "must be in (0, 0.2] for the unity-magnitude EI shaper",
                   error=ProblemFileError)
    signs = np.array([1.0, -1.0, 1.0, -1.0, 1.0])

    def undamped(x):
        a, b = x
        return [1.0 - 2.0 * math.cos(a) + 2.0 * math.cos(b) + vtol,
                a * math.sin(a) - b * math.sin(b)]

    a, b = optimize.fsolve(undamped, [1.74, 2.3], xtol=1e-13)

    def real_g(nu):
        return 1.0 - 2.0 * math.cos(nu * a) + 2.0 * math.cos(nu * b)

    # the zeros of the (real, symmetric) undamped residual on each side of ν = 1
    grid = np.linspace(0.3, 1.7, 1401)
    values = np.array([real_g(x) for x in grid])
    cross = np.nonzero(np.sign(values[1:]) != np.sign(values[:-1]))[0]
    below = [optimize.brentq(real_g, grid[i], grid[i + 1], xtol=1e-15) for i in cross
             if grid[i] < 1.0]
    above = [optimize.brentq(real_g, grid[i], grid[i + 1], xtol=1e-15) for i in cross
             if grid[i] > 1.0]
    x = np.array([b - a, b, b + a, 2.0 * b, below[-1], above[0]])

    def residual(tau, nu, z):
        rate = z * (tau - tau[-1]) + 1j * math.sqrt(1.0 - z * z) * tau
        e = signs * np.exp(nu * rate)
        return e.sum(), (e * rate).sum()

    def conditions(v, z):
        tau = np.concatenate([[0.0], v[:4]])
        g, dg = residual(tau, 1.0, z)
        g1, _ = residual(tau, v[4], z)
        g2, _ = residual(tau, v[5], z)
        return [abs(g) ** 2 - vtol**2, (np.conj(g) * dg).real, g1.real, g1.imag, g2.real,
                g2.imag]

    steps = int(math.ceil(zeta / 0.01))
    for z in np.linspace(0.0, zeta, steps + 1)[1:]:
        sol, info, ier, msg = optimize.fsolve(conditions, x, args=(z,), full_output=True,
                                              xtol=1e-14)
        if np.max(np.abs(info["fvec"])) > 1e-12 or np.any(np.diff(sol[:4]) <= 0.0) or \
                sol[0] <= 0.0:
            raise SolverError(f"unity-magnitude EI shaper: the conditions could not be "
                              f"solved at zeta={z:.4g}, vtol={vtol:.4g}: {str(msg).strip()}")
        x = sol
    return Shaper(np.concatenate([[0.0], x[:4]]) / omega, signs)
