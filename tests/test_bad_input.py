"""Every bad input gets the one-line error with exit status 2 (issue 13).

Each reproducer of the issue is a parametrized case: the Python loaders raise a
:class:`~casflex.errors.CasflexError` subclass naming the field and value, and the CLI
answers exactly one stderr line and exit status 2, before any heavy work. A fuzz test then
mutates the bundled problem files (huge, tiny and negative numbers, wrong types, unknown
keys, non-UTF-8 bytes, finite but physically impossible values) and requires every failure
of the robot, move, sensor and study loaders to be a CasflexError, and everything they
accept to lie within the plausibility bounds (``casflex._validate.BOUNDS``). The
reproducers of issue 13 part 3 (impossible values, numerical breakdown) are in
``tests/test_faults.py``.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from casflex._cache import CacheError, load_verified, save_verified
from casflex._validate import BOUNDS
from casflex.cli import main
from casflex.design.study import load_study
from casflex.errors import CasflexError, ModelError, ProblemFileError
from casflex.moves import load_move, load_moves
from casflex.robot import Section, load
from casflex.sensors import load_sensors

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "problems" / "arm2link.toml"
MOVES = ROOT / "problems" / "moves.toml"
STRAIN = ROOT / "problems" / "sensors" / "arm2link_strain.toml"
STUDY = ROOT / "problems" / "studies" / "arm2link_move1.toml"
ACCEL = ROOT / "problems" / "sensors" / "arm2link_accel.toml"
TESTBED = ROOT / "problems" / "testbed.toml"
BIG = 10**400  # an integer beyond the float range (TOML integers have no size limit)
NOT_UTF8 = b"\n# \xff\xfe caf\xe9\n"
#: an integer literal of more than 4300 digits (Python will not even print it as an int)
HUGE_LITERAL = "1" + "0" * 4400


def study_text() -> str:
    """The bundled study with absolute paths, so that a copy works from any directory."""
    return STUDY.read_text().replace('"../', f'"{ROOT}/problems/')


TEXTS = {"robot": lambda: ROBOT.read_text(), "moves": lambda: MOVES.read_text(),
         "sensors": lambda: STRAIN.read_text(), "study": study_text,
         "accel": lambda: ACCEL.read_text(), "testbed": lambda: TESTBED.read_text()}


def loader(kind: str, arm):
    return {"robot": load, "testbed": load, "moves": load_moves,
            "sensors": lambda p: load_sensors(p, arm), "accel": lambda p: load_sensors(p, arm),
            "study": load_study}[kind]


def edited(kind: str, old: str, new: str) -> str:
    text = TEXTS[kind]()
    assert old in text, (kind, old)
    return text.replace(old, new, 1)


# (loader, file edit, field named in the error); None: the whole file is not UTF-8
LOADER_CASES = {
    # UnicodeDecodeError in every loader
    "robot-not-utf8": ("robot", None, "<file>"),
    "moves-not-utf8": ("moves", None, "<file>"),
    "sensors-not-utf8": ("sensors", None, "<file>"),
    "study-not-utf8": ("study", None, "<file>"),
    # OverflowError: integers too large for a float
    "robot-E": ("robot", ("E = 69.0e9 ", f"E = {BIG} "), "link[2].material.E"),
    "robot-gravity": ("robot", ("gravity = [0.0, 0.0, -9.81]", f"gravity = [0, 0, {BIG}]"),
                      "gravity"),
    "robot-angle": ("robot", ("value = -90.0", f"value = {BIG}"), "link[1].alpha"),
    "robot-damping": ("robot", ("damping_ratio = 0.0", f"damping_ratio = {-BIG}"),
                      "damping_ratio"),
    "robot-section-a-int": ("robot", ("a = 0.005 ", f"a = {BIG} "), "link[2].section.a"),
    "moves-q0": ("moves", ("q0 = [0.0, 0.0, 0.0]", f"q0 = [0, 0, {BIG}]"), "move1.q0"),
    "moves-duration": ("moves", ("duration = 2.0", f"duration = {BIG}"), "move1.duration"),
    "sensors-s": ("sensors", ("s = 0.05 ", f"s = {BIG} "), "sensor[0].s"),
    "sensors-distance": ("sensors", ("distance = [0.0035, 0.0025]", f"distance = [{BIG}, 1]"),
                         "sensor[0].distance"),
    "sensors-distance-scalar": ("sensors", ("distance = [0.0035, 0.0025]",
                                            f"distance = {BIG}"), "sensor[0].distance"),
    "sensors-noise": ("sensors", ("noise = 3.0e-7", f"noise = {BIG}"), "sensor[0].noise"),
    "study-vtol": ("study", ("vtol = 0.05", f"vtol = {BIG}"), "shaper.vtol"),
    "study-modes": ("study", ("modes = 3 ", f"modes = {BIG} "), "model.modes"),
    "study-R": ("study", ("Q = 5e-9", f"Q = 5e-9\nR = {BIG}"), "estimator.R"),
    # an integer of more than 4300 digits: tomllib raises a plain ValueError
    "robot-huge-literal": ("robot", ("E = 69.0e9 ", f"E = {HUGE_LITERAL} "), "<toml>"),
    # OverflowError inside Section.rectangle / Section.tube
    "robot-section-a-1e300": ("robot", ("a = 0.005 ", "a = 1e300 "), "link[2].section.a"),
    "robot-tube-1e200": ("robot", ('shape = "rectangle"\na = 0.005                     # m, '
                                   'along local y\nb = 0.007',
                                   'shape = "tube"\nouter_diameter = 1e200\nwall = 1e199'),
                         "link[2].section.outer_diameter"),
    # TypeError: a non-string angle unit
    "robot-unit-list": ("robot", ('unit = "deg"', 'unit = ["deg"]'), "link[1].alpha"),
    "robot-unit-table": ("robot", ('unit = "deg"', "unit = {a = 1}"), "link[1].alpha"),
    "robot-unit-int": ("robot", ('unit = "deg"', "unit = 5"), "link[1].alpha"),
}


@pytest.mark.parametrize("case", sorted(LOADER_CASES))
def test_loader_rejects_with_problem_file_error(case, tmp_path, arm):
    kind, edit, field = LOADER_CASES[case]
    path = tmp_path / f"{kind}.toml"
    if edit is None:
        path.write_bytes(TEXTS[kind]().encode() + NOT_UTF8)
    else:
        path.write_text(edited(kind, *edit))
    with pytest.raises(ProblemFileError) as info:
        loader(kind, arm)(path)
    assert info.value.field == field
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_load_move_of_a_non_utf8_file(tmp_path):
    path = tmp_path / "moves.toml"
    path.write_bytes(MOVES.read_bytes() + NOT_UTF8)
    with pytest.raises(ProblemFileError, match="cannot be read"):
        load_move(f"{path}:move1")


@pytest.mark.parametrize("call", [lambda: Section.rectangle(1e300, 1.0),
                                  lambda: Section.rectangle(BIG, 1.0),
                                  lambda: Section.tube(1e200, 1e199)],
                         ids=["rectangle-1e300", "rectangle-bigint", "tube-1e200"])
def test_section_overflow_is_a_model_error(call):
    # the plausibility bound on the dimensions (10 um to 10 m) rejects them before any
    # section property can overflow
    with pytest.raises(ModelError, match=r"must lie in \[1e-05, 10\] m|must be finite"):
        call()


def test_corrupt_gain_schedule_cache_file_reads_as_missing(tmp_path):
    """A truncated or foreign gains-*.npz (zipfile.BadZipFile inside) is recomputed."""
    path = tmp_path / "gains-x.npz"
    save_verified(path, "key", gains=np.ones(3))
    whole = path.read_bytes()
    for corrupt in (whole[: len(whole) // 2], b"PK\x03\x04 not a zip", whole[:-30] + bytes(30)):
        path.write_bytes(corrupt)
        assert load_verified(path, "key") is None
    save_verified(path, "key", gains=np.ones(3))  # and is overwritten in place
    assert load_verified(path, "key")["gains"].tolist() == [1.0, 1.0, 1.0]


@pytest.mark.slow
def test_corrupt_gain_schedule_cache_is_recomputed(tmp_path, arm_model):
    from casflex.control.perturbation import cached_gain_schedule

    model, table = arm_model(1, step_deg=45.0)
    axis = -np.pi + 2 * np.pi * np.arange(8) / 8
    first = cached_gain_schedule(model, 1.0, 10.0, 0.15, table, axis, cache_dir=tmp_path)
    for path in tmp_path.glob("gains-*.npz"):
        path.write_bytes(path.read_bytes()[:100])
    again = cached_gain_schedule(model, 1.0, 10.0, 0.15, table, axis, cache_dir=tmp_path)
    assert not again.info.get("from_cache", False)
    np.testing.assert_array_equal(again.gains, first.gains)


@pytest.mark.parametrize("make", ["file", "under-file"])
def test_unwritable_cache_is_a_cache_error(tmp_path, make):
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    target = blocker / "gains.npz" if make == "file" else blocker / "sub" / "gains.npz"
    with pytest.raises(CacheError, match="--cache-dir") as info:
        save_verified(target, "key", gains=np.ones(2))
    assert isinstance(info.value, CasflexError) and isinstance(info.value, OSError)
    assert str(blocker) in str(info.value)


# ------------------------------------------------------------------------------ the CLI


def cli_cases(tmp: Path) -> dict:
    """verb arguments and the text the one error line must hold."""
    afile = tmp / "afile"
    afile.write_text("")
    missing = tmp / "missing_dir" / "x.png"
    bad_robot, bad_moves, bad_study, bad_sensors = (tmp / f"{k}.toml" for k in
                                                    ("robot", "moves", "study", "sensors"))
    bad_robot.write_bytes(ROBOT.read_bytes() + NOT_UTF8)
    bad_moves.write_bytes(MOVES.read_bytes() + NOT_UTF8)
    bad_study.write_bytes(study_text().encode() + NOT_UTF8)
    bad_sensors.write_bytes(STRAIN.read_bytes() + NOT_UTF8)
    big_e = tmp / "big_e.toml"
    big_e.write_text(edited("robot", "E = 69.0e9 ", f"E = {BIG} "))
    robot, move, study, sensors = str(ROBOT), f"{MOVES}:move1", str(STUDY), str(STRAIN)
    return {
        "design-out-file": (["design", study, "--out", str(afile)],
                            ["--out", str(afile), "existing file"]),
        "design-out-under-file": (["design", study, "--out", str(afile / "sub")],
                                  ["--out", "existing file"]),
        "codegen-out-file": (["codegen", robot, "--sensors", sensors, "--out", str(afile)],
                             ["--out", str(afile), "existing file"]),
        "simulate-plot-missing-dir": (["simulate", robot, "--move", move, "--plot",
                                       str(missing)], ["--plot", str(missing), "not exist"]),
        "simulate-plot-format": (["simulate", robot, "--move", move, "--plot",
                                  str(tmp / "x.docx")], ["--plot", "figure format 'docx'"]),
        "modes-plot-missing-dir": (["modes", robot, "--plot", str(missing)],
                                   ["--plot", str(missing)]),
        "sweep-plot-missing-dir": (["sweep", robot, "--joint", "3", "--from", "0", "--to",
                                    "1", "--step", "1", "--plot", str(missing)],
                                   ["--plot", str(missing)]),
        "accessibility-plot-missing-dir": (["accessibility", robot, "--plot", str(missing)],
                                           ["--plot", str(missing)]),
        "simulate-cache-dir-file": (["simulate", robot, "--move", move, "--modes", "1",
                                     "--step", "45deg", "--cache-dir", str(afile / "c")],
                                    [str(afile), "--cache-dir", "cannot be written"]),
        "modes-robot-not-utf8": (["modes", str(bad_robot)], [str(bad_robot), "<file>"]),
        "modes-robot-bigint": (["modes", str(big_e)], ["link[2].material.E", str(BIG)[:20]]),
        "simulate-move-not-utf8": (["simulate", robot, "--move", f"{bad_moves}:move1"],
                                   [str(bad_moves), "<file>"]),
        "design-study-not-utf8": (["design", str(bad_study), "--out", str(tmp / "o")],
                                  [str(bad_study), "<file>"]),
        "codegen-sensors-not-utf8": (["codegen", robot, "--sensors", str(bad_sensors),
                                      "--out", str(tmp / "c")], [str(bad_sensors), "<file>"]),
    }


CLI_CASES = [
    "design-out-file", "design-out-under-file", "codegen-out-file",
    "simulate-plot-missing-dir", "simulate-plot-format", "modes-plot-missing-dir",
    "sweep-plot-missing-dir", "accessibility-plot-missing-dir", "simulate-cache-dir-file",
    "modes-robot-not-utf8", "modes-robot-bigint", "simulate-move-not-utf8",
    "design-study-not-utf8", "codegen-sensors-not-utf8"]


@pytest.mark.parametrize("case", CLI_CASES)
def test_cli_bad_input_is_one_line_exit_2(case, tmp_path, capsys):
    argv, names = cli_cases(tmp_path)[case]
    status = main(argv + ["--json"])
    out = capsys.readouterr()
    assert status == 2
    lines = out.err.splitlines()
    assert len(lines) == 1, out.err
    assert lines[0].startswith(f"casflex {argv[0]}: error: ")
    for name in names:
        assert name in lines[0]
    assert out.out == ""
    assert not (tmp_path / "missing_dir").exists()


def test_cli_cases_are_all_listed(tmp_path):
    assert sorted(cli_cases(tmp_path)) == sorted(CLI_CASES)


def test_cli_error_message_of_several_lines_is_one_line(capsys, monkeypatch):
    from casflex.commands import modes

    def run(args, log):
        raise ModelError("solver said:\n  line two\n\nline three")

    monkeypatch.setattr(modes, "run", run)
    assert main(["modes", str(ROBOT)]) == 2
    assert capsys.readouterr().err == ("casflex modes: error: solver said: line two "
                                       "line three\n")


# ------------------------------------------------------------------------------ fuzzing

class Literal:
    """TOML text written as is."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return f"Literal({len(self.text)} characters)"


