"""Hand-contact affordances: where the hand held each articulated part, as a contact region, a
contact point and a grasp frame on the part at its canonical state, with the demonstrated joint
motion; and affordances.json, their file in the twin folder.

affordances.json (``"format": "funrec-affordances/1"``), every position in the twin's world frame
with the part at its canonical state (state 0, the pose of ``meshes/part_k.ply``)::

    {
      "format": "funrec-affordances/1",
      "hand_source": "detected",          # "capture" (masks/hand/) or "detected" (funrec.hands)
      "fps": 15.0,                         # capture frame rate: times_s = frame / fps
      "parts": [
        {
          "name": "part_0",                # as in articulation.json
          "joint_type": "revolute",        # as in articulation.json
          "contact_point": [x, y, z],      # where the hand held the part, metres
          "T_world_grasp": [[4 x 4]],      # grasp frame at the canonical state, row-major
          "handle_found": true,            # contact snapped to protruding handle geometry
          "interactions": [                # one per hold, in time order
            {"frames": [i, ...], "times_s": [t, ...], "states": [s, ...]}
          ],
          "contact_region": {"points": [[x, y, z], ...], "weights": [w, ...]},
          "contact_path": {"states": [s, ...], "points": [[x, y, z], ...]}
        }
      ],
      "missing": [{"name": "part_1", "reason": "..."}]
    }

- ``contact_point``: the centre of the handle the hand held (``handle_found``: the piece of
  geometry standing out of the front nearest to the hand's contact; on a handle longer than
  35 cm the point of its axis level with the hand), else the centre of the contact core.
- ``T_world_grasp``: origin at the contact point; z is the approach direction, from the hand's
  side into the part's front surface (minus the outward surface normal); x runs along the
  handle (principal direction of the handle geometry, or a fallback, see
  :class:`AffordanceConfig`); y = z cross x is across the handle, the finger-closing axis of a
  parallel gripper (funrec_robot's grasp frame: z approach, y finger axis), so a gripper whose
  grasp frame is aligned with it closes across the bar. Signs: of x and y, the one closer to
  the camera's up direction during the hold points up.
- At joint state ``s`` the grasp is ``joint_transform(s) @ T_world_grasp`` (FORMATS.md section 2
  joint transforms; :func:`funrec.query.grasp_frame`).
- ``interactions``: consecutive frames in which the hand held the part (its distal end stayed
  at the grip in the part's frame) and the part moved; ``states`` are the part's joint states
  there (interpolated between tracked frames, held constant outside them).
- ``contact_region``: part surface points (canonical state) near the gripping end of the hand
  during the holds, ``weights`` in (0, 1] (1 = most contact).
- ``contact_path``: the contact point moved by the joint over ``range`` of articulation.json,
  sampled at ``states``.
- ``missing``: articulated parts without an affordance and why (never held while moving).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from funrec.capture import Capture
from funrec.errors import FormatError
from funrec.geometry.camera import backproject
from funrec.geometry.joints import JOINT_TYPES, joint_transforms
from funrec.geometry.transforms import check_transform, invert_transform, make_transform, transform_points
from funrec.hands import HAND_SOURCES, HandConfig, HandMasks, detect_hands, part_poses
from funrec.segmentation import PartMasks
from funrec.tracking import CameraTrajectory, Progress
from funrec.twin_format import ArticulatedPart, read_json_object
from funrec.typed import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)

AFFORDANCES_FORMAT = "funrec-affordances/1"
"""Format tag written into and required from affordances.json."""
AFFORDANCES_FILE = "affordances.json"
"""File name of the affordances in a twin folder."""

_REFERENCE_WIDTH_PX = 640
"""Image width at which pixel sizes of :class:`AffordanceConfig` are given."""
_HAND_MARGIN_PX = 5
"""Hand masks are grown by this many pixels (at 640 px width) before observing the part around
them: mask outlines are imprecise and edge depth mixes hand and part."""

PartSurface = trimesh.Trimesh | trimesh.PointCloud | npt.ArrayLike
"""A part's surface at its canonical state, world frame: a mesh, a point cloud or (N, 3) points."""


