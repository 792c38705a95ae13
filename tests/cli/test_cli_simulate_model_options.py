"""``casflex simulate --shape-rates --foreshortening``: the model options reach the model."""

from __future__ import annotations

import contextlib
import io

import pytest

from casflex.cli import main
from casflex.errors import ModelError

ARGS = ["simulate", "problems/arm2link.toml", "--move", "problems/moves.toml:move2",
        "--json"]


def _cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture()
def captured(monkeypatch):
    """simulate_move's keywords; the command stopped there with a one-line error."""
    import casflex.simulate

    seen = {}

    def capture(*args, **kwargs):
        seen.update(kwargs)
        raise ModelError("stopped by the test")

    monkeypatch.setattr(casflex.simulate, "simulate_move", capture)
    return seen


@pytest.mark.parametrize("flags, rates, short", [
    ([], False, False), (["--shape-rates"], True, False),
    (["--shape-rates", "--foreshortening", "--method", "rk4"], True, True),
    (["--foreshortening"], False, True),
    (["--shape-rates", "--foreshortening", "--method", "poly"], True, True)])
def test_flags_reach_simulate_move(captured, flags, rates, short):
    rc, out, err = _cli([*ARGS, *flags])
    assert rc == 2 and "stopped by the test" in err
    assert captured["shape_rates"] is rates and captured["foreshortening"] is short
    assert captured["kinematics"] == "truncated"


def test_kinematics_reaches_simulate_move(captured):
    rc, out, err = _cli([*ARGS, "--kinematics", "exact", "--method", "rk4"])
    assert rc == 2 and "stopped by the test" in err
    assert captured["kinematics"] == "exact"


def test_exact_kinematics_refuse_poly(captured):
    rc, out, err = _cli([*ARGS, "--kinematics", "exact"])  # poly is the default method
    assert rc == 2 and "--kinematics exact: needs --method rk4" in err and not captured
