"""The point function's derivatives through its tables as Taylor polynomials
(casflex.planning.table_taylor) against central differences of the point function and
against CasADi's differentiation through the lookup calls, on the Table 8 arm's tables."""

import casadi as ca
import numpy as np
import pytest

from casflex.planning.derivatives import implicit_point_function, static_lookup
from casflex.planning.table_taylor import taylor_tables


@pytest.fixture(scope="module")
def tabled(arm_model):
    model, _ = arm_model(2, gravity=None, delta_order=0)
    return static_lookup(model)


def _bound_derivatives(phi):
    t = taylor_tables(phi)
    w = ca.SX.sym("w", phi.size1_in(0))
    c, P = ca.SX.sym("c"), ca.SX.sym("P", t.lookup.nnz_out(0))
    y = t.function.call([w, c, P])[0]
    mu = ca.SX.sym("mu", y.shape[0])
    J = t.bind(ca.jacobian(y, w), c, P, w)
    H = t.bind(ca.hessian(ca.dot(mu, y), w)[0], c, P, w)
    return ca.Function("d", [w, mu], [t.bind(y, c, P, w), ca.densify(J), ca.densify(H)]), t


def _direct_derivatives(phi):
    w = ca.SX.sym("w", phi.size1_in(0))
    y = phi(w)
    mu = ca.SX.sym("mu", y.shape[0])
    return ca.Function("d0", [w, mu], [y, ca.densify(ca.jacobian(y, w)),
                                       ca.densify(ca.hessian(ca.dot(mu, y), w)[0])])


@pytest.mark.parametrize("scenarios", [0, 2])
def test_taylor_tables_give_the_point_derivatives(tabled, scenarios):
    """At random points of the arm's working range: the values equal ``φ``'s to 1e-11 of
    the largest, the Jacobian equals central differences of ``φ`` (step 1e-6: 1e-6 of
    the largest entry; an independent reference) and CasADi's Jacobian through the
    lookup calls to 1e-8; the Hessian equals CasADi's to 1e-5 of the largest entry — the
    spread of CasADi's own Hessian through the calls, measured by taking it two ways
    (``hessian`` and the Jacobian of ``Jᵀμ``), is 7e-7 on move 1's model, where the
    Taylor form's two ways agree to 5e-16. The derivatives call no table function but
    the lookup of the values and their first three derivatives."""
    phi = implicit_point_function(tabled, scenarios)
    new, t = _bound_derivatives(phi)
    old = _direct_derivatives(phi)
    assert t.lookup.nnz_out(0) % 4 == 0
    calls = [new.instructions_sx()[k].which_function().name()
             for k in range(new.n_instructions()) if new.instruction_id(k) == ca.OP_CALL]
    assert set(calls) == {t.lookup.name()}
    rng = np.random.default_rng(8)
    nw = phi.size1_in(0)
    for _ in range(4):
        w = rng.normal(size=nw) * 0.3
        mu = rng.normal(size=phi.size1_out(0))
        (y1, J1, H1), (y0, J0, H0) = ([np.asarray(v) for v in f(w, mu)] for f in (new, old))
        assert np.abs(y1 - y0).max() <= 1e-11 * np.abs(y0).max()
        assert np.abs(J1 - J0).max() <= 1e-8 * np.abs(J0).max()
        assert np.abs(H1 - H0).max() <= 1e-5 * np.abs(H0).max()
        h = 1e-6
        fd = np.array([(np.asarray(phi(w + h * e)) - np.asarray(phi(w - h * e))).ravel()
                       / (2 * h) for e in np.eye(nw)]).T
        assert np.abs(J1 - fd).max() <= 1e-6 * np.abs(J1).max()


def test_taylor_tables_leave_other_functions_alone(onelink_point):
    """Without tables (the one-link arm's pointwise modes) there is nothing to replace."""
    assert taylor_tables(onelink_point) is None


@pytest.fixture
def onelink_point():
    from casflex.model import FlexibleModel, PointwiseProvider
    from casflex.robot import load

    robot = load("problems/onelink.toml")
    return implicit_point_function(
        FlexibleModel(robot, PointwiseProvider(robot, [0.0], count=1), gravity=None), 0)
