"""Whether intrinsics can describe the camera that took a capture (checked when a capture is loaded)."""

from __future__ import annotations

import math
from typing import Protocol

MAX_IMAGE_PIXELS = 50_000_000
"""Largest image accepted, pixels (8K UHD is 33 MP); checked from headers before anything is decoded."""
ASPECT_RANGE = (0.5, 2.0)
"""Plausible fx / fy (square pixels: 1)."""
FOV_RANGE_DEG = (10.0, 170.0)
"""Plausible horizontal and vertical fields of view, degrees."""


class _Intrinsics(Protocol):
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


def intrinsics_problem(K: _Intrinsics) -> str | None:
    """Why intrinsics cannot describe the camera that took a capture, or None.

    Refuses an image over ``MAX_IMAGE_PIXELS``, fx / fy outside ``ASPECT_RANGE``, a field of view outside
    ``FOV_RANGE_DEG`` and a principal point more than a quarter of the image outside it.
    """
    if K.width * K.height > MAX_IMAGE_PIXELS:
        return f"{K.width}x{K.height} is {K.width * K.height / 1e6:.0f} MP; at most {MAX_IMAGE_PIXELS / 1e6:.0f} MP are accepted"
    aspect = K.fx / K.fy
    if not ASPECT_RANGE[0] <= aspect <= ASPECT_RANGE[1]:
        return (f"fx {K.fx:g} and fy {K.fy:g} differ by a factor {max(aspect, 1 / aspect):.1f}: depth cameras have (nearly) square "
                f"pixels, expected {ASPECT_RANGE[0]} <= fx/fy <= {ASPECT_RANGE[1]}")
    for name, size, focal in (("horizontal", K.width, K.fx), ("vertical", K.height, K.fy)):
        fov = math.degrees(2.0 * math.atan(size / (2.0 * focal)))
        if not FOV_RANGE_DEG[0] <= fov <= FOV_RANGE_DEG[1]:
            return f"{name} field of view {fov:.1f} deg (size {size} px, focal {focal:g} px) is outside {FOV_RANGE_DEG} deg"
    for name, centre, size in (("cx", K.cx, K.width), ("cy", K.cy, K.height)):
        if not -0.25 * size <= centre <= 1.25 * size:
            return f"principal point {name} {centre:g} is far outside the {size}-pixel image"
    return None


__all__ = ["ASPECT_RANGE", "FOV_RANGE_DEG", "MAX_IMAGE_PIXELS", "intrinsics_problem"]
