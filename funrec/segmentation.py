"""Pixel-aligned part segmentation (paper: "Pixel-aligned part segmentation"): per-frame masks
of an articulated part from its moving tracks and poses, with classical vision in place of SAM/SAM2.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from skimage.segmentation import felzenszwalb

from funrec.capture import Capture
from funrec.errors import ReconstructionError
from funrec.geometry.camera import backproject
from funrec.geometry.transforms import check_transform, invert_transform
from funrec.point_tracks import PointTracks
from funrec.tracking import CameraTrajectory, Progress
from funrec.typed import BoolArray, Float32Array, FloatArray, IntArray, UInt8Array

logger = logging.getLogger(__name__)

@dataclass(frozen=True)
class SegmentationConfig:
    """Settings of :func:`segment_parts`; defaults suit 640x480 Kinect-like RGB-D at 0.5-3 m."""

    keyframe_count: int = 8
    """Q keyframes spread uniformly over the part's frames (paper: uniform keyframes)."""
    segment_width_px: int = 320
    """Keyframes are over-segmented at this image width (never upsampled): felzenszwalb costs
    ~0.8 s at 640x480 and ~0.15 s at 320x240, and regions are far larger than 2 px anyway."""
    colour_weight: float = 1.0
    """Feature units per CIELAB unit in the over-segmentation."""
    depth_edge_weight: float = 30.0
    """Feature units of a depth discontinuity (see ``depth_edge_relative``). Raw depth is not a
    feature: felzenszwalb cuts depth ramps (floors seen at a slant) into bands."""
    depth_edge_relative: float = 0.01
    """A depth step between neighbouring pixels of this fraction of the depth (1 cm at 1 m, ~4
    sigma of Kinect-like noise) gets the full ``depth_edge_weight``; smaller steps scale down."""
    normal_weight: float = 20.0
    """Feature units per unit of normal difference (a 90 degree crease is ~28 units)."""
    segment_scales: tuple[float, ...] = (500.0, 3000.0)
    """Felzenszwalb scale k of each over-segmentation, fine to coarse (larger: bigger regions;
    feature units times pixels). Each pixel takes the motion ratio of the finest region around
    it that holds a track, as SAM's multi-granularity masks would; a pixel whose regions hold no
    track at any scale is unknown and casts no vote in the part model."""
    segment_sigma_px: float = 1.0
    """Gaussian pre-smoothing of the feature image, pixels at ``segment_width_px``."""
    segment_min_size_px: int = 100
    """Smallest over-segmentation region, pixels at ``segment_width_px`` (scaled with the area
    when the image is narrower)."""
    motion_ratio_threshold: float = 0.5
    """eta_m: a region is part when n_m / (n_m + n_s + eps) exceeds it (paper)."""
    motion_ratio_eps: float = 0.5
    """eps of the motion ratio: avoids division by zero, and with eta_m = 0.5 a region holding a
    single moving track and no static one still counts as part (1 / 1.5 > 0.5)."""
    voxel_m: float = 0.004
    """Voxel edge of the canonical part model, metres: 4 mm is ~2 px at 1 m with fx ~ 525,
    so the propagated boundary is within ~1 px of the keyframe evidence."""
    depth_tolerance_m: float = 0.02
    """tau: observed and predicted depth agree when closer than this. Kinect-like noise is
    sigma ~ 5 mm at 2 m, so 4 sigma, which also absorbs ~5 mm of pose error."""
    min_vote_ratio: float = 0.5
    """A model voxel is kept when part votes / all votes over the keyframes exceed this; votes
    against are keyframes that see the voxel's place as static surface or as free space."""
    hand_margin_px: int = 4
    """Hand masks are dilated by this many pixels before exclusion: depth is worst at edges."""
    fill_missing_depth: bool = True
    """Pixels without depth inside the predicted part silhouette join the mask when surrounded
    by mask pixels (a morphological closing); the true mask does not depend on depth dropouts."""


