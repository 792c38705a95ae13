"""Robust plans by continuation (casflex.planning.restarts.solve_by_continuation) on the
one-link arm: the path's last plan is the robust plan solved directly."""

from __future__ import annotations

import pytest

from casflex.errors import ModelError, SolverError
from casflex.moves import Move
from casflex.planning import (
    CEILING_STATUS,
    CONTINUATION_HALVINGS,
    PATH_RISE,
    PATH_STATUSES,
    PROGRESS_STATUS,
    PlannedMove,
    continuation_steps,
    plan_move,
    plan_robustness,
    solve_by_continuation,
    verify_plan,
)

MOVE = Move([0.0], [1.0], 2.0, settle=1.0)
COMMON = {"torque_limit": 0.1, "intervals": 40}


@pytest.mark.parametrize("end", [2e-3, [2e-3, 3e-3, 1.5e-3]])
def test_the_path_ends_at_the_direct_robust_plan(onelink, end):
    direct = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1)
    path = plan_move(onelink, MOVE, **COMMON, end=end, robust=0.1, robust_steps=3)
    assert direct.stats["success"] and path.stats["success"]
    # two routes to one optimum: the same duration to the solver's tolerance
    assert path.duration == pytest.approx(direct.duration, rel=1e-7)
    steps = path.stats["continuation"]
    # the nominal problem first (no plan given), then three robust problems
    assert [s["robust"] for s in steps] == pytest.approx([0.0, 0.1 / 3, 0.2 / 3, 0.1])
    # the nominal problem's bound at every step (scalar end), or each scenario's moved
    # from the nominal 2 mm a third of the way per step
    expected = [[2e-3]] + ([[2e-3] * 3] * 3 if isinstance(end, float) else
                           [[2e-3, 2e-3 + k * 1e-3 / 3, 2e-3 - k * 0.5e-3 / 3] for k in (1, 2, 3)])
    for s, bounds in zip(steps, expected, strict=True):
        assert s["end_bounds"] == pytest.approx(bounds, rel=1e-12)
    # every step solved: by Ipopt's tests, or (a step warm from a converged plan) by the
    # progress rule of ProgressStop.near_solution, the duration equal either way (above)
    assert all(s["status"] in ("Solve_Succeeded", PROGRESS_STATUS) for s in steps)
    assert steps[0]["status"] == "Solve_Succeeded"
    assert path.stats["continuation_iterations"] == sum(s["iterations"] for s in steps)
    # and the plan meets its bounds when simulated at the frequency errors
    v = verify_plan(onelink, path, dt=1e-4, errors=[-0.1, 0.1], torque=False)
    bounds = [end] * 3 if isinstance(end, float) else end
    residuals = [v["prescribed"], v["errors"][0]["prescribed"], v["errors"][1]["prescribed"]]
    assert all(r <= 1.05 * b for r, b in zip(residuals, bounds, strict=True))


def test_from_a_plan_the_path_starts_there(onelink):
    nominal = plan_move(onelink, MOVE, **COMMON, end=2e-3)
    path = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1, robust_steps=2,
                     guess=nominal)
    assert [s["robust"] for s in path.stats["continuation"]] == [0.05, 0.1]
    direct = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1)
    assert path.duration == pytest.approx(direct.duration, rel=1e-7)


def test_restarts_on_the_nominal_and_the_last_problem(onelink):
    lines = []
    p = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1, robust_steps=2,
                  restarts=1, restart_rtol=0.0, log=lines.append)
    # one line per problem and its result, one per pass of the restarted ones
    assert [line.split(":")[0] for line in lines if line.startswith("continuation")] == [
        "continuation, the nominal problem"] + [
        f"continuation, problem at {f} of the path" for f in ("0.5", "1")]
    assert sum(line.startswith("  restart 1") for line in lines) == 2
    assert lines[-4] == ("continuation, problem at 1 of the path: robust 0.1, end "
                         "[2.0, 2.0, 2.0] mm")
    steps = p.stats["continuation"]
    assert [s["robust"] for s in steps] == [0.0, 0.05, 0.1]
    assert "passes" in p.stats and len(p.stats["passes"]) == 2  # the last problem's


def test_one_step_is_the_robust_problem_alone(onelink):
    a = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1)
    b = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1, robust_steps=1)
    assert "continuation" not in b.stats and b.duration == a.duration


def test_no_robust_error_no_path(onelink):
    p = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust_steps=4)
    assert "continuation" not in p.stats


