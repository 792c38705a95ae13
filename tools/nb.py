"""Write a notebook from a plain Python file with ``# %%`` cell markers.

Notebooks in ``notebooks/`` are kept as ``.py`` sources (``# %% [markdown]`` cells hold
Markdown in comment lines). This writes the ``.ipynb`` without outputs; the committed
notebooks are the executed ones written by ``python tools/run_notebooks.py``, whose code
cells are exactly those of :func:`build`.

Usage: ``python tools/nb.py notebooks/01_tmm.py`` writes ``notebooks/01_tmm.ipynb``.
"""

import sys
from pathlib import Path

import nbformat


def build(path):
    """The notebook (no outputs) of one ``# %%`` source file."""
    text = Path(path).read_text()
    cells = []
    for chunk in text.split("# %%")[1:]:
        header, _, body = chunk.partition("\n")
        body = body.strip("\n")
        if header.strip().startswith("[markdown]"):
            lines = [line[2:] if line.startswith("# ") else line.lstrip("#")
                     for line in body.splitlines()]
            cells.append(nbformat.v4.new_markdown_cell("\n".join(lines)))
        else:
            cells.append(nbformat.v4.new_code_cell(body))
    for i, cell in enumerate(cells):
        cell.id = f"cell-{i:03d}"   # stable: a regenerated notebook differs where it changed
    nb = nbformat.v4.new_notebook(cells=cells)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    return nb


def convert(path):
    """Convert one ``# %%`` source file to an unexecuted notebook next to it."""
    out = Path(path).with_suffix(".ipynb")
    nbformat.write(build(path), out)
    return out


if __name__ == "__main__":
    for p in sys.argv[1:]:
        print(convert(p))
