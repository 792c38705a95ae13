"""``casflex check`` and ``casflex accessibility`` end to end."""

import json

import numpy as np

from casflex.cli import main


def test_cli_check_and_accessibility(capsys, tmp_path, monkeypatch, model_cache):
    # the run's shared cache (tables and schedules are keyed on everything they depend on)
    monkeypatch.setenv("CASFLEX_CACHE", str(model_cache))
    argv = ["check", "problems/arm2link.toml", "--move", "problems/moves.toml:control_move1",
            "--controller", "inversion", "--step", "15deg", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stable"] is True and {"worst_margin", "worst_time"} <= set(out)
    assert main(argv[:5] + ["composite", "--step", "15deg", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stable"] is False and out["worst_margin"] < 0
    png = tmp_path / "acc.png"
    assert main(["accessibility", "problems/arm2link.toml", "--joints", "2", "3", "--step",
                 "30deg", "--plot", str(png), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["joints"] == [2, 3] and len(out["grid"]) == 2 and len(out["grid"][0]) == 12
    index = np.array(out["index"])
    assert index.shape == (3, 12, 12)
    j90, jm90 = 9, 3  # q = pi/2 and -pi/2 on the [-pi, pi) axis of 12 points
    assert index[0, j90, jm90] < 1e-9 and index[2, j90, jm90] < 1e-9
    assert png.exists()
