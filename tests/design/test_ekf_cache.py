"""The design job's EKF step kept in the cache (casflex.design.loop_ekf_step): read back as
the graph that was stored (equal outputs, bit for bit), built again when an input changes."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

import casflex.estimation
from casflex.design import load_study, loop_ekf_step
from casflex.estimation import tabulate_plant

STUDY = Path(__file__).resolve().parents[2] / "problems" / "studies" / "arm2link_move1.toml"


@pytest.fixture(scope="module")
def pieces(arm_model, accel_sensors, model_cache):
    """The bundled study, a one-mode model of the arm at the study's (the same) sensor
    points, coarse (the cache, not the filter, is tested: the model of
    tests/simulate/test_closed_loop_paths.py), its table, and the shared cache (where its
    plant is tabulated once)."""
    study = load_study(STUDY)
    model, table = arm_model(1, step_deg=30, points=accel_sensors.points, gravity=None,
                             delta_order=0)
    tabulate_plant(model, cache_dir=model_cache)
    return study, model, table, model_cache


@pytest.fixture()
def builds(monkeypatch, pieces):
    """The calls of ekf_step_function that loop_ekf_step makes; the plant it asks for (a
    grid, or None) is recorded and the shared one returned (not tabulated again)."""
    calls = []
    ekf_step_function = casflex.estimation.ekf_step_function
    model_cache = pieces[3]

    def counted(*args, **kwargs):
        calls.append(kwargs)
        return ekf_step_function(*args, **kwargs)

    def shared_plant(model, *, grid=None, cache_dir=None):
        calls.append({"plant_grid": grid})
        return tabulate_plant(model, cache_dir=model_cache)

    monkeypatch.setattr(casflex.estimation, "ekf_step_function", counted)
    monkeypatch.setattr(casflex.estimation, "tabulate_plant", shared_plant)
    return calls


def _outputs(step):
    """The step at a fixed, non-trivial argument."""
    x = np.r_[1e-3, -2e-3, 0.1, 0.2][:step.size1_in(0)]
    nx = x.size
    args = [x, np.eye(nx) * 1e-4 + 1e-6, np.linspace(-0.5, 0.7, step.size1_in(2)),
            np.linspace(0.1, 0.9, step.size1_in(3)), np.ones(step.size1_in(4))]
    return [np.asarray(v) for v in step(*args)]


def test_the_step_read_back_is_the_one_built(pieces, builds, tmp_path):
    study, model, table, model_cache = pieces
    cache = tmp_path
    first = loop_ekf_step(model, table, study, 1e-3, cache_dir=cache)
    again = loop_ekf_step(model, table, study, 1e-3, cache_dir=cache)
    assert len(builds) == 2 and len(list((cache / "ekf").glob("*.npz"))) == 1
    assert again.serialize() == first.serialize()
    for a, b in zip(_outputs(first), _outputs(again), strict=True):
        assert np.array_equal(a, b)  # the same graph: the same numbers, bit for bit
    # against a step built directly (independent of the cache)
    plant = tabulate_plant(model, cache_dir=model_cache)
    direct = casflex.estimation.ekf_step_function(plant, study.sensors, study.estimator["Q"],
                                                  study.estimator["R"], 1e-3)
    for a, b in zip(_outputs(direct), _outputs(again), strict=True):
        assert np.array_equal(a, b)


def test_a_changed_input_builds_again(pieces, builds, tmp_path):
    study, model, table, _ = pieces
    cache = tmp_path
    loop_ekf_step(model, table, study, 1e-3, cache_dir=cache)
    other_q = copy.copy(study)
    other_q.estimator = dict(study.estimator, Q=study.estimator["Q"] * 2)
    other_model = copy.copy(study)
    other_model.model = dict(study.model, delta_order=1)
    loop_ekf_step(model, table, other_q, 1e-3, cache_dir=cache)
    loop_ekf_step(model, table, study, 2e-3, cache_dir=cache)
    loop_ekf_step(model, table, other_model, 1e-3, cache_dir=cache)
    grid = [table.grid[0][2:9]]
    loop_ekf_step(model, table, study, 1e-3, grid, cache_dir=cache)
    assert len(builds) == 2 * 5 and len(list((cache / "ekf").glob("*.npz"))) == 5
    assert builds[-2]["plant_grid"] is grid  # the plant asked for on that grid


def test_without_a_cache_or_a_table_key_it_is_built_every_time(pieces, builds, tmp_path):
    study, model, _, _ = pieces
    cache = tmp_path
    for _ in range(2):
        loop_ekf_step(model, None, study, 1e-3, cache_dir=cache)
    assert len(builds) == 2 * 2 and not (cache / "ekf").exists()
