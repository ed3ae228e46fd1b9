"""Reference "methods" that write twin folders (FORMATS.md section 2): an oracle built from the
ground truth, a naive baseline that uses none, and Open3D's own RGB-D odometry + TSDF
integration (a static reconstruction without parts, timed beside FunREC in ``funrec bench``).

The first two exercise :mod:`funrec.bench.evaluate` and :mod:`funrec.bench.run` at both ends of
the score range; the Open3D one is the speed (and camera/static-geometry) reference.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from funrec.errors import FunrecError
from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.capture import load_capture, write_mask
from funrec.formats.ground_truth import read_ground_truth
from funrec.formats.twin import TwinArticulation, make_part, write_articulation
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.typed import FloatArray

LOGGER = logging.getLogger(__name__)

TRIVIAL_PIVOT_CAMERA0 = (0.0, 0.0, 1.0)
"""Pivot of the trivial baseline's door, camera-0 frame: 1 m straight ahead of camera 0."""
TRIVIAL_AXIS_CAMERA0 = (0.0, -1.0, 0.0)
"""Axis of the trivial baseline's door: vertical (up) for a level camera, whose y points down."""
TRIVIAL_DOOR_SIZE_M = (0.4, 0.6)
"""Width and height of the trivial baseline's door plane, metres."""


