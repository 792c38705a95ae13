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
import inspect
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


#: the move of the small-and-slow test, where the modal model's theory holds
SMALL_SLOW = PlanarMove("small_slow", -0.05, 0.06, 2.0, settle=1.0)
#: the move of the reference's convergence test (elbow2_1s with a shorter settle)
CONVERGENCE_MOVE = PlanarMove("elbow2_1s_short", -0.8, 1.2, 1.0, settle=1.0)

#: committed reference runs, ``ancf-<key>.npz`` (see :func:`reference_key`)
STORED_RUNS_DIR = Path(__file__).parent / "reference_runs"
#: the runs stored there: (move, elements per link, step [s]) — the fidelity and
#: convergence tests' and notebook 02's (8 elements). ``python tests/fidelity_cases.py``
#: computes the missing ones and removes the stale ones.
STORED_RUNS = (
    *((move, 16, 1e-3) for move in MOVES.values()),
    (SMALL_SLOW, 16, 1e-3),
    (CONVERGENCE_MOVE, 16, 1e-3),
    (CONVERGENCE_MOVE, 32, 1e-3),
    (CONVERGENCE_MOVE, 16, 5e-4),
    (MOVES["move2"], 8, 1e-3),
    (MOVES["elbow2_1s"], 8, 1e-3),
)


def compute_reference_run(move: PlanarMove, n_elements: int, dt: float
                          ) -> dict[str, np.ndarray]:
    """Reference tip deflection ``{"t", "d"}`` [s, m], computed from scratch."""
    arm = TwoLinkArm((BEAM, BEAM), n_elements)
    run = arm.simulate(BangBang(0.0, move.q2f, move.duration),
                       BangBang(0.5 * np.pi, 0.5 * np.pi + move.q3f, move.duration),
                       move.t_end, dt)
    return {"t": run["t"], "d": run["tip"] - run["tip_rigid"]}


def reference_key(move: PlanarMove, n_elements: int, dt: float) -> str:
    """Key of a reference run: a hash of the reference's source
    (``reference_beam_dynamics.py``), of :func:`compute_reference_run` and of the run's
    parameters (move, elements, step, beam). Any change to them gives a new key, so a
    stored run is never used for a reference that differs from it."""
    source = (Path(__file__).parent / "reference_beam_dynamics.py").read_bytes()
    source += inspect.getsource(compute_reference_run).encode()
    params = repr((move, n_elements, dt, BEAM)).encode()
    return hashlib.sha256(source + params).hexdigest()[:20]


def _stored_name(move: PlanarMove, n_elements: int, dt: float) -> str:
    return f"ancf-{reference_key(move, n_elements, dt)}.npz"


def _read_run(path: Path, dt: float) -> dict[str, np.ndarray]:
    """A run written by :func:`_write_run`; its times are ``k dt`` as in the simulation."""
    with np.load(path) as z:
        d = z["d"]
    return {"t": np.arange(len(d)) * dt, "d": d}


def _write_run(path: Path, run: dict[str, np.ndarray], params: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, d=run["d"], params=np.array(params))
    tmp.replace(path)


def reference_run(move: PlanarMove, n_elements: int = 16, dt: float = 1e-3,
                  cache: Path | None = None) -> dict[str, np.ndarray]:
    """Reference tip deflection ``{"t", "d"}`` [s, m]: the committed run of
    :data:`STORED_RUNS_DIR` when its key is current, else one cached as ``.npz`` under
    ``cache``, else computed (and then cached under ``cache``)."""
    name = _stored_name(move, n_elements, dt)
    for directory in (STORED_RUNS_DIR, cache):
        if directory is not None and (Path(directory) / name).exists():
            return _read_run(Path(directory) / name, dt)
    out = compute_reference_run(move, n_elements, dt)
    if cache is not None:
        _write_run(Path(cache) / name, out, repr((move, n_elements, dt)))
    return out


def stale_stored_runs() -> tuple[list[str], list[str]]:
    """``(missing, stale)``: stored runs of :data:`STORED_RUNS` without a file under the
    current key, and files of :data:`STORED_RUNS_DIR` that no current run uses."""
    wanted = {_stored_name(*run) for run in STORED_RUNS}
    present = {p.name for p in STORED_RUNS_DIR.glob("ancf-*.npz")}
    missing = [repr((m.name, ne, dt)) for m, ne, dt in STORED_RUNS
               if _stored_name(m, ne, dt) not in present]
    return missing, sorted(present - wanted)


def store_reference_runs(processes: int = 2) -> None:
    """Compute the missing runs of :data:`STORED_RUNS` into :data:`STORED_RUNS_DIR` (in
    ``processes`` processes) and remove the stale files."""
    from casflex._parallel import parallel_map

    wanted = {_stored_name(*run): run for run in STORED_RUNS}
    for path in STORED_RUNS_DIR.glob("ancf-*.npz"):
        if path.name not in wanted:
            path.unlink()
    todo = [(name, run) for name, run in wanted.items()
            if not (STORED_RUNS_DIR / name).exists()]
    # longest first (elements × steps) so that the two processes end together
    jobs = sorted(todo, key=lambda job: -job[1][1] * job[1][0].t_end / job[1][2])
    for name, out in parallel_map(compute_reference_run, jobs, processes=processes,
                                  chunksize=1, progress=True, desc="reference runs"):
        move, ne, dt = wanted[name]
        _write_run(STORED_RUNS_DIR / name, out, repr((move, ne, dt)))


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


if __name__ == "__main__":
    # through the module's own name, so that the process pool pickles its functions by it
    import fidelity_cases

    fidelity_cases.store_reference_runs()
