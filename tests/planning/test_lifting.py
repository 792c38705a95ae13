"""A nominal plan lifted into the robust NLP (casflex.planning.lifting), the scenarios'
collocated guess, and the bound path of the continuation, on the one-link arm."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.moves import Move
from casflex.planning import (
    LOOSE_BOUNDS,
    PlannedMove,
    collocated_modal_guess,
    continuation_steps,
    frequency_shifted_model,
    modal_guess,
    plan_move,
    solve_by_continuation,
)
from casflex.planning.derivatives import implicit_collocation_function

MOVE = Move([0.0], [1.0], 2.0, settle=1.0)
COMMON = {"torque_limit": 0.1, "intervals": 40}
BOUND = 2e-3


@pytest.fixture(scope="module")
def nominal(onelink):
    return plan_move(onelink, MOVE, **COMMON, end=BOUND)


def _block(plan, kind, name):
    """The values (x) or multipliers (g) of one named block, as a rows x columns array."""
    values = plan.solution["x" if kind == "x" else "lam_g"]
    for block, offset, rows, cols in plan.solution["layout"][kind]:
        if block == name:
            return values[offset:offset + rows * cols].reshape((rows, cols), order="F")
    raise KeyError(name)


def test_the_layout_finds_the_blocks_of_the_plan(nominal):
    # the blocks read through the layout are the plan's own node values, torques and T
    assert _block(nominal, "x", "T")[0, 0] == pytest.approx(nominal.duration, rel=1e-14)
    np.testing.assert_allclose(_block(nominal, "x", "U").T, nominal.node_tau, rtol=0,
                               atol=1e-14)
    np.testing.assert_allclose(_block(nominal, "x", "X").T, nominal.node_x, rtol=0,
                               atol=1e-14)
    # every variable and constraint is in exactly one block
    for kind, total in (("x", nominal.solution["x"].size),
                        ("g", nominal.solution["lam_g"].size)):
        blocks = sorted(nominal.solution["layout"][kind], key=lambda b: b[1])
        ends = [offset + rows * cols for _, offset, rows, cols in blocks]
        assert [b[1] for b in blocks] == [0] + ends[:-1] and ends[-1] == total
    # the end bound is the one active inequality: its multiplier is the only nonzero
    # among the end rows
    assert _block(nominal, "g", "end 0 residual")[0, 0] != 0.0


def test_the_layout_is_saved_with_the_plan(nominal, tmp_path):
    back = PlannedMove.load(nominal.save(tmp_path / "plan.npz"))
    assert back.solution["layout"] == nominal.solution["layout"]


def test_a_loose_robust_problem_starts_and_stays_at_the_nominal_plan(onelink, nominal):
    # scenario bounds loose enough that the nominal plan meets them at +-10 %: the robust
    # optimum is the nominal one, and the lifted start is already there
    loose = plan_move(onelink, MOVE, **COMMON, end=[BOUND, 0.1, 0.1], robust=0.1,
                      guess=nominal)
    assert loose.stats["lifted_start"]
    assert loose.stats["iterations"] <= 5
    assert loose.duration == pytest.approx(nominal.duration, rel=1e-9)
    # the scenarios' multipliers start (and stay) zero; the nominal rows keep theirs
    assert _block(loose, "g", "end 1 residual")[0, 0] == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(_block(loose, "x", "X")[:4], _block(nominal, "x", "X"),
                               rtol=0, atol=1e-7)


@pytest.mark.parametrize("end", [BOUND, [BOUND, 3e-3, 1.5e-3]])
def test_the_lifted_start_ends_at_the_direct_robust_plan(onelink, nominal, end):
    direct = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1)
    lifted = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1, guess=nominal)
    assert lifted.stats["lifted_start"] and not direct.stats["lifted_start"]
    assert lifted.duration == pytest.approx(direct.duration, rel=1e-6)


def test_a_plan_without_layout_is_not_lifted(onelink, nominal):
    solution = {k: v for k, v in nominal.solution.items() if k != "layout"}
    import dataclasses

    old = dataclasses.replace(nominal, solution=solution)
    p = plan_move(onelink, MOVE, **COMMON, end=BOUND, robust=0.1, guess=old)
    assert not p.stats["lifted_start"] and not p.stats["warm_start_duals"]


def test_the_collocated_guess_solves_the_collocation_equations(onelink, nominal):
    # the scenario rows solved from G's equations under the plan's joint rows: G's own
    # defects vanish there, where the exact simulation of the shifted model misses them
    # by its collocation error; both describe the same motion to that error
    N, degree, r = 40, 3, 0.1
    h = nominal.duration / N
    G, _ = implicit_collocation_function(onelink, 1, degree)
    k = np.repeat(np.arange(N), degree)
    tc = np.asarray(ca.collocation_points(degree, "legendre")).ravel()
    x, xdot = (np.asarray(a).T for a in nominal.propagator(k, np.tile(tc, N) * h))
    times = (np.arange(N)[:, None] + tc[None, :]).ravel() * h
    simulated = modal_guess(frequency_shifted_model(onelink, r), nominal,
                            nominal.duration, 20 * N, np.arange(N + 1) * 20, times)
    [(nodes, points)] = collocated_modal_guess(G, [1.0 + r], nominal.node_x, x,
                                               xdot[:, 2:3], nominal.node_tau, h,
                                               [simulated])

    def defects(rows_nodes, rows_points):
        Xa = np.hstack([nominal.node_x, rows_nodes]).T
        Xca = np.hstack([x, rows_points]).T
        d, _, xf = G.map(N)(Xa[:, :N], Xca, xdot[:, 2:3].T, nominal.node_tau.T, h,
                            ca.DM([1.0 + r]))
        scale = np.max(np.abs(rows_nodes), axis=0)
        gaps = (np.asarray(xf)[4:] - Xa[4:, 1:]).T / scale
        return np.max(np.abs(np.asarray(d)[4:].T / scale)), np.max(np.abs(gaps))

    collocated, exact = defects(nodes, points), defects(*simulated)
    assert max(collocated) < 1e-10
    assert max(exact) > 1e-6  # the simulation is not on the collocation grid
    amplitude = np.max(np.abs(simulated[0]), axis=0)
    np.testing.assert_array_less(np.max(np.abs(nodes - simulated[0]), axis=0),
                                 0.05 * amplitude)


def test_the_bound_path_ends_at_the_direct_robust_plan(onelink, nominal):
    end = [BOUND, 2.5e-3, 1.5e-3]
    direct = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1)
    lines = []
    path = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1, robust_path="bounds",
                     robust_steps=2, log=lines.append)
    assert path.duration == pytest.approx(direct.duration, rel=1e-6)
    steps = path.stats["continuation"]
    # the nominal problem, then the loose one and two tightening steps at the full error
    assert [s["robust"] for s in steps] == [0.0, 0.1, 0.1, 0.1]
    expected = [BOUND] + [[BOUND, *(b * LOOSE_BOUNDS ** (1 - f) for b in end[1:])]
                          for f in (0.0, 0.5, 1.0)]
    for got, want in zip([s["end_bounds"] for s in steps], expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12)
    assert lines[0].startswith("continuation, the nominal problem: robust 0,")


def test_the_bound_path_from_a_nominal_plan_lifts_it(onelink, nominal):
    end = [BOUND, 2.5e-3, 1.5e-3]
    seen = []

    def solve(**kw):
        plan = plan_move(**kw)
        seen.append(plan.stats["lifted_start"])
        return plan

    p = solve_by_continuation(solve, {"model": onelink, "start": MOVE, **COMMON, "end": end,
                                      "robust": 0.1, "guess": nominal}, 2, "bounds")
    assert seen == [True, False, False]  # the first robust problem from the nominal plan
    assert [s["robust"] for s in p.stats["continuation"]] == [0.1, 0.1, 0.1]


def test_the_bound_path_resumes_after_its_plan(onelink, nominal):
    end = [BOUND, 2.5e-3, 1.5e-3]
    half = plan_move(onelink, MOVE, **COMMON, robust=0.1, guess=nominal,
                     end=continuation_steps(0.1, end, 2, "bounds")[1][1])
    p = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1, robust_path="bounds",
                  robust_steps=4, guess=half)
    # half-way through the bounds (0.5 of the path): the steps at 0.75 and 1 remain
    assert [s["robust"] for s in p.stats["continuation"]] == [0.1, 0.1]
    np.testing.assert_allclose(p.stats["continuation"][-1]["end_bounds"], end, rtol=1e-12)


@pytest.mark.parametrize("kw, field", [
    ({"robust_path": "both"}, "robust_path"),
    ({"robust_path": "bounds", "end": "rest"}, "end"),
])
def test_bad_paths_are_refused(onelink, kw, field):
    with pytest.raises(ModelError, match=field):
        plan_move(onelink, MOVE, **{**COMMON, "robust": 0.1, "end": BOUND, **kw})


def _violations(onelink, **kw):
    seen = []
    plan = plan_move(onelink, MOVE, **COMMON, robust=0.1,
                     progress=lambda k, f, v: seen.append(v), **kw)
    return plan, seen


def test_elastic_bounds_start_feasible_and_end_at_the_plan_within_the_bounds(onelink,
                                                                             nominal):
    # from a plan for loose bounds, the tight bounds exceeded at the start: the elastic
    # excesses start at the start's (plus the allowance, 1e-3 of the bound) and count as
    # the violation the iterates report, relative to the bound, beyond the allowance;
    # the elastic plan is the one within the bounds (no excess left)
    tight = [BOUND, 2.5e-3, 1.5e-3]
    loose = plan_move(onelink, MOVE, **COMMON, end=[BOUND, 0.1, 0.1], robust=0.1,
                      guess=nominal, elastic=50.0)
    direct = plan_move(onelink, MOVE, **COMMON, end=tight, robust=0.1)
    hard, hard_seen = _violations(onelink, end=tight, guess=plan_move(
        onelink, MOVE, **COMMON, end=[BOUND, 0.1, 0.1], robust=0.1, guess=nominal))
    soft, soft_seen = _violations(onelink, end=tight, guess=loose, elastic=50.0)
    start = max((r - b) / b for r, b in zip(loose.stats["residual_bound"][1:], tight[1:],
                                            strict=True))
    # (the residual's smoothing is 1e-3 of the bound per mode, so the loose plan's
    # recorded residual is the tight problem's within ~1 %: 1.1801 against 1.1646)
    assert start > 0.1 and soft_seen[0] == pytest.approx(start, rel=0.02)
    assert hard_seen[0] > 1e-4 and soft_seen[-1] < 1e-6
    assert soft.duration == pytest.approx(direct.duration, rel=1e-6)
    assert hard.duration == pytest.approx(direct.duration, rel=1e-6)
    assert max(soft.stats["end_excess"]) < 1e-3 * min(tight[1:])
    for got, bound in zip(soft.stats["residual_bound"], tight, strict=True):
        assert got <= bound + 1e-7  # Ipopt's constraint tolerance, in m


def test_an_elastic_price_below_the_bounds_multipliers_is_no_plan(onelink, nominal):
    # a price of 1e-3 s/m makes the excess cheaper than the time it saves
    from casflex.errors import SolverError

    loose = plan_move(onelink, MOVE, **COMMON, end=[BOUND, 0.1, 0.1], robust=0.1,
                      guess=nominal, elastic=1e-3)
    with pytest.raises(SolverError, match="no plan within the end bounds: scenario 1"):
        plan_move(onelink, MOVE, **COMMON, end=[BOUND, 1e-4, 1e-4], robust=0.1,
                  guess=loose, elastic=1e-3)
