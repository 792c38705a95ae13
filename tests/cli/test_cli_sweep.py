"""The ``casflex sweep`` verb: JSON contract, degrees, tracking, plot, errors."""

import json

import numpy as np
import pytest

from casflex.cli import main
from casflex.robot import load
from casflex.tmm import natural_frequencies

ARM = "problems/arm2link.toml"


def _run(capsys, *argv):
    rc = main(["sweep", ARM, *argv, "--json"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out), out.err  # exactly one JSON document on stdout


def test_sweep_json_is_one_object(capsys):
    data, err = _run(capsys, "--joint", "3", "--from", "0", "--to", "0.2", "--step", "0.1",
                     "--modes", "3", "--processes", "1")
    assert set(data) == {"joint", "q", "omega"}
    assert data["joint"] == 3
    np.testing.assert_allclose(data["q"], [0.0, 0.1, 0.2])
    assert np.shape(data["omega"]) == (3, 3)
    arm = load(ARM)
    np.testing.assert_allclose(data["omega"][1], natural_frequencies(arm, [0, 0, 0.1],
                                                                     count=3), rtol=1e-10)
    assert "sweeping q3" in err and "mode 1" in err


def test_sweep_accepts_degrees_and_pi(capsys):
    data, _ = _run(capsys, "--joint", "3", "--from", "-180deg", "--to", "-177deg",
                   "--step", "1.5deg", "--modes", "2", "--processes", "1")
    np.testing.assert_allclose(np.degrees(data["q"]), [-180.0, -178.5, -177.0])
    data, _ = _run(capsys, "--joint", "3", "--from", "-pi", "--to", "pi", "--step", "pi",
                   "--modes", "1", "--processes", "1", "--q", "0.1", "10deg", "0")
    np.testing.assert_allclose(data["q"], [-np.pi, 0.0, np.pi])


def test_tracked_sweep_follows_the_crossing_and_plots(capsys, tmp_path):
    png = tmp_path / "sweep.png"
    argv = ["--joint", "3", "--from", "40deg", "--to", "60deg", "--step", "2.5deg",
            "--modes", "3"]
    raw, _ = _run(capsys, *argv)
    tracked, err = _run(capsys, *argv, "--track", "--plot", str(png))
    raw, tracked = np.array(raw["omega"]), np.array(tracked["omega"])
    # sorted: modes 2 and 3 meet and turn back (Fig. 25); tracked: they cross (Fig. 26)
    np.testing.assert_allclose(np.sort(tracked, axis=1), raw, rtol=1e-9)
    assert np.any(tracked[:, 1] > tracked[:, 2])
    d2_raw = np.abs(np.diff(raw[:, 1:3], 2, axis=0)).max()
    d2_trk = np.abs(np.diff(tracked[:, 1:3], 2, axis=0)).max()
    assert d2_trk < 0.2 * d2_raw
    assert png.stat().st_size > 10_000
    assert "lowest MAC" in err


@pytest.mark.parametrize("argv, message", [
    (["--joint", "4", "--from", "0", "--to", "1", "--step", "0.1"], "joints 1..3"),
    (["--joint", "0", "--from", "0", "--to", "1", "--step", "0.1"], "joints 1..3"),
    (["--joint", "3", "--from", "0", "--to", "1", "--step", "0"], "must be > 0"),
    (["--joint", "3", "--from", "0", "--to", "1", "--step", "-1deg"], "must be > 0"),
    (["--joint", "3", "--from", "1", "--to", "0", "--step", "0.1"], "greater than --to"),
    (["--joint", "3", "--from", "0", "--to", "1", "--step", "abc"], "not an angle"),
    (["--joint", "3", "--from", "0", "--to", "1", "--step", "1e-9"], "at most"),
    (["--joint", "3", "--from", "0", "--to", "1", "--step", "0.5", "--q", "0"],
     "has 3 joints"),
    (["--joint", "3", "--from", "0", "--to", "1", "--step", "0.5", "--modes", "0"],
     "--modes"),
])
def test_sweep_errors_are_one_line(capsys, argv, message):
    assert main(["sweep", ARM, *argv, "--json"]) == 2
    out = capsys.readouterr()
    assert out.out == ""
    assert message in out.err and "Traceback" not in out.err
    assert len(out.err.strip().splitlines()) == 1


def test_missing_robot_file(capsys):
    assert main(["sweep", "problems/nope.toml", "--joint", "1", "--from", "0", "--to", "1",
                 "--step", "0.5"]) == 2
    assert "cannot be read" in capsys.readouterr().err
