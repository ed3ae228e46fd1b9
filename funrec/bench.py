"""Benchmark runner: reconstruct every sequence of a synthetic suite in a subprocess, score each
twin with :func:`funrec.evaluate.evaluate_twin` and write report.json and report.md.

A sequence that crashes, times out or yields an unreadable twin is a failure row; the run
never aborts on one sequence.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging
import os
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from funrec.capture import load_capture
from funrec.errors import FunrecError
from funrec.evaluate import EvalConfig, TwinEvaluation, evaluate_twin, evaluation_to_json, failed_evaluation

LOGGER = logging.getLogger(__name__)

METHODS = ("funrec", "oracle", "trivial")
"""Methods :func:`run_bench` can run: the reconstruction, and the two reference baselines."""
_BASELINE_SNIPPET = "import sys; from funrec.baselines import {function}; {function}(sys.argv[1], sys.argv[2])"
# Forks the measured command from a bare interpreter (~10 MB) and writes its wait status and
# ru_maxrss to argv[1]. Linux carries a process's peak RSS across fork and exec (exec records
# the old address space's high-water mark), so a command started straight from the bench
# would report at least the bench's own RSS.
_LAUNCHER = (
    "import os, sys\n"
    "pid = os.fork()\n"
    "if pid == 0:\n"
    "    try:\n"
    "        os.execvp(sys.argv[2], sys.argv[2:])\n"
    "    except OSError as exc:\n"
    "        sys.stderr.write(f'cannot run {sys.argv[2]}: {exc}\\n')\n"
    "        os._exit(127)\n"
    "_, status, rusage = os.wait4(pid, 0)\n"
    "with open(sys.argv[1], 'w') as f:\n"
    "    f.write(f'{status} {rusage.ru_maxrss}')\n"
    "code = os.waitstatus_to_exitcode(status)\n"
    "sys.exit(code if code >= 0 else 128 - code)\n"
)
_PROJECT_ROOT = Path(__file__).resolve().parents[1]

ProgressCallback = Callable[[int, int], None]
"""``progress(done, total)``, called after each (method, sequence) run; the CLI draws a bar."""


@dataclass(frozen=True)
class BenchConfig:
    """Settings of :func:`run_bench`."""

    method: str = "funrec"
    """Method to run: "funrec" (reconstruct in a subprocess), "oracle" or "trivial" (funrec.baselines)."""
    suite: str = "bench"
    """Named suite of funrec.synth used to generate missing sequences ("bench" or "smoke")."""
    timeout_s: float = 1800.0
    """Wall-time limit per sequence, seconds; a run that exceeds it is killed and is a failure row."""
    only: tuple[str, ...] | None = None
    """Run only these sequence names (None: every sequence of the suite folder)."""
    reconstruct_args: tuple[str, ...] = ()
    """Extra arguments appended to ``funrec reconstruct CAPTURE -o TWIN`` (method "funrec" and ablations)."""
    ablations: tuple[tuple[str, tuple[str, ...]], ...] = ()
    """(label, extra reconstruct args) pairs; each runs "funrec reconstruct" with reconstruct_args
    plus its extra args as an additional method and gets a row in the ablation table."""
    generate_missing: bool = True
    """Generate missing sequences with funrec.synth.generate_suite before running."""
    jobs: int = 1
    """Sequences run in parallel (each in its own subprocess)."""
    evaluation: EvalConfig = EvalConfig()
    """Evaluation settings."""


@dataclass(frozen=True)
class SequenceResult:
    """One method on one sequence: how the run went and its evaluation."""

    name: str
    """Sequence name (folder name in the suite)."""
    method: str
    """Method label (the method, or an ablation label)."""
    status: str
    """"ok", "failed" (crash, bad exit code, unreadable twin) or "timeout"."""
    reason: str | None
    """Why the run failed; None when status is "ok"."""
    frame_count: int
    """Frames in the capture (0 if the capture is unreadable)."""
    wall_s: float | None
    """Wall time of the run subprocess, seconds; None if it never started."""
    peak_rss_mb: float | None
    """Peak resident memory of the run subprocess (its ru_maxrss), MiB; None if unknown (timeout)."""
    evaluation: TwinEvaluation
    """Scores; when the run failed every true part fails with the run's reason."""
    twin_dir: Path
    """Where the twin was written."""
    log_path: Path | None
    """stdout and stderr of the run subprocess."""

    @property
    def frames_per_s(self) -> float | None:
        """Throughput of a completed run: frames / wall time."""
        if self.status != "ok" or not self.wall_s or not self.frame_count:
            return None
        return self.frame_count / self.wall_s


