"""A camera trajectory locked onto an opening drawer (the drawer filled the view, so the camera
tracker took it for the world) is detected from the part articulation finds, and undone."""

from __future__ import annotations

import numpy as np

from funrec.camera.tracking import CameraTrajectory
from funrec.geometry.joints import joint_transforms
from funrec.parts.articulation import estimate_articulation
from funrec.parts.camera_lock import unlock_camera
from funrec.parts.fragment_tracks import WindowTracks
from funrec.parts.point_tracks import PointTracks
from tests.helpers.track_scenes import make_scene


def _trajectory(T_world_camera: np.ndarray) -> CameraTrajectory:
    return CameraTrajectory(T_world_camera, np.zeros(0, dtype=np.int64), np.ones(len(T_world_camera), dtype=bool))


def _drawer_scene(seed: int = 3):
    """A drawer opening 0.35 m (then closing to 60 %) seen by a nearly still camera (3 mm steps);
    a small scene (40 frames, 80 drawer and 150 static tracks) keeps the three fits at ~5 s."""
    return make_scene(np.random.default_rng(seed), ("prismatic",), num_frames=40, part_tracks=80, static_tracks=150,
                      hand_tracks=15, max_states=(0.35,))


def test_a_camera_that_followed_the_drawer_is_held_still_and_the_drawer_found_again() -> None:
    scene = _drawer_scene()
    spec = scene.parts[0]
    # What a tracker locked onto the drawer estimates: the drawer still, the camera and the rest
    # of the scene moved by the drawer's inverse motion.
    T_locked_world = np.linalg.inv(joint_transforms(spec.joint_type, spec.axis, spec.pivot, spec.states))
    p_locked = np.einsum("fij,fnj->fni", T_locked_world[:, :3, :3], scene.tracks.p_world) + T_locked_world[:, None, :3, 3]
    tracks = PointTracks(p_locked, scene.tracks.uv, scene.tracks.visible)
    trajectory = _trajectory(T_locked_world @ scene.T_world_camera)
    windows = [WindowTracks(0, len(trajectory.T_world_camera) - 1, tracks)]
    found = estimate_articulation(tracks).interacted
    assert found is not None and len(np.intersect1d(found.track_indices, spec.track_indices)) == 0  # the scene as "part"

    unlocked = unlock_camera(trajectory, windows, [(0, found)])

    assert unlocked is not None
    corrected, moved = unlocked
    # The correction is the inverse of the fitted motion of 150 static tracks with 3 mm noise: its
    # error is ~1 mm; 1 cm allows for the drift of the state fit without admitting the 35 cm lock.
    error = np.linalg.norm(corrected.T_world_camera[:, :3, 3] - scene.T_world_camera[:, :3, 3], axis=1)
    assert error.max() < 0.01
    part = estimate_articulation(moved[0].tracks).interacted
    assert part is not None and part.joint_type == "prismatic"
    # Same tolerances as a drawer found under a correct camera (tests/test_articulation.py): 3 deg
    # of axis, 2 cm of travel.
    assert np.degrees(np.arccos(min(1.0, abs(float(part.axis_world @ spec.axis))))) < 3.0
    assert abs(np.ptp(part.states) - np.ptp(spec.states)) < 0.02


def test_a_correct_camera_is_left_alone() -> None:
    scene = _drawer_scene()
    trajectory = _trajectory(scene.T_world_camera)
    found = estimate_articulation(scene.tracks).interacted
    assert found is not None
    assert unlock_camera(trajectory, [WindowTracks(0, len(scene.T_world_camera) - 1, scene.tracks)], [(0, found)]) is None
