"""The shared cache mechanisms (casflex._cache) and their use by the JIT, tables, plants."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from casflex._cache import (
    atomic_write_text,
    build_shared,
    load_verified,
    remove_stale_files,
    save_verified,
    staged_directory,
)

# ---- content digest


def _rewrite_npz(path, change):
    """Rewrite the .npz at ``path`` with ``change(arrays)`` applied, every other array
    (the key and digest included) kept as stored."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    change(arrays)
    np.savez(path, **arrays)


def test_altered_value_with_the_same_key_is_not_loaded(tmp_path):
    path = tmp_path / "p.npz"
    save_verified(path, "k", a=np.arange(5.0), b=np.ones((2, 2)))
    assert load_verified(path, "k") is not None

    def flip(arrays):
        a = arrays["a"].copy()
        a.view(np.uint8)[3] ^= 0x01  # one byte of one value
        arrays["a"] = a

    _rewrite_npz(path, flip)
    assert load_verified(path, "k") is None


def test_altered_bytes_inside_the_zip_are_not_loaded(tmp_path):
    path = tmp_path / "p.npz"
    save_verified(path, "k", a=np.arange(100.0))
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    raw = bytearray(members["a.npy"])
    raw[-5] ^= 0x40
    members["a.npy"] = bytes(raw)
    with zipfile.ZipFile(path, "w") as z:  # valid zip again (new CRC), one byte changed
        for n, b in members.items():
            z.writestr(n, b)
    assert load_verified(path, "k") is None


def test_file_without_digest_is_recomputed_not_a_crash(tmp_path):
    path = tmp_path / "old.npz"
    np.savez(path, __key__=np.array("k"), a=np.arange(3))  # written before digests
    assert load_verified(path, "k") is None


def test_round_trip_keeps_dtype_and_shape(tmp_path):
    path = tmp_path / "p.npz"
    save_verified(path, "k", i=np.arange(3, dtype=np.int32), s=np.array("text"),
                  m=np.eye(2), f=1.5)
    got = load_verified(path, "k")
    assert got["i"].dtype == np.int32 and got["m"].shape == (2, 2)
    assert str(got["s"]) == "text" and float(got["f"]) == 1.5


# ---- leftovers


def _age(path, seconds):
    t = time.time() - seconds
    os.utime(path, (t, t))


def test_remove_stale_files_removes_only_old_leftovers(tmp_path):
    old_tmp = tmp_path / "p0000001.npz.abc.tmp"
    new_tmp = tmp_path / "p0000002.npz.def.tmp"
    old_build = tmp_path / ".build-lib-x-123"
    new_build = tmp_path / ".build-lib-y-456"
    old_npz = tmp_path / "p0000003.npz"
    for f in (old_tmp, new_tmp, old_npz):
        f.write_text("")
    for d in (old_build, new_build):
        d.mkdir()
        (d / "lib.so").write_text("")
    for p in (old_tmp, old_build, old_npz):
        _age(p, 2 * 3600)
    assert remove_stale_files(tmp_path) == 2
    assert not old_tmp.exists() and not old_build.exists()
    assert new_tmp.exists() and new_build.exists() and old_npz.exists()
    assert remove_stale_files(tmp_path / "missing") == 0


def test_temporary_file_of_a_killed_writer_is_removed_at_once(tmp_path):
    """A temporary file names its writer; a writer that has ended (killed mid-write) leaves
    one that the next build removes however young it is, while a live writer's stays."""
    from casflex._cache import writer_tag

    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)
    dead_pid = int(child.stdout)  # has exited
    orphan = tmp_path / f"p0000004.npz.{writer_tag(dead_pid)}-x1y2z3.tmp"
    live = tmp_path / f"p0000005.npz.{writer_tag()}-x1y2z3.tmp"
    orphan.write_text("")
    live.write_text("")
    assert remove_stale_files(tmp_path) == 1
    assert not orphan.exists() and live.exists()


def test_failed_writes_leave_no_tmp(tmp_path):
    class Boom(Exception):
        pass

    with pytest.raises(Boom), staged_directory(tmp_path / "lib") as staging:
        (staging / "x").write_text("")
        raise Boom
    with pytest.raises(AttributeError):  # fails inside the write: no text to encode
        atomic_write_text(tmp_path / "x.txt", None)
    assert list(tmp_path.iterdir()) == []


# ---- shared per-point builds


def _square(log):
    def compute(items):
        for i in items:
            log.append(i)
            yield i, {"v": np.array(float(i) ** 2)}
    return compute


