"""Compiled point kernels of the TMM: the Wittrick–Williams count, Brent's method on
``det subU`` per bracket, the system columns and the sampled beam field of the shapes.

The root search of :mod:`casflex.tmm.solve` evaluates the same two quantities at batches
of (configuration, ω) points. In numpy each evaluation is a few hundred calls on 6 × 6
and 12 × 12 arrays, and their per-call overhead, not the arithmetic, sets the time. These
kernels do the same arithmetic point by point in machine code (numba, ``cache=True``: the
compiled code is kept next to this file or in ``NUMBA_CACHE_DIR``). Without numba,
``AVAILABLE`` is False and the numpy path runs alone; the numpy path is also the
reference the kernels are tested against and the fallback when a kernel meets a singular
matrix (the numpy path has the least-squares and diagnosis branches).

Data layout (C configurations, E elements): ``kind`` (E,) with 0 beam, 1 body, 2 offset,
3 spring; per element constants ``beam`` (E, 12) and per configuration matrices ``R12``
(C, E, 12, 12), ``R6`` and ``G`` (C, E, 6, 6), ``M`` (C, E, 6, 6), ``T`` (C, E, 12, 12),
``axis`` (C, E, 3); the beam layout ``flat``, ``gather``, ``ratio`` (E, 40) comes from
:func:`casflex.tmm.elements.beam_field`'s table.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["AVAILABLE", "pack"]  # noqa: F822 (AVAILABLE: module __getattr__)

# ``AVAILABLE`` (True when the compiled kernels can run: numba importable) and the
# kernels ``count_points``, ``refine_brackets``, ``system_points``, ``field_points`` are
# made on first use (module ``__getattr__`` below): importing numba costs ~0.5 s, which
# a command that reads its modal tables from the cache never needs.
_KERNELS = ("count_points", "refine_brackets", "system_points", "field_points")

#: state permutation [u, θ, M, F] -> [u, θ, F, M] (as in casflex.tmm.solve)
_CONJUGATE = np.array([0, 1, 2, 3, 4, 5, 9, 10, 11, 6, 7, 8])


def pack(items, size: int) -> dict:
    """Arrays of the kernels from a stack's element items (see the module docstring).

    Parameters
    ----------
    items : list of dict
        ``_Stack.items`` of :mod:`casflex.tmm.solve`: the element and its stacked matrices.
    size : int
        Number of configurations C.

    Returns
    -------
    dict of numpy.ndarray

    Examples
    --------
    >>> pack([], 1)["kind"].shape
    (0,)
    """
    from casflex.tmm.elements import layout

    E = len(items)
    out = {
        "kind": np.zeros(E, dtype=np.int64), "beam": np.zeros((E, 12)),
        "flat": np.zeros((E, 40), dtype=np.int64), "gather": np.zeros((E, 40), dtype=np.int64),
        "ratio": np.zeros((E, 40)), "R12": np.zeros((size, E, 12, 12)),
        "R6": np.zeros((size, E, 6, 6)), "M": np.zeros((size, E, 6, 6)),
        "G": np.zeros((size, E, 6, 6)), "T": np.zeros((size, E, 12, 12)),
        "axis": np.zeros((size, E, 3)), "stiffness": np.zeros(E),
    }
    for j, data in enumerate(items):
        e = data["element"]
        if e.kind == "beam":
            P = e.params
            sec, mat, L = P["section"], P["material"], P["length"]
            EA, EIx, EIy, GJ = mat.E * sec.A, mat.E * sec.Ix, mat.E * sec.Iy, mat.G * sec.J
            rho_A, rho_Ip = mat.rho * sec.A, mat.rho * sec.Ip
            table = layout(EA, EIx, EIy, GJ, rho_A, rho_Ip)
            out["kind"][j] = 0
            out["flat"][j], out["gather"][j] = table["flat"], table["gather"]
            out["ratio"][j] = table["ratio"][:, 0]
            mu = mat.rho * sec.A
            out["beam"][j] = [
                L, table["stiff"][0, 0], table["stiff"][1, 0], table["wave"][0, 0],
                table["wave"][1, 0], table["bend"][0, 0], table["bend"][1, 0],
                np.sqrt(mat.rho / mat.E), np.sqrt(mat.rho * sec.Ip / (mat.G * sec.J)),
                (mu / (mat.E * sec.Iy)) ** 0.25, (mu / (mat.E * sec.Ix)) ** 0.25, 0.0]
            out["R12"][:, j] = data["R12"]
            out["R6"][:, j] = data["R6"]
        elif e.kind == "body":
            out["kind"][j] = 1
            out["M"][:, j] = data["M"]
        elif e.kind == "offset":
            out["kind"][j] = 2
            out["T"][:, j] = data["T"]
            out["G"][:, j] = data["G"]
        else:
            out["kind"][j] = 3
            out["T"][:, j] = data["T"]
            out["axis"][:, j] = data["axis"]
            out["stiffness"][j] = e.params["stiffness"]
    return out


def _beam_local(c, flat, gather, ratio, w):
    """Local 12 × 12 transfer matrix of a beam at ω (the closed forms of beam_field)."""
    L = c[0]
    vals = np.empty(20)
    for r in range(2):
        stiff, wave, bend = c[1 + r], c[3 + r], c[5 + r]
        k = w * wave
        cs, sn = math.cos(k * L), math.sin(k * L)
        sinc = sn / k if k != 0.0 else L
        vals[r] = cs
        vals[2 + r] = sinc / stiff
        vals[4 + r] = (-stiff * k) * sn
        lam = math.sqrt(w) * bend
        x = lam * L
        ch, sh, co, si = math.cosh(x), math.sinh(x), math.cos(x), math.sin(x)
        S, T = 0.5 * (ch + co), 0.5 * (sh + si)
        U, V = 0.5 * (ch - co), 0.5 * (sh - si)
        vals[6 + r] = S
        if lam > 0.0:
            vals[8 + r] = T / lam
            vals[10 + r] = U / lam**2
            vals[12 + r] = V / lam**3
        else:
            vals[8 + r] = L
            vals[10 + r] = L**2 / 2.0
            vals[12 + r] = L**3 / 6.0
        vals[14 + r] = lam * V
        vals[16 + r] = lam**2 * U
        vals[18 + r] = lam**3 * T
    out = np.zeros(144)
    for i in range(40):
        out[flat[i]] = vals[gather[i]] * ratio[i]
    return out.reshape(12, 12)


def _point_slogdet(c, w, kind, beam, flat, gather, ratio, R12, M, T):
    """Sign and log|det subU| of configuration c at ω."""
    U = _point_system(c, w, kind, beam, flat, gather, ratio, R12, M, T)
    return np.linalg.slogdet(np.ascontiguousarray(U[6:12, :]))


def _system(cfg, omega, kind, beam, flat, gather, ratio, R12, M, T):
    """Columns 6–11 of the system matrix at every point, (n, 12, 6)."""
    out = np.empty((omega.size, 12, 6))
    for p in range(omega.size):
        out[p] = _point_system(cfg[p], omega[p], kind, beam, flat, gather, ratio, R12, M, T)
    return out


def _field(c, flat, gather, ratio, s, omega, z):
    """Local states ``U(s_p, ω_m) z_m`` of one beam, (m, P, 12)."""
    out = np.empty((omega.size, s.size, 12))
    cs = c.copy()
    for m in range(omega.size):
        for p in range(s.size):
            cs[0] = s[p]
            U = _beam_local(cs, flat, gather, ratio, omega[m])
            out[m, p] = U @ z[m]
    return out


def _point_system(c, w, kind, beam, flat, gather, ratio, R12, M, T):
    """Columns 6–11 of the system matrix of configuration c at ω (12 × 6)."""
    U = np.zeros((12, 6))
    for i in range(6):
        U[6 + i, i] = 1.0
    for j in range(kind.size):
        if kind[j] == 0:
            R = R12[c, j]
            B = _beam_local(beam[j], flat[j], gather[j], ratio[j], w)
            U = R @ (B @ (R.T @ U))
        elif kind[j] == 1:
            w2 = w * w
            jump = M[c, j] @ np.ascontiguousarray(U[0:6, :])  # [force; moment] rows
            U = U.copy()
            U[6:9, :] -= w2 * jump[3:6, :]
            U[9:12, :] -= w2 * jump[0:3, :]
        else:
            U = T[c, j] @ U
    return U


def _refine(cfg, lo, hi, kind, beam, flat, gather, ratio, R12, M, T):
    """Brent's method on det subU in every bracket [lo, hi] holding one simple root.

    The determinant is scaled per bracket by its magnitude at ``lo`` (from slogdet: no
    overflow). Returns the roots, a flag per bracket (False: no sign change at the ends,
    or a non-finite determinant) and the number of determinant evaluations.
    """
    n = lo.size
    roots = np.empty(n)
    ok = np.ones(n, dtype=np.bool_)
    evaluations = 0
    eps = 2.220446049250313e-16
    for i in range(n):
        c = cfg[i]
        a, b = lo[i], hi[i]
        sa, la = _point_slogdet(c, a, kind, beam, flat, gather, ratio, R12, M, T)
        sb, lb = _point_slogdet(c, b, kind, beam, flat, gather, ratio, R12, M, T)
        evaluations += 2
        if not (math.isfinite(la) or sa == 0.0) or not (math.isfinite(lb) or sb == 0.0):
            ok[i] = False
            roots[i] = 0.5 * (a + b)
            continue
        ref = la if math.isfinite(la) else lb
        fa = sa * math.exp(la - ref) if sa != 0.0 else 0.0
        fb = sb * math.exp(lb - ref) if sb != 0.0 else 0.0
        if fa == 0.0:
            roots[i] = a
            continue
        if fb == 0.0:
            roots[i] = b
            continue
        if (fa > 0.0) == (fb > 0.0):
            ok[i] = False
            roots[i] = 0.5 * (a + b)
            continue
        # Brent (zeroin): b is the best estimate, c2 the contrapoint
        c2, fc = a, fa
        d = e = b - a
        for _ in range(200):
            if (fb > 0.0) == (fc > 0.0):
                c2, fc = a, fa
                d = e = b - a
            if abs(fc) < abs(fb):
                a, fa = b, fb
                b, fb = c2, fc
                c2, fc = a, fa
            tol = 2.0 * eps * abs(b) + 0.5e-14 * abs(b)
            m = 0.5 * (c2 - b)
            if abs(m) <= tol or fb == 0.0:
                break
            if abs(e) >= tol and abs(fa) > abs(fb):
                s = fb / fa
                if a == c2:
                    p = 2.0 * m * s
                    q = 1.0 - s
                else:
                    q = fa / fc
                    r = fb / fc
                    p = s * (2.0 * m * q * (q - r) - (b - a) * (r - 1.0))
                    q = (q - 1.0) * (r - 1.0) * (s - 1.0)
                if p > 0.0:
                    q = -q
                else:
                    p = -p
                if 2.0 * p < min(3.0 * m * q - abs(tol * q), abs(e * q)):
                    e = d
                    d = p / q
                else:
                    d = m
                    e = m
            else:
                d = m
                e = m
            a, fa = b, fb
            if abs(d) > tol:
                b += d
            else:
                b += tol if m > 0.0 else -tol
            sb, lb = _point_slogdet(c, b, kind, beam, flat, gather, ratio, R12, M, T)
            evaluations += 1
            if not (math.isfinite(lb) or sb == 0.0):
                ok[i] = False
                break
            fb = sb * math.exp(lb - ref) if sb != 0.0 else 0.0
        roots[i] = b
    return roots, ok, evaluations


def _solve(A, B):
    """A⁻¹ B by Gaussian elimination with partial pivoting; NaN rows if A is singular."""
    n = A.shape[0]
    a = A.copy()
    x = B.copy()
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[piv, k]):
                piv = i
        if a[piv, k] == 0.0:
            x[:, :] = np.nan
            return x
        if piv != k:
            for j in range(n):
                a[k, j], a[piv, j] = a[piv, j], a[k, j]
            for j in range(x.shape[1]):
                x[k, j], x[piv, j] = x[piv, j], x[k, j]
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            if f != 0.0:
                for j in range(k + 1, n):
                    a[i, j] -= f * a[k, j]
                for j in range(x.shape[1]):
                    x[i, j] -= f * x[k, j]
    for k in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            v = x[k, j]
            for i in range(k + 1, n):
                v -= a[k, i] * x[i, j]
            x[k, j] = v / a[k, k]
    return x


def _negative_eigenvalues(A):
    """Number of negative eigenvalues of the symmetric part of A (cyclic Jacobi)."""
    n = A.shape[0]
    a = 0.5 * (A + A.T)
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale += a[i, j] * a[i, j]
    for _ in range(50):
        off = 0.0
        for i in range(n):
            for j in range(i + 1, n):
                off += a[i, j] * a[i, j]
        if off <= 1e-34 * scale:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                if a[p, q] == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):  # columns p, q
                    akp, akq = a[k, p], a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(n):  # rows p, q
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
    negatives = 0
    for i in range(n):
        if a[i, i] < 0.0:
            negatives += 1
    return negatives


def _clamped_bending_count(beta):
    if beta < 4.0:
        return 0.0
    i = math.floor(beta / math.pi)
    v = 1.0 - math.cosh(beta) * math.cos(beta)
    sgn = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return i - (1.0 - (-1.0) ** i * sgn) / 2.0


def _count(cfg, omega, kind, beam, flat, gather, ratio, R6, M, G, axis, stiffness):
    n = omega.size
    counts = np.zeros(n)
    finite = np.ones(n, dtype=np.bool_)
    conj = np.array([0, 1, 2, 3, 4, 5, 9, 10, 11, 6, 7, 8])
    eye = np.eye(6)
    for p in range(n):
        c, w = cfg[p], omega[p]
        w2 = w * w
        Z = np.zeros((6, 6))
        cnt = 0.0
        for j in range(kind.size - 1, -1, -1):
            if kind[j] == 1:
                Z = Z - w2 * M[c, j]
            elif kind[j] == 2:
                Gj = G[c, j]
                Z = Gj.T @ Z @ Gj
            elif kind[j] == 3:
                ev = np.zeros(6)
                ev[3:6] = axis[c, j]
                Ze = Z @ ev
                pv = Ze @ ev + stiffness[j]
                if pv < 0.0:
                    cnt += 1.0
                Z = Z - np.outer(Ze, Ze) / pv
            else:
                Tl = _beam_local(beam[j], flat[j], gather[j], ratio[j], w)
                Tc = np.empty((12, 12))
                for a in range(12):
                    for b in range(12):
                        Tc[a, b] = Tl[conj[a], conj[b]]
                Tdd = np.ascontiguousarray(Tc[:6, :6])
                Tdf = np.ascontiguousarray(Tc[:6, 6:])
                Tfd = np.ascontiguousarray(Tc[6:, :6])
                Tff = np.ascontiguousarray(Tc[6:, 6:])
                Tdf_inv = _solve(Tdf, eye)
                K00 = Tdf_inv @ Tdd
                K10 = Tfd - Tff @ K00
                K11 = Tff @ Tdf_inv
                R = R6[c, j]
                pivot = K11 + R.T @ Z @ R
                if not np.all(np.isfinite(pivot)):
                    finite[p] = False
                    break
                cnt += _negative_eigenvalues(pivot)
                Z = R @ (K00 + Tdf_inv @ _solve(pivot, K10)) @ R.T
                L = beam[j, 0]
                cnt += math.floor(w * L * beam[j, 7] / math.pi)
                cnt += math.floor(w * L * beam[j, 8] / math.pi)
                cnt += _clamped_bending_count(L * math.sqrt(w) * beam[j, 9])
                cnt += _clamped_bending_count(L * math.sqrt(w) * beam[j, 10])
        if finite[p] and not np.all(np.isfinite(Z)):
            finite[p] = False
        counts[p] = cnt
    return counts, finite


def _compile():
    """Import numba and wrap the kernels (their machine code is compiled on first call,
    or read from numba's cache); without numba, ``AVAILABLE`` is False."""
    g = globals()
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is the optional "fast" extra
        g.update(dict.fromkeys(_KERNELS), AVAILABLE=False)
        return
    jit = numba.njit(cache=True)
    # the helpers first: the kernels call them through these module globals
    for name in ("_beam_local", "_clamped_bending_count", "_solve", "_negative_eigenvalues",
                 "_point_system", "_point_slogdet"):
        g[name] = jit(g[name])
    g.update(system_points=jit(_system), field_points=jit(_field),
             refine_brackets=jit(_refine), count_points=jit(_count), AVAILABLE=True)


def __getattr__(name):
    if name == "AVAILABLE" or name in _KERNELS:
        _compile()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