@dataclass(frozen=True)
class BenchSummary:
    """Aggregate of one method over sequences, in the layout of the paper's tables.

    Part metrics average over non-failed parts; ``fail_pct`` is over all true parts; CD and
    ATE average over sequences that have them; throughput is total frames over total wall
    time of completed runs; peak memory is the maximum over runs.
    """

    sequences: int
    """Sequences run."""
    failed_sequences: int
    """Sequences whose run or twin failed."""
    parts: int
    """True parts over all sequences."""
    failed_parts: int
    """True parts that failed (no match, wrong joint type, or their sequence failed)."""
    invented_parts: int
    """Predicted parts matched to no true part, summed."""
    axis_revolute_deg: float | None
    """Mean axis direction error of revolute parts, degrees (None: no scored part of the type)."""
    axis_prismatic_deg: float | None
    """Mean axis direction error of prismatic parts, degrees."""
    pivot_m: float | None
    """Mean axis position (pivot line) error of revolute parts, metres."""
    state_revolute_deg: float | None
    """Mean state error of revolute parts, degrees."""
    state_prismatic_m: float | None
    """Mean state error of prismatic parts, metres."""
    fail_pct: float | None
    """Failed true parts over all true parts, percent (None: no true parts)."""
    adds_auc: float | None
    """Mean ADD-S AUC (0-10 cm), percent."""
    add_auc: float | None
    """Mean ADD AUC (0-10 cm), percent."""
    chamfer_cm: float | None
    """Mean scene chamfer distance, cm."""
    miou: float | None
    """Mean part mIoU, percent (parts without a non-empty true mask in their frames are left out)."""
    camera_ate_cm: float | None
    """Mean camera ATE (camera-0 frame, no alignment), cm."""
    frames_per_s: float | None
    """Total frames over total wall time of completed runs."""
    peak_rss_mb: float | None
    """Largest peak RSS of a run subprocess, MiB."""


@dataclass(frozen=True)
class MethodReport:
    """All sequences of one method (or ablation) and their summary."""

    label: str
    """Method name or ablation label."""
    command: tuple[str, ...]
    """Command template run per sequence; CAPTURE and TWIN stand for the folders."""
    sequences: tuple[SequenceResult, ...]
    """Per-sequence results, in suite order."""
    summary: BenchSummary
    """Aggregate over ``sequences``."""


@dataclass(frozen=True)
class BenchReport:
    """Everything :func:`run_bench` measured, plus where and how it ran."""

    suite_dir: Path
    """The suite folder run."""
    out_dir: Path
    """Where twins, logs and the report were written."""
    methods: tuple[MethodReport, ...]
    """The main method first, then one entry per ablation."""
    git_commit: str
    """``git rev-parse --short HEAD``, with "-dirty" if tracked files changed; "unknown" without git."""
    machine: str
    """CPU model, core count, OS and architecture."""
    date: str
    """Start time, ISO 8601 UTC."""
    command_line: str
    """The command line that started the bench."""
    config: BenchConfig
    """The settings it ran with."""

    @property
    def main(self) -> MethodReport:
        return self.methods[0]

    @property
    def ablations(self) -> tuple[MethodReport, ...]:
        return self.methods[1:]


