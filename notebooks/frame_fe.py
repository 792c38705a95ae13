"""A short 3-D frame finite-element model of a robot: the notebooks' independent reference.

Notebooks 01 and 08 check casflex's transfer-matrix results against it. It shares no code
with casflex's physics: only the geometry of the arm (ends and section axes of every beam,
pose of every body) is read from casflex's chain. The test suite's fuller reference, with
joint springs and robots read from problem files, is ``tests/reference_fem.py``.
"""

import numpy as np
from scipy.linalg import eigh

from casflex.tmm import build_chain


def frame_fe(robot, q, n_modes=6, n_elements=40):
    """Natural frequencies [rad/s] and nodal displacements of a 3-D frame finite-element
    model of ``robot`` at ``q``: Euler–Bernoulli beams (axial, torsion, bending in two
    planes) with consistent mass, rigid bodies lumped at their nodes, clamped at the base
    (joint springs are not modelled).
    Only the geometry (ends and section axes of every beam, pose of every body) is read
    from casflex's chain. Displacements: (n_modes, n_beams, n_elements + 1, 3) [m·√kg⁻¹]."""
    nodes, beams, bodies = [], [], []

    def node(p):
        """Index of the node at ``p``: beams that meet share it."""
        for i, x in enumerate(nodes):
            if np.linalg.norm(x - p) < 1e-9:
                return i
        nodes.append(np.array(p, dtype=float))
        return len(nodes) - 1

    for e in build_chain(robot, q).elements:
        if e.kind == "beam":
            beams.append((e, [node(p) for p in np.linspace(e.start, e.end, n_elements + 1)]))
        elif e.kind == "body":
            bodies.append(e)
    K = np.zeros((6 * len(nodes), 6 * len(nodes)))
    M = np.zeros_like(K)
    bar, lin = np.array([[1.0, -1.0], [-1.0, 1.0]]), np.array([[2.0, 1.0], [1.0, 2.0]]) / 6

    def bending(L):
        k = np.array([[12, 6 * L, -12, 6 * L], [6 * L, 4 * L**2, -6 * L, 2 * L**2],
                      [-12, -6 * L, 12, -6 * L], [6 * L, 2 * L**2, -6 * L, 4 * L**2]]) / L**3
        m = np.array([[156, 22 * L, 54, -13 * L], [22 * L, 4 * L**2, 13 * L, -3 * L**2],
                      [54, 13 * L, 156, -22 * L], [-13 * L, -3 * L**2, -22 * L, 4 * L**2]])
        return k, m * L / 420

    for e, ids in beams:
        s, mat = e.params["section"], e.params["material"]
        ez = (e.end - e.start) / np.linalg.norm(e.end - e.start)   # beam axis
        ex = e.R[:, 0] - (e.R[:, 0] @ ez) * ez                       # section axes
        ex /= np.linalg.norm(ex)
        R = np.column_stack([ex, np.cross(ez, ex), ez])
        L = np.linalg.norm(e.end - e.start) / n_elements
        k, m = np.zeros((12, 12)), np.zeros((12, 12))
        # local DOFs (ux, uy, uz, rx, ry, rz) at both ends; the slope of ux is +ry, of uy −rx
        blocks = [((2, 8), mat.E * s.A / L * bar, mat.rho * s.A * L * lin, (1, 1)),
                  ((5, 11), mat.G * s.J / L * bar, mat.rho * s.Ip * L * lin, (1, 1))]
        kb, mb = bending(L)
        blocks += [((0, 4, 6, 10), mat.E * s.Iy * kb, mat.rho * s.A * mb, (1, 1, 1, 1)),
                   ((1, 3, 7, 9), mat.E * s.Ix * kb, mat.rho * s.A * mb, (1, -1, 1, -1))]
        for dofs, kk, mm, sign in blocks:
            sg = np.outer(sign, sign)
            k[np.ix_(dofs, dofs)] += kk * sg
            m[np.ix_(dofs, dofs)] += mm * sg
        T = np.kron(np.eye(4), R.T)   # global -> local, per 3-vector
        k, m = T.T @ k @ T, T.T @ m @ T
        for a, b in zip(ids[:-1], ids[1:], strict=True):
            idx = np.r_[6 * a:6 * a + 6, 6 * b:6 * b + 6]
            K[np.ix_(idx, idx)] += k
            M[np.ix_(idx, idx)] += m
    for e in bodies:
        p = e.params
        c = e.R @ p["com_offset"]
        C = np.array([[0, -c[2], c[1]], [c[2], 0, -c[0]], [-c[1], c[0], 0]])
        mb = p["mass"] * np.block([[np.eye(3), -C], [C, C.T @ C]])
        mb[3:, 3:] += e.R @ np.diag(p["inertia"]) @ e.R.T
        i = node(e.start)
        M[6 * i:6 * i + 6, 6 * i:6 * i + 6] += mb
    K, M = 0.5 * (K + K.T), 0.5 * (M + M.T)
    base = 6 * node(build_chain(robot, q).elements[0].start)
    free = np.setdiff1d(np.arange(K.shape[0]), np.arange(base, base + 6))   # clamped
    # M v = μ K v with μ = 1/ω²: the lowest modes are the largest μ, found to near machine
    # precision (K v = ω² M v loses digits to the stiff rotations of tiny rotary inertia)
    n = free.size
    mu, v = eigh(M[np.ix_(free, free)], K[np.ix_(free, free)],
                 subset_by_index=[n - n_modes, n - 1])
    v = v[:, ::-1] / np.sqrt(np.einsum("ik,ij,jk->k", v[:, ::-1], M[np.ix_(free, free)],
                                       v[:, ::-1]))   # mass-normalised
    full = np.zeros((K.shape[0], n_modes))
    full[free] = v
    u = full.reshape(len(nodes), 6, n_modes)[:, :3]
    return 1.0 / np.sqrt(mu[::-1]), np.array([[u[ids, :, j] for _, ids in beams]
                                              for j in range(n_modes)])
