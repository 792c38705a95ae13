"""The NLP's derivatives assembled from per-interval blocks (casflex.planning.assembly)
against CasADi's own derivatives of the whole problem, and plans made with them against
plans made with CasADi's."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.planning import block_derivatives, plan_move
from casflex.robot import load


def _toy_problem(fixed_duration=False):
    """An Opti problem of the planner's shape: a nonlinear interval function mapped over
    5 intervals, its inputs node columns, interval columns and T / N, its rows scaled,
    the variables linearly scaled (with an offset), other nonlinear constraints and
    objective terms beside it."""
    x, xc, u, h = ca.SX.sym("x", 2), ca.SX.sym("xc", 2, 2), ca.SX.sym("u"), ca.SX.sym("h")
    G = ca.Function("G", [x, xc, u, h],
                    [h * ca.sin(xc[0, :]) * x[1] - xc[1, :] ** 2 + u * x[0],
                     ca.vertcat(h ** 2 * u * xc[0, 0], ca.exp(0.1 * xc[1, 1]) * x[0]),
                     x + h])  # the last output is not a constraint row
    N = 5
    opti = ca.Opti()
    X, Xc, U = opti.variable(2, N + 1), opti.variable(2, 2 * N), opti.variable(1, N)
    T = 2.0 if fixed_duration else opti.variable()
    opti.set_linear_scale(X, 3.0, 0.5)
    opti.set_linear_scale(Xc, np.linspace(0.5, 2.0, 4 * N).reshape(2, 2 * N))
    if not fixed_duration:
        opti.set_linear_scale(T, 2.0)
        opti.subject_to(opti.bounded(0.1, T, 10.0))
    args = [X[:, :N], Xc, U, T / N]
    a, b, c = G.map(N)(*args)
    opti.subject_to(X[:, 0] == 0)
    sa, sb = np.linspace(1.0, 2.0, 2 * N).reshape(1, 2 * N), np.full((2, N), 0.25)
    rows = [opti.ng]
    opti.subject_to(ca.vec(a / sa) == 0)
    opti.subject_to(X[0, 1:] ** 2 + X[1, 1:] * X[0, 1:] - c[0, :] <= 1)  # uses output 2
    rows.append(opti.ng)
    opti.subject_to(ca.vec(b / sb) == 0)
    opti.minimize((T if not fixed_duration else 0) + ca.sumsqr(U) * T + ca.sumsqr(Xc) ** 2)
    return opti, G, args, [a, b], rows, [sa, sb], N


@pytest.mark.parametrize("fixed_duration", [False, True])
def test_block_derivatives_equal_casadi_s_own(fixed_duration):
    # the reference: CasADi's Jacobian and Hessian of the whole NLP in Opti's scaled
    # variables (x = s x~ + o), at a random point with random multipliers
    opti, G, args, mapped, rows, scales, N = _toy_problem(fixed_duration)
    d = block_derivatives(opti, G, args, mapped, [0, 1], rows, scales, N)
    assert sorted(block_derivatives(opti, G, args, mapped, [0, 1], rows, scales, N,
                                    hessian=False)) == ["jac_g"]
    # the same sums of the same products in another order: round-off of the entries
    _assert_equal_to_casadi_s(opti, d, 1e-12)


def _assert_equal_to_casadi_s(opti, d, tol, scale=1.0, seed=15):
    """``d``'s constraint values, Jacobian and Hessian equal CasADi's of the whole NLP in
    Opti's scaled variables (x = s x~ + o) to ``tol`` (relative, and of the largest entry)
    at random points (``scale`` times normal) with random multipliers."""
    adv = opti.advanced
    s = np.asarray(adv.x_linear_scale).ravel()
    o = np.asarray(adv.x_linear_scale_offset).ravel()
    xt = ca.MX.sym("xt", opti.nx)
    nlp = ca.Function("nlp", [opti.x], [opti.f, opti.g])
    f, g = nlp(s * xt + o)
    lam_f, lam_g = ca.MX.sym("lf"), ca.MX.sym("lg", opti.ng)
    ref_jac = ca.Function("rj", [xt], [g, ca.jacobian(g, xt)])
    ref_hess = ca.Function("rh", [xt, lam_f, lam_g],
                           [ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), xt)[0])])
    rng = np.random.default_rng(seed)
    for _ in range(3):
        xv, lf, lg = scale * rng.normal(size=opti.nx), rng.normal(), rng.normal(size=opti.ng)
        g_b, J_b = d["jac_g"](xv, [])
        g_r, J_r = ref_jac(xv)
        H_b = d["hess_lag"](xv, [], lf, lg)
        H_r = ref_hess(xv, lf, lg)
        for new, ref in ((g_b, g_r), (J_b, J_r), (H_b, H_r)):
            ref = ref.full()
            np.testing.assert_allclose(new.full(), ref, rtol=tol,
                                       atol=tol * max(np.max(np.abs(ref)), 1.0))
        assert np.all(np.triu(H_b.full()) == H_b.full())  # Ipopt's upper triangle


def test_point_split_derivatives_equal_casadi_s_own(onelink):
    # the planner's NLP shape with its interval function built from the point function
    # of the implicit dynamics (the nominal one-link model and two frequency-shifted
    # scenarios), every variable scaled with an offset, the rows scaled: the derivatives
    # from the point blocks (casflex.planning.derivatives) against CasADi's of the whole
    # scaled NLP
    from casflex.planning.derivatives import implicit_collocation_function

    G, split = implicit_collocation_function(onelink, 2, 3)
    nxa, n, K, N = G.size1_in(0), onelink.n, 3, 4
    rng = np.random.default_rng(3)
    opti = ca.Opti()
    X, Xc = opti.variable(nxa, N + 1), opti.variable(nxa, K * N)
    Ac, U, T = opti.variable(n, K * N), opti.variable(n, N), opti.variable()
    for v in (X, Xc, Ac, U):
        opti.set_linear_scale(v, rng.uniform(0.1, 2.0, v.shape), rng.normal(size=v.shape))
    opti.set_linear_scale(T, 1.7, 0.3)
    args = [X[:, :N], Xc, Ac, U, T / N, ca.DM([0.9, 1.1])]
    defects, torque, xf = G.map(N)(*args)
    sd, st = rng.uniform(0.5, 3.0, defects.shape), rng.uniform(0.5, 3.0, torque.shape)
    rows = [opti.ng]
    opti.subject_to(ca.vec(defects / sd) == 0)
    rows.append(opti.ng)
    opti.subject_to(ca.vec(torque / st) == 0)
    opti.subject_to(X[:, 1:] - xf == 0)
    opti.subject_to(X[:, 0] == 0)
    opti.subject_to(ca.sumsqr(X[:, N]) <= 1.0)
    opti.minimize(T + ca.sumsqr(U) * T)
    d = block_derivatives(opti, G, args, [defects, torque], [0, 1], rows, [sd, st], N,
                          point=split)
    _assert_equal_to_casadi_s(opti, d, 1e-10, scale=0.3)
    with pytest.raises(ValueError, match="other outputs"):
        block_derivatives(opti, G, args, [defects], [0], rows[:1], [sd], N, point=split)


@pytest.mark.parametrize("kw", [
    {"end": 2e-3},
    {"end": "rest", "robust": 0.1},
    {"objective": "energy", "duration": 2.5, "end": "rest"},
])
def test_plans_with_block_derivatives_equal_casadi_s(onelink, kw):
    # the derivatives are the same to round-off (above), so both solves reach the same
    # optimum to Ipopt's tolerance (1e-8). The iterations may differ: with the end at rest
    # in three scenarios the KKT systems are degenerate, and another sparsity pattern
    # (another pivot order in MUMPS) takes another path (robust case: 17 and 24
    # iterations, durations equal to 1e-12 relative)
    move = Move([0.0], [1.0], 2.0, settle=1.0)
    common = {"torque_limit": 0.05, "velocity_limit": 1.0, "intervals": 24, **kw}
    a = plan_move(onelink, move, derivatives="casadi", **common)
    for derivatives in ("blocks", "blocks-jacobian", "points"):
        b = plan_move(onelink, move, derivatives=derivatives, **common)
        assert b.stats["derivatives"] == derivatives
        assert a.stats["status"] == b.stats["status"] == "Solve_Succeeded"
        assert b.duration == pytest.approx(a.duration, rel=1e-9)
        # torques: measured up to 3.5e-7 of the limit apart (the ≤ 2 mm robust case)
        np.testing.assert_allclose(b.node_tau, a.node_tau, atol=1e-5 * 0.05)


def _recording_compiler(cache_dir, built):
    """A compile_function building at -O0 in ``cache_dir`` that records the names of the
    functions of every library it builds in ``built``."""
    from casflex.codegen import compile_cached

    def compile_points(functions):
        lib, _ = compile_cached(functions, "plan_points", cache_dir=cache_dir,
                                flags=("-O0",))
        built.append(sorted(lib))
        return [lib[f.name()] for f in functions]
    return compile_points


def test_compiled_point_derivatives_give_casadi_s_plan(onelink, tmp_path):
    # the point function's Jacobian and Hessian compiled to C (as casflex plan
    # --derivatives points and benchmarks/bench_planning.py --compile do)
    built = []
    compile_points = _recording_compiler(tmp_path, built)
    move = Move([0.0], [1.0], 2.0, settle=1.0)
    common = {"torque_limit": 0.05, "velocity_limit": 1.0, "intervals": 24, "end": 2e-3}
    a = plan_move(onelink, move, **common)
    b = plan_move(onelink, move, derivatives="points", compile_function=compile_points,
                  **common)
    # the point function itself (the constraint values, casflex.planning.assembly.
    # point_values), then its derivatives
    assert built == [["implicit_point"], ["implicit_point_hess", "implicit_point_jac"]]
    assert a.stats["status"] == b.stats["status"] == "Solve_Succeeded"
    assert b.duration == pytest.approx(a.duration, rel=1e-9)
    np.testing.assert_allclose(b.node_tau, a.node_tau, atol=1e-5 * 0.05)


def test_a_limited_memory_hessian_compiles_no_hessian_and_finds_the_same_plan(onelink,
                                                                              tmp_path):
    # Ipopt's quasi-Newton Hessian (casflex plan --hessian limited-memory): only the
    # point function and its Jacobian are compiled, and the plan is the exact-Hessian
    # one (measured 5e-11 apart in T: 28 iterations against 16)
    built = []
    compile_points = _recording_compiler(tmp_path, built)
    move = Move([0.0], [1.0], 2.0, settle=1.0)
    common = {"torque_limit": 0.05, "velocity_limit": 1.0, "intervals": 24, "end": 2e-3,
              "derivatives": "points"}
    exact = plan_move(onelink, move, **common)
    quasi = plan_move(onelink, move, compile_function=compile_points,
                      ipopt_options={"hessian_approximation": "limited-memory"}, **common)
    assert built == [["implicit_point"], ["implicit_point_jac"]]
    assert not quasi.stats["timings"].get("n_call_nlp_hess_l")
    assert quasi.stats["status"] == exact.stats["status"] == "Solve_Succeeded"
    assert quasi.duration == pytest.approx(exact.duration, rel=1e-8)


def test_point_compiler_quick_now_optimised_in_the_background(onelink, tmp_path):
    # casflex plan's and the design job's compile_function: the quick build at once, the
    # optimised one from a detached process, used by the next NLP that compiles; the
    # plans equal CasADi's to Ipopt's tolerance whichever build runs
    import time

    from casflex.planning import OPTIMISED_FLAGS, QUICK_FLAGS, point_compiler

    move = Move([0.0], [1.0], 2.0, settle=1.0)
    common = {"torque_limit": 0.05, "velocity_limit": 1.0, "intervals": 24, "end": 2e-3,
              "derivatives": "points"}
    reference = plan_move(onelink, move, **{**common, "derivatives": "casadi"})
    lines = []
    compile_points = point_compiler("points", tmp_path, lines.append, background=True)
    first = plan_move(onelink, move, compile_function=compile_points, **common)
    # values and derivatives each: the quick build, the optimised one started
    assert compile_points.builds == [QUICK_FLAGS, QUICK_FLAGS]
    assert sum("in the background" in line for line in lines) == 2
    jit = tmp_path / "jit"
    end = time.monotonic() + 120.0
    while list(jit.glob(".gen-*")) and time.monotonic() < end:
        time.sleep(0.1)
    assert not list(jit.glob(".gen-*")), "the background builds did not finish in 2 min"
    second = plan_move(onelink, move, compile_function=compile_points, **common)
    assert compile_points.builds[2:] == [OPTIMISED_FLAGS, OPTIMISED_FLAGS]
    for plan in (first, second):
        assert plan.stats["status"] == "Solve_Succeeded"
        assert plan.duration == pytest.approx(reference.duration, rel=1e-9)
    # without the background build: the quick one only, and nothing started
    lines.clear()
    other = tmp_path / "other"
    quick_only = point_compiler("points", other, lines.append, background=False)
    plan_move(onelink, move, compile_function=quick_only, **common)
    assert quick_only.builds == [QUICK_FLAGS, QUICK_FLAGS] and not lines
    assert not list((other / "jit").glob(".gen-*"))
    assert len(list((other / "jit").glob("plan_points-*"))) == 2


def test_point_values_equal_the_mapped_interval_function(onelink):
    # the constraint values from the point split (compiled or not) against the interval
    # function's own, at random arguments
    from casflex.planning.assembly import point_values
    from casflex.planning.derivatives import implicit_collocation_function

    G, split = implicit_collocation_function(onelink, 2, 3)
    N = 4
    rng = np.random.default_rng(1)
    args = [ca.DM(rng.normal(size=(G.size1_in(i), G.size2_in(i) * (N if i < 4 else 1))))
            for i in range(6)]
    ref = G.map(N)(*args)
    got = point_values(G, split, [ca.MX(a) for a in args], N)
    for j, out in zip(split.outputs, got, strict=True):
        assert out.shape == ref[j].shape
        np.testing.assert_allclose(np.asarray(ca.evalf(out)), np.asarray(ref[j]),
                                   rtol=1e-12, atol=1e-12)


def test_block_derivatives_need_implicit_collocation(onelink):
    with pytest.raises(ModelError, match="derivatives"):
        plan_move(onelink, [0.0], [1.0], torque_limit=0.05, transcription="shooting",
                  derivatives="blocks")
    with pytest.raises(ModelError, match="derivatives"):
        plan_move(onelink, [0.0], [1.0], torque_limit=0.05, derivatives="exact")


def test_point_function_scenarios_are_the_frequency_shifted_models():
    # the point function's scenario rows (the nominal modal rows with s² K and s D, the
    # factors an input) against the models of casflex.planning.frequency_shifted_model
    # (their frequencies scaled in the provider): the two-link arm with gravity, two modes
    from casflex.planning import frequency_shifted_model
    from casflex.planning.derivatives import implicit_point_function

    robot = load("problems/arm2link.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.3, -0.4, 0.2], count=2))
    n, m = model.n, model.m
    errors = [-0.1, 0.07]
    phi = implicit_point_function(model, len(errors))
    rows = [frequency_shifted_model(model, r).functions()["dddelta"] for r in errors]
    rng = np.random.default_rng(7)
    nx = 2 * (n + m)
    for _ in range(5):
        xa = rng.normal(size=nx + 2 * m * len(errors)) * 0.3
        a, h = rng.normal(size=n), 0.013
        y = phi(np.r_[xa, a, h, [1.0 + r for r in errors]]).full().ravel()
        q, dq = xa[:n], xa[n + m:2 * n + m]
        for k, row in enumerate(rows):
            z = xa[nx + 2 * m * k:nx + 2 * m * (k + 1)]
            got = y[nx + 2 * m * k + m:nx + 2 * m * (k + 1)] / h
            ref = row(q, dq, a, z[:m], z[m:]).full().ravel()
            np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
            np.testing.assert_array_equal(y[nx + 2 * m * k:nx + 2 * m * k + m], h * z[m:])
    # a factor of 1 is the nominal model's rows
    xa = rng.normal(size=nx + 2 * m) * 0.3
    one = implicit_point_function(model, 1)
    y = one(np.r_[xa, a, h, 1.0]).full().ravel()
    nominal = model.functions()["dddelta"](xa[:n], xa[n + m:2 * n + m], a, xa[nx:nx + m],
                                           xa[nx + m:]).full().ravel()
    np.testing.assert_allclose(y[nx + m:nx + 2 * m] / h, nominal, rtol=1e-13, atol=1e-15)