def _mean(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def summarize(results: tuple[SequenceResult, ...] | list[SequenceResult]) -> BenchSummary:
    """Aggregate sequence results as described in :class:`BenchSummary`."""
    parts = [p for r in results for p in r.evaluation.parts]
    scored = [p for p in parts if not p.failed]
    revolute = [p for p in scored if p.joint_type == "revolute"]
    prismatic = [p for p in scored if p.joint_type == "prismatic"]
    done = [r for r in results if r.status == "ok" and r.wall_s]
    wall = sum(r.wall_s or 0.0 for r in done)
    rss = [r.peak_rss_mb for r in results if r.peak_rss_mb is not None]
    return BenchSummary(
        sequences=len(results),
        failed_sequences=sum(r.status != "ok" for r in results),
        parts=len(parts),
        failed_parts=len(parts) - len(scored),
        invented_parts=sum(len(r.evaluation.invented_parts) for r in results),
        axis_revolute_deg=_mean([p.axis_error_deg for p in revolute]),
        axis_prismatic_deg=_mean([p.axis_error_deg for p in prismatic]),
        pivot_m=_mean([p.pivot_error_m for p in revolute]),
        state_revolute_deg=_mean([p.state_error for p in revolute]),
        state_prismatic_m=_mean([p.state_error for p in prismatic]),
        fail_pct=100.0 * (len(parts) - len(scored)) / len(parts) if parts else None,
        adds_auc=_mean([p.adds_auc for p in scored]),
        add_auc=_mean([p.add_auc for p in scored]),
        chamfer_cm=_mean([r.evaluation.chamfer_cm for r in results]),
        miou=_mean([p.miou for p in scored]),
        camera_ate_cm=_mean([r.evaluation.camera_ate_cm for r in results]),
        frames_per_s=sum(r.frame_count for r in done) / wall if wall > 0 else None,
        peak_rss_mb=max(rss) if rss else None,
    )


@dataclass(frozen=True)
class _ChildResult:
    returncode: int
    """Exit code of the command; negative: killed by that signal."""
    wall_s: float
    """Wall time from start to exit, seconds."""
    peak_rss_mb: float | None
    """Peak resident memory of the command, MiB; None if it was killed before reporting."""
    timed_out: bool
    """True if it was killed at the time limit."""


def _run_child(command: list[str], log_path: Path, timeout_s: float, active: set[int] | None = None) -> _ChildResult:
    """Run ``command`` in its own session, killing the whole group after ``timeout_s``.

    The command runs under a bare-interpreter launcher (see ``_LAUNCHER``) that reaps it with
    ``os.wait4`` and reports its own ``ru_maxrss`` (KiB on Linux): the peak memory of the
    command and the descendants it waited for, not of the bench. The process-group id is in
    ``active`` while it runs, so an interrupted bench can kill it (its own session does not
    receive the terminal's Ctrl-C).
    """
    active = set() if active is None else active
    env = dict(os.environ)
    # The child must import the same funrec as this process, installed or not.
    env["PYTHONPATH"] = os.pathsep.join([str(_PROJECT_ROOT), *filter(None, [env.get("PYTHONPATH")])])
    log_path.parent.mkdir(parents=True, exist_ok=True)
    rusage_path = log_path.with_name(f".{log_path.name}.rusage")
    rusage_path.unlink(missing_ok=True)
    timed_out = threading.Event()
    start = time.perf_counter()
    with open(log_path, "wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-I", "-S", "-c", _LAUNCHER, str(rusage_path), *command],
            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env, start_new_session=True,
        )

        def kill() -> None:
            timed_out.set()
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

        timer = threading.Timer(timeout_s, kill)
        active.add(process.pid)
        timer.start()
        try:
            process.wait()
        finally:
            timer.cancel()
            active.discard(process.pid)
    wall_s = time.perf_counter() - start
    try:
        status_text, maxrss_kib = rusage_path.read_text().split()
        rusage_path.unlink()
        returncode, peak_rss_mb = os.waitstatus_to_exitcode(int(status_text)), int(maxrss_kib) / 1024.0
    except (OSError, ValueError):  # killed before the launcher could report
        returncode, peak_rss_mb = process.returncode, None
    return _ChildResult(returncode, wall_s, peak_rss_mb, timed_out.is_set())


def _method_command(method: str, extra: tuple[str, ...], capture: str, twin: str) -> list[str]:
    if method == "funrec":
        return [sys.executable, "-m", "funrec", "reconstruct", capture, "-o", twin, *extra]
    function = {"oracle": "write_oracle_twin", "trivial": "write_trivial_twin"}[method]
    return [sys.executable, "-c", _BASELINE_SNIPPET.format(function=function), capture, twin]


