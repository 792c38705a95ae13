"""casflex.control.accessibility: modal system, controllability rank, accessibility indexes.

Independent check: accessibility and controllability rank against a finite-difference
linearisation of the model's ``ode``.
"""

import numpy as np
import pytest

from casflex import control
from casflex.moves import Move

Q_HORIZONTAL = np.array([0.0, 0.0, -np.pi / 2])
Q_ONE = np.array([0.0, 1.0, -np.pi / 2])
Q_VERTICAL = np.array([0.0, np.pi / 2, -np.pi / 2])


def fd_linearization(model, q, h=1e-6):
    """Central differences of the model's ode about rest at q (tau = 0, no gravity)."""
    f = model.functions()["ode"]
    n, m = model.n, model.m
    x0 = np.r_[q, np.zeros(m + n + m)]
    u0 = np.zeros(n)
    A = np.zeros((x0.size, x0.size))
    B = np.zeros((x0.size, n))
    for i in range(x0.size):
        e = np.zeros(x0.size)
        e[i] = h
        A[:, i] = (f(x0 + e, u0) - f(x0 - e, u0)).full().ravel() / (2 * h)
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        B[:, i] = (f(x0, u0 + e) - f(x0, u0 - e)).full().ravel() / (2 * h)
    return A, B


@pytest.mark.parametrize("q", [Q_HORIZONTAL, Q_ONE, Q_VERTICAL])
def test_accessibility_and_rank_against_finite_differences(elbow_model, q):
    model = elbow_model
    n, m = model.n, model.m
    A, B = fd_linearization(model, q)
    ddq_tau, ddd_tau = B[n + m:2 * n + m], B[2 * n + m:]
    # δ̈ = −M_qδᵀ q̈ − K δ at rest: −M_qδᵀ = (∂δ̈/∂τ)(∂q̈/∂τ)⁻¹
    Mqd_T = -ddd_tau @ np.linalg.inv(ddq_tau)
    a_fd = np.linalg.norm(Mqd_T, axis=1)
    np.testing.assert_allclose(control.accessibility(model, q), a_fd, atol=1e-6)
    # the stiffness of eq. 201: ∂(δ̈ + M_qδᵀ q̈)/∂δ = −K
    K_fd = -(A[2 * n + m:, n:n + m] + Mqd_T @ A[n + m:2 * n + m, n:n + m])
    Am, Bm = (x.full() for x in control.modal_system(model)(q))
    np.testing.assert_allclose(-Am[m:, :m], K_fd, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(Bm[m:], -Mqd_T, atol=1e-6)
    # ranks: eq. 203 on (A, B) and the full linearisation from τ (rigid modes included)
    inaccessible = int(np.sum(a_fd < 1e-6))
    _, rank, _ = control.controllability(model, q)
    assert rank == 2 * m - 2 * inaccessible
    # PBH test on the full linearisation: eigenvalues λ with rank [A − λI, B] < N
    scale = np.linalg.norm(np.hstack([A, B]), 2)
    lost = sum(np.linalg.svd(np.hstack([A - lam * np.eye(A.shape[0]), B]),
                             compute_uv=False)[-1] < 1e-9 * scale
               for lam in np.linalg.eigvals(A))
    assert lost == 2 * inaccessible
    if q is Q_VERTICAL:
        assert inaccessible == 2 and a_fd[1] > 0.1  # modes 1 and 3 (Fig. 120)


def test_accessibility_map_mode2_independent_of_shoulder(elbow_model):
    q2 = np.linspace(-np.pi, np.pi, 25)
    axes, a = control.accessibility_map(elbow_model, joints=(1, 2), axes=(q2, [-np.pi / 2]))
    assert a.shape == (3, 25, 1)
    a2 = a[1, :, 0]
    assert np.ptp(a2) < 1e-9 * a2.max()  # Fig. 120: a2 does not depend on q2
    # a1 and a3 fall to zero at the vertical configuration and are largest horizontal
    for k in (0, 2):
        assert control.accessibility(elbow_model, Q_VERTICAL)[k] < 1e-12
        assert control.accessibility(elbow_model, Q_HORIZONTAL)[k] > \
            control.accessibility(elbow_model, Q_ONE)[k] > 0.0


def test_accessibility_along_a_move(elbow_model):
    move = Move(Q_HORIZONTAL, Q_VERTICAL, 2.0)
    a = control.accessibility_along(elbow_model, move, [0.0, 1.0, 2.0])
    assert a[0, 0] > a[1, 0] > a[2, 0] and a[2, 0] < 1e-12