def _dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_build_shared_takes_over_claims_of_dead_processes(tmp_path):
    import socket
    (tmp_path / "p1.npz.claim").write_text(f"{socket.gethostname()} {_dead_pid()}\n")
    log = []
    got = {i: (float(a["v"]), c) for i, a, c in
           build_shared(range(3), lambda i: tmp_path / f"p{i}.npz", "k", _square(log))}
    assert got == {0: (0.0, True), 1: (1.0, True), 2: (4.0, True)}
    assert sorted(log) == [0, 1, 2]
    assert not list(tmp_path.glob("*.claim"))


def test_build_shared_takes_over_claims_past_the_timeout(tmp_path):
    claim = tmp_path / "p0.npz.claim"
    claim.write_text("another-host 1\n")
    _age(claim, 100)
    log = []
    list(build_shared([0], lambda i: tmp_path / f"p{i}.npz", "k", _square(log), timeout=50))
    assert log == [0]


def test_build_shared_waits_for_a_live_claim(tmp_path):
    import socket
    claim = tmp_path / "p1.npz.claim"
    claim.write_text(f"{socket.gethostname()} {os.getppid()}\n")  # a live process

    def other_process_finishes():
        time.sleep(0.5)
        save_verified(tmp_path / "p1.npz", "k", v=np.array(1.0))
        claim.unlink()

    threading.Thread(target=other_process_finishes).start()
    log = []
    got = {i: c for i, _, c in
           build_shared(range(3), lambda i: tmp_path / f"p{i}.npz", "k", _square(log),
                        poll=0.05)}
    assert got == {0: True, 1: False, 2: True} and sorted(log) == [0, 2]


def test_build_shared_releases_claims_on_failure(tmp_path):
    def failing(items):
        yield items[0], {"v": np.array(0.0)}
        raise RuntimeError("worker died")

    with pytest.raises(RuntimeError):
        list(build_shared(range(3), lambda i: tmp_path / f"p{i}.npz", "k", failing))
    assert not list(tmp_path.glob("*.claim"))
    assert load_verified(tmp_path / "p0.npz", "k") is not None


def _table_in_subprocess(cache, out):
    code = ("import numpy as np, sys; from casflex.robot import load; "
            "from casflex.modal.tables import build_table; "
            "t = build_table(load('problems/arm2link.toml'), np.radians(np.arange(0, 90.5, 0.5)),"
            " 3, cache_dir=sys.argv[1], processes=1); "
            "np.savez(sys.argv[2], omega=t.omega, phi=t.values['phi_tip'] "
            "if 'phi_tip' in t.values else t.omega, n=t.info['computed_modes'])")
    return subprocess.Popen([sys.executable, "-c", code, str(cache), str(out)],
                            env={**os.environ, "PYTHONPATH": str(Path.cwd())})


@pytest.mark.slow
def test_two_processes_share_a_table_bit_identically(tmp_path):
    procs = [_table_in_subprocess(tmp_path / "shared", tmp_path / f"r{k}.npz")
             for k in range(2)]
    assert [p.wait() for p in procs] == [0, 0]
    single = _table_in_subprocess(tmp_path / "alone", tmp_path / "r_single.npz")
    assert single.wait() == 0
    r = [np.load(tmp_path / f"r{k}.npz") for k in (0, 1, "_single")]
    for name in ("omega", "phi"):
        assert np.array_equal(r[0][name], r[2][name]) and np.array_equal(r[1][name],
                                                                         r[2][name])
    assert int(r[0]["n"]) + int(r[1]["n"]) >= int(r[2]["n"]) == 181
    assert not list((tmp_path / "shared").rglob("*.claim"))
    assert not list((tmp_path / "shared").rglob("*.tmp"))


# ---- JIT cache: only private libraries are loaded


@pytest.mark.needs_cc
def test_jit_refuses_a_library_writable_by_others(tmp_path):
    import casadi as ca

    from casflex.codegen import BuildError
    from casflex.codegen.jit import compile_cached

    x = ca.SX.sym("x")
    f = ca.Function("twice", [x], [2 * x])
    funs, info = compile_cached([f], "perm_jit", cache_dir=tmp_path)
    assert info["built"] and float(funs["twice"](3.0)) == 6.0
    assert (os.stat(tmp_path / "jit").st_mode & 0o077) == 0
    lib = Path(info["library"])
    os.chmod(lib, os.stat(lib).st_mode | 0o002)
    with pytest.raises(BuildError) as err:
        compile_cached([f], "perm_jit", cache_dir=tmp_path)
    assert str(lib) in str(err.value) and "writable by group or others" in str(err.value)
    os.chmod(lib, os.stat(lib).st_mode & ~0o022)
    assert compile_cached([f], "perm_jit", cache_dir=tmp_path)[1]["built"] is False
    os.chmod(tmp_path / "jit", 0o777)
    with pytest.raises(BuildError, match="jit' is writable by group or others"):
        compile_cached([f], "perm_jit", cache_dir=tmp_path)
