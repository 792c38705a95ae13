"""The shaper table bundle: C shaping equals a convolution written here, off-grid refused."""

import math
import subprocess

import numpy as np
import pytest

from casflex.codegen.compiler import find_compiler, run_compiler
from casflex.codegen.shaper_table import shaper_table_bundle
from casflex.errors import ProblemFileError
from casflex.shaping import FrequencyRange, Shaper, si_shaper

MAIN = r"""
#include <stdio.h>
#include "tab.h"
int main(void) {
    tab_state s;
    double u;
    int first = 1;
    while (scanf("%lf", &u) == 1) {
        if (first) { tab_init(&s, u); first = 0; }
        printf("%.17g\n", tab_apply(&s, u));
    }
    return 0;
}
"""


def shaped_reference(delays, amps, u):
    """y[k] = Σ A_i u[k - d_i], the input held at u[0] before the first sample."""
    y = np.zeros_like(u)
    for d, a in zip(delays, amps, strict=True):
        y += a * np.concatenate([np.full(d, u[0]), u[: u.size - d]])
    return y


@pytest.mark.needs_cc
def test_c_table_shapes_like_the_convolution(tmp_path):
    dt = 1e-3
    hz = 2 * math.pi
    shaper = si_shaper([FrequencyRange(3 * hz, 4 * hz, 0.0, 0.05)], dt=dt).shaper
    files = shaper_table_bundle(shaper, dt, "tab", tmp_path)
    (tmp_path / "main.c").write_text(MAIN)
    run_compiler(find_compiler() + ["-O2", "-o", "shape", "main.c", files["source"].name],
                 tmp_path)
    rng = np.random.default_rng(7)
    u = np.concatenate([np.full(5, 0.3), rng.normal(size=400)])
    out = subprocess.run([str(tmp_path / "shape")], input="\n".join(f"{v:.17g}" for v in u),
                         capture_output=True, text=True, check=True).stdout
    y = np.array(out.split(), dtype=float)
    delays = np.rint(shaper.times / dt).astype(int)
    # same products summed in a different order: a few ulps of max |u| per impulse
    np.testing.assert_allclose(y, shaped_reference(delays, shaper.amplitudes, u),
                               rtol=0.0, atol=1e-14)


def test_off_grid_and_merged_impulses(tmp_path):
    with pytest.raises(ProblemFileError, match=r"times\[1\].*sample grid.*si_shaper"):
        shaper_table_bundle(Shaper([0.0, 0.0105], [0.5, 0.5]), 1e-3, "zv", tmp_path)
    with pytest.raises(ProblemFileError, match="name"):
        shaper_table_bundle(Shaper([0.0], [1.0]), 1e-3, "2bad", tmp_path)
    with pytest.raises(ProblemFileError, match="dt"):
        shaper_table_bundle(Shaper([0.0], [1.0]), 0.0, "ok", tmp_path)
    # two impulses 1e-12 s apart are one sample: one table entry with the summed amplitude
    files = shaper_table_bundle(Shaper([0.0, 0.002, 0.002 + 1e-12], [0.5, 0.25, 0.25]),
                                1e-3, "two", tmp_path)
    src = files["source"].read_text()
    assert "two_delays[TWO_N_IMPULSES] = {0, 2}" in src
    assert "two_amplitudes[TWO_N_IMPULSES] = {0.5, 0.5}" in src
    assert "#define TWO_HISTORY 3" in files["header"].read_text()


@pytest.mark.slow
@pytest.mark.needs_cc
def test_design_job_writes_the_table_of_its_shaper(tmp_path):
    """The design job's C table, compiled with a driver written here, shapes a reference as
    the shaper in its summary.json does (convolution written in this test)."""
    import json
    from pathlib import Path

    from casflex.design import run_design

    # the bundled study made small (as in run_design's example): a 5 ms loop
    text = Path("problems/studies/arm2link_move1.toml").read_text()
    for old, new in [('"../', f'"{Path.cwd()}/problems/'), ("modes = 3 ", "modes = 1 "),
                     ("grid_step = 3.0", "grid_step = 30.0"), ("dt = 0.001", "dt = 0.005"),
                     ("settle = 3.0", "settle = 0.5"), ('"composite"', '"inversion"'),
                     ("compile = true", "compile = false")]:
        text = text.replace(old, new)
    (tmp_path / "small.toml").write_text(text)
    out = tmp_path / "out"
    run_design(tmp_path / "small.toml", out, cache_dir=tmp_path / "cache", processes=1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["c_shaper_table"] == {"header": "arm2link_shaper.h",
                                         "source": "arm2link_shaper.c"}
    assert {"arm2link_shaper.h", "arm2link_shaper.c"} <= set(summary["c_files"])
    dt = 0.005
    times = np.array(summary["shaper"]["times"])
    amps = np.array(summary["shaper"]["amplitudes"])
    steps = times / dt
    delays = np.rint(steps).astype(int)
    # the job's shaper is digital: its impulses on the loop's 5 ms grid (float round-off)
    np.testing.assert_allclose(steps, delays, rtol=0.0, atol=1e-9)
    assert np.unique(delays).size == delays.size  # no two impulses on one sample
    c_dir = out / "c"
    (c_dir / "drive.c").write_text(MAIN.replace("tab", "arm2link_shaper"))
    run_compiler(find_compiler() + ["-O2", "-o", "drive", "drive.c", "arm2link_shaper.c"],
                 c_dir)
    rng = np.random.default_rng(11)
    u = np.concatenate([np.full(3, -0.2), rng.normal(size=3 * int(delays[-1]) + 50)])
    run = subprocess.run([str(c_dir / "drive")], input="\n".join(f"{v:.17g}" for v in u),
                         capture_output=True, text=True, check=True).stdout
    # same products summed in another order: a few ulps of max |u| per impulse
    np.testing.assert_allclose(np.array(run.split(), dtype=float),
                               shaped_reference(delays, amps, u), rtol=0.0, atol=1e-13)
