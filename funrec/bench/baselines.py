"""Two reference "methods" that write twin folders (FORMATS.md section 2) without reconstructing:
an oracle built from the ground truth, and a naive baseline that uses none.

They exercise :mod:`funrec.bench.evaluate` and :mod:`funrec.bench.run` at both ends of the score range.
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


__all__ = ["write_oracle_twin", "write_trivial_twin"]