@dataclass(frozen=True)
class AffordanceConfig:
    """Settings of :func:`find_affordances`; lengths in metres, durations in seconds."""

    hands: HandConfig = field(default_factory=HandConfig)
    """Hand detection, used when no hand masks are passed in."""
    surface_spacing_m: float = 0.005
    """Mesh faces are sampled with one point per this spacing squared (as the ground truth's
    5 mm points); point clouds are used as they are."""
    hand_erosion_px: int = 2
    """Hand masks are eroded by this many pixels (at 640 px image width, scaled with the width)
    before lifting: edge depth mixes hand and scene."""
    hand_stride_px: int = 2
    """Every k-th hand pixel in each direction is lifted (at 640 px image width, scaled with the
    width; a hand covers thousands of pixels)."""
    distal_quantile: float = 0.98
    """The hand's far end: points whose distance from the camera is within ``distal_band_m`` of
    this quantile of all hand points' distances. The egocentric arm reaches away from the eyes,
    so its far end is the gripping hand, whichever side of it the camera sees."""
    distal_band_m: float = 0.04
    """Depth of the hand's far end, metres (about a hand's thickness)."""
    contact_distance_m: float = 0.08
    """Far-end points within this of the part surface put the hand at the part. The camera sees
    the back of the hand, 4-6 cm off the surface it grips (measured on the synthetic bench)."""
    min_contact_points: int = 5
    """Fewest far-end points near the part for a frame to count as touching it."""
    hold_radius_m: float = 0.04
    """A touching frame is a hold when the far end's centroid, in the part's canonical frame, is
    within this of the grip position (where it stays longest): a held hand moves with the part."""
    max_gap_s: float = 0.2
    """Holds separated by shorter gaps (missed detections) are merged."""
    min_hold_s: float = 0.3
    """Shorter holds are dropped (brushing past a part)."""
    min_motion_rad: float = 0.05
    """A hold of a revolute part is an interaction only if the part turns this much during it."""
    min_motion_m: float = 0.02
    """A hold of a prismatic part is an interaction only if the part slides this much during it."""
    vote_top_fraction: float = 0.5
    """Surface points with at least this fraction of the top contact vote form the contact core,
    whose vote-weighted centre is the first contact estimate."""
    region_fraction: float = 0.25
    """Surface points with at least this fraction of the top vote form the contact region."""
    region_max_points: int = 2000
    """Most points written for the contact region (highest weights kept)."""
    search_radius_m: float = 0.2
    """Radius around the first estimate in which the front surface is fitted and the handle is
    searched: holds a door handle (14 cm) whole when the first estimate is off by 5 cm."""
    front_cell_m: float = 0.005
    """Cell size of the front-layer test (as seen from the hand), metres."""
    front_depth_m: float = 0.015
    """Points deeper than this behind the front-most point of their cell are hidden (the inner
    side of a door, drawer walls, bins) and take no part in the surface fit."""
    plane_tolerance_m: float = 0.005
    """RANSAC inlier distance of the front plane: a few mm of fused-mesh noise."""
    plane_hypotheses: int = 200
    """RANSAC hypotheses for the front plane."""
    max_handle_length_m: float = 0.35
    """A handle piece up to this long (along its principal direction) gives the contact at its
    centre: the first estimate's error runs mostly along the handle (2-4 cm on the synthetic
    bench), while its centre is where a hand or gripper holds it best. On a longer handle (an
    oven bar, a fridge's long bar), or one that reaches out of ``search_radius_m``, the contact
    is the point of the handle's axis level with the hand's far end, where the hand was."""
    handle_min_height_m: float = 0.008
    """Points standing this far out of the front plane are handle geometry (bars stand 3 cm out,
    knobs 3 cm, recessed grips' lips 1-2 cm; 8 mm is above the fit noise)."""
    handle_max_height_m: float = 0.08
    """... and no farther (anything farther is not a handle)."""
    handle_link_m: float = 0.012
    """Handle points closer than this are linked into one piece (2-3 surface spacings)."""
    min_handle_points: int = 5
    """Fewest handle points for the contact to be snapped to the handle."""
    handle_anisotropy: float = 2.0
    """The handle's principal direction gives the grasp x axis when its extent ratio (square root
    of the eigenvalue ratio) exceeds this; otherwise a fallback: the joint axis for revolute
    parts (bars on doors run along the hinge), the wider direction of the front for prismatic."""
    observe_frames: int = 8
    """Frames outside the holds whose depth adds to the part surface around the contact before the
    handle is searched: the hand hides the handle while it is held, so a part fused from the
    frames in which it moves often lacks it (a third of the points near the handle, measured)."""
    observe_window_s: float = 4.0
    """... chosen evenly among the frames within this time of a hold in which the part rests at
    its canonical state (the contact moved less than ``observe_still_m``; the handle is seen
    before the grasp) or has moved it at least ``observe_min_displacement_m`` (after the release).
    The points are kept where they lie, seen along the front's normal, inside the part surface's
    outline with holes up to ``observe_fill_m`` filled, which leaves out the static scene."""
    observe_min_views: int = 2
    """An observed voxel (``surface_spacing_m``) counts when this many of the frames saw it."""
    observe_still_m: float = 0.005
    """See ``observe_window_s``."""
    observe_min_displacement_m: float = 0.25
    """See ``observe_window_s``."""
    observe_fill_m: float = 0.12
    """See ``observe_window_s``: a hole the hand left in the fused part (its size, measured)."""
    footprint_cell_m: float = 0.01
    """Cell size of the part outline test, metres."""
    path_samples: int = 21
    """States sampled over the joint range for the contact path."""
    seed: int = 0
    """Seed of the surface sampling and the plane RANSAC (results are deterministic)."""

    def __post_init__(self) -> None:
        positive = (self.surface_spacing_m, self.distal_band_m, self.contact_distance_m, self.hold_radius_m,
                    self.search_radius_m, self.front_cell_m, self.plane_tolerance_m, self.handle_link_m)
        if min(positive) <= 0 or not 0.0 < self.distal_quantile <= 1.0 or self.hand_stride_px < 1:
            raise ValueError(f"AffordanceConfig needs positive lengths, 0 < distal_quantile <= 1 and hand_stride_px >= 1, got {self}")
        if not 0.0 < self.vote_top_fraction <= 1.0 or not 0.0 < self.region_fraction <= 1.0 or self.path_samples < 2:
            raise ValueError(f"AffordanceConfig needs fractions in (0, 1] and path_samples >= 2, got {self}")


