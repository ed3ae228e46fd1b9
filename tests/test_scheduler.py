"""The scheduler behind funrec batch and funrec bench: jobs in order from local threads and from a local Ray
instance, and the memory-limited child process each job runs (its own peak memory, CPU time, exit codes)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from funrec.bench.batch import BatchConfig
from funrec.bench.scheduler import run_funrec_child, run_jobs
from funrec.errors import FunrecError


def _square(x: int, offset: int, active: set[int] | None = None) -> tuple[int, bool]:
    return x * x + offset, active is not None


def test_local_jobs_come_back_in_job_order_with_progress():
    calls = []
    rows = run_jobs(_square, [(x, 1) for x in range(7)], workers=3, progress=lambda done, total: calls.append((done, total)))
    assert rows == [(x * x + 1, True) for x in range(7)]  # local jobs get the set of running process groups
    assert calls[-1] == (7, 7) and [done for done, _ in calls] == list(range(1, 8))
    with pytest.raises(FunrecError, match="workers"):
        run_jobs(_square, [(1, 0)], workers=0)


def test_child_peak_memory_is_the_childs_own(tmp_path):
    # 100 MB of ones, written so the pages are resident.
    result = run_funrec_child([sys.executable, "-c", "import numpy as np; a = np.ones(12_500_000); a.sum()"], tmp_path / "log.txt", 60.0)
    assert result.returncode == 0 and not result.timed_out
    assert result.peak_mb > 100.0
    # Writing 100 MB and importing numpy takes well over 10 ms of CPU; numpy's BLAS threads start on import, so
    # the CPU time may exceed the wall time, but not twice it on this 2-core machine (+10 ms clock granularity).
    assert 0.01 < result.cpu_s <= 2 * result.seconds + 0.01
    # Linux carries the peak RSS of a process across fork and exec; the launcher keeps a
    # 200 MB bench from showing up as the peak of a child that does nothing (~10 MB).
    ballast = np.ones(25_000_000)
    ballast.sum()
    idle = run_funrec_child([sys.executable, "-c", "pass"], tmp_path / "log.txt", 60.0)
    assert idle.returncode == 0 and idle.peak_mb < 60.0
    del ballast


def test_child_exit_codes(tmp_path):
    assert run_funrec_child([sys.executable, "-c", "raise SystemExit(3)"], tmp_path / "log", 60.0).returncode == 3
    assert run_funrec_child([sys.executable, "-c", "import os; os.kill(os.getpid(), 9)"], tmp_path / "log", 60.0).returncode == -9
    missing = run_funrec_child([str(tmp_path / "no-such-program")], tmp_path / "log", 60.0)
    assert missing.returncode == 127 and "cannot run" in (tmp_path / "log").read_text()


def _sleep_and_time(seconds: float, active: set[int] | None = None) -> tuple[float, float]:
    import time

    start = time.time()
    time.sleep(seconds)
    return start, time.time()


# Starts a local Ray instance: 9 s on an idle machine, so it stays in the default run.
def test_ray_runs_as_many_jobs_at_once_as_workers():
    ray = pytest.importorskip("ray")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray workers cannot import test modules
    # Ray sizes a node's "memory" resource from the memory free when it starts: 17.5 GB on this idle 24 GB
    # machine, less when other programs run. Reserving the 8 GB address-space limit per task then ran the
    # batch one capture at a time (bench suite with 2 workers: 0.9 captures running on average). A node
    # with 5 GB to hand out must run two tasks with funrec batch's default reservation at once.
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _memory=5 * 2**30)
    try:
        timings = run_jobs(_sleep_and_time, [(3.0,), (3.0,)], workers=2, ray="local", task_memory_mb=BatchConfig().task_memory_mb)
    finally:
        ray.shutdown()
    (a0, a1), (b0, b1) = timings
    assert max(a0, b0) < min(a1, b1), "the two Ray tasks did not run at the same time"
