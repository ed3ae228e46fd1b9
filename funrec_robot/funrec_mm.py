"""The project's mobile manipulator, ``funrec_mm``: one Python source for its MJCF, URDF and robot YAML.

A 0.5 x 0.5 m holonomic base (x, y, yaw), a torso column at its back and a 7-DoF spherical-shoulder /
spherical-wrist arm with Kinova-Gen3-like link lengths and masses and Franka-Panda-like actuator
limits, ending in a 2F-85-like parallel-jaw gripper. The arm's first axis points forward out of the
torso at shoulder height, like a human shoulder, so that the shoulder pitch (+-128 deg) sweeps the
gripper level from 0.3 m to 1.6 m high at 0.6 m in front of the base centre; an arm standing upright
on the torso cannot reach down to 0.4 m there with a level gripper. ``tests/test_robot_model.py``
regenerates the three files under ``robots/`` and fails if the committed ones differ; regenerate with
``python -m funrec_robot.funrec_mm [ROBOTS_DIR]``.

Grasp frame ``grasp_site`` (between the finger pads): z is the approach direction (out of the palm),
y the finger motion axis (towards the left finger), x = y cross z. At zero joint positions the arm
points straight forward (base +x) with link z along the arm, link y along base y and link x down.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from funrec_robot.kinematic_tree import (
    Geom,
    Inertial,
    Joint,
    JointCoupling,
    KinematicTree,
    Link,
    PositionServo,
    Site,
)
from funrec_robot.model_writer import format_number, write_model_files

NAME = "funrec_mm"
SOURCE = "funrec_robot/funrec_mm.py"

BASE_HALF_EXTENTS = (0.25, 0.25, 0.14)
"""Chassis collision box half extents, m: a 0.5 x 0.5 m footprint, 0.05 m ground clearance, top at 0.33 m."""
SHOULDER_HEIGHT = 0.95
"""Height of the arm's first axis above the floor, m; centres the 0.3-1.6 m handle band."""
SHOULDER_X = 0.03
"""Forward offset of the shoulder pitch axis (arm_joint2) from the base centre, m. With 0.3 m from the
wrist centre to the grasp point, a level grasp at 0.6 m puts the wrist 0.27 m from the shoulder at
mid height, safely beyond the 0.23 m the elbow limit allows."""
TORSO_DEPTH = 0.102
"""Torso column depth along x, m: it spans from the back edge of the base to 0.148 m behind the centre."""
TORSO_TOP = 1.05
"""Height of the top of the torso column, m."""
FLANGE_LENGTH = 0.05
"""Arm base flange between the torso's front face and the first axis, m."""
# Kinova Gen3 7-DoF segment lengths between consecutive joint axes, m (its small lateral offsets dropped).
SEGMENTS = (0.1284, 0.2104, 0.2104, 0.2084, 0.1059, 0.1059, 0.0615)
"""Joint 1->2, 2->3, 3->4, 4->5, 5->6, 6->7, 7->flange distances along the straight arm, m."""
ARM_MASSES = (1.377, 1.164, 1.164, 0.930, 0.678, 0.678, 0.500)
"""Kinova Gen3 link masses for links 1-7, kg."""
ARM_RADII = (0.05, 0.05, 0.05, 0.045, 0.04, 0.04, 0.04)
"""Capsule radii of links 1-7, m."""
FINGER_STROKE = 0.0425
"""Travel of each finger from closed (pads touching) to open, m (85 mm total, like a Robotiq 2F-85)."""
GRASP_DEPTH = 0.13
"""Distance from the flange to the grasp point between the pad centres, m."""

_ARM_GREY = (0.75, 0.77, 0.8, 1.0)
_DARK = (0.2, 0.2, 0.22, 1.0)
_BLUE = (0.16, 0.4, 0.7, 1.0)


def _arm_joint(index: int) -> Joint:
    """Joint ``arm_joint<index>`` (1-based): odd joints turn about the link axis z, even ones pitch about y.

    Limits: velocity and effort of the Franka Panda's large (1-4) and small (5-7) actuators;
    acceleration below Panda's maxima; positions Gen3-like (finite on the roll joints).
    """
    large = index <= 4
    rolls = index % 2 == 1
    upper = {1: 2.9, 3: 2.9, 5: 2.9, 7: 2.9, 2: 2.24, 4: 2.57, 6: 2.09}[index]
    return Joint(
        name=f"arm_joint{index}",
        kind="revolute",
        axis=(0.0, 0.0, 1.0) if rolls else (0.0, 1.0, 0.0),
        lower=-upper,
        upper=upper,
        velocity=2.175 if large else 2.61,
        acceleration=10.0 if large else 15.0,
        effort=87.0 if large else 12.0,
        damping=1.0 if large else 0.5,
        armature=0.1 if large else 0.05,
    )


