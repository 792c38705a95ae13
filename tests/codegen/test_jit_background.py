"""The optimised library built in a detached process (casflex.codegen.compile_in_background)
and found by the cache lookup that never compiles (casflex.codegen.cached_library)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import pytest

from casflex.codegen import cached_library, compile_cached, compile_in_background


def _cube():
    x = ca.SX.sym("x", 2)
    return ca.Function("cube", [x], [x**3 + ca.sin(x)])


def _wait(condition, seconds=120.0):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.1)
    return False


def _jobs(cache):
    return list((Path(cache) / "jit").glob(".gen-*"))


def test_background_build_lands_where_compile_cached_looks(tmp_path):
    f = _cube()
    assert cached_library([f], "bg_cube", cache_dir=tmp_path, flags=("-O2",)) is None
    t0 = time.perf_counter()
    lib = compile_in_background([f], "bg_cube", cache_dir=tmp_path, flags=("-O2",))
    assert time.perf_counter() - t0 < 30.0  # returns without waiting for the compiler
    assert lib is not None and lib.name.startswith("libbg_cube")
    assert _wait(lambda: lib.is_file() and not _jobs(tmp_path))
    loaded = cached_library([f], "bg_cube", cache_dir=tmp_path, flags=("-O2",))
    x = [0.3, -1.7]
    assert float(ca.norm_inf(loaded["cube"](x) - f(x))) == 0.0
    # the same cache entry compile_cached would have built: nothing to build there now
    funs, info = compile_cached([f], "bg_cube", cache_dir=tmp_path, flags=("-O2",))
    assert info["built"] is False and info["library"] == str(lib)
    # other flags are another library
    assert cached_library([f], "bg_cube", cache_dir=tmp_path, flags=("-O0",)) is None


def test_nothing_started_when_already_built(tmp_path):
    f = _cube()
    compile_cached([f], "bg_cube", cache_dir=tmp_path, flags=("-O1",))
    assert compile_in_background([f], "bg_cube", cache_dir=tmp_path, flags=("-O1",)) is None
    assert not _jobs(tmp_path)


def test_a_live_builder_blocks_a_second_build_and_a_dead_one_does_not(tmp_path):
    f = _cube()
    # where the build would go: start one, let it finish, then remove the library again
    lib = compile_in_background([f], "bg_cube", cache_dir=tmp_path, flags=("-O2",))
    assert _wait(lambda: lib.is_file() and not _jobs(tmp_path))
    entry = lib.parent
    for p in entry.iterdir():
        p.unlink()
    entry.rmdir()
    job = entry.parent / f".gen-{entry.name}-bg-fake"
    job.mkdir()
    (job / "pid").write_text(str(os.getpid()))  # a live process "building" it
    assert compile_in_background([f], "bg_cube", cache_dir=tmp_path, flags=("-O2",)) is None
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)
    (job / "pid").write_text(ended.stdout.strip())  # its builder has died
    assert compile_in_background([f], "bg_cube", cache_dir=tmp_path,
                                 flags=("-O2",)) == lib
    assert _wait(lambda: lib.is_file())


def test_a_failed_background_build_leaves_only_the_library_missing(tmp_path):
    f = _cube()
    lib = compile_in_background([f], "bg_cube", cache_dir=tmp_path,
                                flags=("-fno-such-flag-anywhere",))
    assert lib is not None
    assert _wait(lambda: not _jobs(tmp_path))  # the job directory is removed
    assert not lib.exists() and not lib.parent.exists()
    assert not list((tmp_path / "jit").glob(".build-*"))


def test_unknown_library_name_is_refused_before_anything_starts(tmp_path):
    from casflex.codegen import CodegenError

    with pytest.raises(CodegenError):
        compile_in_background([_cube()], "not a name", cache_dir=tmp_path)
    assert not _jobs(tmp_path)


def test_tiered_compiler_follows_the_environment_unless_told(tmp_path, monkeypatch):
    from casflex.codegen import tiered_compiler

    f = _cube()
    monkeypatch.setenv("CASFLEX_BACKGROUND_BUILDS", "0")
    lines = []
    off = tiered_compiler("bg_tiers", quick_flags=("-O0",), optimised_flags=("-O2",),
                          cache_dir=tmp_path / "off", log=lines.append)
    x = [0.3, -1.7]
    assert float(ca.norm_inf(off([f])[0](x) - f(x))) == 0.0
    assert off.builds == [("-O0",)] and not lines and not _jobs(tmp_path / "off")
    told = tiered_compiler("bg_tiers", quick_flags=("-O0",), optimised_flags=("-O2",),
                           cache_dir=tmp_path / "on", log=lines.append, background=True)
    told([f])
    assert told.builds == [("-O0",)] and len(lines) == 1 and "-O2" in lines[0]
    assert f"({f.name()})" in lines[0]  # which functions: a solve compiles two sets
    optimised = Path(tmp_path, "on", "jit")
    assert _wait(lambda: not _jobs(tmp_path / "on")
                 and cached_library([f], "bg_tiers", cache_dir=tmp_path / "on",
                                    flags=("-O2",)) is not None)
    told([f])
    assert told.builds == [("-O0",), ("-O2",)] and optimised.is_dir()


def _with_repeats():
    """A Jacobian, where automatic differentiation repeats work (as the planner's)."""
    x = ca.SX.sym("x", 3)
    y = ca.vertcat(ca.sin(x[0] * x[1]) * ca.exp(x[2]), ca.cos(x[0] * x[1]) / (1 + x[2] ** 2))
    return ca.Function("jac_demo", [x], [ca.vec(ca.jacobian(y, x))])


def test_a_build_without_repeats_is_its_own_entry_with_the_same_values(tmp_path):
    from casflex.codegen import tiered_compiler, without_repeats

    f = _with_repeats()
    assert without_repeats([f])[0].n_instructions() < f.n_instructions()
    plain, info_plain = compile_cached([f], "jac_demo", cache_dir=tmp_path, flags=("-O1",))
    lean, info_lean = compile_cached([f], "jac_demo", cache_dir=tmp_path, flags=("-O1",),
                                     cse=True)
    assert info_plain["built"] and info_lean["built"]
    assert info_plain["library"] != info_lean["library"]  # cse is part of the key
    for x in ([0.3, -1.7, 0.2], [2.0, 0.5, -3.0]):
        assert (lean["jac_demo"](x).full() == plain["jac_demo"](x).full()).all()
        assert (lean["jac_demo"](x).full() == f(x).full()).all()
    # the background builder eliminates them too: its library is compile_cached's
    lib = compile_in_background([f], "jac_demo", cache_dir=tmp_path, flags=("-O2",),
                                cse=True)
    assert _wait(lambda: lib.is_file() and not _jobs(tmp_path))
    assert compile_cached([f], "jac_demo", cache_dir=tmp_path, flags=("-O2",),
                          cse=True)[1]["built"] is False
    compile_function = tiered_compiler("jac_demo", quick_flags=("-O1",),
                                       optimised_flags=("-O2",), cache_dir=tmp_path,
                                       background=False, cse=True)
    [g] = compile_function([f])
    assert compile_function.builds == [("-O2",)]  # the background's library
    assert (g([0.3, -1.7, 0.2]).full() == f([0.3, -1.7, 0.2]).full()).all()
