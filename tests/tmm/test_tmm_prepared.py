"""The TMM's fast path (issue 17 part 2): prepared set-up, compiled pose, compiled shapes.

* The compiled walk of the DH rows (``Prepared.pose``) against ``build_chain`` and the
  element matrices of ``casflex.tmm.elements`` (an independent implementation: numpy,
  element by element), on every robot of ``problems/`` with a TMM chain.
* The compiled mode shapes (null vector by inverse iteration, fields by angle-addition
  recurrences) against a reference written here (null vector of the same ``subU`` by
  inverse iteration in extended precision, closed-form fields of
  ``casflex.tmm.elements`` at every point): 1e-11 of each field's peak.
* ``modes`` (compiled pose) against the chain path (``build_chain``), and the lazy grid
  counts of the compiled search against the numpy path and the exact counts.
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
    count_below,
    fast,
    kernels,
    mode_shapes,
    modes,
    natural_frequencies,
    sweep_frequencies,
)
from casflex.tmm import elements as el
from casflex.tmm.chain import body_mass_global

ROBOTS = ["arm2link", "testbed", "arm4_spatial", "arm2link_actuated", "arm3_spatial",
          "arm6_3flex", "onelink"]


def sign_flips(new, old):
    """+1/-1 per mode: the unit-peak scaling makes the largest displacement +1; a mode
    whose largest |entry| is reached twice with opposite signs (to round-off) may come
    out with either sign (as in test_roots_and_shapes_with_and_without_kernels)."""
    m = old.displacement.shape[0]
    flip = np.sign(np.sum(new.displacement.reshape(m, -1) * old.displacement.reshape(m, -1),
                          axis=1))
    for k in np.flatnonzero(flip < 0):
        flat = old.displacement[k].ravel()
        assert abs(flat.max() + flat.min()) < 1e-8, f"mode {k} flipped without a tie"
    return flip


def assert_fields_close(new, old, tol, label):
    flip = sign_flips(new, old)
    for field in MODE_FIELDS:
        a, b = getattr(new, field), getattr(old, field)
        a = a * flip.reshape((-1,) + (1,) * (a.ndim - 1))
        scale = np.abs(b).max() if b.size else 1.0  # the field's largest entry
        np.testing.assert_allclose(a, b, rtol=0, atol=tol * scale + 1e-300,
                                   err_msg=f"{field}, {label}")


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


def null_vector_long(A):
    """Unit null vector of the nearly singular A by inverse iteration in extended
    precision (numpy.longdouble, 64-bit mantissa on x86): the reference for both paths."""
    A = A.astype(np.longdouble)
    n = A.shape[0]
    x = np.ones(n, dtype=np.longdouble)
    for _ in range(3):
        a, y = A.copy(), x.copy()
        for k in range(n):  # Gaussian elimination with partial pivoting
            p = k + int(np.argmax(np.abs(a[k:, k])))
            a[[k, p]], y[[k, p]] = a[[p, k]], y[[p, k]]
            if a[k, k] == 0:
                a[k, k] = np.finfo(np.longdouble).eps
            f = a[k + 1:, k] / a[k, k]
            a[k + 1:] -= np.outer(f, a[k])
            y[k + 1:] -= f * y[k]
        for k in range(n - 1, -1, -1):
            y[k] = (y[k] - a[k, k + 1:] @ y[k + 1:]) / a[k, k]
        x = y / np.sqrt(np.sum(y * y))
    return x.astype(float)


def reference_shapes(chain, omega, subs, n_points):
    """The sampled states [u, θ, M, F] (m, beams, points, 12), unit peak displacement:
    null vector of each ``subU`` in extended precision, fields from the public closed
    forms (numpy, element by element)."""
    out = []
    for w, sub in zip(omega, subs, strict=True):
        z = np.concatenate([np.zeros(6), null_vector_long(sub / np.abs(sub).max())])
        beams = []
        for e in chain.elements:
            if e.kind == "beam":
                P = e.params
                sec, mat = P["section"], P["material"]
                s = np.linspace(0.0, 1.0, n_points) * P["length"]
                U = el.beam_field(s, w, mat.E * sec.A, mat.E * sec.Ix, mat.E * sec.Iy,
                                  mat.G * sec.J, mat.rho * sec.A, mat.rho * sec.Ip)
                local = U @ (e.rotation12.T @ z)
                beams.append(local)
                z = e.rotation12 @ local[-1]
            elif e.kind == "body":
                z = el.point_body_matrix(w, body_mass_global(e))[0] @ z
            elif e.kind == "offset":
                z = el.offset_matrix(e.params["r"]) @ z
            else:
                z = el.joint_spring_matrix(e.params["stiffness"], e.params["axis"]) @ z
        states = np.array(beams)
        disp = states[..., 0:3].ravel()
        out.append(states / disp[np.argmax(np.abs(disp))])
    return np.array(out)


@pytest.mark.parametrize("name", ["arm2link", "testbed", "arm4_spatial", "arm3_spatial"])
def test_compiled_shapes_equal_an_extended_precision_reference(name):
    robot = load(f"problems/{name}.toml")
    prepared = fast.prepare(robot)
    for q in np.random.default_rng(17).uniform(-np.pi, np.pi, (3, robot.n_joints)):
        new = modes(robot, q, count=5)
        w = new.omega
        if (new.multiplicity > 1).any():
            continue  # a multiple root takes the numpy path
        # the null vector is that of the compiled path's subU: the shapes of the highest
        # modes amplify a change of subU's round-off 1e6-fold (the numpy path's subU,
        # product in another order, gives shapes 1e-9 apart on arm4_spatial's 5th mode)
        a = prepared.pose(np.asarray(q)[None])
        subs = kernels.system_points(np.zeros(w.size, dtype=np.int64), w, a["kind"],
                                     a["beam"], a["flat"], a["gather"], a["ratio"], a["R3"],
                                     a["M"], a["T"])[:, 6:12, :]
        chain = build_chain(robot, q)
        ref = reference_shapes(chain, w, subs, 51)
        for m in range(w.size):
            for k, field in enumerate(("displacement", "rotation", "moment", "force")):
                x, y = getattr(new, field)[m], ref[m, ..., 3 * k:3 * k + 3]
                sign = np.sign(np.sum(new.displacement[m] * ref[m, ..., 0:3]))
                # each of u, θ, M, F against its own peak: the null vector (inverse
                # iteration in double vs extended precision) carried through the chain
                # (recurrences over 50 points vs closed forms at each point); 1e-11. (The
                # numpy path's SVD null vector is off by up to 1e-9 on these high modes.)
                err = np.abs(sign * x - y).max() / np.abs(y).max()
                assert err <= 1e-11, (field, m, q, err)
        # the derived fields are the states' formulas (ModeShapes docstring)
        beams = chain.beams
        EIx = np.array([b.params["material"].E * b.params["section"].Ix for b in beams])
        GJ = np.array([b.params["material"].G * b.params["section"].J for b in beams])
        np.testing.assert_allclose(new.slope[..., 1], -new.rotation[..., 0], rtol=1e-15)
        np.testing.assert_allclose(new.curvature[..., 1],
                                   -new.moment[..., 0] / EIx[None, :, None], rtol=1e-14)
        np.testing.assert_allclose(new.twist_rate, new.moment[..., 2] / GJ[None, :, None],
                                   rtol=1e-14)


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
        # roots 1e-12 apart move the unit-peak shapes by that times the null vector's
        # sensitivity (as in test_roots_and_shapes_with_and_without_kernels)
        assert_fields_close(shapes, reference, 1e-8, f"q = {q}")


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


@pytest.mark.parametrize("name", ["arm4_spatial", "arm6_3flex", "testbed"])
def test_lazy_grid_counts_find_every_root(name, monkeypatch):
    # the compiled search counts only where the count changes (bisection over the grid
    # indices); the numpy path counts every grid point. The spatial arms have near-double
    # roots (the two bending planes of their links)
    robot = load(f"problems/{name}.toml")
    qs = np.random.default_rng(29).uniform(-np.pi, np.pi, (5, robot.n_joints))
    new = sweep_frequencies(robot, qs, 8)
    monkeypatch.setattr(kernels, "AVAILABLE", False)
    old = sweep_frequencies(robot, qs, 8)
    monkeypatch.undo()
    # the numpy path refines by subdivision + inverse cubic interpolation: 3.0e-11 from
    # Brent on these near-double roots (measured; the same before the lazy counts)
    np.testing.assert_allclose(new, old, rtol=1e-10)
    # no root lost or doubled: the exact count steps by one at every root
    for q, w in zip(qs, new, strict=True):
        chain = build_chain(robot, q)
        gaps = np.minimum(np.diff(w, prepend=0.0), np.diff(w, append=np.inf))
        assert gaps.min() > 1e-8 * w.max()  # simple roots, so ±1e-9 brackets each one
        below = count_below(chain, w * (1.0 - 1e-9))
        above = count_below(chain, w * (1.0 + 1e-9))
        np.testing.assert_array_equal(below, np.arange(w.size))
        np.testing.assert_array_equal(above, np.arange(1, w.size + 1))


@pytest.mark.parametrize("name", ["arm2link", "onelink", "arm4_spatial"])
def test_brent_on_the_determinant_path_equals_brentq_on_the_full_system(name):
    # the compiled Brent evaluates det subU on a shortened chain product: no rotation of
    # the start [0; I], consecutive beams joined by one rotation R_nextᵀ R, and the last
    # beam's rotation back to base components left out (det U[6:12] does not change under
    # blockdiag(R, R)). Reference: scipy's brentq on the determinant of the full system
    # matrix (``system_points``: every rotation made, numpy's LU)
    import scipy.optimize

    robot = load(f"problems/{name}.toml")
    prepared = fast.prepare(robot)
    compared = 0
    for q in np.random.default_rng(5).uniform(-np.pi, np.pi, (3, robot.n_joints)):
        k = prepared.pose(q[None, :])
        w = natural_frequencies(robot, q, count=4)
        if np.any(np.diff(w) < 1e-6 * w[1:]):
            continue  # near-double roots: no sign change in a narrow bracket

        def det(omega, scale, k=k):
            sub = kernels.system_points(np.zeros(1, dtype=np.int64), np.array([omega]),
                                        k["kind"], k["beam"], k["flat"], k["gather"],
                                        k["ratio"], k["R3"], k["M"], k["T"])[0, 6:]
            sign, logabs = np.linalg.slogdet(sub)
            return sign * np.exp(logabs - scale)

        lo, hi = w * (1.0 - 1e-3), w * (1.0 + 1e-3)
        found, ok, _ = kernels.refine_brackets(np.zeros(w.size, dtype=np.int64), lo, hi,
                                               k["kind"], k["beam"], k["flat"], k["gather"],
                                               k["ratio"], k["R3"], k["M"], k["T"])
        assert ok.all()
        for root, a, b in zip(found, lo, hi, strict=True):
            scale = np.linalg.slogdet(kernels.system_points(
                np.zeros(1, dtype=np.int64), np.array([a]), k["kind"], k["beam"], k["flat"],
                k["gather"], k["ratio"], k["R3"], k["M"], k["T"])[0, 6:])[1]
            reference = scipy.optimize.brentq(det, a, b, args=(scale,), xtol=1e-14 * a,
                                              rtol=1e-15)
            compared += 1
            # both refine to ~1e-13 on determinants equal to round-off (as the compiled
            # and numpy searches in test_tmm_fast.py)
            np.testing.assert_allclose(root, reference, rtol=1e-11, err_msg=f"q = {q}")
    assert compared >= 8