@dataclass(frozen=True)
class Interaction:
    """One hold of a part: the demonstrated joint trajectory."""

    frames: IntArray
    """(n,) consecutive frame indices of the hold."""
    times_s: FloatArray
    """(n,) time of each frame from the capture start, seconds (frame / fps)."""
    states: FloatArray
    """(n,) joint state of the part at each frame, radians or metres from the canonical state."""

    def __post_init__(self) -> None:
        n = len(self.frames)
        if n == 0 or np.shape(self.frames) != (n,) or np.shape(self.times_s) != (n,) or np.shape(self.states) != (n,):
            raise ValueError(f"frames, times_s and states must be equal-length non-empty (n,), got "
                             f"{np.shape(self.frames)}, {np.shape(self.times_s)}, {np.shape(self.states)}")


@dataclass(frozen=True)
class PartAffordance:
    """Where and how the hand held one part (world frame, part at its canonical state)."""

    name: str
    """Part name, as in articulation.json."""
    joint_type: str
    """"revolute" or "prismatic"."""
    contact_point: FloatArray
    """(3,) robust centre of the contact, world frame at the canonical state, metres."""
    T_world_grasp: FloatArray
    """(4, 4) grasp frame at the canonical state (z approach, x along the handle, y = z x x)."""
    handle_found: bool
    """True when the contact point was snapped to protruding handle geometry."""
    interactions: tuple[Interaction, ...]
    """Holds in time order (at least one)."""
    region_points: FloatArray
    """(M, 3) part surface points in contact, world frame at the canonical state."""
    region_weights: FloatArray
    """(M,) contact weight of each region point in (0, 1]."""
    path_states: FloatArray
    """(S,) joint states sampled over the part's range, radians or metres."""
    path_points: FloatArray
    """(S, 3) the contact point at each of ``path_states``, world frame."""

    def __post_init__(self) -> None:
        if self.joint_type not in JOINT_TYPES:
            raise ValueError(f"joint_type must be one of {JOINT_TYPES}, got {self.joint_type!r}")
        if np.shape(self.contact_point) != (3,) or np.shape(self.T_world_grasp) != (4, 4):
            raise ValueError(f"contact_point must be (3,) and T_world_grasp (4, 4), got {np.shape(self.contact_point)}, {np.shape(self.T_world_grasp)}")
        M, S = len(self.region_points), len(self.path_states)
        if np.shape(self.region_points) != (M, 3) or np.shape(self.region_weights) != (M,):
            raise ValueError(f"region_points must be (M, 3) and region_weights (M,), got {np.shape(self.region_points)}, {np.shape(self.region_weights)}")
        if np.shape(self.path_states) != (S,) or np.shape(self.path_points) != (S, 3):
            raise ValueError(f"path_states must be (S,) and path_points (S, 3), got {np.shape(self.path_states)}, {np.shape(self.path_points)}")
        if not self.interactions:
            raise ValueError("a part affordance needs at least one interaction")


@dataclass(frozen=True)
class Affordances:
    """Hand-contact affordances of a twin (contents of affordances.json)."""

    parts: tuple[PartAffordance, ...]
    """One entry per part the hand was seen holding while it moved."""
    missing: tuple[tuple[str, str], ...]
    """(part name, reason) of each articulated part without an affordance."""
    hand_source: str
    """"capture" or "detected": where the hand masks came from."""
    fps: float
    """Capture frame rate, frames per second (times_s = frame / fps)."""

    def __post_init__(self) -> None:
        if self.hand_source not in HAND_SOURCES:
            raise ValueError(f"hand_source must be one of {HAND_SOURCES}, got {self.hand_source!r}")
        names = [p.name for p in self.parts] + [name for name, _ in self.missing]
        if len(set(names)) != len(names):
            raise ValueError(f"part names repeat: {names}")

    def part(self, name: str) -> PartAffordance | None:
        """The affordance of part ``name``, or None if it has none."""
        return next((p for p in self.parts if p.name == name), None)


