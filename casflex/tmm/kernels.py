"""Compiled kernels of the TMM: the whole root search of a configuration in one call
(Wittrick–Williams counts on the grid, bisection, Brent's method on ``det subU``), and the
point kernels (count, Brent per bracket, system columns, sampled beam field of the shapes).

The root search of :mod:`casflex.tmm.solve` evaluates two quantities at (configuration,
ω) points. In numpy each evaluation is a few hundred calls on 6 × 6 and 12 × 12 arrays,
and their per-call overhead, not the arithmetic, sets the time. These kernels do the same
arithmetic point by point in machine code (numba, ``cache=True``: the compiled code is
kept next to this file or in ``NUMBA_CACHE_DIR``), with explicit loops on preallocated
work arrays: the beam matrix is applied through its 40 non-zero entries and the rotation
through its 3 × 3 blocks (no BLAS call, no allocation per point). ``search_roots`` runs
:func:`casflex.tmm.solve._roots`'s algorithm (same grid brackets, bisection and Brent)
without a return to Python; it counts at the grid points lazily (where the count changes,
by bisection over the grid indices: 12 counts instead of 37 for 5 modes of the Table 8
arm), which gives the same brackets because the count never falls with ω. The check that
it never falls is then made on the points counted (the numpy path checks every grid
point; it runs, and diagnoses, whenever the compiled search reports a breakdown).
Without numba, ``AVAILABLE`` is False and the numpy path runs alone; the numpy path is
also the reference the kernels are tested against and the fallback when a kernel meets a
singular matrix or a breakdown (the numpy path has the least-squares and diagnosis
branches).

Data layout (C configurations, E elements): ``kind`` (E,) with 0 beam, 1 body, 2 offset,
3 spring; per element constants ``beam`` (E, 12) and per configuration matrices ``R3``
(C, E, 3, 3), ``G`` (C, E, 6, 6), ``M`` (C, E, 6, 6), ``T`` (C, E, 12, 12),
``axis`` (C, E, 3); the beam layout ``flat``, ``gather``, ``ratio`` (E, 40) comes from
:func:`casflex.tmm.elements.beam_field`'s table.
"""

from __future__ import annotations

import math
import threading

import numpy as np

__all__ = ["AVAILABLE", "constants", "pack", "search"]  # noqa: F822 (AVAILABLE: module __getattr__)

# ``AVAILABLE`` (True when the compiled kernels can run: numba importable) and the
# kernels ``count_points``, ``refine_brackets``, ``system_points``, ``field_points``,
# ``search_roots`` are
# made on first use (module ``__getattr__`` below): importing numba costs ~0.5 s, which
# a command that reads its modal tables from the cache never needs.
_KERNELS = ("count_points", "refine_brackets", "system_points", "field_points", "search_roots")