def _last_line(log_path: Path) -> str:
    try:
        lines = [line.strip() for line in log_path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return lines[-1][:300] if lines else ""


def _run_sequence(
    label: str, method: str, extra: tuple[str, ...], capture: Path, out_dir: Path, config: BenchConfig, active: set[int]
) -> SequenceResult:
    """Run one method on one capture and evaluate; every failure becomes a result, never an exception."""
    twin = out_dir / "twins" / label / capture.name
    log_path = out_dir / "logs" / label / f"{capture.name}.log"
    gt_dir = capture / "gt"

    def failure(status: str, reason: str, frames: int = 0, child: _ChildResult | None = None) -> SequenceResult:
        LOGGER.warning("%s on %s: %s", label, capture.name, reason)
        wall, rss = (child.wall_s, child.peak_rss_mb) if child else (None, None)
        return SequenceResult(capture.name, label, status, reason, frames, wall, rss, failed_evaluation(twin, gt_dir, reason), twin, log_path)

    try:
        frame_count = len(load_capture(capture, check_headers=False))
    except FunrecError as exc:
        return failure("failed", f"capture unreadable: {exc}")
    if twin.exists():
        shutil.rmtree(twin)  # a stale twin from an earlier bench must never be scored
    twin.parent.mkdir(parents=True, exist_ok=True)
    try:
        child = _run_child(_method_command(method, extra, str(capture), str(twin)), log_path, config.timeout_s, active)
    except OSError as exc:  # cannot start the process or write its log
        return failure("failed", f"cannot run: {exc}", frame_count)
    if child.timed_out:
        return failure("timeout", f"timeout after {config.timeout_s:g} s", frame_count, child)
    if child.returncode != 0:
        return failure("failed", f"exit code {child.returncode}: {_last_line(log_path)}", frame_count, child)
    try:
        evaluation = evaluate_twin(twin, gt_dir, config.evaluation)
    except Exception as exc:  # a bug in scoring one twin must not lose the other rows
        LOGGER.exception("evaluation of %s crashed", twin)
        return failure("failed", f"evaluation crashed: {type(exc).__name__}: {exc}", frame_count, child)
    status, reason = ("ok", None) if evaluation.ok else ("failed", evaluation.failure)
    return SequenceResult(capture.name, label, status, reason, frame_count, child.wall_s, child.peak_rss_mb, evaluation, twin, log_path)


def _is_sequence(path: Path) -> bool:
    return path.is_dir() and (path / "gt" / "gt.json").is_file() and (path / "intrinsics.json").is_file()


def _prepare_suite(suite_dir: Path, config: BenchConfig) -> list[Path]:
    """Sequence folders to run, in order.

    With ``generate_missing``, funrec.synth.generate_suite makes the suite's missing
    sequences (it skips complete ones) and, without ``only``, the suite's sequences are run.
    Otherwise the complete captures found in ``suite_dir`` (filtered by ``only``) are run.
    """
    names = list(config.only) if config.only else None
    if config.generate_missing:
        todo = None if names is None else [n for n in names if not _is_sequence(suite_dir / n)]
        if todo is None or todo:
            try:
                synth = importlib.import_module("funrec.synth")
            except ImportError as exc:
                raise FunrecError(f"{suite_dir}: cannot generate sequences ({todo or 'the suite'}): funrec.synth is unavailable ({exc})") from None
            LOGGER.info("generating missing sequences of suite %r in %s", config.suite, suite_dir)
            paths = synth.generate_suite(suite_dir, suite=config.suite, only=todo)
            names = names if names is not None else [Path(p).name for p in paths]
    found = sorted(p.name for p in suite_dir.iterdir() if _is_sequence(p)) if suite_dir.is_dir() else []
    names = found if names is None else names
    absent = [n for n in names if not _is_sequence(suite_dir / n)]
    if absent:
        raise FunrecError(f"{suite_dir}: no capture with gt/ for {absent}; found {found}")
    if not names:
        raise FunrecError(f"{suite_dir}: no sequences (folders with intrinsics.json and gt/gt.json)")
    return [suite_dir / n for n in names]


def _git_commit() -> str:
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=_PROJECT_ROOT, capture_output=True, text=True, check=True, timeout=30).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + ("-dirty" if dirty else "")


def _machine() -> str:
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model or platform.processor() or 'unknown CPU'}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}"


