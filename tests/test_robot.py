"""Robot descriptions: loading, geometry, and every ProblemFileError rule."""

import dataclasses
import math
import tomllib

import numpy as np
import pytest

from casflex.errors import ModelError, ProblemFileError
from casflex.robot import Section, load, loads, rectangle_torsion_constant

try:
    from reference_fem import dh_frames, section_constants
except ImportError:  # pragma: no cover - when tests/ is imported as a package
    from tests.reference_fem import dh_frames, section_constants

FLEX = """
[[link]]
joint = "revolute"
d = 1.0
[link.section]
shape = "rectangle"
a = 0.005
b = 0.007
[link.material]
E = 69e9
G = 26.9e9
rho = 2700.0
"""


def test_shipped_problem_files_load():
    arm = load("problems/arm2link.toml")
    assert arm.n_joints == 3
    assert [link.length for link in arm.flexible_links] == [1.0, 1.0]
    assert arm.flexible_links[0].beam_along == "a"
    assert arm.flexible_links[1].beam_along == "d"
    bed = load("problems/testbed.toml")
    assert [link.joint_stiffness for link in bed.links[:3]] == [120.0, 100.0, 90.0]
    tube = bed.flexible_links[0].section
    assert tube.kind == "tube" and tube.J == tube.Ip


def test_frames_follow_modified_dh():
    """Tip of the Table 8 arm by hand: link 1 along x0, link 2 hanging down at q = 0."""
    arm = load("problems/arm2link.toml")
    np.testing.assert_allclose(arm.frames([0, 0, 0])[-1][:3, 3], [1, 0, -1], atol=1e-15)
    # q1 rotates about the vertical; q2 lifts link 1 (z2 = y0 at q1 = 0)
    T = arm.frames([math.pi / 2, 0, 0])[-1]
    np.testing.assert_allclose(T[:3, 3], [0, 1, -1], atol=1e-12)
    T = arm.frames([0, 0, -math.pi / 2])[-1]  # elbow folds link 2 along +x
    np.testing.assert_allclose(T[:3, 3], [2, 0, 0], atol=1e-12)


def test_rectangle_section_and_torsion_constant():
    s = Section.rectangle(0.005, 0.007)  # a along y, b along x
    # second moments of a few 1e-11 m^4: pytest.approx's default abs = 1e-12 would accept
    # anything within 1 %; closed forms, so round-off (1e-12 relative, abs = 0)
    assert s.Ix == pytest.approx(0.007 * 0.005**3 / 12, rel=1e-12, abs=0)
    assert s.Iy == pytest.approx(0.005 * 0.007**3 / 12, rel=1e-12, abs=0)
    assert s.Ip == pytest.approx(s.Ix + s.Iy, rel=1e-12, abs=0)
    # St-Venant constants of rectangles (Timoshenko & Goodier table: k1 a b^3)
    for ratio, k1 in [(1.0, 0.1406), (2.0, 0.2287), (4.0, 0.2808), (10.0, 0.3123)]:
        assert rectangle_torsion_constant(ratio, 1.0) == pytest.approx(k1 * ratio, rel=2e-3)
    # thin strip tends to a b^3 / 3 (1 - 0.630 b/a)
    assert rectangle_torsion_constant(100.0, 1.0) == pytest.approx(
        100.0 / 3.0 * (1 - 0.630 / 100.0), rel=1e-3)


@pytest.mark.parametrize("table", [
    {"shape": "rectangle", "a": 0.005, "b": 0.007},
    {"shape": "rectangle", "a": 0.02, "b": 0.004},
    {"shape": "tube", "outer_diameter": 0.0127, "wall": 0.00041},
])
def test_section_constants_match_independent_formulas(table):
    # reference_fem computes A, Ix, Iy, J (Saint-Venant's series, its own code) and Ip from
    # the file's numbers; both sides are closed forms: agreement to round-off (1e-12)
    section = (Section.rectangle(table["a"], table["b"]) if table["shape"] == "rectangle"
               else Section.tube(table["outer_diameter"], table["wall"]))
    ref = section_constants(table)
    for key in ("A", "Ix", "Iy", "Ip"):
        assert getattr(section, key) == pytest.approx(ref[key], rel=1e-12, abs=0), key
    # J: casflex sums 50 odd terms of the series, whose tail (~1/(4·100⁴) of a sum of ~1)
    # leaves ~1e-9; the reference sums 200. 1e-8 allowed (a 0.05 % error is 5e-4)
    assert section.J == pytest.approx(ref["J"], rel=1e-8, abs=0)