def constants(elements) -> dict:
    """The configuration-independent arrays of the kernels (see the module docstring).

    Parameters
    ----------
    elements : sequence of casflex.tmm.Element
        The chain's elements (only their kinds and parameters are read).

    Returns
    -------
    dict of numpy.ndarray
        ``kind``, ``beam``, ``flat``, ``gather``, ``ratio``, ``stiffness``.

    Examples
    --------
    >>> from casflex.robot import load
    >>> from casflex.tmm import build_chain
    >>> constants(build_chain(load("problems/arm2link.toml"), [0, 0, 0]).elements)["kind"]
    array([0, 0])
    """
    from casflex.tmm.elements import layout

    E = len(elements)
    out = {
        "kind": np.zeros(E, dtype=np.int64), "beam": np.zeros((E, 12)),
        "flat": np.zeros((E, 40), dtype=np.int64), "gather": np.zeros((E, 40), dtype=np.int64),
        "ratio": np.zeros((E, 40)), "stiffness": np.zeros(E),
    }
    for j, e in enumerate(elements):
        out["kind"][j] = ("beam", "body", "offset", "spring").index(e.kind)
        if e.kind == "beam":
            P = e.params
            sec, mat, L = P["section"], P["material"], P["length"]
            EA, EIx, EIy, GJ = mat.E * sec.A, mat.E * sec.Ix, mat.E * sec.Iy, mat.G * sec.J
            rho_A, rho_Ip = mat.rho * sec.A, mat.rho * sec.Ip
            table = layout(EA, EIx, EIy, GJ, rho_A, rho_Ip)
            out["flat"][j], out["gather"][j] = table["flat"], table["gather"]
            out["ratio"][j] = table["ratio"][:, 0]
            mu = mat.rho * sec.A
            out["beam"][j] = [
                L, table["stiff"][0, 0], table["stiff"][1, 0], table["wave"][0, 0],
                table["wave"][1, 0], table["bend"][0, 0], table["bend"][1, 0],
                np.sqrt(mat.rho / mat.E), np.sqrt(mat.rho * sec.Ip / (mat.G * sec.J)),
                (mu / (mat.E * sec.Iy)) ** 0.25, (mu / (mat.E * sec.Ix)) ** 0.25, 0.0]
        elif e.kind == "spring":
            out["stiffness"][j] = e.params["stiffness"]
    return out


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
    >>> pack([], 1)["R3"].shape
    (1, 0, 3, 3)
    """
    E = len(items)
    out = constants([data["element"] for data in items])
    out.update({
        "M": np.zeros((size, E, 6, 6)), "G": np.zeros((size, E, 6, 6)),
        "T": np.zeros((size, E, 12, 12)), "axis": np.zeros((size, E, 3)),
        "R3": np.zeros((size, E, 3, 3)),
    })
    for j, data in enumerate(items):
        e = data["element"]
        out["R3"][:, j] = data["R3"]
        if e.kind == "body":
            out["M"][:, j] = data["M"]
        elif e.kind == "offset":
            out["T"][:, j] = data["T"]
            out["G"][:, j] = data["G"]
        elif e.kind == "spring":
            out["T"][:, j] = data["T"]
            out["axis"][:, j] = data["axis"]
    return out


def search(kernel: dict, points: np.ndarray, cap: float, count: int | None,
           omega_max: float | None, double_tol: float, rtol: float) -> list | None:
    """The root search of every configuration of a packed stack, compiled (``search_roots``).

    Parameters
    ----------
    kernel : dict
        :func:`pack`'s arrays.
    points : numpy.ndarray
        The static probe, then the search grid [rad/s].
    cap : float
        Highest ω the grid may be extended to [rad/s].
    count, omega_max : int or None, float or None
        As for :func:`casflex.tmm.natural_frequencies` (omega_max in rad/s).
    double_tol, rtol : float
        Relative width of a multiple root's bracket; relative tolerance of the bisection
        fallback.

    Returns
    -------
    list of (numpy.ndarray, numpy.ndarray) or None
        ``(values, multiplicities)`` per configuration, or None when a configuration needs
        the Python path (a breakdown to diagnose, too few roots below ``cap``).

    Examples
    --------
    >>> # no element, so no root below the cap: the Python path reports it
    >>> search(pack([], 1), np.array([1e-3, 1.0]), 10.0, 1, None, 1e-9, 1e-12) is None
    True
    """
    if omega_max is not None and not omega_max > 0.0:
        return None
    g = globals()
    if "search_roots" not in g:
        _compile()
    if not g["AVAILABLE"]:  # pragma: no cover - without numba
        return None
    k = kernel
    values, multiplicity, filled, status = g["search_roots"](
        points, float(cap), -1 if count is None else int(count),
        -1.0 if omega_max is None else float(omega_max), float(double_tol), float(rtol),
        k["kind"], k["beam"], k["flat"], k["gather"], k["ratio"], k["R3"], k["M"],
        k["G"], k["T"], k["axis"], k["stiffness"], 64 if count is None else int(count))
    if status.any():
        return None
    return [(values[c, :n], multiplicity[c, :n]) for c, n in enumerate(filled)]


def _beam_values(c, w, vals):
    """The 20 closed-form quantities of a beam's local transfer matrix at ω (``vals``).

    ``c`` holds the beam constants of :func:`pack` (``c[0]`` the length); quantity j of
    row r sits at ``2 j + r`` as in :func:`casflex.tmm.elements.layout`.
    """
    L = c[0]
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


def _point_system(c, w, kind, beam, flat, gather, ratio, R3, M, T, U, W, vals, det_only):
    """Columns 6–11 of the system matrix of configuration c at ω, into U (12 × 6).

    The beam matrix is applied through its 40 non-zero entries and the rotation
    ``blockdiag(R, R, R, R)`` through its four 3 × 3 blocks; ``W`` and ``vals`` are work
    arrays (12 × 6, 29: the beam's 20 quantities, then a 3 × 3 rotation).

    The start ``[0; I]`` is rotated into the first beam's components by copying Rᵀ
    (the products with 0 and 1 are exact). With ``det_only`` U is good for
    ``det U[6:12]`` only, which does not change under ``blockdiag(R, R)`` (det R = 1):
    a beam followed by a beam (or by nothing) keeps U in its own components, and the
    next beam turns it with the one rotation ``R_nextᵀ R`` instead of two.
    """
    U[:, :] = 0.0
    for i in range(6):
        U[6 + i, i] = 1.0
    w2 = w * w
    fresh = True  # U is still [0; I], in base components
    local = -1  # with det_only: U is in the components of beam ``local`` (-1: base)
    E = kind.size
    for j in range(E):
        if kind[j] == 0:
            R = R3[c, j]
            if fresh:  # W = blockdiag(Rᵀ) [0; I]: rows 6–11 hold blockdiag(Rᵀ, Rᵀ)
                W[:, :] = 0.0
                for b in range(2):
                    for i in range(3):
                        for k in range(3):
                            W[6 + 3 * b + i, 3 * b + k] = R[k, i]
            else:
                if local >= 0:  # Q = Rᵀ R_local: from beam ``local``'s components to R's
                    Rp = R3[c, local]
                    for i in range(3):
                        for k in range(3):
                            vals[20 + 3 * i + k] = (R[0, i] * Rp[0, k] + R[1, i] * Rp[1, k]
                                                    + R[2, i] * Rp[2, k])
                else:  # Q = Rᵀ: base to local components
                    for i in range(3):
                        for k in range(3):
                            vals[20 + 3 * i + k] = R[k, i]
                for b in range(4):  # W = blockdiag(Q) U
                    for i in range(3):
                        r0, r1, r2 = vals[20 + 3 * i], vals[21 + 3 * i], vals[22 + 3 * i]
                        for col in range(6):
                            W[3 * b + i, col] = (r0 * U[3 * b, col] + r1 * U[3 * b + 1, col]
                                                 + r2 * U[3 * b + 2, col])
            fresh = False
            _beam_values(beam[j], w, vals)
            U[:, :] = 0.0
            for i in range(40):  # U = B W over the non-zero entries of B
                f = flat[j, i]
                row, column = f // 12, f % 12
                v = vals[gather[j, i]] * ratio[j, i]
                for col in range(6):
                    U[row, col] += v * W[column, col]
            if det_only and (j == E - 1 or kind[j + 1] == 0):
                local = j
                continue
            local = -1
            for b in range(4):  # back to base components: blockdiag(R) U
                for i in range(3):
                    r0, r1, r2 = R[i, 0], R[i, 1], R[i, 2]
                    for col in range(6):
                        W[3 * b + i, col] = (r0 * U[3 * b, col] + r1 * U[3 * b + 1, col]
                                             + r2 * U[3 * b + 2, col])
            U[:, :] = W
        elif kind[j] == 1:  # M d gives [force; moment]; the state holds [M; F]
            Mj = M[c, j]
            for i in range(6):
                for col in range(6):
                    s = 0.0
                    for k in range(6):
                        s += Mj[i, k] * U[k, col]
                    W[i, col] = s
            for i in range(3):
                for col in range(6):
                    U[6 + i, col] -= w2 * W[3 + i, col]
                    U[9 + i, col] -= w2 * W[i, col]
            fresh = False
        else:
            Tj = T[c, j]
            for i in range(12):
                for col in range(6):
                    s = 0.0
                    for k in range(12):
                        s += Tj[i, k] * U[k, col]
                    W[i, col] = s
            U[:, :] = W
            fresh = False


def _slogdet6(U, A):
    """Sign and log|det| of rows 6–11 of U (12 × 6), LU with partial pivoting in A."""
    for i in range(6):
        for k in range(6):
            A[i, k] = U[6 + i, k]
    sign, logabs = 1.0, 0.0
    for k in range(6):
        piv = k
        for i in range(k + 1, 6):
            if abs(A[i, k]) > abs(A[piv, k]):
                piv = i
        if A[piv, k] == 0.0:
            return 0.0, -math.inf
        if piv != k:
            sign = -sign
            for j in range(6):
                A[k, j], A[piv, j] = A[piv, j], A[k, j]
        d = A[k, k]
        if d < 0.0:
            sign = -sign
        logabs += math.log(abs(d))
        for i in range(k + 1, 6):
            f = A[i, k] / d
            for j in range(k + 1, 6):
                A[i, j] -= f * A[k, j]
    return sign, logabs


def _work():
    """Work arrays of the point kernels: (12 × 6) × 2, 29 values, (12 × 12), (6 × 6) × 8."""
    return (np.empty((12, 6)), np.empty((12, 6)), np.empty(29), np.empty((12, 12)),
            np.empty((8, 6, 6)))


def _point_slogdet(c, w, kind, beam, flat, gather, ratio, R3, M, T, U, W, vals, A):
    _point_system(c, w, kind, beam, flat, gather, ratio, R3, M, T, U, W, vals, True)
    return _slogdet6(U, A)


def _system(cfg, omega, kind, beam, flat, gather, ratio, R3, M, T):
    """Columns 6–11 of the system matrix at every point, (n, 12, 6)."""
    out = np.empty((omega.size, 12, 6))
    U, W, vals, _, _ = _work()
    for p in range(omega.size):
        _point_system(cfg[p], omega[p], kind, beam, flat, gather, ratio, R3, M, T, U, W, vals,
                      False)
        out[p] = U
    return out


def _field(c, flat, gather, ratio, s, omega, z):
    """Local states ``U(s_p, ω_m) z_m`` of one beam, (m, P, 12)."""
    out = np.zeros((omega.size, s.size, 12))
    cs = c.copy()
    vals = np.empty(20)
    for m in range(omega.size):
        for p in range(s.size):
            cs[0] = s[p]
            _beam_values(cs, omega[m], vals)
            for i in range(40):
                f = flat[i]
                out[m, p, f // 12] += vals[gather[i]] * ratio[i] * z[m, f % 12]
    return out


def _brent(c, a, b, kind, beam, flat, gather, ratio, R3, M, T, U, W, vals, A, ends, known):
    """Brent's method (zeroin) on det subU in a bracket [a, b] holding one simple root.

    The determinant is scaled by its magnitude at an end (from the log-determinant: no
    overflow). ``ends`` holds (sign, log|det|) at a and b: read where ``known`` says so
    (bit 1: a, bit 2: b; a bracket sharing an end with one already refined), evaluated
    and written otherwise. Returns the root, False when there is no sign change at the
    ends or a determinant is not finite, and the number of determinant evaluations.
    """
    eps = 2.220446049250313e-16
    evaluations = 0
    if known & 1 == 0:
        ends[0], ends[1] = _point_slogdet(c, a, kind, beam, flat, gather, ratio, R3, M, T, U,
                                          W, vals, A)
        evaluations += 1
    if known & 2 == 0:
        ends[2], ends[3] = _point_slogdet(c, b, kind, beam, flat, gather, ratio, R3, M, T, U,
                                          W, vals, A)
        evaluations += 1
    sa, la, sb, lb = ends[0], ends[1], ends[2], ends[3]
    if not (math.isfinite(la) or sa == 0.0) or not (math.isfinite(lb) or sb == 0.0):
        return 0.5 * (a + b), False, evaluations
    ref = la if math.isfinite(la) else lb
    fa = sa * math.exp(la - ref) if sa != 0.0 else 0.0
    fb = sb * math.exp(lb - ref) if sb != 0.0 else 0.0
    if fa == 0.0:
        return a, True, evaluations
    if fb == 0.0:
        return b, True, evaluations
    if (fa > 0.0) == (fb > 0.0):
        return 0.5 * (a + b), False, evaluations
    c2, fc = a, fa  # b is the best estimate, c2 the contrapoint
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
        sb, lb = _point_slogdet(c, b, kind, beam, flat, gather, ratio, R3, M, T, U, W, vals,
                                A)
        evaluations += 1
        if not (math.isfinite(lb) or sb == 0.0):
            return b, False, evaluations
        fb = sb * math.exp(lb - ref) if sb != 0.0 else 0.0
    return b, True, evaluations


def _refine(cfg, lo, hi, kind, beam, flat, gather, ratio, R3, M, T):
    """Brent's method in every bracket [lo, hi] holding one simple root (:func:`_brent`)."""
    n = lo.size
    roots = np.empty(n)
    ok = np.ones(n, dtype=np.bool_)
    evaluations = 0
    U, W, vals, _, B = _work()
    ends = np.empty(4)
    for i in range(n):
        roots[i], ok[i], k = _brent(cfg[i], lo[i], hi[i], kind, beam, flat, gather, ratio,
                                    R3, M, T, U, W, vals, B[0], ends, 0)
        evaluations += k
    return roots, ok, evaluations


#: the partner of each local DOF [u, θ] in the beam's decoupled blocks (-1: alone)
_PARTNER = (4, 3, -1, 1, 0, -1)


def _congruence6(R, A, X, out, transpose):
    """``out = S A Sᵀ`` with ``S = blockdiag(R, R)`` (or its transpose), by 3 × 3 blocks."""
    for i in range(6):  # X = A Sᵀ
        for b in range(3):
            for J in range(2):
                s = 0.0
                for k in range(3):
                    s += A[i, 3 * J + k] * (R[k, b] if transpose else R[b, k])
                X[i, 3 * J + b] = s
    for I in range(2):  # out = S X
        for a in range(3):
            for col in range(6):
                s = 0.0
                for k in range(3):
                    s += (R[k, a] if transpose else R[a, k]) * X[3 * I + k, col]
                out[3 * I + a, col] = s


def _matmul6(A, B, out):
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += A[i, k] * B[k, j]
            out[i, j] = s


def _solve_into(A, B, a, x):
    """x = A⁻¹ B by Gaussian elimination with partial pivoting (a: work copy of A).

    Returns False if A is singular (a zero pivot) or not finite.
    """
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            a[i, j] = A[i, j]
            x[i, j] = B[i, j]
    for k in range(n):
        piv = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[piv, k]):
                piv = i
        if not a[piv, k] != 0.0:  # zero or NaN
            return False
        if piv != k:
            for j in range(n):
                a[k, j], a[piv, j] = a[piv, j], a[k, j]
                x[k, j], x[piv, j] = x[piv, j], x[k, j]
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            if f != 0.0:
                for j in range(k + 1, n):
                    a[i, j] -= f * a[k, j]
                for j in range(n):
                    x[i, j] -= f * x[k, j]
    for k in range(n - 1, -1, -1):
        for j in range(n):
            v = x[k, j]
            for i in range(k + 1, n):
                v -= a[k, i] * x[i, j]
            x[k, j] = v / a[k, k]
    return True


