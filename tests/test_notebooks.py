"""Every notebook source in notebooks/ runs, and its committed .ipynb is current.

The committed ``.ipynb`` files are executed notebooks written by
``python tools/run_notebooks.py``: their code cells must be exactly those of the ``.py``
source and every code cell must have run, in order, in one kernel. A notebook cell that
runs longer than 3 minutes is an error (nbclient's timeout): a hang fails instead of
stalling CI. How long the notebooks take is measured in benchmarks/, not here.
"""

import sys
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
try:
    from run_notebooks import build, execute, sources
finally:
    sys.path.pop(0)

SOURCES = sources()
IDS = [p.stem for p in SOURCES]
RERUN = "run python tools/run_notebooks.py {stem}"


def _outputs(nb):
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]


@pytest.mark.slow
@pytest.mark.parametrize("source", SOURCES, ids=IDS)
def test_notebook_runs(source):
    nb = execute(source)
    errors = [o for o in _outputs(nb) if o.output_type == "error"]
    assert not errors
    # no progress-bar widgets or their fallback warnings in what a reader sees
    text = "".join(o.get("text", "") for o in _outputs(nb) if o.output_type == "stream")
    assert "IProgress" not in text


def test_every_source_has_a_notebook():
    assert SOURCES, "no notebooks/NN_*.py"
    orphans = sorted(p.name for p in (ROOT / "notebooks").glob("*.ipynb")
                     if not p.with_suffix(".py").exists())
    assert not orphans, f"notebooks without a .py source: {orphans}"


@pytest.mark.parametrize("source", SOURCES, ids=IDS)
def test_committed_notebook_is_current(source):
    """Code and markdown as in the source; executed in order, with outputs and figures."""
    path = source.with_suffix(".ipynb")
    assert path.exists(), f"{path.name} missing: " + RERUN.format(stem=source.stem)
    committed = nbformat.read(path, as_version=4)
    expected = build(source)
    assert [(c.cell_type, c.source) for c in committed.cells] == \
        [(c.cell_type, c.source) for c in expected.cells], \
        f"{path.name} differs from {source.name}: " + RERUN.format(stem=source.stem)
    code = [c for c in committed.cells if c.cell_type == "code"]
    counts = [c.execution_count for c in code]
    assert counts == list(range(1, len(code) + 1)), \
        f"{path.name} was not executed top to bottom in one kernel: " + \
        RERUN.format(stem=source.stem)
    outputs = _outputs(committed)
    assert outputs, f"{path.name} has no outputs: " + RERUN.format(stem=source.stem)
    assert not [o for o in outputs if o.output_type == "error"], f"{path.name} has errors"
    draws = "plt." in source.read_text() or "plotting" in source.read_text()
    if draws:
        assert any("image/png" in o.get("data", {}) for o in outputs), \
            f"{path.name} draws figures but none is stored: " + RERUN.format(stem=source.stem)
