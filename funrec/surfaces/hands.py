"""Hand masks of every frame: the capture's own masks when it has them, otherwise detected as
surfaces that violate the free space seen by neighbouring frames, grown by a skin-colour model
learned from those detections in the same video.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from funrec.camera.tracking import CameraTrajectory, Progress
from funrec.formats.affordances import HAND_SOURCES, TWIN_HAND_MASKS
from funrec.formats.capture import Capture
from funrec.formats.twin import ArticulatedPart
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform
from funrec.parallel import in_order
from funrec.surfaces.segmentation import EncodedMasks, PartMasks, encode_mask
from funrec.typed import BoolArray, Float32Array, FloatArray, IntArray, UInt8Array

logger = logging.getLogger(__name__)

_SAME_POSE = 1e-6
"""Entries of a part's relative motion between two frames below this (m, or rotation-matrix
units) mean the part did not move: its motion hypothesis is then the static one."""
_NO_DEPTH = 1e3
"""Stand-in depth (m) for missing readings inside the min filter: farther than any sensor reads,
so a hole never hides a real surface, and windows of holes only stay untestable."""


@dataclass(frozen=True)
class HandConfig:
    """Settings of :func:`detect_hands`; defaults suit 640x480 egocentric RGB-D at 15-30 fps."""

    use_capture_masks: bool = True
    """Return the capture's masks/hand/ files when it has them (frames without a file are empty);
    False always detects (evaluation, or masks not trusted)."""
    work_width_px: int = 320
    """Detection runs at this image width (never upsampled); 320 px keeps a forearm 20+ px wide
    at arm's length and costs a quarter of full resolution."""
    reference_offsets_s: tuple[float, ...] = (-3.2, -1.6, -0.8, -0.4, 0.4, 0.8, 1.6, 3.2)
    """Times of the reference frames relative to the tested frame, seconds. A hand moves several
    centimetres in 0.4 s while reaching or pulling; references 1.6-3.2 s away often see the scene
    without the hand and from farther away, which separates the static scene from the arm
    that moves with the head (on the synthetic bench, mean IoU 0.87 with the four nearest only)."""
    free_space_margin_m: float = 0.02
    """A pixel violates a reference frame's free space when it lies closer to that camera than the
    surface it saw by this margin plus ``free_space_margin_per_m`` times the depth, metres: several
    sigma of Kinect-class depth noise (~3 mm at 1 m) plus ~1 cm of pose and joint error."""
    free_space_margin_per_m: float = 0.02
    """Depth-proportional part of the free-space margin, metres per metre of depth."""
    reference_window_px: int = 3
    """Side of the min filter on the reference depth (working resolution, odd): a reprojected pixel
    next to a depth edge must clear the nearest surface of the window, not the one behind it."""
    max_range_m: float = 1.2
    """Hand and arm points lie within arm's reach of the eyes (shoulder offset + 0.8 m arm), metres;
    detections beyond are other moving things."""
    min_range_m: float = 0.1
    """Readings nearer than this are ignored, metres (below any RGB-D sensor's minimum range)."""
    seed_opening_px: int = 3
    """Side of the morphological opening of the free-space detections (working resolution):
    removes isolated violations at depth edges and flying pixels."""
    min_component_fraction: float = 0.0008
    """Detections in connected pieces smaller than this fraction of the image are dropped
    (60 px at 320x240; a hand at 1.2 m covers over ten times more)."""
    colour_bins: int = 128
    """Bins per chroma axis (Cr, Cb of YCrCb) of the skin and background colour histograms. Fine
    bins separate skin from wood and warm floors: mean IoU on the synthetic bench 0.931 with 32,
    0.946 with 64, 0.951 with 128 bins (measured)."""
    colour_smoothing_bins: float = 1.0
    """Gaussian smoothing of the histograms, bins (fills gaps between the bins actually seen)."""
    luma_range: tuple[int, int] = (25, 240)
    """Pixels with luma (Y, 0-255) outside this range have unreliable chroma and no colour vote."""
    skin_probability: float = 0.6
    """A pixel is skin-coloured when P(skin | chroma) exceeds this (equal priors)."""
    min_colour_samples: float = 0.02
    """Fewest free-space detections (whole video) needed to learn the colour model, as a fraction
    of one image's pixels; with fewer, the detections are returned without colour growth."""
    min_seed_overlap: float = 0.0003
    """A skin-coloured region joins the hand only if it holds detected pixels amounting to this
    fraction of the image (23 px at 320x240): colour alone never makes a hand."""
    max_component_fraction: float = 0.45
    """A grown region larger than this fraction of the image is a leak into a skin-coloured
    background and keeps only its detected pixels."""
    depth_edge_m: float = 0.03
    """Depth steps larger than this (plus ``depth_edge_per_m`` times the depth) between
    neighbouring pixels separate regions during growth, metres: a hand in front of the scene is
    bounded by such steps."""
    depth_edge_per_m: float = 0.03
    """Depth-proportional part of the depth-edge threshold, metres per metre."""
    two_sided: bool = True
    """A pixel is a seed only if it violates a past and a future reference frame (each side that
    has a testable reference): a hand comes and goes, so the space it fills at one time is free
    both before and after, while a part whose motion is estimated wrongly (tracked too short, a
    state off) leaves free space on one side only, where it swung away or will swing to. Such
    pixels also count as static scene (no colour growth into them). Measured on a reconstructed
    wall cabinet whose tracked span ended while the door still opened: IoU 17 % one-sided, 70 %
    two-sided; with exact (ground-truth) part motion it costs about 2 points (97 % to 95 %)."""
    min_static_references: int = 2
    """A pixel that agrees with at least this many reference frames (its reprojection matches the
    depth seen there, while the depth at the same pixel, which an object carried with the camera
    would keep, does not) and violates none is static scene and never grows into the hand, whatever its colour: this stops growth into
    skin-coloured furniture that the hand touches without a depth step."""
    closing_px: int = 5
    """Side of the final morphological closing (working resolution), filling gaps at fingers."""
    threads: int = 2
    """Frames worked on at once, in threads (the whole-image numpy and OpenCV operations release
    the GIL, so a second core shares the work); the masks do not depend on it. 1: one at a time."""

    def __post_init__(self) -> None:
        if self.work_width_px < 16 or not self.reference_offsets_s or 0.0 in self.reference_offsets_s:
            raise ValueError(f"HandConfig needs work_width_px >= 16 and non-zero reference offsets, got {self}")
        if not 0.0 < self.skin_probability < 1.0 or self.colour_bins < 4:
            raise ValueError(f"HandConfig needs 0 < skin_probability < 1 and colour_bins >= 4, got {self}")
        if self.reference_window_px % 2 == 0 or self.seed_opening_px % 2 == 0 or self.closing_px % 2 == 0:
            raise ValueError("HandConfig window, opening and closing sizes must be odd")
        if self.threads < 1:
            raise ValueError(f"HandConfig needs threads >= 1, got {self.threads}")


