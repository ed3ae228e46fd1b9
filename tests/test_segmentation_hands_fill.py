"""Part masks where a hand mask covers the part, and the watershed fill of undecided keyframe
pixels (funrec.surfaces.segmentation._propagate and _keyframe_mask), on synthetic depth."""

from __future__ import annotations

import numpy as np

from funrec.surfaces.segmentation import SegmentationConfig, _keyframe_mask, _propagate, _View

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
H, W = 240, 320


def _panel_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 0.4 x 0.4 m panel 1.5 m away in front of a wall at 3 m: depth (H, W), panel (H, W) bool,
    the panel's model (3, M) voxels in the camera frame, and pixel coordinates x (H, W) on the panel plane."""
    config = SegmentationConfig()
    depth = np.full((H, W), 3.0, dtype=np.float32)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    x, y = (u - K[0, 2]) / K[0, 0] * 1.5, (v - K[1, 2]) / K[1, 1] * 1.5
    panel = (np.abs(x) < 0.2) & (np.abs(y) < 0.2)
    depth[panel] = 1.5
    a, b = np.meshgrid(np.arange(-0.2, 0.2, config.voxel_m), np.arange(-0.2, 0.2, config.voxel_m))
    p_part = np.stack([a.ravel(), b.ravel(), np.full(a.size, 1.5)]).astype(np.float32)
    return depth, panel, p_part, np.stack([x, y])


def test_a_hand_mask_over_the_part_does_not_erase_depth_that_lies_on_the_posed_part() -> None:
    """A detected hand mask (captures without hand masks: foreground that blocks free space) covers
    the left half of the panel, whose depth is the panel's, and a forearm 0.7 m in front of its right
    half. The covered half is part (IoU with the panel minus the forearm > 0.95, as without hands);
    the forearm is not, by depth. Before: the whole hand mask was cut out (IoU ~0.5)."""
    depth, panel, p_part, (x, y) = _panel_scene()
    forearm = (np.abs(x - 0.1) < 0.05) & (np.abs(y) < 0.05)
    depth[forearm] = 0.8
    hand = (panel & (x < 0.0)) | forearm
    mask = _propagate(_View(depth, hand), p_part, np.eye(4), K, SegmentationConfig())
    truth = panel & ~forearm
    assert (mask & truth).sum() / (mask | truth).sum() > 0.95
    assert not (mask & forearm).any()


def test_a_hand_mask_still_keeps_pixels_without_depth_out_of_the_mask() -> None:
    """Pixels without depth inside the silhouette are filled only off the hand: nothing tells there
    whether the hand or the part was seen. A dropout 2 px wide (the closing fills gaps of one voxel
    spacing on either side) across the panel, its upper half under the hand mask: the lower half joins
    the mask, the upper half does not."""
    depth, panel, p_part, _ = _panel_scene()
    hole = np.zeros((H, W), dtype=bool)
    hole[100:140, 159:161] = True
    depth[hole] = 0.0
    hand = hole.copy()
    hand[120:] = False
    mask = _propagate(_View(depth, hand), p_part, np.eye(4), K, SegmentationConfig())
    assert mask[hole & ~hand].all()
    assert not mask[hand].any()


def test_undecided_pixels_join_the_part_only_within_fine_regions_that_hold_part_evidence() -> None:
    """A keyframe (at the segmentation size) with three fine regions: the part (columns 0-19, with part
    evidence), an undecided surface next to it (columns 20-69: a static window frame along which the
    sash slides, or a cabinet's inside, gives no depth evidence either way) and a static surface
    (columns 70-89, static evidence). The coarse over-segmentation joins the part and the undecided
    surface; its evidence (3 % of its area) is too sparse for it to decide itself (5 %), and no edge
    separates the two (flat gradient), so the watershed floods the undecided surface from the part
    seed: it must stay out of the part (before: flooded, within the coarse region)."""
    h, w = 60, 90
    fine = np.zeros((h, w), dtype=np.int32)
    fine[:, 20:70], fine[:, 70:] = 1, 2
    coarse = np.where(fine == 2, 1, 0).astype(np.int32)
    view = _View(np.full((h, w), 1.5, dtype=np.float32), np.zeros((h, w), dtype=bool),
                 segments=np.stack([fine, coarse]), gradient=np.zeros((h, w), dtype=np.float32))
    part_px = np.zeros((h, w), dtype=bool)
    part_px[::3, 0:20:3] = True  # 12 % of the part's fine region, 3 % of the coarse one
    static_px = np.zeros((h, w), dtype=bool)
    static_px[::3, 70::3] = True
    none = np.zeros((h, w), dtype=np.int64)
    part, known = _keyframe_mask(view, view.depth_m, part_px, static_px, none, none, SegmentationConfig())
    assert part[:, :20].all()
    assert not part[:, 20:].any()
    assert not known[:, 20:70].any()
