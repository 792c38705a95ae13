"""The builder process of :func:`casflex.codegen.jit.compile_in_background`.

``python -m casflex.codegen._background JOB`` (started in a new session, its output going
nowhere) loads the functions saved in the job directory ``JOB``, compiles them into the
cache entry named in ``JOB/job.json`` and removes ``JOB``: a failed build only leaves the
library missing.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path


def _build(job: Path) -> int:
    import json

    import casadi as ca

    from casflex.codegen.jit import build_library

    try:
        (job / "pid").write_text(str(os.getpid()))
        spec = json.loads((job / "job.json").read_text())
        functions = [ca.Function.load(str(job / f"{i}.casadi"))
                     for i in range(spec["functions"])]
        target = Path(spec["target"])
        if not target.is_dir():  # put in place complete, or not at all
            build_library(functions, spec["name"], target, spec["cmd"], spec["flags"],
                          spec.get("cse", False))
        return 0
    finally:
        shutil.rmtree(job, ignore_errors=True)


def main(argv: list[str]) -> int:
    """Build the job whose directory is ``argv[0]``; return the exit status.

    Parameters
    ----------
    argv : list of str
        The job directory written by :func:`casflex.codegen.compile_in_background`.

    Returns
    -------
    int
        0 when the library was built (or was already there); a failed build raises.

    Examples
    --------
    Run by :func:`casflex.codegen.compile_in_background`, not by hand:

    >>> main  # doctest: +ELLIPSIS
    <function main at ...>
    """
    return _build(Path(argv[0]))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
