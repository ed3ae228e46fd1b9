"""Point tracks per dynamic fragment: each fragment (with some context) is tracked on its own, as
the paper does, so a long walk never exhausts the track budget before its last interaction and
its static stretches are not tracked at all; a part seen in several fragments gets their tracks
joined over its whole span.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from funrec.camera.tracking import CameraTrajectory
from funrec.formats.capture import Capture
from funrec.parts.point_tracks import PointTrackConfig, PointTracks, track_points
from funrec.typed import IntArray


@dataclass(frozen=True)
class WindowTracks:
    """Point tracks of a span of consecutive frames; their frame i is capture frame first + i."""

    first: int
    """First capture frame (inclusive)."""
    last: int
    """Last capture frame (inclusive)."""
    tracks: PointTracks
    """Tracks over the last - first + 1 frames of the span, world frame."""

    def __post_init__(self) -> None:
        if self.tracks.num_frames != self.last - self.first + 1:
            raise ValueError(f"frames {self.first}-{self.last} need {self.last - self.first + 1} track frames, "
                             f"got {self.tracks.num_frames}")


def sub_capture(capture: Capture, first: int, last: int) -> Capture:
    """The capture restricted to frames first..last (inclusive); its frame i is frame first + i."""
    span = slice(first, last + 1)
    known = capture.T_world_camera_known
    return dataclasses.replace(
        capture,
        stems=capture.stems[span],
        rgb_paths=capture.rgb_paths[span],
        depth_paths=capture.depth_paths[span],
        mask_paths={kind: paths[span] for kind, paths in capture.mask_paths.items()},
        T_world_camera_known=None if known is None else known[span],
    )


def sub_trajectory(trajectory: CameraTrajectory, first: int, last: int) -> CameraTrajectory:
    """The camera poses of frames first..last (inclusive), frame indices shifted by -first."""
    span = slice(first, last + 1)
    keys = np.asarray(trajectory.keyframes)
    keys = keys[(keys >= first) & (keys <= last)] - first
    inliers = trajectory.inliers[span] if len(trajectory.inliers) else trajectory.inliers
    return CameraTrajectory(trajectory.T_world_camera[span], keys.astype(np.int64), trajectory.tracked[span], inliers)


def track_window(
    capture: Capture,
    trajectory: CameraTrajectory,
    first: int,
    last: int,
    config: PointTrackConfig = PointTrackConfig(),  # noqa: B008 (frozen, immutable default)
    progress: Callable[[int, int], None] | None = None,
) -> WindowTracks:
    """Point tracks (:func:`funrec.parts.point_tracks.track_points`) of frames first..last only."""
    tracks = track_points(sub_capture(capture, first, last), sub_trajectory(trajectory, first, last), config, progress)
    return WindowTracks(first, last, tracks)


def join_windows(windows: Sequence[WindowTracks]) -> tuple[WindowTracks, list[int]]:
    """One span from the first window's first frame to the last window's last frame holding every
    window's tracks side by side (invisible outside their own window).

    Returns:
        The joined tracks and, per window, the index of its first track in them.
    """
    first, last = min(w.first for w in windows), max(w.last for w in windows)
    F = last - first + 1
    total = sum(w.tracks.num_tracks for w in windows)
    p_world, uv = np.full((F, total, 3), np.nan), np.full((F, total, 2), np.nan)
    visible = np.zeros((F, total), dtype=bool)
    offsets, offset = [], 0
    for w in windows:
        rows, cols = slice(w.first - first, w.last - first + 1), slice(offset, offset + w.tracks.num_tracks)
        p_world[rows, cols], uv[rows, cols], visible[rows, cols] = w.tracks.p_world, w.tracks.uv, w.tracks.visible
        offsets.append(offset)
        offset += w.tracks.num_tracks
    return WindowTracks(first, last, PointTracks(p_world, uv, visible)), offsets


def global_indices(offsets: Sequence[int], track_indices: Sequence[IntArray]) -> IntArray:
    """Track indices of several windows in their joined tracks (see :func:`join_windows`)."""
    return np.concatenate([offset + np.asarray(t, dtype=np.int64) for offset, t in zip(offsets, track_indices, strict=True)])


__all__ = ["WindowTracks", "global_indices", "join_windows", "sub_capture", "sub_trajectory", "track_window"]
