"""The SI shaper NLP for Ipopt with its exact Hessian assembled from matrix products.

The constraints of the specified-insensitivity NLP are ``V_j² = C_j² + S_j²`` at m sample
frequencies (residual vibration at the same instant), with ``C = Cm a`` and ``S = Sm a``
linear in the amplitudes, ``Cm_ji = exp(ζ_j ω_j t_i) cos(ω_dj t_i)`` and ``Sm`` the same with
``sin``. The Hessian of the Lagrangian ``Σ_j λ_j V_j²`` is dense in (a, t); letting CasADi
differentiate an SX graph of it costs O(m n²) symbolic operations to build (0.7 s for
m = 114 samples and n = 20 impulses, three times per design). Here it is written as

``H = 2 JCᵀ diag(λ) JC + 2 JSᵀ diag(λ) JS + D``,

with ``JC = [Cm, DC ∘ a]`` the Jacobian of C (``DC = ζω Cm - ω_d Sm``), likewise JS, and
``D`` the second derivatives of C and S themselves, which only couple ``a_i`` with ``t_i``
and ``t_i`` with itself. As MX matrix products it builds in milliseconds; Ipopt receives
it through ``nlpsol``'s ``hess_lag`` option.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

__all__ = ["si_nlp_with_hessian"]


def si_nlp_with_hessian(omega: ArrayLike, zeta: ArrayLike, n: int
                        ) -> tuple[dict, ca.Function]:
    """The SI NLP (x, f, g) in MX and the exact Hessian of its Lagrangian.

    ``x = [A (n); t (n)]``, ``f = t_n``, ``g = [Σ A - 1; t_{i+1} - t_i (n - 1);
    V_j² (m)]`` with ``V_j`` the residual vibration at the same instant at ``omega[j]``,
    ``zeta[j]``.

    Parameters
    ----------
    omega : array_like, shape (m,)
        Sample natural frequencies, rad/s.
    zeta : array_like, shape (m,)
        Their damping ratios.
    n : int
        Number of impulses.

    Returns
    -------
    nlp : dict
        ``{"x", "f", "g"}`` for :func:`casadi.nlpsol`.
    hess_lag : casadi.Function
        ``(x, p, lam_f, lam_g) -> triu(∇²_x (lam_f f + lam_gᵀ g))``, the ``hess_lag``
        option of :func:`casadi.nlpsol`.

    Examples
    --------
    The Hessian equals CasADi's own differentiation of the Lagrangian:

    >>> nlp, hess = si_nlp_with_hessian([5.0, 7.0, 9.0], [0.0, 0.02, 0.05], 3)
    >>> lam = ca.MX.sym("lam", nlp["g"].numel())
    >>> ad = ca.Function("ad", [nlp["x"], lam],
    ...                  [ca.triu(ca.hessian(ca.dot(lam, nlp["g"]), nlp["x"])[0])])
    >>> rng = np.random.default_rng(0)
    >>> x, lg = rng.uniform(0.1, 1.0, 6), rng.uniform(-1.0, 1.0, lam.numel())
    >>> diff = np.array(ad(x, lg)) - np.array(hess(x, [], 1.0, lg))
    >>> bool(np.max(np.abs(diff)) < 1e-12)
    True
    """
    omega = np.asarray(omega, dtype=float).reshape(-1)
    zeta = np.broadcast_to(np.asarray(zeta, dtype=float), omega.shape)
    m = omega.size
    x = ca.MX.sym("x", 2 * n)
    a, t = x[:n], x[n:]
    zw = ca.DM(zeta * omega)
    wd = ca.DM(omega * np.sqrt(1.0 - zeta**2))
    decay = ca.exp(ca.mtimes(zw, t.T))  # same instant: no exp(-ζω t_n)
    phase = ca.mtimes(wd, t.T)
    cm = decay * ca.cos(phase)  # (m, n)
    sm = decay * ca.sin(phase)
    c = ca.mtimes(cm, a)
    s = ca.mtimes(sm, a)
    g = ca.vertcat(ca.sum1(a) - 1.0, t[1:] - t[:-1], c**2 + s**2)
    zw_mn = ca.repmat(zw, 1, n)
    wd_mn = ca.repmat(wd, 1, n)
    dc = zw_mn * cm - wd_mn * sm  # ∂Cm/∂t
    ds = zw_mn * sm + wd_mn * cm
    d2c = (zw_mn**2 - wd_mn**2) * cm - 2.0 * zw_mn * wd_mn * sm
    d2s = (zw_mn**2 - wd_mn**2) * sm + 2.0 * zw_mn * wd_mn * cm
    a_rows = ca.repmat(a.T, m, 1)
    jc = ca.horzcat(cm, dc * a_rows)
    js = ca.horzcat(sm, ds * a_rows)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", g.numel())
    lam = lam_g[n:]  # multipliers of the V² constraints (the others are linear)
    two_lam = ca.repmat(2.0 * lam, 1, 2 * n)
    h = ca.mtimes(jc.T, two_lam * jc) + ca.mtimes(js.T, two_lam * js)
    wc = 2.0 * lam * c
    ws = 2.0 * lam * s
    cross = ca.mtimes(dc.T, wc) + ca.mtimes(ds.T, ws)  # ∂²/∂a_i∂t_i
    tt = a * (ca.mtimes(d2c.T, wc) + ca.mtimes(d2s.T, ws))  # ∂²/∂t_i²
    h = h + ca.vertcat(ca.horzcat(ca.MX(n, n), ca.diag(cross)),
                       ca.horzcat(ca.diag(cross), ca.diag(tt)))
    hess = ca.Function("nlp_hess_l", [x, ca.MX.sym("p", 0), lam_f, lam_g], [ca.triu(h)],
                       ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
    return {"x": x, "f": t[n - 1], "g": g}, hess
