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
