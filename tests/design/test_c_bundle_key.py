"""The key a second design run compares to keep its C bundle (casflex.design.c_bundle_key):
equal for equal inputs, different when anything the bundle is generated from changes."""

from __future__ import annotations

import copy
from pathlib import Path

import casadi as ca

from casflex.design import c_bundle_key, load_study
from casflex.sensors import Accelerometer, SensorSet

STUDY = Path(__file__).resolve().parents[2] / "problems" / "studies" / "arm2link_move1.toml"


def _functions(scale=2.0):
    """A stand-in EKF step and controller, built afresh on every call."""
    x = ca.SX.sym("x", 2)
    return (ca.Function("ekf_step", [x], [scale * x]),
            ca.Function("composite", [x], [ca.sin(x)]))


def test_the_key_is_equal_for_inputs_built_again():
    study, again = load_study(STUDY), load_study(STUDY)
    ekf, ctrl = _functions()
    ekf2, ctrl2 = _functions()
    assert c_bundle_key(study, ekf, ctrl, 1e-3, [1.0, 2.0, 3.0], 5.0) == \
        c_bundle_key(again, ekf2, ctrl2, 1e-3, [1.0, 2.0, 3.0], 5.0)


def test_the_key_changes_with_every_input():
    study = load_study(STUDY)
    ekf, ctrl = _functions()
    base = (study, ekf, ctrl, 1e-3, [1.0, 2.0, 3.0], 5.0)
    key = c_bundle_key(*base)

    def edited(section, field, value):
        s = copy.copy(study)
        setattr(s, section, dict(getattr(s, section), **{field: value}))
        return s

    other_sensors = copy.copy(study)
    other_sensors.sensors = SensorSet([Accelerometer(2, 0.9), *study.sensors.sensors[1:]])
    changed = {
        "ekf": (study, _functions(3.0)[0], ctrl, 1e-3, [1.0, 2.0, 3.0], 5.0),
        "controller": (study, ekf, ca.Function("composite", [ca.SX.sym("x", 2)],
                                               [ca.SX.sym("x", 2) * 0]), 1e-3,
                       [1.0, 2.0, 3.0], 5.0),
        "dt": (study, ekf, ctrl, 2e-3, [1.0, 2.0, 3.0], 5.0),
        "torque limits": (study, ekf, ctrl, 1e-3, [1.0, 2.0, 3.0 + 1e-12], 5.0),
        "unguarded": (study, ekf, ctrl, 1e-3, None, None),
        "gate": (study, ekf, ctrl, 1e-3, [1.0, 2.0, 3.0], 6.0),
        "P0 of the guard": (edited("estimator", "P0", 2e-4), *base[1:]),
        "bundle name": (edited("codegen", "name", "other"), *base[1:]),
        "compile": (edited("codegen", "compile", False), *base[1:]),
        "sensors": (other_sensors, *base[1:]),
    }
    keys = {name: c_bundle_key(*args) for name, args in changed.items()}
    assert all(k != key for k in keys.values()), [n for n, k in keys.items() if k == key]
    assert len(set(keys.values())) == len(keys)
