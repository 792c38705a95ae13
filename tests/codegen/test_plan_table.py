"""The planned-move table: compiled, read back by its C functions, equal to the plan;
between samples the C interpolation equals numpy's."""

import subprocess

import numpy as np
import pytest

from casflex.codegen import find_compiler, plan_table_bundle, run_compiler
from casflex.errors import ProblemFileError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.planning import plan_move
from casflex.robot import load

MAIN = r"""
#include <stdio.h>
#include "ref.h"
int main(void) {
    double q[REF_N_JOINTS], dq[REF_N_JOINTS], ddq[REF_N_JOINTS], tau[REF_N_JOINTS];
    double t;
    long k;
    int j;
    char kind;
    while (scanf(" %c", &kind) == 1) {
        if (kind == 'k') { if (scanf("%ld", &k) != 1) return 1; ref_row(k, q, dq, ddq, tau); }
        else { if (scanf("%lf", &t) != 1) return 1; ref_at(t, q, dq, ddq, tau); }
        for (j = 0; j < REF_N_JOINTS; ++j)
            printf("%.17g %.17g %.17g %.17g ", q[j], dq[j], ddq[j], tau[j]);
        printf("\n");
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def plan():
    robot = load("problems/onelink.toml")
    model = FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None)
    p = plan_move(model, [0.0], [0.5], torque_limit=0.2, intervals=12, settle=0.5)
    assert p.stats["success"]
    return p


def run(exe, lines):
    out = subprocess.run([str(exe)], input="\n".join(lines), capture_output=True,
                         text=True, check=True).stdout
    return np.array([row.split() for row in out.splitlines()], dtype=float)


@pytest.mark.needs_cc
def test_c_table_is_the_plan(tmp_path, plan):
    dt = 1e-3
    files = plan_table_bundle(plan, dt, "ref", tmp_path)
    (tmp_path / "main.c").write_text(MAIN)
    run_compiler(find_compiler() + ["-O2", "-o", "ref", "main.c", files["source"].name],
                 tmp_path)
    K = files["samples"]
    assert (K - 1) * dt >= plan.duration > (K - 2) * dt
    ks = np.arange(-2, K + 3)
    rows = run(tmp_path / "ref", [f"k {k}" for k in ks])
    # every sample read back equals the plan sampled in Python (%.17g round-trips)
    t = np.clip(ks, 0, K - 1) * dt
    q, dq, ddq = plan.sample(t)
    law = plan.torque_law()
    tau = np.array([law(float(tk), None) for tk in t])
    inside = (ks >= 0) & (ks < K)
    np.testing.assert_array_equal(rows[inside, 0], q[inside, 0])
    np.testing.assert_array_equal(rows[inside, 1], dq[inside, 0])
    np.testing.assert_array_equal(rows[inside, 2], ddq[inside, 0])
    np.testing.assert_array_equal(rows[inside, 3], tau[inside, 0])
    # outside: at rest at the ends, the start's torque before, the holding torque after
    np.testing.assert_array_equal(rows[ks < 0, 0], plan.q0[0])
    np.testing.assert_array_equal(rows[ks >= K, 0], q[-1, 0])
    np.testing.assert_array_equal(rows[~inside][:, 1:3], 0.0)
    np.testing.assert_array_equal(rows[ks >= K, 3], plan.hold_torque[0])
    # the last sample is at rest at qf (the plan's end, sampled after its duration)
    last = rows[ks == K - 1][0]
    assert last[0] == plan.qf[0] and last[1] == 0.0 and last[2] == 0.0
    # between samples: linear interpolation, as numpy's interp of the table. C takes the
    # fraction as t / dt - k, numpy as (t - t_k) / (t_k+1 - t_k): they differ by a few
    # ulps of t / dt (< K), times the step between two samples, plus a few ulps of the
    # values
    rng = np.random.default_rng(3)
    ts = np.sort(rng.uniform(0.0, (K - 1) * dt, 500))
    at = run(tmp_path / "ref", [f"t {v:.17g}" for v in ts])
    grid = np.arange(K) * dt
    for col, table in enumerate((q, dq, ddq, tau)):
        ref = np.interp(ts, grid, table[2:K + 2, 0])
        eps = np.finfo(float).eps
        budget = 4 * eps * (K * np.abs(np.diff(table[:, 0])).max() + np.abs(table).max())
        np.testing.assert_allclose(at[:, col], ref, rtol=0.0, atol=budget)


def test_bad_arguments(tmp_path, plan):
    with pytest.raises(ProblemFileError, match="dt"):
        plan_table_bundle(plan, 0.0, "ref", tmp_path)
    with pytest.raises(ProblemFileError, match="dt.*duration"):
        plan_table_bundle(plan, 10.0, "ref", tmp_path)
    with pytest.raises(ProblemFileError, match="name"):
        plan_table_bundle(plan, 1e-3, "2bad", tmp_path)