def _negative_eigenvalues(A, a):
    """Number of negative eigenvalues of the symmetric part of A (6 × 6, work array a).

    Sylvester's law of inertia on a symmetric indefinite ``LDLᵀ`` factorisation with
    Bunch–Kaufman pivoting (1 × 1 and 2 × 2 pivots, backward stable): the count is the
    negative eigenvalues of D.
    """
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            a[i, j] = 0.5 * (A[i, j] + A[j, i])
    alpha = (1.0 + math.sqrt(17.0)) / 8.0
    negatives = 0
    k = 0
    while k < n:
        akk = abs(a[k, k])
        r, colmax = k, 0.0
        for i in range(k + 1, n):
            if abs(a[i, k]) > colmax:
                r, colmax = i, abs(a[i, k])
        if akk == 0.0 and colmax == 0.0:  # a zero eigenvalue: not negative
            k += 1
            continue
        size, p = 1, k
        if akk < alpha * colmax:
            rowmax = 0.0
            for j in range(k, n):
                if j != r and abs(a[r, j]) > rowmax:
                    rowmax = abs(a[r, j])
            if akk * rowmax >= alpha * colmax * colmax:
                p = k
            elif abs(a[r, r]) >= alpha * rowmax:
                p = r
            else:
                size, p = 2, r
        t = k + size - 1  # the pivot block ends at t; bring row/column p there
        if p != t:
            for j in range(n):
                a[t, j], a[p, j] = a[p, j], a[t, j]
            for i in range(n):
                a[i, t], a[i, p] = a[i, p], a[i, t]
        if size == 1:
            d = a[k, k]
            if d < 0.0:
                negatives += 1
            for i in range(k + 1, n):
                f = a[i, k] / d
                for j in range(k + 1, n):
                    a[i, j] -= f * a[k, j]
        else:
            d11, d12, d22 = a[k, k], a[k + 1, k], a[k + 1, k + 1]
            det = d11 * d22 - d12 * d12
            if det < 0.0:
                negatives += 1
            elif d11 + d22 < 0.0:
                negatives += 2
            for i in range(k + 2, n):
                # [f1, f2] = [a_ik, a_i,k+1] D⁻¹
                f1 = (a[i, k] * d22 - a[i, k + 1] * d12) / det
                f2 = (a[i, k + 1] * d11 - a[i, k] * d12) / det
                for j in range(k + 2, n):
                    a[i, j] -= f1 * a[k, j] + f2 * a[k + 1, j]
        k += size
    return negatives