def test_frames_match_independent_dh_walk(rng):
    # reference_fem.dh_frames walks the rows of the file itself (tomllib, own rotations)
    for name in ("arm2link", "testbed"):
        robot = load(f"problems/{name}.toml")
        with open(f"problems/{name}.toml", "rb") as fh:
            rows = tomllib.load(fh)["link"]
        for _ in range(3):
            q = rng.uniform(-np.pi, np.pi, robot.n_joints)
            np.testing.assert_allclose(robot.frames(q), np.array(dh_frames(rows, q)),
                                       rtol=0, atol=1e-14)


def test_angles_accept_units():
    r = loads('[[link]]\njoint = "revolute"\nalpha = { value = 90, unit = "deg" }\n')
    assert r.links[0].alpha == pytest.approx(math.pi / 2)


def _err(text, match):
    with pytest.raises(ProblemFileError, match=match) as info:
        loads(text, path="robot.toml")
    assert "robot.toml" in str(info.value)
    return info.value


def test_unknown_and_missing_keys():
    e = _err(FLEX.replace('d = 1.0', 'd = 1.0\nlenght = 2.0'), "unknown key")
    assert e.field == "link[0].lenght"
    _err("name = 'x'\n", "link.*required")
    _err(FLEX.replace('rho = 2700.0', ''), r"link\[0\]\.material\.rho.*required")
    _err(FLEX.replace('[link.material]\nE = 69e9\nG = 26.9e9\nrho = 2700.0', ''),
         "needs both")
    _err(FLEX.replace('shape = "rectangle"', 'shape = "hexagon"'), "must be one of")
    _err("bogus = 1\n" + FLEX, "field 'bogus'.*unknown key")


def test_lengths_and_moduli_rules():
    e = _err(FLEX.replace("d = 1.0", "d = 0.0"), "non-zero length")
    assert e.value == 0.0
    _err(FLEX.replace("d = 1.0", "d = -1.0"), "must be > 0")
    for key in ("E", "G", "rho"):
        old = {"E": "E = 69e9", "G": "G = 26.9e9", "rho": "rho = 2700.0"}[key]
        e = _err(FLEX.replace(old, f"{key} = 0.0"), "must be > 0")
        assert e.field == f"link[0].material.{key}"
        _err(FLEX.replace(old, f"{key} = -5.0"), "must be > 0")


def test_nan_and_inf_rejected():
    e = _err(FLEX.replace("E = 69e9", "E = nan"), "finite")
    assert e.field == "link[0].material.E"
    _err(FLEX.replace("d = 1.0", "d = inf"), "finite")
    _err('[[link]]\njoint = "revolute"\n[link.tip]\nmass = 1.0\ninertia = [0, nan, 0]\n',
         "finite")
    _err("gravity = [0, 0, inf]\n" + FLEX, "finite")


def test_tube_wall_rule():
    tube = FLEX.replace('shape = "rectangle"\na = 0.005\nb = 0.007',
                        'shape = "tube"\nouter_diameter = 0.0127\nwall = 0.00635')
    e = _err(tube, "smaller than the outer radius")
    assert e.field == "link[0].section.wall"
    ok = loads(tube.replace("wall = 0.00635", "wall = 0.00041"))
    assert ok.flexible_links[0].section.kind == "tube"


def test_flexible_link_that_cannot_be_placed():
    """A beam must lie along a or along d (the TMM assembly of §3.2.4), not both."""
    e = _err(FLEX.replace("d = 1.0", "d = 1.0\na = 0.5"), "along a or along d")
    assert e.field == "link[0].d"


def test_other_rules():
    _err('[[link]]\njoint = "fixed"\n', "at least one revolute")
    _err('[[link]]\njoint = "prismatic"\n', "must be one of")
    _err('[[link]]\njoint = "fixed"\njoint_stiffness = 10.0\n', "needs a revolute joint")
    _err('[[link]]\njoint = "revolute"\njoint_stiffness = -1.0\n', "must be > 0")
    _err('[[link]]\njoint = "revolute"\n[link.tip]\nmass = -1.0\n', "must be >= 0")
    _err('[[link]]\njoint = "revolute"\nd = "one"\n', "must be a number")
    _err("damping_ratio = 1.5\n" + FLEX, "must be < 1")
    _err("this is not toml", "not valid TOML")
    with pytest.raises(ProblemFileError, match="cannot be read"):
        load("problems/does-not-exist.toml")


def test_q_is_checked():
    arm = load("problems/arm2link.toml")
    with pytest.raises(ModelError, match="3 joint variables"):
        arm.frames([0.0, 0.0])
    with pytest.raises(ModelError, match="finite"):
        arm.frames([0.0, np.nan, 0.0])


# ------------------------------------------------------------------ joint limits


