"""Whether a readable capture is usable: enough frames, depth readings in a plausible unit, colour that is
not black, intrinsics that describe a real camera. ``funrec check`` fails a capture that no reconstruction
could use, naming the file (and frame) and what is wrong."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from funrec.errors import CaptureError
from funrec.formats.capture import Capture

MIN_FRAMES = 3
"""Fewest frames a reconstruction can use (tracking and articulation need motion across several views)."""
MIN_MEDIAN_DEPTH_M = 0.05
"""A capture whose median depth reading is nearer than this stores depth in another unit (e.g. metres as integers)."""
MAX_MEDIAN_DEPTH_M = 50.0
"""... or farther than this."""
MIN_VALID_DEPTH = 0.01
"""Fewest depth readings a frame must have, as a fraction of its pixels, for it to count."""
BLACK_LEVEL = 8
"""A colour frame whose brightest pixel is at most this is black."""
def check_capture_usable(capture: Capture, progress: Callable[[int, int], None] | None = None) -> None:
    """Decode every frame (and mask) and refuse a capture no reconstruction can use.

    Raises:
        CaptureError: fewer than ``MIN_FRAMES`` frames; no depth readings; depth in an implausible unit;
            black colour; each naming the file (and frame).
    """
    root, n = capture.root, len(capture)
    if n < MIN_FRAMES:
        raise CaptureError(root / "rgb", f"{n} frame{'s' if n != 1 else ''}; a reconstruction needs at least {MIN_FRAMES} "
                                         "(the camera must move across several views)")
    medians: list[float] = []
    no_depth: list[int] = []
    black: list[int] = []
    for frame in range(n):
        rgb = capture.rgb(frame)
        depth = capture.depth_m(frame)
        for kind in capture.mask_paths:
            capture.mask(kind, frame)
        valid = depth[depth > 0]
        if valid.size < MIN_VALID_DEPTH * depth.size:
            no_depth.append(frame)
        else:
            medians.append(float(np.median(valid)))
        if int(rgb.max()) <= BLACK_LEVEL:
            black.append(frame)
        if progress is not None:
            progress(frame + 1, n)
    _refuse_frames(capture.depth_paths, no_depth, n, f"fewer than {MIN_VALID_DEPTH:.0%} of its pixels have a depth reading")
    _refuse_frames(capture.rgb_paths, black, n, f"black (no pixel brighter than {BLACK_LEVEL})")
    median = float(np.median(medians))
    if not MIN_MEDIAN_DEPTH_M <= median <= MAX_MEDIAN_DEPTH_M:
        scale = capture.intrinsics.depth_scale
        raise CaptureError(
            capture.depth_paths[0],
            f"median depth reading {median:.4g} m with depth_scale {scale:g} is not a room-scale distance "
            f"({MIN_MEDIAN_DEPTH_M}-{MAX_MEDIAN_DEPTH_M} m): depth is stored in another unit (e.g. metres as integers); "
            "fix intrinsics.json's depth_scale or re-convert",
        )


def _refuse_frames(paths: tuple[Path, ...], frames: list[int], n: int, what: str) -> None:
    """Refuse when at least half the frames are unusable, naming the first."""
    if frames and 2 * len(frames) >= n:
        raise CaptureError(paths[frames[0]], f"{what}; so are {len(frames)} of {n} frames", frames[0])


__all__ = ["MIN_FRAMES", "check_capture_usable"]