def _clamped_bending_count(beta):
    if beta < 4.0:
        return 0.0
    i = math.floor(beta / math.pi)
    v = 1.0 - math.cosh(beta) * math.cos(beta)
    sgn = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return i - (1.0 - (-1.0) ** i * sgn) / 2.0


def _count_point(c, w, kind, beam, flat, gather, ratio, R3, M, G, axis, stiffness, vals,
                 Tc, B):
    """Wittrick–Williams count below ω of configuration c, and whether it is finite.

    ``vals`` (20), ``Tc`` (12 × 12) and ``B`` (8, 6, 6) are work arrays.
    """
    w2 = w * w
    Z, Tinv, K00, K10, P, X, Y, E = B[0], B[1], B[2], B[3], B[4], B[5], B[6], B[7]
    Z[:, :] = 0.0
    cnt = 0.0
    for j in range(kind.size - 1, -1, -1):
        if kind[j] == 1:
            for a in range(6):
                for b in range(6):
                    Z[a, b] -= w2 * M[c, j, a, b]
        elif kind[j] == 2:
            Gj = G[c, j]
            _matmul6(Z, Gj, X)
            for a in range(6):
                for b in range(6):
                    s = 0.0
                    for k in range(6):
                        s += Gj[k, a] * X[k, b]
                    Z[a, b] = s
        elif kind[j] == 3:
            ax = axis[c, j]
            pv = stiffness[j]
            for a in range(6):
                s = 0.0
                for k in range(3):
                    s += Z[a, 3 + k] * ax[k]
                vals[a] = s  # Z e
            for k in range(3):
                pv += vals[3 + k] * ax[k]
            if pv < 0.0:
                cnt += 1.0
            for a in range(6):
                for b in range(6):
                    Z[a, b] -= vals[a] * vals[b] / pv
        else:
            # local transfer matrix with forces as [F, M] (work-conjugate to [u, θ]); the
            # permutation swaps rows/columns 6–8 and 9–11 and is its own inverse
            _beam_values(beam[j], w, vals)
            Tc[:, :] = 0.0
            for i in range(40):
                f = flat[j, i]
                row, column = f // 12, f % 12
                row = row + 3 if 6 <= row < 9 else (row - 3 if row >= 9 else row)
                column = column + 3 if 6 <= column < 9 else (column - 3 if column >= 9
                                                              else column)
                Tc[row, column] = vals[gather[j, i]] * ratio[j, i]
            # the local DOFs decouple (axial u_z, torsion θ_z, bending u_x–θ_y and
            # u_y–θ_x): every block of Tc couples a DOF only with itself and its partner
            Tinv[:, :] = 0.0  # Tdf⁻¹, group by group
            for a in range(6):
                p = _PARTNER[a]
                if p < 0:
                    if not Tc[a, 6 + a] != 0.0:
                        return cnt, False
                    Tinv[a, a] = 1.0 / Tc[a, 6 + a]
                elif p > a:
                    d = Tc[a, 6 + a] * Tc[p, 6 + p] - Tc[a, 6 + p] * Tc[p, 6 + a]
                    if not (d != 0.0 and math.isfinite(d)):
                        return cnt, False
                    Tinv[a, a], Tinv[p, p] = Tc[p, 6 + p] / d, Tc[a, 6 + a] / d
                    Tinv[a, p], Tinv[p, a] = -Tc[a, 6 + p] / d, -Tc[p, 6 + a] / d
            for a in range(6):
                p = _PARTNER[a]
                for b in range(6):  # K00 = Tdf⁻¹ Tdd
                    K00[a, b] = Tinv[a, a] * Tc[a, b] + (Tinv[a, p] * Tc[p, b] if p >= 0
                                                         else 0.0)
            for a in range(6):
                p = _PARTNER[a]
                for b in range(6):  # K10 = Tfd − Tff K00; K11 = Tff Tdf⁻¹ (into E)
                    K10[a, b] = Tc[6 + a, b] - Tc[6 + a, 6 + a] * K00[a, b] - (
                        Tc[6 + a, 6 + p] * K00[p, b] if p >= 0 else 0.0)
                    E[a, b] = Tc[6 + a, 6 + a] * Tinv[a, b] + (
                        Tc[6 + a, 6 + p] * Tinv[p, b] if p >= 0 else 0.0)
            R = R3[c, j]
            _congruence6(R, Z, X, P, True)  # pivot = K11 + Rᵀ Z R
            for a in range(6):
                for b in range(6):
                    P[a, b] += E[a, b]
                    if not math.isfinite(P[a, b]):
                        return cnt, False
            cnt += _negative_eigenvalues(P, Y)
            if not _solve_into(P, K10, Y, X):  # X = pivot⁻¹ K10
                return cnt, False
            for a in range(6):  # Y = K00 − K01 pivot⁻¹ K10 with K01 = −Tdf⁻¹
                p = _PARTNER[a]
                for b in range(6):
                    Y[a, b] = K00[a, b] + Tinv[a, a] * X[a, b] + (
                        Tinv[a, p] * X[p, b] if p >= 0 else 0.0)
            _congruence6(R, Y, X, Z, False)  # Z = R Y Rᵀ
            L = beam[j, 0]
            cnt += math.floor(w * L * beam[j, 7] / math.pi)
            cnt += math.floor(w * L * beam[j, 8] / math.pi)
            cnt += _clamped_bending_count(L * math.sqrt(w) * beam[j, 9])
            cnt += _clamped_bending_count(L * math.sqrt(w) * beam[j, 10])
    for a in range(6):
        for b in range(6):
            if not math.isfinite(Z[a, b]):
                return cnt, False
    return cnt, True


