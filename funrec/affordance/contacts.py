"""Hand-contact affordances: where the hand held each articulated part, as a contact region, a
contact point and a grasp frame on the part at its canonical state, with the demonstrated joint
motion.

affordances.json, their file in the twin folder, is specified in docs/formats.md section 6
(read and written by :mod:`funrec.formats.affordances`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from funrec.affordance.handle import grasp_at_handle
from funrec.affordance.observe import inside_footprint, observed_surface
from funrec.affordance.types import REFERENCE_WIDTH_PX, AffordanceConfig, PartSurface
from funrec.camera.tracking import CameraTrajectory, Progress
from funrec.formats.affordances import (
    Affordances,
    Interaction,
    PartAffordance,
)
from funrec.formats.capture import Capture
from funrec.formats.twin import ArticulatedPart
from funrec.geometry.camera import backproject
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.surfaces.hands import HandMasks, detect_hands, part_poses
from funrec.surfaces.segmentation import PartMasks
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Touch:
    """One frame in which the hand's far end is at a part (private)."""

    frame: int
    p_part: FloatArray
    """(n, 3) far-end hand points within the contact distance, canonical part (world) frame."""
    up_part: FloatArray
    """(3,) the camera's up direction (-y) in the canonical part frame."""


def find_affordances(
    capture: Capture,
    trajectory: CameraTrajectory,
    parts: Sequence[ArticulatedPart],
    surfaces: Sequence[PartSurface],
    part_masks: Sequence[PartMasks] = (),
    hands: HandMasks | None = None,
    config: AffordanceConfig = AffordanceConfig(),  # noqa: B008 (frozen, immutable default)
    progress: Progress | None = None,
) -> Affordances:
    """Find where the hand held each part and turn it into a grasp.

    1. Hand masks: ``hands``, or :func:`funrec.surfaces.hands.detect_hands` (the capture's masks when it
       has them, else detection; ``part_masks`` help it compensate the parts' motion).
    2. Each frame's hand pixels are lifted with depth; the far end of the arm (the points
       farthest from the camera, ``distal_*``) is moved into each part's canonical frame with
       ``inv(T_world_part)`` of that frame's state. Frames where it lies within
       ``contact_distance_m`` of the part surface touch the part.
    3. Holds: touching frames whose far end stays within ``hold_radius_m`` of the grip position
       (canonical frame), in runs of at least ``min_hold_s`` during which the part moves by
       ``min_motion_*``. Parts never held that way are listed as missing.
    4. Contact: surface points near the far end during the holds get votes (closer, more); the
       vote-weighted centre of the top votes is the first estimate. The hand hid the handle
       while it held it, so the surface around it is completed with depth from a few frames
       before the grasp or after the release (``observe_*``), inside the part's outline, and
       voted again. The contact is then snapped to the handle: the piece of geometry standing
       out of the front plane (the front-most wide layer parallel to the dominant plane; a part
       fused with a few wrong states holds a copy of its front behind it) within
       ``handle_search_radius_m``, nearest to the estimate by squared distance per point (bar,
       knob, grip lip). A snapped contact far from the hand (``max_hand_distance_m``), or a
       revolute part's front not containing its hinge (``max_front_hinge_cos``), means the plane
       was the top of the held bar seen from above: the contact is then the axis of the bar under
       the hand (a circle fitted across it, ``bar_fit_radius_m``).
    5. Grasp frame, demonstrated trajectory (states during each hold) and contact path (the
       contact point moved over the joint range), see the module docstring for conventions.

    Frames are streamed once (hand masks are PNG-encoded; only the far-end points are kept),
    then ``observe_frames`` frames per part are read again.

    Args:
        capture: the capture (depth is read again here).
        trajectory: camera poses ``T_world_camera`` (F, 4, 4), world frame of the twin.
        parts: articulated parts (joint, tracked frames and states, range), world frame.
        surfaces: one per part, its surface at the canonical state in the world frame (the twin's
            ``meshes/part_k.ply``): mesh (faces are sampled), point cloud or (N, 3) points.
        part_masks: per-part masks for hand detection (optional).
        hands: hand masks of every frame; detected when None.
        config: settings.
        progress: optional ``progress(done, total)``: hand detection (two passes, when it runs),
            then one step per frame.

    Returns:
        :class:`Affordances` with one entry per held part and the others listed as missing.

    Raises:
        ValueError: inputs of mismatched lengths or shapes.
    """
    F = len(capture)
    if len(surfaces) != len(parts):
        raise ValueError(f"{len(surfaces)} surfaces for {len(parts)} parts; give one per part")
    if np.shape(trajectory.T_world_camera) != (F, 4, 4):
        raise ValueError(f"trajectory has {len(trajectory.T_world_camera)} poses for {F} frames")
    rng = np.random.default_rng(config.seed)
    offset = 0 if hands is None else -2 * F  # detection reports 2F steps, then F more here
    if hands is None:
        detect_progress = None if progress is None else (lambda done, _total: progress(done, 3 * F))
        hands = detect_hands(capture, trajectory, parts, part_masks, config.hands, detect_progress)
    if len(hands) != F:
        raise ValueError(f"hand masks cover {len(hands)} frames, the capture has {F}")
    points = [_surface_points(s, config.surface_spacing_m, rng, part.name) for s, part in zip(surfaces, parts)]
    trees = [cKDTree(p) if len(p) else None for p in points]
    T_part_world = [invert_transform(part_poses(part, F)) for part in parts]
    touches: list[list[_Touch]] = [[] for _ in parts]
    K = capture.intrinsics.K
    scale = capture.intrinsics.width / REFERENCE_WIDTH_PX
    erosion = int(round(config.hand_erosion_px * scale))
    stride = max(1, int(round(config.hand_stride_px * scale)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erosion + 1,) * 2)
    for frame, hand in hands:
        if progress is not None:
            progress(offset + 2 * F + frame + 1, offset + 3 * F)
        if not hand.any():
            continue
        if erosion > 0:
            hand = cv2.erode(hand.astype(np.uint8), kernel) > 0
        p_camera = _far_end(hand, capture.depth_m(frame), K, stride, config)
        if p_camera is None:
            continue
        T_world_camera = trajectory.T_world_camera[frame]
        up_world = -T_world_camera[:3, 1]
        for k, tree in enumerate(trees):
            if tree is None:
                continue
            T_part_camera = T_part_world[k][frame] @ T_world_camera
            p_part = transform_points(T_part_camera, p_camera)
            distance, _ = tree.query(p_part, distance_upper_bound=config.contact_distance_m)
            near = distance < config.contact_distance_m
            if np.count_nonzero(near) >= config.min_contact_points:
                touches[k].append(_Touch(frame, p_part[near], T_part_world[k][frame][:3, :3] @ up_world))
    found, missing = [], []
    for part, p_surface, tree, part_touches in zip(parts, points, trees, touches):
        if tree is None:
            missing.append((part.name, "the part has no surface points"))
            continue
        def observe(c_part: FloatArray, holds: tuple[Interaction, ...], part: ArticulatedPart = part) -> FloatArray:
            return observed_surface(capture, trajectory, hands, part, c_part, holds, config)

        result = _part_affordance(part, p_surface, part_touches, observe, capture.intrinsics.fps, F, config, rng)
        if isinstance(result, str):
            missing.append((part.name, result))
            logger.info("%s: no affordance (%s)", part.name, result)
        else:
            found.append(result)
            logger.info("%s: %d holds, contact %s, handle %s", part.name, len(result.interactions),
                        np.round(result.contact_point, 3).tolist(), "found" if result.handle_found else "not found")
    return Affordances(tuple(found), tuple(missing), hands.source, float(capture.intrinsics.fps))


