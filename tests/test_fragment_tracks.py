"""Per-fragment point tracks: sub-captures, sub-trajectories and joined windows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, load_capture
from funrec.parts.fragment_tracks import WindowTracks, join_windows, sub_capture, sub_trajectory
from funrec.parts.point_tracks import PointTracks


def _tracks(frame_count: int, track_count: int, value: float) -> PointTracks:
    p = np.full((frame_count, track_count, 3), value)
    return PointTracks(p, np.zeros((frame_count, track_count, 2)), np.ones((frame_count, track_count), bool))


def test_sub_capture_reads_the_frames_of_its_span(tmp_path: Path) -> None:
    writer = CaptureWriter(tmp_path, CaptureIntrinsics(8, 6, 10.0, 10.0, 3.5, 2.5))
    for f in range(10):
        writer.write_frame(f, np.full((6, 8, 3), 10 * f, np.uint8), np.full((6, 8), 1.0 + 0.1 * f), hand_mask=np.eye(6, 8, f % 3) > 0)
    capture = load_capture(tmp_path)
    part = sub_capture(capture, 4, 7)
    assert len(part) == 4
    for i in range(4):
        np.testing.assert_array_equal(part.rgb(i), capture.rgb(4 + i))
        np.testing.assert_array_equal(part.depth_m(i), capture.depth_m(4 + i))
        np.testing.assert_array_equal(part.mask("hand", i), capture.mask("hand", 4 + i))


def test_sub_trajectory_shifts_keyframes() -> None:
    T = np.tile(np.eye(4), (10, 1, 1))
    T[:, 0, 3] = np.arange(10)
    trajectory = CameraTrajectory(T, np.array([0, 3, 6, 9]), np.ones(10, bool), np.arange(10))
    part = sub_trajectory(trajectory, 3, 7)
    np.testing.assert_array_equal(part.T_world_camera[:, 0, 3], [3, 4, 5, 6, 7])
    np.testing.assert_array_equal(part.keyframes, [0, 3])
    np.testing.assert_array_equal(part.inliers, [3, 4, 5, 6, 7])


def test_join_windows_places_each_window_in_its_frames() -> None:
    a = WindowTracks(10, 14, _tracks(5, 3, 1.0))
    b = WindowTracks(30, 33, _tracks(4, 2, 2.0))
    joined, offsets = join_windows([a, b])
    assert (joined.first, joined.last, offsets) == (10, 33, [0, 3])
    assert joined.tracks.p_world.shape == (24, 5, 3)
    assert joined.tracks.visible[0:5, :3].all() and not joined.tracks.visible[5:, :3].any()
    assert joined.tracks.visible[20:24, 3:].all() and not joined.tracks.visible[:20, 3:].any()
    np.testing.assert_array_equal(joined.tracks.p_world[20, 3:], 2.0)
    assert np.isnan(joined.tracks.p_world[10]).all()  # between the windows: nothing tracked


def test_window_tracks_must_cover_their_frames() -> None:
    with pytest.raises(ValueError, match="need 5 track frames"):
        WindowTracks(10, 14, _tracks(4, 1, 0.0))
