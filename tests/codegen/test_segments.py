"""Long SX functions cut into pieces for the C compiler (``casflex.codegen.segments``) and
the model bundle's tables limited to what its dynamics read
(``casflex.codegen.model_reads``): the same numbers, bit for bit, as the uncut function
and the full model, in CasADi's VM and in C."""

import casadi as ca
import numpy as np
import pytest

from casflex import codegen
from casflex.codegen.model_reads import quantities_read, reading_model
from casflex.codegen.segments import pieces, segmented
from casflex.errors import ModelError
from casflex.model import FlexibleModel, TableProvider


def _chain():
    """An SX function of 1 000+ instructions with every kind of node the models have:
    unary and binary operations, constants, a call of an MX interpolant (the models'
    static table lookup), of a B-spline's derivative and of an SX function, a sparse and
    a dense output, an output entry that is a plain input and one that is a constant."""
    x, y = ca.SX.sym("x", 3), ca.SX.sym("y", 2, 2)
    grid = np.linspace(-4.0, 4.0, 9)
    table = ca.interpolant("table", "linear", [grid], np.c_[np.sin(grid), grid**2].ravel("F"))
    z = ca.SX.sym("z")
    twist = ca.Function("twist", [z], [ca.atan2(ca.sin(z), 1.5 + ca.cos(z))])
    v = ca.vertcat(x, y[0, 1])
    for k in range(60):
        lookup = table(ca.tanh(v[k % 4]))
        v = ca.vertcat(v[1] * lookup[0] - ca.sqrt(1.0 + v[2] ** 2),
                       v[2] / (2.0 + ca.cos(v[0])) + lookup[1],
                       twist(v[3] + 0.1 * k),
                       ca.exp(-v[0] ** 2) * y[1, 0] + v[1])
    # a B-spline and its derivative: CasADi's AD calls a derivative function of the
    # B-spline, which has no scalar (SX) form and must stay a call
    spline = ca.interpolant("spline", "bspline", [grid], np.cos(grid))
    v[3] = v[3] * ca.jacobian(spline(ca.tanh(x[0]) + 0.3 * x[1]), x)[1]
    sparse = ca.SX(ca.Sparsity.lower(3))
    sparse[0, 0], sparse[1, 0], sparse[2, 1] = v[0], x[1], 2.0
    sparse[1, 1], sparse[2, 2], sparse[2, 0] = v[1] * v[2], ca.sumsqr(v), v[3]
    return ca.Function("chain", [x, y], [sparse, ca.vertcat(v, ca.sum1(x))],
                       ["x", "y"], ["L", "v"])


def _args(rng):
    return [rng.normal(size=3), rng.normal(size=(2, 2))]


def test_pieces_give_the_uncut_function_bit_for_bit():
    f = _chain()
    assert f.n_instructions() > 1000
    for size in (1, 97, 500):
        g = segmented(f, size)
        assert (g.name(), g.name_in(), g.name_out()) == (f.name(), f.name_in(), f.name_out())
        assert g.sparsity_out(0) == f.sparsity_out(0)
        parts = pieces(g)
        # (a piece whose values all have other sources, inputs and constants, is dropped)
        assert 1 < len(parts) <= -(-f.n_instructions() // size)
        for p in parts:   # at most `size` operations, plus its I/O and constants
            assert sum(p.instruction_id(k) not in (ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST)
                       for k in range(p.n_instructions())) <= size
        rng = np.random.default_rng(size)
        for _ in range(4):
            args = _args(rng)
            for a, b in zip(f(*args), g(*args), strict=True):
                assert np.array_equal(a.full(), b.full())
    assert segmented(f, f.n_instructions()) is f   # short enough: unchanged
    with pytest.raises(ModelError, match="max_instructions must be an integer >= 1"):
        segmented(f, 0)


@pytest.mark.needs_cc
def test_pieces_in_c_are_the_uncut_function_in_c(tmp_path):
    f = _chain()
    both = codegen.generate([f, ca.Function("cut", *_ports(segmented(f, 400)))], tmp_path,
                            name="pieces")
    lib = codegen.build(both, flags=("-O0",))
    whole, cut = codegen.load(lib, "chain"), codegen.load(lib, "cut")
    rng = np.random.default_rng(7)
    for _ in range(4):
        args = _args(rng)
        for a, b in zip(whole(*args), cut(*args), strict=True):
            assert np.array_equal(a.full(), b.full())


def _ports(g):
    ins = [ca.MX.sym(g.name_in(i), g.sparsity_in(i)) for i in range(g.n_in())]
    return ins, g.call(ins), g.name_in(), g.name_out()


@pytest.mark.slow
def test_model_bundle_reads_only_the_tables_of_its_dynamics(arm_model, accel_sensors):
    model, table = arm_model(2, step_deg=15, points=accel_sensors.points)
    static = FlexibleModel(model.robot, TableProvider(table, lookup="static"),
                           gravity="robot")
    read = quantities_read(static)
    # the sensor points' quantities are the sensors', not the dynamics'
    assert {"C1", "C2", "omega"} <= set(read)
    assert not any(k.startswith("point_") for k in read)
    lean = reading_model(static)
    ref, got = static.functions(), lean.functions()
    rng = np.random.default_rng(3)
    for _ in range(4):
        q, d = rng.uniform(-3, 3, 3), 1e-2 * rng.normal(size=2)
        assert np.array_equal(ref["mass"](q, d).full(), got["mass"](q, d).full())
        args = [q, rng.normal(size=3), d, rng.normal(size=2), rng.normal(size=3)]
        for a, b in zip(ref["forward"](*args), got["forward"](*args), strict=True):
            assert np.array_equal(a.full(), b.full())
