"""A hand-built 12-frame 64x48 capture with ground truth, written with numpy only (no funrec.synth):
a wall and a floor as static points, a revolute door and a prismatic drawer front as part points, a
moving camera whose frame 0 is not the world frame, and part masks made by projecting the posed
part points. The evaluation and bench tests score twins against it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import trimesh

from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, write_mask
from funrec.formats.ground_truth import GroundTruthPart, write_ground_truth_json
from funrec.formats.twin import make_part
from funrec.geometry.camera import project
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import invert_transform, make_transform, transform_points

FRAME_COUNT = 12
INTRINSICS = CaptureIntrinsics(width=64, height=48, fx=40.0, fy=40.0, cx=31.5, cy=23.5, depth_scale=1000.0, fps=15.0)


def grid(corner, edge_u, edge_v, step):
    """(N, 3) points on the parallelogram ``corner + u * edge_u + v * edge_v``, about ``step`` apart."""
    corner, edge_u, edge_v = (np.asarray(v, dtype=float) for v in (corner, edge_u, edge_v))
    nu = int(round(np.linalg.norm(edge_u) / step)) + 1
    nv = int(round(np.linalg.norm(edge_v) / step)) + 1
    u, v = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv), indexing="ij")
    return corner + u.reshape(-1, 1) * edge_u + v.reshape(-1, 1) * edge_v


def _look_at(position, target):
    """T_world_camera of an OpenCV camera at ``position`` looking at ``target``, world z up."""
    forward = np.asarray(target, dtype=float) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return make_transform(np.stack([right, down, forward], axis=1), position)


def _ramp(start, stop, top):
    frames = np.arange(FRAME_COUNT)
    return top * np.clip((frames - start) / (stop - start), 0.0, 1.0)


def write_tiny_sequence(root: Path, name: str = "seq0", offset=(0.0, 0.0, 0.0)) -> Path:
    """Write a 12-frame 64x48 capture with ground truth in FORMATS.md section 4 layout.

    Args:
        root: parent folder.
        name: sequence folder name.
        offset: (3,) shift of the whole scene and camera path in the world frame, metres.

    Returns:
        The capture folder.
    """
    capture = root / name
    gt_dir = capture / "gt"
    offset = np.asarray(offset, dtype=float)
    T_world_camera = np.stack(
        [
            _look_at(offset + [0.1 * np.sin(0.3 * i), -1.5 + 0.02 * i, 1.2 + 0.05 * np.cos(0.4 * i)], offset + [0.0, 1.0, 0.9])
            for i in range(FRAME_COUNT)
        ]
    )
    static = np.concatenate(
        [grid([-1, 1, 0], [2, 0, 0], [0, 0, 2], 0.05), grid([-1, -1, 0], [2, 0, 0], [0, 2, 0], 0.05)]
    ) + offset
    door = make_part("door", "revolute", [0, 0, -1], offset + [-0.6, 0.95, 0.0], np.arange(FRAME_COUNT), _ramp(2, 7, 1.2))
    drawer = make_part("drawer", "prismatic", [0, -1, 0], None, np.arange(FRAME_COUNT), _ramp(6, 11, 0.3))
    points = {
        "door": grid([-0.6, 0.95, 0.5], [0.5, 0, 0], [0, 0, 0.8], 0.025) + offset,
        "drawer": grid([0.2, 0.95, 0.4], [0.5, 0, 0], [0, 0, 0.2], 0.025) + offset,
    }
    writer = CaptureWriter(capture, INTRINSICS)
    for frame in range(FRAME_COUNT):
        writer.write_frame(frame, np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64)))
    for part in (door, drawer):
        T_camera_world = invert_transform(T_world_camera)
        for frame in range(FRAME_COUNT):
            p_world = transform_points(joint_transform(part.joint_type, part.axis_world, part.pivot_world, part.states[frame]), points[part.name])
            uv, _ = project(transform_points(T_camera_world[frame], p_world), INTRINSICS.K)
            mask = np.zeros((48, 64), np.uint8)
            inside = np.all(np.isfinite(uv), axis=1)
            pixels = np.round(uv[inside]).astype(int)
            keep = (pixels[:, 0] >= 0) & (pixels[:, 0] < 64) & (pixels[:, 1] >= 0) & (pixels[:, 1] < 48)
            mask[pixels[keep, 1], pixels[keep, 0]] = 1
            mask = cv2.dilate(mask, np.ones((3, 3), np.uint8))
            if part.name == "drawer" and frame == 0:
                mask[:] = 0  # an empty true mask must be ignored, not scored
            write_mask(gt_dir / "masks" / part.name / f"{frame:06d}.png", mask > 0)
    (gt_dir / "points").mkdir(parents=True)
    trimesh.PointCloud(static).export(str(gt_dir / "points" / "static.ply"))
    for part_name, p in points.items():
        trimesh.PointCloud(p).export(str(gt_dir / "points" / f"{part_name}.ply"))
    parts = (
        GroundTruthPart(door, offset + np.array([-0.15, 0.93, 0.9]), ((2, 7),)),
        GroundTruthPart(drawer, offset + np.array([0.45, 0.93, 0.5]), ((6, 11),)),
    )
    write_ground_truth_json(gt_dir / "gt.json", FRAME_COUNT, parts, np.eye(4), {"description": "test fixture"})
    write_camera_poses(gt_dir / "camera_poses.txt", T_world_camera)
    return capture
