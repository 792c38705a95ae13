"""The TMM's fast path (issue 17 part 2): prepared set-up, compiled pose, compiled shapes.

* The compiled walk of the DH rows (``Prepared.pose``) against ``build_chain`` and the
  element matrices of ``casflex.tmm.elements`` (an independent implementation: numpy,
  element by element), on every robot of ``problems/`` with a TMM chain.
* The compiled mode shapes (null vector by inverse iteration, fields by angle-addition
  recurrences) against the numpy path (SVD null vector, closed-form fields at every
  point) at the same frequencies: 1e-11 of each field's peak.
* The cache: keyed on the robot's parameters by value, never stale.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from casflex.robot import load
from casflex.tmm import (
    MODE_FIELDS,
    build_chain,
    mode_shapes,
    modes,
    natural_frequencies,
    sweep_frequencies,
)
from casflex.tmm import elements as el
from casflex.tmm import fast, kernels
from casflex.tmm.chain import body_mass_global

ROBOTS = ["arm2link", "testbed", "arm4_spatial", "arm2link_actuated", "arm3_spatial",
          "arm6_3flex", "onelink"]


@pytest.fixture(autouse=True)
def compiled():
    if not kernels.AVAILABLE:
        pytest.skip("numba is not installed: only the numpy path runs")


@pytest.mark.parametrize("name", ROBOTS)
def test_compiled_pose_equals_build_chain(name):
    robot = load(f"problems/{name}.toml")
    qs = np.random.default_rng(5).uniform(-np.pi, np.pi, (3, robot.n_joints))
    arrays = fast.prepare(robot).pose(qs)
    for c, q in enumerate(qs):
        chain = build_chain(robot, q)
        for j, e in enumerate(chain.elements):
            # the same products of the same rotations, summed in another order: round-off
            # of unit-size entries and of metre-size positions
            np.testing.assert_allclose(arrays["R3"][c, j], e.R, rtol=0, atol=1e-14)
            np.testing.assert_allclose(arrays["start"][c, j], e.start, rtol=0, atol=1e-14)
            if e.kind == "body":
                M = body_mass_global(e)
                np.testing.assert_allclose(arrays["M"][c, j], M, rtol=0,
                                           atol=1e-14 * np.abs(M).max())
            elif e.kind == "offset":
                np.testing.assert_allclose(arrays["T"][c, j], el.offset_matrix(e.params["r"]),
                                           rtol=0, atol=1e-14)
                np.testing.assert_allclose(arrays["G"][c, j], el.offset_matrix(
                    e.params["r"])[:6, :6], rtol=0, atol=1e-14)
            elif e.kind == "spring":
                T = el.joint_spring_matrix(e.params["stiffness"], e.params["axis"])
                np.testing.assert_allclose(arrays["T"][c, j], T, rtol=0,
                                           atol=1e-14 * np.abs(T).max())
                np.testing.assert_allclose(arrays["axis"][c, j], e.params["axis"], rtol=0,
                                           atol=1e-14)


@pytest.mark.parametrize("name", ["arm2link", "testbed", "arm4_spatial", "arm3_spatial"])
def test_compiled_shapes_equal_the_numpy_shapes(name, monkeypatch):
    robot = load(f"problems/{name}.toml")
    for q in np.random.default_rng(17).uniform(-np.pi, np.pi, (3, robot.n_joints)):
        chain = build_chain(robot, q)
        w, mult = natural_frequencies(chain, count=5, return_multiplicity=True)
        if (mult > 1).any():
            continue  # a multiple root takes the numpy path in both
        new = mode_shapes(chain, w, mult, n_points=51)
        monkeypatch.setattr(kernels, "AVAILABLE", False)
        old = mode_shapes(chain, w, mult, n_points=51)
        monkeypatch.undo()
        for field in ("omega", "s", "R", "position", "body_position"):
            np.testing.assert_allclose(getattr(new, field), getattr(old, field), rtol=0,
                                       atol=1e-14 * max(1.0, np.abs(getattr(old, field)).max()))
        for attr in ("rows", "body_rows", "spring_rows"):
            assert getattr(new, attr) == getattr(old, attr)
        for field in MODE_FIELDS:
            a, b = getattr(new, field), getattr(old, field)
            for m in range(a.shape[0]):
                # same frequency, same chain: the null vectors of one 6 x 6 matrix (inverse
                # iteration vs SVD) and the fields by recurrence vs closed form differ by
                # round-off times the null vector's condition and the recurrence's 50
                # steps; 1e-11 of each field's peak
                scale = np.abs(b[m]).max() if b[m].size else 1.0
                np.testing.assert_allclose(a[m], b[m], rtol=0, atol=1e-11 * scale + 1e-300,
                                           err_msg=f"{field}, mode {m}, q = {q}")


@pytest.mark.parametrize("name", ["arm2link", "arm4_spatial", "testbed"])
def test_modes_fast_path_equals_the_chain_path(name):
    # modes(robot, q) poses by the compiled walk; natural_frequencies(chain) and
    # mode_shapes(chain) take build_chain's pose: equal to the round-off of the pose
    robot = load(f"problems/{name}.toml")
    for q in np.random.default_rng(23).uniform(-np.pi, np.pi, (3, robot.n_joints)):
        shapes = modes(robot, q, count=5)
        chain = build_chain(robot, q)
        w, mult = natural_frequencies(chain, count=5, return_multiplicity=True)
        reference = mode_shapes(chain, w, mult, n_points=51)
        np.testing.assert_array_equal(shapes.multiplicity, reference.multiplicity)
        # both roots from Brent to 5e-15 on determinants equal to round-off
        np.testing.assert_allclose(shapes.omega, reference.omega, rtol=1e-12)
        for field in MODE_FIELDS:
            a, b = getattr(shapes, field), getattr(reference, field)
            # roots 1e-12 apart move the unit-peak shapes by that times the null vector's
            # sensitivity (as in test_roots_and_shapes_with_and_without_kernels)
            scale = np.abs(b).max() if b.size else 1.0
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-8 * scale, err_msg=field)


def test_the_cache_is_keyed_on_the_parameters():
    arm = load("problems/arm2link.toml")
    assert fast.prepare(arm) is fast.prepare(load("problems/arm2link.toml"))
    # a stiffer link 2: another key, other frequencies, the same as the full path's
    link = arm.links[3]
    stiff = dataclasses.replace(link, material=dataclasses.replace(
        link.material, E=2.0 * link.material.E))
    other = dataclasses.replace(arm, links=(*arm.links[:3], stiff))
    assert fast.prepare(other) is not fast.prepare(arm)
    q = [0.0, 0.3, -0.7]
    w_arm = natural_frequencies(arm, q, count=4)
    w_other = natural_frequencies(other, q, count=4)
    assert np.all(np.abs(w_other / w_arm - 1.0) > 1e-3)
    np.testing.assert_allclose(w_other, natural_frequencies(build_chain(other, q), count=4),
                               rtol=1e-12)
    # bounded
    for k in range(fast.CACHE_SIZE + 3):
        fast.prepare(dataclasses.replace(arm, links=(*arm.links[:3], dataclasses.replace(
            link, material=dataclasses.replace(link.material, E=(1.0 + k / 100) * 69e9)))))
    assert len(fast.CACHE) <= fast.CACHE_SIZE


def test_a_refused_robot_is_refused_with_the_full_message():
    # a robot check_chain refuses is cached as "full path": the message names the q
    from casflex.errors import ModelError
    arm = load("problems/arm2link.toml")
    link = arm.links[3]
    material = dataclasses.replace(link.material)
    object.__setattr__(material, "E", 1e40)  # behind Material's own check, as a bug could
    robot = dataclasses.replace(arm, links=(*arm.links[:3], dataclasses.replace(
        link, material=material)))
    for q in ([0.0, 0.0, 0.0], [0.1, 0.2, 0.3]):
        with pytest.raises(ModelError, match=r"ill-conditioned at q = \[0\.1|\[0\., 0\."):
            natural_frequencies(robot, q, count=2)
    assert fast.prepare(robot) is None


@pytest.mark.parametrize("name", ["arm4_spatial", "arm6_3flex"])
def test_lazy_grid_counts_find_the_numpy_search_roots(name, monkeypatch):
    # the compiled search counts only where the count changes (bisection over the grid
    # indices); the numpy path counts every grid point: same brackets, same roots. The
    # spatial arms have near-double roots (two bending planes of a near-square section)
    robot = load(f"problems/{name}.toml")
    qs = np.random.default_rng(29).uniform(-np.pi, np.pi, (5, robot.n_joints))
    new = sweep_frequencies(robot, qs, 8)
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    old = sweep_frequencies(robot, qs, 8)
    monkeypatch.undo()
    # Brent (compiled) vs subdivision + inverse cubic interpolation (numpy), as in
    # test_compiled_search_equals_the_numpy_search
    np.testing.assert_allclose(new, old, rtol=1e-11)
