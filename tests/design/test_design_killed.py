"""A design job killed by SIGTERM leaves none of its worker processes behind (issue 17)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _stat(pid):
    """``(state, ppid, pgrp)`` of process ``pid`` (Linux /proc), ``None`` if it is gone."""
    try:
        fields = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):  # ended meanwhile
        return None
    # "pid (command) state ppid pgrp ...": the command may hold spaces and parentheses
    return fields[0], int(fields[1]), int(fields[2])


def _processes():
    return [int(e.name) for e in Path("/proc").iterdir() if e.name.isdigit()]


def _children(pid):
    """Process ids whose parent is ``pid``."""
    return [p for p in _processes() if (_stat(p) or (None, None))[1] == pid]


def _group_alive(pgid):
    """Processes of the process group ``pgid`` still running (a zombie, ended but not yet
    reaped, is not)."""
    alive = []
    for p in _processes():
        st = _stat(p)
        if st is not None and st[2] == pgid and st[0] != "Z":
            alive.append(p)
    return alive


@pytest.mark.slow  # 10-20 s: a fresh interpreter, the tables of a small study
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_sigterm_ends_the_jobs_workers(tmp_path, model_study):
    # a small study (one mode, a coarse grid), an empty cache, two processes
    study = model_study(replace=[
        ("modes = 3 ", "modes = 1 "), ("grid_step = 3.0", "grid_step = 30.0"),
        ("dt = 0.001", "dt = 0.005"), ("settle = 3.0", "settle = 0.5"),
        ('"composite"', '"inversion"'), ("compile = true", "compile = false")])
    env = dict(os.environ, MPLBACKEND="Agg")
    log = tmp_path / "stderr.txt"  # a file: workers left behind would hold a pipe open
    with log.open("wb") as err:
        job = subprocess.Popen(
            [sys.executable, "-m", "casflex.cli", "design", str(study), "--out",
             str(tmp_path / "out"), "--cache-dir", str(tmp_path / "cache"), "--processes",
             "2"], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err,
            start_new_session=True)  # its own process group: the job and all it forks
    try:
        # killed while it tabulates the EKF plant (seconds on an empty cache), when the
        # figures' workers run: those were left behind
        deadline = time.monotonic() + 600.0  # the tables of the model first, under load
        while job.poll() is None and time.monotonic() < deadline and \
                "EKF plant tables" not in log.read_text():
            time.sleep(0.05)
        workers = _children(job.pid)
        assert workers, f"the job has no worker (exit {job.returncode}): {log.read_text()}"
        job.send_signal(signal.SIGTERM)
        job.wait(timeout=120)
        # the job ends by the signal, as it would without a handler ...
        assert job.returncode == -signal.SIGTERM, log.read_text()[-2000:]
        # ... and its workers with it: terminated by it, not running on after it (a busy
        # worker of the old code drew its figures on; given a moment to exit)
        deadline = time.monotonic() + 5.0
        while _group_alive(job.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _group_alive(job.pid)
    finally:
        if job.poll() is None:
            job.kill()
            job.wait()
        for left in _group_alive(job.pid):  # what the old code left behind
            os.kill(left, signal.SIGKILL)
