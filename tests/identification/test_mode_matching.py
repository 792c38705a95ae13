"""Measured and modelled modes paired by MAC at the sensors, where frequency order fails.

One aluminium beam (0.8 m, rectangle a × b) clamped at a hub: its bending modes in the two
section directions form two families whose frequencies scale with a and with b alone
(EI ∝ a³b or ab³, mass per length ∝ ab). The robot file says b = 7 mm, the "real" beam has
b = 4.2 mm < a = 5 mm, so the lowest b-direction mode crosses below the lowest
a-direction mode. The test rig excites and sees only the b-direction family (measured:
its first two modes, frequencies and shapes at three two-axis accelerometers), from the
independent beam FE model of the tests (tests/reference_fem.py, 40 elements:
discretisation error below 1e-5 relative on these modes). Frequency order pairs measured
f1 with the modelled lowest mode, which is the wrong family; MAC pairs it right.
"""

from __future__ import annotations

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.identification import (
    FitParameter,
    Measurements,
    calibrate,
    mac_matrix,
    match_modes,
    parse_parameter_path,
    read_channels,
    read_measurements,
    with_parameters,
)
from casflex.robot import loads
from casflex.tmm import build_chain

try:
    import reference_fem as fem
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests import reference_fem as fem

B_TRUE = 0.0042
BEAM = ('[[link]]\njoint = "revolute"\nname = "hub"\n'
        '[[link]]\nname = "beam"\nd = 0.8\n'
        '[link.section]\nshape = "rectangle"\na = 0.005\nb = 0.007\n'
        '[link.material]\nE = 69e9\nG = 26.9e9\nrho = 2700.0\n')
SENSORS = "".join(f'[[sensor]]\nname = "s{i + 1}"\ntype = "accelerometer"\nlink = "beam"\n'
                  f's = {s}\naxes = "xy"\n' for i, s in enumerate((0.3, 0.55, 0.8)))
Q = np.array([[0.0], [1.0]])


