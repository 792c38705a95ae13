"""An input shaper as a table for the real-time loop: C header and source.

A digital shaper (impulse times on the loop's sample grid, e.g. from
``casflex.shaping.si_shaper(..., dt=dt)``) becomes a table of delays in samples and
amplitudes, and a C function that shapes one reference sample per loop tick:
``y[k] = Σ A_i u[k - d_i]`` over a ring buffer of the last ``max(d) + 1`` inputs, the
reference being at rest at its initial value before the first tick (what
:func:`casflex.shaping.apply_shaper` assumes for positions).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from casflex._validate import identifier, number, output_directory
from casflex.errors import ProblemFileError
from casflex.shaping import Shaper

__all__ = ["shaper_table_bundle"]

#: How far (in samples) an impulse time may lie from the sample grid.
_GRID_TOL = 1e-6

_HEADER = """\
/* {name}: input shaper table, {n} impulses on a {dt!r} s sample grid (casflex). */
#ifndef {guard}
#define {guard}

#define {upper}_N_IMPULSES {n}
#define {upper}_HISTORY {history}

extern const int {name}_delays[{upper}_N_IMPULSES];        /* samples */
extern const double {name}_amplitudes[{upper}_N_IMPULSES];  /* sum 1 */

typedef struct {{
    double history[{upper}_HISTORY];  /* last inputs, ring buffer */
    int head;                         /* index of the newest input */
}} {name}_state;

/* Start at rest at the reference's initial value u0. */
void {name}_init({name}_state *s, double u0);
/* Push the reference sample u of this tick and return the shaped sample. */
double {name}_apply({name}_state *s, double u);

#endif
"""

_SOURCE = """\
#include "{name}.h"

const int {name}_delays[{upper}_N_IMPULSES] = {{{delays}}};
const double {name}_amplitudes[{upper}_N_IMPULSES] = {{{amplitudes}}};

void {name}_init({name}_state *s, double u0) {{
    int i;
    for (i = 0; i < {upper}_HISTORY; ++i) s->history[i] = u0;
    s->head = 0;
}}

double {name}_apply({name}_state *s, double u) {{
    int i;
    double y = 0.0;
    s->head = (s->head + 1) % {upper}_HISTORY;
    s->history[s->head] = u;
    for (i = 0; i < {upper}_N_IMPULSES; ++i) {{
        y += {name}_amplitudes[i]
             * s->history[(s->head - {name}_delays[i] + {upper}_HISTORY) % {upper}_HISTORY];
    }}
    return y;
}}
"""


def shaper_table_bundle(shaper: Shaper, dt: float, name: str,
                        directory: str | os.PathLike) -> dict[str, Path]:
    """Write ``<name>.h`` and ``<name>.c``: the shaper as a table and its C apply function.

    Parameters
    ----------
    shaper : casflex.shaping.Shaper
        A digital shaper: every impulse time (relative to the first) a whole number of
        samples ``dt`` (to 1e-6 of a sample), e.g. ``si_shaper(..., dt=dt).shaper``.
    dt : float
        Loop sample time, s.
    name : str
        C identifier: prefix of the files, the tables and the functions.
    directory : str or os.PathLike
        Output directory (created if needed).

    Returns
    -------
    dict
        ``{"header": Path, "source": Path}``.

    Raises
    ------
    ProblemFileError
        ``dt <= 0``, a bad ``name`` or ``directory``, or an impulse off the sample grid
        (naming it: design the shaper with ``si_shaper(..., dt=dt)``).

    Examples
    --------
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> files = shaper_table_bundle(Shaper([0.0, 0.003], [0.5, 0.5]), 1e-3, "zv1", d)
    >>> "zv1_delays[ZV1_N_IMPULSES] = {0, 3}" in files["source"].read_text()
    True
    """
    if not isinstance(shaper, Shaper):
        raise TypeError("shaper must be a casflex.shaping.Shaper")
    dt = number(dt, "dt", low=0.0, low_open=True, error=ProblemFileError)
    name = identifier(name, "name", error=ProblemFileError)
    out = output_directory(directory, "directory", error=ProblemFileError)
    steps = (shaper.times - shaper.times[0]) / dt
    delays = np.rint(steps).astype(int)
    off = np.abs(steps - delays)
    if np.any(off > _GRID_TOL):
        i = int(np.argmax(off))
        raise ProblemFileError(
            None, f"shaper.times[{i}]", float(shaper.times[i]),
            f"is not on the {dt!r} s sample grid ({steps[i]:.6f} samples): design the "
            "shaper with si_shaper(..., dt=dt)")
    # impulses on the same sample act as one
    keep, index = np.unique(delays, return_inverse=True)
    amps = np.zeros(keep.size)
    np.add.at(amps, index, shaper.amplitudes)
    upper = name.upper()
    fields = {"name": name, "upper": upper, "n": keep.size, "dt": dt,
              "history": int(keep[-1]) + 1, "guard": f"{upper}_SHAPER_TABLE_H",
              "delays": ", ".join(str(int(d)) for d in keep),
              "amplitudes": ", ".join(f"{a:.17g}" for a in amps)}
    out.mkdir(parents=True, exist_ok=True)
    header = out / f"{name}.h"
    source = out / f"{name}.c"
    header.write_text(_HEADER.format(**fields))
    source.write_text(_SOURCE.format(**fields))
    return {"header": header, "source": source}
