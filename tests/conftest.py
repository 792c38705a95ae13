"""Shared robots, sensor sets and models of the test suite, and its markers.

Tests run from the repository root (the README's command); problem files are named by
their path from there. Markers (registered in ``pyproject.toml``, ``--strict-markers``):

``slow``
    takes more than a few seconds on two cores (tabulates a model, runs Ipopt many times,
    executes a notebook). ``python -m pytest -m "not slow"`` is the fast suite.
``needs_cc``
    compiles generated C with the system compiler (``cc``).
``quick``
    the quick subset, set here on the tests of :data:`QUICK_FILES` that are not slow:
    ``python -m pytest -m quick``.

Models are built through :func:`arm_model`, a session-wide memo keyed by the build
options, with their modal tables in one session cache directory: two test modules that
ask for the same model share one build.

State and order: the whole session runs on a temporary cache (``$CASFLEX_CACHE`` is set
to a fresh directory when pytest starts, before collection, and removed at the end, so no
test reads or writes the user's cache and tables are built once per session); tests that
draw random numbers take the ``rng`` fixture, seeded from the test's own id, so that a
failure seen in the full run reproduces with ``-k``.

Parallel runs (pytest-xdist, ``-n 2 --dist loadfile`` in ``pyproject.toml``): each worker
is a session of its own over whole test files, the longest files (:data:`HEAVY_FILES`)
first, with its own ``$CASFLEX_CACHE`` (a
sub-directory of the run's temporary directory, so a test sees the cache exactly as in a
one-process run); only the modal tables of :func:`arm_model` live in one directory shared
by the workers (their builds coordinate through :func:`casflex._cache.build_shared`, and a
table is the same whichever worker computes it). ``-n 0`` runs in one process.
"""

from __future__ import annotations

import os

# One BLAS thread per process, set before numpy loads (here, and in the workers and
# subprocesses, which inherit the environment): the two workers already fill the two
# cores, and OpenBLAS's threads on the suite's small matrices spin against each other
# (a reference beam run took 57 s of CPU with the default threads against 1.6 s with
# one, on the 2-core machine). A value the user set is kept.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
# No optimised builds of the planner's derivatives in the background (casflex.codegen.
# tiered_compiler): a test's plan is done before one would be used, and each costs up to
# a minute of the compiler on the cores the suite runs on. The tests of that mechanism ask
# for it explicitly (background=True).
os.environ.setdefault("CASFLEX_BACKGROUND_BUILDS", "0")

import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import zlib  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
# helpers shared by test modules in sub-folders (reference_fem.py)
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))

ARM_FILE = ROOT / "problems" / "arm2link.toml"
TESTBED_FILE = ROOT / "problems" / "testbed.toml"
ACCEL_FILE = ROOT / "problems" / "sensors" / "arm2link_accel.toml"
STRAIN_FILE = ROOT / "problems" / "sensors" / "arm2link_strain.toml"
MOVES_FILE = ROOT / "problems" / "moves.toml"


_CACHE_ENV = {}


#: The quick subset (``python -m pytest -m quick``, under a minute on two cores): the tests
#: not marked slow of these files, one or more per layer that need no model tables, no
#: compiler and no solver runs (the robot files, the TMM against its references, the
#: mass normalisation, mode tracking, closed-form shapers, moves, the cache, the
#: architecture rules).
QUICK_FILES = (
    "tests/test_robot.py",
    "tests/test_cache.py",
    "tests/test_moves.py",
    "tests/test_architecture.py",
    "tests/test_plausibility_bounds.py",
    "tests/tmm/test_tmm_fixtures.py",
    "tests/tmm/test_tmm.py",
    "tests/modal/test_normalize.py",
    "tests/modal/test_tracking.py",
    "tests/shaping/test_shaping_shapers.py",
    "tests/shaping/test_shaping_family.py",
)


#: Test files that take a minute or more of one worker's time in the full run (CI logs
#: their tests' durations), longest first. In a pytest-xdist run they are scheduled first
#: (the longest-first rule: ``--no-loadscope-reorder`` in ``pyproject.toml`` keeps this
#: order), so that no long file starts near the end while the other worker idles.
HEAVY_FILES = (
    "tests/test_notebooks.py",
    "tests/model/test_model_fidelity.py",
    "tests/model/test_spatial_fidelity.py",
    "tests/model/test_spatial_reference.py",
    "tests/estimation/test_plant_model_options.py",
    "tests/test_faults.py",
    "tests/test_bad_input.py",
    "tests/simulate/test_closed_loop_paths.py",
    "tests/design/test_design.py",
    "tests/model/test_foreshortening.py",
    "tests/estimation/test_estimation.py",
    "tests/model/test_shape_rates.py",
)


def pytest_collection_modifyitems(config, items):
    """Mark the quick subset (:data:`QUICK_FILES`, not slow) with ``quick``; in a
    pytest-xdist worker, put the files of :data:`HEAVY_FILES` first, in its order (both
    workers collect, and so order, identically)."""
    quick = {str(ROOT / name) for name in QUICK_FILES}
    for item in items:
        if str(item.path) in quick and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.quick)
    if os.environ.get("PYTEST_XDIST_WORKER"):
        rank = {str(ROOT / name): k for k, name in enumerate(HEAVY_FILES)}
        items.sort(key=lambda item: rank.get(str(item.path), len(HEAVY_FILES)))


#: set by the controller of a pytest-xdist run for its workers: the run's directory
_RUN_DIR_ENV = "CASFLEX_TEST_RUN_DIR"


