"""Benchmark runner: reconstruct every sequence of a synthetic suite in a subprocess, score each
twin with :func:`funrec.bench.evaluate.evaluate_twin` and write report.json and report.md
(:mod:`funrec.bench.report`).

A sequence that crashes, times out or yields an unreadable twin is a failure row; the run
never aborts on one sequence.
"""

from __future__ import annotations

import importlib
import json
import logging
import os
import platform
import shlex
import shutil
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

from funrec.bench.config import (
    ABLATION_SETS,
    METHODS,
    SPEED_BASELINES,
    STANDARD_ABLATIONS,
    BenchConfig,
)
from funrec.bench.evaluate import evaluate_twin, failed_evaluation
from funrec.bench.fragment_metrics import FragmentScore, score_twin_fragments
from funrec.bench.launcher import LimitedRun
from funrec.bench.report import (
    BenchReport,
    BenchSummary,
    MethodReport,
    SequenceResult,
    format_report,
    report_to_json,
    report_to_markdown,
    summarize,
)
from funrec.bench.scheduler import Progress, last_log_line, run_funrec_child, run_jobs
from funrec.errors import FunrecError
from funrec.formats.capture import load_capture
from funrec.formats.staged_folder import refuse_output_over_input, write_text_staged

LOGGER = logging.getLogger(__name__)

DEFAULT_FAMILY = "textured"
"""Family of a sequence whose gt.json names none (generator version 1: the textured bench)."""
_BASELINE_SNIPPET = "import sys; from funrec.bench.baselines import {function}; {function}(sys.argv[1], sys.argv[2])"
_PROJECT_ROOT = Path(__file__).resolve().parents[1]

ProgressCallback = Progress
"""``progress(done, total)``, called after each (method, sequence) run; the CLI draws a bar."""


def _method_command(method: str, extra: tuple[str, ...], capture: str, twin: str) -> list[str]:
    if method == "funrec":
        return [sys.executable, "-m", "funrec", "reconstruct", capture, "-o", twin, *extra]
    function = {"oracle": "write_oracle_twin", "trivial": "write_trivial_twin", "open3d": "write_open3d_twin"}[method]
    return [sys.executable, "-c", _BASELINE_SNIPPET.format(function=function), capture, twin]


def _run_sequence(
    label: str, method: str, extra: tuple[str, ...], capture: Path, out_dir: Path, config: BenchConfig,
    active: set[int] | None = None,
) -> SequenceResult:
    """Run one method on one capture and evaluate; every failure becomes a result, never an exception.
    A job of :func:`funrec.bench.scheduler.run_jobs`, the scheduler of funrec batch."""
    twin = out_dir / "twins" / label / capture.name
    log_path = out_dir / "logs" / label / f"{capture.name}.log"
    gt_dir = capture / "gt"

    def failure(status: str, reason: str, frames: int = 0, child: LimitedRun | None = None) -> SequenceResult:
        LOGGER.warning("%s on %s: %s", label, capture.name, reason)
        wall, rss, cpu = (child.seconds, child.peak_mb, child.cpu_s) if child else (None, None, None)
        return SequenceResult(
            capture.name, label, status, reason, frames, wall, rss, failed_evaluation(twin, gt_dir, reason), twin, log_path,
            cpu, family=sequence_family(capture),
        )

    try:
        frame_count = len(load_capture(capture, check_headers=False))
    except FunrecError as exc:
        return failure("failed", f"capture unreadable: {exc}")
    if twin.exists():
        shutil.rmtree(twin)  # a stale twin from an earlier bench must never be scored
    twin.parent.mkdir(parents=True, exist_ok=True)
    try:
        command = _method_command(method, extra, str(capture), str(twin))
        child = run_funrec_child(command, log_path, config.timeout_s, config.memory_limit_mb, active)
    except OSError as exc:  # cannot start the process or write its log
        return failure("failed", f"cannot run: {exc}", frame_count)
    if child.timed_out:
        return failure("timeout", f"timeout after {config.timeout_s:g} s", frame_count, child)
    if child.returncode != 0:
        return failure("failed", f"exit code {child.returncode}: {last_log_line(log_path)}", frame_count, child)
    try:
        evaluation = evaluate_twin(twin, gt_dir, config.evaluation)
    except Exception as exc:  # a bug in scoring one twin must not lose the other rows
        LOGGER.exception("evaluation of %s crashed", twin)
        return failure("failed", f"evaluation crashed: {type(exc).__name__}: {exc}", frame_count, child)
    status, reason = ("ok", None) if evaluation.ok else ("failed", evaluation.failure)
    return SequenceResult(
        capture.name, label, status, reason, frame_count, child.seconds, child.peak_mb, evaluation, twin, log_path, child.cpu_s,
        _fragment_score(twin, gt_dir), family=sequence_family(capture),
    )


def sequence_family(capture: Path) -> str:
    """The bench family of a generated capture: ``generator.spec.family`` of its gt/gt.json
    (:data:`DEFAULT_FAMILY` when the file predates families or cannot be read)."""
    try:
        spec = json.loads((Path(capture) / "gt" / "gt.json").read_text()).get("generator", {}).get("spec", {})
    except (OSError, ValueError, AttributeError):
        return DEFAULT_FAMILY
    family = spec.get("family") if isinstance(spec, dict) else None
    return family if isinstance(family, str) and family else DEFAULT_FAMILY


