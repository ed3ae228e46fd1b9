"""The robot bench's summary: parts refused before any optimisation apart from those the robot accepts, per
family, with the plan-time median and 95th percentile."""

from __future__ import annotations

import numpy as np

from funrec_robot.bench import DEFAULT_FAMILY, BenchRow, _all_refused, _family, summarize


def _row(case: str, family: str, passed: bool, refused: bool = False, cpu: float = 1.0) -> BenchRow:
    planned = passed or not refused
    return BenchRow(case, "part_0", "revolute", planned, passed, "" if passed else "why", cpu, cpu, 10.0 if planned else np.nan,
                    0, 0.0, 1, 5.0, refused, family)


def test_summary_counts_refused_parts_apart_per_family() -> None:
    rows = [
        _row("a", "plain", True, cpu=0.5), _row("b", "plain", False, cpu=4.0), _row("c", "plain", False, refused=True, cpu=0.1),
        _row("d", "geometry", True, cpu=1.0),
    ]
    summary = summarize(rows)
    assert (summary["parts"], summary["refused"], summary["accepted"], summary["passed"]) == (4, 1, 3, 2)
    assert summary["success_rate_accepted"] == 2 / 3
    plain = summary["families"]["plain"]
    assert (plain["parts"], plain["refused"], plain["accepted"], plain["passed"]) == (3, 1, 2, 1)
    assert plain["median_plan_cpu_time_s"] == 0.5 and plain["p95_plan_cpu_time_s"] > 3.0
    assert summary["families"]["geometry"]["passed"] == 1


def test_family_is_read_from_the_generator_spec() -> None:
    assert _family({"generator": {"spec": {"family": "dark"}}}) == "dark"
    assert _family({"generator": {"spec": {}}}) == DEFAULT_FAMILY
    assert _family({}) == DEFAULT_FAMILY


def test_a_true_part_is_refused_on_twins_only_when_every_twin_part_was_refused() -> None:
    assert _all_refused([("twin part_0: handle at 1.75 m; spot_arm reaches 0.00-1.60 m", True)])
    assert not _all_refused([("twin part_0: refused", True), ("twin part_1: base placement: no pose", False)])
    assert not _all_refused([])  # no twin part at all: the twin's failure, not the robot's refusal


def test_an_unexpected_exception_fails_the_parts_of_its_case_only(tmp_path, monkeypatch, caplog) -> None:  # noqa: ANN001
    """A bug in one part (an exception that is not a ``FunrecError``) used to end the whole bench run: it is now a
    failure row naming the part and the error, for each part of its case not yet reported, and the next case runs."""
    from types import SimpleNamespace

    from funrec_robot import bench

    for case in ("a_case", "b_case"):
        (tmp_path / case / "gt").mkdir(parents=True)
        (tmp_path / case / "gt" / "gt.json").write_text("{}")

    def part(name: str) -> SimpleNamespace:
        return SimpleNamespace(part=SimpleNamespace(name=name, joint_type="revolute"))

    monkeypatch.setattr(bench, "read_ground_truth", lambda root: SimpleNamespace(extra={}, parts=[part("part_0"), part("part_1")]))
    monkeypatch.setattr(bench, "load_robot", lambda path: None)

    def rows(case, gt, *args):  # noqa: ANN001, ANN002, ANN202
        yield _row(case, DEFAULT_FAMILY, True)
        if case == "a_case":
            raise ZeroDivisionError("division by zero")
        yield BenchRow(case, "part_1", "revolute", True, True, "", 1.0, 1.0, 10.0, 0, 0.0, 1, 5.0)

    monkeypatch.setattr(bench, "_ground_truth_rows", rows)
    out = bench.bench_suite(tmp_path, "robot.yaml")
    assert [(r.case, r.part, r.passed) for r in out] == [
        ("a_case", "part_0", True), ("a_case", "part_1", False), ("b_case", "part_0", True), ("b_case", "part_1", True)]
    assert out[1].failure == "unexpected error: ZeroDivisionError: division by zero" and not out[1].planned
    assert "a_case: unexpected error: ZeroDivisionError" in caplog.text
