"""The model bundle's C kept small and quick to compile: the local B-spline read from a
static table (one coefficient table for the value and its derivatives, out of the work
memory) and ``forward`` split into the model's smaller functions; ``casflex codegen
--fit/--basis``."""

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

from casflex import codegen
from casflex.cli import main
from casflex.codegen import split_forward
from casflex.errors import ModelError
from casflex.modal import ModalTable, local_bspline_function
from casflex.model import FlexibleModel, PointwiseProvider, TableProvider


def _spline_and_derivatives(f):
    x = ca.SX.sym("x")
    y = f(x)
    dy = ca.jacobian(y, x)
    return ca.Function("g", [x], [y, dy, ca.jacobian(dy, x)])


def test_static_rows_are_the_pointer_rows_bit_for_bit():
    grid = np.linspace(-1.0, 2.0, 23)
    rng = np.random.default_rng(4)
    values = np.c_[np.sin(3 * grid), grid**3, np.exp(grid)] @ rng.normal(size=(3, 7))
    static = _spline_and_derivatives(local_bspline_function("s", grid, values,
                                                            rows="static"))
    pointer = _spline_and_derivatives(local_bspline_function("p", grid, values))
    # the independent reference: scipy's B-spline and its derivatives (the same fit)
    ref = make_interp_spline(grid, values, k=3)
    for x in np.r_[grid[0], grid[-1], grid[7], rng.uniform(-1.0, 2.0, 20)]:
        got = [o.full().ravel() for o in static(x)]
        # the rows are read with weights exactly 1 and 0: the same doubles as the pointer
        for a, b in zip(got, pointer(x), strict=True):
            assert np.array_equal(a, b.full().ravel())
        for order, a in enumerate(got):
            want = ref(x, nu=order)
            # Cox-de Boor vs scipy's de Boor: rounding of O(10) operations on values
            # of O(10) (the second derivative of values varying over 0.1 of the axis)
            assert np.max(np.abs(a - want)) <= 1e-11 * (1 + np.max(np.abs(want)))


def test_static_rows_keep_the_table_out_of_the_work_memory(tmp_path):
    grid = np.linspace(0.0, 3.0, 200)
    values = np.sin(np.outer(grid, np.arange(1, 21)) / 10)   # 200 x 20: 4 000 coefficients
    sizes = {}
    for rows in ("pointer", "static"):
        g = _spline_and_derivatives(local_bspline_function(rows, grid, values, rows=rows))
        b = codegen.generate([ca.Function(f"g_{rows}", g.sx_in(), g.call(g.sx_in()))],
                             tmp_path / rows, name=f"b_{rows}")
        sizes[rows] = b.functions[0].sz_w
        text = b.source.read_text()
        # value, first and second derivative share one coefficient table in the C
        assert text.count("static const casadi_real casadi_c") <= 4
    # the table (4 000 coefficients) leaves the work; what stays is the output's entries
    # and derivatives, the two knot vectors (~200 each, still MX constants) and the
    # rows interpolant's own few slots
    assert sizes["pointer"] - sizes["static"] > 0.99 * 4000 and sizes["static"] < 1000


def _states(n, m, rng):
    return [rng.uniform(-3, 3, n), rng.normal(size=n), 1e-3 * rng.normal(size=m),
            1e-2 * rng.normal(size=m), rng.normal(size=n)]


@pytest.mark.parametrize("options", [{}, {"delta_order": 0}, {"modal_mass": "identity"},
                                     {"kinematics": "exact"}])
def test_split_forward_is_the_model_forward(arm, options):
    # modes frozen at one configuration: the model's q-dependence is its kinematics only
    provider = PointwiseProvider(arm, [0.0, 0.0, 0.4], 2)
    model = FlexibleModel(arm, provider, gravity="robot", **options)
    ref, got = model.functions()["forward"], split_forward(model)
    assert got.name_in() == ref.name_in() and got.name_out() == ref.name_out()
    rng = np.random.default_rng(2)
    for _ in range(6):
        args = _states(model.n, model.m, rng)
        a = np.concatenate([o.full().ravel() for o in ref(*args)])
        b = np.concatenate([o.full().ravel() for o in got(*args)])
        # the same operations grouped differently: rounding of the solve (cond(M) ~ 1e3)
        assert np.max(np.abs(a - b)) <= 1e-12 * np.max(np.abs(a))


@pytest.mark.slow
def test_static_lookup_model_is_the_interpolant_model(arm_model, accel_sensors):
    model, table = arm_model(2, points=accel_sensors.points)
    static = FlexibleModel(model.robot, TableProvider(table, lookup="static"),
                           gravity="robot")
    ref, got = model.functions()["forward"], split_forward(static)
    rng = np.random.default_rng(5)
    for _ in range(6):
        args = _states(model.n, model.m, rng)
        a = np.concatenate([o.full().ravel() for o in ref(*args)])
        b = np.concatenate([o.full().ravel() for o in got(*args)])
        # CasADi's iterative spline fit vs scipy's direct solve agree to ~1e-14 of the
        # table values; through M's derivatives and the solve, a few 1e-12 of ddX
        assert np.max(np.abs(a - b)) <= 1e-10 * np.max(np.abs(a))


