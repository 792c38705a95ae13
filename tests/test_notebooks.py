"""Execute every notebook in notebooks/ and check that each is current with its source.

A notebook cell that runs longer than 3 minutes is an error (nbclient's timeout): a hang
fails instead of stalling CI. How long the notebooks take is measured in benchmarks/, not here.
"""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    env_backend = os.environ.get("MPLBACKEND")
    os.environ["MPLBACKEND"] = "Agg"
    try:
        NotebookClient(nb, timeout=180, kernel_name="python3",
                       resources={"metadata": {"path": str(path.parent)}}).execute()
    finally:
        if env_backend is None:
            os.environ.pop("MPLBACKEND", None)
        else:
            os.environ["MPLBACKEND"] = env_backend


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_matches_its_source(path):
    """The .ipynb is generated from the .py source by tools/nb.py; they must agree."""
    import sys

    sys.path.insert(0, str(ROOT / "tools"))
    try:
        from nb import convert
    finally:
        sys.path.pop(0)
    source = path.with_suffix(".py")
    assert source.exists(), f"{path.name} has no .py source"
    committed = nbformat.read(path, as_version=4)
    regenerated = nbformat.read(convert_to_tmp(convert, source), as_version=4)
    assert [c.source for c in committed.cells] == [c.source for c in regenerated.cells], (
        f"{path.name} is out of date: run python tools/nb.py {source.relative_to(ROOT)}")


def convert_to_tmp(convert, source):
    import shutil
    import tempfile

    tmp = Path(tempfile.mkdtemp()) / source.name
    shutil.copy(source, tmp)
    return convert(tmp)
