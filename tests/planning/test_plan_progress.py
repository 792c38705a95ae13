"""The live display of a planner's solve (``plan_move(progress=...)``) and the iteration
callback it shares with the progress rule (casflex.planning.iteration_callback)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.planning import iteration_callback, plan_move


def test_progress_callable_sees_every_iterate_and_ends_on_the_plan(onelink):
    seen = []
    plan = plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20,
                     progress_stop=False, progress=lambda *a: seen.append(a))
    # Ipopt's iterates 0 (the guess) to iter_count, numbered in order
    assert [s[0] for s in seen] == list(range(plan.stats["iterations"] + 1))
    # the last iterate is the plan: its T and its constraint violation as plan_move
    # measures them after the solve
    assert seen[-1][1] == pytest.approx(plan.duration, rel=1e-12)
    assert seen[-1][2] == pytest.approx(plan.stats["constraint_violation"], abs=1e-12)
    # the guess (the rigid bang-bang move stretched by 1.3) is not at the optimum
    assert seen[0][1] > 1.2 * plan.duration


def test_progress_and_the_rule_see_the_same_iterates(onelink):
    # both listen to one callback: the rule's trace is what the display was given, up to
    # the iterate where the rule stopped the solve
    seen = []
    plan = plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20,
                     progress=lambda i, f, v: seen.append((f, v)))
    assert seen == [tuple(p) for p in plan.stats["objective_trace"]]


def test_progress_counter_on_stderr_is_closed(onelink, capsys):
    from tqdm import tqdm

    plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20, progress=True,
              name="swing")
    err = capsys.readouterr().err
    assert "Ipopt swing" in err
    assert not [bar for bar in tqdm._instances if "Ipopt" in str(bar.desc)]


def test_log_names_the_problem_size_before_a_cold_solve(onelink):
    # the size decides how long a solve takes: the log says it before Ipopt starts, with
    # the rule that chose it
    lines = []
    plan = plan_move(onelink, [0.0], [1.0], torque_limit=0.1, velocity_limit=1.0,
                     log=lines.append, restarts=1)
    size = [line for line in lines if "intervals" in line]
    N = plan.node_tau.shape[0]
    assert len(size) == 1  # the restart is warm: no second line
    assert size[0].startswith(f"planned: {N} collocation intervals (3 points each), from "
                              "ω_max h <= 1 at the guess's")
    omega = float(size[0].split("ω_max ")[-1].split(" rad/s")[0])
    T_guess = float(size[0].split("guess's ")[1].split(" s")[0])
    assert omega * T_guess == pytest.approx(N, rel=0.01)  # the figures as printed, rounded
    lines.clear()
    plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=12, log=lines.append,
              transcription="shooting")
    assert lines[0].startswith("planned: 12 shooting intervals (")


def test_progress_rejects_other_values_before_solving(onelink):
    with pytest.raises(ModelError, match="progress = 'yes'.*bool or a callable"):
        plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20, progress="yes")


def test_a_listener_that_returns_true_stops_ipopt_there():
    # min (x - 2)^2 + (y - 1)^2 s.t. x + y >= 4 (optimum x = 2.5, y = 1.5): the second
    # listener asks to stop at the third iterate; both are called at every iterate
    x = ca.SX.sym("x", 2)
    calls = {"a": [], "b": []}

    def a(f, v):
        calls["a"].append((f, v))

    def b(f, v):
        calls["b"].append((f, v))
        return len(calls["b"]) == 3

    cb = iteration_callback([4.0], [np.inf], 2, [a, b])
    solver = ca.nlpsol("s", "ipopt", {"x": x, "f": (x[0] - 2) ** 2 + (x[1] - 1) ** 2,
                                      "g": x[0] + x[1]},
                       {"iteration_callback": cb, "print_time": False,
                        "ipopt": {"print_level": 0, "sb": "yes"}})
    solver(x0=[0.0, 0.0], lbg=4.0, ubg=np.inf)
    assert solver.stats()["return_status"] == "User_Requested_Stop"
    assert solver.stats()["iter_count"] == 2
    assert calls["a"] == calls["b"] and len(calls["a"]) == 3
    # the violation is the posed bound's: x + y = 0 against >= 4 at the start
    assert calls["a"][0] == (5.0, 4.0)


def test_ctrl_c_during_a_solve_interrupts_the_plan(onelink, ctrl_c):
    # a SIGINT while Ipopt runs reaches Python at the next iterate's callback; CasADi
    # would turn the KeyboardInterrupt into User_Requested_Stop, so that plan_move
    # reported "no plan" and the restarts went on with their next pass: it must
    # interrupt instead, from any pass
    import os
    import signal

    for restarts, passes, at in ((0, 1, 3), (2, 2, 1)):
        # interrupt at iterate `at` of pass `passes` (each pass numbers from 0)
        seen = []

        def interrupt(i, f, v, seen=seen, passes=passes, at=at):
            seen.append(i)
            if seen.count(0) == passes and i == at:
                os.kill(os.getpid(), signal.SIGINT)

        with pytest.raises(KeyboardInterrupt):
            plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20,
                      restarts=restarts, progress=interrupt)
        # no iterate after the interrupt, no further pass
        assert seen.count(0) == passes and seen[-1] == at


def test_an_error_in_the_progress_callable_is_raised_as_itself(onelink):
    def broken(i, f, v):
        raise ValueError("display broke")

    with pytest.raises(ValueError, match="display broke"):
        plan_move(onelink, [0.0], [1.0], torque_limit=0.1, intervals=20, progress=broken)


def _interrupt_at(test):
    """A progress callable that sends SIGINT at the first iterate where ``test(seen, i,
    f, v)`` holds; ``seen`` lists the ``(i, f, v)`` it was given."""
    import os
    import signal

    seen = []

    def call(i, f, v):
        seen.append((i, f, v))
        if test(seen, i, f, v):
            os.kill(os.getpid(), signal.SIGINT)
    return call, seen


def test_interrupt_keeps_the_last_feasible_iterate(onelink, ctrl_c):
    from casflex.planning import INTERRUPTED_STATUS, PlanInterrupted

    kw = {"torque_limit": 0.1, "intervals": 20, "progress_stop": False}
    # the first feasible iterate after the guess: the plan is that iterate
    call, seen = _interrupt_at(lambda s, i, f, v: i > 0 and v <= 1e-6)
    with pytest.raises(PlanInterrupted) as info:
        plan_move(onelink, [0.0], [1.0], progress=call, **kw)
    plan = info.value.plan
    assert plan.stats["status"] == INTERRUPTED_STATUS and not plan.stats["converged"]
    assert plan.duration == pytest.approx(seen[-1][1], rel=1e-12)
    assert plan.stats["constraint_violation"] <= 1e-6
    # as a guess it continues to the plan of an uninterrupted solve
    full = plan_move(onelink, [0.0], [1.0], **kw)
    resumed = plan_move(onelink, [0.0], [1.0], guess=plan, **kw)
    assert resumed.duration == pytest.approx(full.duration, rel=1e-6)
    # an infeasible iterate is no plan
    call, seen = _interrupt_at(lambda s, i, f, v: v > 1e-6)
    with pytest.raises(PlanInterrupted) as info:
        plan_move(onelink, [0.0], [1.0], progress=call, **kw)
    assert info.value.plan is None and "not feasible" in info.value.note


def test_interrupt_in_a_restart_keeps_the_best_finished_pass(onelink, ctrl_c):
    from casflex.planning import PlanInterrupted

    kw = {"torque_limit": 0.08, "intervals": 20, "restarts": 2}
    first = plan_move(onelink, [0.0], [1.0], **{**kw, "restarts": 0})
    # at the second pass's guess (iterate 0 again: the first pass's plan)
    call, seen = _interrupt_at(lambda s, i, f, v: i == 0 and len(s) > 1)
    with pytest.raises(PlanInterrupted) as info:
        plan_move(onelink, [0.0], [1.0], progress=call, **kw)
    plan = info.value.plan
    assert "finished pass" in info.value.note
    assert plan.duration == first.duration and plan.stats["status"] == first.stats["status"]
