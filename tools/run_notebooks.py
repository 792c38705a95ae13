"""Execute the notebooks' ``.py`` sources and write the executed ``.ipynb`` next to them.

The committed notebooks carry their outputs (numbers and figures) so that a reader
browsing the repository sees them; this is the one command that regenerates them::

    python tools/run_notebooks.py            # every notebooks/NN_*.py
    python tools/run_notebooks.py 01 04_input_shaping notebooks/06_realtime.py

A name is a source path, a notebook stem or its two-digit number. Each notebook runs in
a fresh kernel from ``notebooks/`` with the inline backend (figures stored as PNG); a
cell that runs longer than 3 minutes is an error. One progress line per notebook goes to
stderr.
``tests/test_notebooks.py`` executes the sources the same way (:func:`execute`) and fails
when a committed notebook's code differs from its source or it has no outputs.
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nb import build  # noqa: E402  (tools/ is not a package)

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = ROOT / "notebooks"
CELL_TIMEOUT_S = 180


def sources():
    """Every notebook source, ``notebooks/NN_*.py``, in order."""
    return sorted(p for p in NOTEBOOK_DIR.glob("[0-9][0-9]_*.py"))


def select(names):
    """The sources named by ``names`` (paths, stems or two-digit numbers); all if empty."""
    every = sources()
    if not names:
        return every
    chosen = []
    for name in names:
        stem = Path(name).stem
        match = [p for p in every if p.stem == stem or p.stem.split("_")[0] == stem]
        if not match:
            known = ", ".join(p.stem for p in every)
            raise SystemExit(f"run_notebooks: no notebook {name!r}; known: {known}")
        chosen += [p for p in match if p not in chosen]
    return chosen


def execute(source):
    """Run the notebook of ``source`` in a fresh kernel; return the executed notebook."""
    nb = build(source)
    # figures drawn inline (PNG in the notebook, as a reader's Jupyter does), never in a
    # window, whatever MPLBACKEND the caller has set
    client = NotebookClient(nb, timeout=CELL_TIMEOUT_S, kernel_name="python3",
                            record_timing=False, extra_arguments=["--matplotlib=inline"],
                            resources={"metadata": {"path": str(Path(source).parent)}})
    old = os.environ.pop("MPLBACKEND", None)
    # the kernel process's own stderr (start-up notices, C-level messages) is shown only
    # when the notebook fails; cell outputs are in the notebook either way
    with tempfile.TemporaryFile("w+") as kernel_log:
        try:
            client.execute(stderr=kernel_log)
        except BaseException:
            kernel_log.seek(0)
            sys.stderr.write(kernel_log.read())
            raise
        finally:
            if old is not None:
                os.environ["MPLBACKEND"] = old
    return nb


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help="notebooks to run (default: all of notebooks/NN_*.py)")
    args = parser.parse_args(argv)
    chosen = select(args.names)
    for i, source in enumerate(chosen, 1):
        print(f"[{i}/{len(chosen)}] {source.stem} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        nb = execute(source)
        out = source.with_suffix(".ipynb")
        nbformat.write(nb, out)
        print(f"[{i}/{len(chosen)}] {source.stem}: wrote {out.relative_to(ROOT)} "
              f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