def _surface_points(surface: PartSurface, spacing_m: float, rng: np.random.Generator, name: str) -> FloatArray:
    """(N, 3) points of a part surface: mesh vertices plus uniform face samples, or the points."""
    if isinstance(surface, trimesh.Trimesh):
        vertices = np.asarray(surface.vertices, dtype=np.float64)
        if len(surface.faces) == 0 or not surface.area > 0.0:
            return vertices
        count = int(math.ceil(surface.area / spacing_m**2))
        samples = np.asarray(trimesh.sample.sample_surface(surface, count, seed=rng)[0], dtype=np.float64)
        return np.concatenate([vertices, samples])
    if isinstance(surface, trimesh.PointCloud):
        return np.asarray(surface.vertices, dtype=np.float64)
    p = np.asarray(surface, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"surface of {name} must be a mesh, a point cloud or (N, 3) points, got shape {p.shape}")
    return p[np.isfinite(p).all(axis=1)]


def _far_end(hand: BoolArray, depth_m: FloatArray, K: FloatArray, s: int, config: AffordanceConfig) -> FloatArray | None:
    """(n, 3) camera-frame hand points at the far end of the arm (every ``s``-th pixel), or None
    without depth."""
    mask = np.zeros_like(hand)
    mask[s // 2 :: s, s // 2 :: s] = hand[s // 2 :: s, s // 2 :: s]
    depth = np.where(mask, depth_m, 0.0)
    p_camera = backproject(depth, K)[mask.ravel()]
    p_camera = p_camera[np.isfinite(p_camera).all(axis=1)]
    if len(p_camera) < config.min_contact_points:
        return None
    r = np.linalg.norm(p_camera, axis=1)
    # Mask pixels beyond arm's reach are scene behind the hand's outline, not hand.
    p_camera, r = p_camera[r < config.hands.max_range_m], r[r < config.hands.max_range_m]
    if len(p_camera) < config.min_contact_points:
        return None
    return p_camera[r >= np.quantile(r, config.distal_quantile) - config.distal_band_m]


def _part_affordance(
    part: ArticulatedPart,
    p_surface: FloatArray,
    touches: list[_Touch],
    observe: Callable[[FloatArray, tuple[Interaction, ...]], FloatArray],
    fps: float,
    frame_count: int,
    config: AffordanceConfig,
    rng: np.random.Generator,
) -> PartAffordance | str:
    """The affordance of one part from its touching frames, or the reason there is none;
    ``observe(c_part, holds)`` returns extra part surface points around a canonical point."""
    if not touches:
        return "the hand never came within the contact distance of it"
    centroids = np.stack([t.p_part.mean(axis=0) for t in touches])
    # Grip position: the touching centroid with the most others within the hold radius (the hand
    # rests there while it holds the part), refined as the mean of those.
    pair_distance = np.linalg.norm(centroids[:, None] - centroids[None], axis=-1)
    support = (pair_distance < config.hold_radius_m).sum(axis=1)
    grip = centroids[pair_distance[int(np.argmax(support))] < config.hold_radius_m].mean(axis=0)
    holding = np.linalg.norm(centroids - grip, axis=1) < config.hold_radius_m
    frames = np.array([t.frame for t in touches])
    states_all = np.interp(np.arange(frame_count), part.frames, part.states) if len(part.frames) else np.zeros(frame_count)
    min_motion = config.min_motion_rad if part.joint_type == "revolute" else config.min_motion_m
    runs = _runs(frames[holding], max(1, round(config.max_gap_s * fps)), max(1, round(config.min_hold_s * fps)))
    interactions = []
    for first, last in runs:
        span = np.arange(first, last + 1)
        if np.ptp(states_all[span]) >= min_motion:
            interactions.append(Interaction(span, span / fps, states_all[span]))
    if not interactions:
        return f"no hold of at least {config.min_hold_s} s during which it moved (touching frames {frames.min()}-{frames.max()})"
    in_hold = np.isin(frames, np.concatenate([i.frames for i in interactions])) & holding
    held = [t for t, h in zip(touches, in_hold) if h]
    votes = _contact_votes(p_surface, held, config)
    if not votes.max() > 0:
        return "no surface point near the hand during the holds"
    c_first = _vote_centre(p_surface, votes, config)
    # The hand hid the grip while it held the part: fill the surface around it from frames where
    # it is visible, and vote again so that a hole under the hand does not bias the centre.
    p_hand = np.concatenate([t.p_part for t in held]).mean(axis=0)
    up = np.mean([t.up_part for t in held], axis=0)
    p_near = p_surface[np.linalg.norm(p_surface - c_first, axis=1) < config.search_radius_m]
    p_seen = observe(c_first, tuple(interactions))
    if len(p_seen) and len(p_near) >= 3:
        p_seen = p_seen[inside_footprint(p_seen, p_near, c_first, p_hand - c_first, config, rng)]
        p_local = np.concatenate([p_near, p_seen])
        c_first = _vote_centre(p_local, _contact_votes(p_local, held, config), config)
    else:
        p_seen = np.zeros((0, 3))
    # The handle is searched farther out than the front is fitted: a 30 cm drawer bar reaches
    # out of the search radius when the first estimate is 3 cm off along it.
    p_local = np.concatenate([p_surface[np.linalg.norm(p_surface - c_first, axis=1) < config.handle_radius_m], p_seen])
    contact, T_world_grasp, handle_found = grasp_at_handle(part, p_local, c_first, p_hand, up, config, rng)
    region = np.flatnonzero(votes >= config.region_fraction * votes.max())
    region = region[np.argsort(-votes[region], kind="stable")[: config.region_max_points]]
    path_states = np.linspace(part.state_range[0], part.state_range[1], config.path_samples)
    path_points = transform_points(joint_transforms(part.joint_type, part.axis_world, part.pivot_world, path_states), np.broadcast_to(contact, (config.path_samples, 3)))
    return PartAffordance(
        name=part.name,
        joint_type=part.joint_type,
        contact_point=contact,
        T_world_grasp=T_world_grasp,
        handle_found=handle_found,
        interactions=tuple(interactions),
        region_points=p_surface[region],
        region_weights=votes[region] / votes.max(),
        path_states=path_states,
        path_points=path_points,
    )



def _contact_votes(p_surface: FloatArray, held: list[_Touch], config: AffordanceConfig) -> FloatArray:
    """(N,) contact vote of each surface point: summed over the held frames, 1 - d / contact
    distance for the distance d to the nearest far-end hand point (0 beyond)."""
    votes = np.zeros(len(p_surface))
    reach = config.contact_distance_m
    for touch in held:
        if len(touch.p_part) == 0:
            continue
        # Only the surface points in the box of the hand points grown by the contact distance can
        # be near one: the others' vote is 0, so they are not queried (the same votes).
        low, high = touch.p_part.min(axis=0) - 1.001 * reach, touch.p_part.max(axis=0) + 1.001 * reach
        near = np.flatnonzero(np.all((p_surface >= low) & (p_surface <= high), axis=1))
        distance, _ = cKDTree(touch.p_part).query(p_surface[near], distance_upper_bound=reach)
        votes[near] += np.where(distance < reach, 1.0 - distance / reach, 0.0)
    return votes


def _vote_centre(p_surface: FloatArray, votes: FloatArray, config: AffordanceConfig) -> FloatArray:
    """(3,) vote-weighted centre of the points with at least ``vote_top_fraction`` of the top vote."""
    core = votes >= config.vote_top_fraction * votes.max()
    return (p_surface[core] * votes[core, None]).sum(axis=0) / votes[core].sum()



def _runs(frames: IntArray, max_gap: int, min_length: int) -> list[tuple[int, int]]:
    """Runs (first, last) of sorted frame indices, bridging gaps up to ``max_gap`` frames and
    keeping runs spanning at least ``min_length`` frames."""
    if len(frames) == 0:
        return []
    breaks = np.flatnonzero(np.diff(frames) > max_gap + 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(frames) - 1]])
    return [(int(frames[a]), int(frames[b])) for a, b in zip(starts, ends) if frames[b] - frames[a] + 1 >= min_length]


__all__ = ["AffordanceConfig", "PartSurface", "find_affordances"]
