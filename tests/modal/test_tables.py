"""Modal tables: shape joints, cache keys, resumable builds, Dask, interpolants."""

import dataclasses
import functools
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from casflex.errors import ModelError
from casflex.modal.tables import (
    ModalTable,
    build_table,
    robot_fingerprint,
    shape_joints,
)
from casflex.tmm import natural_frequencies

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ shape joints


def test_shape_joint_rule(arm, testbed):
    assert shape_joints(arm) == (2,)  # q1, q2 rotate the clamped structure rigidly
    assert shape_joints(testbed) == (1, 2)  # the joint-1 spring is about the q1 axis


@pytest.mark.parametrize("name", ["arm", "testbed"])
def test_frequencies_independent_of_excluded_joints(name, arm, testbed):
    robot = {"arm": arm, "testbed": testbed}[name]
    joints = shape_joints(robot)
    rng = np.random.default_rng(7)
    base = rng.uniform(-np.pi, np.pi, robot.n_joints)
    w0 = natural_frequencies(robot, base, count=4)
    for k in range(robot.n_joints):
        q = base.copy()
        q[k] += 0.9
        w = natural_frequencies(robot, q, count=4)
        if k in joints:
            assert np.max(np.abs(w / w0 - 1)) > 1e-3, f"joint {k} should change the modes"
        else:
            np.testing.assert_allclose(w, w0, rtol=1e-8)


def test_spring_about_another_axis_makes_a_shape_joint(arm):
    links = list(arm.links)
    links[0] = dataclasses.replace(links[0], joint_stiffness=50.0)  # about z0: q1 still free
    assert shape_joints(dataclasses.replace(arm, links=tuple(links))) == (1, 2)


# ------------------------------------------------------------------ cache and keys


def test_the_cached_modes_key_covers_every_tmm_module(monkeypatch):
    # every module of casflex/tmm computes modes on some path (numpy or the compiled
    # kernels), so a change to any of them must invalidate the cached raw modes
    import casflex.modal.tablekeys as tablekeys
    import casflex.tmm

    seen = []
    monkeypatch.setattr(tablekeys, "source_digest",
                        lambda *modules: seen.extend(m.__name__ for m in modules) or "x")
    tablekeys.tmm_digest()
    package = Path(casflex.tmm.__file__).parent
    modules = {f"casflex.tmm.{p.stem}" for p in package.glob("*.py") if p.stem != "__init__"}
    assert modules and modules <= set(seen), sorted(modules - set(seen))
    assert "casflex.robot" in seen


def test_changing_a_parameter_forces_a_rebuild(arm, tmp_path):
    grid = np.radians(np.arange(0.0, 50.0, 10.0))
    kw = dict(quantities=False, cache_dir=tmp_path, processes=1)
    first = build_table(arm, grid, 3, **kw)
    assert first.info["computed_modes"] == grid.size and not first.info["from_cache"]
    again = build_table(arm, grid, 3, **kw)
    assert again.info["from_cache"] and again.info["key"] == first.info["key"]
    np.testing.assert_array_equal(again.omega, first.omega)
    # renaming or moving the file does not matter ...
    renamed = dataclasses.replace(arm, name="other", source="/elsewhere.toml")
    assert robot_fingerprint(renamed) == robot_fingerprint(arm)
    assert build_table(renamed, grid, 3, **kw).info["from_cache"]
    # ... a material, a tip body or a spring does
    links = list(arm.links)
    mat = dataclasses.replace(links[3].material, E=0.9 * links[3].material.E)
    stiffer = dataclasses.replace(arm, links=(*links[:3], dataclasses.replace(
        links[3], material=mat)))
    rebuilt = build_table(stiffer, grid, 3, **kw)
    assert rebuilt.info["key"] != first.info["key"]
    assert rebuilt.info["modes_key"] != first.info["modes_key"]
    assert rebuilt.info["computed_modes"] == grid.size and not rebuilt.info["from_cache"]
    assert np.all(rebuilt.omega < first.omega)
    tip = dataclasses.replace(links[3], tip=dataclasses.replace(links[3].tip, mass=0.1))
    heavy = dataclasses.replace(arm, links=(*links[:3], tip))
    assert robot_fingerprint(heavy) != robot_fingerprint(arm)
    # a different grid or mode count is a different table
    assert build_table(arm, grid[:-1], 3, **kw).info["key"] != first.info["key"]
    assert build_table(arm, grid, 2, **kw).info["modes_key"] != first.info["modes_key"]