# --------------------------------------------------------------------------------------------
# The stage
# --------------------------------------------------------------------------------------------


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

    1. Hand masks: ``hands``, or :func:`funrec.hands.detect_hands` (the capture's masks when it
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
       out of the front plane nearest to the estimate (bar, knob, grip lip).
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
    scale = capture.intrinsics.width / _REFERENCE_WIDTH_PX
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
            return _observed_surface(capture, trajectory, hands, part, c_part, holds, config)

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
        p_local = np.concatenate([p_near, p_seen[_inside_footprint(p_seen, p_near, c_first, p_hand - c_first, config, rng)]])
        c_first = _vote_centre(p_local, _contact_votes(p_local, held, config), config)
    else:
        p_local = p_near
    contact, T_world_grasp, handle_found = _grasp(part, p_local, c_first, p_hand, up, config, rng)
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


def _inside_footprint(
    p_seen: FloatArray, p_part: FloatArray, c: FloatArray, towards_hand: FloatArray, config: AffordanceConfig, rng: np.random.Generator
) -> BoolArray:
    """(n,) observed points that lie inside the part's outline: seen along the normal of the
    part's front plane near ``c``, in a cell of the part points' occupancy grid after a closing
    of ``observe_fill_m`` (which fills the hole the hand left), and within the handle height."""
    _, origin, normal, _ = _front_plane(p_part, c, towards_hand, config, rng)
    e1 = np.cross(normal, np.eye(3)[int(np.argmin(np.abs(normal)))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    n = int(np.ceil(config.search_radius_m / config.footprint_cell_m)) + 1

    def cells(p: FloatArray) -> tuple[IntArray, IntArray]:
        d = p - c
        return (np.floor(d @ e1 / config.footprint_cell_m).astype(np.int64) + n, np.floor(d @ e2 / config.footprint_cell_m).astype(np.int64) + n)

    grid = np.zeros((2 * n + 1, 2 * n + 1), dtype=np.uint8)
    i, j = cells(p_part)
    ok = (i >= 0) & (i <= 2 * n) & (j >= 0) & (j <= 2 * n)
    grid[i[ok], j[ok]] = 1
    size = 2 * int(round(config.observe_fill_m / config.footprint_cell_m / 2)) + 1
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    i, j = cells(p_seen)
    ok = (i >= 0) & (i <= 2 * n) & (j >= 0) & (j <= 2 * n)
    inside = np.zeros(len(p_seen), dtype=bool)
    inside[ok] = grid[i[ok], j[ok]] > 0
    return inside & (np.abs((p_seen - origin) @ normal) < config.handle_max_height_m)


def _contact_votes(p_surface: FloatArray, held: list[_Touch], config: AffordanceConfig) -> FloatArray:
    """(N,) contact vote of each surface point: summed over the held frames, 1 - d / contact
    distance for the distance d to the nearest far-end hand point (0 beyond)."""
    votes = np.zeros(len(p_surface))
    for touch in held:
        distance, _ = cKDTree(touch.p_part).query(p_surface, distance_upper_bound=config.contact_distance_m)
        votes += np.where(distance < config.contact_distance_m, 1.0 - distance / config.contact_distance_m, 0.0)
    return votes


def _vote_centre(p_surface: FloatArray, votes: FloatArray, config: AffordanceConfig) -> FloatArray:
    """(3,) vote-weighted centre of the points with at least ``vote_top_fraction`` of the top vote."""
    core = votes >= config.vote_top_fraction * votes.max()
    return (p_surface[core] * votes[core, None]).sum(axis=0) / votes[core].sum()


def _observed_surface(
    capture: Capture,
    trajectory: CameraTrajectory,
    hands: HandMasks,
    part: ArticulatedPart,
    c_part: FloatArray,
    holds: tuple[Interaction, ...],
    config: AffordanceConfig,
) -> FloatArray:
    """(n, 3) surface points (canonical frame) within ``search_radius_m`` of ``c_part`` lifted
    from up to ``observe_frames`` frames near the holds (see ``observe_window_s``), hand pixels
    (dilated) left out, voxel-downsampled to ``surface_spacing_m``. Static scene is still among
    them (see :func:`_inside_footprint`)."""
    F = len(capture)
    T_world_part = part_poses(part, F)
    moved = np.linalg.norm(transform_points(T_world_part, np.broadcast_to(c_part, (F, 3))) - c_part, axis=1)
    held = np.zeros(F, dtype=bool)
    for hold in holds:
        held[hold.frames[0] : hold.frames[-1] + 1] = True
    edges = np.array([h.frames[i] for h in holds for i in (0, -1)])
    near_hold = np.abs(np.arange(F)[:, None] - edges[None]).min(axis=1) <= config.observe_window_s * capture.intrinsics.fps
    still_or_moved = (moved < config.observe_still_m) | (moved >= config.observe_min_displacement_m)
    candidates = np.flatnonzero(~held & near_hold & still_or_moved)
    if len(candidates) == 0 or config.observe_frames < 1:
        return np.zeros((0, 3))
    chosen = candidates[np.unique(np.round(np.linspace(0, len(candidates) - 1, min(config.observe_frames, len(candidates)))).astype(int))]
    K = capture.intrinsics.K
    W, H = capture.intrinsics.width, capture.intrinsics.height
    margin = max(1, round(_HAND_MARGIN_PX * W / _REFERENCE_WIDTH_PX))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1,) * 2)
    found = []
    for frame in chosen:
        T_camera_part = invert_transform(trajectory.T_world_camera[frame]) @ T_world_part[frame]
        c_camera = transform_points(T_camera_part, c_part[None])[0]
        if c_camera[2] <= 0:
            continue
        u, v = K[0, 0] * c_camera[0] / c_camera[2] + K[0, 2], K[1, 1] * c_camera[1] / c_camera[2] + K[1, 2]
        r = K[0, 0] * config.search_radius_m / c_camera[2]
        u0, u1, v0, v1 = (int(np.clip(x, 0, n)) for x, n in ((u - r, W), (u + r + 1, W), (v - r, H), (v + r + 1, H)))
        if u1 <= u0 or v1 <= v0:
            continue
        depth = capture.depth_m(int(frame))
        keep = np.zeros((H, W), dtype=bool)
        keep[v0:v1, u0:u1] = True
        keep &= cv2.dilate(hands.mask(int(frame)).astype(np.uint8), kernel) == 0
        p_camera = backproject(np.where(keep, depth, 0.0), K)[keep.ravel()]
        p_camera = p_camera[np.isfinite(p_camera).all(axis=1)]
        p_part = transform_points(invert_transform(T_camera_part), p_camera)
        found.append(p_part[np.linalg.norm(p_part - c_part, axis=1) < config.search_radius_m])
    if not found:
        return np.zeros((0, 3))
    # One point per voxel and frame, then voxels seen in several frames: flying pixels at depth
    # edges and noise do not repeat, surfaces do.
    voxels, points = [], []
    for p in found:
        keys, first = np.unique(np.floor(p / config.surface_spacing_m).astype(np.int64), axis=0, return_index=True)
        voxels.append(keys)
        points.append(p[first])
    keys, first, count = np.unique(np.concatenate(voxels), axis=0, return_index=True, return_counts=True)
    return np.concatenate(points)[first[count >= min(config.observe_min_views, len(found))]]


def _runs(frames: IntArray, max_gap: int, min_length: int) -> list[tuple[int, int]]:
    """Runs (first, last) of sorted frame indices, bridging gaps up to ``max_gap`` frames and
    keeping runs spanning at least ``min_length`` frames."""
    if len(frames) == 0:
        return []
    breaks = np.flatnonzero(np.diff(frames) > max_gap + 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [len(frames) - 1]])
    return [(int(frames[a]), int(frames[b])) for a, b in zip(starts, ends) if frames[b] - frames[a] + 1 >= min_length]


