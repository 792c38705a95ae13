"""The 4-joint design study (issue 21) loads with its settings, and the new keys are
checked like every other (one line naming file, field, value and rule)."""

from pathlib import Path

import numpy as np
import pytest

from casflex.design import load_study
from casflex.errors import ProblemFileError
from casflex.robot import load

ROOT = Path(__file__).resolve().parents[2]
STUDY = ROOT / "problems/studies/arm4_spatial_all_joints.toml"


def test_arm4_study_loads_inside_the_limits():
    s = load_study(STUDY)
    assert s.robot.name == "arm4_spatial_actuated" and s.robot.n_joints == 4
    assert s.model["interpolation"] == "linear"
    assert s.controller["schedule_region"] == "move"
    assert s.controller["schedule_interpolation"] == "linear"
    assert s.estimator["plant_region"] == "move"
    assert s.sensors.n_outputs == 9  # three 3-axis accelerometers
    for q in (s.move.q0, s.move.qf):
        s.robot.within_limits(q)
    # the actuated arm is the bare arm plus motor inertias: the same flexible structure
    bare = load(ROOT / "problems/arm4_spatial.toml")
    assert s.robot.joint_limits == bare.joint_limits
    assert [link.section for link in s.robot.links] == [link.section for link in bare.links]
    assert [link.tip for link in s.robot.links] == [link.tip for link in bare.links]
    inertias = [link.motor_inertia for link in s.robot.links if link.joint == "revolute"]
    np.testing.assert_array_equal(inertias, [21.6e-3, 21.6e-3, 11.0e-3, 3.7e-3])


@pytest.mark.parametrize("key, value", [("model.interpolation", '"cubic"'),
                                        ("controller.schedule_region", '"everywhere"'),
                                        ("controller.schedule_interpolation", "1"),
                                        ("estimator.plant_region", '"grid"')])
def test_new_study_keys_are_checked(tmp_path, key, value):
    section, name = key.split(".")
    text = STUDY.read_text().replace('"../', f'"{ROOT}/problems/')
    lines = [line for line in text.splitlines() if not line.startswith(f"{name} =")]
    text = "\n".join(lines).replace(f"[{section}]", f"[{section}]\n{name} = {value}", 1)
    (tmp_path / "study.toml").write_text(text)
    with pytest.raises(ProblemFileError, match=key.replace(".", r"\.")) as info:
        load_study(tmp_path / "study.toml")
    assert "\n" not in str(info.value)