def test_stale_or_foreign_point_file_is_never_read(arm, tmp_path):
    grid = np.radians([0.0, 10.0, 20.0, 30.0])
    kw = dict(quantities=False, cache_dir=tmp_path, processes=1)
    first = build_table(arm, grid, 3, **kw)
    mdir = next(tmp_path.glob("modes-*"))
    tdir = next(tmp_path.glob("table-*"))
    (tdir / "table.npz").unlink()
    # overwrite one point with another point's file (its key is right, but make it
    # foreign by re-saving with a wrong key) and truncate another
    with np.load(mdir / "p0000001.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["__key__"] = np.array("not-this-table")
    np.savez(mdir / "p0000001.npz", **arrays)
    (mdir / "p0000002.npz").write_bytes(b"truncated")
    again = build_table(arm, grid, 3, **kw)
    assert again.info["computed_modes"] == 2 and again.info["cached_modes"] == 2
    np.testing.assert_allclose(again.omega, first.omega, rtol=1e-12)


def counting_quantities(robot, q, shapes, count_dir=None):
    """Test quantity function: counts its calls in files, fails on demand.

    ``count_dir`` can be bound with functools.partial for runs in worker processes (a
    forkserver started earlier in the session does not see variables set by a test); the
    failure point comes from the environment and is only used in-process.
    """
    count_dir = Path(count_dir or os.environ["CASFLEX_TEST_COUNT_DIR"])
    fail_after = int(os.environ.get("CASFLEX_TEST_FAIL_AFTER", "-1"))
    done = len(list(count_dir.glob("call-*")))
    if 0 <= fail_after <= done:
        raise RuntimeError("simulated crash")
    (count_dir / f"call-{uuid.uuid4().hex}").touch()
    return {"omega2": np.asarray(shapes.omega) ** 2,
            "tip": np.asarray(shapes.displacement)[:, -1, -1, :]}


def test_interrupted_quantities_resume_without_recomputing(arm, tmp_path, monkeypatch):
    grid = np.radians(np.arange(0.0, 80.0, 10.0))
    count_dir = tmp_path / "calls"
    count_dir.mkdir()
    monkeypatch.setenv("CASFLEX_TEST_COUNT_DIR", str(count_dir))
    monkeypatch.setenv("CASFLEX_TEST_FAIL_AFTER", "3")
    kw = dict(quantities=counting_quantities, cache_dir=tmp_path / "cache", processes=1)
    with pytest.raises(RuntimeError, match="simulated crash"):
        build_table(arm, grid, 3, **kw)
    assert len(list(count_dir.glob("call-*"))) == 3
    monkeypatch.setenv("CASFLEX_TEST_FAIL_AFTER", "-1")
    table = build_table(arm, grid, 3, **kw)
    assert table.info["computed_modes"] == 0  # the TMM stage had finished
    assert table.info["computed_quantities"] == grid.size - 3
    assert len(list(count_dir.glob("call-*"))) == grid.size  # each point exactly once
    np.testing.assert_allclose(table.values["omega2"], table.omega**2)
    assert table.values["tip"].shape == (grid.size, 3, 3)


def test_killed_build_resumes_where_it_stopped(arm, tmp_path):
    cache = tmp_path / "cache"
    code = (
        "import numpy as np\n"
        "from casflex.robot import load\n"
        "from casflex.modal.tables import build_table\n"
        f"robot = load({str(ROOT / 'problems/arm2link.toml')!r})\n"
        "grid = np.linspace(-1.5, 1.5, 90)\n"
        f"build_table(robot, grid, 3, quantities=False, cache_dir={str(cache)!r}, "
        "processes=1)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            done = list(cache.glob("modes-*/p*.npz"))
            if len(done) >= 8:
                break
            assert proc.poll() is None, "the build finished before it could be killed"
            time.sleep(0.005)
        proc.kill()
    finally:
        proc.wait()
    before = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns)
              for p in cache.glob("modes-*/p*.npz")}
    assert 8 <= len(before) < 90
    assert not list(cache.glob("table-*/table.npz"))
    table = build_table(arm, np.linspace(-1.5, 1.5, 90), 3, quantities=False,
                        cache_dir=cache, processes=1)
    assert table.info["cached_modes"] == len(before)
    assert table.info["computed_modes"] == 90 - len(before)
    for p in cache.glob("modes-*/p*.npz"):  # finished points were not rewritten
        if p.name in before:
            assert (p.stat().st_ino, p.stat().st_mtime_ns) == before[p.name]
    assert not list(cache.glob("**/*.tmp"))  # nothing half-written is left behind


