"""Synthetic ground truth written beside a generated capture (FORMATS.md section 4)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FormatError
from funrec.formats.camera_poses import read_camera_poses
from funrec.formats.twin import ArticulatedPart, part_from_json, part_to_json, read_json_object
from funrec.geometry.transforms import check_transform
from funrec.typed import FloatArray


@dataclass(frozen=True)
class GroundTruthPart:
    """A true articulated part: its joint and states, plus what the generator knows."""

    part: ArticulatedPart
    """Joint, states over every frame of the capture (world frame of gt/camera_poses.txt)."""
    handle_world: FloatArray
    """(3,) centre of the handle at the canonical state, world frame."""
    intervals: tuple[tuple[int, int], ...]
    """Frame spans [first, last] (inclusive) in which the hand holds the part."""


@dataclass(frozen=True)
class GroundTruth:
    """Everything in a capture's gt/ folder, with lazily read masks and points."""

    root: Path
    """The gt/ folder."""
    frame_count: int
    """Number of frames of the capture."""
    parts: tuple[GroundTruthPart, ...]
    """True articulated parts (empty for camera-only sequences)."""
    T_world_camera: FloatArray
    """(F, 4, 4) true camera-to-world poses."""
    T_scene_world: FloatArray
    """(4, 4) maps the ground-truth world frame into the frame of scene.xml."""
    extra: dict[str, Any]
    """Other gt.json fields (generator settings, sequence description); never needed to score."""

    @property
    def scene_xml(self) -> Path:
        return self.root / "scene.xml"

    def mask_path(self, part_name: str, frame: int) -> Path:
        return self.root / "masks" / part_name / f"{frame:06d}.png"

    def points_path(self, name: str) -> Path:
        """Path of ``points/<name>.ply`` ("static" or a part name)."""
        return self.root / "points" / f"{name}.ply"


def ground_truth_to_json(
    frame_count: int,
    parts: tuple[GroundTruthPart, ...],
    T_scene_world: FloatArray,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The gt.json dictionary."""
    data: dict[str, Any] = {"format": "funrec-gt/1", "frame_count": int(frame_count)}
    data["T_scene_world"] = np.asarray(T_scene_world, dtype=float).tolist()
    rows = []
    for gt_part in parts:
        row = part_to_json(gt_part.part)
        row["handle"] = [float(v) for v in gt_part.handle_world]
        row["intervals"] = [[int(a), int(b)] for a, b in gt_part.intervals]
        rows.append(row)
    data["parts"] = rows
    if extra:
        data.update({k: v for k, v in extra.items() if k not in data})
    return data


def write_ground_truth_json(path: str | Path, frame_count: int, parts: tuple[GroundTruthPart, ...], T_scene_world: FloatArray, extra: dict[str, Any] | None = None) -> None:
    """Write gt.json."""
    Path(path).write_text(json.dumps(ground_truth_to_json(frame_count, parts, T_scene_world, extra), indent=2) + "\n")


def read_ground_truth(gt_dir: str | Path) -> GroundTruth:
    """Read a gt/ folder (gt.json and camera_poses.txt; masks and points stay on disk).

    Args:
        gt_dir: the gt/ folder, or the capture folder that holds it.
    """
    root = Path(gt_dir)
    if not (root / "gt.json").is_file() and (root / "gt" / "gt.json").is_file():
        root = root / "gt"
    path = root / "gt.json"
    data = read_json_object(path)
    frame_count = data.get("frame_count")
    if not isinstance(frame_count, int) or frame_count <= 0:
        raise FormatError(path, f"frame_count must be a positive integer, got {frame_count!r}")
    try:
        T_scene_world = check_transform(data.get("T_scene_world", np.eye(4).tolist()), "T_scene_world")
    except ValueError as exc:
        raise FormatError(path, str(exc)) from None
    parts_data = data.get("parts")
    if not isinstance(parts_data, list):
        raise FormatError(path, "parts must be a list")
    parts = []
    for k, row in enumerate(parts_data):
        part = part_from_json(path, k, row)
        handle = row.get("handle")
        if not isinstance(handle, list) or len(handle) != 3:
            raise FormatError(path, f"parts[{k}].handle must be [x, y, z]")
        intervals = row.get("intervals")
        if not isinstance(intervals, list) or not all(isinstance(i, list) and len(i) == 2 for i in intervals):
            raise FormatError(path, f"parts[{k}].intervals must be a list of [first, last]")
        parts.append(GroundTruthPart(part, np.asarray(handle, dtype=np.float64), tuple((int(a), int(b)) for a, b in intervals)))
    poses = read_camera_poses(root / "camera_poses.txt")
    if len(poses.frames) != frame_count:
        raise FormatError(root / "camera_poses.txt", f"{len(poses.frames)} poses for {frame_count} frames")
    known = {"format", "frame_count", "T_scene_world", "parts"}
    return GroundTruth(
        root=root,
        frame_count=frame_count,
        parts=tuple(parts),
        T_world_camera=poses.T_world_camera,
        T_scene_world=T_scene_world,
        extra={k: v for k, v in data.items() if k not in known},
    )


__all__ = ["GroundTruth", "GroundTruthPart", "ground_truth_to_json", "read_ground_truth", "write_ground_truth_json"]
