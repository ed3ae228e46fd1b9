"""Scores of detected dynamic fragments against the ground truth's interaction intervals: boundary
errors in seconds, missed and invented interactions."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from funrec.formats.fragments import Fragments, read_fragments
from funrec.formats.twin import read_json_object

BOUNDARY_TOLERANCE_S = 0.5
"""A matched fragment whose first and last frames are both within this of the true interval's
passes (issue 4: boundaries within 0.5 s of the true interaction intervals)."""


@dataclass(frozen=True)
class FragmentScore:
    """Detected dynamic fragments compared with the true interaction intervals."""

    true_intervals: tuple[tuple[int, int], ...]
    """Inclusive (first, last) frames of every true interaction, all parts, time order."""
    detected: tuple[tuple[int, int], ...]
    """Inclusive (first, last) frames of every detected dynamic fragment."""
    matches: tuple[tuple[int, int], ...]
    """(true index, detected index) of matched pairs (temporal overlap, one-to-one)."""
    start_error_s: tuple[float, ...]
    """Per match, |detected first - true first| / fps, seconds."""
    end_error_s: tuple[float, ...]
    """Per match, |detected last - true last| / fps, seconds."""
    missed: int
    """True interactions no detected fragment overlaps."""
    invented: int
    """Detected dynamic fragments that overlap no true interaction."""

    @property
    def max_boundary_error_s(self) -> float:
        """Largest start or end error over the matches, seconds (0 without matches)."""
        return float(max(self.start_error_s + self.end_error_s, default=0.0))

    @property
    def passed(self) -> bool:
        """No miss, no invention, every boundary within :data:`BOUNDARY_TOLERANCE_S`."""
        return self.missed == 0 and self.invented == 0 and self.max_boundary_error_s <= BOUNDARY_TOLERANCE_S


def _overlap(a: tuple[int, int], b: tuple[int, int]) -> int:
    return max(0, min(a[1], b[1]) - max(a[0], b[0]) + 1)


def score_fragments(detected: list[tuple[int, int]], true_intervals: list[tuple[int, int]], fps: float) -> FragmentScore:
    """Match detected dynamic spans to true intervals one-to-one by largest temporal overlap
    (Hungarian assignment on the overlap in frames; pairs that do not overlap never match).

    Args:
        detected: inclusive (first, last) frames of the detected dynamic fragments.
        true_intervals: inclusive (first, last) frames of the true interactions.
        fps: frame rate, frames per second.
    """
    detected = sorted((int(a), int(b)) for a, b in detected)
    true_intervals = sorted((int(a), int(b)) for a, b in true_intervals)
    overlap = np.array([[_overlap(t, d) for d in detected] for t in true_intervals], dtype=np.float64)
    overlap = overlap.reshape(len(true_intervals), len(detected))
    rows, cols = linear_sum_assignment(-overlap) if overlap.size else (np.zeros(0, int), np.zeros(0, int))
    matches = [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if overlap[r, c] > 0]
    start = tuple(abs(detected[c][0] - true_intervals[r][0]) / fps for r, c in matches)
    end = tuple(abs(detected[c][1] - true_intervals[r][1]) / fps for r, c in matches)
    # Unmatched fragments overlapping a true interval (one interaction split in two) are not
    # inventions but count against nothing either; those overlapping none are invented.
    invented = sum(1 for c, d in enumerate(detected) if c not in {m[1] for m in matches}
                   and not any(_overlap(t, d) for t in true_intervals))
    missed = len(true_intervals) - len(matches)
    return FragmentScore(tuple(true_intervals), tuple(detected), tuple(matches), start, end, missed, invented)


def true_intervals(gt_dir: str | Path) -> list[tuple[int, int]]:
    """Every part's ``intervals`` of gt.json (FORMATS.md section 4), inclusive frames, time order."""
    gt_dir = Path(gt_dir)
    path = gt_dir / "gt.json" if (gt_dir / "gt.json").exists() else gt_dir / "gt" / "gt.json"
    data = read_json_object(path)
    return sorted((int(a), int(b)) for part in data.get("parts", []) for a, b in part.get("intervals", []))


def score_twin_fragments(twin_dir: str | Path, gt_dir: str | Path) -> FragmentScore:
    """Score a twin's fragments.json against the ground truth's interaction intervals."""
    fragments: Fragments = read_fragments(twin_dir)
    # a dynamic fragment that no part explains is reported (with its reason), not scored as a found interaction
    detected = [(f.first, f.last) for f in fragments.dynamic if f.part is not None]
    return score_fragments(detected, true_intervals(gt_dir), fragments.fps)


def format_fragment_score(score: FragmentScore) -> str:
    """One line: counts, matched boundary errors and pass/fail."""
    errors = ", ".join(f"{s:.2f}/{e:.2f}" for s, e in zip(score.start_error_s, score.end_error_s, strict=True))
    return (f"{len(score.true_intervals)} true, {len(score.detected)} detected, {len(score.matches)} matched, "
            f"{score.missed} missed, {score.invented} invented; start/end errors (s): {errors or '-'}; "
            f"max {score.max_boundary_error_s:.2f} s -> {'pass' if score.passed else 'FAIL'}")


__all__ = ["BOUNDARY_TOLERANCE_S", "FragmentScore", "format_fragment_score", "score_fragments", "score_twin_fragments",
           "true_intervals"]
