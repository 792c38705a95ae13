"""Compiled body of the TMM's mode shapes of simple roots (:func:`casflex.tmm.fast.shape_fields`).

Per mode: the null vector of ``subU`` by inverse iteration (:func:`_null_vector`), the
state carried along the chain, the local state sampled along every beam with
angle-addition recurrences on the uniform grid (one ``sin``/``cos``/``sinh``/``cosh`` per
beam and mode instead of twelve per point), then the derived fields and the unit-peak
scaling. Plain Python functions: :mod:`casflex.tmm.fast` wraps them with numba
(``cache=True``) on first use, through :func:`wrap`.

The sampled state ``B(s) z`` is summed over the beam matrix's 40 non-zero entries in
runs of one row each, in a register (a sum per row in memory made every term wait for
the previous one's store: 18 of the kernel's 32 µs for 5 modes of the Table 8 arm at
51 points; now ~11). The sums and their order are those of the former row-by-row
accumulation, so the fields are bit for bit the same.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["shapes", "wrap"]


def _null_vector(A, x, piv):
    """Unit null vector of the nearly singular 6 × 6 ``A`` (overwritten by its LU) into x,
    by two steps of inverse iteration; False when A is not finite or zero."""
    n = 6
    scale = 0.0
    for i in range(n):
        for j in range(n):
            if not math.isfinite(A[i, j]):
                return False
            scale = max(scale, abs(A[i, j]))
    if scale == 0.0:
        return False
    # (a pivot merely small must stay as it is: raising it to eps·scale would bias the
    # null vector by eps·κ, 1e-11 on ill-conditioned modes)
    tiny = 1e-200 * scale
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(A[i, k]) > abs(A[p, k]):
                p = i
        piv[k] = p
        if p != k:
            for j in range(n):
                A[k, j], A[p, j] = A[p, j], A[k, j]
        if A[k, k] == 0.0:  # exactly singular: any tiny pivot gives the null vector
            A[k, k] = tiny
        for i in range(k + 1, n):
            A[i, k] /= A[k, k]
            for j in range(k + 1, n):
                A[i, j] -= A[i, k] * A[k, j]
    for i in range(n):
        x[i] = 1.0
    for _ in range(2):
        for k in range(n):  # L y = P x
            p = piv[k]
            x[k], x[p] = x[p], x[k]
        for i in range(n):
            for j in range(i):
                x[i] -= A[i, j] * x[j]
        for i in range(n - 1, -1, -1):  # U z = y
            for j in range(i + 1, n):
                x[i] -= A[i, j] * x[j]
            x[i] /= A[i, i]
        norm = 0.0
        for i in range(n):
            norm += x[i] * x[i]
        norm = math.sqrt(norm)
        if not (norm > 0.0 and math.isfinite(norm)):
            return False
        for i in range(n):
            x[i] /= norm
    return True


def shapes(c, omega, sub, s, moduli, kind, beam, flat, gather, ratio, R3, M, T, axis,
           stiffness):
    """The mode-shape fields of configuration ``c`` at its simple roots ``omega``.

    Parameters
    ----------
    c : int
        The configuration in the packed arrays.
    omega : numpy.ndarray
        (m,) simple natural frequencies [rad/s].
    sub : numpy.ndarray
        (m, 12, 6) columns 6–11 of the system matrix at them (``kernels.system_points``).
    s : numpy.ndarray
        (n_beams, n_points) uniform sample points from each beam's start [m].
    moduli : numpy.ndarray
        (n_beams, 4) ``EIx, EIy, GJ, EA`` [N m², N m², N m², N].
    kind, beam, flat, gather, ratio, R3, M, T, axis, stiffness
        The packed arrays of :mod:`casflex.tmm.kernels`.

    Returns
    -------
    tuple
        The fields of :data:`casflex.tmm.fast.SHAPE_FIELDS` in order (unit peak
        displacement), then True; False last when a null vector cannot be made.

    Examples
    --------
    >>> import numpy as np
    >>> from casflex.robot import load
    >>> from casflex.tmm import fast, kernels, natural_frequencies
    >>> arm = load("problems/arm2link.toml")
    >>> prepared = fast.prepare(arm)
    >>> k, layout = prepared.pose(np.zeros((1, 3))), prepared.shape_layout(11)
    >>> w = natural_frequencies(arm, [0.0, 0.0, 0.0], count=2)
    >>> packed = [k[name] for name in ("kind", "beam", "flat", "gather", "ratio", "R3")]
    >>> sub = kernels.system_points(np.zeros(2, dtype=np.int64), w, *packed, k["M"], k["T"])
    >>> out = shapes(0, w, sub, layout["s"], layout["moduli"], *packed, k["M"], k["T"],
    ...              k["axis"], k["stiffness"])
    >>> out[0].shape, float(abs(out[0]).max()), out[-1]
    ((2, 2, 11, 3), 1.0, True)
    """
    m = omega.size
    nb, P = s.shape
    n_body, n_spring = 0, 0
    for j in range(kind.size):
        n_body += kind[j] == 1
        n_spring += kind[j] == 3
    local = np.zeros((m, nb, P, 12))
    body = np.zeros((m, n_body, 6))
    body_local = np.zeros((m, n_body, 6))
    spring = np.zeros((m, n_spring))
    A = np.empty((6, 6))
    f0 = np.empty(6)
    piv = np.empty(6, dtype=np.int64)
    z = np.empty(12)
    zl = np.empty(12)
    zn = np.empty(12)
    vals = np.empty(20)
    trig = np.empty((2, 6))  # per bending/wave row r: cos, sin (wave), cosh, sinh, cos, sin
    step = np.empty((2, 6))
    factor = np.empty((2, 5))
    coef = np.empty(40)
    row_of = np.empty(40, dtype=np.int64)
    ok = True
    for mode in range(m):
        w = omega[mode]
        w2 = w * w
        for i in range(6):
            for j in range(6):
                A[i, j] = sub[mode, 6 + i, j]
        if not _null_vector(A, f0, piv):
            ok = False
            break
        for i in range(6):
            z[i] = 0.0
            z[6 + i] = f0[i]
        ib, ibody, ispring = 0, 0, 0
        for j in range(kind.size):
            R = R3[c, j]
            if kind[j] == 0:
                for b in range(4):  # base to local components: blockdiag(Rᵀ) z
                    for i in range(3):
                        zl[3 * b + i] = (R[0, i] * z[3 * b] + R[1, i] * z[3 * b + 1]
                                         + R[2, i] * z[3 * b + 2])
                h = s[ib, 1] - s[ib, 0]
                for r in range(2):  # per row r: factors of the 20 quantities, recurrences
                    stiff, k_wave = beam[j, 1 + r], w * beam[j, 3 + r]
                    lam = math.sqrt(w) * beam[j, 5 + r]
                    factor[r, 0] = 1.0 / (k_wave * stiff) if k_wave != 0.0 else 0.0
                    factor[r, 1] = -stiff * k_wave
                    factor[r, 2], factor[r, 3], factor[r, 4] = lam, lam * lam, lam * lam * lam
                    for q in range(6):
                        trig[r, q] = 1.0 if q % 2 == 0 else 0.0
                    step[r, 0], step[r, 1] = math.cos(k_wave * h), math.sin(k_wave * h)
                    step[r, 2], step[r, 3] = math.cosh(lam * h), math.sinh(lam * h)
                    step[r, 4], step[r, 5] = math.cos(lam * h), math.sin(lam * h)
                for i in range(40):  # B(s) z = sum of vals[gather] (ratio z[column]) e_row
                    f = flat[j, i]
                    row_of[i] = f // 12
                    coef[i] = ratio[j, i] * zl[f % 12]
                for p in range(P):
                    sp = s[ib, p]
                    for r in range(2):
                        cs, sn = trig[r, 0], trig[r, 1]
                        vals[r] = cs
                        # sin(ks)/(k stiff); s/stiff at ω = 0
                        vals[2 + r] = sn * factor[r, 0] if factor[r, 0] != 0.0 else (
                            sp / beam[j, 1 + r])
                        vals[4 + r] = factor[r, 1] * sn
                        ch, sh, co, si = trig[r, 2], trig[r, 3], trig[r, 4], trig[r, 5]
                        S_, T_ = 0.5 * (ch + co), 0.5 * (sh + si)
                        U_, V_ = 0.5 * (ch - co), 0.5 * (sh - si)
                        lam, lam2, lam3 = factor[r, 2], factor[r, 3], factor[r, 4]
                        vals[6 + r] = S_
                        if lam > 0.0:
                            vals[8 + r] = T_ / lam
                            vals[10 + r] = U_ / lam2
                            vals[12 + r] = V_ / lam3
                        else:
                            vals[8 + r] = sp
                            vals[10 + r] = sp * sp / 2.0
                            vals[12 + r] = sp * sp * sp / 6.0
                        vals[14 + r] = lam * V_
                        vals[16 + r] = lam2 * U_
                        vals[18 + r] = lam3 * T_
                        # angle addition to the next point of the uniform grid
                        a0, a1 = trig[r, 0], trig[r, 1]
                        trig[r, 0] = a0 * step[r, 0] - a1 * step[r, 1]
                        trig[r, 1] = a1 * step[r, 0] + a0 * step[r, 1]
                        a0, a1 = trig[r, 2], trig[r, 3]
                        trig[r, 2] = a0 * step[r, 2] + a1 * step[r, 3]
                        trig[r, 3] = a1 * step[r, 2] + a0 * step[r, 3]
                        a0, a1 = trig[r, 4], trig[r, 5]
                        trig[r, 4] = a0 * step[r, 4] - a1 * step[r, 5]
                        trig[r, 5] = a1 * step[r, 4] + a0 * step[r, 5]
                    # summed in a register over each run of entries in one row (the
                    # layout's rows come in runs; the same sums in the same order as
                    # accumulating in ``local``, without a store and load per term)
                    x = local[mode, ib, p]
                    row, acc = row_of[0], 0.0
                    for i in range(40):
                        if row_of[i] != row:
                            x[row] += acc
                            row, acc = row_of[i], 0.0
                        acc += vals[gather[j, i]] * coef[i]
                    x[row] += acc
                last = local[mode, ib, P - 1]
                for b in range(4):  # back to base components at the beam end
                    for i in range(3):
                        z[3 * b + i] = (R[i, 0] * last[3 * b] + R[i, 1] * last[3 * b + 1]
                                        + R[i, 2] * last[3 * b + 2])
                ib += 1
            elif kind[j] == 1:
                for i in range(6):
                    body[mode, ibody, i] = z[i]
                for b in range(2):
                    for i in range(3):
                        body_local[mode, ibody, 3 * b + i] = (
                            R[0, i] * z[3 * b] + R[1, i] * z[3 * b + 1]
                            + R[2, i] * z[3 * b + 2])
                ibody += 1
                for i in range(6):  # M d gives [force; moment]; the state holds [M; F]
                    v = 0.0
                    for q in range(6):
                        v += M[c, j, i, q] * z[q]
                    zn[i] = v
                for i in range(3):
                    z[6 + i] -= w2 * zn[3 + i]
                    z[9 + i] -= w2 * zn[i]
            else:
                if kind[j] == 3:
                    v = 0.0
                    for i in range(3):
                        v += z[6 + i] * axis[c, j, i]
                    spring[mode, ispring] = v / stiffness[j]
                    ispring += 1
                for i in range(12):
                    v = 0.0
                    for q in range(12):
                        v += T[c, j, i, q] * z[q]
                    zn[i] = v
                z[:] = zn
    disp = np.empty((m, nb, P, 3))
    rot = np.empty((m, nb, P, 3))
    mom = np.empty((m, nb, P, 3))
    frc = np.empty((m, nb, P, 3))
    slope = np.empty((m, nb, P, 2))
    curvature = np.empty((m, nb, P, 2))
    twist = np.empty((m, nb, P))
    axial = np.empty((m, nb, P))
    if not ok:
        return disp, rot, mom, frc, slope, curvature, twist, axial, body, body_local, \
            spring, False
    for mode in range(m):
        peak, best = 0.0, -1.0  # the first largest |displacement|, its sign kept
        for b in range(nb):
            for p in range(P):
                for i in range(3):
                    v = local[mode, b, p, i]
                    if abs(v) > best:
                        best, peak = abs(v), v
        if peak == 0.0:
            peak = 1.0
        scale = 1.0 / peak
        for b in range(nb):
            EIx, EIy, GJ, EA = moduli[b, 0], moduli[b, 1], moduli[b, 2], moduli[b, 3]
            for p in range(P):
                x = local[mode, b, p]
                for i in range(3):
                    disp[mode, b, p, i] = x[i] * scale
                    rot[mode, b, p, i] = x[3 + i] * scale
                    mom[mode, b, p, i] = x[6 + i] * scale
                    frc[mode, b, p, i] = x[9 + i] * scale
                slope[mode, b, p, 0] = x[4] * scale
                slope[mode, b, p, 1] = -x[3] * scale
                curvature[mode, b, p, 0] = x[7] / EIy * scale
                curvature[mode, b, p, 1] = -x[6] / EIx * scale
                twist[mode, b, p] = x[8] / GJ * scale
                axial[mode, b, p] = x[11] / EA * scale
        for i in range(n_body):
            for q in range(6):
                body[mode, i, q] *= scale
                body_local[mode, i, q] *= scale
        for i in range(n_spring):
            spring[mode, i] *= scale
    return disp, rot, mom, frc, slope, curvature, twist, axial, body, body_local, spring, True


def wrap(jit):
    """Wrap :func:`shapes` with ``jit``, its helper ``_null_vector`` first (:func:`shapes`
    calls it through this module's globals). Once per process (numba refuses to wrap a
    function twice): :func:`casflex.tmm.fast.compiled_kernel` does it under its lock.

    Parameters
    ----------
    jit : callable
        The decorator, ``numba.njit(cache=True)``.

    Returns
    -------
    numba.core.registry.CPUDispatcher
        The compiled :func:`shapes`.

    Examples
    --------
    >>> from casflex.tmm import fast
    >>> fast.compiled_kernel("shapes").py_func is shapes
    True
    """
    global _null_vector
    _null_vector = jit(_null_vector)
    return jit(shapes)