def _count(cfg, omega, kind, beam, flat, gather, ratio, R3, M, G, axis, stiffness):
    n = omega.size
    counts = np.zeros(n)
    finite = np.ones(n, dtype=np.bool_)
    _, _, vals, Tc, B = _work()
    for p in range(n):
        counts[p], finite[p] = _count_point(cfg[p], omega[p], kind, beam, flat, gather,
                                            ratio, R3, M, G, axis, stiffness, vals, Tc, B)
    return counts, finite


#: status of :func:`_search` per configuration
SEARCH_OK, SEARCH_BREAKDOWN, SEARCH_TOO_FEW, SEARCH_FULL = 0, 1, 2, 3


def _search(points, cap, count, omega_max, double_tol, rtol, kind, beam, flat, gather,
            ratio, R3, M, G, T, axis, stiffness, width):
    """The whole root search of :func:`casflex.tmm.solve._roots` for every configuration.

    The grid is counted lazily (see the module docstring). ``points`` is the static probe
    followed by the search grid; ``count`` ≤ 0 means no
    count, ``omega_max`` ≤ 0 no upper limit. Returns per configuration the values and
    multiplicities (C, width), how many are filled and a status: ``SEARCH_OK``, or a case
    the Python path handles with its diagnosis (``SEARCH_BREAKDOWN``: a count not finite,
    above 0 at the probe or falling, a determinant not finite, a root at the probe;
    ``SEARCH_TOO_FEW``: fewer than ``count`` roots below the cap; ``SEARCH_FULL``: more
    than ``width`` values).
    """
    C = R3.shape[0]
    values = np.zeros((C, width))
    multiplicity = np.zeros((C, width), dtype=np.int64)
    filled = np.zeros(C, dtype=np.int64)
    status = np.zeros(C, dtype=np.int64)
    U, W, vals, Tc, B = _work()
    A = np.empty((6, 6))
    ends = np.empty(4)
    for c in range(C):
        grid = np.empty(points.size - 1 + 8 * 64)
        counts = np.empty(grid.size, dtype=np.int64)
        n = points.size - 1
        grid[:n] = points[1:]
        n0, ok = _count_point(c, points[0], kind, beam, flat, gather, ratio, R3, M, G, axis,
                              stiffness, vals, Tc, B)
        if not ok or n0 > 0.0:
            status[c] = SEARCH_BREAKDOWN
            continue
        # the counts are evaluated lazily: at the top of the grid, then by bisection over
        # the grid indices where the count changes (it never falls with ω: equal counts
        # at two grid points mean no root between them). The brackets are the grid
        # intervals holding roots, those of counting every grid point.
        broken = False
        v, ok = _count_point(c, grid[n - 1], kind, beam, flat, gather, ratio, R3, M, G,
                             axis, stiffness, vals, Tc, B)
        counts[n - 1] = int(v)
        broken = not ok
        if omega_max <= 0.0:
            while not broken and counts[n - 1] < count and grid[n - 1] < cap:
                if n + 8 > grid.size:
                    broken = True
                    break
                start = grid[n - 1] * 2.0
                stop = min(grid[n - 1] * 256.0, cap)
                for i in range(8):
                    grid[n + i] = start * (stop / start) ** (i / 7.0)
                grid[n + 7] = stop
                v, ok = _count_point(c, grid[n + 7], kind, beam, flat, gather, ratio, R3, M,
                                     G, axis, stiffness, vals, Tc, B)
                counts[n + 7] = int(v)
                if not ok or counts[n + 7] < counts[n - 1]:
                    broken = True
                n += 8
        if broken:
            status[c] = SEARCH_BREAKDOWN
            continue
        if omega_max <= 0.0:
            if counts[n - 1] < count:
                status[c] = SEARCH_TOO_FEW
                continue
            want = count
        else:
            want = counts[n - 1] if count <= 0 else min(count, counts[n - 1])
        # brackets on a stack: (lo, hi, count at lo, count at hi)
        size = n + 64
        lo, hi = np.empty(size), np.empty(size)
        nlo, nhi = np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64)
        top = 0
        first, last = np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64)
        first[0], last[0] = -1, n - 1  # grid index -1 is ω = 0, count 0
        ranges = 1
        while ranges > 0:
            ranges -= 1
            i, j = first[ranges], last[ranges]
            ci = counts[i] if i >= 0 else 0
            if counts[j] == ci or ci >= want:
                continue
            if j == i + 1:
                lo[top], hi[top] = (grid[i] if i >= 0 else 0.0), grid[j]
                nlo[top], nhi[top] = ci, counts[j]
                top += 1
                continue
            mid = (i + j) // 2
            v, ok = _count_point(c, grid[mid], kind, beam, flat, gather, ratio, R3, M, G,
                                 axis, stiffness, vals, Tc, B)
            counts[mid] = int(v)
            if not ok or not (ci <= counts[mid] <= counts[j]) or ranges + 2 > size:
                broken = True
                break
            first[ranges], last[ranges] = mid, j
            first[ranges + 1], last[ranges + 1] = i, mid
            ranges += 2
        if broken:
            status[c] = SEARCH_BREAKDOWN
            continue
        roots = np.empty(width)
        mult = np.empty(width, dtype=np.int64)
        found = 0
        # the ends of the brackets refined so far and their determinants: neighbouring
        # brackets share an end, whose determinant is then not evaluated again
        seen = np.empty(2 * width)
        seen_ends = np.empty((2 * width, 2))
        n_seen = 0
        while top > 0 and not broken:
            top -= 1
            a, b, na, nb = lo[top], hi[top], nlo[top], nhi[top]
            if not (nb > na and na < want):
                continue
            if found >= width:
                status[c] = SEARCH_FULL
                broken = True
                break
            if nb - na == 1:
                a = max(a, 1e-12 * b)
                known = 0
                for i in range(n_seen):
                    if seen[i] == a:
                        ends[0], ends[1] = seen_ends[i, 0], seen_ends[i, 1]
                        known |= 1
                    elif seen[i] == b:
                        ends[2], ends[3] = seen_ends[i, 0], seen_ends[i, 1]
                        known |= 2
                r, ok, _ = _brent(c, a, b, kind, beam, flat, gather, ratio, R3, M, T, U, W,
                                  vals, A, ends, known)
                for i in range(2):
                    if known & (1 << i) == 0 and n_seen < seen.size:
                        seen[n_seen] = a if i == 0 else b
                        seen_ends[n_seen, 0], seen_ends[n_seen, 1] = ends[2 * i], ends[2 * i + 1]
                        n_seen += 1
                if not ok:  # no sign change seen: bisect on the exact counts instead
                    v, ok = _count_point(c, a, kind, beam, flat, gather, ratio, R3, M, G,
                                         axis, stiffness, vals, Tc, B)
                    lo_i, hi_i = a, b
                    while ok and hi_i - lo_i > rtol * hi_i:
                        mid = 0.5 * (lo_i + hi_i)
                        vm, ok = _count_point(c, mid, kind, beam, flat, gather, ratio, R3, M,
                                              G, axis, stiffness, vals, Tc, B)
                        if vm > v:
                            hi_i = mid
                        else:
                            lo_i = mid
                    if not ok:
                        broken = True
                        break
                    r = 0.5 * (lo_i + hi_i)
                roots[found], mult[found] = r, 1
                found += 1
            elif b - a <= double_tol * b:
                roots[found], mult[found] = 0.5 * (a + b), nb - na
                found += 1
            else:
                mid = 0.5 * (a + b)
                v, ok = _count_point(c, mid, kind, beam, flat, gather, ratio, R3, M, G, axis,
                                     stiffness, vals, Tc, B)
                if not ok or not (na <= v <= nb):
                    broken = True
                    break
                if top + 2 > size:
                    status[c] = SEARCH_FULL
                    broken = True
                    break
                lo[top], hi[top], nlo[top], nhi[top] = mid, b, int(v), nb
                lo[top + 1], hi[top + 1], nlo[top + 1], nhi[top + 1] = a, mid, na, int(v)
                top += 2
        if broken:
            if status[c] == SEARCH_OK:
                status[c] = SEARCH_BREAKDOWN
            continue
        for i in range(found):
            if not (roots[i] > points[0]) or not math.isfinite(roots[i]):
                broken = True
        if broken:
            status[c] = SEARCH_BREAKDOWN
            continue
        order = np.argsort(roots[:found])
        k = 0
        for i in order:
            for _ in range(mult[i]):
                if (count > 0 and k >= count) or (omega_max > 0.0 and roots[i] > omega_max):
                    break
                if k >= width:
                    status[c] = SEARCH_FULL
                    break
                values[c, k], multiplicity[c, k] = roots[i], mult[i]
                k += 1
        filled[c] = k
    return values, multiplicity, filled, status


