"""Every verb of the ``casflex`` command follows one set of conventions (issue 18;
``casflex.commands.common``): its ``--help`` runs, its help lines share one style, its
positional files and options are named alike, gravity, cache and frequency-unit options
have one spelling each, joints are 1-based, and old spellings still work for one release
with a one-line note on stderr."""

import argparse
import json
import re

import pytest

import casflex.codegen
from casflex.cli import VERBS, build_parser, main
from casflex.commands.common import FREQUENCY_UNITS, ArgumentParser

#: the verbs that build modal tables (or other cached results): --cache-dir and --no-cache
BUILDS_TABLES = {"simulate", "shaper", "check", "accessibility", "codegen", "design", "plan"}
#: the verbs whose figure has a frequency axis in a unit of the user's choice
FREQUENCY_PLOTS = {"sweep"}
#: the first word of every verb's help: an imperative
IMPERATIVES = {"compute", "map", "check", "simulate", "design", "generate", "run", "plan",
               "identify", "fit"}
#: the positional file arguments: attribute -> metavar
POSITIONALS = {"robot": "ROBOT.toml", "study": "STUDY.toml", "problem": "PROBLEM.toml",
               "log": "LOG.csv"}
#: options spelled with capitals because they are the symbols of the EKF (Q, R, P0)
SYMBOL_OPTIONS = {"--Q", "--R", "--P0"}


def _verbs():
    """verb -> (module, its own parser as the CLI builds it)."""
    parser = build_parser()
    out = {}
    for action in parser._subparsers._group_actions:  # argparse keeps sub-parsers there
        for verb, sub in action.choices.items():
            out[verb] = sub
    return out


def _actions(sub):
    return [a for a in sub._actions
            if not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS]


