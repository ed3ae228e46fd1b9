"""Self-tests of generated ground truth that use only the written files (capture and gt/).

The part-depth check: a pixel of a part's true mask must see the part's surface. Its depth,
lifted to the canonical pose through the true camera pose and the true joint state, must land
on the same surface when mapped into a frame a few frames later and compared with that
frame's depth under the part's mask. Depth seen through a window, or a mask that covers
something else, shows up as a large median disagreement.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from funrec.errors import FunrecError
from funrec.formats.capture import load_capture, read_mask
from funrec.formats.ground_truth import read_ground_truth
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.typed import FloatArray

PART_DEPTH_TOLERANCE_M = 0.015
"""Largest acceptable median part-depth disagreement between frames, metres (issue 12)."""


@dataclass(frozen=True)
class PartDepthConsistency:
    """How well one part's masked depth agrees with itself across frames through the true joint."""

    part: str
    """Ground-truth part name."""
    median_m: float | None
    """Median |predicted - observed| depth over all compared pixels, metres; None if none compared."""
    pixels: int
    """Pixels compared."""
    frame_pairs: int
    """Frame pairs (f, f + gap) with both masks present."""

    @property
    def ok(self) -> bool:
        return self.median_m is not None and self.median_m <= PART_DEPTH_TOLERANCE_M


def _lift(depth_m: FloatArray, mask: np.ndarray, K: FloatArray, stride: int) -> FloatArray:
    """(N, 3) camera-frame points of the masked pixels with a depth reading (every stride-th pixel)."""
    sub = np.zeros_like(mask)
    sub[::stride, ::stride] = True
    v, u = np.nonzero(mask & sub & (depth_m > 0))
    z = depth_m[v, u]
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)


def _residuals(p_camera: FloatArray, depth_m: FloatArray, mask: np.ndarray, K: FloatArray) -> FloatArray:
    """|z - depth| of camera-frame points that project inside ``mask`` onto a depth reading."""
    z = p_camera[:, 2]
    front = z > 1e-6
    u = np.round(K[0, 0] * p_camera[front, 0] / z[front] + K[0, 2]).astype(int)
    v = np.round(K[1, 1] * p_camera[front, 1] / z[front] + K[1, 2]).astype(int)
    H, W = depth_m.shape
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u, v, z = u[inside], v[inside], z[front][inside]
    keep = mask[v, u] & (depth_m[v, u] > 0)
    return np.abs(z[keep] - depth_m[v[keep], u[keep]])


def part_depth_consistency(
    capture_dir: str | Path, gap: int = 5, frame_step: int = 3, pixel_stride: int = 2
) -> tuple[PartDepthConsistency, ...]:
    """Check every true part of a generated capture (see the module docstring).

    Args:
        capture_dir: a capture folder with gt/ (FORMATS.md sections 1 and 4).
        gap: frames between the two frames of a pair.
        frame_step: use every frame_step-th first frame.
        pixel_stride: use every pixel_stride-th pixel in both image directions.

    Returns:
        One result per true part, in gt.json order.

    Raises:
        FunrecError: the capture or its ground truth cannot be read.
    """
    capture_dir = Path(capture_dir)
    capture = load_capture(capture_dir, check_headers=False)
    gt = read_ground_truth(capture_dir / "gt")
    intr = capture.intrinsics
    K = np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])
    results = []
    for gt_part in gt.parts:
        part = gt_part.part
        T_world_part = dict(zip(part.frames.tolist(), part.T_world_part()))
        residuals: list[FloatArray] = []
        pairs = 0
        for f in range(0, gt.frame_count - gap, frame_step):
            g = f + gap
            paths = (gt.mask_path(part.name, f), gt.mask_path(part.name, g))
            if f not in T_world_part or g not in T_world_part or not all(p.is_file() for p in paths):
                continue
            mask_f, mask_g = (read_mask(p) for p in paths)
            p_camera_f = _lift(capture.depth_m(f), mask_f, K, pixel_stride)
            if len(p_camera_f) == 0:
                continue
            # camera f -> world -> canonical part -> world at g -> camera g
            T_g_f = (
                invert_transform(gt.T_world_camera[g])
                @ T_world_part[g]
                @ invert_transform(T_world_part[f])
                @ gt.T_world_camera[f]
            )
            residuals.append(_residuals(transform_points(T_g_f, p_camera_f), capture.depth_m(g), mask_g, K))
            pairs += 1
        values = np.concatenate(residuals) if residuals else np.empty(0)
        median = float(np.median(values)) if len(values) else None
        results.append(PartDepthConsistency(part.name, median, int(len(values)), pairs))
    return tuple(results)


def check_part_depth(capture_dir: str | Path, gap: int = 5) -> tuple[PartDepthConsistency, ...]:
    """:func:`part_depth_consistency`, raising if any part disagrees by more than
    :data:`PART_DEPTH_TOLERANCE_M` (median) or cannot be compared at all.

    Raises:
        FunrecError: naming the capture, the part and its median disagreement.
    """
    results = part_depth_consistency(capture_dir, gap)
    bad = [r for r in results if not r.ok]
    if bad:
        listed = ", ".join(
            f"{r.part}: " + ("no comparable pixels" if r.median_m is None else f"median {100 * r.median_m:.2f} cm")
            for r in bad
        )
        raise FunrecError(
            f"{capture_dir}: masked part depth disagrees across {gap} frames through the true joint "
            f"(tolerance {100 * PART_DEPTH_TOLERANCE_M:.1f} cm): {listed}"
        )
    return results


__all__ = ["PART_DEPTH_TOLERANCE_M", "PartDepthConsistency", "check_part_depth", "part_depth_consistency"]
