"""Scoring detected dynamic fragments against true interaction intervals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from funrec.bench.fragment_metrics import score_fragments, score_twin_fragments, true_intervals
from funrec.formats.fragments import Fragments, write_fragments
from funrec.parts.fragments import fragments_from_spans

FPS = 15.0


def test_boundary_errors_misses_and_inventions() -> None:
    truth = [(72, 118), (162, 191), (300, 320)]
    detected = [(75, 114), (160, 200), (240, 250)]
    score = score_fragments(detected, truth, FPS)
    assert score.matches == ((0, 0), (1, 1))
    np.testing.assert_allclose(score.start_error_s, [3 / FPS, 2 / FPS])  # exact frame counts / fps
    np.testing.assert_allclose(score.end_error_s, [4 / FPS, 9 / FPS])
    assert score.missed == 1 and score.invented == 1
    assert score.max_boundary_error_s == pytest.approx(9 / FPS)
    assert not score.passed


def test_perfect_and_empty_cases_pass() -> None:
    assert score_fragments([(10, 20)], [(12, 24)], FPS).passed  # 2 and 4 frames: < 7.5
    assert score_fragments([], [], FPS).passed
    assert not score_fragments([(10, 20)], [], FPS).passed
    assert not score_fragments([], [(10, 20)], FPS).passed


def test_one_interaction_split_in_two_is_not_an_invention() -> None:
    score = score_fragments([(10, 30), (34, 50)], [(10, 50)], FPS)
    assert score.invented == 0 and score.missed == 0 and len(score.matches) == 1
    assert not score.passed  # the matched piece ends 20 frames early


def test_twin_fragments_against_gt_json(tmp_path: Path) -> None:
    gt = tmp_path / "gt"
    gt.mkdir()
    parts = [{"name": "part_0", "intervals": [[72, 118], [162, 191]]}, {"name": "part_1", "intervals": [[20, 40]]}]
    (gt / "gt.json").write_text(json.dumps({"format": "funrec-gt/1", "parts": parts}))
    assert true_intervals(tmp_path) == [(20, 40), (72, 118), (162, 191)]
    twin = tmp_path / "twin"
    twin.mkdir()
    spans = [(21, 40), (72, 117), (163, 190)]
    write_fragments(twin, Fragments(fragments_from_spans(spans, 230, ["part_1", "part_0", "part_0"]), 230, FPS, np.zeros(230)))
    score = score_twin_fragments(twin, gt)
    assert score.passed and score.max_boundary_error_s == pytest.approx(1 / FPS)
