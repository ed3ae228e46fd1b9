"""Tests of funrec.surfaces.hands: capture masks pass through, detection on the tiny synthetic capture.

The stage inputs come from the capture's ground truth (``ground_truth_inputs`` in
tests/helpers/stage_inputs.py): camera poses mapped to a chosen twin world frame through frame 0,
joints, true part masks and true part points.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from funrec.formats.capture import load_capture, read_mask
from funrec.formats.twin import ArticulatedPart, make_part
from funrec.surfaces.hands import HandConfig, detect_hands, part_poses
from tests.helpers.stage_inputs import ground_truth_inputs

MIN_MEAN_IOU_TINY = 0.7
"""Mean per-frame IoU detection must reach on the tiny 80x60 capture without its masks (frames
with a true hand). Measured 0.82: the forearm is 3-6 px wide there, so one pixel of boundary
error costs 20-30 % IoU; the 640x480 bench reaches ~0.95."""


def _ious(hands, gt_folder: Path) -> tuple[list[float], int]:
    """Per-frame IoU over frames with a true hand, and the number of frames with a false hand."""
    ious, false_frames = [], 0
    for frame, mask in hands:
        truth = read_mask(gt_folder / f"{frame:06d}.png")
        if truth.any():
            ious.append((mask & truth).sum() / (mask | truth).sum())
        elif mask.sum() > 0.001 * mask.size:
            false_frames += 1
    return ious, false_frames


def test_capture_masks_are_returned_as_they_are(tiny_capture: Path) -> None:
    capture = load_capture(tiny_capture)
    trajectory, *_ = ground_truth_inputs(tiny_capture, np.eye(4))
    hands = detect_hands(capture, trajectory)
    assert hands.source == "capture" and len(hands) == len(capture)
    for frame, mask in hands:
        np.testing.assert_array_equal(mask, capture.mask("hand", frame))


def test_detection_without_capture_masks_finds_the_hand(tiny_capture: Path) -> None:
    capture = load_capture(tiny_capture)
    trajectory, parts, masks, _ = ground_truth_inputs(tiny_capture, np.eye(4))
    hands = detect_hands(capture, trajectory, parts, masks, HandConfig(use_capture_masks=False))
    assert hands.source == "detected" and hands.colour_model
    ious, false_frames = _ious(hands, tiny_capture / "gt" / "masks" / "hand")
    assert np.mean(ious) >= MIN_MEAN_IOU_TINY, np.round(ious, 2)
    assert false_frames <= 1


def test_detection_does_not_depend_on_the_world_frame(tiny_capture: Path) -> None:
    capture = load_capture(tiny_capture)
    T = np.array([[0.0, -1.0, 0.0, 0.3], [1.0, 0.0, 0.0, -2.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]])
    config = HandConfig(use_capture_masks=False)
    a = detect_hands(capture, *ground_truth_inputs(tiny_capture, np.eye(4))[:3], config)
    b = detect_hands(capture, *ground_truth_inputs(tiny_capture, T)[:3], config)
    changed = sum(int((ma ^ mb).sum()) for (_, ma), (_, mb) in zip(a, b))
    assert changed <= 0.001 * len(capture) * capture.intrinsics.width * capture.intrinsics.height  # float round-off only


def test_part_poses_hold_the_end_states_outside_the_tracked_frames() -> None:
    part = make_part("door", "prismatic", [1.0, 0.0, 0.0], None, [2, 3, 5], [0.0, 0.1, 0.3])
    T = part_poses(part, 8)
    np.testing.assert_allclose(T[:, 0, 3], [0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.3, 0.3])
    np.testing.assert_allclose(T[:, :3, :3], np.broadcast_to(np.eye(3), (8, 3, 3)))


def test_config_and_input_validation(tiny_capture: Path) -> None:
    with pytest.raises(ValueError, match="non-zero reference offsets"):
        HandConfig(reference_offsets_s=(0.0,))
    with pytest.raises(ValueError, match="odd"):
        HandConfig(closing_px=4)
    capture = load_capture(tiny_capture)
    trajectory, parts, masks, _ = ground_truth_inputs(tiny_capture, np.eye(4))
    short = dataclasses.replace(trajectory, T_world_camera=trajectory.T_world_camera[:3], tracked=trajectory.tracked[:3])
    with pytest.raises(ValueError, match="3 poses for 24 frames"):
        detect_hands(capture, short)
    with pytest.raises(ValueError, match="2 part mask sets for 1 parts"):
        detect_hands(capture, trajectory, parts, [masks[0], masks[0]], HandConfig(use_capture_masks=False))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rev_cabinet_right_00", "pri_drawer_01", "rev_wall_cabinet_00"])
def test_bench_detection_iou(name: str) -> None:
    root = Path(__file__).resolve().parents[1] / "bench_suite" / name
    if not (root / "gt").is_dir():
        pytest.skip(f"{root} not generated")
    capture = load_capture(root, check_headers=False)
    trajectory, parts, masks, _ = ground_truth_inputs(root, np.eye(4))
    hands = detect_hands(capture, trajectory, parts, masks, HandConfig(use_capture_masks=False))
    ious, false_frames = _ious(hands, root / "gt" / "masks" / "hand")
    assert np.mean(ious) >= 0.85 and false_frames == 0


def test_a_part_tracked_too_short_does_not_become_hand(tiny_capture: Path) -> None:
    """The reconstruction may stop tracking a door while it still opens (its state then holds,
    wrongly). The free space the door leaves is on one side in time only; with two-sided seeds
    less of the door enters the hand masks."""
    capture = load_capture(tiny_capture)
    trajectory, (part,), masks, _ = ground_truth_inputs(tiny_capture, np.eye(4))
    moving = np.flatnonzero(np.abs(np.diff(part.states)) > 1e-4)
    cut = int(moving[len(moving) // 2])  # tracked until halfway through the opening
    short = make_part(part.name, part.joint_type, part.axis_world, part.pivot_world, part.frames[:cut], part.states[:cut])
    gt_folder = tiny_capture / "gt" / "masks" / "hand"

    def false_pixels(p: ArticulatedPart, two_sided: bool) -> int:
        hands = detect_hands(capture, trajectory, [p], masks, HandConfig(use_capture_masks=False, two_sided=two_sided))
        return sum(int((mask & ~read_mask(gt_folder / f"{frame:06d}.png")).sum()) for frame, mask in hands)

    baseline = false_pixels(part, True)  # outline errors with the true motion (measured 228 px)
    one_sided, two_sided = false_pixels(short, False) - baseline, false_pixels(short, True) - baseline
    # Measured 776 and 439 excess pixels: in a 24-frame video most frames lack references on one
    # side (untested sides do not count), so only part of the door is removed here; on the
    # 640x480 bench a reconstructed wall cabinet went from IoU 17 % to 43 %.
    assert two_sided < 0.75 * one_sided, (one_sided, two_sided)
