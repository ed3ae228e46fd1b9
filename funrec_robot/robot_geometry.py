"""Facts about a robot's body that base placement and grasping need, measured on its MuJoCo model at home.

Shoulder and wrist centres, the reach between them, circles covering the robot's floor footprint (base and
home-pose arm, each with its height band) and how far the fingers reach past the grasp frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from funrec.typed import FloatArray
from funrec_robot.robot import RobotDescription
from funrec_robot.scene import box_corners, geom_boxes, subtree_bodies
from funrec_robot.sim_model import (
    RobotIndices,
    apply_couplings,
    build_mujoco_model,
    hand_bodies,
    reset_to_home,
    robot_indices,
)

FIXED_JAW_REACH_M = 0.02
"""A geom of the hand (not of a finger) reaching this close to the fingertips along the approach is a fixed
jaw, m (palms and wrist housings end well short of the fingertips)."""
TURRET_RIM_POINTS = 16
"""Points on the rim of an arm's turret disc tested against the base's discs (``_turret_circle``)."""
FOOTPRINT_CELL_M = 0.3
"""Largest side of the cells whose circumscribed circles cover a footprint rectangle, m."""

TELESCOPE_MARGIN_M = 0.05
"""How far inside its travel base placement measures a telescoping arm's reach from, at either end, m: the whole-body
IK's margin for hinges, which it kept for slides too until ``IKConfig.limit_margin_m``; placement was tuned on it
(Stretch 3), and the IK keeps the 4 cm beyond it as room."""


@dataclass(frozen=True)
class Circle:
    """A disc on the floor, in the base frame, that covers part of the robot between two heights."""

    centre_base: FloatArray
    """(2,) centre, base frame, m."""
    radius: float
    """Radius, m."""
    z_band: tuple[float, float]
    """(low, high) heights of what the disc covers, m above the base frame."""


@dataclass(frozen=True)
class RobotGeometry:
    """A robot's body as base placement sees it, from its model at the home pose with the base at zero."""

    p_base_shoulder: FloatArray
    """(3,) centre of the shoulder (anchor of the second arm joint), base frame, m."""
    wrist_to_grasp: float
    """Distance from the wrist centre (anchor of the second-last arm joint) to the grasp frame, m."""
    reach: float
    """Length of the chain from shoulder to wrist at full stretch (sum of anchor-to-anchor distances), m."""
    base_circles: tuple[Circle, ...]
    """Discs covering the robot without its arm (base, torso, head)."""
    arm_circles: tuple[Circle, ...]
    """Discs covering the arm at its home pose."""
    fingertip_depth: float
    """How far the finger geoms reach past the grasp frame along its z (the approach), m."""
    finger_depth_range: tuple[float, float]
    """(near, far) extent of the finger pads along the grasp z, relative to the grasp frame, m."""
    finger_corners: FloatArray
    """(M, 3) corners of the finger geoms' boxes in the grasp frame with the gripper open, m."""
    closed_finger_corners: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    """The same with the gripper at its closed command: a hinged jaw (Spot's) reaches further forward closed
    than open, and closes on the handle with its tip there."""
    palm_corners: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    """(P, 3) corners of the boxes of the hand's other geoms (palm, gripper body) in the grasp frame, m."""
    lift_range: tuple[float, float] | None = None
    """When the first arm joint is a vertical slide (a torso, a lift, a mast): how far the shoulder can move
    down and up from its home height, (<= 0, >= 0) m; None otherwise."""
    lift_sign: float = 1.0
    """+1 when the lift joint's position raises the shoulder, -1 when it lowers it."""
    reach_min: float = 0.0
    """Nearest the wrist comes to the shoulder with a telescoping arm drawn in (as far as the IK moves it), m;
    0 for other arms."""
    reach_yaw: float = 0.0
    """Direction the arm reaches out in, as a yaw about the base's z from its x axis, rad: the extending direction
    of a telescoping arm's horizontal slide, else 0 (forward)."""
    fixed_jaw: tuple[float, float] | None = None
    """A one-jaw gripper's fixed jaw: (grasp y of its inner face, the side it lies on, -1 or +1), m; None when
    every jaw moves. A handle taken at the grasp point would sit in it by half its thickness."""
    reach_up: float | None = None
    """How far the arm itself moves the wrist up or down from the shoulder, m: None for an arm of revolute joints
    (its reach, any way), a telescoping arm's travel times the sine of its slide's elevation (0 for a horizontal
    slide: the lift alone raises its wrist)."""


