"""start_closed_loop: a state-feedback loop's sample steps in a worker process give the
numbers of simulate_closed_loop in this process, bit for bit (the same step Function, the
same arithmetic), and its errors surface when the result is asked for."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from casflex.control import inversion_controller
from casflex.errors import ModelError, SolverError
from casflex.model import FlexibleModel, PointwiseProvider
from casflex.moves import Move
from casflex.simulate import simulate_closed_loop, start_closed_loop


@pytest.fixture(scope="module")
def small(arm):
    """One mode at one configuration (no tables): the loop machinery, not the model."""
    model = FlexibleModel(arm, PointwiseProvider(arm, [0, 0, 0], 1), gravity=None)
    return model, Move([0, 0, 0], [-0.3, 0.2, 0.1], 0.4, settle=0.1)


@pytest.fixture(scope="module")
def pool():
    with ProcessPoolExecutor(1) as executor:
        yield executor


def test_worker_loop_equals_the_loop_here(small, pool):
    """The sampled loop of the design job's true-state runs (compiled there; the same
    Function pickled here: its SX form)."""
    model, move = small
    law = inversion_controller(model, Kp=4.0, Kd=4.0)
    here = simulate_closed_loop(model, law, move, dt=2e-3, sampled=True)
    there = start_closed_loop(pool, model, law, move, dt=2e-3, sampled=True)()
    for name in ("t", "x", "tau", "qd", "tip", "tip_rigid"):
        assert np.array_equal(getattr(there, name), getattr(here, name)), name
    assert float(np.abs(here.tracking_error).max()) > 0  # the loop did move


def test_a_diverging_worker_loop_raises_when_finished(small, pool):
    model, move = small
    law = inversion_controller(model, Kp=1e9, Kd=1e5)  # far beyond what 10 ms can hold
    with pytest.raises(SolverError) as here:
        simulate_closed_loop(model, law, move, dt=1e-2, sampled=True)
    finish = start_closed_loop(pool, model, law, move, dt=1e-2, sampled=True)  # no error yet
    with pytest.raises(SolverError) as there:
        finish()
    assert str(there.value) == str(here.value)


def test_unknown_options_are_refused(small, pool):
    model, move = small
    with pytest.raises(ModelError, match="sample_time"):
        start_closed_loop(pool, model, inversion_controller(model), move, sample_time=1e-3)