HUGE_AND_TINY = [BIG, -BIG, Literal(HUGE_LITERAL), 2**63, -(2**63), 1e308, -1e308,
                 1.7976931348623157e308, 1e-320, 5e-324, -5e-324, 0, 0.0, -0.0, -1, -1.0, 1,
                 math.nan, math.inf, -math.inf,
                 # issue 13 part 3: finite but physically impossible
                 1e300, -1e300, 1e-300, 1e-308, 1e40, 9e18, 1e5, 1e-5, 1e-3, 100.0, 1e4]
WRONG_TYPES = [True, False, "", "x", "deg", "rad", "\u00ff", "link1", "../nope.toml",
               "rectangle", "strain", [], [1], [1.0, 2.0, 3.0], [[1]], ["deg"], [BIG, 0, 0],
               {}, {"value": 1}, {"value": 90, "unit": 5}, {"value": BIG, "unit": "deg"},
               {"unit": ["deg"]}, {"value": [1], "unit": "rad"}]
# fresh copies: a mutation must never edit the shared lists and tables above
VALUES = st.one_of(st.sampled_from(HUGE_AND_TINY + WRONG_TYPES).map(copy.deepcopy),
                   st.floats(allow_nan=True, allow_infinity=True),
                   st.integers(min_value=-(10**500), max_value=10**500),
                   st.text(max_size=6), st.lists(st.floats(), max_size=4))
