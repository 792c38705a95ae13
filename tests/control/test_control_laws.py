"""casflex.control.laws: the tracking laws.

Independent check: eq. 210 written out term by term from the model's ``mass`` and
``coriolis`` functions against the controller. (The reference a law follows belongs to
casflex.moves and is tested in tests/test_moves.py.)
"""

import numpy as np

from casflex import control
from casflex.model import FlexibleModel, PointwiseProvider

Q_ONE = np.array([0.0, 1.0, -np.pi / 2])


def test_inversion_law_is_eq_210_at_zero_deflection(elbow_model, arm):
    model = FlexibleModel(arm, PointwiseProvider(arm, Q_ONE, count=3), gravity=None)
    f = model.functions()
    n, m = model.n, model.m
    rng = np.random.default_rng(1)
    ctrl = control.inversion_controller(model, Kp=1.0, Kd=2.0)
    for _ in range(3):
        q = Q_ONE + rng.normal(0, 0.3, n)
        dq, dd = rng.normal(0, 1, n), rng.normal(0, 0.1, m)
        qd, dqd, ddqd = rng.normal(0, 1, (3, n))
        x = np.r_[q, np.zeros(m), dq, dd]
        M = f["mass"](q, np.zeros(m)).full()
        C = f["coriolis"](q, np.zeros(m), dq, dd).full()
        Mqq, Mqd = M[:n, :n], M[:n, n:]
        v = ddqd + 2.0 * (dqd - dq) + 1.0 * (qd - q)
        # eq. 210 (δ = 0, so K δ = 0)
        tau = ((Mqq - Mqd @ Mqd.T) @ v + C[:n, :n] @ dq + C[:n, n:] @ dd
               - Mqd @ (C[n:, :n] @ dq + C[n:, n:] @ dd))
        np.testing.assert_allclose(ctrl(qd, dqd, ddqd, x).full().ravel(), tau, rtol=1e-9,
                                   atol=1e-12)
        # and the joints then follow v exactly
        ddq, _ = f["forward"](q, dq, np.zeros(m), dd, ctrl(qd, dqd, ddqd, x))
        np.testing.assert_allclose(ddq.full().ravel(), v, rtol=1e-8, atol=1e-10)