def pytest_configure(config):
    """Point ``$CASFLEX_CACHE`` at a fresh directory for the session (subprocesses too);
    in a pytest-xdist worker, at the worker's own directory inside the run's."""
    _CACHE_ENV["previous"] = os.environ.get("CASFLEX_CACHE")
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    run_dir = os.environ.get(_RUN_DIR_ENV)
    if worker and run_dir:  # the controller made the run's directory and removes it
        cache = Path(run_dir) / f"cache-{worker}"
        cache.mkdir(exist_ok=True)
        _CACHE_ENV["run_dir"] = run_dir
    else:
        run_dir = tempfile.mkdtemp(prefix="casflex-test-cache-")
        _CACHE_ENV["run_dir"] = _CACHE_ENV["owned"] = run_dir
        os.environ[_RUN_DIR_ENV] = run_dir
        cache = Path(run_dir) / "cache"
        cache.mkdir()
    os.environ["CASFLEX_CACHE"] = str(cache)


def pytest_unconfigure(config):
    owned = _CACHE_ENV.pop("owned", None)
    previous = _CACHE_ENV.pop("previous", None)
    _CACHE_ENV.pop("run_dir", None)
    if previous is None:
        os.environ.pop("CASFLEX_CACHE", None)
    else:
        os.environ["CASFLEX_CACHE"] = previous
    if owned is not None:
        os.environ.pop(_RUN_DIR_ENV, None)
        shutil.rmtree(owned, ignore_errors=True)


@pytest.fixture
def ctrl_c():
    """Python's own SIGINT handler (a KeyboardInterrupt in the main thread) for the test,
    the one a user's terminal session has. pytest-xdist's workers ignore SIGINT, and a
    test that runs a notebook's kernel puts the default handler back for the rest of its
    worker, so a test that sends itself SIGINT passed or failed with the order of the
    files on the workers (three planner tests failed in a CI rehearsal of session 22)."""
    import signal

    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.fixture
def rng(request):
    """A numpy Generator seeded from the test's node id: the same numbers in the full run
    and with ``-k``, different streams for different tests."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


@pytest.fixture(scope="session")
def arm():
    """The dissertation's Table 8 arm (two 1 m aluminium links, three joints)."""
    from casflex.robot import load

    return load(ARM_FILE)


@pytest.fixture(scope="session")
def testbed():
    """The testbed arm of §4.5 (problems/testbed.toml)."""
    from casflex.robot import load

    return load(TESTBED_FILE)


@pytest.fixture(scope="session")
def accel_sensors(arm):
    """The two tip accelerometers of the studies (problems/sensors/arm2link_accel.toml)."""
    from casflex.sensors import load_sensors

    return load_sensors(ACCEL_FILE, arm)


@pytest.fixture(scope="session")
def strain_sensors(arm):
    """The strain-gauge pairs of the studies (problems/sensors/arm2link_strain.toml)."""
    from casflex.sensors import load_sensors

    return load_sensors(STRAIN_FILE, arm)


@pytest.fixture(scope="session")
def move():
    """``move(name)``: a move of problems/moves.toml (``"move1"``, ``"control_move3"``...)."""
    from casflex.moves import load_move

    return lambda name: load_move(f"{MOVES_FILE}:{name}")


@pytest.fixture(scope="session")
def model_cache():
    """One modal-table cache directory for the whole run (shared by xdist workers)."""
    path = Path(_CACHE_ENV["run_dir"]) / "tables"
    path.mkdir(exist_ok=True)
    return path


@pytest.fixture(scope="session")
def arm_model(arm, model_cache):
    """``arm_model(n_modes, step_deg=15, **options)`` -> ``(model, table)`` of the Table 8
    arm, built once per distinct set of options in the session.

    ``options`` are :func:`casflex.model.build_model` keywords (``gravity``,
    ``delta_order``, ``points``, ``grid``...); ``step_deg`` is the grid step of the shape
    joint in degrees (ignored when ``grid`` is given).
    """
    from casflex.model import build_model

    built = {}

    def get(n_modes, step_deg=15.0, **options):
        key = (n_modes, step_deg, repr(sorted(options.items())))
        if key not in built:
            options.setdefault("processes", 1)
            if "grid" not in options:
                options["step"] = np.radians(step_deg)
            built[key] = build_model(arm, n_modes=n_modes, cache_dir=model_cache, **options)
        return built[key]

    return get


@pytest.fixture
def model_study(tmp_path):
    """``make(model_lines="", replace=())``: the bundled design study copied, with the files
    it names, under ``tmp_path/problems``; ``model_lines`` added to its [model] section and
    the ``(old, new)`` pairs of ``replace`` applied (each ``old`` must be there)."""
    study = ROOT / "problems" / "studies" / "arm2link_move1.toml"

    def make(model_lines="", replace=()):
        pdir = tmp_path / "problems"
        (pdir / "sensors").mkdir(parents=True, exist_ok=True)
        (pdir / "studies").mkdir(exist_ok=True)
        for name in ("arm2link.toml", "arm2link_actuated.toml", "moves.toml",
                     "sensors/arm2link_accel.toml"):
            shutil.copy(ROOT / "problems" / name, pdir / name)
        text = study.read_text()
        for old, new in (("delta_order = 0", "delta_order = 0\n" + model_lines), *replace):
            assert old in text
            text = text.replace(old, new)
        path = pdir / "studies" / "study.toml"
        path.write_text(text)
        return path

    return make


@pytest.fixture
def build_kwargs(monkeypatch):
    """The keywords the design job hands to build_model; the job is stopped there with
    ``RuntimeError("stop")``."""
    import casflex.model

    seen = {}

    def capture(*args, **kwargs):
        seen.update(kwargs)
        raise RuntimeError("stop")

    monkeypatch.setattr(casflex.model, "build_model", capture)
    return seen
