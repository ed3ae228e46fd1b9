"""Kinect-like depth and colour noise applied to exact renders.

Depth: range limits, holes along depth discontinuities, depth-dependent axial Gaussian noise
(Nguyen, Izadi and Lovell 2012: sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 metres), random
dropout, millimetre quantisation. Colour: slight optical blur and additive Gaussian noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from funrec.typed import FloatArray, UInt8Array


@dataclass(frozen=True)
class SensorNoise:
    """Parameters of the depth and colour noise model."""

    min_depth_m: float = 0.3
    """Closest reading; nearer surfaces read 0."""
    max_depth_m: float = 6.0
    """Farthest reading; farther surfaces read 0."""
    sigma_base_m: float = 0.0012
    """Axial noise at 0.4 m, metres (Nguyen et al. 2012)."""
    sigma_quad_per_m: float = 0.0019
    """Quadratic growth of the axial noise: sigma = base + quad (z - 0.4)^2, per metre."""
    edge_jump_m: float = 0.03
    """A pixel is on a depth edge when a 4-neighbour differs by more than this plus 2 % of its depth."""
    edge_drop_prob: float = 0.75
    """Probability of dropping an edge pixel."""
    edge_halo_prob: float = 0.3
    """Probability of dropping a pixel one step away from an edge."""
    dropout_prob: float = 0.003
    """Probability of dropping any other valid pixel."""
    depth_step_m: float = 0.001
    """Depth quantisation step, metres (depth_scale 1000)."""
    rgb_sigma: float = 2.0
    """Colour noise standard deviation, 8-bit levels."""
    blur_px: float = 0.6
    """Gaussian optical blur of the colour image (standard deviation, pixels); it also
    smooths the aliased edges of the renderer, which draws without multisampling."""

    def sigma_m(self, depth_m: npt.ArrayLike) -> FloatArray:
        """Axial noise standard deviation at each depth, metres."""
        z = np.asarray(depth_m, dtype=np.float64)
        return self.sigma_base_m + self.sigma_quad_per_m * (z - 0.4) ** 2


def depth_edges(depth_m: FloatArray, jump_m: float) -> npt.NDArray[np.bool_]:
    """Pixels with a 4-neighbour whose depth differs by more than ``jump_m + 0.02 z``
    (missing readings count as infinitely far).

    Args:
        depth_m: (H, W) depth in metres, 0 = none.
        jump_m: fixed part of the threshold, metres.

    Returns:
        (H, W) bool edge map.
    """
    z = np.where(depth_m > 0, depth_m, 1e3)
    padded = np.pad(z, 1, mode="edge")
    centre = padded[1:-1, 1:-1]
    threshold = jump_m + 0.02 * np.minimum(centre, 10.0)
    edges = np.zeros(depth_m.shape, dtype=bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        edges |= np.abs(padded[dy : dy + depth_m.shape[0], dx : dx + depth_m.shape[1]] - centre) > threshold
    return edges


def noisy_depth(
    depth_m: FloatArray, rng: np.random.Generator, noise: SensorNoise = SensorNoise(), exact: bool = False
) -> FloatArray:
    """Simulate a Kinect-like depth reading.

    Args:
        depth_m: (H, W) exact depth in metres, 0 = no surface.
        rng: random generator.
        noise: model parameters.
        exact: only apply the range limits and quantisation (noise-free switch).

    Returns:
        (H, W) float64 depth in metres, multiples of ``noise.depth_step_m``; 0 = no reading.
    """
    z = np.asarray(depth_m, dtype=np.float64)
    valid = (z >= noise.min_depth_m) & (z <= noise.max_depth_m)
    if not exact:
        edges = depth_edges(z, noise.edge_jump_m)
        halo = cv2.dilate(edges.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~edges
        u = rng.random(z.shape)
        drop = (edges & (u < noise.edge_drop_prob)) | (halo & (u < noise.edge_halo_prob)) | (u < noise.dropout_prob)
        z = z + rng.standard_normal(z.shape) * noise.sigma_m(z)
        valid &= ~drop & (z >= noise.min_depth_m) & (z <= noise.max_depth_m)
    out = np.round(z / noise.depth_step_m) * noise.depth_step_m
    return np.where(valid, out, 0.0)


def noisy_rgb(rgb: npt.ArrayLike, rng: np.random.Generator, noise: SensorNoise = SensorNoise()) -> UInt8Array:
    """Blur the colour image a little (optics) and add Gaussian colour noise.

    Args:
        rgb: (H, W, 3) uint8 colour.
        rng: random generator.
        noise: model parameters.

    Returns:
        (H, W, 3) uint8 noisy colour.
    """
    image = np.asarray(rgb, dtype=np.float32)
    if noise.blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), noise.blur_px)
    return np.clip(
        np.round(image + rng.standard_normal(image.shape, dtype=np.float32) * noise.rgb_sigma), 0, 255
    ).astype(np.uint8)


__all__ = ["SensorNoise", "depth_edges", "noisy_depth", "noisy_rgb"]
