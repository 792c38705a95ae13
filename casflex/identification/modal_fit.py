"""Natural frequencies and damping ratios from a free-decay record (impulse test).

Method
------
1. **First look (Welch).** Averaged, channel-normalised power spectral density
   (:func:`scipy.signal.welch`, Hann window, half-record segments); its peaks above the
   noise floor (10 dB) give the peak list and the band of interest (up to twice the
   highest peak).
2. **Band and decay.** The record is low-pass filtered and decimated to about five samples
   per period of the band's top (zero-phase polyphase FIR, edge samples dropped: a linear
   filter maps a damped sinusoid ``e^{λt}`` onto ``H(λ) e^{λt}``, so frequencies and
   damping are kept). The free decay starts where the record first reaches 30 % of its
   largest excursion (the end of the impulse).
3. **Poles over model orders (ERA).** One block-Hankel matrix of every channel's decay,
   one SVD, then for every even model order up to ``max_order`` the shift-invariance of
   the truncated observability matrix gives the discrete poles (Kung's / the Eigensystem
   Realisation Algorithm for a free response). ERA is used because it treats all channels
   at once, needs no initial guess, and its order sweep comes from a single SVD.
4. **Stabilisation.** A pole is *stable* when the next lower order has a pole within
   0.5 % in frequency and 20 % in damping; the stable poles are clustered by frequency
   and a cluster present in at least 30 % of the orders is a mode. Noise poles move from
   order to order and are rejected; the offset gives a real pole at 0 Hz, dropped.
5. **Parametric fit.** Damped-sinusoid least squares over all channels: per mode the
   natural frequency and damping ratio (nonlinear), per channel and mode a cosine and a
   sine amplitude and per channel an offset (linear, eliminated by variable projection).
   It starts from the stable poles and reaches the maximum-likelihood estimate for white
   noise; standard errors come from the full Jacobian with each channel weighted by its
   residual standard deviation. A mode no channel sees at 5 standard errors, or whose
   damping leaves ``(0, 0.5)``, is dropped as spurious and the fit repeated.

"Which channels see a mode": those where its initial amplitude exceeds 5 standard errors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from casflex._validate import number
from casflex.errors import ModelError, SolverError
from casflex.identification.logs import uniform_sample_rate

__all__ = ["ModalEstimate", "WelchSpectrum", "welch_spectrum", "identify_modes"]

#: significance (amplitude / standard error) at which a channel sees a mode
SEEN_Z = 5.0
#: stabilisation tolerances between consecutive model orders
STABLE_DF, STABLE_DZETA = 0.005, 0.2
#: fraction of the model orders in which a stable pole cluster must appear
STABLE_FRACTION = 0.3
#: highest damping ratio accepted for a mode
MAX_DAMPING = 0.5


@dataclass(frozen=True)
class WelchSpectrum:
    """Welch power spectral densities of every channel and the peak list.

    Attributes
    ----------
    f_hz : numpy.ndarray
        (F,) frequencies [Hz].
    psd : numpy.ndarray
        (F, C) power spectral densities [(m/s²)²/Hz].
    combined : numpy.ndarray
        (F,) mean of the channel PSDs each divided by its median (dimensionless).
    peaks_hz : numpy.ndarray
        Frequencies of the peaks of ``combined`` at least 10 dB above its median floor,
        highest first [Hz].

    Examples
    --------
    >>> s = WelchSpectrum(np.arange(3.0), np.ones((3, 1)), np.ones(3), np.array([1.0]))
    >>> s.peaks_hz.tolist()
    [1.0]
    """

    f_hz: np.ndarray
    psd: np.ndarray
    combined: np.ndarray
    peaks_hz: np.ndarray


@dataclass(frozen=True)
class ModalEstimate:
    """Modes identified from one record.

    Attributes
    ----------
    frequency_hz, frequency_std_hz : numpy.ndarray
        (K,) natural frequencies and their standard errors [Hz], ascending.
    damping, damping_std : numpy.ndarray
        (K,) damping ratios and their standard errors [-].
    amplitude : numpy.ndarray
        (K, C) initial amplitude of each mode at each channel [channel unit].
    significance : numpy.ndarray
        (K, C) amplitude over its standard error.
    channels : tuple of str
        Channel names.
    sample_rate : float
        Sample rate of the record, from its time column [Hz].
    fit_rate : float
        Rate of the decimated signal the fit used [Hz].
    start : float
        Start of the fitted free decay, from the first sample [s].
    noise_std : numpy.ndarray
        (C,) residual standard deviation per channel after the fit [channel unit].
    spectrum : WelchSpectrum
        The first look.
    stabilisation : list of (int, numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Per model order: order, pole frequencies [Hz], damping ratios, stable flags.
    rejected_hz : list of float
        Candidate modes dropped by the significance or damping test [Hz].
    phase : numpy.ndarray or None
        (K, C) phase of each mode at each channel, ``A cos(ω_d t − phase)`` from the
        start of the fitted decay [rad].

    Examples
    --------
    >>> e = ModalEstimate(np.array([2.0]), np.array([0.01]), np.array([0.02]),
    ...                   np.array([0.001]), np.array([[1.0, 0.0]]),
    ...                   np.array([[50.0, 0.1]]), ("a", "b"), 1000.0, 100.0, 0.0,
    ...                   np.ones(2), None, [], [])
    >>> e.seen_by
    [['a']]
    """

    frequency_hz: np.ndarray
    frequency_std_hz: np.ndarray
    damping: np.ndarray
    damping_std: np.ndarray
    amplitude: np.ndarray
    significance: np.ndarray
    channels: tuple[str, ...]
    sample_rate: float
    fit_rate: float
    start: float
    noise_std: np.ndarray
    spectrum: WelchSpectrum | None
    stabilisation: list = field(default_factory=list)
    rejected_hz: list = field(default_factory=list)
    phase: np.ndarray | None = None

    @property
    def shape(self) -> np.ndarray | None:
        """(K, C) real mode shapes at the channels: the amplitudes signed by their phase
        relative to the channel that sees the mode most (in phase ``+``, opposite ``−``;
        the modes of a lightly damped structure are real to first order)."""
        if self.phase is None:
            return None
        ref = np.argmax(self.significance, axis=1)
        rel = self.phase - np.take_along_axis(self.phase, ref[:, None], axis=1)
        return self.amplitude * np.where(np.cos(rel) >= 0.0, 1.0, -1.0)

    @property
    def seen_by(self) -> list[list[str]]:
        """Per mode, the channels that see it (significance above 5)."""
        return [[c for c, z in zip(self.channels, row, strict=True) if z > SEEN_Z]
                for row in self.significance]

    def as_dict(self) -> dict:
        """The estimate as plain values (for JSON).

        Returns
        -------
        dict
            ``frequency_hz``, ``frequency_std_hz``, ``damping``, ``damping_std``,
            ``seen_by``, ``shape`` (per mode, channel name -> signed amplitude, or null),
            ``sample_rate_hz``, ``peaks_hz``, ``rejected_hz``.

        Examples
        --------
        >>> e = ModalEstimate(np.array([2.0]), np.array([0.01]), np.array([0.02]),
        ...                   np.array([0.001]), np.array([[1.0]]), np.array([[50.0]]),
        ...                   ("a",), 1000.0, 100.0, 0.0, np.ones(1), None, [], [])
        >>> e.as_dict()["seen_by"]
        [['a']]
        """
        return {
            "frequency_hz": self.frequency_hz, "frequency_std_hz": self.frequency_std_hz,
            "damping": self.damping, "damping_std": self.damping_std,
            "seen_by": self.seen_by,
            "shape": None if self.shape is None else [
                dict(zip(self.channels, row.tolist(), strict=True)) for row in self.shape],
            "sample_rate_hz": self.sample_rate,
            "peaks_hz": None if self.spectrum is None else self.spectrum.peaks_hz,
            "rejected_hz": list(self.rejected_hz),
        }


def welch_spectrum(signals: ArrayLike, sample_rate: float) -> WelchSpectrum:
    """Welch PSDs of the channels and the peaks of their normalised mean.

    Parameters
    ----------
    signals : array_like
        (N,) or (N, C) signals [channel unit].
    sample_rate : float
        [Hz].

    Returns
    -------
    WelchSpectrum

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(5000) / 500.0
    >>> y = np.sin(2 * np.pi * 7.0 * t) + 0.01 * rng.standard_normal(t.size)
    >>> float(welch_spectrum(y, 500.0).peaks_hz[0].round(1))
    7.0
    """
    import scipy.signal

    y = np.asarray(signals, dtype=float)
    y = y.reshape(y.shape[0], -1)
    n = y.shape[0]
    nperseg = max(16, n // 2)
    f, p = scipy.signal.welch(y - y.mean(axis=0), fs=sample_rate, nperseg=nperseg, axis=0)
    floor = np.median(p, axis=0)
    floor = np.where(floor > 0.0, floor, 1.0)
    combined = np.mean(p / floor, axis=1)
    idx, _ = scipy.signal.find_peaks(combined, height=10.0 * np.median(combined))
    idx = idx[f[idx] > 0.0]
    order = np.argsort(combined[idx])[::-1]
    return WelchSpectrum(f, p, combined, f[idx][order])


def _era_poles(y, dt, max_order, rows):
    """ERA poles for every even order 2..max_order: list of (order, lambda)."""
    n, c = y.shape
    cols = n - rows + 1
    H = np.empty((rows * c, cols))
    for i in range(rows):
        H[i * c:(i + 1) * c] = y[i:i + cols].T
    U, S, _ = np.linalg.svd(H, full_matrices=False)
    out = []
    for order in range(2, max_order + 1, 2):
        O = U[:, :order] * np.sqrt(S[:order])
        A = np.linalg.lstsq(O[:-c], O[c:], rcond=None)[0]
        z = np.linalg.eigvals(A)
        z = z[np.abs(z) > 1e-12]
        out.append((order, np.log(z.astype(complex)) / dt))
    return out


def _stable_modes(poles, fmin, fmax):
    """Stabilisation diagram and the clusters of stable poles: (diagram, [(f, zeta)])."""
    diagram, stable = [], []
    previous = None
    for order, lam in poles:
        lam = lam[lam.imag > 0.0]
        f = np.abs(lam) / (2 * np.pi)
        zeta = -lam.real / np.abs(lam)
        keep = (f >= fmin) & (f <= fmax) & (zeta > 0.0) & (zeta < MAX_DAMPING)
        f, zeta = f[keep], zeta[keep]
        flags = np.zeros(f.size, dtype=bool)
        if previous is not None and previous[0].size:
            for i in range(f.size):
                df = np.abs(previous[0] - f[i]) / f[i]
                j = int(np.argmin(df))
                flags[i] = (df[j] < STABLE_DF
                            and abs(previous[1][j] - zeta[i]) < STABLE_DZETA * zeta[i])
        diagram.append((order, f, zeta, flags))
        stable.extend(zip(f[flags], zeta[flags], np.full(flags.sum(), order), strict=True))
        previous = (f, zeta)
    if not stable:
        return diagram, []
    stable.sort()
    clusters, current = [], [stable[0]]
    for item in stable[1:]:
        if item[0] - current[-1][0] > STABLE_DF * item[0]:
            clusters.append(current)
            current = [item]
        else:
            current.append(item)
    clusters.append(current)
    n_orders = len(poles)
    modes = []
    for cl in clusters:
        orders = {o for _, _, o in cl}
        if len(orders) >= max(3, STABLE_FRACTION * n_orders):
            modes.append((float(np.median([x[0] for x in cl])),
                          float(np.median([x[1] for x in cl]))))
    return diagram, modes


def _basis(t, sigma, wd):
    """(N, 2K + 1) damped cosines and sines and a constant."""
    e = np.exp(-np.outer(t, sigma))
    return np.column_stack([e * np.cos(np.outer(t, wd)), e * np.sin(np.outer(t, wd)),
                            np.ones_like(t)])


def _projected_residual(x, t, Yw):
    k = x.size // 2
    B = _basis(t, x[:k], x[k:])
    coef = np.linalg.lstsq(B, Yw, rcond=None)[0]
    return (Yw - B @ coef).ravel()


def _fit(t, Y, omega, zeta):
    """Damped-sinusoid least squares; returns (omega_n, zeta, cov of (w, z), amplitude,
    amplitude std, channel std, phase)."""
    k = omega.size
    sigma0, wd0 = zeta * omega, omega * np.sqrt(1.0 - zeta**2)
    weight = np.std(Y, axis=0)
    weight = np.where(weight > 0.0, weight, 1.0)
    x0 = np.concatenate([sigma0, wd0])
    scale = np.concatenate([np.maximum(sigma0, 1e-3 * wd0), wd0])
    for _ in range(2):  # second pass with the residual noise as channel weights
        sol = least_squares(_projected_residual, x0, args=(t, Y / weight), method="lm",
                            x_scale=scale, xtol=1e-12, ftol=1e-12)
        x0 = sol.x
        B = _basis(t, x0[:k], x0[k:])
        coef = np.linalg.lstsq(B, Y, rcond=None)[0]
        resid = Y - B @ coef
        dof = max(1, t.size - B.shape[1] - 2 * k / Y.shape[1])
        weight = np.sqrt(np.sum(resid**2, axis=0) / dof)
        weight = np.where(weight > 0.0, weight, np.finfo(float).tiny)
    sigma, wd = x0[:k], x0[k:]
    if np.any(wd <= 0.0):
        raise SolverError("damped-sinusoid fit: a mode's frequency went to zero")
    # full Jacobian of the weighted residuals: nonlinear (sigma, wd) then per channel
    # linear (cos, sin, offset)
    n, c = Y.shape
    e = np.exp(-np.outer(t, sigma))
    cos, sin = np.cos(np.outer(t, wd)), np.sin(np.outer(t, wd))
    p_lin = 2 * k + 1
    J = np.zeros((n * c, 2 * k + c * p_lin))
    for ch in range(c):
        a, b = coef[:k, ch], coef[k:2 * k, ch]
        rows = slice(ch * n, (ch + 1) * n)
        model = e * (a * cos + b * sin)
        J[rows, :k] = -t[:, None] * model / weight[ch]
        J[rows, k:2 * k] = t[:, None] * e * (-a * sin + b * cos) / weight[ch]
        J[rows, 2 * k + ch * p_lin:2 * k + (ch + 1) * p_lin] = B / weight[ch]
    try:
        cov = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(J.T @ J)
    wn = np.hypot(sigma, wd)
    z = sigma / wn
    g = np.zeros((2 * k, 2 * k))  # d(wn, zeta) / d(sigma, wd)
    for i in range(k):
        g[i, i], g[i, k + i] = sigma[i] / wn[i], wd[i] / wn[i]
        g[k + i, i] = wd[i] ** 2 / wn[i] ** 3
        g[k + i, k + i] = -sigma[i] * wd[i] / wn[i] ** 3
    cov_wz = g @ cov[:2 * k, :2 * k] @ g.T
    amp = np.hypot(coef[:k], coef[k:2 * k]).T  # (C, K)
    amp_std = np.zeros_like(amp)
    for ch in range(c):
        base = 2 * k + ch * p_lin
        for i in range(k):
            a, b = coef[i, ch], coef[k + i, ch]
            idx = [base + i, base + k + i]
            grad = np.array([a, b]) / max(amp[ch, i], np.finfo(float).tiny)
            amp_std[ch, i] = np.sqrt(max(grad @ cov[np.ix_(idx, idx)] @ grad, 0.0))
    phase = np.arctan2(coef[k:2 * k], coef[:k])  # (K, C): a cos + b sin = A cos(wt - phase)
    return wn, z, cov_wz, amp.T, amp_std.T, weight, phase


def identify_modes(t: ArrayLike, signals: ArrayLike, *, channels: tuple[str, ...] | None = None,
                   n_modes: int | None = None, fmin_hz: float | None = None,
                   fmax_hz: float | None = None, start: float | None = None,
                   max_order: int | None = None) -> ModalEstimate:
    """Natural frequencies, damping ratios and their standard errors from a free decay.

    Parameters
    ----------
    t : array_like
        (N,) uniformly spaced sample times [s]; the sample rate is taken from them.
    signals : array_like
        (N,) or (N, C) accelerometer channels [m/s²]; offsets are allowed.
    channels : tuple of str, optional
        Channel names (default ``ch1``, ``ch2`` ...).
    n_modes : int, optional
        Report at most this many modes (the most significant ones, in frequency order).
    fmin_hz, fmax_hz : float, optional
        Band searched [Hz]; default from two periods over the record to twice the highest
        Welch peak.
    start : float, optional
        Start of the free decay after the first sample [s]; default where the record first
        reaches 30 % of its largest excursion.
    max_order : int, optional
        Highest ERA model order of the stabilisation check (default 2 × (peaks + 8),
        at most 80).

    Returns
    -------
    ModalEstimate

    Raises
    ------
    ModelError
        Bad arguments, or no mode found.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> t = np.arange(4000) / 400.0
    >>> wn, zeta = 2 * np.pi * 3.0, 0.02                 # 3 Hz, 2 % damping
    >>> y = np.exp(-zeta * wn * t) * np.cos(wn * np.sqrt(1 - zeta**2) * t)
    >>> est = identify_modes(t, y + 0.001 * rng.standard_normal(t.size))
    >>> est.frequency_hz.round(3).tolist(), est.damping.round(3).tolist()
    ([3.0], [0.02])
    """
    import scipy.signal

    t = np.asarray(t, dtype=float)
    y = np.asarray(signals, dtype=float)
    y = y.reshape(y.shape[0], -1)
    if t.ndim != 1 or t.size != y.shape[0]:
        raise ModelError(f"signals: {y.shape[0]} samples for {t.size} times")
    if t.size < 64:
        raise ModelError(f"t: a record needs at least 64 samples; got {t.size}")
    if not np.all(np.isfinite(y)):
        raise ModelError("signals: must be finite")
    if channels is None:
        channels = tuple(f"ch{i + 1}" for i in range(y.shape[1]))
    channels = tuple(channels)
    if len(channels) != y.shape[1]:
        raise ModelError(f"channels: {len(channels)} names for {y.shape[1]} signals")
    if n_modes is not None:
        n_modes = number(n_modes, "n_modes", low=1, integer=True)
    fs = uniform_sample_rate(t)
    duration = t[-1] - t[0]
    spectrum = welch_spectrum(y, fs)
    if fmax_hz is None:
        if spectrum.peaks_hz.size == 0:
            raise ModelError("no resonance peak stands 10 dB above the noise floor of the "
                             "record; give fmax_hz")
        fmax_hz = min(2.0 * float(spectrum.peaks_hz.max()), 0.4 * fs)
    fmax_hz = number(fmax_hz, "fmax_hz", low=0.0, low_open=True, high=0.5 * fs)
    fmin_hz = 2.0 / duration if fmin_hz is None else number(fmin_hz, "fmin_hz", low=0.0)
    if fmin_hz >= fmax_hz:
        raise ModelError(f"fmin_hz = {fmin_hz:g}: must be below fmax_hz = {fmax_hz:g}")

    # band-limit and decimate to ~5 samples per period of fmax
    yd, td = y, t - t[0]
    rate = fs
    while rate / (5.0 * fmax_hz) >= 2.0:
        q = int(min(10, rate // (5.0 * fmax_hz)))
        if yd.shape[0] // q < 200:
            break
        z = scipy.signal.resample_poly(yd, 1, q, axis=0)
        td = td[0] + np.arange(z.shape[0]) * q / rate
        yd, td = z[10:-10], td[10:-10]  # the filter's half length at each end
        rate = rate / q

    if start is None:
        dev = yd - np.median(yd, axis=0)
        energy = np.sum(dev**2 / np.maximum(np.var(yd, axis=0), 1e-300), axis=1)
        # the first sample at 30 % of the largest excursion: the end of the impulse
        i0 = int(np.argmax(energy >= 0.3 * energy.max()))
    else:
        start = number(start, "start", low=0.0, high=duration)
        i0 = int(np.searchsorted(td, start))
    yd, td = yd[i0:], td[i0:]
    if yd.shape[0] < 32:
        raise ModelError("the free decay after the start holds fewer than 32 samples at the "
                         "fitted rate; give an earlier start or a longer record")
    t_fit = td - td[0]

    n, c = yd.shape
    if max_order is None:
        max_order = min(80, 2 * (spectrum.peaks_hz.size + 8))
    max_order = number(max_order, "max_order", low=4, integer=True)
    # block rows: room for the model order, at most ~240 Hankel rows (the SVD's cost)
    rows = int(min(max(2 * max_order // c + 2, 240 // c), n // 3))
    if rows * c < max_order or n - rows < max_order:
        raise ModelError(f"the record is too short for model order {max_order}: "
                         f"{n} samples at the fitted rate")
    scale = np.std(yd, axis=0)
    scale = np.where(scale > 0.0, scale, 1.0)
    centred = (yd - np.mean(yd, axis=0)) / scale
    poles = _era_poles(centred, 1.0 / rate, max_order, rows)
    diagram, candidates = _stable_modes(poles, fmin_hz, fmax_hz)
    if not candidates:
        raise ModelError("no stable pole: the record shows no free decay in "
                         f"{fmin_hz:.3g}–{fmax_hz:.3g} Hz")
    omega = 2 * np.pi * np.array([f for f, _ in candidates])
    zeta = np.array([z for _, z in candidates])
    rejected = []
    while True:
        wn, z, cov, amp, amp_std, noise, phase = _fit(t_fit, yd, omega, zeta)
        signif = amp / np.maximum(amp_std, np.finfo(float).tiny)
        bad = (z <= 0.0) | (z >= MAX_DAMPING) | (signif.max(axis=1) <= SEEN_Z)
        # two candidates converged onto one mode: keep the more significant one
        order = np.argsort(wn)
        for a, b in zip(order[:-1], order[1:], strict=True):
            if abs(wn[b] - wn[a]) < 1e-3 * wn[b]:
                bad[a if signif[a].max() < signif[b].max() else b] = True
        if not bad.any():
            break
        worst = np.flatnonzero(bad)
        rejected.extend((wn[worst] / (2 * np.pi)).tolist())
        keep = ~bad
        if not keep.any():
            raise ModelError("every candidate mode was rejected as spurious (not seen "
                             "above the noise by any channel)")
        omega, zeta = wn[keep], z[keep]
    if n_modes is not None and wn.size > n_modes:
        strongest = np.sort(np.argsort(signif.max(axis=1))[::-1][:n_modes])
        keep = np.zeros(wn.size, dtype=bool)
        keep[strongest] = True
        wn, z, cov, amp, amp_std, noise, phase = _fit(t_fit, yd, wn[keep], z[keep])
        signif = amp / np.maximum(amp_std, np.finfo(float).tiny)
    order = np.argsort(wn)
    k = wn.size
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return ModalEstimate(
        frequency_hz=wn[order] / (2 * np.pi), frequency_std_hz=std[:k][order] / (2 * np.pi),
        damping=z[order], damping_std=std[k:][order], amplitude=amp[order],
        significance=signif[order], channels=channels, sample_rate=fs, fit_rate=rate,
        start=float(td[0]), noise_std=noise, spectrum=spectrum, stabilisation=diagram,
        rejected_hz=sorted(rejected), phase=phase[order])
