"""Planar fidelity cases: casflex's modal model against the ANCF reference.

Shared by ``tests/model/test_model_fidelity.py`` and ``benchmarks/bench_fidelity.py``.
The reference (:mod:`reference_beam_dynamics`) knows nothing of casflex; this module maps
the Table 8 arm and its moves into the reference's plane and compares tip deflections.

Plane of the moves (q1 held at 0): the base x0–z0 plane, written as ``(x, −z)``. Joint 2
turns about +y0, so in these coordinates link 1 points at the angle ``θ1 = q2``; link 2
points at ``θ1 + φ`` with ``φ = q3 + π/2`` (at q = 0 the arm is an L: link 1 along x0,
link 2 down −z0).

Tip deflection, identical on both sides: the in-plane displacement of the tip relative to
the rigid tip at the same joint angles, ``d(t) = tip − tip_rigid`` as an ``(x, −z)``
vector [m]. Figures of merit: the peak ``max |d|``, the residual ``max |d|`` after the
move ends, and the worst gap ``max |d_model − d_ref|`` over the time history, in % of the
reference's peak.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from reference_beam_dynamics import BangBang, PlanarBeam, TwoLinkArm

# Table 8 arm (problems/arm2link.toml): aluminium links of 1 m, 5 mm (along the joint
# axes) x 7 mm (in the plane of motion) rectangular section; in-plane bending uses the
# second moment a b³/12 about the joint axis.
E, RHO, SEC_A, SEC_B, LENGTH = 69.0e9, 2700.0, 0.005, 0.007, 1.0
BEAM = PlanarBeam(LENGTH, E * SEC_A * SEC_B, E * SEC_A * SEC_B**3 / 12.0,
                  RHO * SEC_A * SEC_B)


@dataclass(frozen=True)
class PlanarMove:
    """q2 and q3 from 0 to ``q2f``, ``q3f`` [rad] in ``duration`` [s], then ``settle`` [s]."""

    name: str
    q2f: float
    q3f: float
    duration: float
    settle: float = 3.0

    @property
    def t_end(self) -> float:
        return self.duration + self.settle


MOVES = {
    "move2": PlanarMove("move2", -1.0, -1.0, 2.0),           # Table 9 move 2
    "elbow2_1s": PlanarMove("elbow2_1s", -0.8, 1.2, 1.0),    # elbow travel 2 rad in 1 s
    "elbow2_2s": PlanarMove("elbow2_2s", -0.8, 1.2, 2.0),    # ... in 2 s
}


#: single-joint moves that separate the causes (q3 held: the shapes do not change)
DIAGNOSTIC_MOVES = {
    "shoulder_1s": PlanarMove("shoulder_1s", -1.0, 0.0, 1.0),
    "shoulder_half_1s": PlanarMove("shoulder_half_1s", -0.5, 0.0, 1.0),
    "shoulder_2s": PlanarMove("shoulder_2s", -1.0, 0.0, 2.0),
    "elbow_1s": PlanarMove("elbow_1s", 0.0, 1.2, 1.0),
}


def reference_run(move: PlanarMove, n_elements: int = 16, dt: float = 1e-3,
                  cache: Path | None = None) -> dict[str, np.ndarray]:
    """Reference tip deflection ``{"t", "d"}`` [s, m], cached as ``.npz`` under ``cache``."""
    source = (Path(__file__).parent / "reference_beam_dynamics.py").read_bytes()
    key = hashlib.sha256(source + repr((move, n_elements, dt, BEAM)).encode()).hexdigest()
    path = None if cache is None else Path(cache) / f"ancf-{key[:20]}.npz"
    if path is not None and path.exists():
        with np.load(path) as z:
            return {"t": z["t"], "d": z["d"]}
    arm = TwoLinkArm((BEAM, BEAM), n_elements)
    run = arm.simulate(BangBang(0.0, move.q2f, move.duration),
                       BangBang(0.5 * np.pi, 0.5 * np.pi + move.q3f, move.duration),
                       move.t_end, dt)
    out = {"t": run["t"], "d": run["tip"] - run["tip_rigid"]}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **out)
        tmp.replace(path)
    return out


def casflex_run(model, move: PlanarMove, dt: float = 1e-3, method: str = "rk4"
                ) -> dict[str, np.ndarray]:
    """casflex's tip deflection ``{"t", "d"}`` for the same move (prescribed joints)."""
    from casflex.moves import Move
    from casflex.simulate import simulate_prescribed

    cmove = Move(np.zeros(3), np.array([0.0, move.q2f, move.q3f]), move.duration,
                 settle=move.settle)
    res = simulate_prescribed(model, cmove, dt=dt, method=method)
    d3 = res.tip_deflection
    return {"t": res.t, "d": np.column_stack([d3[:, 0], -d3[:, 2]]),
            "out_of_plane": np.abs(d3[:, 1]).max()}


def on_grid(run: dict[str, np.ndarray], t: np.ndarray) -> np.ndarray:
    """Deflection of ``run`` at the times ``t`` (linear interpolation per component)."""
    return np.column_stack([np.interp(t, run["t"], run["d"][:, k]) for k in range(2)])


def link2_direction(move: PlanarMove, t: np.ndarray) -> np.ndarray:
    """Unit vector along the rigid link 2 at the times ``t``, (N, 2)."""
    th = np.array([BangBang(0.0, move.q2f, move.duration)(x)[0] for x in t])
    ph = np.array([BangBang(0.5 * np.pi, 0.5 * np.pi + move.q3f, move.duration)(x)[0]
                   for x in t])
    return np.column_stack([np.cos(th + ph), np.sin(th + ph)])


def compare(model_run: dict, ref_run: dict, t_move_end: float,
            move: PlanarMove | None = None) -> dict[str, float]:
    """Peak, residual and worst gap of ``model_run`` against ``ref_run``.

    ``peak_pct`` and ``residual_pct`` are signed relative differences (model − reference)
    in % of the reference's value; ``gap_pct`` is ``max_t |d_m − d_r|`` in % of the
    reference's peak. Both runs are compared on the model's time grid.
    """
    t = model_run["t"]
    dm, dr = model_run["d"], on_grid(ref_run, t)
    nm, nr = np.linalg.norm(dm, axis=1), np.linalg.norm(dr, axis=1)
    after = t >= t_move_end - 1e-12
    peak_r, peak_m = nr.max(), nm.max()
    res_r, res_m = nr[after].max(), nm[after].max()
    gap = np.linalg.norm(dm - dr, axis=1)
    out = {"peak_ref_mm": 1e3 * peak_r, "peak_pct": 100 * (peak_m / peak_r - 1),
           "residual_ref_mm": 1e3 * res_r, "residual_pct": 100 * (res_m / res_r - 1),
           "gap_pct": 100 * gap.max() / peak_r, "gap_at_s": float(t[np.argmax(gap)])}
    if move is not None:
        u = link2_direction(move, t)
        normal = np.column_stack([-u[:, 1], u[:, 0]])
        out["gap_along_pct"] = 100 * np.abs(((dm - dr) * u).sum(1)).max() / peak_r
        out["gap_normal_pct"] = 100 * np.abs(((dm - dr) * normal).sum(1)).max() / peak_r
    return out