@dataclass(frozen=True)
class HandMasks(EncodedMasks):
    """Per-frame hand masks (255 = hand or arm), every frame of the capture in order."""

    source: str
    """"capture" (the capture's masks/hand/ files) or "detected" (:func:`detect_hands`)."""
    colour_model: bool = False
    """True when detected masks were grown with a learned skin-colour model."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.source not in HAND_SOURCES:
            raise ValueError(f"source must be one of {HAND_SOURCES}, got {self.source!r}")


def part_poses(part: ArticulatedPart, frame_count: int) -> FloatArray:
    """(F, 4, 4) T_world_part at every frame: canonical part -> posed part, world frame.

    States between tracked frames are interpolated linearly; before the first and after the
    last tracked frame the part holds its first and last tracked state (a part is only tracked
    while it moves, so outside that span it rests).
    """
    if len(part.frames) == 0:
        return np.broadcast_to(np.eye(4), (frame_count, 4, 4)).copy()
    states = np.interp(np.arange(frame_count), part.frames, part.states)
    return joint_transforms(part.joint_type, part.axis_world, part.pivot_world, states)


def detect_hands(
    capture: Capture,
    trajectory: CameraTrajectory,
    parts: Sequence[ArticulatedPart] = (),
    part_masks: Sequence[PartMasks] = (),
    config: HandConfig = HandConfig(),  # noqa: B008 (frozen, immutable default)
    progress: Progress | None = None,
) -> HandMasks:
    """Hand (and arm) masks of every frame.

    With capture masks (and ``config.use_capture_masks``) they are returned as they are.
    Otherwise, at ``work_width_px``:

    1. Free-space violations: each pixel of frame i is lifted with its depth and moved into
       the reference frames i + ``reference_offsets_s``: pixels of a part's mask by the camera
       and that part's motion, other pixels by the camera motion and, where a part moved, by
       that part's motion too. A pixel that lands in front of the surface a reference camera
       saw (by the free-space margin) under every hypothesis is where something was absent at
       that time: it moves independently of the scene and of the parts. Violations within
       ``max_range_m`` (the egocentric arm's reach), found both in past and in future
       references (``two_sided``), that survive an opening are seeds. Pixels
       that agree with references where the camera moved enough to tell are static scene.
    2. Skin colour, adaptive per video: chroma histograms (Cr, Cb) of the seeds and of the
       static scene give P(skin | chroma).
    3. Growth: skin-coloured pixels within reach that are not static scene, split at depth
       edges, form regions; a region holding enough seeds (``min_seed_overlap``) joins the
       hand. This recovers the parts of the arm that move with the camera (near the shoulder)
       or with the held part (the fingers on the handle).

    Frames are streamed twice (seeds, colour statistics and the depth masks growth needs, then
    growth from the colour images alone); only the reference window of depth images is held.

    Args:
        capture: the capture.
        trajectory: camera poses ``T_world_camera`` (F, 4, 4).
        parts: articulated parts (joint and tracked states, world frame); their motion
            compensates their pixels.
        part_masks: per-part masks aligned with ``parts`` (or empty: parts then count as static,
            and a moving part may be detected as hand while it moves towards the camera).
        config: settings.
        progress: optional ``progress(done, total)`` over the two passes.

    Returns:
        :class:`HandMasks` for every frame, full resolution.

    Raises:
        ValueError: the trajectory or the part masks do not match the capture.
    """
    F = len(capture)
    H, W = capture.intrinsics.height, capture.intrinsics.width
    if np.shape(trajectory.T_world_camera) != (F, 4, 4):
        raise ValueError(f"trajectory has {len(trajectory.T_world_camera)} poses for {F} frames")
    if part_masks and len(part_masks) != len(parts):
        raise ValueError(f"{len(part_masks)} part mask sets for {len(parts)} parts; give one per part or none")
    if capture.has_hand_masks and config.use_capture_masks:
        png = []
        for frame in range(F):
            mask = capture.mask("hand", frame)
            png.append(encode_mask(np.zeros((H, W), dtype=bool) if mask is None else mask))
        return HandMasks(np.arange(F, dtype=np.int64), tuple(png), H, W, "capture")
    return _Detector(capture, trajectory, parts, part_masks, config).run(progress)


class _Detector:
    """State of one detection run (private): working-resolution geometry and the depth window."""

    def __init__(
        self,
        capture: Capture,
        trajectory: CameraTrajectory,
        parts: Sequence[ArticulatedPart],
        part_masks: Sequence[PartMasks],
        config: HandConfig,
    ) -> None:
        self.capture, self.config = capture, config
        self.F = len(capture)
        intr = capture.intrinsics
        self.scale = max(1.0, intr.width / config.work_width_px)
        self.size = (round(intr.width / self.scale), round(intr.height / self.scale))
        sx, sy = self.size[0] / intr.width, self.size[1] / intr.height
        # Pixel centres map as u' = (u + 0.5) s - 0.5 under cv2.resize.
        self.K = np.array([[intr.fx * sx, 0.0, (intr.cx + 0.5) * sx - 0.5], [0.0, intr.fy * sy, (intr.cy + 0.5) * sy - 0.5], [0.0, 0.0, 1.0]])
        w, h = self.size
        v, u = np.mgrid[0:h, 0:w]
        self.rays_by_row = np.stack([(u - self.K[0, 2]) / self.K[0, 0], (v - self.K[1, 2]) / self.K[1, 1], np.ones((h, w))]).reshape(3, -1)
        """(3, h*w) viewing ray (z = 1) of every pixel, one row per coordinate."""
        self.T_world_camera = np.asarray(trajectory.T_world_camera, dtype=np.float64)
        self.T_camera_world = invert_transform(self.T_world_camera)
        self.T_world_part = [part_poses(p, self.F) for p in parts]
        self.part_index = [{int(f): k for k, f in enumerate(m.frames)} for m in part_masks]
        self.part_masks = part_masks
        # At least one frame away, whatever the frame rate.
        self.offsets = sorted({int(round(s * intr.fps)) or int(np.sign(s)) for s in config.reference_offsets_s})
        self._depth: dict[int, Float32Array] = {}
        self._min_depth: dict[int, Float32Array] = {}

    # -- inputs at working resolution ------------------------------------------------------
    def _resize(self, image: np.ndarray, nearest: bool = True) -> np.ndarray:
        if image.shape[1] == self.size[0]:
            return image
        return cv2.resize(image, self.size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)

    # Depth images are held flat with one more reading, the one of pixels outside the image, so that
    # a reprojection reads them with one gather (no masked replacement after it).
    def depth(self, frame: int) -> Float32Array:
        """(h, w) depth of a frame at working resolution, metres, 0 = no reading."""
        return self.depth_flat(frame)[:-1].reshape(self.size[1], self.size[0])

    def depth_flat(self, frame: int) -> Float32Array:
        """(h*w + 1,) :meth:`depth` flat, then 0 (no reading) for pixels outside the image."""
        depth = self._depth.get(frame)
        if depth is None:  # two threads may both decode a frame: the same values
            depth = self._depth[frame] = _padded(self._resize(self.capture.depth_m(frame).astype(np.float32)), 0.0)
        return depth

    def min_depth(self, frame: int) -> Float32Array:
        """(h*w + 1,) min-filtered depth of a reference frame, flat, holes at ``_NO_DEPTH``, then
        ``_NO_DEPTH`` for pixels outside the image."""
        near = self._min_depth.get(frame)
        if near is None:
            d = self.depth(frame)
            size = self.config.reference_window_px
            near = self._min_depth[frame] = _padded(cv2.erode(np.where(d > 0, d, _NO_DEPTH).astype(np.float32), np.ones((size, size), np.uint8)), _NO_DEPTH)
        return near

    def evict(self, before: int) -> None:
        """Forget the depth of frames before ``before`` (no frame worked on still needs them)."""
        for cache in (self._depth, self._min_depth):
            for frame in [f for f in list(cache) if f < before]:  # list(): one step, while threads add frames
                cache.pop(frame, None)

    def labels(self, frame: int) -> IntArray:
        """(h*w,) 0 for static pixels, k + 1 for pixels of part k's mask."""
        labels = np.zeros(self.size[1] * self.size[0], dtype=np.int64)
        for k, index in enumerate(self.part_index):
            if frame in index:
                mask = self._resize(self.part_masks[k].mask(index[frame]).astype(np.uint8)) > 0
                labels[mask.ravel()] = k + 1
        return labels

    # -- pass 1: free-space violations -----------------------------------------------------
    def _reproject(self, p_camera: FloatArray, T_ref_frame: FloatArray, ref: int) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
        """Move (3, n) points of a frame (one row per coordinate) into reference camera ``ref``
        with ``T_ref_frame``.

        Returns:
            z_ref (n,) depth in the reference camera; seen (n,) min-filtered and exact (n,) raw
            reference depth at the reprojection (float32; ``_NO_DEPTH`` and 0 outside the
            image); ok (n,) whether the reprojection could be tested.
        """
        w, h = self.size
        R, t = T_ref_frame[:3, :3], T_ref_frame[:3, 3]
        # Row by row on contiguous coordinate rows: 7x faster than einsum over (n, 3) points and,
        # unlike a BLAS product, no threads that compete with other work on a small machine
        # (ten times slower, measured). In place, one flat gather instead of boolean-masked
        # indexing: half the time of the expression form (~40 % of a detection), the same
        # arithmetic in the same order, so the same bits.
        x, y, z = p_camera
        scratch = np.empty_like(x)

        def row(i: int) -> FloatArray:  # R[i, 0] x + R[i, 1] y + R[i, 2] z + t[i], summed left to right
            out = np.multiply(R[i, 0], x)
            out += np.multiply(R[i, 1], y, out=scratch)
            out += np.multiply(R[i, 2], z, out=scratch)
            out += t[i]
            return out

        z_ref = row(2)
        u, v = row(0), row(1)
        with np.errstate(invalid="ignore", divide="ignore"):
            for image, f, c in ((u, self.K[0, 0], self.K[0, 2]), (v, self.K[1, 1], self.K[1, 2])):
                image *= f
                image /= z_ref
                image += c
                np.rint(image, out=image)
        inside = z_ref > self.config.min_range_m
        inside &= u >= 0
        inside &= u < w
        inside &= v >= 0
        inside &= v < h
        v *= w  # pixel index v w + u, exact in float64; h w outside (the padded reading)
        v += u
        np.copyto(v, float(w * h), where=~inside)
        index = v.astype(np.intp)
        seen = self.min_depth(ref)[index]
        exact = self.depth_flat(ref)[index]
        return z_ref, seen, exact, inside & (seen < _NO_DEPTH)

    def _margin(self, z: FloatArray) -> FloatArray:
        return self.config.free_space_margin_m + self.config.free_space_margin_per_m * z

    def violations(self, frame: int) -> tuple[BoolArray, BoolArray]:
        """(h, w) seeds (violations within reach, opened) and (h, w) static pixels (agree with at
        least ``min_static_references`` references and violate none).

        A pixel of part k's mask is tested under part k's motion only. Any other pixel is tested
        under the static hypothesis and under the motion of every part whose state differs
        between the two frames, and violates only if no hypothesis explains it: part pixels
        outside the part's masks (its masks cover the tracked frames only) are then no hand.

        Pixels beyond reach (``max_range_m``) are tested only when the frame has seeds: seeds lie
        within reach, growth only reaches pixels within reach (:meth:`depth_masks`), and the static
        pixels beyond reach count only in the scene colour statistics of frames with seeds. Each
        pixel is tested on its own, so the masks are those of testing every pixel, at about half
        the cost (most of a room is beyond arm's reach, and about half the frames show no hand).
        """
        cfg = self.config
        w, h = self.size
        depth = self.depth(frame)
        z = depth.ravel().astype(np.float64)
        valid = z > cfg.min_range_m
        p_camera = self.rays_by_row * z  # (3, h*w): one contiguous row per coordinate
        labels = self.labels(frame)
        count = np.zeros(h * w, dtype=np.int32)
        agree = np.zeros(h * w, dtype=np.int32)
        # Per side (past references, future references): violated by one / tested by one.
        side_violated = np.zeros((2, h * w), dtype=bool)
        side_tested = np.zeros((2, h * w), dtype=bool)
        reach = valid & (np.linalg.norm(p_camera, axis=0) < cfg.max_range_m)
        near = reach | (depth.ravel() < cfg.max_range_m)  # as depth_masks compares them

        def test(pixels: IntArray) -> BoolArray:
            """Test ``pixels``; (h*w,) the pixels violating so far."""
            count[pixels], side_violated[:, pixels], side_tested[:, pixels], agree[pixels] = self._tests(
                frame, pixels, z, p_camera, labels)
            violating = count > 0
            if cfg.two_sided:
                violating &= np.all(side_violated | ~side_tested, axis=0)
            return violating

        violating = test(np.flatnonzero(valid & near))
        seeds = (violating & reach).reshape(h, w).astype(np.uint8)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cfg.seed_opening_px, cfg.seed_opening_px))
        seeds = cv2.morphologyEx(seeds, cv2.MORPH_OPEN, kernel)
        seeds = _drop_small(seeds > 0, cfg.min_component_fraction * w * h)
        if seeds.any():  # the pixels beyond reach are needed only then (see above)
            violating = test(np.flatnonzero(valid & ~near))
        # With two_sided, a pixel that violates one side only (a part whose motion is estimated
        # wrongly) is static where it agrees with enough references: it must not be grown into.
        static = ((agree >= cfg.min_static_references) & ~(violating if cfg.two_sided else count > 0)).reshape(h, w)
        return seeds, static

    def _tests(self, frame: int, pixels: IntArray, z: FloatArray, p_camera: FloatArray, labels: IntArray
               ) -> tuple[IntArray, BoolArray, BoolArray, IntArray]:
        """The reference tests of some valid pixels of a frame: (n,) flat ``pixels`` of the frame's
        (h*w,) depths ``z``, (3, h*w) points ``p_camera`` and (h*w,) labels (:meth:`labels`).

        Returns:
            (n,) references violated, (2, n) violated by a past / future one, (2, n) tested by a
            past / future one, (n,) references agreed with (static evidence).
        """
        n = len(pixels)
        labels, z = labels[pixels], z[pixels]
        # Each label's pixels (static scene, then part k + 1's mask) and their points, once per call.
        groups = [(label, group, p_camera[:, pixels[group]]) for label in range(len(self.T_world_part) + 1)
                  if len(group := np.flatnonzero(labels == label))]
        margin_z = self._margin(z)
        count = np.zeros(n, dtype=np.int32)
        agree = np.zeros(n, dtype=np.int32)
        side_violated = np.zeros((2, n), dtype=bool)
        side_tested = np.zeros((2, n), dtype=bool)
        T_world_frame = self.T_world_camera[frame]
        for offset in self.offsets:
            ref = frame + offset
            if not 0 <= ref < self.F:
                continue
            T_ref_world = self.T_camera_world[ref]
            T_move = [T_world_part[ref] @ invert_transform(T_world_part[frame]) for T_world_part in self.T_world_part]
            moved = [k for k, T in enumerate(T_move) if not np.allclose(T, np.eye(4), atol=_SAME_POSE)]
            violated = np.zeros(n, dtype=bool)
            ok = np.zeros(n, dtype=bool)
            consistent = np.zeros(n, dtype=bool)
            for label, group, p_group in groups:
                own = T_ref_world @ (T_world_frame if label == 0 else T_move[label - 1] @ T_world_frame)
                z_ref, seen, exact, tested = self._reproject(p_group, own, ref)
                margin = self._margin(z_ref)
                hit = tested & (z_ref < seen - margin)
                if label == 0:
                    for k in moved:
                        suspect = np.flatnonzero(hit)
                        z_k, seen_k, _, tested_k = self._reproject(p_group[:, suspect], T_ref_world @ T_move[k] @ T_world_frame, ref)
                        hit[suspect] = ~tested_k | (z_k < seen_k - self._margin(z_k))
                violated[group] = hit
                ok[group] = tested
                consistent[group] = tested & (np.abs(exact - z_ref) < margin)  # raw, not min-filtered
            count += violated
            side_violated[int(offset > 0)] |= violated
            side_tested[int(offset > 0)] |= ok
            # Static evidence needs the hypothesis to agree where the camera-rigid one (same
            # pixel, same depth) does not: the arm near the shoulder moves with the head and
            # agrees with both, so it never counts as scene.
            same_pixel = self.depth_flat(ref)[pixels]
            rigid = (same_pixel > 0) & (np.abs(same_pixel - z) < margin_z)
            agree += ok & consistent & ~violated & ~rigid
        return count, side_violated, side_tested, agree

    # -- pass 2: colour growth -------------------------------------------------------------
    def chroma_bins(self, rgb: UInt8Array) -> tuple[IntArray, BoolArray]:
        """(h, w) histogram bin of each pixel's chroma and (h, w) pixels with usable luma."""
        ycrcb = cv2.cvtColor(self._resize(rgb, nearest=False), cv2.COLOR_RGB2YCrCb)
        bins = self.config.colour_bins
        cr = ycrcb[..., 1].astype(np.int64) * bins // 256
        cb = ycrcb[..., 2].astype(np.int64) * bins // 256
        lo, hi = self.config.luma_range
        return cr * bins + cb, (ycrcb[..., 0] >= lo) & (ycrcb[..., 0] <= hi)

    def depth_masks(self, frame: int) -> tuple[BoolArray, BoolArray]:
        """(h, w) pixels within reach (or without depth) and, of those, the ones off depth edges:
        all that growth needs of a frame's depth, kept from pass 1 so pass 2 reads no depth."""
        z = self.depth(frame)
        near = (z <= 0) | (z < self.config.max_range_m)
        return near, near & ~_depth_edges(z, self.config)

    def grow(self, frame: int, seeds: BoolArray, static: BoolArray, near: BoolArray, growable: BoolArray,
             skin: FloatArray | None) -> BoolArray:
        cfg = self.config
        w, h = self.size
        if skin is None:
            grown = seeds
        else:
            bins, usable = self.chroma_bins(self.capture.rgb(frame))
            candidate = (skin[bins] > cfg.skin_probability) & usable & growable & ~static
            count, labels = cv2.connectedComponents((candidate | seeds).astype(np.uint8), connectivity=8)
            seeds_per = np.bincount(labels[seeds], minlength=count)
            area = np.bincount(labels.ravel(), minlength=count)
            keep = (seeds_per >= max(1.0, cfg.min_seed_overlap * w * h)) & (area <= cfg.max_component_fraction * w * h)
            keep[0] = False
            grown = keep[labels] | seeds
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cfg.closing_px, cfg.closing_px))
        closed = cv2.morphologyEx(grown.astype(np.uint8), cv2.MORPH_CLOSE, kernel) > 0
        return closed & near  # closing must not bridge onto the scene behind

    def _unpack(self, bits: UInt8Array) -> BoolArray:
        """(h, w) bool mask from ``np.packbits`` of it."""
        w, h = self.size
        return np.unpackbits(bits, count=h * w).reshape(h, w).view(bool)

    def run(self, progress: Progress | None) -> HandMasks:
        cfg = self.config
        F = self.F
        bins = cfg.colour_bins
        hist_skin = np.zeros(bins * bins)
        hist_scene = np.zeros(bins * bins)
        # Pass 1's masks for pass 2, packed 8 pixels a byte: lossless like PNG at a 30th of its
        # encoding time (PNG encoding took 8 of the 123 CPU-s of plain_rev_cabinet_right_00).
        seed_bits, static_bits, near_bits, growable_bits = [], [], [], []

        def first_pass(frame: int) -> tuple[list[UInt8Array], tuple[IntArray, IntArray] | None]:
            """A frame's packed seed, static, near and growable masks, and its skin and scene chroma counts."""
            seeds, static = self.violations(frame)
            near, growable = self.depth_masks(frame)
            counts = None
            if seeds.any():
                chroma, usable = self.chroma_bins(self.capture.rgb(frame))
                core = cv2.erode(seeds.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
                counts = (np.bincount(chroma[core & usable], minlength=bins * bins),
                          np.bincount(chroma[static & usable], minlength=bins * bins))
            return [np.packbits(mask) for mask in (seeds, static, near, growable)], counts

        # handed out in frame order: the histograms sum in the same order, and the depth window moves on
        for frame, (packed, counts) in enumerate(in_order(first_pass, range(F), cfg.threads, "funrec-hands")):
            for store, bits in zip((seed_bits, static_bits, near_bits, growable_bits), packed, strict=True):
                store.append(bits)
            if counts is not None:
                hist_skin += counts[0]
                hist_scene += counts[1]
            self.evict(frame + 1 + min(self.offsets))  # the frames after it are worked on: their window is kept
            if progress is not None:
                progress(frame + 1, 2 * F)
        skin = _skin_probability(hist_skin, hist_scene, cfg.min_colour_samples * self.size[0] * self.size[1], cfg)
        logger.info("hand detection: %d seed pixels; colour model %s", int(hist_skin.sum()), "learned" if skin is not None else "not learned (too few seeds)")
        self._depth.clear()
        self._min_depth.clear()
        H, W = self.capture.intrinsics.height, self.capture.intrinsics.width

        def second_pass(frame: int) -> bytes:
            mask = self.grow(frame, *(self._unpack(store[frame]) for store in (seed_bits, static_bits, near_bits, growable_bits)), skin)
            if mask.shape != (H, W):
                mask = cv2.resize(mask.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR) > 0.5
            return encode_mask(mask)

        png = []
        for frame, encoded in enumerate(in_order(second_pass, range(F), cfg.threads, "funrec-hands")):
            png.append(encoded)
            if progress is not None:
                progress(F + frame + 1, 2 * F)
        return HandMasks(np.arange(F, dtype=np.int64), tuple(png), H, W, "detected", colour_model=skin is not None)


def write_hand_masks(folder: str | Path, hands: HandMasks) -> None:
    """Write every mask as ``folder/<frame:06d>.png`` (8-bit, 255 = hand), e.g. a twin's
    :data:`TWIN_HAND_MASKS`; the stored PNG bytes are written as they are."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for frame, png in zip(hands.frames, hands.png):
        (folder / f"{int(frame):06d}.png").write_bytes(png)


def _padded(image: np.ndarray, outside: float) -> np.ndarray:
    """(h*w + 1,) ``image`` flat, then ``outside``."""
    flat = np.empty(image.size + 1, dtype=image.dtype)
    flat[:-1] = image.ravel()
    flat[-1] = outside
    return flat


def _drop_small(mask: BoolArray, min_area: float) -> BoolArray:
    """Remove 8-connected pieces of ``mask`` smaller than ``min_area`` pixels."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area
    keep[0] = False
    return keep[labels]


def _depth_edges(depth_m: Float32Array, config: HandConfig) -> BoolArray:
    """(h, w) pixels next to a depth step (3x3 max - min above the threshold at that depth)."""
    d = np.where(depth_m > 0, depth_m, 0).astype(np.float32)
    kernel = np.ones((3, 3), np.uint8)
    high = cv2.dilate(d, kernel)
    low = cv2.erode(np.where(d > 0, d, _NO_DEPTH).astype(np.float32), kernel)
    low = np.where(low >= _NO_DEPTH, high, low)
    return (d > 0) & (high - low > config.depth_edge_m + config.depth_edge_per_m * d)


def _skin_probability(hist_skin: FloatArray, hist_scene: FloatArray, min_samples: float, config: HandConfig) -> FloatArray | None:
    """(bins*bins,) P(skin | chroma bin) with equal priors, or None with fewer than ``min_samples``
    skin samples."""
    if hist_skin.sum() < min_samples or hist_scene.sum() == 0:
        return None
    bins = config.colour_bins
    sigma = config.colour_smoothing_bins

    def density(hist: FloatArray) -> FloatArray:
        smooth = cv2.GaussianBlur(hist.reshape(bins, bins).astype(np.float64), (0, 0), sigma) if sigma > 0 else hist.reshape(bins, bins)
        return smooth.ravel() / max(smooth.sum(), 1e-12)

    p_skin, p_scene = density(hist_skin), density(hist_scene)
    return p_skin / np.maximum(p_skin + p_scene, 1e-12)


__all__ = ["HAND_SOURCES", "TWIN_HAND_MASKS", "HandConfig", "HandMasks", "detect_hands", "part_poses", "write_hand_masks"]
