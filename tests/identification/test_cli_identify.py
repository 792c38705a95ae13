"""``casflex identify`` and ``casflex calibrate --logs`` through the command line.

Logs are written here from damped sinusoids at known frequencies (for the calibration:
the natural frequencies of the independent FE model of the "real" arm of
test_updating.py, which this module imports through its helper functions).
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from casflex.cli import main

ZETA = np.array([0.01, 0.02, 0.015, 0.03])


def run_cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(args)
    return status, out.getvalue(), err.getvalue()


def write_log(path, f_hz, q=None, fs=500.0, duration=10.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(fs * duration)) / fs
    cols = {"t": t}
    if q is not None:
        cols.update({f"q{j + 1}": np.full(t.size, v) for j, v in enumerate(q)})
    for c, name in enumerate(("acc_x", "acc_z")):
        y = np.full(t.size, 9.81 * c)
        for k, f in enumerate(f_hz):
            wn = 2 * np.pi * f
            z = ZETA[k % ZETA.size]
            y += (0.3 + 0.1 * c + 0.05 * k) * np.exp(-z * wn * t) * np.cos(
                wn * np.sqrt(1 - z * z) * t + rng.uniform(0, 6))
        cols[name] = y + 250e-6 * 9.81 * rng.standard_normal(t.size)
    header = ",".join(cols)
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=header,
               comments="")


def test_identify_json_and_plot(tmp_path):
    write_log(tmp_path / "log.csv", [1.5, 6.0])
    status, out, err = run_cli(["identify", str(tmp_path / "log.csv"), "--config", "0,0,300deg",
                                "--plot", str(tmp_path / "id.png"), "--json"])
    assert status == 0, err
    result = json.loads(out)
    assert result["frequency_hz"] == pytest.approx([1.5, 6.0], rel=2e-3)
    assert result["damping"] == pytest.approx([0.01, 0.02], rel=0.1)
    assert result["q"] == pytest.approx([0.0, 0.0, np.radians(300.0)])
    assert result["seen_by"] == [["acc_x", "acc_z"]] * 2
    assert (tmp_path / "id.png").stat().st_size > 0


def test_identify_bad_log_is_one_line(tmp_path):
    (tmp_path / "log.csv").write_text("t,acc\n0,1\n0.1,x\n")
    status, out, err = run_cli(["identify", str(tmp_path / "log.csv"), "--json"])
    assert status == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "row 3" in err


@pytest.mark.slow  # eight identifications and a fit
def test_calibrate_from_logs(tmp_path):
    from test_updating import ARM, E_TRUE, MASS_TRUE, Q, fe_frequencies_hz, truth_robot

    truth = truth_robot()
    logs = []
    for i, q in enumerate(Q):
        path = tmp_path / f"log{i}.csv"
        write_log(path, fe_frequencies_hz(truth, q), q=q, seed=i)
        logs.append(str(path))
    (tmp_path / "fit.toml").write_text(
        '[[parameter]]\npath = "link2.material.E"\nmin = 30e9\nmax = 120e9\n'
        '[[parameter]]\npath = "link2.tip.mass"\nmin = 0.0\nmax = 1.0\n')
    status, out, err = run_cli(["calibrate", ARM, "--logs", *logs, "--fit",
                                str(tmp_path / "fit.toml"), "--processes", "1", "--json"])
    assert status == 0, err
    result = json.loads(out)
    assert result["identifiable"] == {"link2.material.E": True, "link2.tip.mass": True}
    assert result["parameters"]["link2.material.E"] == pytest.approx(E_TRUE, rel=5e-3)
    assert result["parameters"]["link2.tip.mass"] == pytest.approx(MASS_TRUE, rel=2e-2)
