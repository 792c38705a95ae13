"""A planned move as a table for the real-time loop's reference: C header and source.

The trajectory of a :class:`casflex.planning.PlannedMove` is sampled on the loop's grid
``t_k = k dt`` (``k = 0 .. K``, ``K dt ≥ duration``) with :meth:`PlannedMove.sample`
(the plan's own discretisation) and written as constant tables of ``q``, ``q̇``, ``q̈``
[rad, rad/s, rad/s²] and the planned torques ``τ`` [N m], row-major, one row per sample.
Two C functions read it: ``<name>_row(k, ...)`` gives sample ``k`` (before the first
sample the start at rest, after the last the end at rest with the holding torque), and
``<name>_at(t, ...)`` interpolates linearly in time between samples (for a loop whose
clock is not on the table's grid).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from casflex._validate import identifier, number, output_directory
from casflex.errors import ProblemFileError

if TYPE_CHECKING:
    from casflex.planning import PlannedMove

__all__ = ["plan_table_bundle"]

_HEADER = """\
/* {name}: planned move '{move}' as a table, {rows} samples every {dt!r} s, {n} joints
   (casflex). Units: rad, rad/s, rad/s^2, N m; time s. */
#ifndef {guard}
#define {guard}

#define {upper}_N_JOINTS {n}
#define {upper}_N_SAMPLES {rows}
#define {upper}_DT {dt!r}
#define {upper}_DURATION {duration!r}

extern const double {name}_q[{upper}_N_SAMPLES * {upper}_N_JOINTS];
extern const double {name}_dq[{upper}_N_SAMPLES * {upper}_N_JOINTS];
extern const double {name}_ddq[{upper}_N_SAMPLES * {upper}_N_JOINTS];
extern const double {name}_tau[{upper}_N_SAMPLES * {upper}_N_JOINTS];
extern const double {name}_hold_tau[{upper}_N_JOINTS];

/* Sample k (k < 0: the start at rest; k >= N_SAMPLES: the end at rest, holding torque).
   Any output pointer may be NULL. */
void {name}_row(long k, double *q, double *dq, double *ddq, double *tau);
/* The reference at time t [s]: linear between the samples, at rest outside the move. */
void {name}_at(double t, double *q, double *dq, double *ddq, double *tau);

#endif
"""

_SOURCE = """\
#include "{name}.h"

const double {name}_q[{upper}_N_SAMPLES * {upper}_N_JOINTS] = {{
{q}}};
const double {name}_dq[{upper}_N_SAMPLES * {upper}_N_JOINTS] = {{
{dq}}};
const double {name}_ddq[{upper}_N_SAMPLES * {upper}_N_JOINTS] = {{
{ddq}}};
const double {name}_tau[{upper}_N_SAMPLES * {upper}_N_JOINTS] = {{
{tau}}};
const double {name}_hold_tau[{upper}_N_JOINTS] = {{{hold}}};

void {name}_row(long k, double *q, double *dq, double *ddq, double *tau) {{
    int j;
    int rest = k < 0 || k >= {upper}_N_SAMPLES;
    long r = k < 0 ? 0 : (k >= {upper}_N_SAMPLES ? {upper}_N_SAMPLES - 1 : k);
    for (j = 0; j < {upper}_N_JOINTS; ++j) {{
        long i = r * {upper}_N_JOINTS + j;
        if (q) q[j] = {name}_q[i];
        if (dq) dq[j] = rest ? 0.0 : {name}_dq[i];
        if (ddq) ddq[j] = rest ? 0.0 : {name}_ddq[i];
        if (tau) tau[j] = k < 0 ? {name}_tau[j] : (rest ? {name}_hold_tau[j] : {name}_tau[i]);
    }}
}}