def _capsule_z(length: float, radius: float, rgba: tuple[float, float, float, float]) -> Geom:
    """A capsule whose axis runs from the link origin to ``length`` along z."""
    return Geom("capsule", (radius, 0.5 * length), pos=(0.0, 0.0, 0.5 * length), rgba=rgba)


def _base_links() -> list[Link]:
    hx, hy, hz = BASE_HALF_EXTENTS
    chassis_z = 0.05 + hz
    base_joints = (
        Joint(
            "base_x",
            "prismatic",
            (1.0, 0.0, 0.0),
            -10.0,
            10.0,
            velocity=0.8,
            acceleration=1.0,
            effort=400.0,
            damping=5.0,
        ),
        Joint(
            "base_y",
            "prismatic",
            (0.0, 1.0, 0.0),
            -10.0,
            10.0,
            velocity=0.8,
            acceleration=1.0,
            effort=400.0,
            damping=5.0,
        ),
        Joint(
            "base_yaw",
            "revolute",
            (0.0, 0.0, 1.0),
            -2.0 * math.pi,
            2.0 * math.pi,
            velocity=1.5,
            acceleration=2.0,
            effort=120.0,
            damping=2.0,
        ),
    )
    wheels = tuple(
        Geom(
            "cylinder",
            (0.05, 0.025),
            pos=(sx * 0.17, sy * 0.2, 0.05),
            rpy=(math.pi / 2, 0.0, 0.0),
            rgba=_DARK,
            collision=False,
        )
        for sx in (1.0, -1.0)
        for sy in (1.0, -1.0)
    )
    base = Link(
        "base_link",
        None,
        joints=base_joints,
        inertial=Inertial.solid_box(55.0, BASE_HALF_EXTENTS, (0.0, 0.0, chassis_z)),
        geoms=(Geom("box", BASE_HALF_EXTENTS, pos=(0.0, 0.0, chassis_z), rgba=_BLUE), *wheels),
    )
    torso_bottom = 0.05 + 2.0 * hz
    half_height = 0.5 * (TORSO_TOP - torso_bottom)
    centre_x = -hx + 0.5 * TORSO_DEPTH
    front_x = -hx + TORSO_DEPTH
    mount = (front_x - centre_x + 0.5 * FLANGE_LENGTH, 0.0, SHOULDER_HEIGHT - torso_bottom)
    torso = Link(
        "torso_link",
        "base_link",
        pos=(centre_x, 0.0, torso_bottom),
        inertial=Inertial.solid_box(8.0, (0.5 * TORSO_DEPTH, 0.1, half_height), (0.0, 0.0, half_height)),
        geoms=(
            Geom("box", (0.5 * TORSO_DEPTH, 0.1, half_height), pos=(0.0, 0.0, half_height), rgba=_ARM_GREY),
            Geom("cylinder", (0.055, 0.5 * FLANGE_LENGTH), pos=mount, rpy=(0.0, 0.5 * math.pi, 0.0), rgba=_DARK),
        ),
    )
    return [base, torso]


def _arm_links() -> list[Link]:
    hx, _, hz = BASE_HALF_EXTENTS
    torso_bottom = 0.05 + 2.0 * hz
    first_axis_x = SHOULDER_X - SEGMENTS[0]
    links = []
    # The first link turns a quarter about y: its z (the arm axis) points forward, its x down.
    parent = "torso_link"
    pos: tuple[float, float, float] = (first_axis_x - (-hx + 0.5 * TORSO_DEPTH), 0.0, SHOULDER_HEIGHT - torso_bottom)
    rpy: tuple[float, float, float] = (0.0, 0.5 * math.pi, 0.0)
    for index in range(1, 8):
        length, radius, mass = SEGMENTS[index - 1], ARM_RADII[index - 1], ARM_MASSES[index - 1]
        geom = (
            Geom("cylinder", (radius, 0.5 * length), pos=(0.0, 0.0, 0.5 * length), rgba=_DARK)
            if index == 7
            else _capsule_z(length, radius, _ARM_GREY if index % 2 else _DARK)
        )
        links.append(
            Link(
                f"arm_link{index}",
                parent,
                pos=pos,
                rpy=rpy,
                joints=(_arm_joint(index),),
                inertial=Inertial.solid_cylinder(mass, radius, length, (0.0, 0.0, 0.5 * length)),
                geoms=(geom,),
            )
        )
        parent, pos, rpy = f"arm_link{index}", (0.0, 0.0, length), (0.0, 0.0, 0.0)
    return links