def _fragment_score(twin: Path, gt_dir: Path) -> FragmentScore | None:
    """The twin's fragments scored against the true interactions; None when it has no fragments.json
    (baselines) or it cannot be read (logged: fragments are not part of FORMATS.md's contract)."""
    if not (twin / "fragments.json").is_file():
        return None
    try:
        return score_twin_fragments(twin, gt_dir)
    except (FunrecError, OSError, ValueError) as exc:
        LOGGER.warning("%s: fragments not scored: %s", twin, exc)
        return None


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


def _ablations(config: BenchConfig) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """Validated settings: the explicit ablations followed by the named set."""
    if config.method not in METHODS:
        raise FunrecError(f"unknown bench method {config.method!r}; expected one of {list(METHODS)}")
    if config.ablation_set not in ABLATION_SETS:
        raise FunrecError(f"unknown ablation set {config.ablation_set!r}; expected one of {list(ABLATION_SETS)}")
    if config.speed_baseline not in SPEED_BASELINES:
        raise FunrecError(f"unknown speed baseline {config.speed_baseline!r}; expected one of {list(SPEED_BASELINES)}")
    if config.ablation_set != "none" and config.method != "funrec":
        raise FunrecError(f"ablation set {config.ablation_set!r} ablates funrec; the method is {config.method!r}")
    if config.jobs < 1 or not config.timeout_s > 0 or min(config.memory_limit_mb, config.task_memory_mb) < 0:
        raise FunrecError(
            f"jobs must be >= 1, timeout_s > 0 and memory_limit_mb >= 0, got {config.jobs}, {config.timeout_s} and {config.memory_limit_mb}"
        )
    for ablation in config.ablations:
        if len(ablation) != 2 or not isinstance(ablation[0], str) or not all(isinstance(a, str) for a in ablation[1]):
            raise FunrecError(f"each ablation must be (label, [extra args]), got {ablation!r}")
    ablations = tuple((label, tuple(extra)) for label, extra in config.ablations) + ABLATION_SETS[config.ablation_set]
    labels = [config.method, *(label for label, _ in ablations)]
    if len(set(labels)) != len(labels):
        raise FunrecError(f"method and ablation labels must be unique, got {labels}")
    return ablations


def _subset(captures: list[Path], selection: str | None, what: str) -> list[Path]:
    """The captures named in the comma-separated ``selection`` (in suite order), or all when None."""
    if selection is None:
        return captures
    names = [n.strip() for n in selection.split(",") if n.strip()]
    unknown = sorted(set(names) - {c.name for c in captures})
    if unknown or not names:
        raise FunrecError(f"{what} {unknown or names} are not among the sequences run: {[c.name for c in captures]}")
    return [c for c in captures if c.name in names]


def run_bench(
    suite_dir: str | Path,
    out_dir: str | Path,
    config: BenchConfig = BenchConfig(),  # noqa: B008 (frozen, immutable default)
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
        FunrecError: unknown method or ablation set, duplicate labels, ablation sequences that
            are not run, or no sequences to run. A sequence that
            crashes or times out is a failure row, never an exception.
    """
    ablations = _ablations(config)
    suite_dir, out_dir = Path(suite_dir), Path(out_dir)
    refuse_output_over_input(out_dir, suite_dir)
    date = datetime.now(timezone.utc).isoformat(timespec="seconds")
    captures = _prepare_suite(suite_dir, config)
    ablation_captures = _subset(captures, config.ablation_sequences, "ablation_sequences")
    baseline_captures = _subset(captures, config.speed_baseline_sequences, "speed_baseline_sequences")
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = [(config.method, config.method, config.reconstruct_args, captures)]
    runs += [(label, "funrec", config.reconstruct_args + extra, ablation_captures) for label, extra in ablations]
    # The speed reference is for the reconstruction; the oracle and trivial twins need none.
    baseline = config.speed_baseline if config.method == "funrec" and config.speed_baseline != "none" else None
    if baseline is not None:
        runs.append((baseline, baseline, (), baseline_captures))
    tasks = [(label, method, extra, capture) for label, method, extra, run_captures in runs for capture in run_captures]
    jobs = [(label, method, extra, capture, out_dir, config) for label, method, extra, capture in tasks]
    finished = run_jobs(_run_sequence, jobs, config.jobs, config.ray, config.task_memory_mb, progress)
    results = {(result.method, result.name): result for result in finished}
    methods = []
    for label, method, extra, run_captures in runs:
        rows = tuple(results[(label, c.name)] for c in run_captures)
        command = tuple(_method_command(method, extra, "CAPTURE", "TWIN"))
        methods.append(MethodReport(label, ("python", *command[1:]), rows, summarize(rows)))
    baselines = tuple(methods[-1:]) if baseline is not None else ()
    methods = methods[: len(methods) - len(baselines)]
    report = BenchReport(
        suite_dir, out_dir, tuple(methods), _git_commit(), _machine(), date,
        command_line if command_line is not None else shlex.join(sys.argv), config, baselines,
    )
    write_text_staged(out_dir / "report.json", json.dumps(report_to_json(report), indent=2) + "\n")
    write_text_staged(out_dir / "report.md", report_to_markdown(report))
    return report


__all__ = [
    "ABLATION_SETS",
    "DEFAULT_FAMILY",
    "METHODS",
    "SPEED_BASELINES",
    "STANDARD_ABLATIONS",
    "BenchConfig",
    "BenchReport",
    "BenchSummary",
    "MethodReport",
    "SequenceResult",
    "format_report",
    "report_to_json",
    "report_to_markdown",
    "run_bench",
    "sequence_family",
    "summarize",
]