def test_a_step_without_plan_names_the_step(onelink):
    # 0.1 N m cannot move the arm 1 rad in 1 s (the rigid minimum is 1.29 s)
    with pytest.raises(SolverError, match=r"continuation found no plan at the nominal "
                                          r"problem \(robust = 0,"):
        plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1, robust_steps=2,
                  objective="energy", duration=1.0, max_iter=100)


def test_a_failed_path_keeps_what_it_reached(onelink):
    # from the nominal plan at 0.1 N m, a robust plan whose -r scenario must stop dead
    # (bound 1e-9 m) at the same 0.1 N m within max_iter = 3: step 1 fails
    nominal = plan_move(onelink, MOVE, **COMMON, end=2e-3)
    with pytest.raises(SolverError) as err:
        plan_move(onelink, MOVE, **COMMON, end=[2e-3, 1e-9, 2e-3], robust=0.1,
                  robust_steps=2, guess=nominal, max_iter=3)
    # the first problem (0.5 of the path), then halvings towards the nominal plan: 0.25,
    # 0.125...; two attempts each (the nominal plan's iterate and multipliers lifted into
    # the robust NLP, then its iterate alone), until one finds a plan or all
    # CONTINUATION_HALVINGS are spent
    assert CONTINUATION_HALVINGS == 5
    assert f"after {CONTINUATION_HALVINGS} halving(s)" in str(err.value)
    records = err.value.continuation
    assert [c["robust"] for c in records[:4]] == [0.05, 0.05, 0.025, 0.025]
    reached = [c for c in records if c["duration"] is not None]
    assert all(c["robust"] < 0.1 for c in reached)
    # the error keeps the last plan the path reached (the nominal one if none)
    last = err.value.plan
    assert last is nominal if not reached else \
        plan_robustness(last) == pytest.approx(reached[-1]["robust"], rel=1e-12)


def test_a_failure_is_tried_again_from_the_iterate_alone_only_if_the_multipliers_were_used(
        onelink):
    from casflex.planning import solve_from_plan

    nominal = plan_move(onelink, MOVE, **COMMON, end=2e-3)
    robust = plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.05, guess=nominal)
    hopeless = {"model": onelink, "start": MOVE, **COMMON, "end": [2e-3, 1e-9, 2e-3],
                "robust": 0.05, "max_iter": 3}
    starts = []

    def solve(**kw):
        starts.append(kw["guess"].solution is not None)
        return plan_move(**kw)

    # from the robust plan (the same variables and constraints): with its multipliers,
    # then from its iterate alone
    plan, failures = solve_from_plan(solve, hopeless, robust)
    assert plan is None and starts == [True, False]
    assert failures[0].solve["used_guess_solution"]
    assert not failures[1].solve["used_guess_solution"]
    # from the nominal plan: lifted into the robust NLP with its multipliers, then from
    # its iterate alone
    starts.clear()
    plan, failures = solve_from_plan(solve, hopeless, nominal)
    assert plan is None and starts == [True, False]
    assert failures[0].solve["used_guess_solution"]
    # from a plan whose multipliers fit neither way (another number of intervals): one
    starts.clear()
    other = plan_move(onelink, MOVE, **{**COMMON, "intervals": COMMON["intervals"] + 2},
                      end=2e-3)
    plan, failures = solve_from_plan(solve, hopeless, other)
    assert plan is None and starts == [True] and len(failures) == 1
    assert not failures[0].solve["used_guess_solution"]


@pytest.mark.parametrize("kw, field", [
    ({"robust_steps": 0}, "robust_steps"), ({"robust_steps": 1.5}, "robust_steps"),
    ({"robust_steps": "2"}, "robust_steps"),
])
def test_bad_steps_are_refused(onelink, kw, field):
    with pytest.raises(ModelError, match=field):
        plan_move(onelink, MOVE, **COMMON, end=2e-3, robust=0.1, **kw)


def test_steps_of_rest_and_of_bad_input():
    assert continuation_steps(0.2, "rest", 4)[-1] == (0.2, "rest")
    with pytest.raises(ModelError, match="robust"):
        continuation_steps(0.0, 2e-3, 2)
    with pytest.raises(ModelError, match="end"):
        continuation_steps(0.1, [2e-3, 1e-3], 2)


def _plan(robust, duration):
    """A stand-in plan that knows the error it was solved at."""
    import numpy as np

    from casflex.planning import PlannedMove

    t = np.array([0.0, duration])
    return PlannedMove(t=t, q=np.zeros((2, 1)), dq=np.zeros((2, 1)), ddq=np.zeros((2, 1)),
                       tau=np.zeros((2, 1)), delta=np.zeros((2, 0)),
                       ddelta=np.zeros((2, 0)), node_t=t, node_x=np.zeros((2, 2)),
                       node_tau=np.zeros((1, 1)), hold_torque=np.zeros(1),
                       stats={"status": "Solve_Succeeded", "iterations": 1,
                              "objective_value": duration, "solve_s": 0.0,
                              "solve_cpu_s": 0.0, "robust": robust})


