"""Tests of the ``casflex shaper`` command (both forms)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from casflex import cli

THREE_RANGES = str(Path(__file__).resolve().parents[2] / "problems/shapers/three_ranges.toml")
ROBOT = "problems/arm2link.toml"


def write(tmp_path, text, name="p.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


# -------------------------------------------------------------------- problem form
def test_cli_json(capsys):
    code = cli.main(["shaper", THREE_RANGES, "--json"])
    out = capsys.readouterr().out
    assert code == 0
    data = json.loads(out)
    assert set(data) == {"times", "amplitudes", "duration", "dt", "start", "lp_duration",
                         "lp_lower_bound", "lp_gap", "ranges"}
    assert data["duration"] <= 0.3192
    assert data["start"] == "lp" and data["dt"] is None
    assert data["lp_lower_bound"] <= data["lp_duration"]
    assert data["lp_gap"] == pytest.approx(data["duration"] / data["lp_lower_bound"] - 1.0)
    assert len(data["times"]) == len(data["amplitudes"])
    assert len(data["ranges"]) == 3
    for r in data["ranges"]:
        assert set(r) == {"omega_min", "omega_max", "zeta", "vtol", "max_prv", "max_prv_eq187"}
        assert r["max_prv"] <= r["vtol"]
        assert r["max_prv_eq187"] <= r["max_prv"]  # undamped: equal up to round-off


def test_cli_digital_shaper(capsys):
    dt = 1e-3
    assert cli.main(["shaper", THREE_RANGES, "--dt", str(dt), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    t = np.array(data["times"])
    a = np.array(data["amplitudes"])
    assert data["dt"] == dt and data["start"] == "digital"
    np.testing.assert_allclose(t / dt, np.round(t / dt), atol=1e-9)  # on the sample grid
    # the analogue optimum is 0.31795 s: the 1 ms grid costs at most one sample
    assert data["duration"] <= 0.31795 + dt
    for r in data["ranges"]:  # this module's own evaluation, undamped
        w = np.linspace(r["omega_min"], r["omega_max"], 40001)
        assert np.abs(np.exp(1j * np.outer(w, t)) @ a).max() <= r["vtol"]
    assert cli.main(["shaper", THREE_RANGES, "--dt", "0"]) == 2
    assert "--dt" in capsys.readouterr().err


def test_cli_plot_and_robot_form(tmp_path, capsys):
    png = tmp_path / "prv.png"
    assert cli.main(["shaper", THREE_RANGES, "--plot", str(png)]) == 0
    assert png.stat().st_size > 1000
    robot = write(tmp_path, "[robot]\nname = 'arm'\n", "robot.toml")
    assert cli.main(["shaper", str(robot), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert "--move FILE:NAME" in captured.err  # the robot form needs the planned move


# --------------------------------------------------------------------- robot form
@pytest.mark.slow
def test_cli_robot_form_json(tmp_path, capsys):
    code = cli.main(["shaper", ROBOT, "--move", "problems/moves.toml:move2", "--margin", "0",
                     "--step", "7.5deg", "--processes", "1", "--cache-dir", str(tmp_path),
                     "--no-simulate", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    data = json.loads(captured.out)
    assert {"times", "amplitudes", "duration", "ranges", "contributions", "tolerances",
            "residual_tip_deflection_unshaped", "residual_tip_deflection_shaped"} <= set(data)
    np.testing.assert_allclose(data["contributions"], [0.0, 1.0, 0.0], atol=1e-6)
    assert data["tolerances"] == [1.0, 0.05, 1.0]
    assert data["duration"] == pytest.approx(0.540, abs=0.005)
    assert data["residual_tip_deflection_shaped"] is None
    assert len(data["ranges"]) == 3 and data["ranges"][1]["max_prv"] <= 0.05


@pytest.mark.parametrize("argv, message", [
    (["shaper", ROBOT, "--json"], "--move"),
    (["shaper", "problems/shapers/three_ranges.toml", "--move",
      "problems/moves.toml:move1"], "takes no --move"),
    (["shaper", ROBOT, "--move", "problems/moves.toml:nosuch"], "no such move"),
    (["shaper", ROBOT, "--move", "problems/moves.toml:move1", "--margin", "1.5"],
     "--margin"),
    (["shaper", ROBOT, "--move", "problems/moves.toml:move1", "--vtol", "0"], "--vtol"),
    (["shaper", "problems/fixtures/fixture1.toml", "--move", "problems/moves.toml:move1"],
     "joint"),
])
def test_cli_robot_form_errors(argv, message, capsys):
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert message in captured.err


def test_cli_json_is_the_only_output_in_a_fresh_process(tmp_path):
    """HiGHS prints a banner to file descriptor 1 when its first model is built; in a
    fresh process (the banner comes once per process) with an empty cache, so that the LP
    runs, ``--json`` must still print nothing but the object."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, CASFLEX_CACHE=str(tmp_path / "cache"))
    main = "import sys; from casflex import cli; sys.exit(cli.main(sys.argv[1:]))"
    run = subprocess.run([sys.executable, "-c", main, "shaper", THREE_RANGES, "--json"],
                         capture_output=True, text=True, env=env, timeout=300, check=True)
    assert json.loads(run.stdout)["duration"] <= 0.3192
