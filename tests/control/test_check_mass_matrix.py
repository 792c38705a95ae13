"""``casflex check`` reports whether the model's mass matrix M(q, 0) is positive definite
over the joint box (control.mass_matrix_over_box, issue 21).

References: numpy's eigenvalues of the whole M(q, 0) at the configurations reported (its
smallest eigenvalue has the sign of the residual joint inertia when M_δδ is positive
definite, Haynsworth inertia additivity), and the exact model of one configuration
(PointwiseProvider: mode integrals of the TMM modes there, positive definite by Bessel's
inequality). The failing case is the bare 4-joint arm's 30° table with cubic B-splines,
whose interpolated integrals of the swapping tube pairs overshoot between grid points
(tests/control/test_gain_schedule_multi.py finds the same at another configuration).
"""

from __future__ import annotations

import json

import casadi as ca
import numpy as np
import pytest

from casflex import control
from casflex.cli import main
from casflex.model import FlexibleModel, PointwiseProvider, build_model
from casflex.robot import load

pytestmark = pytest.mark.filterwarnings("ignore:modal table of:RuntimeWarning")


def _lowest_eigenvalue_of_M(model, q):
    M0 = ca.Function("M0", [model.q], [ca.substitute(model.M, model.delta,
                                                     ca.SX.zeros(model.m))])
    return float(np.linalg.eigvalsh(M0(q).full())[0])


@pytest.mark.slow
def test_arm2link_mass_matrix_is_positive_over_the_box(arm_model):
    model, table = arm_model(3, 15.0, gravity=None, delta_order=0)
    r = control.mass_matrix_over_box(model)
    # the 15° full turn: 24 grid points and the 24 centres of its cells (the last one
    # closing the turn)
    assert r["holds"] and r["points"] == 48 and r["value"] > 0
    for q in ([0.0, 0.0, r["q"][2]], [0.3, -1.0, 2.1]):
        assert _lowest_eigenvalue_of_M(model, q) > 0
    # the table given explicitly is the provider's default
    assert control.mass_matrix_over_box(model, table)["value"] == r["value"]


@pytest.fixture(scope="module")
def bare_arm4(model_cache):
    bare = load("problems/arm4_spatial.toml")
    model, _ = build_model(bare, 3, step=np.radians(30.0), gravity=None, delta_order=0,
                           cache_dir=model_cache, processes=2)
    return bare, model


@pytest.mark.slow
def test_indefinite_mass_matrix_of_cubic_tables_is_found(bare_arm4):
    bare, model = bare_arm4
    r = control.mass_matrix_over_box(model)
    assert not r["holds"] and r["value"] < 0
    q = np.asarray(r["q"])
    assert _lowest_eigenvalue_of_M(model, q) < 0  # numpy agrees: M itself is indefinite
    exact = FlexibleModel(bare, PointwiseProvider(bare, q, count=3), gravity=None,
                          delta_order=0)
    assert _lowest_eigenvalue_of_M(exact, q) > 0  # the arm is not: the table is wrong
    # the box is the table's grid inside the joint limits, refined by the cell centres
    limits = [bare.joint_limits[j] for j in model.provider.shape_joints]
    for value, lim in zip(q[list(model.provider.shape_joints)], limits, strict=True):
        assert lim is None or lim[0] <= value <= lim[1]


def test_cli_check_reports_the_mass_matrix_over_the_box(capsys, monkeypatch, model_cache):
    monkeypatch.setenv("CASFLEX_CACHE", str(model_cache))
    assert main(["check", "problems/arm2link.toml", "--move",
                 "problems/moves.toml:control_move1", "--controller", "inversion",
                 "--step", "15deg", "--json"]) == 0
    captured = capsys.readouterr()
    box = json.loads(captured.out)["mass_matrix_box"]
    assert box["holds"] is True and box["points"] == 48 and box["unit"] == "kg m^2"
    assert "mass matrix over the joint box (48 configurations): holds" in captured.err


@pytest.mark.slow
def test_cli_check_flags_the_indefinite_mass_matrix(capsys, monkeypatch, model_cache,
                                                     bare_arm4):
    monkeypatch.setenv("CASFLEX_CACHE", str(model_cache))  # bare_arm4's table: cached
    assert main(["check", "problems/arm4_spatial.toml", "--move",
                 "problems/moves.toml:arm4_all_joints", "--controller", "inversion",
                 "--step", "30deg", "--json"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    box = out["mass_matrix_box"]
    assert box["holds"] is False and box["value"] < 0
    assert box["value"] == control.mass_matrix_over_box(
        bare_arm4[1], q=[0.0, 0.3, 0.5, -0.8])["value"]  # the move's start for q1, q2
    assert "mass matrix over the joint box" in captured.err and "FAILS" in captured.err