def test_a_step_too_long_is_halved():
    # a solver that reaches a problem only from a plan within 0.03 of its error: the
    # path 0 -> 0.05 -> 0.1 needs both steps halved (0.025, then 0.075)
    def solve(robust, guess, **kw):
        if abs(robust - guess.stats["robust"]) > 0.03 + 1e-12:
            raise SolverError(f"too far: {guess.stats['robust']} -> {robust}")
        return _plan(robust, 1.0 + robust)

    from casflex.planning import solve_by_continuation

    lines = []
    p = solve_by_continuation(solve, {"robust": 0.1, "end": 2e-3, "guess": _plan(0.0, 1.0),
                                      "log": lines.append}, 2)
    steps = p.stats["continuation"]
    assert [(round(s["robust"], 6), s["duration"] is None) for s in steps] == [
        (0.05, True), (0.025, False), (0.05, False), (0.1, True), (0.075, False),
        (0.1, False)]
    assert p.stats["robust"] == 0.1
    assert sum("halving the step" in line for line in lines) == 2


def test_the_robust_problems_of_a_path_share_one_compiled_library(onelink, tmp_path):
    # the scenarios' frequency factors are an input of the compiled point function: the
    # nominal problem builds its libraries (values; Jacobian and Hessian), the robust
    # problems at r = 0.05 and 0.1 one pair between them; the path ends where the
    # interpreted one does
    from casflex.planning import point_compiler

    kw = {**COMMON, "end": 2e-3, "robust": 0.1, "robust_steps": 2, "derivatives": "points"}
    compiled = point_compiler("points", tmp_path, background=False)
    path = plan_move(onelink, MOVE, **kw, compile_function=compiled)
    assert [s["robust"] for s in path.stats["continuation"]] == [0.0, 0.05, 0.1]
    assert len(compiled.builds) == 6  # two sets per problem, each found or built
    assert len(list((tmp_path / "jit").glob("plan_points-*"))) == 4
    interpreted = plan_move(onelink, MOVE, **kw)
    assert path.duration == pytest.approx(interpreted.duration, rel=1e-7)


@pytest.mark.parametrize("given, expected", [
    (0.0, [0.025, 0.05, 0.075, 0.1]),   # the nominal plan: the whole path
    (0.05, [0.075, 0.1]),               # half-way: the rest of it
    (0.06, [0.075, 0.1]),               # between two problems: from the next one
    (0.1, [0.1]),                       # at the end: the last problem again
    (0.2, [0.1]),                       # beyond: the last problem from it
])
def test_a_path_resumes_after_the_robust_plan_given(given, expected):
    from casflex.planning import solve_by_continuation

    def solve(robust, guess, **kw):
        return _plan(robust, 2.0 + robust)

    start = _plan(given, 2.0)
    start.stats["scenarios"] = [0.0, -given, given] if given else [0.0]
    p = solve_by_continuation(solve, {"robust": 0.1, "end": 2e-3, "guess": start}, 4)
    assert [round(s["robust"], 6) for s in p.stats["continuation"]] == expected


def _escaping_solver(calls, escape=5.0):
    """A solver whose path, from a plan more than 0.03 of the error away, leaves for an
    ``escape`` s plan (what Ipopt did on move 1 of the design study: 5.37 s in session 19,
    2.65 s where the path's plan was 2.135 s in session 32's CI rehearsal), and which
    stops on its way up at the ceiling it is given; near steps end at 2 s + the error."""
    def solve(robust, guess, duration_ceiling=None, **kw):
        calls.append((robust, duration_ceiling))
        start = 1.0 if not isinstance(guess, PlannedMove) else guess.stats["robust"]
        duration = 2.0 + robust if abs(robust - start) <= 0.03 + 1e-12 or robust == 0.0 \
            else escape
        if duration_ceiling is not None and duration > duration_ceiling:
            raise SolverError(f"plan_move: Ipopt found no plan ({CEILING_STATUS})")
        return _plan(robust, duration)
    return solve


#: the path of the escaping solver when escapes count as steps too long: the nominal
#: problem, then 0.05 escapes: halved to 0.025, then 0.05, then 0.1 escapes: halved to
#: 0.075, then 0.1
HALVED_PATH = [(0.0, 2.0), (0.05, None), (0.025, 2.025), (0.05, 2.05), (0.1, None),
               (0.075, 2.075), (0.1, 2.1)]


