"""Logs holding several configurations: cut into segments of constant joint angles, each
identified, and the whole campaign fitted (``casflex calibrate --logs`` on one file).

The campaign log is built here: at each configuration a free decay at the natural
frequencies of the independent FE model of the "real" arm of test_updating.py, the joints
moving on a ramp between configurations (with the accelerometers shaking meanwhile), and
encoder noise on the joint columns.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from casflex.cli import main
from casflex.errors import ProblemFileError
from casflex.identification import VibrationLog, read_log, split_configurations

FS = 500.0
ZETA = (0.01, 0.02, 0.015, 0.03)


def campaign(configs, f_hz, hold=10.0, ramp=1.5, seed=0):
    """t, q (N, n), channels (N, 2): holds at ``configs`` joined by linear ramps."""
    rng = np.random.default_rng(seed)
    t_parts, q_parts, y_parts = [], [], []
    t0 = 0.0
    for i, q in enumerate(configs):
        if i:
            n = int(ramp * FS)
            s = np.arange(n) / n
            q_parts.append(configs[i - 1] + np.outer(s, q - configs[i - 1]))
            y_parts.append(0.5 * rng.standard_normal((n, 2)))  # motion: no free decay
            t_parts.append(t0 + np.arange(n) / FS)
            t0 += n / FS
        n = int(hold * FS)
        t = np.arange(n) / FS
        y = np.zeros((n, 2)) + [0.0, 9.81]
        for k, f in enumerate(f_hz[i]):
            wn = 2 * np.pi * f
            z = ZETA[k % len(ZETA)]
            for c in range(2):
                y[:, c] += (0.3 + 0.1 * c + 0.05 * k) * np.exp(-z * wn * t) * np.cos(
                    wn * np.sqrt(1 - z * z) * t + rng.uniform(0, 6))
        y_parts.append(y + 250e-6 * 9.81 * rng.standard_normal(y.shape))
        q_parts.append(q + 2e-4 * rng.standard_normal((n, q.size)))  # encoder noise
        t_parts.append(t0 + t)
        t0 += n / FS
    return np.concatenate(t_parts), np.vstack(q_parts), np.vstack(y_parts)


def test_split_finds_the_holds_and_drops_the_ramps():
    configs = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, -1.0], [0.0, 0.5, 1.0]])
    t, q, y = campaign(configs, [[2.0]] * 3, hold=4.0, ramp=1.0)
    parts = split_configurations(VibrationLog(t, y, ("a", "b"), q, "c.csv"))
    assert len(parts) == 3
    for part, qc, start in zip(parts, configs, (0.0, 5.0, 10.0), strict=True):
        assert part.configuration == pytest.approx(qc, abs=1e-3)  # 2e-4 rad noise
        # a segment may take in the ramp samples within the 5 mrad band at either end
        # (the ramps move <= 2 mrad a sample: up to 2.5 samples, plus one for the noise)
        assert part.t[0] == pytest.approx(start, abs=3.5 / FS)
        assert part.t[-1] - part.t[0] == pytest.approx(4.0, abs=7.0 / FS)
        assert "c.csv, t = " in part.source
    # a slow move (0.5 rad in 10 s: a 5 mrad band is left every 0.1 s) is no segment,
    # however long it lasts
    t2 = np.arange(int(14 * FS)) / FS
    q2 = np.clip((t2 - 2.0) / 10.0, 0.0, 1.0)[:, None] * [0.0, 0.5, 0.0]
    parts = split_configurations(VibrationLog(t2, np.zeros((t2.size, 1)), ("a",), q2, None))
    assert [round(float(p.configuration[1]), 3) for p in parts] == [0.0, 0.5]
    # a hold whose first sample sits at the band's edge, then noise crossing it: one
    # segment, not two
    q3 = np.full((t2.size, 1), 0.0)
    q3[0] = 0.0045
    q3[1:] += 2e-4 * np.random.default_rng(1).standard_normal((t2.size - 1, 1))
    parts = split_configurations(VibrationLog(t2, np.zeros((t2.size, 1)), ("a",), q3, None))
    assert len(parts) == 1 and parts[0].t.size == t2.size
    # a minimum duration above the holds leaves nothing: a one-line error
    with pytest.raises(ProblemFileError, match="lasts 5 s"):
        split_configurations(VibrationLog(t, y, ("a", "b"), q, "c.csv"), min_duration=5.0)
    with pytest.raises(ProblemFileError, match="q1..qn"):
        split_configurations(VibrationLog(t, y, ("a", "b"), None, "c.csv"))


@pytest.mark.slow  # four identifications and a fit
def test_calibrate_from_one_campaign_log(tmp_path):
    from test_updating import ARM, E_TRUE, MASS_TRUE, Q, fe_frequencies_hz, truth_robot

    truth = truth_robot()
    configs = Q[[0, 2, 3, 5]]
    t, q, y = campaign(configs, [fe_frequencies_hz(truth, qc) for qc in configs])
    cols = {"t": t, **{f"q{j + 1}": q[:, j] for j in range(3)}, "acc_x": y[:, 0],
            "acc_z": y[:, 1]}
    np.savez(tmp_path / "campaign.npz", **cols)
    assert len(split_configurations(read_log(tmp_path / "campaign.npz"))) == 4
    (tmp_path / "fit.toml").write_text(
        '[[parameter]]\npath = "link2.material.E"\nmin = 30e9\nmax = 120e9\n'
        '[[parameter]]\npath = "link2.tip.mass"\nmin = 0.0\nmax = 1.0\n')
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(["calibrate", ARM, "--logs", str(tmp_path / "campaign.npz"), "--fit",
                       str(tmp_path / "fit.toml"), "--processes", "1", "--json"])
    assert status == 0, err.getvalue()
    assert err.getvalue().count("row ") == 4
    result = json.loads(out.getvalue())
    assert result["identifiable"] == {"link2.material.E": True, "link2.tip.mass": True}
    # the targets from exact data; the 250 ug noise moves the identified
    # frequencies by ~1e-5 relative, far inside them
    assert result["parameters"]["link2.material.E"] == pytest.approx(E_TRUE, rel=5e-3)
    assert result["parameters"]["link2.tip.mass"] == pytest.approx(MASS_TRUE, rel=2e-2)


def test_a_log_that_is_no_archive_or_a_damaged_one_names_the_file(tmp_path):
    t, q, y = campaign(np.array([[0.0]]), [[3.0]], hold=2.0)
    good = tmp_path / "good.npz"
    np.savez(good, t=t, q1=q[:, 0], acc_x=y[:, 0])
    assert read_log(good).t.size == t.size
    text = tmp_path / "text.npz"  # a CSV named .npz: numpy took it for a pickle
    text.write_text("t,a\n0,1\n")
    with pytest.raises(ProblemFileError, match=r"text.npz: field '<file>'.*is not a NumPy "
                       r"\.npz archive \(a log is a CSV file") as err:
        read_log(text)
    assert "pickle" not in str(err.value)
    damaged = bytearray(good.read_bytes())  # a damaged member: zipfile.BadZipFile before
    damaged[300:340] = bytes(b ^ 0xFF for b in damaged[300:340])
    (tmp_path / "damaged.npz").write_bytes(damaged)
    with pytest.raises(ProblemFileError, match=r"damaged.npz: field '<file>'.*cannot be read: "
                       r"Bad CRC-32"):
        read_log(tmp_path / "damaged.npz")
    objects = tmp_path / "objects.npz"  # arrays of Python objects are never unpickled
    np.savez(objects, t=np.array([0.0, {"x": 1}], dtype=object))
    with pytest.raises(ProblemFileError, match=r"objects.npz: field '<file>'.*cannot be read"):
        read_log(objects)