def fe_modes(robot, q, channels, count=4):
    """FE frequencies [Hz] and shapes at the channels (local beam axes) of ``robot``."""
    chain = build_chain(robot, q)
    (beam,) = [e for e in chain.elements if e.kind == "beam"]
    sec, mat = beam.params["section"], beam.params["material"]
    seg = fem.Segment(beam.start, beam.end, beam.R[:, 0], E=mat.E, G=mat.G, rho=mat.rho,
                      A=sec.A, Ix=sec.Ix, Iy=sec.Iy, J=sec.J, Ip=sec.Ip, n_elements=40)
    omega, shapes = fem.modes([seg], [], [], clamp=beam.start, n_modes=count)
    length = np.linalg.norm(np.asarray(beam.end) - np.asarray(beam.start))
    phi = np.empty((count, len(channels)))
    for c, ch in enumerate(channels):
        u = shapes.sample(0, [ch.s / length])[:, 0, :]  # (modes, 3) global
        phi[:, c] = u @ beam.R[:, ch.axis]
    return omega / (2 * np.pi), phi


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = tmp_path_factory.mktemp("crossing")
    (d / "sensors.toml").write_text(SENSORS)
    robot = loads(BEAM)
    channels = read_channels(d / "sensors.toml", robot)
    b = parse_parameter_path("beam.section.b", robot)
    truth = with_parameters(robot, [b], [B_TRUE])
    f, shapes = [], []
    for q in Q:
        fq, phi = fe_modes(truth, q, channels)
        # b1 < a1 < b2 < a2 (f ∝ the dimension along the bending direction, and the second
        # bending mode is 6.27 times the first): the b family is modes 0 and 2; check that
        # its shapes lie along one section axis and the a family's along the other
        family = np.abs(phi[:, 0::2]).sum(axis=1) > np.abs(phi[:, 1::2]).sum(axis=1)
        assert family.tolist() in ([True, False, True, False], [False, True, False, True])
        f.append(fq[[0, 2]])
        shapes.append(phi[[0, 2]])
    header = "q1,f1,f2," + ",".join(f"f{j + 1}_{c.name}" for j in range(2) for c in channels)
    rows = [",".join(repr(float(v)) for v in (*q, *fq, *phi.ravel()))
            for q, fq, phi in zip(Q, f, shapes, strict=True)]
    (d / "meas.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    return robot, channels, b, read_measurements(d / "meas.csv", 1)


def test_shape_columns_are_read(case):
    _, channels, _, data = case
    assert data.shapes.shape == (2, 2, 6)
    assert sorted(data.channels) == sorted(c.name for c in channels)


def test_mac_pairs_the_crossed_modes_and_recovers_b(case):
    robot, channels, b, data = case
    param = [FitParameter(b, 0.002, 0.012, 0.007)]
    # frequency order: measured f1 (b family) is fitted to the modelled lowest mode, of
    # the a family, whose frequency does not depend on b: the fit cannot recover b
    by_order = calibrate(robot, Measurements(data.q, data.frequency_hz, None), param,
                         processes=1)
    assert not (by_order.identifiable[0]
                and by_order.values[0] == pytest.approx(B_TRUE, rel=5e-3))
    assert by_order.rms_after_hz > 0.1
    fit = calibrate(robot, data, param, processes=1, channels=channels)
    assert fit.identifiable == [True]
    # issue target for a stiffness-like parameter from exact data: 0.5 %; the FE's
    # discretisation error (< 1e-5) is what is left
    assert fit.values[0] == pytest.approx(B_TRUE, rel=5e-3)
    assert fit.rms_after_hz < 1e-3 * fit.rms_before_hz
    # at the fitted b the b family's first mode is the lowest: pairs (0, 2) and MAC ~ 1
    assert fit.pairing.tolist() == [[0, 2], [0, 2]]
    assert np.all(fit.mac > 0.99)
    d = fit.as_dict()
    assert d["modelled_mode"] == [[1, 3], [1, 3]] and len(d["mac"]) == 2


def test_a_shape_no_modelled_mode_has_is_refused(case):
    robot, channels, b, data = case
    bad = data.shapes.copy()
    bad[0, 0] = [1.0, 1.0, -1.0, 1.0, 1.0, -1.0]  # no bending mode of the beam looks so
    with pytest.raises(ModelError, match=r"row 1: mode f1 .*MAC"):
        calibrate(robot, Measurements(data.q, data.frequency_hz, None, None, data.channels,
                                      bad), [FitParameter(b, 0.002, 0.012, 0.007)],
                  processes=1, channels=channels)


def test_match_modes_frequency_tie_break_and_order_fallback():
    phi = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    # two modelled modes with the same shape: the nearer frequency wins
    idx, mac = match_modes(np.array([2.05, np.nan]), np.array([[1.0, 0.0], [np.nan] * 2]),
                           np.array([1.0, 2.0, 3.0]), phi)
    assert idx.tolist() == [1, -1] and mac[0] == pytest.approx(1.0)
    # a mode without shape takes the lowest modelled mode left
    idx, _ = match_modes(np.array([1.0, 3.0]), np.array([[np.nan] * 2, [0.0, 1.0]]),
                         np.array([1.0, 2.0, 3.0]), phi)
    assert idx.tolist() == [0, 2]
    assert mac_matrix(np.array([[1.0, 2.0]]), np.array([[-2.0, -4.0]]))[0, 0] == (
        pytest.approx(1.0))


@pytest.mark.slow  # two identifications and two fits
def test_calibrate_from_logs_matches_by_identified_shapes(case, tmp_path):
    """Logs of the b family's free decays: the identified (signed) shapes pair the modes."""
    import contextlib
    import io
    import json

    from casflex.cli import main

    robot, channels, b, data = case
    rng = np.random.default_rng(3)
    fs = 500.0
    t = np.arange(int(10 * fs)) / fs
    logs = []
    for r, q in enumerate(Q):
        y = np.zeros((t.size, len(data.channels)))
        for j, (f, zeta) in enumerate(zip(data.frequency_hz[r], (0.01, 0.02), strict=True)):
            wn = 2 * np.pi * f
            decay = np.exp(-zeta * wn * t) * np.cos(wn * np.sqrt(1 - zeta**2) * t + 0.3 + j)
            phi = data.shapes[r, j] / np.abs(data.shapes[r, j]).max()
            y += decay[:, None] * (0.5 - 0.2 * j) * phi
        y += 250e-6 * 9.81 * rng.standard_normal(y.shape)  # the accelerometers' noise
        path = tmp_path / f"log{r}.npz"
        np.savez(path, t=t, q1=np.full(t.size, q[0]),
                 **{c: y[:, i] for i, c in enumerate(data.channels)})
        logs.append(str(path))
    (tmp_path / "sensors.toml").write_text(SENSORS)
    (tmp_path / "fit.toml").write_text('[[parameter]]\npath = "beam.section.b"\n'
                                       'min = 0.002\nmax = 0.012\ninitial = 0.007\n')
    (tmp_path / "beam.toml").write_text(BEAM)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(["calibrate", str(tmp_path / "beam.toml"), "--logs", *logs, "--fit",
                       str(tmp_path / "fit.toml"), "--sensors", str(tmp_path / "sensors.toml"),
                       "--processes", "1", "--json"])
    assert status == 0, err.getvalue()
    result = json.loads(out.getvalue())
    assert result["modelled_mode"] == [[1, 3], [1, 3]]
    # the identified shapes carry the noise: MAC still far above the 0.7 threshold
    assert min(min(row) for row in result["mac"]) > 0.99
    assert result["parameters"]["beam.section.b"] == pytest.approx(B_TRUE, rel=5e-3)
    assert "MAC" in err.getvalue()


def test_cli_shape_channel_errors_are_one_line(case, tmp_path):
    import contextlib
    import io

    from casflex.cli import main

    (tmp_path / "beam.toml").write_text(BEAM)
    (tmp_path / "fit.toml").write_text('[[parameter]]\npath = "beam.section.b"\n'
                                       'min = 0.002\nmax = 0.012\n')
    (tmp_path / "sensors.toml").write_text(SENSORS.replace('name = "s3"', 'name = "t3"'))
    (tmp_path / "m.csv").write_text("q1,f1,f1_s3_x\n0,5.36,0.4\n")

    def run(*extra):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main(["calibrate", str(tmp_path / "beam.toml"), "--data",
                           str(tmp_path / "m.csv"), "--fit", str(tmp_path / "fit.toml"),
                           "--processes", "1", *extra])
        return status, out.getvalue(), err.getvalue()

    status, out, err = run("--sensors", str(tmp_path / "sensors.toml"))
    errors = [ln for ln in err.splitlines() if "error" in ln]
    assert status == 2 and out == "" and len(errors) == 1 and "Traceback" not in err
    assert "s3_x" in errors[0] and "t3_x" in errors[0]
    status, _, err = run("--sensors", str(tmp_path / "sensors.toml"), "--mac-min", "1.5")
    assert status == 2 and "--mac-min" in err
    (tmp_path / "m.csv").write_text("q1,f1,f2_s1_x\n0,5.36,0.4\n")
    status, _, err = run()
    assert status == 2 and "f2" in err and len(err.strip().splitlines()) == 1