def _durations(plan):
    return [(round(s["robust"], 6), s["duration"]) for s in plan.stats["continuation"]]


def test_an_energy_path_follows_the_escape():
    # a plan of fixed duration has no duration to rise: no ceiling, no path rise
    calls = []
    p = solve_by_continuation(_escaping_solver(calls), {
        "robust": 0.1, "end": 2e-3, "guess": "shaped", "objective": "energy"}, 2)
    assert p.duration == 5.0
    assert all(ceiling is None for _, ceiling in calls)


@pytest.mark.parametrize("ceiling", [None, 3.2])
@pytest.mark.parametrize("escape", [5.0, 2.65])
def test_an_escape_is_a_step_too_long(ceiling, escape):
    # above the ceiling (5 s) or only above PATH_RISE over the last plan (2.65 s under a
    # 3.2 s ceiling): either way no plan of the path's, and a shorter step is taken
    calls = []
    p = solve_by_continuation(_escaping_solver(calls, escape), {
        "robust": 0.1, "end": 2e-3, "guess": "shaped", "duration_ceiling": ceiling}, 2)
    assert _durations(p) == HALVED_PATH
    # the nominal problem starts from the caller's guess: no ceiling there; then each
    # problem's is the lower of the ceiling and PATH_RISE over the last plan reached
    last = [2.0, 2.0, 2.025, 2.05, 2.05, 2.075]
    assert calls[0] == (0.0, None)
    assert [c for _, c in calls[1:]] == pytest.approx(
        [min(ceiling or float("inf"), (1.0 + PATH_RISE) * d) for d in last], rel=1e-15)


def test_a_rise_within_path_rise_is_taken():
    # a path whose plans rise by 5 % a problem (below PATH_RISE): no step halved
    def solve(robust, guess, duration_ceiling=None, **kw):
        duration = 2.0 * 1.05 ** round(robust / 0.05)
        assert duration_ceiling is None or duration <= duration_ceiling
        return _plan(robust, duration)

    p = solve_by_continuation(solve, {"robust": 0.1, "end": 2e-3, "guess": "shaped"}, 2)
    assert [round(s["robust"], 6) for s in p.stats["continuation"]] == [0.0, 0.05, 0.1]


def test_a_plan_not_converged_before_the_last_problem_is_a_step_too_long():
    # a solver whose plans from more than 0.03 of the error away end at Ipopt's
    # acceptable level 1 % longer (what the plans that left move 1's bound path did,
    # session 33): such a plan is no plan of the path's before its last problem, whose
    # plan is the result as it ended
    def solve(robust, guess, **kw):
        start = guess.stats["robust"] if isinstance(guess, PlannedMove) else 0.0
        far = abs(robust - start) > 0.03 + 1e-12
        plan = _plan(robust, (2.0 + robust) * (1.01 if far else 1.0))
        plan.stats["status"] = "Solved_To_Acceptable_Level" if far else "Solve_Succeeded"
        plan.stats["iterations"] = 7
        return plan

    p = solve_by_continuation(solve, {"robust": 0.1, "end": 2e-3, "guess": "shaped"}, 2)
    # 0.05 from the nominal plan: not converged, halved to 0.025; then 0.05; the last
    # problem (0.1, 0.05 away) taken as it ended
    assert [(r, d and round(d, 9)) for r, d in _durations(p)] == [
        (0.0, 2.0), (0.05, None), (0.025, 2.025), (0.05, 2.05), (0.1, round(2.1 * 1.01, 9))]
    assert p.stats["status"] == "Solved_To_Acceptable_Level"
    refused = p.stats["continuation"][1]
    assert "Solved_To_Acceptable_Level at 2.0705 s" in refused["status"]
    assert refused["iterations"] == 7  # its solve counted
    assert set(PATH_STATUSES) == {"Solve_Succeeded", PROGRESS_STATUS}


def test_from_a_plan_at_the_end_of_the_path_a_failure_is_not_halved():
    # a plan already at the path's error (or beyond): the last problem from it, and no
    # "shorter step" to take when it fails
    calls = []

    def solve(robust, guess, **kw):
        calls.append(robust)
        raise SolverError("no plan")

    start = _plan(0.1, 2.0)
    start.stats["scenarios"] = [0.0, -0.1, 0.1]
    with pytest.raises(SolverError, match="after 0 halving"):
        solve_by_continuation(solve, {"robust": 0.1, "end": 2e-3, "guess": start}, 4)
    assert calls == [0.1]  # the stand-in carries no multipliers: one attempt