@dataclass(frozen=True)
class PartMasks:
    """Per-frame masks of one articulated part, stored PNG-encoded so a long video never holds
    (F_k, H, W) arrays; the bytes are exactly the files of FORMATS.md masks/part_k/."""

    frames: IntArray
    """(F_k,) frame indices (capture order) with a mask."""
    png: tuple[bytes, ...]
    """(F_k,) 8-bit single-channel PNG of each mask (255 = part, 0 = not)."""
    height: int
    """Image height H in pixels."""
    width: int
    """Image width W in pixels."""
    keyframes: IntArray
    """(Q,) frame indices whose over-segmentation built the part model (empty if none)."""

    def __post_init__(self) -> None:
        if np.ndim(self.frames) != 1 or len(self.png) != len(self.frames):
            raise ValueError(f"frames must be (F_k,) with one PNG each, got {np.shape(self.frames)} and {len(self.png)}")

    def __len__(self) -> int:
        return len(self.frames)

    def mask(self, index: int) -> BoolArray:
        """(H, W) bool mask at position ``index`` of :attr:`frames` (not a frame number)."""
        return decode_mask(self.png[index])

    def __iter__(self) -> Iterator[tuple[int, BoolArray]]:
        """Yield ``(frame, mask)`` one mask at a time."""
        for index, frame in enumerate(self.frames):
            yield int(frame), self.mask(index)

    @classmethod
    def from_masks(cls, frames: npt.ArrayLike, masks: npt.ArrayLike, keyframes: npt.ArrayLike = ()) -> PartMasks:
        """Build from in-memory (F_k, H, W) bool masks (tests, learned segmenters)."""
        masks = np.asarray(masks, dtype=bool)
        if masks.ndim != 3:
            raise ValueError(f"masks must be (F_k, H, W), got {masks.shape}")
        return cls(np.asarray(frames, dtype=np.int64), tuple(encode_mask(m) for m in masks), masks.shape[1],
                   masks.shape[2], np.asarray(keyframes, dtype=np.int64))