_COMPILE_LOCK = threading.Lock()


def _compile():
    """Import numba and wrap the kernels (their machine code is compiled on first call,
    or read from numba's cache); without numba, ``AVAILABLE`` is False. Once, under a
    lock: two threads (Dask workers of one process) would otherwise both wrap the helpers,
    and numba refuses to wrap a function twice."""
    with _COMPILE_LOCK:
        if "AVAILABLE" not in globals():
            _wrap_kernels()


def _wrap_kernels():
    g = globals()
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is the optional "fast" extra
        g.update(dict.fromkeys(_KERNELS), AVAILABLE=False)
        return
    jit = numba.njit(cache=True)
    # the helpers first: the kernels call them through these module globals
    for name in ("_beam_values", "_point_system", "_slogdet6", "_work", "_point_slogdet",
                 "_brent", "_matmul6", "_congruence6", "_solve_into", "_negative_eigenvalues",
                 "_clamped_bending_count", "_count_point"):
        g[name] = jit(g[name])
    g.update(system_points=jit(_system), field_points=jit(_field),
             refine_brackets=jit(_refine), count_points=jit(_count),
             search_roots=jit(_search), AVAILABLE=True)


def __getattr__(name):
    if name == "AVAILABLE" or name in _KERNELS:
        _compile()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
