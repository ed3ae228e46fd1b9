"""Build an :class:`ArticulationTask` from what FunREC writes: a synthetic capture's ground truth (gt/) or a twin.

Each source is one function returning the same plain task, so the planner never knows where a task came
from. Both map the source's world frame into the frame of the scene the robot plans in.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from funrec.errors import FormatError, PlanningError
from funrec.ground_truth import GroundTruth, read_ground_truth
from funrec.twin_format import read_articulation
from funrec.typed import FloatArray
from funrec_robot.errors import format_names
from funrec_robot.scene import part_front, part_joint
from funrec_robot.task import ArticulationTask


@dataclass(frozen=True)
class SceneSource:
    """A scene to plan in and where its task comes from."""

    scene_xml: Path
    """MJCF of the scene (gt/scene.xml or a twin's twin.xml)."""
    kind: str
    """'gt' (gt.json beside it) or 'twin' (articulation.json and affordances.json beside it)."""
    folder: Path
    """The gt/ or twin folder."""


def locate_scene(path: str | Path) -> SceneSource:
    """Resolve what a user passes as a scene: an MJCF file, a gt/ folder, a capture folder holding gt/, or a
    twin folder.

    Raises:
        PlanningError: nothing that describes the scene's articulated parts is found beside it.
    """
    path = Path(path)
    folder = path.parent if path.is_file() else path
    if not path.exists():
        raise PlanningError(f"{path}: no such scene file or folder")
    if (folder / "gt" / "gt.json").is_file():
        folder = folder / "gt"
    if (folder / "gt.json").is_file():
        scene = path if path.is_file() else folder / "scene.xml"
        return SceneSource(scene, "gt", folder)
    if (folder / "articulation.json").is_file():
        scene = path if path.is_file() else folder / "twin.xml"
        return SceneSource(scene, "twin", folder)
    raise PlanningError(
        f"{path}: expected an MJCF scene with gt.json (synthetic ground truth) or articulation.json and "
        "affordances.json (a twin) beside it, or such a folder"
    )


def load_task(source: SceneSource, part: str | None = None, scene_model: mujoco.MjModel | None = None) -> ArticulationTask:
    """The task of a part of a located scene (``task_from_ground_truth`` or ``task_from_twin``)."""
    if source.kind == "gt":
        return task_from_ground_truth(source.folder, part, scene_model)
    return task_from_twin(source.folder, part)


def _pick_part(names: list[str], part: str | None, where: Path) -> int:
    if part is None:
        if len(names) != 1:
            raise PlanningError(f"{where}: {len(names)} parts, choose one with --part: {format_names(names)}")
        return 0
    if part not in names:
        raise PlanningError(f"{where}: no part '{part}'; parts: {format_names(names)}")
    return names.index(part)


def _transform_vector(T: FloatArray, v: npt.ArrayLike) -> FloatArray:
    return T[:3, :3] @ np.asarray(v, dtype=np.float64)


def _transform_point(T: FloatArray, p: npt.ArrayLike) -> FloatArray:
    return T[:3, :3] @ np.asarray(p, dtype=np.float64) + T[:3, 3]


def _capture_fps(gt: GroundTruth) -> float | None:
    intrinsics = gt.root.parent / "intrinsics.json"
    if intrinsics.is_file():
        fps = json.loads(intrinsics.read_text()).get("fps")
        if isinstance(fps, (int, float)) and fps > 0:
            return float(fps)
    spec = gt.extra.get("generator", {}).get("spec", {})
    fps = spec.get("fps") if isinstance(spec, dict) else None
    return float(fps) if isinstance(fps, (int, float)) and fps > 0 else None


def task_from_ground_truth(
    gt_dir: str | Path, part: str | None = None, scene_model: mujoco.MjModel | None = None
) -> ArticulationTask:
    """The task for one part of a synthetic capture, from gt/gt.json and gt/scene.xml.

    The joint, range and handle centre come from gt.json; the approach direction (minus the outward normal of
    the part's front), the handle's long axis and the handle's standoff from the front are read off the
    part's geoms in scene.xml. The demonstration is the first interval in which the hand holds the part.

    Args:
        gt_dir: the gt/ folder or the capture folder holding it.
        part: part name (= joint name in scene.xml); may be omitted when there is one part.
        scene_model: the compiled scene.xml (alone or with a robot), to avoid compiling it again.

    Raises:
        PlanningError: unknown part or a part whose front cannot be found; FormatError for a bad gt.json.
    """
    gt = read_ground_truth(gt_dir)
    names = [p.part.name for p in gt.parts]
    gt_part = gt.parts[_pick_part(names, part, gt.root / "gt.json")]
    joint = gt_part.part
    T = gt.T_scene_world
    model = scene_model if scene_model is not None else mujoco.MjModel.from_xml_path(str(gt.scene_xml))
    joint_id = part_joint(model, joint.name)
    p_contact = _transform_point(T, gt_part.handle_world)
    front = part_front(model, joint_id, p_contact)
    demo_times, demo_states = np.zeros(0), np.zeros(0)
    fps = _capture_fps(gt)
    if gt_part.intervals and fps is not None:
        first, last = gt_part.intervals[0]
        keep = (joint.frames >= first) & (joint.frames <= last)
        demo_times = (joint.frames[keep] - first) / fps
        demo_states = joint.states[keep]
    return ArticulationTask(
        part=joint.name,
        joint_type=joint.joint_type,
        axis_world=_transform_vector(T, joint.axis_world),
        pivot_world=None if joint.pivot_world is None else _transform_point(T, joint.pivot_world),
        state_range=joint.state_range,
        state_current=float(model.qpos0[model.jnt_qposadr[joint_id]]),
        p_world_contact=p_contact,
        approach_world=-front.normal_world,
        handle_axis_world=front.handle_axis_world,
        surface_offset=front.standoff,
        handle_width=front.handle_width,
        handle_depth=front.handle_depth,
        demo_times=demo_times,
        demo_states=demo_states,
        source=f"gt:{gt.root}",
        source_files=(gt.root / "gt.json", gt.scene_xml),
    )


def _affordance_rows(path: Path) -> list[dict[str, Any]]:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise FormatError(path, f"cannot read: {exc}") from None
    rows = data.get("parts") if isinstance(data, dict) else None
    if not isinstance(rows, list):
        raise FormatError(path, "expected an object with a 'parts' list")
    return rows


def task_from_twin(
    twin_dir: str | Path,
    part: str | None = None,
    T_scene_twin: npt.ArrayLike | None = None,
    state_current: float = 0.0,
) -> ArticulationTask:
    """The task for one part of a reconstructed twin, from articulation.json and affordances.json.

    affordances.json is read as ``{"parts": [{"name": NAME, "contact_point": [x, y, z],
    "T_world_grasp": 4x4, "surface_offset": m (optional), "handle_width": m (optional)}]}`` in the twin's world frame, with the grasp
    frame's z the approach direction and y the handle's long axis (the robot's grasp frame closes its
    fingers across it: its x is this y).

    Args:
        twin_dir: twin folder (FORMATS.md section 2).
        part: part name; may be omitted when there is one part.
        T_scene_twin: (4, 4) maps the twin's world frame into the scene the robot plans in (identity when
            planning in twin.xml itself).
        state_current: state of the part in the scene when the robot arrives, rad or m.

    Raises:
        FormatError: a missing or malformed file or field; PlanningError: unknown part.
    """
    root = Path(twin_dir)
    articulation_path, affordances_path = root / "articulation.json", root / "affordances.json"
    twin = read_articulation(articulation_path)
    names = [p.name for p in twin.parts]
    joint = twin.parts[_pick_part(names, part, articulation_path)]
    rows = [row for row in _affordance_rows(affordances_path) if isinstance(row, dict) and row.get("name") == joint.name]
    if not rows:
        raise FormatError(affordances_path, f"no affordance for part '{joint.name}'")
    row = rows[0]
    try:
        p_contact = np.asarray(row["contact_point"], dtype=np.float64).reshape(3)
        T_world_grasp = np.asarray(row["T_world_grasp"], dtype=np.float64).reshape(4, 4)
    except (KeyError, ValueError, TypeError) as exc:
        raise FormatError(affordances_path, f"part '{joint.name}': contact_point (3) and T_world_grasp (4x4) needed: {exc}") from None
    T = np.eye(4) if T_scene_twin is None else np.asarray(T_scene_twin, dtype=np.float64)
    offset = row.get("surface_offset")
    return ArticulationTask(
        part=joint.name,
        joint_type=joint.joint_type,
        axis_world=_transform_vector(T, joint.axis_world),
        pivot_world=None if joint.pivot_world is None else _transform_point(T, joint.pivot_world),
        state_range=joint.state_range,
        state_current=state_current,
        p_world_contact=_transform_point(T, p_contact),
        approach_world=_transform_vector(T, T_world_grasp[:3, 2]),
        handle_axis_world=_transform_vector(T, T_world_grasp[:3, 1]),
        surface_offset=float(offset) if isinstance(offset, (int, float)) else None,
        handle_width=float(row["handle_width"]) if isinstance(row.get("handle_width"), (int, float)) else None,
        source=f"twin:{root}",
        source_files=(articulation_path, affordances_path),
    )


__all__ = ["SceneSource", "load_task", "locate_scene", "task_from_ground_truth", "task_from_twin"]
