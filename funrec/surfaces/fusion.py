"""TSDF fusion (paper: "Reconstruction and interactive manipulation"): the static scene in the world
frame and each articulated part in its canonical frame, from masked depth, as triangle meshes.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
import open3d as o3d
import open3d.core as o3c
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from funrec.camera.tracking import CameraTrajectory, Progress
from funrec.errors import ReconstructionError
from funrec.formats.capture import Capture
from funrec.geometry.transforms import check_transform, invert_transform
from funrec.surfaces.hands import HandMasks
from funrec.surfaces.segmentation import PartMasks
from funrec.typed import BoolArray, FloatArray

logger = logging.getLogger(__name__)

_BLOCK_RESOLUTION = 8
"""Voxels per block edge of the sparse grid: 8^3 blocks allocate less empty space around thin
surfaces than 16^3 at the same integration speed (measured)."""
_INITIAL_BLOCKS = 10000
"""Initial hash-map capacity in blocks; the map grows on demand."""


@dataclass(frozen=True)
class FusionConfig:
    """Settings of :func:`fuse_tsdf`; defaults suit 640x480 Kinect-like depth at 0.5-3 m."""

    static_voxel_m: float = 0.01
    """Voxel edge of the static volume, metres: 1 cm is ~6 px at 1 m, below the depth noise of
    distant surfaces and enough for a room-scale mesh."""
    static_truncation_m: float = 0.04
    """TSDF truncation of the static volume, metres: 4 voxels, several times the depth noise
    (sigma ~ 5 mm at 2 m) so noisy samples still average into one surface."""
    part_voxel_m: float = 0.005
    """Voxel edge of each part volume, metres: parts are small and thin (a 2 cm door leaf)."""
    part_truncation_m: float = 0.015
    """TSDF truncation of each part volume, metres: below a door leaf's thickness (~2 cm) so views
    of its back face do not carve its front face, still 3 sigma of depth noise at 1.5 m."""
    max_depth_m: float = 5.0
    """Depth readings beyond this are ignored: Kinect-like noise grows with the square of depth
    (sigma ~ 4 cm at 5 m, where the TSDF still averages it to < 1 cm over a few views). At 3 m
    the far walls and floor of a kitchen were missing (scene chamfer 2.2 cm instead of 0.4 cm)."""
    frame_stride: int = 3
    """Integrate every k-th frame: at 15 fps consecutive views overlap almost entirely. Measured
    on synthetic 640x480 kitchens: stride 3 adds 0.3 mm of chamfer distance to stride 2 and
    costs ~40% less time."""
    exclusion_margin_px: int = 4
    """Hand and part masks are dilated by this many pixels before being cut from the static
    depth: depth is worst at object edges (mixed and flying pixels)."""
    part_mask_erosion_px: int = 2
    """Part masks are eroded by this many pixels before fusing the part, for the same reason."""
    min_observations: float = 1.0
    """Marching cubes skips voxels with a lower integration weight (~ number of integrated views).
    1 keeps surfaces glimpsed once at the stride; 2 lost 1 cm of completeness (measured)."""
    part_agreement_m: float = 0.03
    """In frames without a part mask, pixels within this distance behind the part mesh (posed at
    the nearest tracked frame) are left out of the static volume; a few sigma of depth noise."""
    part_thickness_m: float = 0.06
    """... and so are pixels up to this far in front of it: a part fused from its opening motion may
    only show its inner face, so the rendered surface can lie a leaf's thickness (2-4 cm, measured
    4.5 cm) behind the front face that the untracked frames see."""
    min_fragment_fraction: float = 0.002
    """Connected mesh pieces with fewer triangles than this fraction of the largest piece are
    removed (floating blobs from noise and mask leaks); 2% also removed real, partly seen
    surfaces (chamfer +0.3 cm, measured)."""


@dataclass(frozen=True)
class Meshes:
    """Fused geometry as trimesh objects (vertex colours as RGBA uint8), all in the world frame."""

    static: trimesh.Trimesh
    """Static scene with hands and parts removed, world frame, metres."""
    parts: tuple[trimesh.Trimesh, ...]
    """One mesh per part at its canonical state (pose = identity), world frame, metres."""
    empty_parts: tuple[int, ...] = ()
    """Parts whose masked depth fused into no surface (their mesh in ``parts`` is empty): the
    caller drops them (a part without pixels cannot be scored or simulated)."""


def fuse_tsdf(
    capture: Capture,
    trajectory: CameraTrajectory,
    part_masks: Sequence[PartMasks],
    T_world_part: Sequence[npt.ArrayLike],
    config: FusionConfig = FusionConfig(),
    progress: Progress | None = None,
    hands: HandMasks | None = None,
) -> Meshes:
    """Fuse the static scene and every part into TSDF volumes and extract their meshes.

    The static volume integrates every ``frame_stride``-th frame at ``T_world_camera`` with hand
    and part pixels (dilated) removed. Part k integrates its masked (eroded) depth at
    ``T_part_camera = inv(T_world_part) @ T_world_camera``, so its mesh is the part at its
    canonical state, in world coordinates. In frames where a part has no mask its pose is taken
    from the nearest tracked frame and the pixels its mesh explains are kept out of the static
    volume. Frames are streamed; memory is the volumes, not the video.

    Args:
        capture: the capture (frames read lazily).
        trajectory: camera poses ``T_world_camera`` (F, 4, 4).
        part_masks: one :class:`PartMasks` per part.
        T_world_part: per part, (F_k, 4, 4) pose at each frame of ``part_masks[k].frames``:
            canonical part -> posed part, world frame.
        config: settings.
        progress: optional ``progress(done, total)`` after each integrated frame.
        hands: hand (and arm) masks of every frame, e.g. detected ones (:func:`funrec.surfaces.hands.detect_hands`);
            None reads the capture's own ``masks/hand`` where present. Without them the person's arm
            would be fused into the static scene wherever later frames do not see through it.

    Returns:
        Static and part meshes.

    Raises:
        ValueError: inconsistent shapes or invalid transforms.
        ReconstructionError: the static volume produced no surface (no valid depth); a part
            whose masks fuse into nothing gets an empty mesh and is listed in ``empty_parts``.
    """
    F = len(capture)
    if len(trajectory.T_world_camera) != F:
        raise ValueError(f"capture has {F} frames but the trajectory {len(trajectory.T_world_camera)}")
    if len(part_masks) != len(T_world_part):
        raise ValueError(f"{len(part_masks)} part mask sets but {len(T_world_part)} part pose stacks")
    poses = [check_transform(T, f"T_world_part[{k}]") for k, T in enumerate(T_world_part)]
    for k, (masks, T) in enumerate(zip(part_masks, poses)):
        if T.shape != (len(masks.frames), 4, 4):
            raise ValueError(f"T_world_part[{k}] must be ({len(masks.frames)}, 4, 4) like part_masks[{k}].frames, got {T.shape}")
    K = capture.intrinsics.K
    lookup = [{int(f): j for j, f in enumerate(m.frames)} for m in part_masks]
    fused = range(0, F, config.frame_stride)
    done = 0
    part_volumes = [_Volume(config.part_voxel_m, config.part_truncation_m, config.max_depth_m) for _ in part_masks]
    static_volume = _Volume(config.static_voxel_m, config.static_truncation_m, config.max_depth_m)
    # One pass over the frames in which every part has a mask: each frame is read once and feeds
    # all volumes. Frames where some part is untracked need that part's mesh, so they wait.
    deferred = []
    for frame in fused:
        masked = [k for k, table in enumerate(lookup) if frame in table]
        if len(masked) < len(lookup):
            deferred.append(frame)  # the static volume waits for the meshes of the unmasked parts
            if not masked:
                continue
        depth_m, rgb, hand = capture.depth_m(frame), capture.rgb(frame), _hand(capture, frame, config, hands)
        T_camera_world = invert_transform(trajectory.T_world_camera[frame])
        exclude = hand
        for k in masked:  # parts tracked in different fragments never share a frame
            j = lookup[k][frame]
            mask = part_masks[k].mask(j)
            exclude = exclude | _dilate(mask, config.exclusion_margin_px)
            keep = _erode(mask, config.part_mask_erosion_px) & ~hand
            part_volumes[k].integrate(np.where(keep, depth_m, 0.0), rgb, K, T_camera_world @ poses[k][j])
        if len(masked) < len(lookup):
            continue
        static_volume.integrate(np.where(exclude, 0.0, depth_m), rgb, K, T_camera_world)
        done += 1
        if progress is not None:
            progress(done, len(fused))
    part_meshes, empty = [], []
    for k, volume in enumerate(part_volumes):
        try:
            part_meshes.append(volume.extract(f"part {k}", config))
        except ReconstructionError as exc:  # empty masks must not cost the static scene and other parts
            logger.warning("%s; part %d has no mesh and should be dropped", exc, k)
            part_meshes.append(trimesh.Trimesh())
            empty.append(k)
    scenes = [None if k in empty else _raycaster(mesh) for k, mesh in enumerate(part_meshes)]
    bounds = [None if k in empty else np.asarray(mesh.bounds) for k, mesh in enumerate(part_meshes)]
    for frame in deferred:
        depth_m, rgb, hand = capture.depth_m(frame), capture.rgb(frame), _hand(capture, frame, config, hands)
        T_camera_world = invert_transform(trajectory.T_world_camera[frame])
        exclude = hand
        for k, masks in enumerate(part_masks):
            j = lookup[k].get(frame)
            if j is not None:
                exclude = exclude | _dilate(masks.mask(j), config.exclusion_margin_px)
                continue
            if scenes[k] is None:
                continue
            # Untracked frame: the part rests at the pose of the nearest tracked frame; leave out
            # the pixels its mesh explains.
            j = int(np.argmin(np.abs(masks.frames - frame)))
            z_part = _render_depth(scenes[k], bounds[k], T_camera_world @ poses[k][j], K, depth_m.shape)
            # Grow the silhouette by the margin with the nearest depth (fills unseen bits of the part).
            z_part = -cv2.dilate(np.where(np.isfinite(z_part), -z_part, -np.inf).astype(np.float32), _disk(config.exclusion_margin_px))
            offset = depth_m - z_part
            near = (depth_m > 0) & (offset > -config.part_thickness_m) & (offset < config.part_agreement_m)
            exclude = exclude | _dilate(near, config.exclusion_margin_px)
        static_volume.integrate(np.where(exclude, 0.0, depth_m), rgb, K, T_camera_world)
        done += 1
        if progress is not None:
            progress(done, len(fused))
    static = static_volume.extract("static scene", config)
    return Meshes(static, tuple(part_meshes), tuple(empty))


class _Volume:
    """A sparse TSDF volume (open3d VoxelBlockGrid on the CPU) with colour.

    The legacy ``ScalableTSDFVolume`` integrates nothing in open3d 0.20 (measured: empty mesh
    from a valid frame; upstream deprecated it for VoxelBlockGrid), so the tensor API is used.
    """

    def __init__(self, voxel_m: float, truncation_m: float, max_depth_m: float) -> None:
        self.grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=(1, 1, 3),
            voxel_size=voxel_m,
            block_resolution=_BLOCK_RESOLUTION,
            block_count=_INITIAL_BLOCKS,
            device=o3c.Device("CPU:0"),
        )
        self.truncation_voxels = truncation_m / voxel_m
        self.max_depth_m = max_depth_m

    def integrate(self, depth_m: FloatArray, rgb: npt.NDArray[np.uint8], K: FloatArray, T_camera_volume: FloatArray) -> None:
        """Fuse one frame: ``depth_m`` (H, W) metres (0 = skip), ``rgb`` (H, W, 3), and the
        transform from the volume's frame (world or canonical part) into the camera."""
        if not np.any((depth_m > 0) & (depth_m < self.max_depth_m)):
            return  # Open3D aborts when no reading falls inside the volume's depth range
        depth = o3d.t.geometry.Image(o3c.Tensor(depth_m.astype(np.float32)))
        colour = o3d.t.geometry.Image(o3c.Tensor(rgb.astype(np.float32) / 255.0))
        K_t, T_t = o3c.Tensor(K), o3c.Tensor(T_camera_volume)
        try:
            blocks = self.grid.compute_unique_block_coordinates(depth, K_t, T_t, 1.0, self.max_depth_m, self.truncation_voxels)
        except RuntimeError as exc:
            # Open3D raises instead of returning nothing when a frame's few valid pixels (a
            # sliver of mask) touch no voxel block; such a frame has nothing to fuse.
            if "No block is touched" not in str(exc):
                raise
            return
        self.grid.integrate(blocks, depth, colour, K_t, K_t, T_t, 1.0, self.max_depth_m, self.truncation_voxels)

    def extract(self, name: str, config: FusionConfig) -> trimesh.Trimesh:
        """Marching-cubes mesh without small fragments, as a trimesh with RGBA vertex colours."""
        if self.grid.hashmap().size() == 0:
            raise ReconstructionError(f"TSDF fusion of the {name} produced no surface (no valid masked depth)")
        mesh = self.grid.extract_triangle_mesh(weight_threshold=config.min_observations).to_legacy()
        if len(mesh.triangles) == 0:
            raise ReconstructionError(f"TSDF fusion of the {name} produced no surface (no valid masked depth)")
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
        colours = (np.clip(np.asarray(mesh.vertex_colors), 0.0, 1.0) * 255).round().astype(np.uint8)
        rgba = np.concatenate([colours, np.full((len(colours), 1), 255, np.uint8)], axis=1)
        result = trimesh.Trimesh(vertices, faces[_large_pieces(faces, len(vertices), config.min_fragment_fraction)],
                                 vertex_colors=rgba, process=False)
        result.remove_unreferenced_vertices()
        logger.info("%s: %d vertices, %d triangles", name, len(result.vertices), len(result.faces))
        return result


