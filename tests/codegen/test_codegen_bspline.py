"""CasADi's B-spline nodes in generated C through casflex's routine
(:func:`casflex.codegen.templates.fused_bspline_source`): the same values as CasADi's own
evaluation bit for bit, for every degree and dimension the rewrite touches, at interior
points, on the knots, at the ends and outside the knots."""

import re

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import BSpline

from casflex import codegen
from casflex.codegen.templates import fused_bspline_source

#: the EKF benchmark's build (no FMA contraction: the operations as written)
FLAGS = ("-O3", "-march=native", "-ffp-contract=off")


def _knots(degree, n_basis, rng):
    """Clamped knots over [-1, 2] with uneven inner spacing (``n_basis`` basis functions)."""
    inner = np.sort(rng.uniform(-1.0, 2.0, n_basis - degree - 1))
    return np.r_[[-1.0] * (degree + 1), inner, [2.0] * (degree + 1)]


def _cases():
    """``(name, knots per axis, degrees, coefficients, m)`` of the nodes tested."""
    rng = np.random.default_rng(7)
    cases = []
    for degree in (1, 2, 3):
        for m in (1, 7, 280):
            t = _knots(degree, 12, rng)
            cases.append((f"d{degree}_m{m}", [t], [degree], rng.standard_normal(12 * m), m))
    # two axes (the first axis's rows fused for degree 2 or 3), three (CasADi's sum)
    for degrees, m in (((3, 3), 5), ((2, 3), 18), ((3, 1), 4), ((1, 3), 6), ((3, 3, 2), 4)):
        knots = [_knots(d, 7, rng) for d in degrees]
        cases.append(("d" + "x".join(map(str, degrees)), knots, list(degrees),
                      rng.standard_normal(7 ** len(degrees) * m), m))
    return cases


CASES = _cases()


def _node(x, knots, degrees, coef, m):
    return ca.bspline(x, ca.DM(coef), [list(t) for t in knots], degrees, m,
                      {"lookup_mode": ["binary"] * len(knots)})


def _function(name, knots, degrees, coef, m):
    x = ca.MX.sym("x", len(knots))
    return ca.Function(name, [x], [_node(x, knots, degrees, coef, m)], ["x"], ["y"])


def _points(knots, rng):
    """Interior points, every knot, the ends and points beyond them (the spline is 0 there)."""
    pts = [rng.uniform(-1.0, 2.0, 40), np.unique(knots), [-1.0, 2.0, -1.5, 2.5, -1e-300]]
    return np.concatenate(pts)


def _reused(name, knots, degrees, coef, m):
    """The node's value as an output and, after it, in another output: its work vector is
    read after the copy to the output, so the routine must keep writing it."""
    x = ca.MX.sym("x", len(knots))
    y = _node(x, knots, degrees, coef, m)
    return ca.Function(name + "_reused", [x], [y, 2.0 * y + x[0]], ["x"], ["y", "z"])


@pytest.mark.needs_cc
def test_rewritten_nodes_equal_casadi_bit_for_bit(tmp_path):
    functions = [_function(*case) for case in CASES]
    reused = [_reused(*case) for case in CASES if case[-1] > 1]
    bundle = codegen.generate(functions + reused, tmp_path, name="boor")
    source = bundle.source.read_text()
    # every vector node goes through the routine, into the output itself unless its value
    # is read again; a scalar one (CasADi sets it to 0 instead of clearing it) is left to
    # CasADi's routine
    scalar = sum(m == 1 for *_, m in CASES)
    direct = len(re.findall(r"casflex_boor_eval\(res\[0\] \? res\[0\] : w", source))
    kept = len(re.findall(r"casflex_boor_eval\(w", source))
    assert (direct, kept) == (len(CASES) - scalar, len(reused))
    assert len(re.findall(r"CASADI_PREFIX\(nd_boor_eval\)\(", source)) == scalar
    lib = codegen.build(bundle, flags=FLAGS)
    rng = np.random.default_rng(8)
    cases = CASES + [case for case in CASES if case[-1] > 1]
    for f, (_, knots, *_) in zip(functions + reused, cases, strict=True):
        g = codegen.load(lib, f.name())
        axes = [_points(t, rng) for t in knots]
        n = max(a.size for a in axes)
        grid = np.stack([np.resize(a, n) for a in axes])
        for x in grid.T:
            for a, b in zip(g(x) if f.n_out() > 1 else [g(x)],
                            f(x) if f.n_out() > 1 else [f(x)], strict=True):
                assert np.array_equal(np.asarray(a), np.asarray(b)), (f.name(), x)


def test_casadi_nodes_are_the_splines():
    """The reference of the bit-for-bit test is the spline: CasADi's node against scipy's
    ``BSpline`` (an independent evaluation), 1-D, inside the knots."""
    rng = np.random.default_rng(9)
    for name, knots, degrees, coef, m in CASES:
        if len(knots) != 1:
            continue
        f = _function(name, knots, degrees, coef, m)
        ref = BSpline(knots[0], coef.reshape(-1, m), degrees[0])
        x = rng.uniform(-1.0, 2.0, 10)
        got = np.hstack([np.asarray(f(v)) for v in x]).T
        assert np.allclose(got, ref(x), rtol=1e-12, atol=1e-12 * np.abs(coef).max())


def test_source_without_cleared_call_unchanged():
    x = ca.SX.sym("x")
    cg = ca.CodeGenerator("plain.c")
    cg.add(ca.Function("plain", [x], [ca.sin(x)]))
    text = cg.dump()
    assert fused_bspline_source(text) == text
    # a call without CasADi's clearing of the output just before it is left alone
    odd = "casadi_clear(w1, 3);\n  casadi_nd_boor_eval(w1,1,a,b,c,d,e,4,x,l, iw, w);"
    assert fused_bspline_source(odd) == odd


@pytest.mark.needs_cc
def test_compile_cached_goes_through_the_routine_bit_for_bit(tmp_path, monkeypatch):
    """The just-in-time libraries (:func:`casflex.codegen.jit.compile_cached`, the
    simulators' and the planner's compiled functions) get the same rewrite as the bundles:
    the same values as CasADi's bit for bit, and the routine's digest is in the cache key
    (a changed rewrite builds anew instead of loading the old library)."""
    from casflex.codegen import jit, templates

    functions = [_function(*case) for case in CASES if case[-1] > 1][:4]
    assert "casflex_boor_eval(" in jit.write_source(functions, "boor_src",
                                                     tmp_path).read_text()
    loaded, info = jit.compile_cached(functions, "boor_jit", cache_dir=tmp_path)
    assert info["built"]
    rng = np.random.default_rng(9)
    for f, case in zip(functions, [c for c in CASES if c[-1] > 1][:4], strict=True):
        axes = [_points(t, rng) for t in case[1]]
        n = max(a.size for a in axes)
        for x in np.stack([np.resize(a, n) for a in axes]).T:
            assert np.array_equal(np.asarray(loaded[f.name()](x)), np.asarray(f(x)))
    assert not jit.compile_cached(functions, "boor_jit", cache_dir=tmp_path)[1]["built"]
    monkeypatch.setattr(jit, "BOOR_ROUTINE_DIGEST", templates.BOOR_ROUTINE_DIGEST + "x")
    assert jit.compile_cached(functions, "boor_jit", cache_dir=tmp_path)[1]["built"]