# ------------------------------------------------------------------ parallel back ends


@pytest.mark.filterwarnings("ignore:modal table of 'arm2link'")  # the coarse turn's MAC
def test_dask_cluster_gives_the_same_table_as_the_process_pool(arm, tmp_path, monkeypatch):
    # the Dask builds keep the raw modes on the workers (tables.KEEP_ON_WORKERS): the
    # tracking runs on per-point data and the tracked points are made on the workers;
    # the pool and in-process builds bring every point's shapes here. Bit for bit equal.
    distributed = pytest.importorskip("distributed")
    from casflex.modal import tables

    grid = np.radians(np.arange(60.0, 121.0, 7.5))  # through the double root at 90 deg
    kw = dict(quantities=functools.partial(counting_quantities, count_dir=str(tmp_path)),
              cache_dir=False)
    turn = np.linspace(-np.pi, np.pi, 8, endpoint=False)  # a full turn: periodic check
    pool = build_table(arm, grid, 4, processes=2, **kw)
    local = build_table(arm, turn, 3, cache_dir=False, processes=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        assert tables.KEEP_ON_WORKERS
        dask = build_table(arm, grid, 4, client=client, **kw)
        dask_turn = build_table(arm, turn, 3, cache_dir=False, client=client)
    assert pool.info["shifted_points"] == 1  # q3 = 90 deg: modes from the vicinity
    assert local.periodic == dask_turn.periodic == (True,)
    timings = ("seconds", "seconds_modes", "seconds_tracking", "seconds_quantities")
    for ours, theirs in ((dask, pool), (dask_turn, local)):
        np.testing.assert_array_equal(ours.omega, theirs.omega)
        assert sorted(ours.values) == sorted(theirs.values)
        for name in theirs.values:
            np.testing.assert_array_equal(ours.values[name], theirs.values[name])
        assert {k: v for k, v in ours.info.items() if k not in timings} == {
            k: v for k, v in theirs.info.items() if k not in timings}


# ------------------------------------------------------------------ interpolants


def test_interpolant_reproduces_the_table_at_grid_points(arm, tmp_path):
    grid = np.radians(np.arange(0.0, 61.0, 5.0))
    table = build_table(arm, grid, 3, quantities=False, cache_dir=tmp_path, processes=1)
    for method in ("bspline", "linear"):
        f = table.function("omega", method)
        g = table.function("displacement", method)
        for i in (0, 4, grid.size - 1):
            np.testing.assert_allclose(f(grid[i]).full().ravel(), table.omega[i],
                                       rtol=1e-10)
            np.testing.assert_allclose(g(grid[i]).full().ravel(),
                                       table.values["displacement"][i].ravel(),
                                       rtol=1e-9, atol=1e-12)
    # between grid points the B-spline follows the TMM closely
    mid = np.radians(27.5)
    exact = np.sort(natural_frequencies(arm, [0, 0, mid], count=5))[:3]
    np.testing.assert_allclose(np.sort(table.function("omega")(mid).full().ravel()),
                               exact, rtol=1e-3)
    with pytest.raises(ModelError, match="no quantity"):
        table.function("nope")
    with pytest.raises(ModelError, match="method"):
        table.function("omega", "cubic")


def test_matrix_values_keep_their_shape_and_periodic_axes_wrap():
    axis = np.linspace(-np.pi, np.pi, 13)  # closed: both ends are the same configuration
    vals = np.stack([np.array([[np.cos(a), np.sin(a)], [2.0, np.cos(2 * a)]]) for a in axis])
    table = ModalTable(grid=(axis,), shape_joints=(2,), values={"M": vals},
                       omega=np.ones((axis.size, 1)), periodic=(True,))
    f = table.function("M")
    assert f(0.3).shape == (2, 2)
    np.testing.assert_allclose(f(axis[3]).full(), vals[3], atol=1e-12)
    for x in (-3.0, 0.4, 3.1):
        np.testing.assert_allclose(f(x + 2 * np.pi).full(), f(x).full(), atol=1e-12)
    # smooth across the seam: the spline sees the data on both sides of +-pi
    np.testing.assert_allclose(f(np.pi - 0.05).full()[0, 0], np.cos(np.pi - 0.05), atol=2e-3)


def test_full_turn_table_is_periodic(arm, tmp_path):
    grid = np.linspace(-np.pi, np.pi, 73)  # 5 deg
    table = build_table(arm, grid, 3, quantities=False, cache_dir=tmp_path, processes=2)
    assert table.periodic == (True,)
    assert table.info["min_mac"] > 0.8
    f = table.function("omega")
    np.testing.assert_allclose(f(np.pi + 0.2).full(), f(-np.pi + 0.2).full(), rtol=1e-12)


def test_default_quantities_are_tabulated(arm, tmp_path):
    grid = np.radians([80.0, 85.0, 90.0, 95.0, 100.0])
    table = build_table(arm, grid, 3, cache_dir=tmp_path, processes=2)
    assert {"omega", "C1", "C2", "N"} <= set(table.values)
    assert table.values["C1"].shape[:1] == (grid.size,)
    # mass normalised and sign-continuous: the link-local modal mass block stays smooth
    N = table.values["N"]
    assert np.all(np.abs(np.diff(N, axis=0)) < 0.5)
    f = table.function("C1")
    np.testing.assert_allclose(f(grid[2]).full().ravel(),
                               table.values["C1"][2].reshape(-1), rtol=1e-9, atol=1e-12)


def test_coarse_grid_warns(arm, tmp_path):
    with pytest.warns(RuntimeWarning, match="refine the grid"):
        build_table(arm, np.radians(np.arange(45.0, 136.0, 15.0)), 4, quantities=False,
                    cache_dir=False, processes=1)


def test_bad_grids_are_rejected(arm, tmp_path):
    kw = dict(quantities=False, cache_dir=tmp_path, processes=1)
    with pytest.raises(ModelError, match="increasing"):
        build_table(arm, [0.3, 0.2, 0.1], 3, **kw)
    with pytest.raises(ModelError, match="axes"):
        build_table(arm, [[0.1, 0.2], [0.1, 0.2]], 3, **kw)
    with pytest.raises(ModelError, match="n_modes"):
        build_table(arm, [0.1, 0.2], 0, **kw)
    table = build_table(arm, [0.1, 0.2, 0.3], 2, **kw)
    with pytest.raises(ModelError, match="at least 4"):
        table.function("omega")
    assert table.function("omega", "linear")(0.15).shape == (2, 1)
