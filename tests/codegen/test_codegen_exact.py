"""C code of the model with exact kinematics (issue 19): the C of ``exact_forward`` (the
model's own ``M`` and ``h`` as separate functions and a solve), compiled, equals the
Python model's ``forward`` and ``ode`` (its docstring checks the split itself against
``forward``); ``casflex codegen --kinematics exact`` validates its flag."""

import numpy as np
import pytest

from casflex import codegen
from casflex.cli import main
from casflex.codegen import exact_forward
from casflex.errors import ModelError
from casflex.model import FlexibleModel, TableProvider


def _states(n, m, rng):
    # deflections of ~0.1 √kg m: the rods well into their nonlinear range
    return [rng.uniform(-3, 3, n), rng.normal(size=n), 0.1 * rng.normal(size=m),
            rng.normal(size=m), rng.normal(size=n)]


def _stacked(outputs):
    return np.concatenate([np.asarray(o).ravel() for o in outputs])


@pytest.mark.slow
@pytest.mark.needs_cc
def test_exact_model_bundle_in_c_is_the_python_model(arm_model, tmp_path):
    """The smallest bundle that proves it: one mode on the 15° table, read from the
    static coefficient table as ``casflex codegen`` does, compiled and loaded back:
    ``forward`` in C against the Python model's ``forward`` and the acceleration rows of
    its ``ode``, at random states. Compiled at -O0: gcc -O2 (the bundle's Makefile) takes
    longer than the 600 s limit of run_compiler on this bundle under load (its CPU time
    is in benchmarks/README_fidelity.md), and the C evaluates the same operations at
    any level. Tolerance as the other codegen tests: C and CasADi's VM evaluate the same
    operations in another grouping, and the solve amplifies rounding by cond(M) ~ 1e3."""
    model, table = arm_model(1, step_deg=15, gravity="robot")
    exact = FlexibleModel(model.robot, TableProvider(table, lookup="static"),
                          gravity="robot", kinematics="exact")
    bundle = codegen.generate([exact_forward(exact)], tmp_path / "exact", name="exact_model")
    forward = codegen.load(codegen.build(bundle, flags=("-O0",)), "forward")
    f = exact.functions()
    n, m = exact.n, exact.m
    rng = np.random.default_rng(1919)
    for _ in range(5):
        q, dq, d, dd, tau = _states(n, m, rng)
        q[2] = rng.uniform(-np.pi, np.pi)  # the shape joint anywhere on the table
        c = _stacked(o.full() for o in forward(q, dq, d, dd, tau))
        py = _stacked(o.full() for o in f["forward"](q, dq, d, dd, tau))
        xdot = f["ode"](np.r_[q, d, dq, dd], tau).full().ravel()
        scale = np.max(np.abs(py))
        assert np.max(np.abs(c - py)) <= 1e-12 * scale
        assert np.max(np.abs(c - xdot[n + m:])) <= 1e-12 * scale


def test_codegen_kinematics_flag_is_checked(tmp_path, capsys):
    with pytest.raises(ModelError, match="kinematics = 'exact': applies to the forward"):
        codegen.realtime_bundles("problems/arm2link.toml",
                                 "problems/sensors/arm2link_accel.toml", tmp_path / "x",
                                 kinematics="exact", model=False)
    with pytest.raises(ModelError, match="kinematics = 'poly': must be one of"):
        codegen.realtime_bundles("problems/arm2link.toml",
                                 "problems/sensors/arm2link_accel.toml", tmp_path / "x",
                                 kinematics="poly")
    code = main(["codegen", "problems/arm2link.toml", "--sensors",
                 "problems/sensors/arm2link_accel.toml", "--out", str(tmp_path / "rt"),
                 "--no-gravity", "--kinematics", "exact", "--no-model"])
    err = capsys.readouterr().err
    assert code == 2 and "--kinematics exact" in err and "Traceback" not in err
    assert not (tmp_path / "rt").exists()