def _grasp(
    part: ArticulatedPart,
    p_local: FloatArray,
    c_first: FloatArray,
    p_hand: FloatArray,
    up: FloatArray,
    config: AffordanceConfig,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, bool]:
    """Contact point (3,), T_world_grasp (4, 4) and whether handle geometry was found, from
    (N, 3) part surface points around the first estimate ``c_first``.

    The front surface around the first estimate is the RANSAC plane of the points visible from
    the hand's side; points standing out of it towards the hand are handle geometry, and the
    linked piece of it nearest to the estimate is the handle: its centre (or, on a long handle,
    the centre of its part near the estimate) is the contact point, its direction the x axis.
    """
    towards_hand = p_hand - c_first if np.linalg.norm(p_hand - c_first) > 1e-9 else up
    front, origin, normal, inliers = _front_plane(p_local, c_first, towards_hand, config, rng)
    plane_points = front[inliers]
    height = (front - origin) @ normal
    candidate = (height > config.handle_min_height_m) & (height < config.handle_max_height_m)
    handle = _nearest_handle(front[candidate], c_first, config)
    handle_found = len(handle) >= config.min_handle_points
    contact = c_first
    if handle_found:
        centre, direction = handle.mean(axis=0), _principal_direction(handle)
        along = (handle - centre) @ direction
        # The middle of the handle's extent, not the mean of its points: the fused part may
        # lack a stretch of the handle that the hand hid.
        contact = centre + 0.5 * (along.min() + along.max()) * direction
        cut = np.linalg.norm(handle - c_first, axis=1).max() > config.search_radius_m - 2 * config.handle_link_m
        if cut or np.ptp(along) > config.max_handle_length_m:  # long, or reaching out of the search
            # Where the hand was along the handle: its far end is centred on the grip (the
            # fingers wrap the bar on both sides), closer than the surface votes when the
            # fused part has a hole under the hand (measured: 0.5 cm against 2.7 cm).
            contact = centre + np.clip((p_hand - centre) @ direction, along.min(), along.max()) * direction
    z = -normal
    x = _handle_axis(part, handle if handle_found else np.zeros((0, 3)), plane_points, z, config)
    y = np.cross(z, x)
    # Sign: of x and y, whichever is closer to the camera's up direction points up.
    if abs(y @ up) >= abs(x @ up):
        if y @ up < 0:
            x, y = -x, -y
    elif x @ up < 0:
        x, y = -x, -y
    return contact, make_transform(np.stack([x, y, z], axis=1), contact), handle_found


