"""Workers die with their parent: a run killed with SIGKILL leaves no pool worker behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from thesis_repro.core import backends, job_kinds, paths
from thesis_repro.core.cache import Job, Result


def _sleep(config: dict, workdir: Path) -> dict:
    """A job that records its worker's pid, then works on for minutes (as a training run does)."""
    (Path(config["pids"]) / str(os.getpid())).write_text("")
    time.sleep(300)
    return {"x": 0.0}


def _pool_execute(job: Job, root: str | None, reference: str | bool) -> Result:
    """A pool worker's entry point from this module: unpickling it imports us, which registers the toy kind."""
    return backends.execute(job, root, reference)


job_kinds.register("test-orphan-sleep", "tests.test_orphans:_sleep")

#: The parent: two such jobs on a pool of two workers (what a figure's ``run_jobs`` does).
PARENT = """
import sys
from thesis_repro.core import backends
from thesis_repro.core.cache import Job, RunCache
from tests.test_orphans import _pool_execute
backends.execute = _pool_execute
jobs = [Job("test-orphan-sleep", {"pids": sys.argv[1], "i": i}) for i in range(2)]
backends.run_jobs(jobs, n_jobs=2, cache=RunCache(sys.argv[2], reference=False), progress=False)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"  # a zombie has ended (it waits only for its new parent to reap it)


def test_no_worker_survives_a_sigkill_of_its_parent(tmp_path):
    pids = tmp_path / "pids"
    pids.mkdir()
    parent = subprocess.Popen([sys.executable, "-c", PARENT, str(pids), str(tmp_path / "runs")], cwd=paths.ROOT)
    try:
        deadline = time.time() + 300  # spawning two workers that import torch takes a while on a busy machine
        while len(list(pids.iterdir())) < 2 and parent.poll() is None and time.time() < deadline:
            time.sleep(0.2)
        workers = [int(p.name) for p in pids.iterdir()]
        assert len(workers) == 2, f"the pool did not start its two jobs (parent exit code {parent.poll()})"
    finally:
        parent.kill()
        parent.wait()
    deadline = time.time() + 60
    while any(_alive(w) for w in workers) and time.time() < deadline:
        time.sleep(0.2)
    survivors = [w for w in workers if _alive(w)]
    for w in survivors:  # leave nothing behind, then fail
        os.kill(w, signal.SIGKILL)
    assert not survivors, f"workers {survivors} outlived their SIGKILLed parent"
