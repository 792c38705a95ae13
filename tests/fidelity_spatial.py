"""Spatial fidelity case: casflex's modal model against the 3-D beam reference (issue 19).

Shared by ``tests/model/test_spatial_fidelity.py`` and ``benchmarks/bench_fidelity.py
--spatial``. The reference (:mod:`reference_beam_3d`, Exudyn's geometrically exact
beams) knows nothing of casflex; this module runs both on the same move and compares tip
deflections.

Tip deflection, identical on both sides: the tip's position minus the rigid tip at the
same joint angles, in the base frame [m] (3 components). Figures of merit as in
``fidelity_cases.compare``: the peak ``max |d|``, the residual ``max |d|`` after the move,
and the worst gap ``max |d_model − d_ref|`` in % of the reference's peak.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from reference_beam_3d import JointMove, cached_run

#: Table 9 move 3 (problems/moves.toml): q1 0 → −π rad in 2 s, q2 and q3 held at 0
MOVE3 = JointMove((0.0, 0.0, 0.0), (-np.pi, 0.0, 0.0), 2.0, settle=3.0)

#: the converged reference of the comparison (elements per link, step [s]): 16 → 32
#: elements moves the tip deflection by 0.64 % of the peak (O(h²): 32 → 64 by ~0.16 %),
#: 1 → 0.5 ms by < 0.01 % (test_spatial_reference.py, benchmarks/README_fidelity.md)
REFERENCE = {"n_elements": 32, "dt": 1e-3}

#: the test data: converged reference runs, keyed by the reference's source (cached_run)
DATA = Path(__file__).parent / "data" / "reference_beam_3d"


def reference_run(move: JointMove = MOVE3, n_elements: int = REFERENCE["n_elements"],
                  dt: float = REFERENCE["dt"], cache: Path | None = DATA
                  ) -> dict[str, np.ndarray]:
    """The reference's tip deflection ``{"t", "d"}`` [s, m] (stored in ``cache``)."""
    return cached_run(move, n_elements, dt, cache=cache)


def casflex_run(model, move: JointMove = MOVE3, dt: float = 1e-3, method: str = "rk4"
                ) -> dict[str, np.ndarray]:
    """casflex's tip deflection ``{"t", "d"}`` for the same move (prescribed joints)."""
    from casflex.moves import Move
    from casflex.simulate import simulate_prescribed

    cmove = Move(np.asarray(move.q0), np.asarray(move.qf), move.duration,
                 settle=move.settle)
    res = simulate_prescribed(model, cmove, dt=dt, method=method)
    return {"t": res.t, "d": np.asarray(res.tip_deflection)}


def on_grid(run: dict[str, np.ndarray], t: np.ndarray) -> np.ndarray:
    """Deflection of ``run`` at the times ``t`` (linear interpolation per component)."""
    return np.column_stack([np.interp(t, run["t"], run["d"][:, k])
                            for k in range(run["d"].shape[1])])


def compare(model_run: dict, ref_run: dict, t_move_end: float) -> dict[str, float]:
    """Peak, residual and worst gap of ``model_run`` against ``ref_run`` (3-D), on the
    model's time grid: ``peak_pct``, ``residual_pct`` signed relative differences in % of
    the reference's value, ``gap_pct`` ``max_t |d_m − d_r|`` in % of the reference's peak.
    """
    t = model_run["t"]
    dm, dr = model_run["d"], on_grid(ref_run, t)
    nm, nr = np.linalg.norm(dm, axis=1), np.linalg.norm(dr, axis=1)
    after = t >= t_move_end - 1e-12
    peak_r, peak_m = nr.max(), nm.max()
    res_r, res_m = nr[after].max(), nm[after].max()
    gap = np.linalg.norm(dm - dr, axis=1)
    return {"peak_ref_mm": 1e3 * peak_r, "peak_pct": 100 * (peak_m / peak_r - 1),
            "residual_ref_mm": 1e3 * res_r, "residual_pct": 100 * (res_m / res_r - 1),
            "gap_pct": 100 * gap.max() / peak_r, "gap_at_s": float(t[np.argmax(gap)])}
