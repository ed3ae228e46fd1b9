"""Benchmark results and their report: per-sequence rows, per-method summaries in the layout
of the paper's tables, and report.md / report.json."""

from __future__ import annotations

import dataclasses
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from funrec.bench.evaluate import TwinEvaluation, evaluation_to_json
from funrec.bench.fragment_metrics import FragmentScore

if TYPE_CHECKING:
    from funrec.bench.config import BenchConfig

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
    cpu_s: float | None = None
    """CPU time (user + system) of the run subprocess, seconds; None if unknown (timeout)."""
    fragments: FragmentScore | None = None
    """The twin's fragments.json scored against the true interaction intervals; None without one."""
    family: str = "textured"
    """Bench family of the sequence (``generator.spec.family`` in its gt.json)."""

    @property
    def frames_per_s(self) -> float | None:
        """Throughput of a completed run: frames / wall time."""
        if self.status != "ok" or not self.wall_s or not self.frame_count:
            return None
        return self.frame_count / self.wall_s

    @property
    def frames_per_cpu_s(self) -> float | None:
        """Throughput of a completed run per CPU second: frames / (user + system time)."""
        if self.status != "ok" or not self.cpu_s or not self.frame_count:
            return None
        return self.frame_count / self.cpu_s


@dataclass(frozen=True)
class BenchSummary:
    """Aggregate of one method over sequences, in the layout of the paper's tables.

    Part metrics average over non-failed parts; ``fail_pct`` is over all true parts; CD and
    ATE average over sequences that have them; throughput is total frames over total wall
    (or CPU) time of completed runs; peak memory is the maximum over runs.
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
    frames_per_cpu_s: float | None = None
    """Total frames over total CPU time (user + system) of completed runs; unlike frames/s it
    does not depend on how busy the machine was."""
    contact_within_3cm_pct: float | None = None
    """Non-failed parts whose contact point is within 3 cm of the true handle, percent of all
    non-failed parts (a part without a contact point counts as a miss)."""
    contact_median_cm: float | None = None
    """Median contact-point-to-handle distance over parts that have one, cm."""
    hand_iou: float | None = None
    """Mean IoU of detected hand masks against the true ones over sequences without given hand masks, percent."""
    fragment_pass_pct: float | None = None
    """Sequences whose dynamic fragments match the true interactions (none missed, none invented, every
    boundary within 0.5 s), percent of sequences with a fragments.json."""
    fragment_boundary_max_s: float | None = None
    """Largest boundary error of a matched fragment over all sequences, seconds."""
    interactions_missed: int = 0
    """True interactions no detected fragment overlaps, all sequences."""
    interactions_invented: int = 0
    """Detected dynamic fragments that overlap no true interaction, all sequences."""


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
    baselines: tuple[MethodReport, ...] = ()
    """Reference methods timed in the same run (the speed baseline), each on its own sequences."""

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
    timed = [r for r in done if r.cpu_s]
    cpu = sum(r.cpu_s or 0.0 for r in timed)
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
        frames_per_cpu_s=sum(r.frame_count for r in timed) / cpu if cpu > 0 else None,
        **_twin_level(results, scored),
    )


def _twin_level(results: tuple[SequenceResult, ...] | list[SequenceResult], scored: list) -> dict[str, Any]:
    """The functional-twin columns of :class:`BenchSummary`: affordances and fragments."""
    contacts = [p.contact_error_m for p in scored if p.contact_error_m is not None]
    frags = [r.fragments for r in results if r.fragments is not None]
    return {
        "contact_within_3cm_pct": 100.0 * sum(c <= 0.03 for c in contacts) / len(scored) if scored else None,
        "contact_median_cm": 100.0 * float(np.median(contacts)) if contacts else None,
        "hand_iou": _mean([r.evaluation.hand_iou for r in results]),
        "fragment_pass_pct": 100.0 * sum(f.passed for f in frags) / len(frags) if frags else None,
        "fragment_boundary_max_s": max((f.max_boundary_error_s for f in frags), default=None),
        "interactions_missed": sum(f.missed for f in frags),
        "interactions_invented": sum(f.invented for f in frags),
    }


TABLE_COLUMNS = (
    "Axis (deg) rev / pri", "Pos (m)", "State (deg / m) rev / pri", "Fail (%)",
    "ADD-S (%)", "ADD (%)", "CD (cm)", "mIoU (%)", "ATE (cm)", "frames/s", "frames/CPU-s", "peak MB",
)
"""Columns of every table: the paper's Tables 1-3 (revolute / prismatic pairs as "XX / YY"),
then camera ATE, throughput (per wall second and per CPU second) and peak memory."""
AGGREGATION_NOTE = (
    "Axis, Pos, State, ADD-S, ADD and mIoU average over non-failed parts; Fail (%) is over all true "
    "parts (a part fails when no predicted part matches it or its joint type is wrong, and every part "
    "of a sequence that crashed, timed out or wrote an unreadable twin fails). CD and ATE average over "
    "scored sequences; frames/s is total frames over total wall time of completed runs and frames/CPU-s "
    "over their total CPU time (user + system; independent of machine load); peak MB is the "
    "largest peak RSS of a run subprocess."
)


def family_rows(results: tuple[SequenceResult, ...]) -> list[tuple[str, BenchSummary]]:
    """One summary per family, in order of first appearance."""
    families = list(dict.fromkeys(r.family for r in results))
    return [(family, summarize([r for r in results if r.family == family])) for family in families]


def _badness(s: BenchSummary) -> tuple[float, float, float, float, float, float]:
    invented = s.invented_parts / s.sequences if s.sequences else 0.0
    return (
        s.failed_sequences / s.sequences if s.sequences else 0.0,
        s.fail_pct or 0.0,
        invented,
        -(100.0 if s.add_auc is None else s.add_auc),
        -(100.0 if s.miou is None else s.miou),
        s.camera_ate_cm or 0.0,
    )


WORST_FAMILY_RULE = (
    "The headline row is the worst family: the largest share of sequences whose run failed, then the "
    "highest Fail (%), then the most invented parts per sequence, then the lowest ADD, then the lowest "
    "mIoU, then the largest ATE."
)
"""How :func:`worst_family` ranks families (written into report.md)."""


def worst_family(results: tuple[SequenceResult, ...]) -> tuple[str, BenchSummary]:
    """The family that scores worst by :data:`WORST_FAMILY_RULE`."""
    return max(family_rows(results), key=lambda row: _badness(row[1]))


@dataclass(frozen=True)
class SpeedComparison:
    """The main method's throughput against a speed baseline on the sequences both completed."""

    baseline: str
    """Baseline label."""
    sequences: tuple[str, ...]
    """Sequences both completed."""
    frames_per_s: float | None
    """Main method: total frames over total wall time on those sequences."""
    baseline_frames_per_s: float | None
    """Baseline: the same."""

    @property
    def ratio(self) -> float | None:
        """Main method frames/s over baseline frames/s."""
        if not self.frames_per_s or not self.baseline_frames_per_s:
            return None
        return self.frames_per_s / self.baseline_frames_per_s


