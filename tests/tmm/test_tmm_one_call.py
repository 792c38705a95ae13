"""One configuration in one compiled call (issue 17 part 2, ``casflex.tmm.one_call``).

``one_call.single`` calls the kernels of the four-call path (the pose, the root search,
the system matrix at the roots, the shapes) from one compiled function, with the same
arguments in the same order: its roots and fields must be those of the four separate
calls bit for bit (``fast.roots`` + ``fast.compiled_shapes``, which the other tests of
tests/tmm check against independent references: the extended-precision shapes, the
chain path, brentq, the exact counts). And whatever the four-call path hands to the
numpy path (multiple roots, a q to refuse, a robot not prepared) must still go there.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.robot import load
from casflex.tmm import MODE_FIELDS, fast, kernels, modes, natural_frequencies, one_call

ROBOTS = ["arm2link", "testbed", "arm4_spatial", "arm2link_actuated", "arm3_spatial",
          "arm6_3flex", "onelink"]


@pytest.fixture(autouse=True)
def compiled():
    if not kernels.AVAILABLE:
        pytest.skip("numba is not installed: only the numpy path runs")


def four_calls(robot, q, count, omega_max, n_points):
    """The path before one_call: fast.roots, then fast.compiled_shapes."""
    found, posed = fast.roots(robot, q, count, omega_max, 1e-9, 1e-12)
    if found is None:
        return None
    w, mult = found[0]
    fields = None
    if (mult == 1).all():
        fields = fast.compiled_shapes(posed[0].shape_layout(n_points), posed[1], w, mult)
    return w, mult, fields


@pytest.mark.parametrize("name", ROBOTS)
def test_one_call_equals_the_four_calls_bit_for_bit(name):
    robot = load(f"problems/{name}.toml")
    qs = np.random.default_rng(41).uniform(-np.pi, np.pi, (4, robot.n_joints))
    for q in qs:
        for count, omega_max in ((5, None), (None, 60.0), (3, 40.0)):
            new = one_call.single(robot, q, count, omega_max, 1e-9, 1e-12, 21)
            old = four_calls(robot, q, count, omega_max, 21)
            assert (new is None) == (old is None)
            if new is None:
                continue
            np.testing.assert_array_equal(new[0], old[0])
            np.testing.assert_array_equal(new[1], old[1])
            assert (new[2] is None) == (old[2] is None)
            if old[2] is None:
                continue
            assert new[2].keys() == old[2].keys()
            for key, value in old[2].items():
                if isinstance(value, np.ndarray):
                    assert new[2][key].shape == value.shape, key
                    np.testing.assert_array_equal(new[2][key], value, err_msg=key)
                else:
                    assert new[2][key] == value, key
            # the frequencies alone: the same roots
            alone = one_call.single(robot, q, count, omega_max, 1e-9, 1e-12, 0)
            np.testing.assert_array_equal(alone[0], old[0])
            assert alone[2] is None


def test_multiple_roots_keep_the_numpy_shapes():
    # arm2link with link 2 folded onto link 1 (q3 = 90°): every root is double. The one
    # call hands back the roots without fields; modes makes the numpy path's basis
    robot = load("problems/arm2link.toml")
    q = np.array([0.0, 0.0, np.pi / 2])
    w, mult, fields = one_call.single(robot, q, 4, None, 1e-9, 1e-12, 51)
    assert fields is None and (mult == 2).all()
    np.testing.assert_array_equal(w, fast.roots(robot, q, 4, None, 1e-9, 1e-12)[0][0][0])
    shapes = modes(robot, q, count=4)
    np.testing.assert_array_equal(shapes.omega, w)
    for field in MODE_FIELDS:
        assert getattr(shapes, field).shape[0] == 4


def test_refused_q_and_robots_take_the_full_path():
    robot = load("problems/arm2link.toml")
    for q in ([0.0, np.nan, 0.0], [0.0, 0.0], [[0.0, 0.0, 0.0]], "abc"):
        assert one_call.single(robot, q, 2, None, 1e-9, 1e-12, 11) is None
    with pytest.raises((ModelError, ValueError)):
        natural_frequencies(robot, [0.0, np.nan, 0.0], count=2)
    assert one_call.single(robot, [0.0, 0.0, 0.0], 2, -1.0, 1e-9, 1e-12, 11) is None
    # a robot check_chain refuses is not prepared: the full path raises its message
    link = robot.links[3]
    material = dataclasses.replace(link.material)
    object.__setattr__(material, "E", 1e40)
    bad = dataclasses.replace(robot, links=(*robot.links[:3], dataclasses.replace(
        link, material=material)))
    assert one_call.single(bad, [0.1, 0.2, 0.3], 2, None, 1e-9, 1e-12, 11) is None
    with pytest.raises(ModelError, match="ill-conditioned"):
        modes(bad, [0.1, 0.2, 0.3], count=2)


def test_alternating_robots_get_their_own_set_ups():
    # the one call takes the set-up prepare finds for the robot's links: a robot with
    # other links (a stiffer link 2) called in turn gets its own set-up and frequencies
    arm = load("problems/arm2link.toml")
    link = arm.links[3]
    stiff = dataclasses.replace(arm, links=(*arm.links[:3], dataclasses.replace(
        link, material=dataclasses.replace(link.material, E=2.0 * link.material.E))))
    q = [0.0, 0.3, -0.7]
    for _ in range(2):
        w_arm = natural_frequencies(arm, q, count=3)
        w_stiff = natural_frequencies(stiff, q, count=3)
        assert fast.prepare(arm) is not fast.prepare(stiff)
        # bending frequencies scale with sqrt(E) where link 2 dominates: clearly apart
        assert np.all(np.abs(w_stiff / w_arm - 1.0) > 1e-3)