def _gripper_links() -> list[Link]:
    palm = (0.035, 0.05, 0.045)
    hand = Link(
        "hand",
        "arm_link7",
        pos=(0.0, 0.0, SEGMENTS[-1]),
        inertial=Inertial.solid_box(0.8, palm, (0.0, 0.0, palm[2])),
        geoms=(Geom("box", palm, pos=(0.0, 0.0, palm[2]), rgba=_DARK),),
        sites=(Site("grasp_site", pos=(0.0, 0.0, GRASP_DEPTH)),),
    )
    pad = (0.01, 0.006, 0.03)
    fingers = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        joint = Joint(
            f"finger_{side}",
            "prismatic",
            (0.0, sign, 0.0),
            0.0,
            FINGER_STROKE,
            velocity=0.075,
            acceleration=1.0,
            effort=100.0,
            damping=2.0,
            armature=0.1,
        )
        # At q = 0 the inner pad faces meet on the y = 0 plane; the pad centres are at the grasp depth.
        fingers.append(
            Link(
                f"finger_{side}_link",
                "hand",
                pos=(0.0, 0.0, 2.0 * palm[2]),
                joints=(joint,),
                inertial=Inertial.solid_box(0.05, pad, (0.0, sign * pad[1], GRASP_DEPTH - 2.0 * palm[2])),
                geoms=(Geom("box", pad, pos=(0.0, sign * pad[1], GRASP_DEPTH - 2.0 * palm[2]), rgba=_ARM_GREY),),
            )
        )
    return [hand, *fingers]


def funrec_mm_tree() -> KinematicTree:
    """The full ``funrec_mm`` robot: base, torso, arm, gripper, servos and the finger coupling."""
    servos = [
        PositionServo("base_x", "base_x", kp=4000.0, kv=1100.0),
        PositionServo("base_y", "base_y", kp=4000.0, kv=1100.0),
        PositionServo("base_yaw", "base_yaw", kp=400.0, kv=75.0),
    ]
    for index in range(1, 8):
        kp, kv = (2000.0, 100.0) if index <= 4 else (500.0, 20.0)
        servos.append(PositionServo(f"arm_joint{index}", f"arm_joint{index}", kp=kp, kv=kv))
    servos.append(PositionServo("gripper", "finger_left", kp=2000.0, kv=40.0))
    return KinematicTree(
        name=NAME,
        links=(*_base_links(), *_arm_links(), *_gripper_links()),
        servos=tuple(servos),
        couplings=(JointCoupling("finger_right", "finger_left"),),
        excluded_contacts=(("finger_left_link", "finger_right_link"),),
    )


HOME = {"arm_joint2": -1.5, "arm_joint4": 2.4, "arm_joint6": -0.9}
"""Home pose of the joints that are not zero there, rad: upper arm up, gripper level and forward at ~1.12 m."""


def _yaml_map(values: dict[str, float], indent: str) -> str:
    return "".join(f"\n{indent}{name}: {format_number(value)}" for name, value in values.items())


def robot_yaml(tree: KinematicTree) -> str:
    """The robot YAML of ``funrec_mm`` (the format ``funrec_robot.load_robot`` reads)."""
    arm = [f"arm_joint{index}" for index in range(1, 8)]
    planning = ["base_x", "base_y", "base_yaw", *arm]
    velocity = {name: tree.joint(name).velocity for name in planning}
    acceleration = {name: tree.joint(name).acceleration for name in planning}
    return f"""\
# generated by {SOURCE}; do not edit, regenerate with `python -m funrec_robot.funrec_mm`.
# A FunREC robot description: see funrec_robot/robot.py for every key. Paths are relative to this file.
name: {NAME}
model: {NAME}/{NAME}.xml
urdf: {NAME}/{NAME}.urdf
root_body: base_link
base:  # holonomic: slides along the base frame's x and y, then a turn about z
  x: base_x
  y: base_y
  yaw: base_yaw
arm_joints: [{", ".join(arm)}]
gripper:
  joints: [finger_left, finger_right]  # finger_right follows finger_left (joint equality)
  actuator: gripper  # position servo on finger_left; open and closed are its targets, m
  open: {format_number(FINGER_STROKE)}
  closed: 0
ee:
  site: grasp_site  # already z = approach, y = finger axis
home:{_yaml_map(HOME, "  ")}
limits:  # position and effort limits are read from the model; MJCF has no speed or acceleration
  velocity:{_yaml_map(velocity, "    ")}
  acceleration:{_yaml_map(acceleration, "    ")}
simulation:
  gravity_compensation: true  # the arm controller cancels gravity, within the joint effort limits
"""


def write_funrec_mm(robots_dir: str | Path) -> tuple[Path, Path, Path]:
    """Write ``robots_dir/funrec_mm/funrec_mm.{xml,urdf}`` and ``robots_dir/funrec_mm.yaml``.

    Returns:
        (mjcf_path, urdf_path, yaml_path).
    """
    robots_dir = Path(robots_dir)
    tree = funrec_mm_tree()
    mjcf_path, urdf_path = write_model_files(tree, robots_dir / NAME, SOURCE)
    yaml_path = robots_dir / f"{NAME}.yaml"
    yaml_path.write_text(robot_yaml(tree))
    return mjcf_path, urdf_path, yaml_path


if __name__ == "__main__":
    write_funrec_mm(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "robots")