def encode_mask(mask: npt.ArrayLike) -> bytes:
    """(H, W) bool mask to 8-bit PNG bytes (255 = inside); fast compression (~1 ms)."""
    ok, buffer = cv2.imencode(".png", np.asarray(mask, dtype=np.uint8) * 255, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    assert ok
    return buffer.tobytes()


def decode_mask(png: bytes) -> BoolArray:
    """8-bit PNG bytes to an (H, W) bool mask (>0 = inside)."""
    return cv2.imdecode(np.frombuffer(png, dtype=np.uint8), cv2.IMREAD_GRAYSCALE) > 0


def segment_parts(
    capture: Capture,
    trajectory: CameraTrajectory,
    tracks: PointTracks,
    moving: npt.ArrayLike,
    frames: npt.ArrayLike,
    T_world_part: npt.ArrayLike,
    config: SegmentationConfig = SegmentationConfig(),
    progress: Progress | None = None,
    static: npt.ArrayLike | None = None,
) -> PartMasks:
    """Pixel-accurate masks of one articulated part in every frame it is tracked in.

    Keyframes are over-segmented (felzenszwalb, two scales) on colour, normals and depth
    discontinuities; a region is part when the ratio
    of moving to static tracks in it exceeds ``eta_m``. Keyframe part pixels are lifted into the
    canonical part frame (``T_part_camera = inv(T_world_part) @ T_world_camera``) and voxelised;
    each voxel is kept by a vote over the keyframes. Every frame renders the posed model and keeps
    pixels whose observed depth agrees within ``tau``, minus (dilated) hand pixels. Frames are
    streamed; only the Q keyframes are held at once.

    Args:
        capture: the capture (frames are read lazily).
        trajectory: camera poses, ``T_world_camera`` (F, 4, 4).
        tracks: point tracks over all F frames, world frame.
        moving: (N,) bool, tracks of this part.
        frames: (F_k,) frame indices the part is tracked in.
        T_world_part: (F_k, 4, 4) part pose at each of ``frames``: canonical part -> posed part, world.
        config: settings.
        progress: optional ``progress(done, total)`` after each frame.
        static: (N,) bool, tracks known to be static; default ``~moving``.

    Returns:
        Masks for every frame of ``frames``.

    Raises:
        ValueError: inconsistent shapes or invalid transforms.
        ReconstructionError: no keyframe region holds moving tracks, so the part has no pixels.
    """
    frames = np.asarray(frames, dtype=np.int64)
    T_world_part = check_transform(T_world_part, "T_world_part")
    moving = np.asarray(moving, dtype=bool)
    static = ~moving if static is None else np.asarray(static, dtype=bool)
    F = len(capture)
    if frames.ndim != 1 or len(frames) == 0 or T_world_part.shape != (len(frames), 4, 4):
        raise ValueError(f"frames must be (F_k,) non-empty and T_world_part (F_k, 4, 4), got {frames.shape}, {T_world_part.shape}")
    if frames.min() < 0 or frames.max() >= F:
        raise ValueError(f"frames must lie in [0, {F}), got [{frames.min()}, {frames.max()}]")
    if len(trajectory.T_world_camera) != F or tracks.num_frames != F:
        raise ValueError(f"capture has {F} frames, trajectory {len(trajectory.T_world_camera)}, tracks {tracks.num_frames}")
    if moving.shape != (tracks.num_tracks,) or static.shape != moving.shape:
        raise ValueError(f"moving and static must be ({tracks.num_tracks},), got {moving.shape}, {static.shape}")
    K = capture.intrinsics.K
    T_part_camera = invert_transform(T_world_part) @ trajectory.T_world_camera[frames]

    key_index = np.unique(np.round(np.linspace(0, len(frames) - 1, min(config.keyframe_count, len(frames)))).astype(int))
    views = []
    for j in key_index:
        view = _read_view(capture, int(frames[j]), config)
        view.part, view.known = _keyframe_mask(view, tracks, moving, static, int(frames[j]), config)
        view.rgb = view.segments = None  # only depth, hand and the masks are needed from here on
        views.append(view)
        logger.debug("keyframe %d: %d part pixels", frames[j], int(view.part.sum()))
    p_part = _vote_model(views, T_part_camera[key_index], K, config)
    if p_part.shape[1] == 0:
        raise ReconstructionError(f"no part pixels: no over-segmentation region of keyframes {frames[key_index].tolist()} "
                                  f"has a moving-track ratio above {config.motion_ratio_threshold}")
    logger.info("part model: %d voxels of %.1f mm from %d keyframes", p_part.shape[1], config.voxel_m * 1e3, len(views))
    png = []
    for j, frame in enumerate(frames):
        view = _read_view(capture, int(frame), config, with_features=False)
        png.append(encode_mask(_propagate(view, p_part, T_part_camera[j], K, config)))
        if progress is not None:
            progress(j + 1, len(frames))
    H, W = capture.intrinsics.height, capture.intrinsics.width
    return PartMasks(frames, tuple(png), H, W, frames[key_index])


@dataclass
class _View:
    """One frame's inputs (mutable scratch, private): depth (H, W) metres, hand (H, W) bool,
    segments (S, H, W) region labels per scale, part and known (H, W) keyframe masks, or None."""

    depth_m: Float32Array
    hand: BoolArray
    rgb: UInt8Array | None = None
    segments: IntArray | None = None
    part: BoolArray | None = None
    known: BoolArray | None = None


def _read_view(capture: Capture, frame: int, config: SegmentationConfig, with_features: bool = True) -> _View:
    depth_m = capture.depth_m(frame).astype(np.float32)
    hand = capture.mask("hand", frame)
    if hand is None:
        hand = np.zeros(depth_m.shape, dtype=bool)
    elif config.hand_margin_px > 0:
        size = 2 * config.hand_margin_px + 1
        hand = cv2.dilate(hand.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))) > 0
    view = _View(depth_m, hand)
    if with_features:
        view.rgb = capture.rgb(frame)
        view.segments = _oversegment(view.rgb, depth_m, capture.intrinsics.K, config)
    return view


