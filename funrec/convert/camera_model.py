"""Calibrated source cameras with lens distortion, and resampling into the undistorted pinhole
images of a capture (FORMATS.md has no distortion model)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from funrec.typed import BoolArray, FloatArray

UNPROJECT_MAX_REPROJECTION_PX = 1e-3
"""A pixel's undistorted ray is valid if it projects back within this many pixels (the Azure Kinect
SDK's unprojection accepts a squared error of 1e-6 px^2, i.e. 1e-3 px)."""
_UNDISTORT_ITERATIONS = 100
"""Fixed-point iterations of cv2.undistortPoints; the Azure Kinect depth lens (k1 ~ 0.5 with a
rational denominator) needs far more than OpenCV's default 5."""


@dataclass(frozen=True)
class LensCamera:
    """A camera with OpenCV-convention intrinsics (pixel centres at integers) and lens distortion."""

    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""
    K: FloatArray
    """(3, 3) intrinsic matrix."""
    distortion: FloatArray
    """(0,), (4,), (5,), (8,) OpenCV coefficients k1 k2 p1 p2 [k3 [k4 k5 k6]] (radial-tangential / Brown-Conrady
    with the rational denominator); empty or all zero for a pinhole camera."""
    max_radius: float | None = None
    """Radius in the normalised image plane (x = X/Z, y = Y/Z) beyond which the model is not valid (the Azure
    Kinect calibration's metric radius); None = no limit."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "distortion", np.asarray(self.distortion, dtype=np.float64).ravel())
        if self.distortion.size not in (0, 4, 5, 8, 12, 14):
            raise ValueError(f"distortion must have 0, 4, 5, 8, 12 or 14 OpenCV coefficients, got {self.distortion.size}")

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.distortion != 0))

    @property
    def size(self) -> tuple[int, int]:
        """(W, H)."""
        return self.width, self.height

    def rays(self) -> tuple[FloatArray, BoolArray]:
        """Undistorted normalised coordinates of every pixel centre.

        Returns:
            xy: (H*W, 2) x = X/Z, y = Y/Z in the camera frame, row-major pixel order.
            valid: (H*W,) False where the distortion model cannot be inverted (outside ``max_radius`` or
                not reprojecting within UNPROJECT_MAX_REPROJECTION_PX).
        """
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        uv = np.stack([u.ravel(), v.ravel()], axis=-1).astype(np.float64)
        if not self.has_distortion:
            xy = (uv - self.K[:2, 2]) / np.diag(self.K)[:2]
            return xy, np.ones(len(xy), dtype=bool)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, _UNDISTORT_ITERATIONS, 1e-12)
        xy = cv2.undistortPoints(uv[:, None, :], self.K, self.distortion, None, None, criteria=criteria)[:, 0, :]
        xy = xy.astype(np.float64)
        valid = np.all(np.isfinite(xy), axis=1)
        if self.max_radius is not None:
            valid &= np.sum(xy**2, axis=1) <= self.max_radius**2
        reprojected = self.project_normalised(np.where(valid[:, None], xy, 0.0))
        valid &= np.linalg.norm(reprojected - uv, axis=1) <= UNPROJECT_MAX_REPROJECTION_PX
        return xy, valid

    def project_normalised(self, xy: npt.ArrayLike) -> FloatArray:
        """Distort and project normalised coordinates.

        Args:
            xy: (N, 2) x = X/Z, y = Y/Z.

        Returns:
            (N, 2) pixels (u, v) in this camera's distorted image.
        """
        xy = np.asarray(xy, dtype=np.float64)
        p = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        uv, _ = cv2.projectPoints(p[:, None, :], np.zeros(3), np.zeros(3), self.K, self.distortion)
        return uv[:, 0, :].astype(np.float64)

    def undistort_maps(self, K_out: npt.ArrayLike, size_out: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap maps that resample this camera's image into an undistorted pinhole image.

        Args:
            K_out: (3, 3) intrinsics of the pinhole output.
            size_out: (W, H) of the output.

        Returns:
            (H, W) float32 source u and v of every output pixel.
        """
        K_out = np.asarray(K_out, dtype=np.float64)
        return cv2.initUndistortRectifyMap(self.K, self.distortion, None, K_out, size_out, cv2.CV_32FC1)


def scale_pinhole(K: npt.ArrayLike, size: tuple[int, int], output_width: int | None) -> tuple[FloatArray, tuple[int, int]]:
    """Intrinsics and size of an image resized to ``output_width`` (aspect kept, pixel centres mapped:
    u_out = (u + 0.5) * s - 0.5).

    Args:
        K: (3, 3) intrinsics of the full image.
        size: (W, H) of the full image.
        output_width: new width in pixels, or None to keep the size.

    Returns:
        (3, 3) scaled intrinsics and the new (W, H).
    """
    K = np.asarray(K, dtype=np.float64).copy()
    W, H = size
    if output_width is None or output_width == W:
        return K, (W, H)
    s = output_width / W
    out = (int(output_width), max(1, int(round(H * s))))
    sx, sy = out[0] / W, out[1] / H
    K_out = np.array([[K[0, 0] * sx, 0.0, (K[0, 2] + 0.5) * sx - 0.5], [0.0, K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5], [0, 0, 1.0]])
    return K_out, out


def remap_colour(rgb: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Resample a colour image with bilinear interpolation; pixels from outside the source are black."""
    return cv2.remap(rgb, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def remap_depth(depth: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Resample a depth image with nearest-neighbour interpolation, so that no depth is mixed across an
    edge; pixels from outside the source are 0 (no reading)."""
    return cv2.remap(depth, maps[0], maps[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def resize_colour(rgb: np.ndarray, size_out: tuple[int, int]) -> np.ndarray:
    """Resize a colour image to (W, H); area averaging when shrinking, bilinear when enlarging."""
    if (rgb.shape[1], rgb.shape[0]) == tuple(size_out):
        return rgb
    shrink = size_out[0] < rgb.shape[1]
    return cv2.resize(rgb, size_out, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def resize_depth(depth: np.ndarray, size_out: tuple[int, int]) -> np.ndarray:
    """Resize a depth image to (W, H) with nearest-neighbour sampling about pixel centres
    (u_src = (u_out + 0.5) * W_src / W_out - 0.5, rounded)."""
    H, W = depth.shape
    if (W, H) == tuple(size_out):
        return depth
    u = ((np.arange(size_out[0]) + 0.5) * W / size_out[0] - 0.5).round().clip(0, W - 1).astype(np.int64)
    v = ((np.arange(size_out[1]) + 0.5) * H / size_out[1] - 0.5).round().clip(0, H - 1).astype(np.int64)
    return depth[v[:, None], u[None, :]]


__all__ = [
    "UNPROJECT_MAX_REPROJECTION_PX",
    "LensCamera",
    "remap_colour",
    "remap_depth",
    "resize_colour",
    "resize_depth",
    "scale_pinhole",
]
