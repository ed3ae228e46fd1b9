"""Fragment submaps: a voxel-thinned static coloured point cloud with normals (and a coarse copy) of the
depth of one fragment's frames, in the fragment's frame (the camera at its anchor frame).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from funrec.formats.capture import Capture
from funrec.geometry.camera import backproject
from funrec.geometry.transforms import invert_transform
from funrec.typed import BoolArray, FloatArray


@dataclass(frozen=True)
class SubmapConfig:
    """How a fragment's static submap is built."""

    voxel_m: float = 0.02
    """Points are thinned to one per voxel of this edge, metres: 2 cm keeps cabinet edges and
    handles for registration."""
    max_points: int = 20000
    """A submap with more points is thinned again with a coarser voxel until it has at most this
    many: ICP cost grows with the points (measured: 0.5 s per colour-ICP run at 52k points, 0.2 s
    at 20k, same accuracy within 2 mm), and a walk through a room gave up to 98k at 2 cm."""
    frame_stride: int = 3
    """Use every k-th frame of the fragment (and its last): consecutive frames overlap almost entirely."""
    pixel_stride: int = 2
    """Use every k-th pixel in each image direction: at 1 m a pixel is ~2 mm, far below a voxel."""
    min_depth_m: float = 0.2
    """Readings closer than this are ignored, metres (sensor minimum range)."""
    max_depth_m: float = 4.0
    """Readings farther than this are ignored, metres: Kinect-like noise (~3 cm at 4 m) would
    exceed the ICP inlier distance."""
    exclusion_margin_px: int = 4
    """Hand and excluded masks are dilated by this many pixels (mixed depth at mask edges)."""
    normal_radius_voxels: float = 2.5
    """Normal estimation radius in voxels of the submap."""
    coarse_voxel_m: float = 0.05
    """Voxel edge of the coarse copy used for FPFH, RANSAC and the first ICP rounds, metres:
    FPFH on the 2 cm cloud took ~3 s per 14k points (measured), on 5 cm ~0.3 s."""
    merge_every: int = 8
    """Frames are thinned one by one and merged (and thinned together) every this many frames:
    memory stays near one submap while the merge is not repeated per frame."""
    min_points: int = 500
    """A submap with fewer points is not registered (too little static geometry)."""


@dataclass(frozen=True, eq=False)
class Submap:
    """The static geometry of one fragment (compared and hashed by identity)."""

    points: FloatArray
    """(N, 3) points p_fragment in the fragment frame, metres."""
    cloud: o3d.geometry.PointCloud
    """The same points with colours (voxel averages) and normals oriented towards the anchor
    camera, for Open3D registration."""
    coarse: o3d.geometry.PointCloud
    """The points thinned to ``coarse_voxel_m``, with normals and colours."""
    normals: FloatArray
    """(N, 3) unit normals of ``points``, oriented towards the anchor camera."""
    tree: cKDTree
    """KD-tree of ``points`` for correspondence search."""
    voxel_m: float
    """Voxel edge the points were thinned to, metres: ``SubmapConfig.voxel_m`` or coarser when
    the submap was capped at ``max_points``."""


def _dilate(mask: BoolArray, radius_px: int) -> BoolArray:
    if radius_px <= 0:
        return mask
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel) > 0