def run_bench(
    suite_dir: str | Path,
    out_dir: str | Path,
    config: BenchConfig = BenchConfig(),
    progress: ProgressCallback | None = None,
    command_line: str | None = None,
) -> BenchReport:
    """Run a method (and its ablations) on every sequence of a suite, score, and write the report.

    Twins go to ``out_dir/twins/<label>/<sequence>/``, run logs to ``out_dir/logs/``, and the
    report to ``out_dir/report.json`` and ``out_dir/report.md``.

    Args:
        suite_dir: folder of capture folders with ground truth (FORMATS.md section 4).
        out_dir: report folder, created if needed.
        config: what to run; see :class:`BenchConfig`.
        progress: optional ``progress(done, total)`` callback over (method, sequence) runs.
        command_line: recorded in the report; defaults to this process's ``sys.argv``.

    Raises:
        FunrecError: unknown method, duplicate labels, or no sequences to run. A sequence that
            crashes or times out is a failure row, never an exception.
    """
    if config.method not in METHODS:
        raise FunrecError(f"unknown bench method {config.method!r}; expected one of {list(METHODS)}")
    labels = [config.method, *(label for label, _ in config.ablations)]
    if len(set(labels)) != len(labels):
        raise FunrecError(f"method and ablation labels must be unique, got {labels}")
    if config.jobs < 1 or not config.timeout_s > 0:
        raise FunrecError(f"jobs must be >= 1 and timeout_s > 0, got {config.jobs} and {config.timeout_s}")
    for ablation in config.ablations:
        if len(ablation) != 2 or not isinstance(ablation[0], str) or not all(isinstance(a, str) for a in ablation[1]):
            raise FunrecError(f"each ablation must be (label, [extra args]), got {ablation!r}")
    suite_dir, out_dir = Path(suite_dir), Path(out_dir)
    date = datetime.now(timezone.utc).isoformat(timespec="seconds")
    captures = _prepare_suite(suite_dir, config)
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = [(config.method, config.method, config.reconstruct_args)]
    runs += [(label, "funrec", config.reconstruct_args + tuple(extra)) for label, extra in config.ablations]
    tasks = [(label, method, extra, capture) for label, method, extra in runs for capture in captures]
    results: dict[tuple[str, str], SequenceResult] = {}
    active: set[int] = set()
    pool = ThreadPoolExecutor(max_workers=config.jobs)
    try:
        futures = [pool.submit(_run_sequence, label, method, extra, capture, out_dir, config, active) for label, method, extra, capture in tasks]
        for future in as_completed(futures):
            result = future.result()
            results[(result.method, result.name)] = result
            if progress is not None:
                progress(len(results), len(tasks))
    except BaseException:
        # Interrupted (or a bug): stop queued runs and kill running children instead of
        # waiting up to timeout_s for each.
        pool.shutdown(wait=False, cancel_futures=True)
        for pgid in list(active):
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        raise
    pool.shutdown()
    methods = []
    for label, method, extra in runs:
        rows = tuple(results[(label, c.name)] for c in captures)
        command = tuple(_method_command(method, extra, "CAPTURE", "TWIN"))
        methods.append(MethodReport(label, ("python", *command[1:]), rows, summarize(rows)))
    report = BenchReport(
        suite_dir, out_dir, tuple(methods), _git_commit(), _machine(), date,
        command_line if command_line is not None else shlex.join(sys.argv), config,
    )
    (out_dir / "report.json").write_text(json.dumps(report_to_json(report), indent=2) + "\n")
    (out_dir / "report.md").write_text(report_to_markdown(report))
    return report


TABLE_COLUMNS = (
    "Axis (deg) rev / pri", "Pos (m)", "State (deg / m) rev / pri", "Fail (%)",
    "ADD-S (%)", "ADD (%)", "CD (cm)", "mIoU (%)", "ATE (cm)", "frames/s", "peak MB",
)
"""Columns of every table: the paper's Tables 1-3 (revolute / prismatic pairs as "XX / YY"),
then camera ATE, throughput and peak memory."""
AGGREGATION_NOTE = (
    "Axis, Pos, State, ADD-S, ADD and mIoU average over non-failed parts; Fail (%) is over all true "
    "parts (a part fails when no predicted part matches it or its joint type is wrong, and every part "
    "of a sequence that crashed, timed out or wrote an unreadable twin fails). CD and ATE average over "
    "scored sequences; frames/s is total frames over total wall time of completed runs; peak MB is the "
    "largest peak RSS of a run subprocess."
)