def _circles(corners: FloatArray, z_low: float, z_high: float) -> tuple[Circle, ...]:
    """Circumscribed circles of a grid of cells covering the rectangle around (N, 2) points."""
    low, high = corners.min(axis=0), corners.max(axis=0)
    counts = np.maximum(np.ceil((high - low) / FOOTPRINT_CELL_M), 1).astype(int)
    size = (high - low) / counts
    radius = float(np.linalg.norm(size) / 2.0)
    out = []
    for i in range(counts[0]):
        for j in range(counts[1]):
            centre = low + size * (np.array([i, j]) + 0.5)
            out.append(Circle(centre_base=centre, radius=radius, z_band=(z_low, z_high)))
    return tuple(out)


def _turret_circle(
    model: mujoco.MjModel, data: mujoco.MjData, joint: int, arm_geoms: np.ndarray, base_circles: tuple[Circle, ...]
) -> tuple[Circle, ...]:
    """The disc the arm's first link sweeps when its joint turns it about a vertical axis (a turret: Spot's
    ``arm_link_sh0``), as one more base disc, if it reaches out of the base's discs or above or below their band;
    else none. Wherever the arm reaches, that link stays within this disc: base placement keeps it clear of the
    part's sweep as it does the base. As an arm disc only the first stop keeps it clear, and of the part where it
    starts only: a fridge door above Spot's body (its band ends at 0.57 m) swung into the shoulder at 1.2 rad
    (plain_rev_fridge_00_r3, 18 mm deep in the plan's own kinematics, 1025 N in the check)."""
    axis = data.xaxis[joint]
    geoms = arm_geoms[model.geom_bodyid[arm_geoms] == model.jnt_bodyid[joint]]
    if model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_HINGE or abs(float(axis[2])) < 1.0 - 1e-6 or not len(geoms):
        return ()
    corners = _corners(model, data, geoms)
    centre = data.xanchor[joint][:2].copy()
    radius = float(np.linalg.norm(corners[:, :2] - centre, axis=1).max())
    band = (float(corners[:, 2].min()), float(corners[:, 2].max()))
    angles = np.linspace(0.0, 2.0 * np.pi, TURRET_RIM_POINTS, endpoint=False)
    rim = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    within = all(any(np.linalg.norm(p - c.centre_base) <= c.radius for c in base_circles) for p in rim)
    if within and all(c.z_band[0] <= band[0] and band[1] <= c.z_band[1] for c in base_circles):
        return ()
    return (Circle(centre_base=centre, radius=radius, z_band=band),)


def _corners(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray) -> FloatArray:
    return box_corners(*geom_boxes(model, data, geoms)).reshape(-1, 3)


_MEASURED: dict[tuple, tuple[mujoco.MjModel, dict[bytes, RobotGeometry]]] = {}
"""By robot file, its modification time and hand: the robot's own compiled model (compiling a robot with meshes
takes 0.03-0.15 s, more the first time) and the geometry already measured on it, by home pose (a robot with a lift
is measured again at the home its lift takes for each handle height: on the one compiled model, which the home
pose does not enter)."""


def measure_robot(robot: RobotDescription) -> RobotGeometry:
    """Measure a robot on its own MuJoCo model at home, base joints at zero, finger joints at the open command."""
    key = (str(robot.yaml_path), robot.yaml_path.stat().st_mtime_ns if robot.yaml_path.is_file() else 0,
           robot.T_ee_grasp.tobytes(), robot.gripper, robot.base_height)
    if key not in _MEASURED:
        _MEASURED[key] = (build_mujoco_model(robot), {})
    model, by_home = _MEASURED[key]
    home = robot.q_home.tobytes()
    if home not in by_home:
        by_home[home] = _measure(robot, model)
    return by_home[home]