LIMITED = """
[[link]]
joint = "revolute"
[[link]]
joint = "revolute"
a = 0.5
q_min = { value = -90.0, unit = "deg" }
q_max = 1.0
"""


def test_joint_limits_read_with_units():
    """Limits are angles like the file's others: deg converted to rad, rad as given;
    a row without limits turns freely (None)."""
    robot = loads(LIMITED, path="robot.toml")
    assert robot.joint_limits == (None, (-math.pi / 2.0, 1.0))
    four = load("problems/arm4_spatial.toml")
    assert four.joint_limits[0] is None
    np.testing.assert_allclose(np.degrees(four.joint_limits[2]), [-150.0, 150.0], rtol=1e-15)
    assert load("problems/arm2link.toml").joint_limits == (None, None, None)


def test_arm3_spatial_has_three_shape_joints():
    """problems/arm3_spatial.toml (the 3-D table of benchmarks/bench_tables.py): the
    compliant base makes the shoulder a shape joint beside the elbow and the wrist."""
    from casflex.modal import shape_joints

    arm3 = load("problems/arm3_spatial.toml")
    assert arm3.n_joints == 4 and len(arm3.flexible_links) == 3
    assert shape_joints(arm3) == (1, 2, 3)
    assert arm3.joint_limits[0] is None
    np.testing.assert_allclose([np.degrees(arm3.joint_limits[k][1]) for k in (1, 2, 3)],
                               [100.0, 150.0, 120.0], rtol=1e-15)


def test_joint_limit_rules():
    e = _err(LIMITED.replace("q_max = 1.0", "q_max = -2.0"), "must be > q_min")
    assert e.field == "link[1].q_max" and e.value == -2.0
    e = _err(LIMITED.replace("q_max = 1.0\n", ""), "need both q_min and q_max")
    assert e.field == "link[1].q_max"
    e = _err(LIMITED.replace("q_max = 1.0", "q_max = 1000.0"), "must lie in")
    assert e.field == "link[1].q_max"  # the plausibility bound of angles (BOUNDS["angle"])
    e = _err(LIMITED.replace('joint = "revolute"\na = 0.5', 'joint = "fixed"\na = 0.5'),
             "need a revolute joint")
    assert e.field == "link[1].q_min"
    _err(LIMITED.replace("q_max = 1.0", 'q_max = { value = 1.0, unit = "grad" }'),
         "unknown angle unit")


def test_joint_limits_in_python():
    arm = load("problems/arm2link.toml")
    with pytest.raises(ModelError, match="lower limit must be < the upper"):
        dataclasses.replace(arm, joint_limits=(None, None, (1.0, 1.0)))
    with pytest.raises(ModelError, match="one .low, high. or None per joint"):
        dataclasses.replace(arm, joint_limits=((0.0, 1.0),))
    with pytest.raises(ModelError, match="must lie in"):
        dataclasses.replace(arm, joint_limits=(None, None, (-1.0, 1e3)))
    limited = dataclasses.replace(arm, joint_limits=(None, [-1.0, 2.0], None))
    assert limited.joint_limits == (None, (-1.0, 2.0), None)
    # the limits are inclusive; outside, the message names the joint (1-based) and limits
    limited.within_limits([10.0, 2.0, 0.0])
    with pytest.raises(ModelError, match=r"q2 = 171\.887 deg .* \[-57\.296, 114\.592\] deg"):
        limited.within_limits([0.0, 3.0, 0.0], "target")


def test_move_outside_the_limits_is_refused_by_simulate():
    """Where the move meets the robot (casflex simulate), before any table is built."""
    import argparse

    from casflex.commands import simulate

    p = argparse.ArgumentParser()
    simulate.add_arguments(p)
    args = p.parse_args(["problems/arm4_spatial.toml", "--move", "problems/moves.toml:move1"])
    with pytest.raises(ModelError, match="4 joints"):
        simulate.run(args, print)
    # the Table 8 move 1 on a copy of the arm whose elbow stops at -45 deg
    import tempfile
    from pathlib import Path

    text = Path("problems/arm2link.toml").read_text().replace(
        'joint = "revolute"            # q3', 'q_min = { value = -45.0, unit = "deg" }\n'
        'q_max = { value = 45.0, unit = "deg" }\njoint = "revolute"            # q3')
    with tempfile.TemporaryDirectory() as tmp:
        robot_file = Path(tmp) / "limited.toml"
        robot_file.write_text(text)
        args = p.parse_args([str(robot_file), "--move", "problems/moves.toml:move1"])
        with pytest.raises(ModelError, match=r"target qf: q3 = -57\.296 deg"):
            simulate.run(args, print)
