"""Tests of funrec.surfaces.segmentation and funrec.surfaces.motion_evidence: mask storage, input validation, track
and pixel motion evidence on known geometry, and mask IoU against synthetic ground truth when the
stage is fed true inputs and when it is fed the estimates of stages 1, 2, 3 and 5."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from funrec.errors import ReconstructionError
from funrec.formats.capture import Capture
from funrec.formats.ground_truth import GroundTruth
from funrec.geometry.camera import backproject, project
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.parts.point_tracks import PointTracks
from funrec.surfaces.segmentation import PartMasks, SegmentationConfig, decode_mask, encode_mask, segment_parts
from tests.helpers.stage_inputs import EstimatedRun, synth_sequence, true_inputs, true_mask

TRACK_VISIBLE_TOL_M = 0.03
"""A simulated track is visible where the observed (noisy) depth is within 3 cm of it: ~6 sigma of
the synthetic sensor's noise at 2 m, so occlusion by a surface > 3 cm in front hides it."""
TARGET_MIOU = 0.85
"""Project target (FORMATS section 5 mIoU >= 85 on the bench)."""


def simulate_tracks(capture: Capture, gt: GroundTruth, T_world_part: np.ndarray, grid_px: int, seed_every: int
                    ) -> tuple[PointTracks, np.ndarray]:
    """Tracks seeded on a pixel grid every ``seed_every`` frames (as TAPIP3D re-seeds), labelled
    moving by the true part mask, moved by the true part pose, visible by a depth test."""
    K, H, W = capture.intrinsics.K, capture.intrinsics.height, capture.intrinsics.width
    F = len(capture)
    v, u = np.mgrid[grid_px // 2:H:grid_px, grid_px // 2:W:grid_px]
    seeds, labels = [], []
    for frame in range(0, F, seed_every):
        depth_m = capture.depth_m(frame)
        ok = depth_m[v, u].ravel() > 0
        p_camera = backproject(depth_m, K).reshape(H, W, 3)[v.ravel()[ok], u.ravel()[ok]]
        p_world = transform_points(gt.T_world_camera[frame], p_camera)
        moving = true_mask(gt, capture, frame)[v.ravel()[ok], u.ravel()[ok]]
        p_world[moving] = transform_points(invert_transform(T_world_part[frame]), p_world[moving])  # canonical
        seeds.append(p_world)
        labels.append(moving)
    p_seed, moving = np.concatenate(seeds), np.concatenate(labels)
    N = len(p_seed)
    p_world_all, uv_all = np.full((F, N, 3), np.nan), np.full((F, N, 2), np.nan)
    visible = np.zeros((F, N), dtype=bool)
    for frame in range(F):
        p_world = p_seed.copy()
        p_world[moving] = transform_points(T_world_part[frame], p_seed[moving])
        uv, z = project(transform_points(invert_transform(gt.T_world_camera[frame]), p_world), K)
        inside = np.isfinite(uv).all(axis=1) & (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5)
        ui = np.where(inside, np.round(np.nan_to_num(uv[:, 0])), 0).astype(int)
        vi = np.where(inside, np.round(np.nan_to_num(uv[:, 1])), 0).astype(int)
        d = capture.depth_m(frame)[vi, ui]
        seen = inside & (d > 0) & (np.abs(d - z) < TRACK_VISIBLE_TOL_M)
        visible[frame], p_world_all[frame, seen], uv_all[frame, seen] = seen, p_world[seen], uv[seen]
    return PointTracks(p_world_all, uv_all, visible), moving


def mean_iou(masks: PartMasks, gt: GroundTruth, capture: Capture) -> tuple[float, int]:
    """FORMATS section 5 mIoU (fraction) over frames with a non-empty true mask."""
    ious = []
    for frame, mask in masks:
        truth = true_mask(gt, capture, frame)
        if truth.any():
            ious.append((mask & truth).sum() / (mask | truth).sum())
    return float(np.mean(ious)), len(ious)


def check_miou(root: Path, grid_px: int) -> float:
    capture, gt, trajectory, frames, T_world_part = true_inputs(root)
    tracks, moving = simulate_tracks(capture, gt, T_world_part, grid_px, seed_every=5)
    masks = segment_parts(capture, trajectory, tracks, moving, frames, T_world_part[frames])
    assert list(masks.frames) == list(frames)
    miou, count = mean_iou(masks, gt, capture)
    assert count > 0
    return miou


@settings(deadline=None, max_examples=25)
@given(arrays(np.bool_, st.tuples(st.integers(1, 40), st.integers(1, 40))))
def test_mask_png_round_trip(mask: np.ndarray) -> None:
    np.testing.assert_array_equal(decode_mask(encode_mask(mask)), mask)


def test_part_masks_stream_in_frame_order() -> None:
    rng = np.random.default_rng(0)
    masks = rng.random((3, 6, 8)) > 0.5
    stored = PartMasks.from_masks([4, 5, 9], masks, keyframes=[4])
    assert (stored.height, stored.width, len(stored)) == (6, 8, 3)
    for (frame, mask), expected_frame, expected in zip(stored, [4, 5, 9], masks):
        assert frame == expected_frame
        np.testing.assert_array_equal(mask, expected)
    with pytest.raises(ValueError, match=r"masks must be \(F_k, H, W\)"):
        PartMasks.from_masks([0], masks[0])


def test_segment_parts_validates_inputs(small_sequence: Path) -> None:
    capture, gt, trajectory, frames, T_world_part = true_inputs(small_sequence)
    tracks, moving = simulate_tracks(capture, gt, T_world_part, grid_px=24, seed_every=20)
    with pytest.raises(ValueError, match=r"T_world_part \(F_k, 4, 4\)"):
        segment_parts(capture, trajectory, tracks, moving, frames, T_world_part[frames][:-1])
    with pytest.raises(ValueError, match="moving and static must be"):
        segment_parts(capture, trajectory, tracks, moving[:-1], frames, T_world_part[frames])
    with pytest.raises(ValueError, match="frames must lie in"):
        segment_parts(capture, trajectory, tracks, moving, frames + len(capture), T_world_part[frames])
    # Evidence comes from the part's motion, not from the caller's track labels: a part whose
    # poses never change has no pixels, whatever the labels say.
    with pytest.raises(ReconstructionError, match="no part pixels"):
        segment_parts(capture, trajectory, tracks, moving, frames, np.tile(np.eye(4), (len(frames), 1, 1)))


def test_segment_parts_reaches_target_iou_with_true_inputs(small_sequence: Path) -> None:
    miou = check_miou(small_sequence, grid_px=12)
    assert miou >= TARGET_MIOU, f"mIoU {100 * miou:.1f} below {100 * TARGET_MIOU:.0f}"


def test_keyframe_count_is_respected(small_sequence: Path) -> None:
    capture, gt, trajectory, frames, T_world_part = true_inputs(small_sequence)
    tracks, moving = simulate_tracks(capture, gt, T_world_part, grid_px=24, seed_every=10)
    config = SegmentationConfig(keyframe_count=3)
    # Twelve frames around the opening: evidence needs the part to move within them.
    first, _ = gt.parts[0].intervals[0]
    window = frames[(frames >= first - 4) & (frames < first + 8)]
    masks = segment_parts(capture, trajectory, tracks, moving, window, T_world_part[window], config)
    assert len(masks.keyframes) == 3 and masks.keyframes[0] == window[0] and masks.keyframes[-1] == window[-1]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "seed", "part"), [("seg_rev_640", 11, "door"), ("seg_pri_640", 12, "drawer")])
