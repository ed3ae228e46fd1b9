"""Poses of the hand proxy over a sequence: reach from a rest pose at the side of the body,
approach and close on the handle, follow it while the joint moves, back off, withdraw.

The grasp frame (see ``hand.py``) is rigidly attached to the handle while the hand holds it,
so the hand stays exactly on the handle whatever the joint does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from funrec.geometry.transforms import make_transform
from funrec.synth.hand import FINGER_REACH, WRIST_IN_GRASP
from funrec.synth.timeline import Timeline
from funrec.typed import FloatArray

if TYPE_CHECKING:
    from funrec.synth.part_geometry import PartGeometry

HIDDEN_M = np.array([0.0, 0.0, -10.0])
"""Where the hand proxy waits when not in use (under the floor), metres."""
PREGRASP_M = 0.1
"""Distance in front of the handle where the reach ends and the approach starts, metres."""
HANDLE_CLEARANCE_M = 0.003
"""Gap kept between the curled fingers and the front surface, metres."""
_UP = np.array([0.0, 0.0, 1.0])


def _ramp(t: float, t0: float, t1: float) -> float:
    s = min(max((t - t0) / max(t1 - t0, 1e-9), 0.0), 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def shoulder(T_world_camera: FloatArray, side: float) -> FloatArray:
    """(3,) shoulder position for a camera pose (4, 4): beside and below the eyes, a little behind.

    Args:
        T_world_camera: (4, 4) camera-to-world (OpenCV).
        side: +1 for the right shoulder, -1 for the left.
    """
    forward = T_world_camera[:3, 2].copy()
    forward[2] = 0.0
    forward /= max(np.linalg.norm(forward), 1e-9)
    right = np.cross(forward, _UP)
    return T_world_camera[:3, 3] + side * 0.18 * right - 0.25 * _UP - 0.05 * forward


def _rest(T_world_camera: FloatArray, side: float) -> FloatArray:
    """(3,) hand position hanging at the side of the body, out of view."""
    forward = T_world_camera[:3, 2].copy()
    forward[2] = 0.0
    forward /= max(np.linalg.norm(forward), 1e-9)
    return shoulder(T_world_camera, side) - 0.5 * _UP + 0.1 * forward


def grasp_pose(part: PartGeometry, p_world_shoulder: FloatArray) -> FloatArray:
    """(4, 4) T_world_grasp on the part's handle at the canonical state.

    The grasp z points into the front, x runs along the bar with its sign chosen so that the
    fingers (grasp y) point away from the shoulder, and the grasp point moves out of the front
    when the handle stands too close to it for the curled fingers.
    """
    z = -part.normal
    x = part.grip_axis / np.linalg.norm(part.grip_axis)
    p = part.handle + part.normal * max(0.0, FINGER_REACH + HANDLE_CLEARANCE_M - part.handle_standoff)
    if np.cross(z, x) @ (p - p_world_shoulder) < 0.0:
        x = -x
    return make_transform(np.stack([x, np.cross(z, x), z], axis=1), p)


def _forearm(T_world_grasp: FloatArray, p_world_shoulder: FloatArray) -> FloatArray:
    """(4, 4) T_world_forearm: origin at the wrist, z towards the shoulder."""
    wrist = T_world_grasp[:3, :3] @ WRIST_IN_GRASP + T_world_grasp[:3, 3]
    z = p_world_shoulder - wrist
    z /= max(np.linalg.norm(z), 1e-9)
    x = np.cross(z, _UP)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return make_transform(np.stack([x, np.cross(z, x), z], axis=1), wrist)


def hand_trajectory(
    timeline: Timeline, parts: tuple[PartGeometry, ...], states: FloatArray, T_world_camera: FloatArray, t: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Hand and forearm poses at every frame.

    Args:
        timeline: the schedule of the interactions.
        parts: part geometry at the canonical state.
        states: (P, F) joint states.
        T_world_camera: (F, 4, 4) camera poses (the shoulder moves with the head).
        t: (F,) frame times, seconds.

    Returns:
        T_world_grasp (F, 4, 4) and T_world_forearm (F, 4, 4); both hidden under the floor
        when the hand is not in use.
    """
    frames = len(t)
    hidden = make_transform(np.eye(3), HIDDEN_M)
    T_world_grasp = np.repeat(hidden[None], frames, axis=0)
    T_world_forearm = T_world_grasp.copy()
    for hold in timeline.holds:
        part = parts[hold.part]
        f_grasp = min(frames - 1, int(round(hold.t_grasp * (frames / timeline.duration))))
        T_cam = T_world_camera[f_grasp]
        side = 1.0 if (part.handle - T_cam[:3, 3]) @ T_cam[:3, 0] > -0.1 else -1.0
        T_canonical = grasp_pose(part, shoulder(T_cam, side))
        R = T_canonical[:3, :3]
        p_grasp = T_canonical[:3, 3]
        p_pre = p_grasp + part.normal * PREGRASP_M
        T_parts = part.poses(states[hold.part])
        for f in np.flatnonzero((t >= hold.t_reach) & (t <= hold.t_clear)):
            now = t[f]
            rest = _rest(T_world_camera[f], side)
            if now < hold.t_approach:
                T = make_transform(R, rest + (p_pre - rest) * _ramp(now, hold.t_reach, hold.t_approach))
            elif now < hold.t_grasp:
                T = make_transform(R, p_pre + (p_grasp - p_pre) * _ramp(now, hold.t_approach, hold.t_grasp))
            else:
                T = T_parts[f] @ T_canonical  # rigidly on the handle (constant after the release)
                back = T[:3, 3] - T[:3, 2] * PREGRASP_M * _ramp(now, hold.t_release, hold.t_back)
                if now > hold.t_back:
                    back = back + (rest - back) * _ramp(now, hold.t_back, hold.t_clear)
                T = make_transform(T[:3, :3], back)
            T_world_grasp[f] = T
            T_world_forearm[f] = _forearm(T, shoulder(T_world_camera[f], side))
    return T_world_grasp, T_world_forearm


__all__ = ["HANDLE_CLEARANCE_M", "HIDDEN_M", "PREGRASP_M", "grasp_pose", "hand_trajectory", "shoulder"]
