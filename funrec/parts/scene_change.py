"""Dense evidence of scene change that the camera motion does not explain: the fraction of depth
pixels of one frame that the frame a few steps later sees through (free-space violations).

A static surface seen in frame a and reprojected into frame b with the camera poses lands on a
pixel whose depth is at most its own depth (the same surface, or something in front of it from
b's viewpoint). Where b sees farther than the reprojected point, that surface has left: a part
swung or slid away, or the hand moved. Tested both ways, a part moving towards the camera shows
up too. Unlike point tracks, this does not fade when a door turns edge-on and its tracks die.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from funrec.formats.capture import Capture
from funrec.typed import BoolArray, FloatArray

_NO_DEPTH = 1e3
"""Stand-in depth (m) of missing readings inside the min filter: farther than any sensor reads."""


@dataclass(frozen=True)
class SceneChangeConfig:
    """Settings of :func:`scene_change`; lengths in metres."""

    work_width_px: int = 160
    """Images are subsampled to about this width (nearest pixel, never upsampled): a part that
    moves covers hundreds of pixels even at 160 px, and the test stays ~10 ms per frame pair."""
    lag_frames: int = 3
    """Frames between the two frames of a pair: 0.2 s at 15 fps, over which an opening part moves
    by centimetres (a door turning 4 deg per frame moves its handle ~8 cm)."""
    margin_m: float = 0.03
    """A reprojected point is seen through when the other frame's depth there exceeds its depth by
    this plus ``margin_per_m`` times the depth: several sigma of Kinect-class noise (~3 mm at 1 m)
    plus ~1-2 cm of camera pose error."""
    margin_per_m: float = 0.03
    """Depth-proportional part of the margin, metres per metre (axial noise and pose error grow
    with distance)."""
    min_depth_m: float = 0.2
    """Readings closer than this are ignored (sensor minimum range)."""
    max_depth_m: float = 4.0
    """Readings farther than this are ignored: noise there exceeds the margin."""
    hand_dilation_px: int = 2
    """Hand masks (at the work resolution) are grown by this many pixels before their pixels are
    left out: a moving hand is not a moving part."""


def _subsample(image: np.ndarray, step: int) -> np.ndarray:
    return image[step // 2 :: step, step // 2 :: step]


def scene_change(
    capture: Capture,
    T_world_camera: FloatArray,
    config: SceneChangeConfig = SceneChangeConfig(),  # noqa: B008 (frozen, immutable default)
    progress: Callable[[int, int], None] | None = None,
) -> FloatArray:
    """Per frame i, the fraction of tested pixels of frames i and i + lag whose surface the other
    frame sees through (both directions pooled), hand pixels left out.

    Frames are streamed once; memory holds ``lag_frames + 1`` subsampled depth images.

    Args:
        capture: the RGB-D capture (its hand masks are used when present).
        T_world_camera: (F, 4, 4) camera poses.
        config: settings.
        progress: optional ``progress(done, total)`` after each frame.

    Returns:
        (F,) fractions in [0, 1]; 0 for the last ``lag_frames`` frames.
    """
    F = len(capture)
    if np.shape(T_world_camera) != (F, 4, 4):
        raise ValueError(f"T_world_camera must be ({F}, 4, 4), got {np.shape(T_world_camera)}")
    step = max(1, capture.intrinsics.width // config.work_width_px)
    K = capture.intrinsics.K.astype(np.float64).copy()
    K[:2, 2] -= step // 2  # subsampled pixel j is full-resolution pixel step // 2 + j * step
    K[:2, :] /= step
    kernel = np.ones((3, 3), np.uint8)
    lag = config.lag_frames
    views: dict[int, tuple[FloatArray, FloatArray, BoolArray]] = {}
    out = np.zeros(F)
    for frame in range(F):
        depth = _subsample(capture.depth_m(frame), step).astype(np.float64)
        valid = (depth > config.min_depth_m) & (depth < config.max_depth_m)
        hand = capture.mask("hand", frame) if capture.has_hand_masks else None
        if hand is not None:
            hand = cv2.dilate(_subsample(hand, step).astype(np.uint8), kernel, iterations=config.hand_dilation_px) > 0
            valid &= ~hand
        # Min filter: a point reprojected next to a depth edge is compared with the nearest
        # surface around it, so pose error at silhouettes does not count as seeing through.
        near = cv2.erode(np.where(valid, depth, _NO_DEPTH).astype(np.float32), kernel).astype(np.float64)
        views[frame] = (depth, near, valid)
        views.pop(frame - lag - 1, None)
        if frame >= lag:
            a, b = frame - lag, frame
            seen_through, tested = 0, 0
            for src, dst in ((a, b), (b, a)):
                s, n = _violations(views[src], views[dst], np.linalg.inv(T_world_camera[dst]) @ T_world_camera[src], K, config)
                seen_through, tested = seen_through + s, tested + n
            out[a] = seen_through / max(tested, 1)
        if progress is not None:
            progress(frame + 1, F)
    return out


def _violations(source: tuple[FloatArray, FloatArray, BoolArray], target: tuple[FloatArray, FloatArray, BoolArray],
                T_target_source: FloatArray, K: FloatArray, config: SceneChangeConfig) -> tuple[int, int]:
    """(seen through, tested) counts of the source's valid pixels reprojected into the target."""
    depth, _, valid = source
    _, near, target_valid = target
    h, w = depth.shape
    v, u = np.nonzero(valid)
    z = depth[v, u]
    p_source = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    p_target = np.einsum("ij,nj->ni", T_target_source[:3, :3], p_source) + T_target_source[:3, 3]
    z_target = p_target[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        u_t = np.rint(K[0, 0] * p_target[:, 0] / z_target + K[0, 2])
        v_t = np.rint(K[1, 1] * p_target[:, 1] / z_target + K[1, 2])
    inside = (z_target > config.min_depth_m) & (u_t >= 0) & (u_t < w) & (v_t >= 0) & (v_t < h)
    rows, cols = v_t[inside].astype(np.int64), u_t[inside].astype(np.int64)
    tested = target_valid[rows, cols] & (near[rows, cols] < _NO_DEPTH)
    z_in = z_target[inside][tested]
    margin = config.margin_m + config.margin_per_m * z_in
    seen_through = near[rows, cols][tested] > z_in + margin
    return int(np.count_nonzero(seen_through)), int(np.count_nonzero(tested))


__all__ = ["SceneChangeConfig", "scene_change"]