def _oversegment(rgb: UInt8Array, depth_m: Float32Array, K: FloatArray, config: SegmentationConfig) -> npt.NDArray[np.int32]:
    """Felzenszwalb graph segmentation of a colour + depth + normal feature image.

    Returns:
        (S, H, W) int32 region labels at full resolution, one map per scale (fine to coarse).
    """
    H, W = depth_m.shape
    s = max(1.0, W / config.segment_width_px)
    size = (round(W / s), round(H / s))
    min_size = max(4, round(config.segment_min_size_px * min(1.0, W / config.segment_width_px) ** 2))
    lab = cv2.cvtColor(cv2.resize(rgb, size, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)
    # Normalised convolution fills depth dropouts so they do not become regions of their own.
    valid = (depth_m > 0).astype(np.float32)
    weight = cv2.GaussianBlur(valid, (0, 0), 3.0)
    filled = np.where(valid > 0, depth_m, cv2.GaussianBlur(depth_m * valid, (0, 0), 3.0) / np.maximum(weight, 1e-6))
    depth_small = cv2.medianBlur(cv2.resize(filled, size, interpolation=cv2.INTER_NEAREST), 5)
    K_small = K.copy()
    K_small[:2] /= s
    p_camera = backproject(depth_small, K_small).reshape(size[1], size[0], 3).astype(np.float32)
    normal = np.cross(np.gradient(p_camera, axis=1), np.gradient(p_camera, axis=0))
    normal = np.nan_to_num(normal / np.maximum(np.linalg.norm(normal, axis=2, keepdims=True), 1e-9))
    step = np.maximum(np.abs(np.gradient(depth_small, axis=0)), np.abs(np.gradient(depth_small, axis=1)))
    edge = np.clip(step / (np.maximum(depth_small, 1e-3) * config.depth_edge_relative), 0.0, 1.0)
    features = np.concatenate(
        [lab * config.colour_weight, normal * config.normal_weight, edge[..., None] * config.depth_edge_weight], axis=2
    )
    with warnings.catch_warnings():
        # skimage warns that a 7-channel image "may not be intended"; it is (channel_axis is given).
        warnings.simplefilter("ignore", RuntimeWarning)
        labels = [
            felzenszwalb(features, scale=scale, sigma=config.segment_sigma_px, min_size=min_size, channel_axis=-1)
            for scale in config.segment_scales
        ]
    return np.stack([cv2.resize(x.astype(np.int32), (W, H), interpolation=cv2.INTER_NEAREST) for x in labels])


def _keyframe_mask(view: _View, tracks: PointTracks, moving: BoolArray, static: BoolArray, frame: int,
                   config: SegmentationConfig) -> tuple[BoolArray, BoolArray]:
    """Motion ratio gamma_r = n_m / (n_m + n_s + eps) of the finest region holding tracks at each pixel.

    Returns:
        part: (H, W) bool, gamma_r > eta_m (paper), hand pixels excluded.
        known: (H, W) bool, pixels of a region (at some scale) holding at least one track.
    """
    assert view.segments is not None
    H, W = view.depth_m.shape
    uv = tracks.uv[frame]
    seen = tracks.visible[frame] & np.isfinite(uv).all(axis=1)
    u = np.round(np.where(seen, uv[:, 0], -1)).astype(np.int64)
    v = np.round(np.where(seen, uv[:, 1], -1)).astype(np.int64)
    seen &= (u >= 0) & (u < W) & (v >= 0) & (v < H)
    seen[seen] &= ~view.hand[v[seen], u[seen]]
    gamma_map = np.full((H, W), np.nan)
    for segments in view.segments[::-1]:  # coarse to fine: finer regions with tracks overwrite
        R = int(segments.max()) + 1
        n_m = np.bincount(segments[v[seen & moving], u[seen & moving]], minlength=R)
        n_s = np.bincount(segments[v[seen & static], u[seen & static]], minlength=R)
        gamma = np.where(n_m + n_s > 0, n_m / (n_m + n_s + config.motion_ratio_eps), np.nan)[segments]
        gamma_map = np.where(np.isnan(gamma), gamma_map, gamma)
    known = ~np.isnan(gamma_map) & ~view.hand
    return known & (gamma_map > config.motion_ratio_threshold), known


def _transform(T_a_b: FloatArray, p_b: FloatArray) -> FloatArray:
    """Apply a rigid transform to (N, 3) points and return them in column layout (3, N).

    ``R @ p`` with p (3, N) contiguous takes ~0.1 ms for 1e5 points, where ``p @ R.T`` with p
    (N, 3) takes 3-30 ms in threaded OpenBLAS on a busy 2-core machine (measured), so the part
    model is kept as (3, M) columns.
    """
    return T_a_b[:3, :3] @ np.ascontiguousarray(p_b.T) + T_a_b[:3, 3:]


def _voxel_keys(p: FloatArray, voxel_m: float) -> IntArray:
    """Pack integer voxel coordinates of (3, N) points (21 bits each, +-4 km at 4 mm) into int64 keys."""
    q = np.floor(p / voxel_m).astype(np.int64) + (1 << 20)
    return (q[0] << 42) | (q[1] << 21) | q[2]


def _vote_model(views: list[_View], T_part_camera: FloatArray, K: FloatArray, config: SegmentationConfig) -> FloatArray:
    """Canonical part model from keyframe masks, cleaned by a vote over the keyframes.

    Args:
        views: Q keyframe views with ``part`` masks.
        T_part_camera: (Q, 4, 4) camera -> canonical part frame at each keyframe.
        K: (3, 3) intrinsics.

    Returns:
        (3, M) voxel centroids ``p_part`` in the canonical part frame, metres (column layout, see
        :func:`_transform`).
    """
    keys, points = [], []
    for view, T in zip(views, T_part_camera):
        assert view.part is not None
        select = (view.part & (view.depth_m > 0)).ravel()
        p_part = _transform(T, backproject(view.depth_m, K)[select])
        keys.append(_voxel_keys(p_part, config.voxel_m))
        points.append(p_part)
    if sum(len(k) for k in keys) == 0:
        return np.zeros((3, 0))
    unique, inverse, counts = np.unique(np.concatenate(keys), return_inverse=True, return_counts=True)
    p_all = np.concatenate(points, axis=1)
    p_part = np.stack([np.bincount(inverse, weights=row, minlength=len(unique)) for row in p_all]) / counts
    votes_for = np.zeros(len(unique))
    votes_against = np.zeros(len(unique))
    for view, T in zip(views, T_part_camera):
        T_camera_part = invert_transform(T)
        hit, z_pred, u, v = _project_inside(p_part, T_camera_part, K, view.depth_m.shape)
        d = view.depth_m[v, u]
        agree = hit & (d > 0) & (np.abs(d - z_pred) < config.depth_tolerance_m)
        free = hit & (d > z_pred + config.depth_tolerance_m)
        votes_for += agree & view.part[v, u]
        votes_against += (agree & ~view.part[v, u] & view.known[v, u]) | free
    keep = votes_for > config.min_vote_ratio * (votes_for + votes_against)
    return np.ascontiguousarray(p_part[:, keep])


def _project_inside(p_part: FloatArray, T_camera_part: FloatArray, K: FloatArray, shape: tuple[int, int]
                    ) -> tuple[BoolArray, FloatArray, IntArray, IntArray]:
    """Project (3, M) canonical points into a frame: (inside-image flag, depth z, column u, row v)
    per point; u, v are clamped to the image so they can index it (use the flag)."""
    p_camera = T_camera_part[:3, :3] @ p_part + T_camera_part[:3, 3:]
    z = p_camera[2]
    zs = np.where(z > 1e-6, z, np.nan)
    u = np.round(K[0, 0] * p_camera[0] / zs + K[0, 2])
    v = np.round(K[1, 1] * p_camera[1] / zs + K[1, 2])
    H, W = shape
    hit = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u = np.where(hit, u, 0).astype(np.int64)
    v = np.where(hit, v, 0).astype(np.int64)
    return hit, z, u, v


def _propagate(view: _View, p_part: FloatArray, T_part_camera: FloatArray, K: FloatArray,
               config: SegmentationConfig) -> BoolArray:
    """Render the posed part model into one frame and keep pixels whose depth agrees."""
    H, W = view.depth_m.shape
    hit, z, u, v = _project_inside(p_part, invert_transform(T_part_camera), K, (H, W))
    z = z[hit].astype(np.float32)
    z_pred = np.full(H * W, np.inf, dtype=np.float32)
    np.minimum.at(z_pred, v[hit] * W + u[hit], z)  # z-buffer: the nearest surface per pixel
    z_pred = z_pred.reshape(H, W)
    # Voxel centres land ~voxel*f/z pixels apart, so a pixel may see only a farther surface (the
    # door's back face) between the front face's splats, and a surface seen at a grazing angle
    # changes depth by centimetres within one spacing: accept an observed depth lying within tau
    # of the range of model depths in a window of one spacing. Occluders (in front of the
    # nearest) and background (behind the farthest) still fail. Closing fills the silhouette's
    # holes without growing it.
    spacing = int(np.ceil(config.voxel_m * K[0, 0] / max(float(np.median(z)), 1e-3))) if len(z) else 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * spacing + 1, 2 * spacing + 1))
    rendered = np.isfinite(z_pred)
    silhouette = cv2.morphologyEx(rendered.astype(np.uint8), cv2.MORPH_CLOSE, kernel) > 0
    z_near = cv2.erode(np.where(rendered, z_pred, np.float32(1e6)), kernel)
    z_far = cv2.dilate(np.where(rendered, z_pred, np.float32(0)), kernel)
    d = view.depth_m
    tau = config.depth_tolerance_m
    mask = silhouette & (d > 0) & (d > z_near - tau) & (d < z_far + tau) & ~view.hand
    if config.fill_missing_depth:
        closed = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, kernel) > 0
        mask |= closed & silhouette & (d <= 0) & ~view.hand
    return mask


__all__ = ["PartMasks", "SegmentationConfig", "decode_mask", "encode_mask", "segment_parts"]
