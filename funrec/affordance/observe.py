"""The part surface around a contact, completed from frames in which the hand does not hide it
(before the grasp, after the release), kept inside the part's outline.
"""

from __future__ import annotations

import cv2
import numpy as np

from funrec.affordance.handle import front_plane
from funrec.affordance.types import REFERENCE_WIDTH_PX, AffordanceConfig
from funrec.camera.tracking import CameraTrajectory
from funrec.formats.affordances import Interaction
from funrec.formats.capture import Capture
from funrec.formats.twin import ArticulatedPart
from funrec.geometry.camera import backproject
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.surfaces.hands import HandMasks, part_poses
from funrec.typed import BoolArray, FloatArray, IntArray

_HAND_MARGIN_PX = 5
"""Hand masks are grown by this many pixels (at 640 px width) before observing the part around
them: mask outlines are imprecise and edge depth mixes hand and part."""


def inside_footprint(
    p_seen: FloatArray, p_part: FloatArray, c: FloatArray, towards_hand: FloatArray, config: AffordanceConfig, rng: np.random.Generator
) -> BoolArray:
    """(n,) observed points that lie inside the part's outline: seen along the normal of the
    part's front plane near ``c``, in a cell of the part points' occupancy grid after a closing
    of ``observe_fill_m`` (which fills the hole the hand left), and within the handle height."""
    _, origin, normal, _ = front_plane(p_part, c, towards_hand, config, rng)
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



def observed_surface(
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
    them (see :func:`inside_footprint`)."""
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
    margin = max(1, round(_HAND_MARGIN_PX * W / REFERENCE_WIDTH_PX))
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



__all__ = ["inside_footprint", "observed_surface"]
