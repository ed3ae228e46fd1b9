"""Score a twin's affordances.json against synthetic ground truth: distance from each contact
point to the true handle centre, and the overlap of the holds with the true hold intervals.

Parts are paired, and the contact error measured, by :func:`funrec.bench.evaluate.evaluate_twin`
(``PartEvaluation.contact_error_m``): both sides in their own camera-0 frame (FORMATS.md
section 5), the contact point and the true handle each moved to its part's state at the first
common tracked frame, so that the two canonical states (twin: first tracked; truth: closed) do
not matter. This module adds the hold intervals and the tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from funrec.bench.evaluate import TwinEvaluation, evaluate_twin
from funrec.errors import FunrecError
from funrec.formats.affordances import read_affordances
from funrec.formats.ground_truth import read_ground_truth

CONTACT_TOLERANCE_M = 0.03
"""A contact point within this of the true handle centre counts as correct (the target is 90 %
of parts): about the half-width of a hand's grip around a handle."""


@dataclass(frozen=True)
class PartAffordanceScore:
    """Affordance scores of one true part; metric fields are None when it failed."""

    true_name: str
    """Name of the true part in gt.json."""
    predicted_name: str | None = None
    """Name of the matched twin part, or None."""
    failure: str | None = None
    """Why the part has no score (unmatched, wrong joint type, no affordance); None if scored."""
    contact_error_m: float | None = None
    """Distance from the contact point to the true handle centre, metres (camera-0 frames, twin
    canonical state)."""
    interval_iou: float | None = None
    """Frame IoU of the twin's holds and the true hold intervals, in [0, 1]."""

    @property
    def within_tolerance(self) -> bool:
        return self.contact_error_m is not None and self.contact_error_m <= CONTACT_TOLERANCE_M


@dataclass(frozen=True)
class AffordanceEvaluation:
    """Affordance scores of one twin."""

    twin_dir: Path
    """The twin folder scored."""
    gt_dir: Path
    """The ground truth scored against."""
    parts: tuple[PartAffordanceScore, ...]
    """One entry per true part, in gt.json order."""
    failure: str | None = None
    """Why the twin could not be scored at all; None if scored."""

    @property
    def fraction_within_tolerance(self) -> float | None:
        """Fraction of true parts (failed ones included) within ``CONTACT_TOLERANCE_M``; None
        without true parts."""
        return float(np.mean([p.within_tolerance for p in self.parts])) if self.parts else None


def evaluate_affordances(
    twin_dir: str | Path, gt_dir: str | Path, evaluation: TwinEvaluation | None = None
) -> AffordanceEvaluation:
    """Score affordances.json of a twin against the ground truth's handles and hold intervals.

    Never raises on a bad twin: an unreadable file makes every true part fail with the reason.

    Args:
        twin_dir: the twin folder.
        gt_dir: the gt/ folder, or the capture folder holding it.
        evaluation: the twin's :func:`funrec.bench.evaluate.evaluate_twin` result, whose part pairing
            is reused (computed here when None; pass it to avoid scoring the twin twice).
    """
    twin_dir, gt_dir = Path(twin_dir), Path(gt_dir)
    try:
        gt = read_ground_truth(gt_dir)
    except FunrecError as exc:
        return AffordanceEvaluation(twin_dir, gt_dir, (), failure=f"ground truth unreadable: {exc}")
    if evaluation is None:
        evaluation = evaluate_twin(twin_dir, gt.root)
    if evaluation.failure is not None:
        reason = evaluation.failure
        return AffordanceEvaluation(twin_dir, gt.root, tuple(PartAffordanceScore(p.part.name, failure=reason) for p in gt.parts), reason)
    try:
        affordances = read_affordances(twin_dir)
    except FunrecError as exc:
        reason = f"twin unreadable: {exc}"
        return AffordanceEvaluation(twin_dir, gt.root, tuple(PartAffordanceScore(p.part.name, failure=reason) for p in gt.parts), reason)
    scores = []
    for gt_part, part_eval in zip(gt.parts, evaluation.parts):
        true = gt_part.part
        name = part_eval.predicted_name
        if name is None or part_eval.failure is not None:
            scores.append(PartAffordanceScore(true.name, name, part_eval.failure or "no part found"))
            continue
        affordance = affordances.part(name)
        if affordance is None or part_eval.contact_error_m is None:
            reason = dict(affordances.missing).get(name, "not in affordances.json")
            scores.append(PartAffordanceScore(true.name, name, f"no affordance ({reason})"))
            continue
        held = np.unique(np.concatenate([i.frames for i in affordance.interactions]))
        truth = np.unique(np.concatenate([np.arange(a, b + 1) for a, b in gt_part.intervals])) if gt_part.intervals else np.zeros(0, int)
        union = len(np.union1d(held, truth))
        iou = len(np.intersect1d(held, truth)) / union if union else None
        scores.append(PartAffordanceScore(true.name, name, None, part_eval.contact_error_m, iou))
    return AffordanceEvaluation(twin_dir, gt.root, tuple(scores))


def format_affordance_evaluation(evaluation: AffordanceEvaluation) -> str:
    """A readable multi-line report of one affordance evaluation."""
    lines = [f"affordances of {evaluation.twin_dir}"]
    if evaluation.failure is not None:
        lines.append(f"  FAILED: {evaluation.failure}")
    for p in evaluation.parts:
        head = f"  {p.true_name}" + (f" <- {p.predicted_name}" if p.predicted_name else "")
        if p.failure is not None:
            lines.append(f"{head}: FAILED - {p.failure}")
            continue
        iou = "-" if p.interval_iou is None else f"{p.interval_iou:.2f}"
        lines.append(f"{head}: contact {100 * p.contact_error_m:.1f} cm from the handle "
                     f"({'ok' if p.within_tolerance else 'over'} {100 * CONTACT_TOLERANCE_M:.0f} cm), hold IoU {iou}")
    return "\n".join(lines)


__all__ = [
    "CONTACT_TOLERANCE_M",
    "AffordanceEvaluation",
    "PartAffordanceScore",
    "evaluate_affordances",
    "format_affordance_evaluation",
]