def _f(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _cells(s: BenchSummary) -> list[str]:
    return [
        f"{_f(s.axis_revolute_deg, 1)} / {_f(s.axis_prismatic_deg, 1)}",
        _f(s.pivot_m, 3),
        f"{_f(s.state_revolute_deg, 1)} / {_f(s.state_prismatic_m, 3)}",
        _f(s.fail_pct, 1),
        _f(s.adds_auc, 1),
        _f(s.add_auc, 1),
        _f(s.chamfer_cm, 2),
        _f(s.miou, 1),
        _f(s.camera_ate_cm, 2),
        _f(s.frames_per_s, 2),
        _f(s.peak_rss_mb, 0),
    ]


def _table(first: str, rows: list[tuple[str, list[str]]]) -> list[str]:
    header = [first, *TABLE_COLUMNS]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + [":---:"] * len(TABLE_COLUMNS)) + "|"]
    lines += ["| " + " | ".join([name, *cells]) + " |" for name, cells in rows]
    return lines


def format_report(report: BenchReport) -> str:
    """The main table (and the ablation table, if any) as Markdown for the terminal."""
    lines = _table("Method", [(m.label, _cells(m.summary)) for m in report.methods[:1]])
    s = report.main.summary
    lines.append(
        f"sequences: {s.sequences} ({s.failed_sequences} failed); true parts: {s.parts} "
        f"({s.failed_parts} failed); invented parts: {s.invented_parts}"
    )
    for row in report.main.sequences:
        if row.status != "ok":
            lines.append(f"  {row.name}: {row.status}: {row.reason}")
    if report.ablations:
        lines += ["", *_table("Ablation", [(m.label, _cells(m.summary)) for m in report.methods])]
    return "\n".join(lines)


def report_to_markdown(report: BenchReport) -> str:
    """report.md: header, main table, per-sequence tables, ablation table, failure reasons."""
    lines = [
        "# FunREC benchmark",
        "",
        f"- git commit: `{report.git_commit}`",
        f"- machine: {report.machine}",
        f"- date: {report.date}",
        f"- method: {report.config.method}" + (f" (ablations: {', '.join(m.label for m in report.ablations)})" if report.ablations else ""),
        f"- command line: `{report.command_line}`",
        f"- suite: `{report.suite_dir}` ({len(report.main.sequences)} sequences), timeout {report.config.timeout_s:g} s per sequence",
        "",
        AGGREGATION_NOTE,
        "",
        "## Results",
        "",
        *_table("Method", [(report.main.label, _cells(report.main.summary))]),
    ]
    if report.ablations:
        lines += ["", "## Ablations", "", *_table("Variant", [(m.label, _cells(m.summary)) for m in report.methods])]
    for method in report.methods:
        lines += ["", f"## Per sequence: {method.label}", "", f"Command: `{shlex.join(method.command)}`", ""]
        lines += _table("Sequence", [(r.name, _cells(summarize([r]))) for r in method.sequences])
        failures = [r for r in method.sequences if r.status != "ok"]
        part_failures = [(r.name, p) for r in method.sequences if r.status == "ok" for p in r.evaluation.parts if p.failed]
        if failures or part_failures:
            lines += ["", "Failures:", ""]
            lines += [f"- {r.name}: {r.status}: {r.reason}" for r in failures]
            lines += [f"- {name} / {p.true_name}: {p.failure}" for name, p in part_failures]
    return "\n".join(lines) + "\n"


def _jsonable(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def report_to_json(report: BenchReport) -> dict[str, Any]:
    """report.json: the header, the config, and per method its summary and every sequence."""
    methods = []
    for method in report.methods:
        rows = []
        for r in method.sequences:
            row = {f.name: getattr(r, f.name) for f in dataclasses.fields(r) if f.name != "evaluation"}
            row["frames_per_s"] = r.frames_per_s
            row["evaluation"] = evaluation_to_json(r.evaluation)
            rows.append(_jsonable(row))
        methods.append({"label": method.label, "command": list(method.command), "summary": dataclasses.asdict(method.summary), "sequences": rows})
    return {
        "format": "funrec-bench/1",
        "git_commit": report.git_commit,
        "machine": report.machine,
        "date": report.date,
        "command_line": report.command_line,
        "suite_dir": str(report.suite_dir),
        "out_dir": str(report.out_dir),
        "config": _jsonable(dataclasses.asdict(report.config)),
        "aggregation": AGGREGATION_NOTE,
        "methods": methods,
    }


__all__ = [
    "METHODS",
    "BenchConfig",
    "BenchReport",
    "BenchSummary",
    "MethodReport",
    "SequenceResult",
    "format_report",
    "report_to_json",
    "report_to_markdown",
    "run_bench",
    "summarize",
]
