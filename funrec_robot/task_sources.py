"""Build an :class:`ArticulationTask` from what FunREC writes: a synthetic capture's ground truth (gt/) or a twin.

Each source is one function returning the same plain task, so the planner never knows where a task came
from. Both map the source's world frame into the frame of the scene the robot plans in.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from funrec.errors import FormatError, PlanningError
from funrec.formats.ground_truth import GroundTruth, read_ground_truth
from funrec.formats.twin import ArticulatedPart, read_articulation
from funrec.typed import FloatArray
from funrec_robot.errors import format_names
from funrec_robot.handle_geometry import (
    BIN_M,
    FRONT_SHARE,
    MIN_HANDLE_POINTS,
    PROUD_M,
    bar_thickness_min,
    measure_handle,
)
from funrec_robot.scene import part_front, part_joint
from funrec_robot.task import ArticulationTask

log = logging.getLogger(__name__)


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


def part_names(source: SceneSource) -> tuple[str, ...]:
    """Names of the articulated parts of a located scene (its ground truth's or its twin's)."""
    if source.kind == "gt":
        return tuple(p.part.name for p in read_ground_truth(source.folder).parts)
    return tuple(p.name for p in read_articulation(source.folder / "articulation.json").parts)


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
        handle_extent=front.handle_extent,
        demo_times=demo_times,
        demo_states=demo_states,
        source=f"gt:{gt.root}",
        source_files=(gt.root / "gt.json", gt.scene_xml),
    )


MESH_GRASP_INSET_M = 0.06
"""Without affordances, a door is grasped this far in from its edge farthest from the hinge, m (where handles sit)."""
MESH_FRONT_BAND_M = 0.01
"""Without affordances, part points within this distance of the part's front's depth form its front, m."""
MESH_HANDLE_DEPTH_M = 0.08
"""Without affordances, points standing more than this in front of the part's front are not its handle (the
bench's handles stand 1.6-3.7 cm proud, Meta-World's drawer bar 18 cm: left to the guess), m."""
MESH_HANDLE_RADIUS_M = 0.04
"""Without affordances, the handle is the mesh points proud of the front within this distance of its densest
point, m: a knob (1.6-3.2 cm) whole, or a stretch of a bar."""


LEVEL_BAR_MAX_TILT = np.deg2rad(30.0)
"""A round bar whose axis lies within this of level is taken level (``_level_approach``), rad."""


def _level_approach(approach: FloatArray, handle_axis: FloatArray) -> FloatArray:
    """(3,) the approach onto a round bar that stands far off its part (no front near the contact), turned about the
    bar's axis to level, on the side the hand came from: a round bar may be taken from any side, and is taken as the
    hand takes a drawer's or a window's bar, into the part. The affordance's approach is the hand's own: from above
    on the twins of mw_drawer_00 (51 degrees down) and mw_window_00 (38), where a drawer pulled level then drew the
    bar along the jaws and out of them (funrec_mm 58 N, Spot 78 N; Fetch left it 3.4 cm short). Unchanged for a bar
    more than ``LEVEL_BAR_MAX_TILT`` off level (the twin's z is up)."""
    handle_axis = np.asarray(handle_axis, dtype=np.float64)
    level = np.cross(np.array([0.0, 0.0, 1.0]), handle_axis)
    if np.linalg.norm(level) < np.cos(LEVEL_BAR_MAX_TILT):
        return approach
    level /= np.linalg.norm(level)
    level -= handle_axis * float(level @ handle_axis)
    level /= np.linalg.norm(level)
    return level if float(level @ approach) >= 0.0 else -level


def _part_points(root: Path, joint: ArticulatedPart) -> FloatArray:
    """(N, 3) vertices of a twin part's mesh (canonical state, twin world); empty without a mesh."""
    import trimesh

    if joint.mesh is None:
        return np.zeros((0, 3))
    mesh_path = root / joint.mesh
    try:
        return np.asarray(trimesh.load(mesh_path, process=False).vertices, dtype=np.float64).reshape(-1, 3)
    except (OSError, ValueError) as exc:
        raise FormatError(mesh_path, f"cannot read the part mesh: {exc}") from None


def _mesh_handle(p_world: FloatArray, front: float, depth: FloatArray, radial: FloatArray | None) -> FloatArray | None:
    """Centre of the handle a part's mesh shows standing proud of its front, or None.

    Handle points stand ``PROUD_M`` to ``MESH_HANDLE_DEPTH_M`` in front of the front (``depth`` of each point,
    ``front`` the front's); on a door only those in the half of it away from the hinge (``radial``: distance
    from the hinge axis) count, where handles sit. The handle is the densest spot among them: the point with
    the most others within ``MESH_HANDLE_RADIUS_M``, and the centroid of those (a knob, or a stretch of a
    bar) is returned.
    """
    proud = (depth >= front + PROUD_M) & (depth <= front + MESH_HANDLE_DEPTH_M)
    if radial is not None:
        proud &= radial >= 0.5 * float(radial.max())
    candidates = p_world[proud]
    if len(candidates) < MIN_HANDLE_POINTS:
        return None
    # Neighbour counts from a k-d tree: the proud points of a noisy twin can be thousands, and pairwise
    # distances are quadratic in memory.
    tree = cKDTree(candidates)
    seed = int(np.argmax(tree.query_ball_point(candidates, MESH_HANDLE_RADIUS_M, return_length=True)))
    close = np.asarray(tree.query_ball_point(candidates[seed], MESH_HANDLE_RADIUS_M), dtype=np.int64)
    if len(close) < MIN_HANDLE_POINTS:
        return None
    return candidates[np.sort(close)].mean(axis=0)


def _mesh_grasp(root: Path, joint: ArticulatedPart) -> tuple[FloatArray, FloatArray, FloatArray, bool]:
    """Contact point, approach and handle axis guessed from a part's mesh when the twin has no affordance, and
    whether the contact is on a handle the mesh shows.

    The front is the side of the part facing the cameras that tracked it (the mesh's thinnest principal
    direction, signed towards them), at the depth of the first well-filled depth bin from that side (not the
    front-most point: a knob stands 3 cm proud of it). A handle standing proud of the front (``_mesh_handle``)
    is grasped at its centre (on the twin of ``geo_angled_rev_cabinet_00``, whose door the hand never came
    near, the knob lay 27 cm above the door's mid-height, where the guess below had put the grasp 3.5 cm off
    the true door). Without one, a door is grasped on its front, ``MESH_GRASP_INSET_M`` in from the edge
    farthest from the hinge, at the part's mid-height; a drawer in the middle of its front. The handle axis is
    the hinge axis for a door, across the motion for a drawer.
    """
    from funrec.formats.camera_poses import read_camera_poses

    if joint.mesh is None:
        raise PlanningError(f"{root}: part '{joint.name}' has neither an affordance nor a mesh to grasp it by")
    mesh_path = root / joint.mesh
    p_world = _part_points(root, joint)
    if len(p_world) < 3:
        raise PlanningError(f"{mesh_path}: part '{joint.name}' has {len(p_world)} mesh points, too few to grasp it by")
    T_world_camera = read_camera_poses(root / "camera_poses.txt").T_world_camera
    tracked = np.asarray(joint.frames, dtype=int)
    tracked = tracked[(tracked >= 0) & (tracked < len(T_world_camera))]
    p_world_viewer = T_world_camera[tracked if tracked.size else slice(None), :3, 3].mean(axis=0)
    centre = p_world.mean(axis=0)
    _, _, Vt = np.linalg.svd(p_world - centre, full_matrices=False)
    normal = Vt[2] if float(Vt[2] @ (p_world_viewer - centre)) >= 0.0 else -Vt[2]
    depth = (p_world - centre) @ normal
    # The front's depth: the first bin from the viewer's side with FRONT_SHARE of the fullest (as
    # handle_geometry.front_standoff does about a contact), then the median depth of the points near it.
    counts, edges = np.histogram(depth, bins=np.arange(depth.min(), depth.max() + BIN_M, BIN_M))
    k = int(np.flatnonzero(counts >= FRONT_SHARE * counts.max())[-1])
    near_front = np.abs(depth - 0.5 * (edges[k] + edges[k + 1])) <= MESH_FRONT_BAND_M
    front_depth = float(np.median(depth[near_front]))
    front = p_world[np.abs(depth - front_depth) <= MESH_FRONT_BAND_M]
    radial = None
    if joint.joint_type == "revolute":
        handle_axis = joint.axis_world
        offsets = p_world - joint.pivot_world
        radial = np.linalg.norm(offsets - np.outer(offsets @ handle_axis, handle_axis), axis=1)
    else:
        handle_axis = np.cross(normal, joint.axis_world)
    handle = _mesh_handle(p_world, front_depth, depth, radial)
    if handle is not None:
        return handle, -normal, handle_axis, True
    if joint.joint_type == "revolute":
        radial_front = front - joint.pivot_world - np.outer((front - joint.pivot_world) @ handle_axis, handle_axis)
        reach = np.linalg.norm(radial_front, axis=1)
        edge = front[int(np.argmax(reach))]
        towards_hinge = -radial_front[int(np.argmax(reach))]
        towards_hinge -= normal * float(towards_hinge @ normal)  # stay on the front
        towards_hinge /= max(float(np.linalg.norm(towards_hinge)), 1e-9)
        contact = edge + MESH_GRASP_INSET_M * towards_hinge
        contact = contact + handle_axis * float((centre - contact) @ handle_axis)
    else:
        contact = front.mean(axis=0)
    return contact, -normal, handle_axis, False


def task_from_twin(
    twin_dir: str | Path,
    part: str | None = None,
    T_scene_twin: npt.ArrayLike | None = None,
    state_current: float = 0.0,
    interaction: int = 0,
) -> ArticulationTask:
    """The task for one part of a reconstructed twin, from articulation.json and affordances.json.

    affordances.json (``funrec-affordances/1``) is read through :func:`funrec.query.load_affordances`: the
    contact point and grasp frame at the canonical state (z the approach, x along the handle: the robot's
    grasp frame closes its fingers across it) and the demonstrated holds. A twin without affordances.json,
    or whose affordances miss the part, falls back to a grasp guessed from the part's mesh
    (``_mesh_grasp``), logs a warning and says so in ``task.source`` (hence in the plan's provenance).
    The handle's standoff from the part's front is measured on the part mesh, and a handle as short as a
    knob is taken for one (no handle axis: the fingers close horizontally; ``measure_handle``), and a bar is
    grasped centred across it.

    Args:
        twin_dir: twin folder (FORMATS.md section 2).
        part: part name; may be omitted when there is one part.
        T_scene_twin: (4, 4) maps the twin's world frame into the scene the robot plans in (identity when
            planning in twin.xml itself).
        state_current: state of the part in the scene when the robot arrives, rad or m.
        interaction: which demonstrated hold becomes the task's demonstration (0: the first).

    Raises:
        FormatError: a missing or malformed file or field; PlanningError: unknown part or hold.
    """
    from funrec.formats.affordances import AFFORDANCES_FILE
    from funrec.formats.twin_gravity import read_twin_gravity
    from funrec.query import load_affordances

    root = Path(twin_dir)
    articulation_path, affordances_path = root / "articulation.json", root / AFFORDANCES_FILE
    twin = read_articulation(articulation_path)
    gravity = read_twin_gravity(root)
    if gravity is not None and not gravity.floor_seen:
        log.warning("%s: the robot stands on a floor the capture did not show (%s)", root, gravity.floor)
    names = [p.name for p in twin.parts]
    joint = twin.parts[_pick_part(names, part, articulation_path)]
    affordance, why = None, f"{affordances_path} is missing"
    if affordances_path.is_file():
        affordances = load_affordances(root)
        affordance = affordances.part(joint.name)
        why = f"{affordances_path}: {dict(affordances.missing).get(joint.name, 'part not in the file')}"
    demo_times, demo_states = np.zeros(0), np.zeros(0)
    on_handle = False
    if affordance is not None:
        p_contact = affordance.contact_point
        approach, handle_axis = affordance.T_world_grasp[:3, 2], affordance.T_world_grasp[:3, 0]
        if not 0 <= interaction < len(affordance.interactions):
            raise PlanningError(f"{affordances_path}: part '{joint.name}' has {len(affordance.interactions)} hold(s), no hold {interaction}")
        hold = affordance.interactions[interaction]
        demo_times, demo_states = hold.times_s - hold.times_s[0], hold.states
        source, files = f"twin:{root.resolve()}", (articulation_path, affordances_path)
    else:
        log.warning("part '%s': no affordance (%s); grasping it where its mesh suggests a handle", joint.name, why)
        p_contact, approach, handle_axis, on_handle = _mesh_grasp(root, joint)
        source, files = f"twin:{root.resolve()}", (articulation_path,)
        why += "; the grasp is on a handle the part mesh shows" if on_handle else "; the grasp is a guess on the part's front"
    # The handle's standoff from the part's front and its shape, measured on the part mesh around a contact
    # the hand made (not around one guessed on the front itself: the planner then assumes a standoff).
    standoff, thickness_max, thickness_min = None, None, None
    if affordance is not None or on_handle:
        p_part = _part_points(root, joint)
        shape = measure_handle(p_part, p_contact, approach, handle_axis)
        standoff, thickness_max = shape.standoff, shape.thickness_max
        if standoff is None and handle_axis is not None:  # no front near the contact: a bar standing far off it
            thickness_min = bar_thickness_min(p_part, p_contact, handle_axis)
            if thickness_min is not None:
                approach = _level_approach(approach, handle_axis)
        if shape.is_knob and shape.p_centre is not None:
            p_contact, handle_axis, thickness_max = shape.p_centre, None, None
        elif shape.p_bar is not None and np.any(shape.p_bar != p_contact):
            log.info("part '%s': grasp centred across its bar, %.1f mm from the affordance's contact point",
                     joint.name, 1e3 * float(np.linalg.norm(shape.p_bar - p_contact)))
            p_contact = shape.p_bar
    T = np.eye(4) if T_scene_twin is None else np.asarray(T_scene_twin, dtype=np.float64)
    return ArticulationTask(
        part=joint.name,
        joint_type=joint.joint_type,
        axis_world=_transform_vector(T, joint.axis_world),
        pivot_world=None if joint.pivot_world is None else _transform_point(T, joint.pivot_world),
        state_range=joint.state_range,
        state_current=state_current,
        p_world_contact=_transform_point(T, p_contact),
        approach_world=_transform_vector(T, approach),
        handle_axis_world=None if handle_axis is None else _transform_vector(T, handle_axis),
        surface_offset=standoff,
        handle_width_max=thickness_max,
        handle_width_min=thickness_min,
        demo_times=demo_times,
        demo_states=demo_states,
        source=source,
        grasp_source="affordances" if affordance is not None else f"mesh fallback ({why})",
        source_files=files,
    )


__all__ = ["SceneSource", "load_task", "locate_scene", "part_names", "task_from_ground_truth", "task_from_twin"]
