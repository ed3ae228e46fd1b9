"""Pinhole camera model in the OpenCV convention (x right, y down, z forward)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from funrec.typed import FloatArray


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Pinhole intrinsics of an undistorted image; pixel (u, v) = (column, row), the
    centre of the top-left pixel is (0, 0)."""

    width: int
    """Image width W in pixels."""
    height: int
    """Image height H in pixels."""
    fx: float
    """Focal length along u, pixels."""
    fy: float
    """Focal length along v, pixels."""
    cx: float
    """Principal point u, pixels."""
    cy: float
    """Principal point v, pixels."""

    @property
    def K(self) -> FloatArray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def backproject(depth_m: npt.ArrayLike, K: npt.ArrayLike) -> FloatArray:
    """Lift a depth image to points in the camera frame.

    Args:
        depth_m: (H, W) depth along the optical axis in metres; 0 marks a missing reading.
        K: (3, 3) pinhole intrinsics.

    Returns:
        (H*W, 3) points ``p_camera`` in metres, row-major pixel order; rows of
        missing pixels are NaN.
    """
    depth_m = np.asarray(depth_m, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    H, W = depth_m.shape
    v, u = np.mgrid[0:H, 0:W]
    z = np.where(depth_m > 0, depth_m, np.nan)
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1).reshape(-1, 3)


def project(p_camera: npt.ArrayLike, K: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Project camera-frame points to pixels.

    Args:
        p_camera: (N, 3) points in the camera frame, metres.
        K: (3, 3) pinhole intrinsics.

    Returns:
        uv: (N, 2) pixel coordinates (u column, v row); NaN for points with z <= 0.
        z: (N,) depth along the optical axis, metres.
    """
    p_camera = np.asarray(p_camera, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    z = p_camera[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        zs = np.where(z > 0, z, np.nan)
        u = K[0, 0] * p_camera[:, 0] / zs + K[0, 2]
        v = K[1, 1] * p_camera[:, 1] / zs + K[1, 2]
    return np.stack([u, v], axis=-1), z


__all__ = ["PinholeIntrinsics", "backproject", "project"]
