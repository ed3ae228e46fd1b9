"""A camera trajectory that followed the interacted part instead of the static scene: detected
from the parts found in the dynamic fragments, and undone.

When a moving part fills most of the view (a sliding wardrobe door seen from close by) and no
object mask tells it apart, the rigid RANSAC of camera tracking takes the part for the world:
the estimated camera moves with the part, the part stands still in the estimated world, and
articulation finds the static scene moving the opposite way as one large "part". Inside the
interaction both explanations fit the pixels equally (two rigid bodies moving relative to each
other); what tells them apart is the person. While someone opens a door or a drawer, the camera
on their head stays nearly still in the world, and it does not move in lock-step with the part
(bench ground truth: the camera travels at most 4.3 cm while any part moves, and 0.27-2 m
relative to the part). So a found part relative to which the camera stays still, while the camera
travels in the estimated world, is the static scene; the camera poses are corrected by that
"part's" inverse motion (nothing changes before it moves; after it, the last correction holds)
and the window tracks with them, and the caller looks for the part again.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from funrec.camera.tracking import CameraTrajectory
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform
from funrec.parts.articulation import PartEstimate
from funrec.parts.fragment_tracks import WindowTracks
from funrec.parts.point_tracks import PointTracks
from funrec.typed import FloatArray

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraLockConfig:
    """When the camera trajectory is taken to have followed a found part (lengths in metres)."""

    enabled: bool = True
    """Look for locks and undo them; off: the camera tracker's trajectory as it is (ablation)."""
    min_camera_motion_m: float = 0.10
    """The camera must travel at least this far (largest distance from where it was when the part
    started moving) in the estimated world while the part moves: over twice the largest travel
    of the camera while a part of the synthetic bench moves (4.3 cm)."""
    rest_fraction: float = 0.05
    """The part is at rest where its state is within this fraction of its range of its first (or
    last) state: only the camera's travel while the part moves counts (a person walks up to a
    cabinet before opening it, and away after)."""
    still_fraction: float = 0.25
    """A camera that travels less than this fraction of its travel in the world relative to the
    part (while the part moves) followed the part. Measured on the ground truth of the 26 parts
    of the synthetic bench (while each moves): the camera travels 4-43 mm in the world and
    18-300x farther relative to the part, while the camera locked onto pri_wardrobe_01's sliding
    door travelled 0.53 m in the estimated world and 2 cm relative to the "part" the static
    scene became."""


def _moving(states: FloatArray, rest_fraction: float) -> slice:
    """The part's frames from the last one at rest before it moves (state within ``rest_fraction``
    of its range of the first state) to the first one at rest after it (same, of the last state):
    the camera may walk before and after an interaction, not while the part moves."""
    tolerance = rest_fraction * np.ptp(states)
    left = np.flatnonzero(np.abs(states - states[0]) > tolerance)
    right = np.flatnonzero(np.abs(states - states[-1]) > tolerance)
    if len(left) == 0 or len(right) == 0:
        return slice(0, len(states))
    return slice(max(left[0] - 1, 0), right[-1] + 2)


def _centre_travel(T_world_camera: FloatArray) -> float:
    """Largest distance (m) of the camera centre from its first position."""
    centres = T_world_camera[:, :3, 3]
    return float(np.linalg.norm(centres - centres[0], axis=1).max()) if len(centres) else 0.0


def lock_correction(
    part: PartEstimate,
    T_world_camera: FloatArray,
    config: CameraLockConfig = CameraLockConfig(),  # noqa: B008 (frozen, immutable default)
) -> FloatArray | None:
    """The correction of a camera trajectory that followed ``part``, or None if it did not.

    Args:
        part: a part found in a window, frames local to the window.
        T_world_camera: (F_w, 4, 4) camera poses of the window's frames.
        config: thresholds.

    Returns:
        (F_w, 4, 4) ``T_world_world`` per window frame: identity before the part's first frame,
        the inverse of its motion from its first state on its frames and the last one after them;
        ``correction @ T_world_camera`` holds the camera still where the part was the static scene.
    """
    frames = part.frames
    T_world_partmoved = joint_transforms(part.joint_type, part.axis_world, part.pivot_world, part.states - part.states[0])
    inverse = invert_transform(T_world_partmoved)
    moving = _moving(part.states, config.rest_fraction)
    world = _centre_travel(T_world_camera[frames[moving]])
    relative = _centre_travel((inverse @ T_world_camera[frames])[moving])
    locked = world >= config.min_camera_motion_m and relative <= config.still_fraction * world
    logger.info("%s part over frames %d-%d: camera travels %.3f m in the world, %.3f m relative to the part%s",
                part.joint_type, frames[0], frames[-1], world, relative, ": camera locked onto it" if locked else "")
    if not locked:
        return None
    correction = np.tile(np.eye(4), (len(T_world_camera), 1, 1))
    correction[frames] = inverse
    correction[frames[-1] + 1 :] = inverse[-1]
    return correction


def _moved_tracks(tracks: PointTracks, correction: FloatArray) -> PointTracks:
    """The tracks with frame i's world points moved by ``correction[i]`` ((F, N, 3), NaN where not visible)."""
    p_world = np.einsum("fij,fnj->fni", correction[:, :3, :3], tracks.p_world) + correction[:, None, :3, 3]
    return dataclasses.replace(tracks, p_world=p_world)


def unlock_camera(
    trajectory: CameraTrajectory,
    windows: Sequence[WindowTracks],
    found: Sequence[tuple[int, PartEstimate]],
    config: CameraLockConfig = CameraLockConfig(),  # noqa: B008 (frozen, immutable default)
) -> tuple[CameraTrajectory, list[WindowTracks]] | None:
    """The trajectory and window tracks with every camera lock of the found parts undone.

    Args:
        trajectory: camera poses of the capture.
        windows: tracked window of each dynamic fragment, in time order.
        found: (window index, part) of the parts found, frames local to their window.
        config: thresholds.

    Returns:
        None when no found part is a lock (:func:`lock_correction`); otherwise the corrected
        trajectory and windows. Locks of later windows were measured in a world already moved by
        the earlier ones, so the corrections compose in time order.
    """
    if not config.enabled:
        return None
    F = len(trajectory.T_world_camera)
    correction = np.tile(np.eye(4), (F, 1, 1))
    locked = False
    for k, part in sorted(found, key=lambda item: windows[item[0]].first):
        window = windows[k]
        local = lock_correction(part, trajectory.T_world_camera[window.first : window.last + 1], config)
        if local is None:
            continue
        locked = True
        capture_correction = np.tile(np.eye(4), (F, 1, 1))
        capture_correction[window.first : window.last + 1] = local
        capture_correction[window.last + 1 :] = local[-1]
        correction = correction @ capture_correction
    if not locked:
        return None
    unlocked = dataclasses.replace(trajectory, T_world_camera=correction @ trajectory.T_world_camera)
    moved = [dataclasses.replace(w, tracks=_moved_tracks(w.tracks, correction[w.first : w.last + 1])) for w in windows]
    return unlocked, moved


__all__ = ["CameraLockConfig", "lock_correction", "unlock_camera"]
