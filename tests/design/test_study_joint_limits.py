"""A study whose move leaves the robot's joint limits is refused when it loads."""

from pathlib import Path

import pytest

from casflex.design import load_study
from casflex.errors import ProblemFileError

ROOT = Path(__file__).resolve().parents[2]


def test_move_outside_the_joint_limits_is_refused(tmp_path):
    robot = (ROOT / "problems/arm2link_actuated.toml").read_text()
    # q3 (the elbow, the third revolute row) limited to ±0.5 rad; move 1 takes it to -1 rad
    blocks = robot.split("[[link]]")
    third = [i for i, b in enumerate(blocks) if 'joint = "revolute"' in b][2]
    lines = blocks[third].split("\n")
    lines.insert(1, "q_min = -0.5\nq_max = 0.5")
    blocks[third] = "\n".join(lines)
    limited = "[[link]]".join(blocks)
    (tmp_path / "robot.toml").write_text(limited)
    study = (ROOT / "problems/studies/arm2link_move1.toml").read_text()
    study = study.replace('robot = "../arm2link_actuated.toml"', 'robot = "robot.toml"')
    study = study.replace('"../moves.toml:move1"', f'"{ROOT / "problems/moves.toml"}:move1"')
    study = study.replace('"../sensors/arm2link_accel.toml"',
                          f'"{ROOT / "problems/sensors/arm2link_accel.toml"}"')
    (tmp_path / "study.toml").write_text(study)
    with pytest.raises(ProblemFileError, match=r"joint limits.*q3") as info:
        load_study(tmp_path / "study.toml")
    assert "\n" not in str(info.value)
    # without the limits the same study loads
    (tmp_path / "robot.toml").write_text(robot)
    assert load_study(tmp_path / "study.toml").move.name == "move1"
