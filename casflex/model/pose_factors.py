"""The pose of a flexible link's base frame as a product of small factors.

:class:`~casflex.model.FlexibleModel` builds each DH row's transform as one 4 × 4
expression (``model.A``) and the pose of a beam's base frame as their product. A
recursive pass over the chain (the accelerometers of :mod:`casflex.sensors` carry a point
inward with the product rule, ``p̈ ← F̈ p + 2 Ḟ ṗ + F p̈``) is cheapest on the finest
factors: one per rotation, translation and beam end, so that most of them depend on one
joint angle or on ``δ`` alone. :func:`pose_factors` rebuilds that chain from the robot's
rows and the model's tables and checks its product against the model's own pose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from casflex.model.strain_kinematics import rod_nodes

if TYPE_CHECKING:
    from casflex.model.equations import FlexibleModel

__all__ = ["pose_factors"]

#: constant entries below this are the round-off of cos 90° and the like: made exact zeros
ROUND_OFF = 1e-15


def _rotation(angle, axis):
    c, s, R = ca.cos(angle), ca.sin(angle), ca.SX.eye(4)
    i, j = (1, 2) if axis == "x" else (0, 1)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _translation(v):
    return ca.vertcat(ca.horzcat(ca.SX.eye(3), ca.SX(v)), ca.DM([[0, 0, 0, 1]]))


def _filled(model, key):
    """The model's quantity ``key`` at its shape joints (its structural zeros kept)."""
    shared = getattr(model, "table_values", None)
    v = shared[key] if shared is not None and key in shared else \
        ca.SX(model.provider.function(key)(model.q_shape))
    return ca.vertcat(*[0 if model.Q[key][i].is_zero() else v[i] for i in range(v.numel())])


def pose_factors(model: FlexibleModel, row: int, placeholders: bool = False
                 ) -> tuple[list[ca.SX], int] | None:
    """Factors of the pose of the base frame of the beam on DH row ``row``.

    One factor per rotation (``α``, ``θ + q``, the section's turn), translation and beam
    end of the rows up to that beam, constant neighbours merged and their round-off
    entries (|x| < :data:`ROUND_OFF`, e.g. cos 90°) exact zeros; the product is checked
    against the model's pose at a random point (1e-12 of its size).

    Parameters
    ----------
    model : casflex.model.FlexibleModel
        Truncated (first-order beam ends) or exact kinematics (the rods' end frames).
    row : int
        DH row (0-based) of a flexible link.
    placeholders : bool
        The table quantities as the model's placeholder symbols ``model.Q`` (the pose of
        :meth:`~casflex.model.FlexibleModel.rebuilt_kinematics`); ``False``: filled with
        their values at the shape joints, as in ``model.T``.

    Returns
    -------
    (list of casadi.SX, int) or None
        The 4 × 4 factors and the number ``k`` of leading rigid ones (no ``δ``, exact
        rotations: their product ``L`` has ``Lᵀ L = I``); ``None`` where the chain is not
        rebuilt (joint springs, foreshortening) or its product misses the model's pose.

    Examples
    --------
    >>> from casflex.model import FlexibleModel, PointwiseProvider
    >>> from casflex.robot import load
    >>> robot = load("problems/arm2link.toml")
    >>> model = FlexibleModel(robot, PointwiseProvider(robot, [0, 0, 0], count=2))
    >>> factors, k = pose_factors(model, 3)   # link 2, behind link 1's deflection
    >>> len(factors), k   # q1, q2 and the fixed turns: 5 rigid; then link 1's end and q3
    (9, 5)
    """
    robot, m, d = model.robot, model.m, model.delta
    if getattr(model, "foreshortening", False) or any(
            link.joint_stiffness is not None for link in robot.links[:row + 1]):
        return None

    def quantity(key):
        return model.Q[key] if placeholders else _filled(model, key)

    def end(b, link):  # the beam's end transform, as the model's
        if getattr(model, "kinematics", "truncated") == "exact":
            return rod_nodes(link, b, quantity("sample_u"), quantity("sample_theta"), d)["end"]
        u, th = (sum((d[j] * v[(b * m + j) * 3:(b * m + j) * 3 + 3] for j in range(m)),
                     ca.SX.zeros(3)) for v in (quantity("end_u"), quantity("end_theta")))
        E = _translation(u + ca.DM([0, 0, link.length]))
        E[:3, :3] = ca.SX.eye(3) + ca.skew(th)
        return E

    joint = {r: k for k, r in enumerate(robot.joint_rows)}
    factors, b = [], 0
    for r, link in enumerate(robot.links[:row + 1]):
        factors.append(_rotation(link.alpha, "x"))
        for along, shift in (("a", [link.a, 0, 0]), ("d", [0, 0, link.d])):
            if along == "d":
                factors.append(_rotation(link.theta + (model.q[joint[r]] if r in joint else 0),
                                         "z"))
            if link.beam_along != along:
                if shift[0] or shift[2]:
                    factors.append(_translation(shift))
                continue
            P = _rotation(link.section_angle, "z")
            P = P if along == "d" else ca.DM(np.eye(4)[[2, 0, 1, 3]]) @ P
            if r == row:
                factors.append(P)
                break
            factors += [P, end(b, link), P.T]
            b += 1
    merged = []
    for F in map(ca.SX, factors):
        if merged and F.is_constant() and merged[-1].is_constant():
            F = ca.SX(ca.DM(merged.pop()) @ ca.DM(F))
        merged.append(F)
    for i, F in enumerate(merged):
        if F.is_constant():
            D = np.array(ca.DM(F))
            merged[i] = ca.SX(np.where(np.abs(D) < ROUND_OFF, 0.0, D))
    k = next((i for i, F in enumerate(merged) if ca.depends_on(F, d)), len(merged))
    T, L = ca.SX.eye(4), ca.SX.eye(4)
    for i, F in enumerate(merged):
        T = T @ F
        L = T if i < k else L
    ref = next(body["T"] for body in model.bodies
               if body["kind"] == "beam" and body["row"] == row)
    syms = ca.symvar(ca.veccat(T, ref, L))
    check = ca.Function("check", syms, [T - ref, ref, L[:3, :3].T @ L[:3, :3] - ca.DM.eye(3)])
    dev, size, ortho = (np.max(np.abs(np.array(v))) for v in check(
        *np.random.default_rng(0).normal(scale=0.3, size=len(syms))))
    if not dev <= 1e-12 * (1.0 + size):  # (NaN fails too)
        return None
    return merged, (k if ortho <= 1e-12 else 0)