void {name}_at(double t, double *q, double *dq, double *ddq, double *tau) {{
    double a[4][{upper}_N_JOINTS], b[4][{upper}_N_JOINTS];
    double *out[4];
    double s = t / {upper}_DT;
    long k;
    int i, j;
    if (t < 0.0 || s >= {upper}_N_SAMPLES - 1) {{
        {name}_row(t < 0.0 ? -1 : {upper}_N_SAMPLES, q, dq, ddq, tau);
        return;
    }}
    k = (long)s;
    s -= (double)k;
    {name}_row(k, a[0], a[1], a[2], a[3]);
    {name}_row(k + 1, b[0], b[1], b[2], b[3]);
    out[0] = q; out[1] = dq; out[2] = ddq; out[3] = tau;
    for (i = 0; i < 4; ++i) {{
        if (!out[i]) continue;
        for (j = 0; j < {upper}_N_JOINTS; ++j) out[i][j] = (1.0 - s) * a[i][j] + s * b[i][j];
    }}
}}
"""


def _numbers(values: np.ndarray) -> str:
    rows = values.reshape(values.shape[0], -1)
    return "".join("    " + ", ".join(f"{v:.17g}" for v in row) + ",\n" for row in rows)


def plan_table_bundle(plan: PlannedMove, dt: float, name: str,
                      directory: str | os.PathLike) -> dict[str, Path]:
    """Write ``<name>.h`` and ``<name>.c``: a planned move sampled on the loop's grid.

    Parameters
    ----------
    plan : casflex.planning.PlannedMove
        The plan (:func:`casflex.planning.plan_move`).
    dt : float
        Loop sample time [s]: the table holds ``t_k = k dt`` from 0 to the first sample
        at or after ``plan.duration``.
    name : str
        C identifier: prefix of the files, the tables and the functions.
    directory : str or os.PathLike
        Output directory (created if needed).

    Returns
    -------
    dict
        ``{"header": Path, "source": Path, "samples": int}``.

    Raises
    ------
    ProblemFileError
        ``dt <= 0`` or larger than the move, a bad ``name`` or ``directory``.

    Examples
    --------
    >>> import tempfile
    >>> from casflex.planning import PlannedMove
    >>> t = np.array([0.0, 1.0])
    >>> p = PlannedMove(t=t, q=np.c_[[0.0, 1.0]], dq=np.zeros((2, 1)),
    ...                 ddq=np.zeros((2, 1)), tau=np.zeros((2, 1)),
    ...                 delta=np.zeros((2, 0)), ddelta=np.zeros((2, 0)), node_t=t,
    ...                 node_x=np.zeros((2, 2)), node_tau=np.zeros((1, 1)),
    ...                 hold_torque=np.zeros(1))
    >>> files = plan_table_bundle(p, 0.25, "ref", tempfile.mkdtemp())
    >>> files["samples"], "#define REF_N_SAMPLES 5" in files["header"].read_text()
    (5, True)
    """
    from casflex.planning import PlannedMove

    if not isinstance(plan, PlannedMove):
        raise TypeError("plan must be a casflex.planning.PlannedMove")
    dt = number(dt, "dt", low=0.0, low_open=True, error=ProblemFileError)
    if dt > plan.duration:
        raise ProblemFileError(None, "dt", dt, f"must not exceed the move's duration "
                               f"{plan.duration!r} s")
    name = identifier(name, "name", error=ProblemFileError)
    out = output_directory(directory, "directory", error=ProblemFileError)
    # the last sample at or after the end: there the plan rests at qf
    rows = int(math.ceil(plan.duration / dt - 1e-9)) + 1
    t = np.arange(rows) * dt
    q, dq, ddq = plan.sample(t)
    law = plan.torque_law()
    tau = np.array([law(float(tk), None) for tk in t])
    upper = name.upper()
    fields = {"name": name, "upper": upper, "n": plan.n_joints, "rows": rows, "dt": dt,
              "duration": plan.duration, "move": plan.name,
              "guard": f"{upper}_PLAN_TABLE_H", "q": _numbers(q), "dq": _numbers(dq),
              "ddq": _numbers(ddq), "tau": _numbers(tau),
              "hold": ", ".join(f"{v:.17g}" for v in np.asarray(plan.hold_torque, float))}
    out.mkdir(parents=True, exist_ok=True)
    header, source = out / f"{name}.h", out / f"{name}.c"
    header.write_text(_HEADER.format(**fields))
    source.write_text(_SOURCE.format(**fields))
    return {"header": header, "source": source, "samples": rows}
