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
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert {"worst_margin", "worst_time"} <= set(out)
    # one verdict per condition (issue 18): eq. 226 holds along the move, eq. 225 does not
    # (Table 8 has no modal damping), so the headline is not "stable"
    conditions = out["conditions"]
    assert set(conditions) == {"zero_dynamics_margin", "modal_damping"}
    assert conditions["zero_dynamics_margin"]["holds"] is True
    assert conditions["zero_dynamics_margin"]["value"] == out["worst_margin"] > 0
    assert conditions["modal_damping"]["holds"] is False and out["damping_condition"] is False
    assert out["stable"] is False
    assert "holds: zero_dynamics_margin" in captured.err
    assert "FAILS: modal_damping" in captured.err
    assert "stable: no (1 of 2 conditions hold)" in captured.err
    assert main(argv[:5] + ["composite", "--step", "15deg", "--json"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert out["stable"] is False and out["worst_margin"] < 0
    conditions = out["conditions"]
    assert set(conditions) == {"slow_loop", "fast_loop_hurwitz"}
    # the slow loop e'' + 2 e' + e = 0 (Kp = 1, Kd = 2): a double root at -1 1/s
    assert conditions["slow_loop"]["holds"] is True
    assert abs(conditions["slow_loop"]["value"] + 1.0) < 1e-6  # double root: np.roots ~1e-8
    assert conditions["fast_loop_hurwitz"]["holds"] is False
    assert conditions["fast_loop_hurwitz"]["value"] == out["worst_real"] > 0
    assert "stable: no (1 of 2 conditions hold)" in captured.err
    # the headline is true when every condition holds: scheduled gains and damping-free
    # conditions of the composite law
    assert main(argv[:5] + ["composite", "--step", "15deg", "--schedule", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stable"] is all(c["holds"] for c in out["conditions"].values())
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