def _front_plane(
    p: FloatArray, c: FloatArray, towards_hand: FloatArray, config: AffordanceConfig, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """The part's front around ``c``: the points within ``search_radius_m`` visible from the hand's
    side (m, 3), a point on their RANSAC plane (3,), its unit normal towards the hand (3,) and the
    plane's inliers (m,). With fewer than 3 points the plane faces the hand through ``c``."""
    near = p[np.linalg.norm(p - c, axis=1) < config.search_radius_m]
    front = near[_front_layer(near - c, towards_hand, config)]
    if len(front) < 3:
        return front, c, towards_hand / np.linalg.norm(towards_hand), np.ones(len(front), dtype=bool)
    origin, normal, inliers = _plane_ransac(front, config, rng)
    return front, origin, (normal if normal @ towards_hand >= 0 else -normal), inliers


def _front_layer(p: FloatArray, view: FloatArray, config: AffordanceConfig) -> BoolArray:
    """(N,) points (relative to a centre) within ``front_depth_m`` of the front-most point of
    their cell, seen along ``view`` (a z-buffer on a grid of ``front_cell_m`` cells)."""
    u = view / np.linalg.norm(view)
    e1 = np.cross(u, np.eye(3)[int(np.argmin(np.abs(u)))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    cells = np.floor(np.stack([p @ e1, p @ e2], axis=1) / config.front_cell_m).astype(np.int64)
    _, cell = np.unique(cells, axis=0, return_inverse=True)
    cell = cell.ravel()
    height = p @ u
    top = np.full(cell.max() + 1 if len(cell) else 0, -np.inf)
    np.maximum.at(top, cell, height)
    return height >= top[cell] - config.front_depth_m


def _plane_ransac(p: FloatArray, config: AffordanceConfig, rng: np.random.Generator) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Dominant plane of (N, 3) points: RANSAC on 3-point samples (all scored in one product),
    refitted by PCA on the inliers. Returns a point on it (3,), unit normal (3,), inliers (N,)."""
    sample = p[rng.integers(0, len(p), size=(config.plane_hypotheses, 3))]
    n = np.cross(sample[:, 1] - sample[:, 0], sample[:, 2] - sample[:, 0])
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-12
    if not ok.any():
        centre = p.mean(axis=0)
        normal = np.linalg.svd(p - centre)[2][2]
        return centre, normal, np.ones(len(p), dtype=bool)
    n = n[ok] / length[ok, None]
    distance = np.abs(np.einsum("knj,kj->kn", p[None] - sample[ok, 0][:, None], n))
    inliers = distance[int(np.argmax((distance < config.plane_tolerance_m).sum(axis=1)))] < config.plane_tolerance_m
    centre = p[inliers].mean(axis=0)
    normal = np.linalg.svd(p[inliers] - centre)[2][2]
    return centre, normal, inliers


def _nearest_handle(p: FloatArray, c: FloatArray, config: AffordanceConfig) -> FloatArray:
    """The handle among (N, 3) handle-height points: the piece (linked by distances below
    ``handle_link_m``, at least ``min_handle_points``) that comes nearest to ``c``, joined by the
    pieces lying along its axis when it is elongated (within ``handle_link_m`` of the line: one
    bar that the hand's hole in the fused part split). (0, 3) if there is none."""
    if len(p) < config.min_handle_points:
        return np.zeros((0, 3))
    pairs = cKDTree(p).query_pairs(config.handle_link_m, output_type="ndarray")
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(p), len(p)))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label)
    nearest = np.full(len(size), np.inf)
    np.minimum.at(nearest, label, np.linalg.norm(p - c, axis=1))
    nearest[size < config.min_handle_points] = np.inf
    if not np.isfinite(nearest).any():
        return np.zeros((0, 3))
    first = p[label == int(np.argmin(nearest))]
    centre, direction = first.mean(axis=0), _principal_direction(first)
    spread = np.linalg.eigvalsh(np.cov((first - centre).T)) if len(first) > 3 else np.zeros(3)
    if not spread[2] > config.handle_anisotropy**2 * spread[1]:
        return first  # a knob or a blob has no axis to extend along
    offset = p - centre
    off_axis = np.linalg.norm(offset - np.outer(offset @ direction, direction), axis=1)
    median_off_axis = np.full(len(size), np.inf)
    for piece in np.flatnonzero(size >= config.min_handle_points):
        median_off_axis[piece] = np.median(off_axis[label == piece])
    return p[median_off_axis[label] < config.handle_link_m]


def _principal_direction(p: FloatArray) -> FloatArray:
    """(3,) unit direction of the largest spread of (N, 3) points."""
    q = p - p.mean(axis=0)
    return np.linalg.eigh(q.T @ q)[1][:, 2]


def _handle_axis(part: ArticulatedPart, handle: FloatArray, front: FloatArray, z: FloatArray, config: AffordanceConfig) -> FloatArray:
    """(3,) unit grasp x axis orthogonal to ``z``: the handle's principal direction when it is
    elongated, else the joint axis (revolute) or the front's wider direction (prismatic)."""
    project = np.eye(3) - np.outer(z, z)

    def principal(p: FloatArray) -> tuple[FloatArray, float]:
        q = (p - p.mean(axis=0)) @ project
        values, vectors = np.linalg.eigh(q.T @ q)
        return vectors[:, 2], float(np.sqrt(values[2] / max(values[1], 1e-18)))

    if len(handle) >= 3:
        axis, ratio = principal(handle)
        if ratio > config.handle_anisotropy:
            return axis / np.linalg.norm(axis)
    axis = project @ part.axis_world if part.joint_type == "revolute" else np.zeros(3)
    if np.linalg.norm(axis) < 0.1 and len(front) >= 3:
        axis = principal(front)[0]
    if np.linalg.norm(axis) < 1e-6:
        axis = project @ np.eye(3)[int(np.argmin(np.abs(z)))]
    return axis / np.linalg.norm(axis)


# --------------------------------------------------------------------------------------------
# affordances.json
# --------------------------------------------------------------------------------------------


def affordances_to_json(affordances: Affordances) -> dict[str, Any]:
    """The affordances.json dictionary (see the module docstring)."""

    def rows(a: FloatArray) -> list[Any]:
        return np.asarray(a, dtype=np.float64).tolist()

    parts = []
    for p in affordances.parts:
        parts.append({
            "name": p.name,
            "joint_type": p.joint_type,
            "contact_point": rows(p.contact_point),
            "T_world_grasp": rows(p.T_world_grasp),
            "handle_found": bool(p.handle_found),
            "interactions": [
                {"frames": [int(f) for f in i.frames], "times_s": rows(i.times_s), "states": rows(i.states)} for i in p.interactions
            ],
            "contact_region": {"points": rows(p.region_points), "weights": rows(p.region_weights)},
            "contact_path": {"states": rows(p.path_states), "points": rows(p.path_points)},
        })
    return {
        "format": AFFORDANCES_FORMAT,
        "hand_source": affordances.hand_source,
        "fps": float(affordances.fps),
        "parts": parts,
        "missing": [{"name": name, "reason": reason} for name, reason in affordances.missing],
    }


def write_affordances(path: str | Path, affordances: Affordances) -> None:
    """Write affordances.json (a file path, or a twin folder to write it into)."""
    path = Path(path)
    if path.is_dir():
        path = path / AFFORDANCES_FILE
    path.write_text(json.dumps(affordances_to_json(affordances), indent=1) + "\n")


class _Reader:
    """Typed field access that raises FormatError naming the file and field (private)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> FormatError:
        return FormatError(self.path, f"{where} {problem}")

    def get(self, data: dict[str, Any], key: str, where: str) -> Any:
        if key not in data:
            raise self.fail(where, f"is missing '{key}'")
        return data[key]

    def array(self, value: Any, where: str, shape: tuple[int | None, ...]) -> FloatArray:
        """Finite float array of ``shape`` (None: any length)."""
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.fail(where, f"must be an array of numbers of shape {_shape_text(shape)}") from None
        if _contains_bool(value):
            raise self.fail(where, "must hold numbers, not booleans")
        if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
            raise self.fail(where, f"has shape {a.shape}, expected {_shape_text(shape)}")
        if not np.all(np.isfinite(a)):
            raise self.fail(where, "contains NaN or infinite values")
        return a


def _shape_text(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def _contains_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    return isinstance(value, list) and any(_contains_bool(v) for v in value)


def _interaction_from_json(r: _Reader, data: Any, where: str) -> Interaction:
    if not isinstance(data, dict):
        raise r.fail(where, "must be an object")
    frames = r.array(r.get(data, "frames", where), f"{where}.frames", (None,))
    if len(frames) == 0 or np.any(frames != np.round(frames)) or np.any(frames < 0) or np.any(np.diff(frames) <= 0):
        raise r.fail(f"{where}.frames", "must be non-empty increasing non-negative integers")
    times = r.array(r.get(data, "times_s", where), f"{where}.times_s", (len(frames),))
    states = r.array(r.get(data, "states", where), f"{where}.states", (len(frames),))
    return Interaction(frames.astype(np.int64), times, states)


def _part_from_json(r: _Reader, data: Any, where: str) -> PartAffordance:
    if not isinstance(data, dict):
        raise r.fail(where, "must be an object")
    name = r.get(data, "name", where)
    if not isinstance(name, str) or not name:
        raise r.fail(f"{where}.name", "must be a non-empty string")
    joint_type = r.get(data, "joint_type", where)
    if joint_type not in JOINT_TYPES:
        raise r.fail(f"{where}.joint_type", f"is {joint_type!r}, expected one of {list(JOINT_TYPES)}")
    contact = r.array(r.get(data, "contact_point", where), f"{where}.contact_point", (3,))
    try:
        T_world_grasp = check_transform(r.array(r.get(data, "T_world_grasp", where), f"{where}.T_world_grasp", (4, 4)), "T_world_grasp")
    except ValueError as exc:
        raise r.fail(f"{where}.T_world_grasp", f"is not a rigid transform ({exc})") from None
    handle_found = r.get(data, "handle_found", where)
    if not isinstance(handle_found, bool):
        raise r.fail(f"{where}.handle_found", "must be true or false")
    interactions_data = r.get(data, "interactions", where)
    if not isinstance(interactions_data, list) or not interactions_data:
        raise r.fail(f"{where}.interactions", "must be a non-empty list")
    interactions = tuple(_interaction_from_json(r, d, f"{where}.interactions[{i}]") for i, d in enumerate(interactions_data))
    region = r.get(data, "contact_region", where)
    path = r.get(data, "contact_path", where)
    if not isinstance(region, dict) or not isinstance(path, dict):
        raise r.fail(where, "contact_region and contact_path must be objects")
    region_points = r.array(r.get(region, "points", f"{where}.contact_region"), f"{where}.contact_region.points", (None, 3)) if region.get("points") else np.zeros((0, 3))
    region_weights = r.array(r.get(region, "weights", f"{where}.contact_region"), f"{where}.contact_region.weights", (len(region_points),))
    if np.any(region_weights <= 0) or np.any(region_weights > 1):
        raise r.fail(f"{where}.contact_region.weights", "must lie in (0, 1]")
    path_states = r.array(r.get(path, "states", f"{where}.contact_path"), f"{where}.contact_path.states", (None,))
    path_points = r.array(r.get(path, "points", f"{where}.contact_path"), f"{where}.contact_path.points", (len(path_states), 3)) if len(path_states) else np.zeros((0, 3))
    return PartAffordance(name, joint_type, contact, T_world_grasp, handle_found, interactions, region_points, region_weights, path_states, path_points)


def read_affordances(path: str | Path) -> Affordances:
    """Read and validate affordances.json (a file path, or a twin folder holding it).

    Raises:
        FormatError: missing file, bad JSON, wrong format tag, or a field of the wrong type,
            shape or value; the message names the file and the field.
    """
    path = Path(path)
    if path.is_dir():
        path = path / AFFORDANCES_FILE
    data = read_json_object(path)
    r = _Reader(path)
    if data.get("format") != AFFORDANCES_FORMAT:
        raise r.fail("format", f"is {data.get('format')!r}, expected {AFFORDANCES_FORMAT!r}")
    hand_source = r.get(data, "hand_source", "the file")
    if hand_source not in HAND_SOURCES:
        raise r.fail("hand_source", f"is {hand_source!r}, expected one of {list(HAND_SOURCES)}")
    fps = r.get(data, "fps", "the file")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps) or fps <= 0:
        raise r.fail("fps", f"must be a positive number, got {fps!r}")
    parts_data = r.get(data, "parts", "the file")
    missing_data = r.get(data, "missing", "the file")
    if not isinstance(parts_data, list) or not isinstance(missing_data, list):
        raise r.fail("parts and missing", "must be lists")
    parts = tuple(_part_from_json(r, d, f"parts[{k}]") for k, d in enumerate(parts_data))
    missing = []
    for k, d in enumerate(missing_data):
        if not isinstance(d, dict) or not isinstance(d.get("name"), str) or not isinstance(d.get("reason"), str):
            raise r.fail(f"missing[{k}]", "must be an object with string 'name' and 'reason'")
        missing.append((d["name"], d["reason"]))
    try:
        return Affordances(parts, tuple(missing), hand_source, float(fps))
    except ValueError as exc:
        raise r.fail("parts", str(exc)) from None


__all__ = [
    "AFFORDANCES_FILE",
    "AFFORDANCES_FORMAT",
    "AffordanceConfig",
    "Affordances",
    "Interaction",
    "PartAffordance",
    "PartSurface",
    "affordances_to_json",
    "find_affordances",
    "read_affordances",
    "write_affordances",
]
