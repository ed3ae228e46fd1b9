"""Ground-truth visible surface points: exact depth back-projected over all frames, static
pixels in the world frame and part pixels moved to their canonical pose, voxel-downsampled.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from funrec.geometry.transforms import transform_points
from funrec.typed import FloatArray, IntArray

VOXEL_M = 0.005
"""Voxel size of the ground-truth point clouds, metres."""
_OFFSET = 1 << 20
_CONSOLIDATE_AT = 2_000_000


def interior_labels(labels: IntArray) -> npt.NDArray[np.bool_]:
    """(H, W) True where a pixel's label equals all its 4-neighbours' (no mixed surfaces at
    region borders, where a pixel may straddle two objects)."""
    padded = np.pad(labels, 1, mode="edge")
    same = np.ones(labels.shape, dtype=bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        same &= padded[dy : dy + labels.shape[0], dx : dx + labels.shape[1]] == labels
    return same


def pixels_to_camera(depth_m: FloatArray, K: FloatArray, mask: npt.NDArray[np.bool_]) -> FloatArray:
    """(N, 3) camera-frame points of the masked pixels (row-major order); depth must be > 0 there."""
    v, u = np.nonzero(mask)
    z = depth_m[v, u]
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)


class VoxelCloud:
    """Union of point sets keeping one point per voxel (the first one seen, so points stay
    exactly on the surfaces)."""

    def __init__(self, voxel_m: float = VOXEL_M) -> None:
        self.voxel_m = voxel_m
        self._keys = np.empty(0, np.int64)
        self._points = np.empty((0, 3))
        self._pending: list[tuple[np.ndarray, FloatArray]] = []
        self._pending_size = 0

    def _key(self, points: FloatArray) -> np.ndarray:
        cells = np.floor(points / self.voxel_m).astype(np.int64) + _OFFSET
        return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]

    def add(self, points: npt.ArrayLike) -> None:
        """Add (N, 3) points (metres)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not len(points):
            return
        keys, first = np.unique(self._key(points), return_index=True)
        self._pending.append((keys, points[first]))
        self._pending_size += len(keys)
        if self._pending_size > _CONSOLIDATE_AT:
            self._consolidate()

    def _consolidate(self) -> None:
        if not self._pending:
            return
        keys = np.concatenate([self._keys, *(k for k, _ in self._pending)])
        points = np.concatenate([self._points, *(p for _, p in self._pending)])
        self._keys, first = np.unique(keys, return_index=True)
        self._points = points[first]
        self._pending, self._pending_size = [], 0

    def points(self) -> FloatArray:
        """(M, 3) one point per occupied voxel."""
        self._consolidate()
        return self._points.copy()

    def __len__(self) -> int:
        self._consolidate()
        return len(self._points)


class SurfaceAccumulator:
    """Collects the visible surface of the static scene and of each part over frames."""

    def __init__(self, part_count: int, voxel_m: float = VOXEL_M, stride: int = 1) -> None:
        self.static = VoxelCloud(voxel_m)
        self.parts = [VoxelCloud(voxel_m) for _ in range(part_count)]
        self.stride = stride
        """Use every stride-th pixel in each direction (other frames fill the gaps)."""

    def add_frame(
        self, depth_m: FloatArray, labels: IntArray, K: FloatArray, T_world_camera: FloatArray, T_world_part: FloatArray
    ) -> None:
        """Add one frame.

        Args:
            depth_m: (H, W) exact depth, metres (0 = none).
            labels: (H, W) 0 static, k + 1 part k, -1 hand or nothing.
            K: (3, 3) intrinsics.
            T_world_camera: (4, 4) true camera pose.
            T_world_part: (P, 4, 4) joint transform of each part at this frame (canonical -> posed).
        """
        keep = (depth_m > 0) & (labels >= 0) & interior_labels(labels)
        if self.stride > 1:
            keep[:, np.arange(keep.shape[1]) % self.stride != 0] = False
            keep[np.arange(keep.shape[0]) % self.stride != 0] = False
        p_world = transform_points(T_world_camera, pixels_to_camera(depth_m, K, keep))
        label = labels[keep]
        self.static.add(p_world[label == 0])
        for k, cloud in enumerate(self.parts):
            selected = label == k + 1
            if np.any(selected):
                T_canonical_world = np.linalg.inv(T_world_part[k])
                cloud.add(transform_points(T_canonical_world, p_world[selected]))


def write_ply(path: str | Path, points: npt.ArrayLike) -> None:
    """Write (N, 3) points as a binary PLY point cloud (trimesh)."""
    import trimesh

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    cloud = trimesh.PointCloud(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    Path(path).write_bytes(cloud.export(file_type="ply"))


__all__ = ["VOXEL_M", "SurfaceAccumulator", "VoxelCloud", "interior_labels", "pixels_to_camera", "write_ply"]
