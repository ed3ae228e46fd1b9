"""Batch reconstruction of a folder of captures: one ``funrec reconstruct`` process per capture under a memory
limit, run by a local process pool or by Ray tasks, resumable, with one summary table (CSV and Markdown).

Each capture runs in its own process (started by funrec/bench/launcher.py, which sets RLIMIT_AS and reports the
peak RSS), so a crash, an out-of-memory kill or a timeout is one failure row and never stops the others. The local
pool and Ray run the same :func:`run_capture` through :func:`funrec.bench.scheduler.run_jobs` (the scheduler
``funrec bench`` uses too), so both give the same twins.
"""

from __future__ import annotations

import csv
import logging
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from funrec.bench.scheduler import Progress, last_log_line, run_funrec_child, run_jobs
from funrec.errors import FunrecError
from funrec.formats.staged_folder import refuse_output_over_input

log = logging.getLogger(__name__)

COLUMNS = ("capture", "status", "parts", "seconds", "cpu_s", "peak_mb", "error")
"""Columns of the summary table (plus axis_error_deg, state_error and failed_parts with evaluation)."""


@dataclass(frozen=True)
class BatchConfig:
    """How ``funrec batch`` runs a folder of captures."""

    workers: int = 2
    """Captures reconstructed at once (local processes, or the CPUs Ray starts with --ray local)."""
    ray: str | None = None
    """Ray cluster address ('auto', 'ray://host:10001') or 'local' to start a Ray instance on this machine;
    None runs a local process pool. Capture and output folders must be on a file system every node sees."""
    memory_limit_mb: int = 8000
    """Address-space limit (RLIMIT_AS) of each reconstruct process, MiB; 0 = none. A reconstruct at 640x480 peaks
    near 1.2 GB resident but maps more virtual memory (thread stacks, allocator arenas, Open3D), so the limit is
    set well above the resident peak."""
    task_memory_mb: int = 2000
    """Resident memory Ray reserves for each capture, MiB (0: none): a 640x480 reconstruct peaked at 1,178 MB on
    the bench suite. Ray starts a task only on a node with this much unreserved memory."""
    timeout_s: float = 3600.0
    """Wall-time limit of one capture, seconds; the process group is killed after it."""
    evaluate: bool = False
    """Score each twin against its capture's gt/ when present (adds axis and state error columns)."""
    reconstruct_args: tuple[str, ...] = ()
    """Extra arguments of ``funrec reconstruct`` (stage options)."""

    def __post_init__(self) -> None:
        if self.workers < 1 or not self.timeout_s > 0 or self.memory_limit_mb < 0 or self.task_memory_mb < 0:
            raise FunrecError(
                f"BatchConfig: workers must be >= 1, timeout_s > 0 and the memory sizes >= 0, got {self}"
            )


@dataclass(frozen=True)
class CaptureResult:
    """One row of the summary."""

    capture: str
    """Capture folder name."""
    status: str
    """'ok', 'skipped' (a complete twin was already there), 'failed' or 'timeout'."""
    parts: int | None
    """Articulated parts in the twin (None without a twin)."""
    seconds: float | None
    """Wall time of the reconstruct process, seconds (None if skipped)."""
    peak_mb: float | None
    """Peak resident memory of the reconstruct process, MiB (None if skipped or killed before reporting)."""
    error: str | None
    """Why it failed (the last line of its log)."""
    cpu_s: float | None = None
    """CPU time (user + system) of the reconstruct process and its children, seconds (None if skipped or killed)."""
    axis_error_deg: float | None = None
    """Mean axis error of the matched true parts, degrees (with evaluation)."""
    state_error: float | None = None
    """Mean state error of the matched true parts, rad or m (with evaluation)."""
    failed_parts: int | None = None
    """True parts not matched or of the wrong joint type (with evaluation)."""


@dataclass(frozen=True)
class BatchReport:
    """All rows and where they were written."""

    rows: tuple[CaptureResult, ...]
    """One per capture, in name order."""
    out_dir: Path
    """Twins are in out_dir/twins/<capture>, logs in out_dir/logs, the table in out_dir/summary.csv and .md."""
    wall_s: float
    """Wall time of the whole batch, seconds."""
    workers: int
    """Captures run at once."""
    backend: str
    """'processes' or 'ray <address>'."""

    @property
    def captures_per_hour(self) -> float | None:
        """Captures reconstructed (status ok) per hour of batch wall time."""
        done = sum(r.status == "ok" for r in self.rows)
        return 3600.0 * done / self.wall_s if done and self.wall_s > 0 else None


def find_captures(dataset_dir: str | Path) -> list[Path]:
    """Capture folders (holding intrinsics.json) directly inside ``dataset_dir``, by name."""
    root = Path(dataset_dir)
    if not root.is_dir():
        raise FunrecError(f"{root}: not a folder")
    captures = sorted(p for p in root.iterdir() if p.is_dir() and (p / "intrinsics.json").is_file())
    if not captures:
        raise FunrecError(f"{root}: no capture folders (sub-folders with intrinsics.json)")
    return captures


def twin_is_complete(twin_dir: Path) -> bool:
    """True if a twin folder is there: TwinWriter renames a twin into place only once complete, so a twin
    folder with articulation.json is a finished one; a killed run leaves only a '.NAME.partial-*' folder."""
    return (twin_dir / "articulation.json").is_file()


def _remove_partials(twin_dir: Path) -> None:
    for stale in twin_dir.parent.glob(f".{twin_dir.name}.partial-*"):
        log.info("removing %s left by an interrupted run", stale)
        shutil.rmtree(stale, ignore_errors=True)