def speed_comparisons(report: BenchReport) -> list[SpeedComparison]:
    """Throughput of the main method against each speed baseline, on the common completed sequences."""
    out = []
    main = {r.name: r for r in report.main.sequences if r.frames_per_s is not None}
    for baseline in report.baselines:
        pairs = [(main[r.name], r) for r in baseline.sequences if r.frames_per_s is not None and r.name in main]
        names = tuple(m.name for m, _ in pairs)
        out.append(
            SpeedComparison(
                baseline.label,
                names,
                summarize([m for m, _ in pairs]).frames_per_s if pairs else None,
                summarize([b for _, b in pairs]).frames_per_s if pairs else None,
            )
        )
    return out


def _method_rows(report: BenchReport) -> list[tuple[str, list[str]]]:
    """Main table rows: the worst family (headline), every family, all sequences, then the baselines."""
    main = report.main
    label = main.label
    worst, worst_summary = worst_family(main.sequences)
    families = family_rows(main.sequences)
    rows = [(f"**{label}: worst family ({worst})**", _cells(worst_summary))]
    if len(families) > 1:
        rows += [(f"{label}: {family}", _cells(s)) for family, s in families]
    rows.append((f"{label}: all {main.summary.sequences} sequences", _cells(main.summary)))
    rows += [(f"{b.label} ({b.summary.sequences} sequences)", _cells(b.summary)) for b in report.baselines]
    return rows


def _speed_lines(report: BenchReport) -> list[str]:
    lines = []
    for c in speed_comparisons(report):
        ratio = "-" if c.ratio is None else f"{c.ratio:.2f}x"
        lines.append(
            f"Speed: {report.main.label} {_f(c.frames_per_s, 2)} frames/s vs {c.baseline} {_f(c.baseline_frames_per_s, 2)} "
            f"frames/s on the same {len(c.sequences)} sequences, run one after the other in this bench: ratio {ratio}"
        )
    return lines


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
        _f(s.frames_per_cpu_s, 2),
        _f(s.peak_rss_mb, 0),
    ]


def _table(first: str, rows: list[tuple[str, list[str]]]) -> list[str]:
    header = [first, *TABLE_COLUMNS]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + [":---:"] * len(TABLE_COLUMNS)) + "|"]
    lines += ["| " + " | ".join([name, *cells]) + " |" for name, cells in rows]
    return lines


TWIN_COLUMNS = (
    "Contact <= 3 cm (%)", "Contact median (cm)", "Hand IoU (%)", "Fragments pass (%)", "Max boundary error (s)",
    "Missed / invented interactions",
)
"""Columns of the functional-twin table (issue 4): affordance contact points against the true
handle, detected hand masks, and dynamic fragments against the true interaction intervals."""