def build_submap(
    capture: Capture,
    T_world_camera: FloatArray,
    first: int,
    last: int,
    anchor: int,
    config: SubmapConfig,
    exclude: Callable[[int], BoolArray | None] | None = None,
) -> Submap:
    """Fuse the depth of frames ``first..last`` (every ``frame_stride``-th and the last) into a
    voxel-thinned cloud in the frame of camera ``anchor``; frames are streamed.

    Args:
        capture: the capture.
        T_world_camera: (F, 4, 4) camera-to-world poses.
        first, last: inclusive frame interval of the fragment.
        anchor: frame whose camera is the fragment frame.
        config: submap settings.
        exclude: optional ``exclude(frame)`` -> (H, W) bool pixels to leave out.
    """
    s = config.pixel_stride
    K = capture.intrinsics.K.copy()
    K[:2, 2] -= s // 2  # the kept pixels are u_full = s * u_sub + s // 2 (rows likewise)
    K[:2] /= s
    T_fragment_world = invert_transform(T_world_camera[anchor])
    merged = o3d.geometry.PointCloud()
    frames = sorted({*range(first, last + 1, config.frame_stride), last})
    for k, frame in enumerate(frames):
        depth = capture.depth_m(frame)
        keep = (depth >= config.min_depth_m) & (depth <= config.max_depth_m)
        for mask in (capture.mask("hand", frame), None if exclude is None else exclude(frame)):
            if mask is not None:
                keep &= ~_dilate(mask, config.exclusion_margin_px)
        p_camera = backproject(np.where(keep, depth, 0.0)[s // 2::s, s // 2::s], K)
        valid = np.isfinite(p_camera[:, 2])
        if valid.any():
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p_camera[valid]))
            cloud.transform(T_fragment_world @ T_world_camera[frame])
            rgb = capture.rgb(frame)[s // 2::s, s // 2::s].reshape(-1, 3)[valid]
            cloud.colors = o3d.utility.Vector3dVector(rgb / 255.0)
            merged += cloud.voxel_down_sample(config.voxel_m)
        if (k + 1) % config.merge_every == 0 or k + 1 == len(frames):
            merged = merged.voxel_down_sample(config.voxel_m)
    merged, voxel_m = _capped(merged, config.voxel_m, config.max_points)
    _with_normals(merged, config.normal_radius_voxels * voxel_m)
    coarse = _with_normals(merged.voxel_down_sample(max(config.coarse_voxel_m, voxel_m)),
                           config.normal_radius_voxels * max(config.coarse_voxel_m, voxel_m))
    points = np.asarray(merged.points).copy()
    return Submap(points, merged, coarse, np.asarray(merged.normals).copy(), cKDTree(points.reshape(-1, 3)), voxel_m)


def _capped(cloud: o3d.geometry.PointCloud, voxel_m: float, max_points: int) -> tuple[o3d.geometry.PointCloud, float]:
    """Thin ``cloud`` (already at ``voxel_m``) with coarser voxels until at most ``max_points`` remain.

    Surface points scale with voxel^-2, so the first guess is voxel_m * sqrt(N / max_points);
    voxel-grid phase effects may leave a few too many, hence the 10 % steps after it."""
    if len(cloud.points) <= max_points:
        return cloud, voxel_m
    voxel_m *= math.sqrt(len(cloud.points) / max_points)
    thinned = cloud.voxel_down_sample(voxel_m)
    while len(thinned.points) > max_points:
        voxel_m *= 1.1
        thinned = cloud.voxel_down_sample(voxel_m)
    return thinned, voxel_m


def _with_normals(cloud: o3d.geometry.PointCloud, radius_m: float) -> o3d.geometry.PointCloud:
    """Estimate normals in place, oriented towards the fragment's camera (the frame origin)."""
    if not cloud.has_points():
        return cloud  # Open3D raises on normals of an empty cloud; an empty submap is never registered
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=30))
    cloud.orient_normals_towards_camera_location(np.zeros(3))
    return cloud


def overlap_fraction(source: Submap, target: Submap, T_target_source: FloatArray, distance_m: float) -> float:
    """Fraction of the smaller submap's (coarse) points within ``distance_m`` of the other submap when
    ``source`` is placed in ``target``'s frame by ``T_target_source`` (4, 4)."""
    if len(source.points) == 0 or len(target.points) == 0:
        return 0.0
    # The coarse clouds suffice: the distance is a few coarse voxels.
    moved = o3d.geometry.PointCloud(source.coarse).transform(T_target_source)
    d_source = np.asarray(moved.compute_point_cloud_distance(target.coarse))
    d_target = np.asarray(target.coarse.compute_point_cloud_distance(moved))
    return float(max(np.mean(d_source < distance_m), np.mean(d_target < distance_m)))


__all__ = ["Submap", "SubmapConfig", "build_submap", "overlap_fraction"]