def _large_pieces(faces: npt.NDArray[np.int64], vertex_count: int, min_fraction: float) -> BoolArray:
    """(T,) True for triangles of connected pieces with at least ``min_fraction`` of the largest
    piece's triangles. scipy's graph components take ~30 ms where open3d's
    ``cluster_connected_triangles`` took ~600 ms on a 300k-triangle room (measured)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(vertex_count, vertex_count))
    _, vertex_piece = connected_components(graph, directed=False)
    piece = vertex_piece[faces[:, 0]]
    sizes = np.bincount(piece)
    return sizes[piece] >= min_fraction * sizes.max()


def _raycaster(mesh: trimesh.Trimesh) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    return scene


def _render_depth(scene: o3d.t.geometry.RaycastingScene, bounds: FloatArray, T_camera_part: FloatArray, K: FloatArray,
                  shape: tuple[int, int]) -> FloatArray:
    """(H, W) depth in metres of the part mesh (axis-aligned ``bounds`` (2, 3), part frame) seen
    from the camera; inf where no hit. Only the pixels inside the image of the mesh's bounding
    box are cast (the same hits; a door seen from afar covers a small part of the view)."""
    H, W = shape
    depth = np.full(shape, np.inf)
    window = _image_window(bounds, T_camera_part, K, shape)
    if window is None:
        return depth
    v0, v1, u0, u1 = window
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(o3d.core.Tensor(K), o3d.core.Tensor(T_camera_part), W, H)
    rays = o3d.core.Tensor(np.ascontiguousarray(rays.numpy()[v0:v1, u0:u1]))
    # Pinhole rays have direction (x/z, y/z, 1) in the camera frame, so t_hit is the depth.
    depth[v0:v1, u0:u1] = scene.cast_rays(rays, nthreads=0)["t_hit"].numpy()
    return depth


def _image_window(bounds: FloatArray, T_camera_part: FloatArray, K: FloatArray,
                  shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """Pixel rows [v0, v1) and columns [u0, u1) that can see the box ``bounds`` (2, 3), part
    frame: the image of its corners, widened by two pixels (rays pass through pixel centres);
    the whole image when a corner lies behind the camera, None when the box is out of view."""
    H, W = shape
    corners = np.array([[bounds[i, 0], bounds[j, 1], bounds[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    p = corners @ T_camera_part[:3, :3].T + T_camera_part[:3, 3]
    if np.any(p[:, 2] <= 1e-6):
        return 0, H, 0, W
    u = K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2]
    v = K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]
    u0, u1 = max(0, int(np.floor(u.min())) - 2), min(W, int(np.ceil(u.max())) + 2)
    v0, v1 = max(0, int(np.floor(v.min())) - 2), min(H, int(np.ceil(v.max())) + 2)
    return (v0, v1, u0, u1) if u0 < u1 and v0 < v1 else None


def _hand(capture: Capture, frame: int, config: FusionConfig, hands: HandMasks | None) -> BoolArray:
    hand = capture.mask("hand", frame) if hands is None else hands.mask(frame)
    if hand is None:
        return np.zeros((capture.intrinsics.height, capture.intrinsics.width), dtype=bool)
    return _dilate(hand, config.exclusion_margin_px)


def _disk(radius_px: int) -> npt.NDArray[np.uint8]:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))


def _dilate(mask: BoolArray, radius_px: int) -> BoolArray:
    return cv2.dilate(mask.astype(np.uint8), _disk(radius_px)) > 0 if radius_px > 0 else mask.copy()


def _erode(mask: BoolArray, radius_px: int) -> BoolArray:
    return cv2.erode(mask.astype(np.uint8), _disk(radius_px)) > 0 if radius_px > 0 else mask.copy()


__all__ = ["FusionConfig", "Meshes", "fuse_tsdf"]