def _part_count(twin_dir: Path) -> int | None:
    from funrec.formats.twin import read_articulation

    try:
        return len(read_articulation(twin_dir / "articulation.json").parts)
    except FunrecError:
        return None


def _evaluate(row: CaptureResult, twin_dir: Path, capture: Path) -> CaptureResult:
    import dataclasses

    import numpy as np

    from funrec.bench.evaluate import evaluate_twin

    if row.status not in ("ok", "skipped") or not (capture / "gt" / "gt.json").is_file():
        return row
    try:
        evaluation = evaluate_twin(twin_dir, capture / "gt")
    except Exception as exc:  # a bug in scoring one twin must not lose the other rows
        return dataclasses.replace(row, error=f"evaluation failed: {type(exc).__name__}: {exc}")
    scored = [p for p in evaluation.parts if not p.failed]

    def mean(values: list[float | None]) -> float | None:
        present = [v for v in values if v is not None]
        return float(np.mean(present)) if present else None

    return dataclasses.replace(
        row,
        axis_error_deg=mean([p.axis_error_deg for p in scored]),
        state_error=mean([p.state_error for p in scored]),
        failed_parts=len(evaluation.parts) - len(scored),
    )


def run_capture(capture: str | Path, out_dir: str | Path, config: BatchConfig = BatchConfig(),  # noqa: B008 (frozen, immutable default)
                active: set[int] | None = None) -> CaptureResult:
    """Reconstruct one capture into ``out_dir/twins/<name>`` in a memory-limited process; never raises.

    A complete twin already there is kept ('skipped'); leftovers of an interrupted run are removed first.
    ``active`` (local scheduler) holds the process group while it runs, to be killed on an interruption.
    """
    capture, out_dir = Path(capture), Path(out_dir)
    twin = out_dir / "twins" / capture.name
    log_path = out_dir / "logs" / f"{capture.name}.log"
    if twin_is_complete(twin):
        row = CaptureResult(capture.name, "skipped", _part_count(twin), None, None, None)
        return _evaluate(row, twin, capture) if config.evaluate else row
    _remove_partials(twin)
    if twin.exists():
        shutil.rmtree(twin)  # a folder without articulation.json is not a twin
    log_path.parent.mkdir(parents=True, exist_ok=True)
    twin.parent.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "-m", "funrec", "reconstruct", str(capture), "-o", str(twin), *config.reconstruct_args]
    run = run_funrec_child(command, log_path, config.timeout_s, config.memory_limit_mb, active)
    if run.timed_out:
        status, parts, error = "timeout", None, f"timeout after {config.timeout_s:g} s"
    elif run.returncode != 0 or not twin_is_complete(twin):
        status, parts, error = "failed", None, f"exit code {run.returncode}: {last_log_line(log_path)}"
        if config.memory_limit_mb and run.returncode not in (0, 2):
            # Running out of a memory limit shows up in many guises (MemoryError, "failed to map segment from
            # shared object" when a library cannot even be loaded): say that the limit may be the cause.
            error += f" (the run had a {config.memory_limit_mb} MiB address-space limit; raise --memory-limit-mb if it ran out)"
    else:
        status, parts, error = "ok", _part_count(twin), None
    row = CaptureResult(capture.name, status, parts, run.seconds, run.peak_mb, error, run.cpu_s)
    return _evaluate(row, twin, capture) if config.evaluate else row


def run_batch(
    dataset_dir: str | Path,
    out_dir: str | Path,
    config: BatchConfig = BatchConfig(),  # noqa: B008 (frozen, immutable default)
    progress: Progress | None = None,
) -> BatchReport:
    """Reconstruct every capture of ``dataset_dir`` and write the summary table.

    Args:
        dataset_dir: folder of capture folders (FORMATS.md section 1).
        out_dir: output folder: twins/<capture>/, logs/<capture>.log, summary.csv, summary.md.
        config: workers, backend, memory limit, evaluation.
        progress: optional ``progress(done, total)``.

    Raises:
        FunrecError: no captures, or Ray requested but not installed. A failing capture is a row.
    """
    refuse_output_over_input(out_dir, dataset_dir)
    captures = find_captures(dataset_dir)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    jobs = [(str(c), str(out_dir), config) for c in captures]
    rows = run_jobs(run_capture, jobs, config.workers, config.ray, config.task_memory_mb, progress)
    backend = "processes" if config.ray is None else f"ray {config.ray}"
    report = BatchReport(tuple(rows), out_dir, time.perf_counter() - start, config.workers, backend)
    write_summary(report, config.evaluate)
    return report


def _cell(value: object) -> str:
    if value is None:
        return ""
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def write_summary(report: BatchReport, evaluated: bool) -> None:
    """Write out_dir/summary.csv and out_dir/summary.md."""
    columns = COLUMNS + (("axis_error_deg", "state_error", "failed_parts") if evaluated else ())
    table = [[_cell(getattr(r, c)) for c in columns] for r in report.rows]
    with open(report.out_dir / "summary.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        writer.writerows(table)
    rate = report.captures_per_hour
    lines = [
        f"# funrec batch: {len(report.rows)} captures, {report.workers} worker(s), {report.backend}",
        "",
        f"wall time {report.wall_s:.1f} s; {'-' if rate is None else f'{rate:.1f}'} captures/hour "
        f"(status ok only); {sum(r.status == 'ok' for r in report.rows)} ok, "
        f"{sum(r.status == 'skipped' for r in report.rows)} skipped, "
        f"{sum(r.status in ('failed', 'timeout') for r in report.rows)} failed",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
        *("| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in table),
    ]
    (report.out_dir / "summary.md").write_text("\n".join(lines) + "\n")


__all__ = ["BatchConfig", "BatchReport", "CaptureResult", "find_captures", "run_batch", "run_capture", "twin_is_complete"]
