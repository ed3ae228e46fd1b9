"""Run independent per-capture jobs on local worker threads or as Ray tasks: the one scheduler behind
``funrec batch`` and ``funrec bench``.

A job is a call ``function(*args, active=...)`` that starts one memory-limited subprocess through
:func:`run_funrec_child` and returns a picklable result row; it never raises for a bad capture. Locally,
each of ``workers`` threads waits on one such subprocess (so the thread pool is a process pool, and
``active`` holds the process groups to kill when interrupted). With a Ray address, every job is a Ray task
with one CPU and the stated resident memory reserved; Ray places it (its own scheduling, not ours) and ``active`` is
None in the task.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any, TypeVar

from funrec.bench.launcher import LimitedRun, run_limited
from funrec.errors import FunrecError

_PROJECT_ROOT = Path(__file__).resolve().parents[1]
Row = TypeVar("Row")
Progress = Callable[[int, int], None]
"""``progress(done, total)``, called after each finished job."""


def run_funrec_child(command: list[str], log_path: Path, timeout_s: float, memory_limit_mb: int = 0,
                     active: set[int] | None = None) -> LimitedRun:
    """Run ``command`` through :func:`funrec.bench.launcher.run_limited` so that it imports the same funrec as
    this process, installed or not (a worktree, a Ray worker on the same file system)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(_PROJECT_ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return run_limited(command, log_path, timeout_s, memory_limit_mb, env, active)


def last_log_line(log_path: Path) -> str:
    """The last non-blank line of a job's log (the error of a failed child), at most 300 characters."""
    try:
        lines = [line.strip() for line in log_path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def run_jobs(function: Callable[..., Row], jobs: Sequence[tuple[Any, ...]], workers: int, ray: str | None = None,
             task_memory_mb: int = 0, progress: Progress | None = None) -> list[Row]:
    """Results of ``function(*job)`` for every job, in job order.

    Args:
        function: a module-level function (Ray pickles it by reference) taking ``active`` as a keyword.
        jobs: argument tuples.
        workers: jobs run at once locally, or the CPUs of a Ray instance started with ``ray="local"``.
        ray: None for local threads; ``"local"`` to start a Ray instance here; otherwise a cluster address
            (``"auto"``, ``"ray://host:10001"``) whose nodes see the same file system.
        task_memory_mb: resident memory Ray reserves per task, MiB (0: none). Ray admits a task only where this
            much of the node's memory is unreserved, so it must be the job's resident peak, not its address-space
            limit: reserving an 8 GB RLIMIT_AS per task let a 24 GB machine run one task at a time.
        progress: optional ``progress(done, total)``.

    Raises:
        FunrecError: Ray requested but not installed.
    """
    if workers < 1:
        raise FunrecError(f"workers must be >= 1, got {workers}")
    if ray is None:
        return _run_local(function, jobs, workers, progress)
    return _run_ray(function, jobs, workers, ray, task_memory_mb, progress)


def _run_local(function: Callable[..., Row], jobs: Sequence[tuple[Any, ...]], workers: int,
               progress: Progress | None) -> list[Row]:
    results: dict[int, Row] = {}
    active: set[int] = set()
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        futures = {pool.submit(function, *job, active=active): i for i, job in enumerate(jobs)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            if progress is not None:
                progress(len(results), len(jobs))
    except BaseException:
        # Interrupted (or a bug): drop queued jobs and kill the running subprocesses, which sit in their own
        # sessions and never see the terminal's Ctrl-C, instead of waiting for each to finish.
        pool.shutdown(wait=False, cancel_futures=True)
        for pgid in list(active):
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        raise
    pool.shutdown()
    return [results[i] for i in range(len(jobs))]


def _run_ray(function: Callable[..., Row], jobs: Sequence[tuple[Any, ...]], workers: int, address: str,
             task_memory_mb: int, progress: Progress | None) -> list[Row]:
    try:
        import ray
    except ImportError:
        raise FunrecError("--ray needs Ray: pip install 'ray>=2.9' (or funrec[ray])") from None
    started = not ray.is_initialized()
    if started:
        if address == "local":
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        # One CPU and the job's resident memory reserved per task; no retries, since a failing capture is a
        # row, not a lost task.
        options = {"memory": task_memory_mb * 2**20} if task_memory_mb > 0 else {}
        task = ray.remote(num_cpus=1, max_retries=0, **options)(function)
        refs = [task.remote(*job, active=None) for job in jobs]
        index = {ref: i for i, ref in enumerate(refs)}
        results: dict[int, Row] = {}
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                results[index[done[0]]] = ray.get(done[0])
                if progress is not None:
                    progress(len(results), len(jobs))
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
        return [results[i] for i in range(len(jobs))]
    finally:
        if started:
            ray.shutdown()


__all__ = ["Progress", "last_log_line", "run_funrec_child", "run_jobs"]