def _write_atomically(out_dir: Path, fill: Callable[[Path], None]) -> Path:
    """Run ``fill(tmp)`` on a fresh folder beside ``out_dir``, then rename it into place.

    An existing ``out_dir`` is replaced only if it is empty or holds an articulation.json
    (an earlier twin); anything else is refused so a typo cannot delete unrelated files.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()) and not (out_dir / "articulation.json").is_file():
        raise FunrecError(f"{out_dir}: exists and is not a twin folder; refusing to overwrite it")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=out_dir.parent))
    try:
        fill(tmp)
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir


def _write_points(path: Path, p: FloatArray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.PointCloud(p).export(str(path))


def _read_points(path: Path) -> FloatArray:
    loaded = trimesh.load(str(path), process=False)
    return np.asarray(loaded.vertices, dtype=np.float64)


def write_oracle_twin(capture_dir: str | Path, out_dir: str | Path) -> Path:
    """Write the ground truth of a generated capture as a twin; it must score perfectly.

    The twin's world frame is the true camera-0 frame, not the ground truth's world frame,
    so an evaluation that skips the frame-0 mapping scores it badly. Meshes are the true
    visible points written as vertex-only PLYs (a point cloud, which the evaluation samples
    as-is), so the chamfer distance is zero up to float32 storage; no surface is
    reconstructed. Masks are copied from ``gt/masks/<part>/``.

    Args:
        capture_dir: a capture folder with ``gt/`` (FORMATS.md section 4).
        out_dir: the twin folder to write; replaced if it already holds a twin.

    Returns:
        ``out_dir``.
    """
    gt = read_ground_truth(Path(capture_dir) / "gt")
    T_camera0_world = invert_transform(gt.T_world_camera[0])

    def fill(tmp: Path) -> None:
        parts = []
        for gt_part in gt.parts:
            part = gt_part.part
            pivot = None if part.pivot_world is None else transform_points(T_camera0_world, part.pivot_world[None])[0]
            mesh = f"meshes/{part.name}.ply"
            _write_points(tmp / mesh, transform_points(T_camera0_world, _read_points(gt.points_path(part.name))))
            masks = f"masks/{part.name}"
            source = gt.root / "masks" / part.name
            if source.is_dir():
                shutil.copytree(source, tmp / masks)
            else:
                (tmp / masks).mkdir(parents=True)
            parts.append(
                make_part(
                    part.name, part.joint_type, T_camera0_world[:3, :3] @ part.axis_world, pivot,
                    part.frames, part.states, part.state_range, mesh=mesh, masks=masks,
                )
            )
        static_mesh = None
        if gt.points_path("static").is_file():
            static_mesh = "meshes/static.ply"
            _write_points(tmp / static_mesh, transform_points(T_camera0_world, _read_points(gt.points_path("static"))))
        write_camera_poses(tmp / "camera_poses.txt", T_camera0_world @ gt.T_world_camera)
        write_articulation(tmp / "articulation.json", TwinArticulation(gt.frame_count, tuple(parts), static_mesh))

    LOGGER.info("writing oracle twin of %s to %s", capture_dir, out_dir)
    return _write_atomically(Path(out_dir), fill)


def _plane_mesh(corner: FloatArray, edge_u: FloatArray, edge_v: FloatArray) -> trimesh.Trimesh:
    """Two-triangle rectangle with corners corner, corner + edge_u, corner + edge_u + edge_v, corner + edge_v."""
    vertices = np.stack([corner, corner + edge_u, corner + edge_u + edge_v, corner + edge_v])
    return trimesh.Trimesh(vertices=vertices, faces=[[0, 1, 2], [0, 2, 3]], process=False)


def write_trivial_twin(capture_dir: str | Path, out_dir: str | Path) -> Path:
    """Write a deliberately naive twin that uses no ground truth, to exercise bad scores.

    Identity camera poses (world = camera 0, the camera never moves), one revolute part with
    a vertical axis through a point 1 m in front of camera 0, state 0 in every frame, an
    all-zero mask in every frame, and a 0.4 m x 0.6 m plane hinged on the axis as the part
    mesh; no static mesh.

    Args:
        capture_dir: a capture folder (FORMATS.md section 1); only its frame count and
            image size are read.
        out_dir: the twin folder to write; replaced if it already holds a twin.

    Returns:
        ``out_dir``.
    """
    capture = load_capture(capture_dir, check_headers=False)
    frame_count = len(capture)
    empty = np.zeros((capture.intrinsics.height, capture.intrinsics.width), dtype=bool)
    pivot = np.asarray(TRIVIAL_PIVOT_CAMERA0)
    axis = np.asarray(TRIVIAL_AXIS_CAMERA0)
    width, height = TRIVIAL_DOOR_SIZE_M

    def fill(tmp: Path) -> None:
        plane = _plane_mesh(pivot - axis * height / 2, np.array([width, 0.0, 0.0]), axis * height)
        (tmp / "meshes").mkdir()
        plane.export(str(tmp / "meshes" / "part_0.ply"))
        for frame in range(frame_count):
            write_mask(tmp / "masks" / "part_0" / f"{frame:06d}.png", empty)
        part = make_part(
            "part_0", "revolute", axis, pivot, np.arange(frame_count), np.zeros(frame_count),
            mesh="meshes/part_0.ply", masks="masks/part_0",
        )
        write_camera_poses(tmp / "camera_poses.txt", np.broadcast_to(np.eye(4), (frame_count, 4, 4)))
        write_articulation(tmp / "articulation.json", TwinArticulation(frame_count, (part,), static_mesh=None))

    LOGGER.info("writing trivial twin of %s to %s", capture_dir, out_dir)
    return _write_atomically(Path(out_dir), fill)


OPEN3D_VOXEL_M = 0.01
"""Voxel size of the Open3D baseline's TSDF volume, metres (the default of FunREC's fusion)."""
OPEN3D_DEPTH_MAX_M = 4.0
"""Farthest depth the Open3D baseline uses for odometry and integration, metres."""


def write_open3d_twin(capture_dir: str | Path, out_dir: str | Path) -> Path:
    """Open3D's RGB-D odometry + TSDF integration as a baseline twin: no parts, camera poses
    and a static mesh.

    Frame-to-frame multi-scale hybrid (photometric + geometric) RGB-D odometry
    (``open3d.t.pipelines.odometry.rgbd_odometry_multi_scale``, the tracker of Open3D's
    reconstruction system), chained from camera 0, and every frame integrated into a
    ``VoxelBlockGrid`` TSDF, whose marching-cubes mesh is the static mesh. A frame whose
    odometry fails keeps the previous frame's motion (constant velocity). Capture hand masks,
    when present, are cut out of the depth, as FunREC does.

    Args:
        capture_dir: a capture folder (FORMATS.md section 1).
        out_dir: the twin folder to write; replaced if it already holds a twin.

    Returns:
        ``out_dir``.
    """
    import open3d as o3d
    import open3d.core as o3c

    capture = load_capture(capture_dir, check_headers=False)
    intr = capture.intrinsics
    K = np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])
    K_t = o3c.Tensor(K)
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=(1, 1, 3),
        voxel_size=OPEN3D_VOXEL_M,
        block_resolution=8,
        block_count=40000,  # 20 MB per 1,000 blocks of 8^3 voxels; the hash map grows when full
        device=o3c.Device("CPU:0"),
    )
    # Open3D's default iterations per pyramid level (coarse to fine), as rgbd_odometry_multi_scale uses them.
    criteria = [o3d.t.pipelines.odometry.OdometryConvergenceCriteria(n) for n in (10, 5, 3)]
    T_world_camera = np.empty((len(capture), 4, 4))
    previous = None
    motion = np.eye(4)  # T_previous_current of the last successful step
    for frame, rgb, depth_m in capture.frames():
        hand = capture.mask("hand", frame)
        depth = np.where(hand, 0.0, depth_m) if hand is not None else depth_m
        image = o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0)),
            o3d.t.geometry.Image(o3c.Tensor(depth.astype(np.float32))),
        )
        if previous is None:
            T_world_camera[frame] = np.eye(4)
        else:
            try:
                result = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                    image, previous, K_t, o3c.Tensor(motion), 1.0, OPEN3D_DEPTH_MAX_M, criteria,
                    o3d.t.pipelines.odometry.Method.Hybrid,
                )
                T_previous_current = result.transformation.numpy()  # source (current) -> target (previous)
                if result.fitness > 0 and np.all(np.isfinite(T_previous_current)):
                    motion = T_previous_current
            except RuntimeError as exc:  # too few valid correspondences
                LOGGER.debug("open3d odometry failed at frame %d: %s", frame, exc)
            T_world_camera[frame] = T_world_camera[frame - 1] @ motion
        previous = image
        if np.any((depth > 0) & (depth < OPEN3D_DEPTH_MAX_M)):
            T_camera_world = o3c.Tensor(invert_transform(T_world_camera[frame]))
            blocks = grid.compute_unique_block_coordinates(image.depth, K_t, T_camera_world, 1.0, OPEN3D_DEPTH_MAX_M)
            grid.integrate(blocks, image.depth, image.color, K_t, T_camera_world, 1.0, OPEN3D_DEPTH_MAX_M)
    if grid.hashmap().size() == 0:
        raise FunrecError(f"{capture_dir}: no depth reading within {OPEN3D_DEPTH_MAX_M} m; Open3D integrated nothing")
    mesh = grid.extract_triangle_mesh(weight_threshold=2.0).to_legacy()
    if len(mesh.triangles) == 0:
        raise FunrecError(f"{capture_dir}: Open3D TSDF integration produced no surface")

    def fill(tmp: Path) -> None:
        (tmp / "meshes").mkdir()
        trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), process=False).export(
            str(tmp / "meshes" / "static.ply")
        )
        write_camera_poses(tmp / "camera_poses.txt", T_world_camera)
        write_articulation(tmp / "articulation.json", TwinArticulation(len(capture), (), "meshes/static.ply"))

    LOGGER.info("writing Open3D odometry + TSDF twin of %s to %s", capture_dir, out_dir)
    return _write_atomically(Path(out_dir), fill)


__all__ = ["OPEN3D_DEPTH_MAX_M", "OPEN3D_VOXEL_M", "write_open3d_twin", "write_oracle_twin", "write_trivial_twin"]