def test_every_verb_is_registered_and_documented():
    assert set(_verbs()) == set(VERBS)


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_help_runs(verb, capsys):
    with pytest.raises(SystemExit) as exc:
        main([verb, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: casflex {verb}") and "--json" in out


def test_top_level_help_lists_every_verb(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for verb in VERBS:
        assert re.search(rf"^\s+{verb}\s", out, re.MULTILINE), verb


def _style(text, where):
    """Lower-case first word (symbols and acronyms as written), no trailing period."""
    assert text and text == text.strip(), where
    assert "\n" not in text, where
    assert not text.endswith("."), f"{where}: {text!r} ends with a period"
    first = text.split()[0]
    assert not re.fullmatch(r"[A-Z][a-z]+\W*", first), f"{where}: {text!r} is capitalised"
    assert "default:" not in text, f"{where}: write '(default X)', not 'default:'"


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_help_lines_share_one_style(verb):
    sub = _verbs()[verb]
    _style(sub.description, f"{verb}: HELP")
    assert sub.description.split()[0] in IMPERATIVES, f"{verb}: {sub.description!r}"
    for action in _actions(sub):
        _style(action.help, f"{verb} {action.option_strings or action.dest}")


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_names_are_alike(verb):
    sub = _verbs()[verb]
    for action in _actions(sub):
        if not action.option_strings:  # positional: a file named by its kind
            assert POSITIONALS.get(action.dest) == action.metavar, (verb, action.dest)
            continue
        for option in action.option_strings:
            assert option in SYMBOL_OPTIONS or re.fullmatch(r"--[a-z][a-z0-9-]*", option), \
                (verb, option)
        if action.metavar is not None and action.option_strings != ["--end"]:
            assert re.fullmatch(r"[A-Z][A-Z0-9_:.,]*(\.[a-z]+)?", action.metavar) or \
                action.metavar.endswith(".png") or action.metavar.endswith(".toml") or \
                action.metavar.endswith(".csv"), (verb, action.option_strings, action.metavar)
        if action.dest == "plot":
            assert action.metavar == "FILE.png", verb
        if action.dest == "modes":  # the number of modes is --modes N everywhere
            assert action.option_strings == ["--modes"] and action.metavar == "N", verb
        if action.dest in ("joint", "joints"):
            assert "1-based" in action.help, (verb, action.help)
        if action.dest == "step":
            assert "deg" in action.help, (verb, action.help)
    options = {o for a in _actions(sub) for o in a.option_strings}
    assert "--count" not in options  # deprecated: hidden


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_gravity_cache_and_unit_have_one_spelling(verb):
    sub = _verbs()[verb]
    by_dest = {a.dest: a for a in _actions(sub)}
    if "gravity" in by_dest:
        g = by_dest["gravity"]
        assert isinstance(g, argparse.BooleanOptionalAction)
        assert g.option_strings == ["--gravity", "--no-gravity"]
        # the convention: no gravity unless asked; codegen keeps its old default for one
        # release when neither flag is given (None, with a note)
        assert g.default is (None if verb == "codegen" else False)
    options = {o for a in _actions(sub) for o in a.option_strings}
    cache = {"--cache-dir", "--no-cache"}
    assert (cache <= options) is (verb in BUILDS_TABLES), verb
    assert not (cache & options) or cache <= options, verb
    if verb in FREQUENCY_PLOTS:
        unit = by_dest["unit"]
        assert tuple(unit.choices) == FREQUENCY_UNITS and unit.default == "rad/s"
    else:
        assert "unit" not in by_dest, verb


def test_every_verb_lets_the_cli_add_json_once():
    """``add_arguments`` of a verb on a bare parser (as the tests and docs do) adds no
    ``--json`` of its own."""
    import importlib

    for verb, module in VERBS.items():
        p = ArgumentParser()
        importlib.import_module(f"casflex.commands.{module}").add_arguments(p)
        assert "--json" not in {o for a in p._actions for o in a.option_strings}, verb


# ---------------------------------------------------------------- deprecated spellings

def test_count_is_a_deprecated_alias_of_modes(capsys):
    assert main(["modes", "problems/arm2link.toml", "--count", "2", "--json"]) == 0
    captured = capsys.readouterr()
    assert len(json.loads(captured.out)["omega"]) == 2
    notes = [line for line in captured.err.splitlines() if "deprecated" in line]
    assert notes == ["casflex: deprecated: --count; use --modes (the old spelling goes in "
                     "the next release)"]
    assert main(["modes", "problems/arm2link.toml", "--modes", "2", "--json"]) == 0
    assert "deprecated" not in capsys.readouterr().err


def test_sweep_count_alias_and_unit(capsys, tmp_path, monkeypatch):
    import casflex.plotting

    units = []
    real = casflex.plotting.plot_sweep
    monkeypatch.setattr(casflex.plotting, "plot_sweep",
                        lambda *a, **k: units.append(k["unit"]) or real(*a, **k))
    base = ["sweep", "problems/arm2link.toml", "--joint", "3", "--from", "0", "--to", "1deg",
            "--step", "1deg", "--processes", "1", "--plot", str(tmp_path / "s.png")]
    assert main([*base, "--count", "1", "--json"]) == 0
    captured = capsys.readouterr()
    assert len(json.loads(captured.out)["omega"][0]) == 1
    assert captured.err.count("casflex: deprecated: --count; use --modes") == 1
    assert main([*base, "--modes", "1", "--unit", "Hz"]) == 0
    assert units == ["rad/s", "Hz"]


def _codegen_kwargs(monkeypatch, argv):
    """What ``casflex codegen argv`` hands to the library (which is not run)."""
    seen = {}

    def fake(robot, sensors, out, **kwargs):
        seen.update(kwargs)
        return []

    monkeypatch.setattr(casflex.codegen, "realtime_bundles", fake)
    assert main(["codegen", "problems/arm2link.toml", "--sensors",
                 "problems/sensors/arm2link_accel.toml", *argv]) == 0
    return seen


def test_codegen_step_gravity_and_cache(monkeypatch, capsys, tmp_path):
    out = ["--out", str(tmp_path / "rt")]
    # old: a bare number is degrees, with a note; new: rad or a deg suffix, no note
    old = _codegen_kwargs(monkeypatch, [*out, "--step", "6", "--no-gravity"])
    err = capsys.readouterr().err
    assert old["step"] == pytest.approx(0.10471975511965977, rel=1e-15)  # 6° in rad
    assert err.count("deprecated") == 1 and "--step 6deg" in err
    new = _codegen_kwargs(monkeypatch, [*out, "--step", "6deg", "--no-gravity"])
    assert new["step"] == old["step"] and "deprecated" not in capsys.readouterr().err
    assert new["gravity"] is False and new["cache_dir"] is None
    # gravity: the flag decides; without it, the old default (gravity) with a note
    assert _codegen_kwargs(monkeypatch, [*out, "--gravity"])["gravity"] is True
    assert "deprecated" not in capsys.readouterr().err
    assert _codegen_kwargs(monkeypatch, out)["gravity"] is True
    err = capsys.readouterr().err
    assert err.count("deprecated") == 1 and "--no-gravity" in err
    # cache
    assert _codegen_kwargs(monkeypatch, [*out, "--no-gravity", "--no-cache"])["cache_dir"] \
        is False
    got = _codegen_kwargs(monkeypatch, [*out, "--no-gravity", "--cache-dir", "c"])
    assert got["cache_dir"] == "c"


def test_no_cache_and_cache_dir_together_is_an_error(capsys):
    assert main(["accessibility", "problems/arm2link.toml", "--no-cache", "--cache-dir",
                 "c"]) == 2
    assert "--no-cache" in capsys.readouterr().err


def test_simulate_defaults(monkeypatch, capsys):
    """``simulate`` runs the fastest exact method (poly) without gravity by default; the
    old ``--gravity`` flag keeps its meaning and ``--no-cache`` reaches the library."""
    import casflex.simulate

    seen = {}

    class Stop(Exception):
        pass

    def fake(robot, move, n_modes, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(casflex.simulate, "simulate_move", fake)
    argv = ["simulate", "problems/arm2link.toml", "--move", "problems/moves.toml:move1"]
    with pytest.raises(Stop):
        main(argv)
    assert (seen["method"], seen["gravity"], seen["cache_dir"]) == ("poly", False, None)
    with pytest.raises(Stop):
        main([*argv, "--gravity", "--no-cache", "--method", "rk4"])
    assert (seen["method"], seen["gravity"], seen["cache_dir"]) == ("rk4", True, False)


@pytest.mark.slow
def test_simulate_default_method_gives_the_rk4_result(tmp_path, capsys):
    """The default (poly) takes the RK4 steps of ``--method rk4`` on the exact polynomial
    form: the figures agree to the interpolation's 1e-10 (relative, per output) carried
    through the steps (the bound the poly tests use is 1e-8)."""
    argv = ["simulate", "problems/arm2link.toml", "--move", "problems/moves.toml:move3",
            "--modes", "1", "--dt", "0.01", "--step", "15deg", "--cache-dir", str(tmp_path),
            "--json"]
    assert main(argv) == 0
    default = json.loads(capsys.readouterr().out)
    assert main([*argv, "--method", "rk4"]) == 0
    rk4 = json.loads(capsys.readouterr().out)
    for key in ("max_tip_deflection", "residual_tip_deflection"):
        assert default[key] == pytest.approx(rk4[key], rel=1e-8)
    assert default["torque_peak"] == pytest.approx(rk4["torque_peak"], rel=1e-8)