BAD_BYTES = [b"\xff", b"\xfe\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\x80", b"\xe9", b"\x00"]


def toml_value(value) -> str:
    """``value`` as an inline TOML value (every table inline, every key quoted)."""
    if isinstance(value, Literal):
        return value.text
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"


def toml_text(doc: dict) -> str:
    return "".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in doc.items())


def places(node, path=()):
    """Every (path, value) of a parsed TOML document, containers included."""
    out = [(path, node)]
    items = node.items() if isinstance(node, dict) else (
        enumerate(node) if isinstance(node, list) else ())
    for key, child in items:
        out += places(child, path + (key,))
    return out


def parent_of(doc, path):
    node = doc
    for key in path[:-1]:
        node = node[key]
    return node


@st.composite
def mutated_files(draw, kind: str) -> bytes:
    """The bundled file of ``kind`` with one to three mutations, as bytes."""
    import tomllib

    doc = tomllib.loads(TEXTS[kind]())
    for _ in range(draw(st.integers(1, 3))):
        spots = [p for p, _ in places(doc) if p]
        path = draw(st.sampled_from(spots))
        parent = parent_of(doc, path)
        action = draw(st.sampled_from(["replace", "replace", "replace", "delete", "add"]))
        if action == "replace":
            parent[path[-1]] = draw(VALUES)
        elif action == "delete":
            del parent[path[-1]]
        else:
            tables = [p for p, v in places(doc) if isinstance(v, dict)]
            table = draw(st.sampled_from(tables))
            node = parent_of(doc, table + ("_",))
            node[draw(st.sampled_from(["colour", "unit", "value", "extra", "link"]))] = draw(
                VALUES)
    data = toml_text(doc).encode()
    if draw(st.booleans()) and draw(st.booleans()):  # one time in four: not UTF-8
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.sampled_from(BAD_BYTES)) + data[at:]
    return data