def _twin_cells(s: BenchSummary) -> list[str]:
    return [
        _f(s.contact_within_3cm_pct, 1),
        _f(s.contact_median_cm, 2),
        _f(s.hand_iou, 1),
        _f(s.fragment_pass_pct, 1),
        _f(s.fragment_boundary_max_s, 2),
        f"{s.interactions_missed} / {s.interactions_invented}",
    ]


def _twin_table(first: str, rows: list[tuple[str, BenchSummary]]) -> list[str]:
    lines = ["| " + " | ".join([first, *TWIN_COLUMNS]) + " |", "|" + "|".join(["---"] + [":---:"] * len(TWIN_COLUMNS)) + "|"]
    return lines + ["| " + " | ".join([name, *_twin_cells(s)]) + " |" for name, s in rows]


def ablation_rows(report: BenchReport) -> tuple[str, list[tuple[str, BenchSummary]]]:
    """Heading and rows of the ablation table: the main method summarised over the sequences the
    ablations ran on, then each ablation. All ablations of a bench run share their sequences."""
    names = [r.name for r in report.ablations[0].sequences] if report.ablations else []
    main = [r for r in report.main.sequences if r.name in names]
    heading = "all sequences" if len(main) == len(report.main.sequences) else f"{len(names)} of {len(report.main.sequences)} sequences: {', '.join(names)}"
    rows = [(f"{report.main.label} (full)", summarize(main))] + [(m.label, m.summary) for m in report.ablations]
    return heading, rows


def format_report(report: BenchReport) -> str:
    """The main table (and the ablation table, if any) as Markdown for the terminal."""
    lines = _table("Method", _method_rows(report))
    lines += _speed_lines(report)
    s = report.main.summary
    lines.append(
        f"sequences: {s.sequences} ({s.failed_sequences} failed); true parts: {s.parts} "
        f"({s.failed_parts} failed); invented parts: {s.invented_parts}"
    )
    for row in report.main.sequences:
        if row.status != "ok":
            lines.append(f"  {row.name}: {row.status}: {row.reason}")
    lines += ["", "Functional twin:", *_twin_table("Method", [(report.main.label, s)])]
    if report.ablations:
        heading, rows = ablation_rows(report)
        lines += ["", f"Ablations ({heading}):", *_table("Ablation", [(label, _cells(s)) for label, s in rows])]
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
        WORST_FAMILY_RULE,
        "",
        "## Results",
        "",
        *_table("Method", _method_rows(report)),
        "",
        *_speed_lines(report),
        "",
        "## Functional twin (affordances, hand masks, fragments)",
        "",
        *_twin_table("Method", [(report.main.label, report.main.summary)]),
    ]
    if report.ablations:
        heading, rows = ablation_rows(report)
        lines += ["", f"## Ablations ({heading})", "", *_table("Variant", [(label, _cells(s)) for label, s in rows])]
    for method in (*report.methods, *report.baselines):
        lines += ["", f"## Per sequence: {method.label}", "", f"Command: `{shlex.join(method.command)}`", ""]
        lines += _table("Sequence", [(f"{r.name} ({r.family})", _cells(summarize([r]))) for r in method.sequences])
        lines += ["", *_twin_table("Sequence", [(r.name, summarize([r])) for r in method.sequences])]
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
    for method in (*report.methods, *report.baselines):
        rows = []
        for r in method.sequences:
            row = {f.name: getattr(r, f.name) for f in dataclasses.fields(r) if f.name not in ("evaluation", "fragments")}
            row["fragments"] = None if r.fragments is None else {
                **dataclasses.asdict(r.fragments), "max_boundary_error_s": r.fragments.max_boundary_error_s,
                "passed": r.fragments.passed}
            row["frames_per_s"] = r.frames_per_s
            row["frames_per_cpu_s"] = r.frames_per_cpu_s
            row["evaluation"] = evaluation_to_json(r.evaluation)
            rows.append(_jsonable(row))
        methods.append({
            "label": method.label, "command": list(method.command), "summary": dataclasses.asdict(method.summary),
            "baseline": method in report.baselines,
            "families": {family: dataclasses.asdict(s) for family, s in family_rows(method.sequences)},
            "sequences": rows,
        })
    worst, _ = worst_family(report.main.sequences)
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
        "worst_family": worst,
        "worst_family_rule": WORST_FAMILY_RULE,
        "speed": [
            {"baseline": c.baseline, "sequences": list(c.sequences), "frames_per_s": c.frames_per_s,
             "baseline_frames_per_s": c.baseline_frames_per_s, "ratio": c.ratio}
            for c in speed_comparisons(report)
        ],
        "methods": methods,
    }


__all__ = [
    "AGGREGATION_NOTE",
    "WORST_FAMILY_RULE",
    "SpeedComparison",
    "TABLE_COLUMNS",
    "TWIN_COLUMNS",
    "BenchReport",
    "BenchSummary",
    "MethodReport",
    "SequenceResult",
    "ablation_rows",
    "family_rows",
    "speed_comparisons",
    "worst_family",
    "format_report",
    "report_to_json",
    "report_to_markdown",
    "summarize",
]
