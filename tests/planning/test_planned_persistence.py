"""A PlannedMove saved and read back (``save`` / ``load``, a NumPy file) or pickled, with
its propagator: the same samples, reference, torques and warm start after the round trip;
the propagator meets the OCP's continuity at the nodes; a bad file is a clear error."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from casflex.errors import ProblemFileError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.planning import PlannedMove, Propagator, plan_move
from casflex.robot import load

KW = {"torque_limit": 0.1, "intervals": 24, "end": 2e-3}


@pytest.fixture(scope="module")
def model():
    robot = load("problems/onelink.toml")
    return FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)


@pytest.fixture(scope="module", params=["collocation", "shooting"])
def plan(request, model):
    return plan_move(model, [0.0], [1.0], transcription=request.param, **KW)


@pytest.fixture(scope="module", params=["npz", "pickle"])
def plans(request, plan, tmp_path_factory):
    if request.param == "pickle":
        return plan, pickle.loads(pickle.dumps(plan))
    path = tmp_path_factory.mktemp("plan") / "plan.npz"
    assert plan.save(path) == path
    return plan, PlannedMove.load(path)


def test_round_trip_samples_bit_for_bit(plans):
    plan, copy = plans
    assert isinstance(copy.propagator, Propagator)
    t = np.linspace(-0.2, plan.duration + 0.2, 301)
    for a, b in zip(plan.sample(t), copy.sample(t), strict=True):
        np.testing.assert_array_equal(a, b)
    law, law_copy = plan.torque_law(), copy.torque_law()
    assert all(np.array_equal(law(s, None), law_copy(s, None)) for s in t)
    ref, ref_copy = plan.casadi_reference(), copy.casadi_reference()
    for s in (0.1, 0.5 * plan.duration, plan.duration - 1e-3):
        for a, b in zip(ref(s), ref_copy(s), strict=True):
            np.testing.assert_array_equal(a.full(), b.full())
    assert json.dumps(copy.stats, sort_keys=True) == json.dumps(plan.stats, sort_keys=True)
    np.testing.assert_array_equal(copy.solution["x"], plan.solution["x"])
    np.testing.assert_array_equal(copy.solution["lam_g"], plan.solution["lam_g"])


def test_the_torque_function_is_the_torque_law(plan):
    # the CasADi form (CasADi's low and a table) against the numpy one (searchsorted),
    # exactly: at random times, at every node, a hair (the law's 1e-9 s) on either side of
    # it, before the start and after the end, and on a simulator's grid of sums of dt
    law, fun = plan.torque_law(), plan.torque_function()
    x = np.zeros(fun.size1_in(1))
    nodes = np.asarray(plan.node_t)
    t = np.r_[np.random.default_rng(0).uniform(-0.3, plan.duration + 0.3, 200), nodes,
              nodes - 2e-9, nodes - 5e-10, nodes + 5e-10, nodes + 2e-9,
              np.cumsum(np.full(int(plan.duration / 1e-3) + 50, 1e-3))]
    got = np.asarray(fun.map(t.size)(t[None, :], np.zeros((x.size, t.size)))).T
    want = np.array([law(float(s), x) for s in t])
    np.testing.assert_array_equal(got, want)


def test_warm_start_from_the_copy_is_the_warm_start_from_the_plan(model, plans):
    plan, copy = plans
    kw = {**KW, "end": 0.9 * KW["end"], "transcription": plan.stats["transcription"]}
    warm = plan_move(model, [0.0], [1.0], guess=plan, **kw)
    warm_copy = plan_move(model, [0.0], [1.0], guess=copy, **kw)
    assert warm_copy.stats["warm_start_duals"]
    assert warm_copy.duration == warm.duration
    assert warm_copy.stats["iterations"] == warm.stats["iterations"]


def test_propagator_reaches_the_next_node(plans):
    """Across an interval the propagator is the OCP's own discretisation: at ``s = h`` it
    lands on the next node to the solver's constraint tolerance (the continuity rows)."""
    plan, copy = plans
    N = plan.node_tau.shape[0]
    h = plan.node_t[1] - plan.node_t[0]
    k = np.arange(N)
    x_end, _ = copy.propagator(k, np.full(N, h))
    scale = np.abs(plan.node_x).max(axis=0) + 1e-12
    err = np.abs(x_end.T - plan.node_x[1:]) / scale
    assert err.max() < 1e-6


def test_bad_plan_files_name_the_file_and_the_field(plan, tmp_path):
    with pytest.raises(ProblemFileError, match="cannot be read"):
        PlannedMove.load(tmp_path / "missing.npz")
    # any file but a zip archive: named as such (numpy's own message took it for a pickle
    # and suggested loading it unsafely), e.g. the trajectory.csv that --out writes beside
    for name in ("text.npz", "trajectory.csv"):
        text = tmp_path / name
        text.write_text("t,q1\n0,0\n")
        with pytest.raises(ProblemFileError, match=fr"{name}: field '<file>'.*is not a NumPy "
                           r"\.npz archive \(a plan is the plan.npz") as err:
            PlannedMove.load(text)
        assert "pickle" not in str(err.value)
    other = tmp_path / "other.npz"
    np.savez(other, t=np.zeros(3))
    with pytest.raises(ProblemFileError, match="'meta'.*not a plan written by"):
        PlannedMove.load(other)
    good = plan.save(tmp_path / "good.npz")
    with np.load(good) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["meta"]))
    for change, match in [({"meta": np.array(json.dumps({**meta, "format": 99}))},
                           "'meta.format' = 99: this casflex reads plans of formats 1 and 2"),
                          ({"node_tau": arrays["node_tau"][:-1]},
                           r"'node_t.shape' = \(25,\): must be \(24,\)"),
                          ({"dq": arrays["dq"][:, :0]},
                           r"'dq.shape' = \(\d+, 0\): must be \(\d+, 1\)")]:
        bad = tmp_path / "bad.npz"
        np.savez(bad, **{**arrays, **change})
        with pytest.raises(ProblemFileError, match=match):
            PlannedMove.load(bad)
    with pytest.raises(Exception, match="path"):
        plan.save(tmp_path / "no" / "such" / "dir" / "plan.npz")