def _measure(robot: RobotDescription, model: mujoco.MjModel) -> RobotGeometry:
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    indices = robot_indices(robot, model)
    data.qpos[indices.qpos[: len(robot.base_joints)]] = 0.0
    # Finger slides at the open command (a position servo's command is the finger position).
    data.qpos[indices.gripper_qpos] = robot.gripper.open
    apply_couplings(indices, data.qpos)
    mujoco.mj_kinematics(model, data)
    arm = [model.joint(f"robot/{name}").id for name in robot.arm_joints]
    shoulder, reach, reach_min, reach_yaw, reach_up = _shoulder_reach(robot, model, data, indices, arm)
    wrist = data.xanchor[arm[-2]].copy()
    p_grasp = data.site_xpos[indices.grasp_site]
    R_world_grasp = data.site_xmat[indices.grasp_site].reshape(3, 3)

    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    # A lift on the root body itself (a legged body's height, ``base_lift``) carries the whole robot: the arm starts
    # at the first joint on a body of its own.
    root = int(indices.bodies[0])
    turret = next(j for j in arm if int(model.jnt_bodyid[j]) != root)
    arm_bodies = subtree_bodies(model, int(model.jnt_bodyid[turret]))
    all_geoms = np.flatnonzero(collides & np.isin(model.geom_bodyid, indices.bodies))
    arm_geoms = all_geoms[np.isin(model.geom_bodyid[all_geoms], arm_bodies)]
    body_geoms = np.setdiff1d(all_geoms, arm_geoms)
    finger_bodies = np.unique(np.concatenate([
        subtree_bodies(model, int(model.jnt_bodyid[model.joint(f"robot/{name}").id])) for name in robot.gripper.joints
    ]))
    finger_geoms = all_geoms[np.isin(model.geom_bodyid[all_geoms], finger_bodies)]
    hand = hand_bodies(robot, model, indices.grasp_site)
    palm_geoms = np.setdiff1d(all_geoms[np.isin(model.geom_bodyid[all_geoms], hand)], finger_geoms)
    # A one-jaw gripper's fixed jaw belongs to the hand's body but reaches as far as the moving jaw: it is a
    # finger (the handle sits against it), not palm.
    tip = float(((_corners(model, data, finger_geoms) - p_grasp) @ R_world_grasp)[:, 2].max())
    far = np.array([((_corners(model, data, [g]) - p_grasp) @ R_world_grasp)[:, 2].max() for g in palm_geoms])
    jaws = palm_geoms[far >= tip - FIXED_JAW_REACH_M] if len(palm_geoms) else palm_geoms
    finger_geoms, palm_geoms = np.union1d(finger_geoms, jaws), np.setdiff1d(palm_geoms, jaws)
    fixed_jaw = None
    if len(jaws):
        y = ((_corners(model, data, jaws) - p_grasp) @ R_world_grasp)[:, 1]
        side = -1.0 if float(y.mean()) < 0.0 else 1.0
        fixed_jaw = (float(y.max() if side < 0 else y.min()), side)

    data.qpos[indices.gripper_qpos] = robot.gripper.closed
    apply_couplings(indices, data.qpos)
    mujoco.mj_kinematics(model, data)
    closed_fingers = (_corners(model, data, finger_geoms) - data.site_xpos[indices.grasp_site]) @ data.site_xmat[
        indices.grasp_site].reshape(3, 3)
    data.qpos[indices.gripper_qpos] = robot.gripper.open
    apply_couplings(indices, data.qpos)
    mujoco.mj_kinematics(model, data)
    body_corners = _corners(model, data, body_geoms)
    arm_corners = _corners(model, data, arm_geoms)
    finger_grasp = (_corners(model, data, finger_geoms) - p_grasp) @ R_world_grasp
    finger_z = finger_grasp[:, 2]
    base_circles = _circles(body_corners[:, :2], float(body_corners[:, 2].min()), float(body_corners[:, 2].max()))
    base_circles += _turret_circle(model, data, turret, arm_geoms, base_circles)
    lift_range, lift_sign = None, 1.0
    first = arm[0]
    if model.jnt_type[first] == mujoco.mjtJoint.mjJNT_SLIDE and abs(float(data.xaxis[first][2])) > 1.0 - 1e-6:
        lift_sign = float(np.sign(data.xaxis[first][2]))
        k = len(robot.base_joints)
        moves = sorted(lift_sign * (float(limit[k]) - float(robot.q_home[k])) for limit in (robot.q_min, robot.q_max))
        lift_range = (moves[0], moves[1])
    return RobotGeometry(
        p_base_shoulder=shoulder.copy(),
        wrist_to_grasp=float(np.linalg.norm(p_grasp - wrist)),
        reach=reach,
        base_circles=base_circles,
        arm_circles=_circles(arm_corners[:, :2], float(arm_corners[:, 2].min()), float(arm_corners[:, 2].max())),
        fingertip_depth=float(finger_z.max()),
        finger_depth_range=(float(finger_z.min()), float(finger_z.max())),
        finger_corners=finger_grasp,
        closed_finger_corners=closed_fingers,
        palm_corners=(_corners(model, data, palm_geoms) - p_grasp) @ R_world_grasp if len(palm_geoms) else np.zeros((0, 3)),
        lift_range=lift_range,
        lift_sign=lift_sign,
        reach_min=reach_min,
        reach_yaw=reach_yaw,
        reach_up=reach_up,
        fixed_jaw=fixed_jaw,
    )