def test_segment_parts_iou_at_full_resolution(request: pytest.FixtureRequest, name: str, seed: int, part: str) -> None:
    root = synth_sequence(request.config.cache.mkdir("funrec_synth"), name, seed, part, 60, 640, 480)
    miou = check_miou(root, grid_px=24)
    assert miou >= TARGET_MIOU, f"{name}: mIoU {100 * miou:.1f} below {100 * TARGET_MIOU:.0f}"


# ----------------------------------------------------------------------------------------------
# Motion evidence on known geometry.

def _translation(t_world: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t_world
    return T


def test_classify_tracks_decides_only_where_the_part_moved() -> None:
    """Prismatic part resting for 16 frames, then moving 0.1 m per frame along x for 4 frames.
    Depth-like noise of 2 mm (well below the 2 cm tolerances) on every observation."""
    from funrec.surfaces.motion_evidence import classify_tracks

    F = 20
    states = np.concatenate([np.zeros(16), [0.1, 0.2, 0.3, 0.4]])
    T_world_part = np.stack([_translation([s, 0.0, 0.0]) for s in states])
    rng = np.random.default_rng(0)
    p_static, p_part = np.array([0.5, 0.0, 2.0]), np.array([0.0, 0.2, 2.0])
    trajectories = {
        "static, seen throughout": (np.tile(p_static, (F, 1)), np.ones(F, bool), -1),
        # Moves for 4 of its 20 frames: a 90th-percentile spread alone would miss it.
        "part, seen throughout": (p_part + states[:, None] * [1, 0, 0], np.ones(F, bool), 1),
        "part, seen only at rest": (np.tile(p_part, (F, 1)), np.arange(F) < 12, 0),
        "static, seen only at rest": (np.tile(p_static, (F, 1)), np.arange(F) < 12, 0),
        # A hand shadow: wanders while the part rests, then follows the part as the hand pulls.
        "shadow": (p_part + np.where(np.arange(F)[:, None] < 16, np.arange(F)[:, None] * [0, 0.01, 0],
                                     states[:, None] * [1, 0, 0] + [0, 0.16, 0]), np.ones(F, bool), 0),
    }
    p_world = np.stack([p for p, _, _ in trajectories.values()], axis=1) + rng.normal(0, 0.002, (F, len(trajectories), 3))
    visible = np.stack([v for _, v, _ in trajectories.values()], axis=1)
    p_world[~visible] = np.nan
    tracks = PointTracks(p_world, np.zeros((F, len(trajectories), 2)), visible)
    labels = classify_tracks(tracks, np.arange(F), T_world_part, np.zeros(len(trajectories), bool), 0.02, 0.02)
    assert dict(zip(trajectories, labels.labels.tolist())) == {k: v for k, (_, _, v) in trajectories.items()}
    # The part track's canonical place is where it rests, 2 mm noise aside.
    np.testing.assert_allclose(labels.p_part[1], p_part, atol=0.005)
    np.testing.assert_allclose(labels.p_anchor, p_part, atol=0.005)


def _plane_depth(K: np.ndarray, shape: tuple[int, int], plate_centre: np.ndarray, plate_half_m: float, wall_z_m: float
                 ) -> np.ndarray:
    """(H, W) depth of a fronto-parallel square plate in front of a fronto-parallel wall."""
    H, W = shape
    v, u = np.mgrid[0:H, 0:W]
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    z = plate_centre[2]
    on_plate = (np.abs(x * z - plate_centre[0]) < plate_half_m) & (np.abs(y * z - plate_centre[1]) < plate_half_m)
    return np.where(on_plate, z, wall_z_m).astype(np.float32)


def test_depth_evidence_finds_the_moved_plate_and_the_static_wall() -> None:
    """A 0.4 m plate at 2 m in front of a wall at 3 m moves by (0.5, 0, -0.4) m (sideways and
    towards the camera). Plate pixels see the wall through their old place and the plate at their
    new one: part. Wall pixels moved with the plate would float 0.4 m in front of the wall: static."""
    from funrec.surfaces.motion_evidence import DepthReference, depth_evidence

    K = np.array([[60.0, 0.0, 39.5], [0.0, 60.0, 29.5], [0.0, 0.0, 1.0]])
    shape = (60, 80)
    move = np.array([0.5, 0.0, -0.4])
    depth_0 = _plane_depth(K, shape, np.array([0.0, 0.0, 2.0]), 0.2, 3.0)
    depth_1 = _plane_depth(K, shape, np.array([0.0, 0.0, 2.0]) + move, 0.2, 3.0)
    no_hand = np.zeros(shape, bool)
    reference = DepthReference.from_frame(depth_1, no_hand, np.eye(4), _translation(move), frame=1)
    part, static = depth_evidence(depth_0, no_hand, K, np.eye(4), np.eye(4), [reference], (0.02, 2.0))
    plate = depth_0 < 2.5
    assert not (part & ~plate).any() and not (static & plate).any()
    assert part[plate].mean() > 0.9, part[plate].mean()
    # Wall pixels whose moved place hides behind the moved plate stay undecided.
    assert static[~plate].mean() > 0.5, static[~plate].mean()


def test_depth_evidence_finds_a_part_whose_moved_place_hides_behind_a_surface() -> None:
    """A drawer's inside (a 0.4 m plate at 2 m, in front of a wall at 3 m) pushed 0.4 m back into
    its carcass, whose front (0.6 m, at 2.3 m) the reference sees where the plate was: the moved
    place lies behind the front, unseen, and free space is seen through the static place. Plate
    pixels are part (with the moved place required seen, none was); wall pixels, whose static place
    is seen or hidden and never free, are not."""
    from funrec.surfaces.motion_evidence import DepthReference, depth_evidence

    K = np.array([[60.0, 0.0, 39.5], [0.0, 60.0, 29.5], [0.0, 0.0, 1.0]])
    shape = (60, 80)
    move = np.array([0.0, 0.0, 0.4])
    depth_0 = _plane_depth(K, shape, np.array([0.0, 0.0, 2.0]), 0.2, 3.0)
    depth_1 = _plane_depth(K, shape, np.array([0.0, 0.0, 2.3]), 0.3, 3.0)
    no_hand = np.zeros(shape, bool)
    reference = DepthReference.from_frame(depth_1, no_hand, np.eye(4), _translation(move), frame=1)
    part, _ = depth_evidence(depth_0, no_hand, K, np.eye(4), np.eye(4), [reference], (0.02, 2.0))
    plate = depth_0 < 2.5
    assert part[plate].mean() > 0.9, part[plate].mean()
    assert not (part & ~plate).any()


# ----------------------------------------------------------------------------------------------
# Estimated inputs: stages 1, 2, 3 and 5 on funrec.synth's smoke door and drawer (320x240).

ESTIMATED_MIN_MIOU = {"smoke_rev_00": 0.65, "smoke_pri_00": 0.80}
"""Measured with the stages of this commit: door 0.73, drawer 0.87 (bench 640x480: 78-95). The
door's estimate stops at 0.47 of its 1.5 rad (stage 2/3 lose it when it turns edge-on), so its
hinge half only moves a few centimetres; the limits leave ~7 points for upstream changes."""


@pytest.mark.slow
def test_segment_parts_iou_with_estimated_inputs(estimated_run: EstimatedRun) -> None:
    name = estimated_run.name
    miou, count = mean_iou(estimated_run.masks, estimated_run.gt, estimated_run.capture)
    assert count >= 20, f"{name}: only {count} tracked frames show the part"
    assert miou >= ESTIMATED_MIN_MIOU[name], f"{name}: mIoU {100 * miou:.1f} below {100 * ESTIMATED_MIN_MIOU[name]:.0f}"


def test_stray_model_voxels_in_front_of_the_part_do_not_cut_holes_in_its_mask() -> None:
    """A part model carries stray voxels (static surface that keyframes at rest labelled part). A
    sheet of them 0.5 m in front of a 0.4 x 0.4 m panel must not hide the panel in a frame that sees
    the panel: its mask is the panel's pixels (IoU > 0.95), not the strays' silhouette; a hand in
    front of the panel stays out of the mask."""
    from funrec.surfaces.segmentation import _propagate, _View

    config = SegmentationConfig()
    K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
    H, W = 240, 320
    depth = np.full((H, W), 3.0, dtype=np.float32)  # a wall 3 m away
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    x, y = (u - K[0, 2]) / K[0, 0] * 1.5, (v - K[1, 2]) / K[1, 1] * 1.5
    panel = (np.abs(x) < 0.2) & (np.abs(y) < 0.2)
    depth[panel] = 1.5
    hand = (np.abs(x - 0.1) < 0.05) & (np.abs(y) < 0.05)
    depth[hand] = 0.8
    step = config.voxel_m
    a, b = np.meshgrid(np.arange(-0.2, 0.2, step), np.arange(-0.2, 0.2, step))
    p_panel = np.stack([a.ravel(), b.ravel(), np.full(a.size, 1.5)])
    c, e = np.meshgrid(np.arange(-0.1, 0.1, step), np.arange(-0.1, 0.1, step))
    p_stray = np.stack([c.ravel() * 0.66, e.ravel() * 0.66, np.full(c.size, 1.0)])  # covers the panel's middle
    p_part = np.concatenate([p_panel, p_stray], axis=1).astype(np.float32)
    mask = _propagate(_View(depth, np.zeros((H, W), dtype=bool)), p_part, np.eye(4), K, config)
    truth = panel & ~hand
    iou = (mask & truth).sum() / (mask | truth).sum()
    assert iou > 0.95, iou
    assert not (mask & hand).any()


# ----------------------------------------------------------------------------------------------
# The part model's place vote, on ray-cast rectangles (world z up, the cabinet front at y = 2 m).

def _render(rectangles: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]], T_world_camera: np.ndarray, K: np.ndarray,
            shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) and surface id (H, W, -1 for none) of rectangles (corner, edge, edge, id), world frame."""
    H, W = shape
    v, u = np.mgrid[0:H, 0:W]
    d_world = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], axis=-1) @ T_world_camera[:3, :3].T
    o = T_world_camera[:3, 3]
    depth, ids = np.full((H, W), np.inf), np.full((H, W), -1)
    for corner, e1, e2, rect_id in rectangles:
        n = np.cross(e1, e2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((corner - o) @ n) / (d_world @ n)
        p = o + t[..., None] * d_world - corner
        s1, s2 = p @ e1 / (e1 @ e1), p @ e2 / (e2 @ e2)
        hit = (t > 0) & (t < depth) & (s1 >= 0) & (s1 <= 1) & (s2 >= 0) & (s2 <= 1)
        depth, ids = np.where(hit, t, depth), np.where(hit, rect_id, ids)
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32), ids


def _rect(corner, e1, e2, rect_id):
    return np.asarray(corner, float), np.asarray(e1, float), np.asarray(e2, float), rect_id


def _place_vote_case(part_rects, static_rects, T_world_part, wrong: dict[int, list[int]],
                     p_camera=(0.6, 0.4, 1.3), target=(0.2, 2.0, 0.5), T_world_part_witness=()) -> np.ndarray:
    """The model (3, M), canonical, that :func:`_vote_model` keeps from keyframes whose masks
    label the part's rectangles and, at keyframe q, the static rectangles ``wrong[q]`` (what
    flooding labels part). Cameras from the front right, above (``p_camera``, moving 0.2 m
    sideways over the keyframes, looking at ``target``), 160 x 120 pixels. Witnesses (depth only)
    at the part poses ``T_world_part_witness``, seen from the middle keyframe's place."""
    from funrec.surfaces.motion_evidence import DepthReference
    from funrec.surfaces.segmentation import _View, _vote_model
    from funrec.synth.motion import look_at

    K = np.array([[150.0, 0.0, 79.5], [0.0, 150.0, 59.5], [0.0, 0.0, 1.0]])
    Q = len(T_world_part)
    p_camera = np.asarray(p_camera) + np.linspace(-0.1, 0.1, Q)[:, None] * np.array([1.0, 0.0, 0.0])
    T_world_camera = np.tile(np.eye(4), (Q, 1, 1))
    T_world_camera[:, :3, :3] = look_at(p_camera, np.tile(target, (Q, 1)))
    T_world_camera[:, :3, 3] = p_camera

    def posed(T):
        R, t = T[:3, :3], T[:3, 3]
        return [(R @ c + t, R @ e1, R @ e2, i) for c, e1, e2, i in part_rects]

    views = []
    for q in range(Q):
        depth, ids = _render(posed(T_world_part[q]) + static_rects, T_world_camera[q], K, (120, 160))
        part = np.isin(ids, [r[3] for r in part_rects] + wrong.get(q, []))
        views.append(_View(depth, np.zeros(depth.shape, bool), part=part, known=np.ones(depth.shape, bool)))
    T_middle = T_world_camera[Q // 2]
    witnesses = []
    for w, T in enumerate(T_world_part_witness):
        depth, _ = _render(posed(T) + static_rects, T_middle, K, (120, 160))
        witnesses.append(DepthReference.from_frame(depth, np.zeros(depth.shape, bool), np.linalg.inv(T_middle), T, 100 + w))
    return _vote_model(views, np.linalg.inv(T_world_part) @ T_world_camera, T_world_camera, K, SegmentationConfig(),
                       witnesses, K)


def _covered(p: np.ndarray, corner, e1, e2, cell_m: float = 0.02) -> float:
    """Fraction of the cells (``cell_m``) of a rectangle that hold a point of (3, M) ``p`` within 1 cm of it."""
    corner, e1, e2 = (np.asarray(x, float) for x in (corner, e1, e2))
    n = np.cross(e1, e2) / np.linalg.norm(np.cross(e1, e2))
    d = p.T - corner
    s1, s2 = d @ e1 / (e1 @ e1), d @ e2 / (e2 @ e2)
    on = (np.abs(d @ n) < 0.01) & (s1 >= 0) & (s1 < 1) & (s2 >= 0) & (s2 < 1)
    shape = (int(np.linalg.norm(e1) / cell_m), int(np.linalg.norm(e2) / cell_m))
    cells = np.zeros(shape, bool)
    cells[(s1[on] * shape[0]).astype(int), (s2[on] * shape[1]).astype(int)] = True
    return float(cells.mean())


def _turn_z(theta: float, pivot: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(-theta), np.sin(-theta)  # the free edge comes towards the cameras (-y)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = pivot - T[:3, :3] @ pivot
    return T


def test_static_surfaces_labelled_part_that_never_leave_their_place_are_dropped_from_the_model() -> None:
    """A door (0.4 x 0.6 m, hinge at its left edge) turns towards the cameras, 0 -> 1.4 rad. Closed,
    the keyframes label the coplanar next door part as well (no depth test tells them apart at
    rest); open, the cabinet's shelf (a plane the turn carries onto itself, seen only open). Both
    pass the part vote (where the door's pose moves them they fall behind static surfaces). The
    place vote drops them: each stays where it was seen while the door's pose moves it away (the
    shelf is seen still there half open, where the door's pose has turned it). The door's own
    is kept: at least 90 % of its 2 cm cells hold a model voxel, and at most 5 % of the model lies
    off the door."""
    door = [_rect([0.0, 2.0, 0.2], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 0)]
    static = [
        _rect([-0.4, 2.0, 0.2], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 1),  # the next door, coplanar when closed
        _rect([0.0, 2.0, 0.2], [0.4, 0.0, 0.0], [0.0, 0.4, 0.0], 2),  # the shelf inside
        _rect([0.0, 2.0, 0.8], [0.4, 0.0, 0.0], [0.0, 0.4, 0.0], 3),  # carcass top
        _rect([0.0, 2.4, 0.2], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 4),  # carcass back
        _rect([0.4, 2.0, 0.2], [0.0, 0.4, 0.0], [0.0, 0.0, 0.6], 5),  # carcass side
        _rect([0.4, 2.0, 0.0], [0.6, 0.0, 0.0], [0.0, 0.0, 1.0], 6),  # the front right of the cabinet
        _rect([-3.0, 0.0, 0.0], [6.0, 0.0, 0.0], [0.0, 3.0, 0.0], 7),  # floor
    ]
    thetas = [0.0, 0.0, 0.0, 0.35, 0.7, 1.05, 1.4, 1.4]
    T_world_part = np.stack([_turn_z(theta, np.array([0.0, 2.0, 0.0])) for theta in thetas])
    kept = _place_vote_case(door, static, T_world_part, {0: [1], 1: [1], 2: [1], 4: [2], 5: [2], 6: [2], 7: [2]})
    on_door = (np.abs(kept[1] - 2.0) < 0.01) & (kept[0] > -0.01) & (kept[0] < 0.41)
    assert _covered(kept, *door[0][:3]) > 0.9, _covered(kept, *door[0][:3])
    assert (~on_door).mean() < 0.05, f"{(~on_door).sum()} of {kept.shape[1]} kept voxels lie off the door"


def test_a_static_surface_hidden_behind_the_open_part_at_every_other_keyframe_is_judged_by_a_witness() -> None:
    """The door of the test above, with keyframes only closed and fully open (1.4 rad): open, the
    door stands in front of most of the next door, which the closed keyframes labelled part, so
    no keyframe sees where those voxels were and the place vote kept them. A depth-only witness
    at 0.5 rad sees the next door still there: they are dropped, and the door is kept."""
    door = [_rect([0.0, 2.0, 0.2], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 0)]
    static = [
        _rect([-0.4, 2.0, 0.2], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 1),  # the next door, coplanar when closed
        _rect([0.0, 2.4, 0.2], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 4),  # carcass back
        _rect([-3.0, 0.0, 0.0], [6.0, 0.0, 0.0], [0.0, 3.0, 0.0], 7),  # floor
    ]
    pivot = np.array([0.0, 2.0, 0.0])
    T_world_part = np.stack([_turn_z(theta, pivot) for theta in [0.0] * 4 + [1.4] * 4])
    next_door = static[0][:3]
    wrong = {0: [1], 1: [1], 2: [1], 3: [1]}
    kept = _place_vote_case(door, static, T_world_part, wrong, p_camera=(0.8, 0.8, 1.3), target=(-0.1, 2.0, 0.5))
    judged = _place_vote_case(door, static, T_world_part, wrong, p_camera=(0.8, 0.8, 1.3), target=(-0.1, 2.0, 0.5),
                              T_world_part_witness=[_turn_z(0.5, pivot)])
    on_next_door = (np.abs(judged[1] - 2.0) < 0.01) & (judged[0] < -0.01)
    assert _covered(kept, *next_door) > 0.2, _covered(kept, *next_door)  # what the witness is for
    assert _covered(judged, *next_door) < 0.15, _covered(judged, *next_door)
    # what is left the witness' turn moved less than 2 tau (0.04 m): a strip 8 cm wide along the hinge
    assert judged[0][on_next_door].min() > -0.09, judged[0][on_next_door].min()
    assert _covered(judged, *door[0][:3]) > 0.9, _covered(judged, *door[0][:3])


def test_a_drawer_floor_that_slides_along_itself_stays_in_the_model() -> None:
    """A drawer (front 0.4 x 0.1 m, floor 0.4 m deep) slides 0.3 m out of its carcass. Its floor is
    a plane the slide carries onto itself: at a less open keyframe the floor is still seen where
    it was. It stays in the model (the front >= 90 % of its 2 cm cells, the floor seen out of the
    carcass >= 85 %): the place is covered by floor voxels that left the carcass' front themselves."""
    drawer = [
        _rect([0.0, 2.0, 0.3], [0.4, 0.0, 0.0], [0.0, 0.0, 0.1], 0),  # front
        _rect([0.0, 2.0, 0.3], [0.4, 0.0, 0.0], [0.0, 0.4, 0.0], 1),  # floor
    ]
    static = [
        _rect([0.0, 2.0, 0.4], [0.4, 0.0, 0.0], [0.0, 0.4, 0.0], 2),  # carcass top over the drawer
        _rect([-0.4, 2.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.0, 1.0], 3),  # fronts left and right
        _rect([0.4, 2.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.0, 1.0], 4),
        _rect([0.0, 2.0, 0.4], [0.4, 0.0, 0.0], [0.0, 0.0, 0.6], 5),  # front above
        _rect([-3.0, 0.0, 0.0], [6.0, 0.0, 0.0], [0.0, 3.0, 0.0], 6),  # floor
    ]
    T_world_part = np.tile(np.eye(4), (8, 1, 1))
    T_world_part[:, 1, 3] = -np.array([0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.3])
    kept = _place_vote_case(drawer, static, T_world_part, {}, p_camera=(0.6, 1.0, 1.6), target=(0.2, 2.0, 0.3))
    assert _covered(kept, *drawer[0][:3]) > 0.9, _covered(kept, *drawer[0][:3])
    seen_floor = ([0.0, 2.1, 0.3], [0.4, 0.0, 0.0], [0.0, 0.18, 0.0])  # the floor seen out of the carcass, behind the front
    # Measured 0.90 (0.03 when every surface still there counts, whatever covers it). A voxel needs twice as many
    # keyframes seeing its place left as still standing (a wall cabinet's static strays, seen at grazing angles
    # with 2 cm of camera error, come out about even); the floor's last strip, seen still there at less open
    # keyframes where few proven voxels cover it, is what that costs.
    assert _covered(kept, *seen_floor) > 0.85, _covered(kept, *seen_floor)



def test_a_panel_that_slides_along_itself_stays_in_the_model() -> None:
    """A sliding wardrobe panel (0.6 x 1.0 m) slides 0.2 m sideways, in front of the fixed panel
    (3 cm behind it). The slide carries the panel onto itself: its middle third is still seen where
    a voxel was at every other keyframe, and only strips at its edges ever leave their place. It
    stays in the model (>= 90 % of its 2 cm cells; measured 1.00): under a slide any model voxel
    covers the place (with only voxels that left some place covering, measured 0.35), and at most
    5 % of the model lies off the panel."""
    panel = [_rect([0.0, 2.0, 0.2], [0.6, 0.0, 0.0], [0.0, 0.0, 1.0], 0)]
    static = [
        _rect([-0.6, 2.03, 0.0], [1.2, 0.0, 0.0], [0.0, 0.0, 1.4], 1),  # the fixed panel behind
        _rect([-3.0, 2.5, 0.0], [6.0, 0.0, 0.0], [0.0, 0.0, 2.5], 2),  # wall
        _rect([-3.0, 0.0, 0.0], [6.0, 0.0, 0.0], [0.0, 3.0, 0.0], 3),  # floor
    ]
    T_world_part = np.tile(np.eye(4), (8, 1, 1))
    T_world_part[:, 0, 3] = -np.array([0.0, 0.0, 0.04, 0.08, 0.12, 0.16, 0.2, 0.2])
    kept = _place_vote_case(panel, static, T_world_part, {}, p_camera=(0.3, 0.6, 1.4), target=(0.1, 2.0, 0.7))
    on_panel = (np.abs(kept[1] - 2.0) < 0.01) & (kept[0] > -0.01) & (kept[0] < 0.61)
    assert _covered(kept, *panel[0][:3]) > 0.9, _covered(kept, *panel[0][:3])
    assert (~on_panel).mean() < 0.05, f"{(~on_panel).sum()} of {kept.shape[1]} kept voxels lie off the panel"


def test_witnesses_judge_turns_not_slides() -> None:
    """One keyframe sees a 0.3 m patch (at 2 m, facing the camera) as part; a witness sees free
    space behind the places of its right third (those voxels left) and a surface still standing at
    the others. Turned 0.5 rad about an axis along its left edge: the witness calls the voxels of
    the left two thirds that moved 2 tau still there. Slid 0.1 m sideways within its plane, the
    patch carries itself onto itself (where the model holds no voxel, an uncovered place is as
    likely a coarse depth reading at its edge): no vote at all."""
    from funrec.surfaces.motion_evidence import DepthReference
    from funrec.surfaces.segmentation import _place_votes, _View

    K = np.array([[150.0, 0.0, 79.5], [0.0, 150.0, 59.5], [0.0, 0.0, 1.0]])
    step = 0.004
    a, b = np.meshgrid(np.arange(0.0, 0.3, step), np.arange(-0.1, 0.1, step))
    p_part = np.stack([a.ravel(), b.ravel(), np.full(a.size, 2.0)])
    wall = np.full((120, 160), 2.0, dtype=np.float32)  # a surface where the left two thirds were
    wall[:, 95:] = 3.0  # free space behind the places of the right third (x > 0.2 m: u > 79.5 + 150 * 0.1)
    view = _View(wall, np.zeros(wall.shape, bool))
    slide = _translation(np.array([0.1, 0.0, 0.0]))
    turn = np.eye(4)
    c, s_ = np.cos(0.5), np.sin(0.5)
    turn[:3, :3] = [[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]]  # about the y axis through (0, 0, 2)
    turn[:3, 3] = np.array([0.0, 0.0, 2.0]) - turn[:3, :3] @ np.array([0.0, 0.0, 2.0])
    votes = {}
    for name, T in (("slide", slide), ("turn", turn)):
        witness = DepthReference.from_frame(wall, np.zeros(wall.shape, bool), np.eye(4), T, frame=1)
        votes[name] = _place_votes([view], p_part, np.ones((1, p_part.shape[1]), bool), np.eye(4)[None],
                                   np.eye(4)[None], K, SegmentationConfig(), [witness], K)
    moved = np.linalg.norm(turn[:3, :3] @ p_part + turn[:3, 3:] - p_part, axis=0) > 0.05
    still = moved & (p_part[0] < 0.19)
    assert still.sum() > 100 and (votes["turn"][1][still] > 0).mean() > 0.9, (votes["turn"][1][still] > 0).mean()
    assert (votes["turn"][0][p_part[0] > 0.21] > 0).mean() > 0.9
    assert not votes["slide"][0].any() and not votes["slide"][1].any()


def test_a_part_region_keeps_only_what_its_evidence_reaches_without_a_depth_jump() -> None:
    """A door seen edge-on is a near strip with part evidence; the region it was decided in also
    holds the cabinet's inside 30 cm behind it. A plain front with evidence on one column carries a
    handle 3 cm proud (2.5 % of the depth: a jump at the default 2 %) and a missing reading. The
    inside goes; the strip, the front, its handle and the missing reading stay."""
    from funrec.surfaces.segmentation import _attached

    depth = np.full((40, 60), 1.8, dtype=np.float32)
    depth[:, 10:14] = 1.5
    depth[:, 30:] = 1.2
    depth[18:22, 40:50] = 1.17
    depth[5, 35] = 0.0
    part = np.zeros_like(depth, dtype=bool)
    part[:, 10:28] = True
    part[:, 30:] = True
    seeds = np.zeros_like(part)
    seeds[:, 11] = True
    seeds[:, 58] = True
    kept = _attached(part, seeds, depth, SegmentationConfig().depth_jump_relative)
    assert kept[:, 10:14].all() and not kept[:, 14:28].any()
    assert kept[:, 30:].all()
    assert not kept[:, :10].any() and not kept[:, 28:30].any()
