"""Pixel-aligned part segmentation (paper: "Pixel-aligned part segmentation"): per-frame masks
of an articulated part from its estimated motion, with classical vision in place of SAM/SAM2.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order
from scipy.spatial import cKDTree
from skimage.segmentation import felzenszwalb, watershed

from funrec.camera.tracking import CameraTrajectory, Progress
from funrec.errors import ReconstructionError
from funrec.formats.capture import Capture
from funrec.geometry.camera import backproject
from funrec.geometry.transforms import check_transform, invert_transform
from funrec.parts.point_tracks import PointTracks
from funrec.surfaces.motion_evidence import (
    DepthReference,
    classify_tracks,
    depth_evidence,
    depth_tolerance,
    track_evidence,
)
from funrec.typed import BoolArray, Float32Array, FloatArray, IntArray, UInt8Array

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SegmentationConfig:
    """Settings of :func:`segment_parts`; defaults suit 640x480 Kinect-like RGB-D at 0.5-3 m."""

    keyframe_count: int = 8
    """Q keyframes spread uniformly over the part's frames (paper: uniform keyframes)."""
    reference_count: int = 4
    """Depth-only reference frames spread over the part's displacement (besides the keyframes):
    keyframe pixels are tested for motion against every reference, so the part must have moved
    between a keyframe and some reference; keyframes alone may all rest at one state."""
    segment_width_px: int = 320
    """Keyframes are over-segmented, and tested for motion, at this image width (never upsampled):
    felzenszwalb costs ~0.8 s at 640x480 and ~0.15 s at 320x240, and regions are far larger than
    2 px anyway."""
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
    it that holds enough motion evidence, as SAM's multi-granularity masks would; a pixel whose
    regions hold too little evidence at every scale is unknown: it may join the part by the
    watershed fill, but never votes against a model voxel."""
    segment_sigma_px: float = 1.0
    """Gaussian pre-smoothing of the feature image, pixels at ``segment_width_px``."""
    segment_min_size_px: int = 100
    """Smallest over-segmentation region, pixels at ``segment_width_px`` (scaled with the area
    when the image is narrower)."""
    motion_ratio_threshold: float = 0.5
    """eta_m: a region is part when n_m / (n_m + n_s + eps) exceeds it (paper)."""
    motion_ratio_eps: float = 0.5
    """eps of the motion ratio (pixel units): avoids division by zero."""
    min_evidence_fraction: float = 0.05
    """A region decides (part or not) only when its motion evidence (pixels plus weighted tracks)
    covers this fraction of its area; otherwise a coarser region decides. Isolated evidence
    pixels (depth noise, flying pixels) then cannot claim a large region."""
    track_tolerance_m: float = 0.02
    """A track follows a hypothesis (static world, or the part's estimated motion) when the 90th
    percentile of its distance from its median place under that hypothesis, over its whole life,
    is below this. Measured on bench tracks with estimated poses: static tracks 4 mm (90th
    percentile of tracks), part tracks 3-11 mm on doors and drawers."""
    min_track_motion_m: float = 0.02
    """An observation decides between the hypotheses only where the part's motion would have
    moved the track this far from its usual place; a track needs two such observations. A track
    seen only while the part rests is explained equally by the static world and by the part."""
    depth_tolerance_m: float = 0.02
    """tau: observed and predicted depth agree when closer than this, up to
    ``depth_tolerance_range_m``. Kinect-like noise is sigma ~ 6 mm at 2 m, so 3 sigma; it also
    absorbs the 1-3 mm part-state and camera errors measured on the bench."""
    depth_tolerance_range_m: float = 2.0
    """Beyond this depth tau grows with z^2 like Kinect-like axial noise (4.5 cm at 3 m)."""
    voxel_m: float = 0.004
    """Voxel edge of the canonical part model, metres: 4 mm is ~2 px at 1 m with fx ~ 525,
    so the propagated boundary is within ~1 px of the keyframe evidence."""
    piece_cell_m: float = 0.02
    """Cell edge of the connectivity test of the part model, metres: gaps narrower than a cell
    (a drawer's contents resting on its floor, a handle) keep pieces together."""
    min_piece_fraction: float = 0.1
    """Model pieces with fewer points than this fraction of the largest piece are dropped
    (measured: a 4 m distant wall patch fused into a door's mesh, 7 cm of part accuracy)."""
    min_vote_ratio: float = 0.5
    """A model voxel is kept when part votes / all votes over the keyframes exceed this; votes
    against are keyframes that see the voxel's place as static surface or as free space."""
    hand_margin_px: int = 4
    """Hand masks are dilated by this many pixels before exclusion: depth is worst at edges."""
    fill_missing_depth: bool = True
    """Pixels without depth inside the predicted part silhouette join the mask when surrounded
    by mask pixels (a morphological closing); the true mask does not depend on depth dropouts."""
    depth_jump_relative: float = 0.02
    """A keyframe region decided part keeps only the pixels its evidence reaches without stepping
    back across a depth jump of this fraction of the depth between neighbouring pixels (2 cm at
    1 m: twice ``depth_edge_relative``, ~8 sigma of Kinect-class noise there); see
    :func:`_attached`. Over-segmentation regions straddle such steps, where both sides are edge
    pixels: a door seen edge-on is a strip a few pixels wide whose region also held the cabinet's
    inside behind it, which only the opened door reveals and no reference sees
    (geo_angled_rev_cabinet_00 keyframes 99 and 117: 1800 and 2500 px off the part). Measured on
    the dumped mask inputs of 9 bench sequences (4 families): geo_angled_rev_cabinet_00 mIoU
    71.3 -> 78.1 (78.4 at 0.01, 78.1 at 0.03, 72.7 at 0.05), mw_window_00 66.2 -> 75.4,
    dark_rev_glass_wall_00 89.1 -> 88.8, the six others (plain door, drawer, wardrobe, fridge,
    sleeve arm, textured door) within 0.1.
    0 turns it off."""


@dataclass(frozen=True)
class EncodedMasks:
    """Per-frame binary masks stored PNG-encoded, so a long video never holds (F, H, W) arrays;
    shared by part masks and hand masks."""

    frames: IntArray
    """(F,) frame indices (capture order) with a mask."""
    png: tuple[bytes, ...]
    """(F,) 8-bit single-channel PNG of each mask (255 = in, 0 = out)."""
    height: int
    """Image height H in pixels."""
    width: int
    """Image width W in pixels."""

    def __post_init__(self) -> None:
        if np.ndim(self.frames) != 1 or len(self.png) != len(self.frames):
            raise ValueError(f"frames must be (F,) with one PNG each, got {np.shape(self.frames)} and {len(self.png)}")

    def __len__(self) -> int:
        return len(self.frames)

    def mask(self, index: int) -> BoolArray:
        """(H, W) bool mask at position ``index`` of :attr:`frames` (not a frame number)."""
        return decode_mask(self.png[index])

    def __iter__(self) -> Iterator[tuple[int, BoolArray]]:
        """Yield ``(frame, mask)`` one mask at a time."""
        for index, frame in enumerate(self.frames):
            yield int(frame), self.mask(index)


@dataclass(frozen=True)
class PartMasks(EncodedMasks):
    """Per-frame masks of one articulated part; the bytes are exactly the files of FORMATS.md
    masks/part_k/ (255 = part)."""

    keyframes: IntArray
    """(Q,) frame indices whose over-segmentation built the part model (empty if none)."""

    @classmethod
    def from_masks(cls, frames: npt.ArrayLike, masks: npt.ArrayLike, keyframes: npt.ArrayLike = ()) -> PartMasks:
        """Build from in-memory (F_k, H, W) bool masks (tests, learned segmenters)."""
        masks = np.asarray(masks, dtype=bool)
        if masks.ndim != 3:
            raise ValueError(f"masks must be (F_k, H, W), got {masks.shape}")
        return cls(np.asarray(frames, dtype=np.int64), tuple(encode_mask(m) for m in masks), masks.shape[1],
                   masks.shape[2], np.asarray(keyframes, dtype=np.int64))


_MASK_PNG = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE,
             cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
"""A mask's rows are long runs of 0 and 255: run-length deflate without a row filter writes them in
a fifth of the time of libpng's filter search at level 1 (0.33 against 1.7 ms for a 640x480 mask),
and smaller (1.1 against 2.9 kB; measured on 280 hand and part masks); the same 8-bit pixels."""


def encode_mask(mask: npt.ArrayLike) -> bytes:
    """(H, W) bool mask to 8-bit PNG bytes (255 = inside); fast compression (~0.3 ms)."""
    ok, buffer = cv2.imencode(".png", np.asarray(mask, dtype=np.uint8) * 255, _MASK_PNG)
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

    Motion evidence comes from the estimated part motion, not from track clusters: every track
    is re-classified as part (it follows ``T_world_part``), static (it stays put while the part
    would have moved it) or neither (hand, shadows, other movers, tracks seen only while the part
    rests), and every keyframe pixel is tested against the depth of reference frames at other
    part states (part: the static world is seen through its old place and the part's motion
    explains it; static: the converse). Decided tracks count in every keyframe that sees their
    place, not only in the frames they were tracked in. Keyframes are over-segmented
    (felzenszwalb, two scales) on colour, normals and depth discontinuities; a region is part when
    the ratio of part to part-plus-static evidence exceeds ``eta_m`` (paper), and undecided pixels
    join the decided surface they are not separated from by an edge (watershed, within fine
    regions holding part pixels). Keyframe part pixels are lifted into the canonical part frame
    (``T_part_camera = inv(T_world_part) @ T_world_camera``) and voxelised; each voxel is kept by
    a vote over the keyframes, and only the model's main connected pieces are kept. Every frame
    renders the posed model and keeps pixels whose observed depth agrees within ``tau``, hand pixels
    included (a hand mask does not remove depth that lies on the posed part). Frames are streamed; only the Q keyframes and the small reference
    depth maps are held at once.

    Args:
        capture: the capture (frames are read lazily).
        trajectory: camera poses, ``T_world_camera`` (F, 4, 4).
        tracks: point tracks over all F frames, world frame.
        moving: (N,) bool, tracks known to belong to this part (e.g. its motion cluster); they
            count as part tracks when they follow ``T_world_part`` within ``track_tolerance_m``.
            Other tracks that follow it are found here.
        frames: (F_k,) increasing frame indices the part is tracked in.
        T_world_part: (F_k, 4, 4) part pose at each of ``frames``: canonical part -> posed part,
            world. Outside ``frames`` the part rests at the pose of the nearest tracked frame.
        config: settings.
        progress: optional ``progress(done, total)`` after each frame.
        static: (N,) bool, tracks known to be static; default: tracks that stay within
            ``track_tolerance_m`` of their world position while the part's motion would have
            moved them further than ``min_track_motion_m``.

    Returns:
        Masks for every frame of ``frames``.

    Raises:
        ValueError: inconsistent shapes or invalid transforms.
        ReconstructionError: no keyframe region holds part evidence (the part never moved away
            from the static world in any view), so the part has no pixels.
    """
    frames = np.asarray(frames, dtype=np.int64)
    T_world_part = check_transform(T_world_part, "T_world_part")
    moving = np.asarray(moving, dtype=bool)
    F = len(capture)
    if frames.ndim != 1 or len(frames) == 0 or T_world_part.shape != (len(frames), 4, 4):
        raise ValueError(f"frames must be (F_k,) non-empty and T_world_part (F_k, 4, 4), got {frames.shape}, {T_world_part.shape}")
    if frames.min() < 0 or frames.max() >= F or np.any(np.diff(frames) <= 0):
        raise ValueError(f"frames must lie in [0, {F}) and increase, got [{frames.min()}, {frames.max()}]")
    if len(trajectory.T_world_camera) != F or tracks.num_frames != F:
        raise ValueError(f"capture has {F} frames, trajectory {len(trajectory.T_world_camera)}, tracks {tracks.num_frames}")
    if moving.shape != (tracks.num_tracks,) or (static is not None and np.shape(static) != moving.shape):
        raise ValueError(f"moving and static must be ({tracks.num_tracks},), got {moving.shape}, {np.shape(static)}")
    K = capture.intrinsics.K
    T_part_camera = invert_transform(T_world_part) @ trajectory.T_world_camera[frames]

    track_labels = classify_tracks(tracks, frames, T_world_part, moving, config.track_tolerance_m,
                                   config.min_track_motion_m)
    if static is not None:
        known_static = np.asarray(static, dtype=bool)
        track_labels = dataclasses.replace(track_labels, labels=np.where(known_static, -1, track_labels.labels).astype(np.int8))
    labels = track_labels.labels
    logger.info("tracks: %d part, %d static, %d undecided", int((labels > 0).sum()), int((labels < 0).sum()),
                int((labels == 0).sum()))
    key_index = np.unique(np.round(np.linspace(0, len(frames) - 1, min(config.keyframe_count, len(frames)))).astype(int))
    scale = _segment_scale(capture.intrinsics.width, config)
    K_small = K.copy()
    K_small[:2] /= scale
    small = (round(capture.intrinsics.width / scale), round(capture.intrinsics.height / scale))
    references = [
        DepthReference.from_frame(*_small_depth_hand(capture, int(frames[j]), small, config),
                                  invert_transform(trajectory.T_world_camera[frames[j]]), T_world_part[j], int(frames[j]))
        for j in _reference_index(T_world_part, track_labels.p_anchor, key_index, config.reference_count)
    ]
    tolerance = (config.depth_tolerance_m, config.depth_tolerance_range_m)
    views = []
    for j in key_index:
        view = _read_view(capture, int(frames[j]), config)
        depth_small, hand_small = _small_depth_hand(capture, int(frames[j]), small, config, view)
        part_px, static_px = depth_evidence(depth_small, hand_small, K_small, trajectory.T_world_camera[frames[j]],
                                            T_world_part[j], references, tolerance)
        part_tracks, static_tracks = track_evidence(track_labels, depth_small, hand_small, K_small,
                                                    trajectory.T_world_camera[frames[j]], T_world_part[j], tolerance,
                                                    _farthest_motion(T_world_part, j, track_labels.p_anchor))
        view.part, view.known = _keyframe_mask(view, depth_small, part_px, static_px, part_tracks, static_tracks, config)
        view.rgb = view.segments = view.gradient = None  # only depth, hand and the masks are needed from here on
        views.append(view)
        logger.debug("keyframe %d: %d part pixels (%d with depth evidence)", frames[j], int(view.part.sum()), int(part_px.sum()))
    # the depth references between the keyframes' part states also judge the model's places (see _place_votes)
    keyframe_frames = set(frames[key_index].tolist())
    witnesses = [reference for reference in references if reference.frame not in keyframe_frames]
    p_part = _vote_model(views, T_part_camera[key_index], trajectory.T_world_camera[frames[key_index]], K,
                         config, witnesses, K_small).astype(np.float32)
    if p_part.shape[1] == 0:
        raise ReconstructionError(f"no part pixels: no over-segmentation region of keyframes {frames[key_index].tolist()} "
                                  f"has a part-evidence ratio above {config.motion_ratio_threshold} (did the part move?)")
    logger.info("part model: %d voxels of %.1f mm from %d keyframes", p_part.shape[1], config.voxel_m * 1e3, len(views))
    png = []
    for j, frame in enumerate(frames):
        view = _read_view(capture, int(frame), config, with_features=False)
        png.append(encode_mask(_propagate(view, p_part, T_part_camera[j], K, config)))
        if progress is not None:
            progress(j + 1, len(frames))
    H, W = capture.intrinsics.height, capture.intrinsics.width
    return PartMasks(frames, tuple(png), H, W, frames[key_index])


def _farthest_motion(T_world_part: FloatArray, j: int, p_anchor: FloatArray | None) -> FloatArray | None:
    """(4, 4) world motion of the part from its pose at position ``j`` to the pose (among its
    frames) that moves ``p_anchor`` (canonical) the farthest; None without an anchor."""
    if p_anchor is None:
        return None
    p_world = T_world_part[:, :3, :3] @ p_anchor + T_world_part[:, :3, 3]
    far = int(np.argmax(np.linalg.norm(p_world - p_world[j], axis=1)))
    return T_world_part[far] @ invert_transform(T_world_part[j])


def _reference_index(T_world_part: FloatArray, p_anchor: FloatArray | None, key_index: IntArray, count: int) -> IntArray:
    """Positions (in the part's frames) of the reference frames: the keyframes plus ``count``
    frames spread evenly over the displacement of ``p_anchor`` (a point on the part, canonical
    frame) from its canonical place, so that references span the part's states."""
    if p_anchor is None or count <= 0:
        return key_index
    p_world = T_world_part[:, :3, :3] @ p_anchor + T_world_part[:, :3, 3]
    displacement = np.linalg.norm(p_world - p_anchor, axis=1)
    targets = np.linspace(displacement.min(), displacement.max(), count)
    extra = np.argmin(np.abs(displacement[None, :] - targets[:, None]), axis=1)
    return np.union1d(key_index, extra)


@dataclass
class _View:
    """One frame's inputs (mutable scratch, private): depth (H, W) metres, hand (H, W) bool,
    segments (S, h, w) region labels per scale at the segmentation size, part and known (H, W)
    keyframe masks, or None."""

    depth_m: Float32Array
    hand: BoolArray
    rgb: UInt8Array | None = None
    segments: IntArray | None = None
    gradient: Float32Array | None = None
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
        view.segments, view.gradient = _oversegment(view.rgb, depth_m, capture.intrinsics.K, config)
    return view


def _segment_scale(width: int, config: SegmentationConfig) -> float:
    """Downscale factor of the segmentation size (>= 1: never upsampled)."""
    return max(1.0, width / config.segment_width_px)


def _small_depth_hand(capture: Capture, frame: int, size: tuple[int, int], config: SegmentationConfig,
                      view: _View | None = None) -> tuple[Float32Array, BoolArray]:
    """Depth (metres, 0 = missing) and dilated hand mask of a frame at the segmentation size
    ``size`` = (w, h); nearest sampling keeps depth edges sharp (no mixed depths)."""
    view = _read_view(capture, frame, config, with_features=False) if view is None else view
    depth = cv2.resize(view.depth_m, size, interpolation=cv2.INTER_NEAREST)
    hand = cv2.resize(view.hand.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    return depth, hand


def _oversegment(rgb: UInt8Array, depth_m: Float32Array, K: FloatArray, config: SegmentationConfig
                 ) -> tuple[npt.NDArray[np.int32], Float32Array]:
    """Felzenszwalb graph segmentation of a colour + depth + normal feature image.

    Returns:
        segments: (S, h, w) int32 region labels at the segmentation size, one map per scale (fine
            to coarse).
        gradient: (h, w) float32 feature gradient magnitude (feature units per pixel), the
            flooding landscape of :func:`_fill_unknown`.
    """
    H, W = depth_m.shape
    s = _segment_scale(W, config)
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
    smooth = cv2.GaussianBlur(features.astype(np.float32), (0, 0), config.segment_sigma_px)
    gradient = np.sqrt(sum(cv2.Sobel(smooth[..., c], cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(smooth[..., c], cv2.CV_32F, 0, 1) ** 2
                           for c in range(smooth.shape[2])))
    return np.stack(labels).astype(np.int32), gradient


def _keyframe_mask(view: _View, depth_small: Float32Array, part_px: BoolArray, static_px: BoolArray, part_tracks: IntArray,
                   static_tracks: IntArray, config: SegmentationConfig) -> tuple[BoolArray, BoolArray]:
    """Motion ratio gamma_r = n_m / (n_m + n_s + eps) of the finest region with enough evidence.

    Evidence is counted at the segmentation size (h, w): pixels with depth evidence, plus tracks
    seen as part or static, each worth the image area per seen track (so sparse tracks and dense
    pixels weigh the same per unit area).

    A region decided part keeps only the pixels attached to its evidence without crossing a depth
    jump (:func:`_attached`).

    Args:
        view: the keyframe with its over-segmentation.
        depth_small: (h, w) depth at the segmentation size, metres (0 = missing).
        part_px, static_px: (h, w) bool depth evidence.
        part_tracks, static_tracks: (h, w) counts of part and static tracks seen at each pixel.
        config: settings.

    Returns:
        part: (H, W) bool, gamma_r > eta_m (paper), hand pixels excluded.
        known: (H, W) bool, pixels of a region (at some scale) with enough evidence.
    """
    assert view.segments is not None
    h, w = part_px.shape
    track_weight = h * w / max(1, int(part_tracks.sum() + static_tracks.sum()))
    part_weight = (part_px + track_weight * part_tracks).ravel()
    static_weight = (static_px + track_weight * static_tracks).ravel()
    gamma_map = np.full((h, w), np.nan)
    for segments in view.segments[::-1]:  # coarse to fine: finer regions with evidence overwrite
        R = int(segments.max()) + 1
        area = np.bincount(segments.ravel(), minlength=R)
        n_m = np.bincount(segments.ravel(), weights=part_weight, minlength=R)
        n_s = np.bincount(segments.ravel(), weights=static_weight, minlength=R)
        enough = (n_m + n_s > 0) & (n_m + n_s >= config.min_evidence_fraction * area)
        gamma = np.where(enough, n_m / (n_m + n_s + config.motion_ratio_eps), np.nan)[segments]
        gamma_map = np.where(np.isnan(gamma), gamma_map, gamma)
    H, W = view.depth_m.shape
    known_small, part_small = ~np.isnan(gamma_map), gamma_map > config.motion_ratio_threshold
    assert view.gradient is not None
    part_small = _fill_unknown(part_small, known_small, view.gradient, view.segments[0])
    if config.depth_jump_relative > 0:
        part_small = _attached(part_small, part_small & (part_px | (part_tracks > 0)), depth_small,
                               config.depth_jump_relative)
    known = cv2.resize(known_small.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0
    part = cv2.resize(part_small.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0
    known &= ~view.hand
    return part & ~view.hand, known


def _attached(part: BoolArray, seeds: BoolArray, depth_m: Float32Array, jump_relative: float) -> BoolArray:
    """The pixels of ``part`` (h, w) that its ``seeds`` reach over 4-neighbours, never stepping back
    across a depth jump (neighbours whose depths differ by more than ``jump_relative`` times the
    nearer one): a surface seen behind the edge of a reached one is not reached, one standing in
    front of a reached one is (a handle on a plain front, the door's edge in front of the cabinet's
    inside: the converse). A pixel without depth is reached from a neighbour but leads nowhere: depth
    drops out along the edge of a surface seen edge-on. A directed reachability on the pixel graph
    (scipy's breadth-first search from a virtual source joined to every seed)."""
    if not seeds.any():
        return part
    h, w = part.shape
    index = np.arange(h * w).reshape(h, w)
    tails, heads = [], []
    for first, second in (((slice(None, -1),), (slice(1, None),)), ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))):
        a, b, za, zb = index[first], index[second], depth_m[first], depth_m[second]
        both = part[first] & part[second]
        jump = np.abs(zb - za) > jump_relative * np.minimum(za, zb)
        # a -> b: from a reading to a nearer or not much farther one, or into a dropout (never out of one:
        # depth drops out along the edge of a surface seen edge-on, next to what lies behind it)
        forward = both & (za > 0) & ((zb <= 0) | ~jump | (zb < za))
        backward = both & (zb > 0) & ((za <= 0) | ~jump | (za < zb))
        tails += [a[forward], b[backward]]
        heads += [b[forward], a[backward]]
    source = h * w
    start = index[seeds & part]
    tails.append(np.full(len(start), source))
    heads.append(start)
    tail, head = np.concatenate(tails), np.concatenate(heads)
    graph = csr_matrix((np.ones(len(tail), dtype=np.int8), (tail, head)), shape=(h * w + 1, h * w + 1))
    reached = np.zeros(h * w + 1, dtype=bool)
    reached[breadth_first_order(graph, source, directed=True, return_predecessors=False)] = True
    return reached[:-1].reshape(h, w)


def _fill_unknown(part: BoolArray, known: BoolArray, gradient: Float32Array, segments: IntArray) -> BoolArray:
    """Give each undecided pixel the decision (part or not) of the region that floods it first
    over the feature gradient (marker watershed): it stays with the surface it is not separated
    from by a colour, normal or depth edge. The flood stays inside the finest over-segmentation
    regions (``segments``) that hold decided part pixels: where static evidence is sparse (a
    distant or featureless room, static surfaces parallel to a slide, a cabinet's inside that
    only the opened door reveals) a part seed would otherwise flood whatever its region holds.
    The watershed alone does not stop there: it floods by the order of the gradient, not its
    height, so an unknown surface behind a strong edge still joins the part when no static seed
    is nearer. Measured on the dumped inputs of bench sequences, flooding within the coarse
    regions (k = 3000) put a vertical sash's static window frame and the wall above into its
    mask (mw_window_00 FP 0.96 of the true area) and a cabinet's inside into an edge-on door's
    (geo_angled_rev_cabinet_00, keyframe 99: 5380 px off the part from 242 px of evidence);
    within the fine regions (k = 500): mIoU 48.8 -> 63.0 and 59.8 -> 69.8, dark_rev_glass_wall_00
    77.8 -> 85.4, and within 1 point elsewhere, plain white doors included."""
    markers = np.where(known, np.where(part, 1, 2), 0).astype(np.int32)
    if not (markers == 1).any():
        return part
    filled = watershed(gradient, markers) == 1
    seeded = np.zeros(int(segments.max()) + 1, dtype=bool)
    seeded[segments[part & known]] = True
    return part | (filled & seeded[segments])


def _transform(T_a_b: FloatArray, p_b: FloatArray) -> FloatArray:
    """Apply a rigid transform to (N, 3) points and return them in column layout (3, N).

    ``R @ p`` with p (3, N) contiguous takes ~0.1 ms for 1e5 points, where ``p @ R.T`` with p
    (N, 3) takes 3-30 ms in threaded OpenBLAS on a busy 2-core machine (measured), so the part
    model is kept as (3, M) columns.
    """
    return _apply(T_a_b, np.ascontiguousarray(p_b.T))


def _apply(T_a_b: FloatArray, p_b: FloatArray) -> FloatArray:
    """Apply a rigid transform to (3, N) column points (see :func:`_transform`)."""
    return T_a_b[:3, :3] @ p_b + T_a_b[:3, 3:]


MAX_PIECE_GRID_CELLS = 20_000_000
"""Largest dense grid of the connectivity test (20 MB of bools)."""


def _voxel_keys(p: FloatArray, voxel_m: float) -> IntArray:
    """Pack integer voxel coordinates of (3, N) points (21 bits each, +-4 km at 4 mm) into int64 keys."""
    q = np.floor(p / voxel_m).astype(np.int64) + (1 << 20)
    return (q[0] << 42) | (q[1] << 21) | q[2]


def _vote_model(views: list[_View], T_part_camera: FloatArray, T_world_camera: FloatArray, K: FloatArray,
                config: SegmentationConfig, witnesses: list[DepthReference] = (), K_witness: FloatArray | None = None
                ) -> FloatArray:
    """Canonical part model from keyframe masks, cleaned by two votes over the keyframes.

    The part vote: keyframes that see the voxel where the part's pose puts it, as part (for) or
    as static surface or free space (against). The place vote (:func:`_place_votes`): a voxel is
    part only if, where a keyframe saw it, other keyframes whose part pose moved it away see
    free space more often than a surface still standing there.

    Args:
        views: Q keyframe views with ``part`` masks.
        T_part_camera: (Q, 4, 4) camera -> canonical part frame at each keyframe.
        T_world_camera: (Q, 4, 4) camera poses of the keyframes.
        K: (3, 3) intrinsics.
        witnesses: more frames (depth only, part states between the keyframes') for the place vote.
        K_witness: (3, 3) intrinsics of the witnesses' depth size.

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
    seen_as_part = np.zeros((len(views), len(unique)), dtype=bool)
    for q, (view, T) in enumerate(zip(views, T_part_camera)):
        T_camera_part = invert_transform(T)
        agree, free, u, v = _depth_test(p_part, T_camera_part, K, view.depth_m, config)
        seen_as_part[q] = agree & view.part[v, u]
        votes_for += seen_as_part[q]
        votes_against += (agree & ~view.part[v, u] & view.known[v, u]) | free
    keep = votes_for > config.min_vote_ratio * (votes_for + votes_against)
    left, stayed = _place_votes(views, p_part, seen_as_part, T_part_camera, T_world_camera, K, config, witnesses,
                                K_witness)
    # Twice as many keyframes must see the place left as still standing: static surfaces seen at grazing angles
    # with 2 cm of camera error come out about even (plain_rev_wall_cabinet_00: 65 % of its static strays kept at
    # left >= stayed, 44 % at twice; the door's own voxels 99.4 % and 98.9 %), and in front of other strays they
    # hid them from the propagation; with them gone, the strays behind made the part's mesh 0.5 m off the door.
    keep &= left >= 2 * stayed
    p_part = p_part[:, keep]
    return np.ascontiguousarray(p_part[:, _main_pieces(p_part, config.piece_cell_m, config.min_piece_fraction)])


def _depth_test(p: FloatArray, T_camera_p: FloatArray, K: FloatArray, depth_m: Float32Array, config: SegmentationConfig
                ) -> tuple[BoolArray, BoolArray, IntArray, IntArray]:
    """Where a frame sees (3, M) points: on its surface within tau (agree), or through them
    (free space); and the pixel (u, v) of each point (clamped; false flags outside the image)."""
    hit, z_pred, u, v = _project_inside(p, T_camera_p, K, depth_m.shape)
    d = depth_m[v, u]
    tau = depth_tolerance(z_pred, config.depth_tolerance_m, config.depth_tolerance_range_m)
    return hit & (d > 0) & (np.abs(d - z_pred) < tau), hit & (d > z_pred + tau), u, v


def _place_votes(views: list[_View], p_part: FloatArray, seen_as_part: BoolArray, T_part_camera: FloatArray,
                 T_world_camera: FloatArray, K: FloatArray, config: SegmentationConfig,
                 witnesses: list[DepthReference] = (), K_witness: FloatArray | None = None) -> tuple[IntArray, IntArray]:
    """Did the part ever leave the places a voxel was seen at? Counts, per voxel, over pairs of a
    keyframe ``a`` that saw it as part and a keyframe ``b`` whose part pose moved it away from
    that place (by more than twice tau): ``b`` sees free space at the place (left) or a surface
    still there (stayed).

    Keyframe masks label part what no depth test can tell from it at their pose: a static surface
    coplanar with the closed front (the next door, a carcass rail), or one the turn carries onto
    itself (a ceiling above a door turning about a vertical hinge); undecided pixels then join the
    part's region. Such surfaces pass the part vote (where the part's pose moves them they fall
    behind the static surface, unseen), but they never leave: another keyframe sees them still
    standing where they were. The part's own surfaces leave free space or are hidden behind the
    moved part (no vote), so this costs them nothing. A surface still there is not counted where
    the model at ``b``'s pose covers the place: a slide carries every surface parallel to it onto
    itself (a drawer's floor, its sides), so any model voxel covers; a turn carries only planes
    normal to its axis onto themselves, and a static shelf or ceiling is covered only by voxels
    that never left, so there only voxels that left some place themselves cover (measured on the
    pickled keyframes of five sequences: a sliding wardrobe panel kept 96 % of its voxels with any
    voxel covering, 62 % with proven ones; a glazed wall cabinet's ceiling 62 % against 27 %).
    A voxel with no vote either way is kept: a strip near a hinge that moves less than 2 tau, or
    a surface whose places are hidden at every other keyframe. A shelf that the door reveals and
    keyframes see at one opening only is such a surface, but so is a drawer's back panel seen
    fully open (measured: dropping both cost plain_pri_drawer_00 15 points of mIoU).

    The keyframes are uniform in time, and a hand opens a part quickly: most rest closed or stand
    fully open, and a door fully open stands in front of what lies next to its hinge. The closed
    keyframes label the coplanar next door part, and no other keyframe sees its place
    (person_sleeve_rev_cabinet_00: 21 thousand of the model's 28 thousand voxels off the door had
    no vote, their places hidden at all four open keyframes, 65 % of them seen still there half
    open). So ``witnesses``, the depth references spread over the part's displacement
    (``reference_count``), judge as further frames ``b`` the voxels that no keyframe could judge;
    where a keyframe voted, the keyframes' votes stand. A witness's surface still there is not
    counted where a voxel covers the place that left some place at any frame, keyframe or witness.
    Witnesses judge turns only: a slide carries its surfaces onto themselves, and a witness's
    coarser depth (``segment_width_px``) at the edges of a sliding panel saw 387 of
    person_elbow_pri_wardrobe_00's panel voxels still there (mIoU 89.3 -> 88.8; a drawer's
    open side is not hidden behind the drawer as a door's hinge side is behind the door).

    Returns:
        left, stayed: (M,) counts; :func:`_vote_model` keeps voxels with ``left >= 2 * stayed``.
    """
    Q, M = seen_as_part.shape
    T_world_part = T_world_camera @ invert_transform(T_part_camera)
    # the frames b that judge: the keyframes, then the witnesses (depth only)
    T_world_part_b = np.concatenate([T_world_part] + [w.T_world_part[None] for w in witnesses])
    T_part_world_b = invert_transform(T_world_part_b)
    T_camera_world_b = np.concatenate([invert_transform(T_world_camera)] + [w.T_camera_world[None] for w in witnesses])
    p_world_camera_b = invert_transform(T_camera_world_b)[:, :3, 3:]  # camera centres, once for every pair (a, b)
    depth_b = [view.depth_m for view in views] + [w.depth_m for w in witnesses]
    K_b = [K] * Q + [K if K_witness is None else K_witness] * len(witnesses)
    T_part_world = T_part_world_b[:Q]
    left = np.zeros((2, M), dtype=np.int64)  # by keyframes, by witnesses
    stays = []  # per pair (a, b): the slide flag, voxels seen at a and moved away at b with a surface still at
    # their place at a, and that place in the part frame at b's pose
    for a in range(Q):
        seen = np.flatnonzero(seen_as_part[a])  # only these: a keyframe sees a fraction of the model
        if len(seen) == 0:
            continue
        p_a = _apply(T_world_part[a], p_part[:, seen])
        for b in range(len(depth_b)):
            if b == a:
                continue
            T_b_a = T_world_part_b[b] @ T_part_world[a]  # the part's motion from a's pose to b's, world
            slides = _slides(T_b_a, p_a, config.depth_tolerance_m)
            if b >= Q and slides:
                continue  # witnesses judge turns only (see above)
            z = np.linalg.norm(p_a - p_world_camera_b[b], axis=0)
            away = np.linalg.norm(_apply(T_b_a, p_a) - p_a, axis=0)
            moved = away > 2 * depth_tolerance(z, config.depth_tolerance_m, config.depth_tolerance_range_m)
            if moved.any():
                agree, free, _, _ = _depth_test(p_a[:, moved], T_camera_world_b[b], K_b[b], depth_b[b], config)
                left[int(b >= Q), seen[moved][free]] += 1
                if agree.any():
                    stays.append((int(b >= Q), slides, seen[moved][agree],
                                  _apply(T_part_world_b[b], p_a[:, moved][:, agree]).T))
    stayed = np.zeros((2, M), dtype=np.int64)
    # what covers a place: any voxel under a slide, a voxel proven to leave some place under a turn (by the
    # keyframes for the keyframes' votes, by any frame for the witnesses')
    proven = (left[0] > 0, left.sum(axis=0) > 0)
    everything = cKDTree(p_part.T) if proven[1].any() else None
    models = {(slides, w): everything if slides else cKDTree(p_part[:, proven[w]].T)
              for w in (0, 1) if proven[w].any() for slides in (True, False)}
    for by_witness, slides, still, p_place_part in stays:
        if (slides, by_witness) not in models:
            continue
        gap, _ = models[slides, by_witness].query(p_place_part, distance_upper_bound=config.depth_tolerance_m)
        stayed[by_witness, still[~np.isfinite(gap)]] += 1
    # the witnesses judge only what no keyframe could
    judged = (left[0] + stayed[0]) > 0
    return np.where(judged, left[0], left[1]), np.where(judged, stayed[0], stayed[1])


def _slides(T_b_a: FloatArray, p: FloatArray, tolerance_m: float) -> bool:
    """Is the motion ``T_b_a`` a slide over the (3, N) points ``p``: does its turn move none of
    them by ``tolerance_m`` beyond the translation of their centroid?"""
    R = T_b_a[:3, :3]
    offset = p - p.mean(axis=1, keepdims=True)
    return bool(np.linalg.norm((R - np.eye(3)) @ offset, axis=0).max() < tolerance_m)


def _main_pieces(p_part: FloatArray, cell_m: float, min_fraction: float) -> BoolArray:
    """(M,) True for points of the (3, M) model whose connected piece (26-connected cells of
    ``cell_m``) holds at least ``min_fraction`` of the largest piece's points: a rigid part is one
    body, and stray evidence (a distant wall, a floor patch) is a separate piece."""
    if p_part.shape[1] == 0:
        return np.zeros(0, dtype=bool)
    cell = np.floor((p_part - p_part.min(axis=1, keepdims=True)) / cell_m).astype(np.int64)
    shape = tuple(cell.max(axis=1) + 1)
    cells = float(np.prod(np.asarray(shape, dtype=np.float64)))  # in floats: a stray far point overflows int64
    if cells > MAX_PIECE_GRID_CELLS:  # a model spanning the room: coarser cells
        return _main_pieces(p_part, cell_m * float(np.cbrt(cells / MAX_PIECE_GRID_CELLS)) * 1.01, min_fraction)
    occupied = np.zeros(shape, dtype=bool)
    occupied[cell[0], cell[1], cell[2]] = True
    labels, _ = ndimage.label(occupied, structure=np.ones((3, 3, 3)))
    piece = labels[cell[0], cell[1], cell[2]]
    sizes = np.bincount(piece)
    return sizes[piece] >= min_fraction * sizes[1:].max()


def _project_inside(p_part: Float32Array, T_camera_part: FloatArray, K: FloatArray, shape: tuple[int, int]
                    ) -> tuple[BoolArray, Float32Array, IntArray, IntArray]:
    """Project (3, M) canonical points into a frame: (inside-image flag, depth z, column u, row v)
    per point; u, v are clamped to the image so they can index it (use the flag). Float32 with
    the projection folded into one 3x4 matrix: this runs for every frame on up to ~2e5 model
    points, and float32 keeps 0.1 um at 10 m."""
    P = (K @ T_camera_part[:3]).astype(np.float32)
    q = P[:, :3] @ p_part.astype(np.float32, copy=False) + P[:, 3:]
    z = q[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(q[0] / z)
        v = np.rint(q[1] / z)
    H, W = shape
    hit = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u = np.where(hit, u, 0).astype(np.int64)
    v = np.where(hit, v, 0).astype(np.int64)
    return hit, z, u, v


def _propagate(view: _View, p_part: Float32Array, T_part_camera: FloatArray, K: FloatArray,
               config: SegmentationConfig) -> BoolArray:
    """Render the posed part model into one frame and keep pixels whose depth agrees."""
    H, W = view.depth_m.shape
    T_camera_part = invert_transform(T_part_camera)
    hit, z, u, v = _project_inside(p_part, T_camera_part, K, (H, W))
    pixel = v[hit] * W + u[hit]
    z = z[hit].astype(np.float32)
    # Only model points that the frame's depth can have seen are rendered: on the observed surface
    # (within tau) or on a pixel without depth. A model carries stray voxels (static surface that
    # keyframes at rest labelled part); in front of the part they won the z-buffer and cut holes in
    # its mask (plain_rev_wall_cabinet_00: 23 % of the model 0.5 m off the leaf, a third of the leaf
    # unmasked while it opened). Occluders and background still fail, as no model point lies there.
    d_at = view.depth_m.ravel()[pixel]
    seen = (d_at <= 0) | (np.abs(d_at - z) < depth_tolerance(z, config.depth_tolerance_m, config.depth_tolerance_range_m))
    pixel, z = pixel[seen], z[seen]
    z_pred = np.full(H * W, np.inf, dtype=np.float32)
    np.minimum.at(z_pred, pixel, z)  # z-buffer: the nearest surface per pixel
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
    tau = depth_tolerance(d, config.depth_tolerance_m, config.depth_tolerance_range_m).astype(np.float32)
    # Hand pixels are not excluded where the observed depth lies on the posed model: there the depth is
    # the part's surface (or a finger touching it, within tau). Hand masks detected as foreground that blocks
    # free space (captures without hand masks) cover the moving front itself while the arm pulls it: measured
    # on the dumped inputs of 8 bench sequences, the hand covered 20-28 thousand of the 28-42 thousand true
    # part pixels of geo_angled_pri_drawer_00 frames 69-76 and 23 of 27 thousand of mw_door_00 frame 85
    # (mIoU 79.5 -> 87.8 and 90.0 -> 95.4); with capture hand masks (dilated by hand_margin_px) the
    # false-positive pixels did not grow measurably (mw_window_00, geo_angled_rev_cabinet_00: +0.3, +1.6 mIoU).
    mask = silhouette & (d > 0) & (d > z_near - tau) & (d < z_far + tau)
    if config.fill_missing_depth:
        closed = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, kernel) > 0
        mask |= closed & silhouette & (d <= 0) & ~view.hand
    return mask


__all__ = ["PartMasks", "SegmentationConfig", "decode_mask", "encode_mask", "segment_parts"]