def _shoulder_reach(
    robot: RobotDescription, model: mujoco.MjModel, data: mujoco.MjData, indices: RobotIndices, arm: list[int]
) -> tuple[FloatArray, float, float, float, float | None]:
    """Shoulder, reach, nearest reach (0 but for a telescoping arm), the direction the arm reaches in and how far
    it moves the wrist up (None: its reach).

    An arm of revolute joints: the shoulder is the anchor of the second arm joint, the reach the anchor-to-anchor
    length from there to the wrist. A telescoping arm (a slide between the shoulder and the wrist): the points the
    wrist can take lie on one line, the slide's, not in a ball about the slide's base. Its "shoulder" is the end of
    the telescope (the anchor of the first joint after the last slide) with the slides drawn in to their limits,
    and the reach runs from there along the slide: ``reach_min`` and ``reach`` are how far the end moves with the
    slides (and the joints coupled to them) drawn in and out to ``TELESCOPE_MARGIN_M`` inside their limits. Base placement's
    ball about that point, with its facing cost along the slide, then holds what the telescope reaches: a point on
    the line at the distance the slide moves it, and off the line only what a turn of the base brings onto it.
    (Measured from the slide's base instead, the ball took wrist targets 8 cm off Stretch 3's line, 4 cm beyond
    what its base can turn the line onto: the IK then missed the grasp by 5-20 mm with the telescope out.)
    ``data`` is left at the pose it came in."""
    k0 = len(robot.base_joints)
    slides = [k for k in range(1, len(arm) - 1) if model.jnt_type[arm[k]] == mujoco.mjtJoint.mjJNT_SLIDE]
    if not slides:
        # A legged body's pitch (``base_pitch``, a hinge on the root body) is measured level: the arm starts after it.
        root = int(indices.bodies[0])
        anchors = data.xanchor[[j for j in arm if not (int(model.jnt_bodyid[j]) == root and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE)]]
        return anchors[1].copy(), float(np.sum(np.linalg.norm(np.diff(anchors[1:-1], axis=0), axis=1))), 0.0, 0.0, None
    end = arm[slides[-1] + 1]  # the joint the telescope carries
    qpos = data.qpos.copy()
    ends = []
    for side, limits, inset in ((1.0, robot.q_min, 0.0), (1.0, robot.q_min, 1.0), (-1.0, robot.q_max, 1.0)):
        for k in slides:
            # the travel base placement counts on: ``TELESCOPE_MARGIN_M`` inside the limits, the leader's share of it
            margin = inset * TELESCOPE_MARGIN_M / robot.stages(robot.arm_joints[k])
            data.qpos[indices.qpos[k0 + k]] = limits[k0 + k] + side * margin
        apply_couplings(indices, data.qpos)
        mujoco.mj_kinematics(model, data)
        ends.append(data.xanchor[end].copy())
    axis = data.xaxis[arm[slides[-1]]]
    reach_yaw = float(np.arctan2(axis[1], axis[0])) if abs(float(axis[2])) < 0.5 else 0.0
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    shoulder = ends[0]
    reach_up = abs(float(ends[2][2] - shoulder[2]))
    return shoulder, float(np.linalg.norm(ends[2] - shoulder)), float(np.linalg.norm(ends[1] - shoulder)), reach_yaw, reach_up


__all__ = ["Circle", "RobotGeometry", "measure_robot"]