def test_table_provider_rejects_an_unknown_lookup():
    table = ModalTable(grid=(np.linspace(0, 3, 7),), shape_joints=(0,),
                       values={"m": np.ones((7, 2))}, omega=np.ones((7, 1)))
    with pytest.raises(ModelError, match="lookup must be"):
        TableProvider(table, lookup="fast")


def test_codegen_hands_fit_and_basis_to_build_model(build_kwargs, tmp_path):
    with pytest.raises(RuntimeError, match="stop"):
        codegen.realtime_bundles("problems/arm2link.toml",
                                 "problems/sensors/arm2link_accel.toml", tmp_path / "rt",
                                 fit="chebyshev", basis="smooth")
    assert build_kwargs["fit"] == "chebyshev" and build_kwargs["basis"] == "smooth"
    assert build_kwargs["step"] is None


def test_codegen_grid_is_the_default(build_kwargs, capsys, tmp_path):
    with pytest.raises(RuntimeError, match="stop"):
        main(["codegen", "problems/arm2link.toml", "--sensors",
              "problems/sensors/arm2link_accel.toml", "--out", str(tmp_path / "rt"),
              "--no-gravity", "--basis", "smooth"])
    assert build_kwargs["fit"] is None and build_kwargs["basis"] == "smooth"


@pytest.mark.parametrize("argv, message", [
    (["--fit", "chebyshev", "--step", "2deg"], "--fit chebyshev has no grid"),
    (["--fit", "spline"], "invalid choice: 'spline'"),
    (["--basis", "pod"], "invalid choice: 'pod'"),
])
def test_codegen_fit_and_basis_errors_are_one_line(argv, message, capsys, tmp_path):
    argv = ["codegen", "problems/arm2link.toml", "--sensors",
            "problems/sensors/arm2link_accel.toml", "--out", str(tmp_path / "rt"),
            "--no-gravity", *argv]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own choices: usage and one error line
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err
    assert sum(message in line for line in err.splitlines()) == 1
    assert not (tmp_path / "rt").exists()


def test_realtime_bundles_checks_fit_and_basis(tmp_path):
    for kwargs, rule in (({"fit": "spline"}, "fit = 'spline': must be one of"),
                         ({"basis": "pod"}, "basis = 'pod': must be one of"),
                         ({"fit": "chebyshev", "step": 0.1}, "has no grid")):
        with pytest.raises(ModelError, match=rule):
            codegen.realtime_bundles("problems/arm2link.toml",
                                     "problems/sensors/arm2link_accel.toml", tmp_path / "x",
                                     **kwargs)


@pytest.mark.slow
def test_one_estimator_plant_with_and_without_controller(monkeypatch, arm_model,
                                                          accel_sensors, tmp_path):
    import casflex.estimation
    import casflex.model
    from casflex.codegen import robot_bundles

    model, table = arm_model(1, points=accel_sensors.points, delta_order=0)
    seen = {"build": [], "plant": [], "ctrl": [], "bundle": []}

    def build(robot, **kwargs):
        seen["build"].append(kwargs["delta_order"])
        return model, table

    def functions(flexible, sensors, **kwargs):  # a stand-in estimator: C in no time
        x = ca.SX.sym("x")
        return {"ekf_step": ca.Function("ekf_step", [x], [2 * x])}, {}

    monkeypatch.setattr(casflex.model, "build_model", build)
    monkeypatch.setattr(casflex.estimation, "tabulate_plant",
                        lambda m, **kw: seen["plant"].append(m.delta_order))
    monkeypatch.setattr(robot_bundles, "make_controller",
                        lambda m, *a, **kw: seen["ctrl"].append(m.delta_order))
    monkeypatch.setattr(robot_bundles, "rt_functions", functions)
    monkeypatch.setattr(robot_bundles, "model_bundle", lambda m, *a, **kw: seen[
        "bundle"].append((m.delta_order, m.provider.lookup)))
    for k, controller in enumerate((None, "composite")):
        codegen.realtime_bundles("problems/arm2link.toml",
                                 "problems/sensors/arm2link_accel.toml", tmp_path / str(k),
                                 controller=controller)
    # the estimator's plant and the controller from M(q) in both runs; the simulation
    # model M(q, delta) to first order without a controller, the controller's with one
    assert seen["build"] == [0, 0] and seen["plant"] == [0, 0] and seen["ctrl"] == [0]
    assert seen["bundle"] == [(1, "static"), (0, "static")]