def assert_plausible(kind: str, result) -> None:
    """What a loader accepts lies within the plausibility bounds (casflex._validate)."""
    def within(quantity, value):
        bound = BOUNDS[quantity]
        assert bound.low <= value <= bound.high, (quantity, value)

    if kind in ("robot", "testbed"):
        for link in result.links:
            for value in (link.a, link.d, *link.tip.com_offset):
                within("offset", value)
            within("tip_mass", link.tip.mass)
            if link.flexible:
                for key in ("E", "G", "rho"):
                    within(key, getattr(link.material, key))
                within("beam_length", link.length)
            if link.joint_stiffness is not None:
                within("joint_stiffness", link.joint_stiffness)
    elif kind == "moves":
        for move in result.values():
            within("move_duration", move.duration)
            for q in (*move.q0, *move.qf):
                within("angle", q)
    elif kind in ("sensors", "accel"):
        for sensor in result:
            if sensor.noise is not None:
                within("noise_strain" if sensor.kind == "strain" else "noise_acceleration",
                       sensor.noise)


def fuzz(kind: str, data: bytes, directory: Path, arm) -> None:
    path = directory / f"fuzz_{kind}.toml"
    path.write_bytes(data)
    try:
        result = loader(kind, arm)(path)
    except CasflexError:
        return  # every failure must be one of these; anything else fails the test
    assert_plausible(kind, result)


FUZZ_SETTINGS = dict(deadline=None, derandomize=True, database=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.mark.parametrize("kind", sorted(TEXTS))
@settings(max_examples=12, **FUZZ_SETTINGS)
@given(data=st.data())
def test_fuzz_loaders_fail_only_with_casflex_errors(kind, data, tmp_path_factory, arm):
    fuzz(kind, data.draw(mutated_files(kind)), tmp_path_factory.getbasetemp(), arm)


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(TEXTS))
@settings(max_examples=2000, **FUZZ_SETTINGS)
@given(data=st.data())
def test_fuzz_loaders_many_examples(kind, data, tmp_path_factory, arm):
    fuzz(kind, data.draw(mutated_files(kind)), tmp_path_factory.getbasetemp(), arm)
