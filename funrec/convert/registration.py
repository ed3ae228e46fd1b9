"""Registering a depth image into another camera: unproject, transform, project, z-buffer."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from funrec.geometry.transforms import check_transform
from funrec.typed import FloatArray


def register_depth(
    depth_m: npt.ArrayLike,
    xy_source: npt.ArrayLike,
    valid_source: npt.ArrayLike,
    T_target_source: npt.ArrayLike,
    K_target: npt.ArrayLike,
    size_target: tuple[int, int],
    splat_2x2: bool,
) -> FloatArray:
    """Re-render a depth image as seen by a pinhole target camera.

    Each valid depth pixel is lifted to ``p_source = z * (x, y, 1)``, moved by ``T_target_source``,
    projected with ``K_target`` and written with a z-buffer (the nearest surface wins), so surfaces
    occluded from the target are removed and pixels the source did not see stay 0.

    Args:
        depth_m: (h, w) depth along the source's optical axis, metres; 0 = no reading.
        xy_source: (h*w, 2) undistorted normalised coordinates (X/Z, Y/Z) of every source pixel, row-major.
        valid_source: (h*w,) bool, pixels whose ray is valid.
        T_target_source: (4, 4) maps source-camera points to target-camera points.
        K_target: (3, 3) pinhole intrinsics of the (undistorted) target image.
        size_target: (W, H) of the target image.
        splat_2x2: write each point to the 2x2 target pixels around its projection instead of the
            nearest one; needed when one source pixel covers more than a target pixel (upsampling), else
            the result has holes. It grows foreground edges by up to half a pixel.

    Returns:
        (H, W) depth along the target's optical axis, metres; 0 = no reading.
    """
    depth_m = np.asarray(depth_m, dtype=np.float64)
    xy = np.asarray(xy_source, dtype=np.float64)
    T = check_transform(T_target_source, "T_target_source")
    K = np.asarray(K_target, dtype=np.float64)
    W, H = size_target
    z = depth_m.ravel()
    keep = np.asarray(valid_source, dtype=bool) & (z > 0) & np.isfinite(z)
    p_source = np.concatenate([xy[keep] * z[keep, None], z[keep, None]], axis=1)
    p_target = p_source @ T[:3, :3].T + T[:3, 3]
    z_t = p_target[:, 2]
    in_front = z_t > 0
    p_target, z_t = p_target[in_front], z_t[in_front]
    u = K[0, 0] * p_target[:, 0] / z_t + K[0, 2]
    v = K[1, 1] * p_target[:, 1] / z_t + K[1, 2]
    if splat_2x2:
        u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        us = np.concatenate([u0, u0 + 1, u0, u0 + 1])
        vs = np.concatenate([v0, v0, v0 + 1, v0 + 1])
        zs = np.tile(z_t, 4)
    else:
        us, vs, zs = np.round(u).astype(np.int64), np.round(v).astype(np.int64), z_t
    inside = (us >= 0) & (us < W) & (vs >= 0) & (vs < H)
    zbuffer = np.full(H * W, np.inf)
    np.minimum.at(zbuffer, vs[inside] * W + us[inside], zs[inside])
    zbuffer[~np.isfinite(zbuffer)] = 0.0
    return zbuffer.reshape(H, W)


__all__ = ["register_depth"]
