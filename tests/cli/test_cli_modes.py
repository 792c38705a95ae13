"""The ``casflex modes`` verb: JSON contract, plot, errors."""

import json

import numpy as np
import pytest

from casflex.cli import main


def test_modes_json_is_one_object(capsys, tmp_path):
    png = tmp_path / "modes.png"
    rc = main(["modes", "problems/arm2link.toml", "--q", "0", "0", "0", "--modes", "3",
               "--plot", str(png), "--json"])
    out = capsys.readouterr()
    assert rc == 0
    data = json.loads(out.out)  # exactly one JSON document on stdout
    assert set(data) == {"q", "omega", "frequency_hz"}
    assert len(data["omega"]) == 3
    np.testing.assert_allclose(np.array(data["omega"]) / (2 * np.pi), data["frequency_hz"])
    # the dissertation's 8.26, 11.93, 23.37 rad/s within 3 % (Table 14 / §3.3.7)
    np.testing.assert_allclose(data["omega"], [8.26, 11.93, 23.37], rtol=0.03)
    assert png.stat().st_size > 10_000
    assert "mode 1" in out.err


def test_modes_accepts_degrees(capsys):
    rc = main(["modes", "problems/arm2link.toml", "--q", "0", "0", "-45deg", "--json"])
    data = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert data["q"][2] == pytest.approx(-np.pi / 4)


def test_modes_errors_are_one_line(capsys):
    assert main(["modes", "problems/arm2link.toml", "--q", "0", "0"]) == 2
    err = capsys.readouterr().err
    assert "has 3 joints" in err and "Traceback" not in err
    assert main(["modes", "problems/arm2link.toml", "--q", "0", "0", "abc"]) == 2
    assert "not an angle" in capsys.readouterr().err
    assert main(["modes", "problems/nope.toml"]) == 2
    assert "cannot be read" in capsys.readouterr().err
