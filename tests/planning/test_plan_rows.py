"""The NLP's start and goal rows in the states' scales (plan format 2): their multipliers
are the duration's sensitivities to the end points, and format-1 plans are read with
their multipliers converted."""

from __future__ import annotations

import json

import numpy as np
import pytest

from casflex.planning import PlannedMove, plan_move

START, GOAL = 0.0, 0.3  # the joint row's scale is then 0.3, not 1
COMMON = {"torque_limit": 0.1, "intervals": 40, "end": "rest", "progress_stop": False}


@pytest.fixture(scope="module")
def plan(onelink):
    return plan_move(onelink, [START], [GOAL], **COMMON)


def _rows(plan, name):
    """Offset and length of the constraint block ``name`` in the plan's NLP."""
    for block, offset, rows, cols in plan.solution["layout"]["g"]:
        if block == name:
            return offset, rows * cols
    raise KeyError(name)


def test_the_end_point_multipliers_are_the_duration_sensitivities(onelink, plan):
    # envelope theorem on L = T + λᵀ g with the rows g = (q(0) − q0) / s and
    # (q(T) − qf) / s: dT*/dq0 = −λ_start / s and dT*/dqf = −λ_goal / s; the derivatives
    # by central differences of cold solves (no warm start: an independent path)
    eps = 1e-3

    def duration(q0, qf):
        return plan_move(onelink, [q0], [qf], **COMMON).duration

    d_start = (duration(START + eps, GOAL) - duration(START - eps, GOAL)) / (2 * eps)
    d_goal = (duration(START, GOAL + eps) - duration(START, GOAL - eps)) / (2 * eps)
    s = plan.solution["scales"]["x"][0]
    lam = plan.solution["lam_g"]
    assert d_start == pytest.approx(-lam[_rows(plan, "start")[0]] / s, rel=1e-3)
    assert d_goal == pytest.approx(-lam[_rows(plan, "goal")[0]] / s, rel=1e-3)
    # the one-link arm's modes do not depend on q: T depends on qf − q0 alone
    assert d_start == pytest.approx(-d_goal, rel=1e-3)


def _as_format_1(plan, path, out, layout=True):
    """``plan``'s file rewritten as format 1 wrote it: the start and goal rows in the
    states' units, so their multipliers divided by the states' scales."""
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["meta"]))
    sx = plan.solution["scales"]["x"]
    n = plan.q.shape[1]
    m = plan.delta.shape[1]
    lam = arrays["solution_lam_g"].copy()
    for name, scale in (("start", sx), ("goal", sx[:n]), ("goal velocity", sx[n + m:2 * n + m])):
        offset, rows = _rows(plan, name)
        lam[offset:offset + rows] /= scale
    meta.update(format=1, layout=meta["layout"] if layout else None)
    np.savez(out, **{**arrays, "solution_lam_g": lam, "meta": np.array(json.dumps(meta))})
    return out


def test_a_format_1_plan_is_read_with_its_multipliers_in_the_new_rows(onelink, plan,
                                                                       tmp_path):
    path = plan.save(tmp_path / "plan.npz")
    old = PlannedMove.load(_as_format_1(plan, path, tmp_path / "old.npz"))
    np.testing.assert_allclose(old.solution["lam_g"], plan.solution["lam_g"], rtol=1e-14,
                               atol=0)
    # as a warm start it is its own solution: Ipopt stays (a start row's multiplier in
    # the wrong units would be off by its scale)
    again = plan_move(onelink, [START], [GOAL], **COMMON, guess=old)
    assert again.stats["warm_start_duals"]
    assert again.stats["iterations"] <= 3
    assert again.duration == pytest.approx(plan.duration, rel=1e-9)
    # a format-1 plan without a layout (saved before casflex recorded one): its rows
    # cannot be found, so it keeps its trajectory but no NLP solution
    bare = PlannedMove.load(_as_format_1(plan, path, tmp_path / "bare.npz", layout=False))
    assert bare.solution is None
    np.testing.assert_array_equal(bare.node_x, plan.node_x)
