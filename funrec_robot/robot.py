"""A robot as FunREC plans for it: joints, limits, gripper and grasp frame, loaded from a robot YAML file.

The YAML file (``robots/<name>.yaml``; see ``robots/fetch.yaml`` for a robot from another project)
points at an MJCF or URDF model and says which of its joints are the mobile base, the arm, the
gripper, or held still. :func:`load_robot` checks every name and number against the model.

Keys (paths are relative to the YAML file, or ``package://<python package>/<path>``):

- ``name``: robot name (default: the file stem).
- ``model``: MJCF or URDF file that MuJoCo compiles. ``urdf``: optional URDF of the same robot (pinocchio).
- ``root_body``: body whose subtree is the robot; the rest of the model file (floor, tables, mocap
  bodies and anything welded to them) is ignored. Optional if the model has one top-level body.
  The base frame is this body's frame at zero base joint positions.
- ``base``: ``{x: JOINT, y: JOINT, yaw: JOINT}``, any subset (none: fixed base). x and y are slides
  along the root body's x and y axes, yaw a hinge about its z axis that comes after them in the chain. Or
  ``{planar: true}``: the model's free joint replaced by such joints (``robot_yaml.PLANAR_JOINTS``), with
  ``height`` (the root body above the floor), ``drive`` and ``lift: true`` (a vertical slide
  ``robot_yaml.BASE_LIFT_JOINT`` after them, a legged body's height, planned as the first arm joint) and ``pitch:
  true`` (then a hinge ``robot_yaml.BASE_PITCH_JOINT`` about the body's y, its pitch, planned with the arm).
- ``arm_joints``: hinge or slide joints the planner moves, base to hand.
- ``gripper``: ``joints`` (fingers), optional ``actuator``, and ``open`` / ``closed`` commands
  (the actuator's control value, or without an actuator the finger joint position).
- ``ee``: ``site`` and optionally the grasp frame in the site frame: ``approach_axis`` (grasp z,
  default [0, 0, 1]), ``closing_axis`` (grasp y, default [0, 1, 0]), ``offset`` (m, default 0).
- ``held_joints``: ``{JOINT: position}`` for robot joints the planner never moves (torso, head).
- ``coupled_joints``: ``{FOLLOWER: LEADER}`` or ``{FOLLOWER: {joint: LEADER, ratio: R}}``: joints that move as
  ``R`` times another robot joint (the stages of a telescoping arm, fingers geared to one slide). The leader
  is a base, arm, gripper or held joint; the follower is listed nowhere else. The planner moves followers with
  their leader; in simulation the model's joint equalities hold them (one is added where the model has none).
- ``home``: ``{JOINT: position}`` for planning joints; others start at the model's reference (qpos0).
- ``postures``: optional list of ``{JOINT: position}`` maps, other home postures (unlisted joints as in
  ``home``) that the planner tries in order when the arm in ``home`` cannot hold the gripper at the handle.
- ``limits``: ``position`` ([lower, upper]), ``velocity``, ``acceleration``, ``effort`` per joint;
  these supply or override the model's values. Every planning joint needs all four in the end.
- ``simulation``: ``gravity_compensation`` (bool), ``damping`` (joint -> value replacing the
  model's) and ``servos`` (joint -> {kp, kv}): a position servo is added to each joint the model
  does not actuate, with its force limited to the joint's effort limit; ``drop_actuators``: actuators of
  the model to leave out (e.g. a tendon actuator of coupled joints, replaced by a servo on the leader).

Every robot joint must be listed exactly once among base, arm, gripper and held joints.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import mujoco
import numpy as np

from funrec.typed import FloatArray
from funrec_robot.errors import RobotDescriptionError, UnknownNameError, format_names
from funrec_robot.model_facts import AXIS_TOLERANCE, ModelFacts, check_base_axes, object_names, read_model_facts
from funrec_robot.robot_yaml import BASE_MOTIONS, RobotFile, read_robot_yaml

BaseType = Literal["fixed", "holonomic", "x+y", "x", "y", "yaw", "x+yaw", "y+yaw"]


@dataclass(frozen=True)
class ServoGains:
    """A position servo ``force = kp (target - q) - kv qdot``, clamped to ``force``."""

    kp: float
    """Position gain, N m/rad or N/m."""
    kv: float
    """Velocity gain, N m s/rad or N s/m."""
    force: float
    """Symmetric force limit, N m or N (the joint's effort limit)."""


@dataclass(frozen=True)
class GripperDescription:
    """A parallel-jaw gripper."""

    joints: tuple[str, ...]
    """Finger joint names."""
    actuator: str | None
    """Actuator of the model that drives the fingers; None when funrec_robot adds a servo per finger."""
    open: float
    """Command for open fingers: the actuator's control, or the finger joint position (m or rad)."""
    closed: float
    """Command for closed fingers, same unit."""
    extra_actuators: tuple[str, ...] = ()
    """Further actuators given the same command (a model with one actuator per finger)."""
    open_width: float | None = None
    """Gap between the jaws at the open command, m; None: twice the open-to-closed span (fingers on slides
    whose command is each finger's travel, m). A hinged jaw (Spot's) gives its gap here."""

    force: float | None = None
    """Effort limit of the finger joints from the robot file (``limits.effort``), N or N m: it also caps the
    model's gripper actuators in simulation (a model's unlimited jaw servo would squeeze a handle with
    hundreds of newtons). None: the model's own limits."""
    release_gap: float | None = None
    """On letting go each finger opens this far clear of the handle, m (``gripper.release_gap``); None: the
    planner's ``GraspConfig.release_gap``. An arm that tracks its retreat loosely wants more room."""
    release_sweep: float | None = None
    """How much deeper into the part or the scene (the handle aside) the gripper, opening on the handle at the end
    of the path, may bring a finger than it lay while holding, m (``gripper.release_sweep``); None: not checked.
    The gripper then opens less than ``release_gap`` (``whole_body.clear_release``)."""
    release_time: float | None = None
    """How long the gripper takes to open on letting go, s (``gripper.release_time``); None: the planner's
    ``PlanConfig.gripper_time``. A hinged jaw whose opening shakes the wrist wants longer: the grasp lets go of
    the part moving as the hand moved last."""
    fall_rest_force: float | None = None
    """Most weight a part let go to fall (a drop-down door) may rest on a finger with, N
    (``gripper.fall_rest_force``); None: the planner's ``PlanConfig.fall_rest_force``. Fingertips on soft pads
    turn under the weight and hook the part's edge as the hand slides off it."""
    fall_retreat_scale: float | None = None
    """Speed of the retreat from such a part, as a fraction of the usual (``gripper.fall_retreat_scale``); None: the
    planner's ``PlanConfig.falling_retreat_scale``."""

    def rest_force(self, planner_default: float) -> float:
        """Most weight a part may rest on a finger with, N: ``fall_rest_force``, else ``planner_default`` (the
        planner's ``PlanConfig.fall_rest_force``)."""
        return planner_default if self.fall_rest_force is None else self.fall_rest_force

    def command(self, half_width: float) -> float:
        """The command that leaves ``half_width`` between the grasp centre and each jaw (linear between closed
        and open; not clipped)."""
        span = self.open - self.closed
        if self.open_width is None:
            return self.closed + half_width * float(np.sign(span))
        return self.closed + half_width * span / (self.open_width / 2.0)

    @property
    def open_gap(self) -> float:
        """Gap between the jaws at the open command, m: ``open_width``, or twice the open-to-closed span (the
        width ``command`` maps to ``open``)."""
        return self.open_width if self.open_width is not None else 2.0 * abs(self.open - self.closed)


@dataclass(frozen=True)
class RobotDescription:
    """A mobile manipulator as the planner sees it, checked against its model.

    The planning joints are the base joints then the arm joints, each one degree of freedom; every
    per-joint array has shape (nq,) in that order. Units are m and rad (per second, per second squared)
    and N or N m. Frames: ``base`` (root body at zero base joints), ``ee`` (the model's end-effector
    site) and ``grasp`` (z = approach direction, y = finger motion axis, x = y cross z).
    """

    name: str
    """Robot name."""
    yaml_path: Path
    """The robot YAML file this was loaded from."""
    model_path: Path
    """MJCF or URDF file of the robot."""
    urdf_path: Path | None
    """URDF of the same robot for pinocchio, if given."""
    root_body: str
    """Body of the model whose subtree is the robot."""
    base_joints: tuple[str, ...]
    """Base joint names, in the order of ``base_motions``."""
    base_motions: tuple[str, ...]
    """Motion of each base joint: 'x', 'y' (slides in the base frame) or 'yaw' (about base z)."""
    arm_joints: tuple[str, ...]
    """Arm joint names, base to hand."""
    gripper: GripperDescription
    """The gripper."""
    ee_site: str
    """End-effector site of the model."""
    T_ee_grasp: FloatArray
    """(4, 4) grasp frame in the end-effector site frame."""
    held_joints: dict[str, float]
    """Joints the planner never moves -> the position the simulation holds, m or rad."""
    q_home: FloatArray
    """(nq,) home configuration."""
    q_min: FloatArray
    """(nq,) lower position limits (-inf where unlimited)."""
    q_max: FloatArray
    """(nq,) upper position limits (+inf where unlimited)."""
    v_max: FloatArray
    """(nq,) speed limits, m/s or rad/s."""
    a_max: FloatArray
    """(nq,) acceleration limits, m/s^2 or rad/s^2."""
    effort_max: FloatArray
    """(nq,) force or torque limits, N or N m."""
    servos: dict[str, ServoGains]
    """Servos funrec_robot adds in simulation, by joint (joints the model does not actuate)."""
    damping: dict[str, float]
    """Joint damping that replaces the model's in simulation, N s/m or N m s/rad."""
    gravity_compensation: bool
    """Whether the simulated controllers cancel gravity (through the actuators, within effort limits)."""
    planar_base: bool = False
    """The model's free joint on the root body was replaced by the planar base joints (``model_facts.robot_spec``)."""
    drive: str = "holonomic"
    """'holonomic' or 'differential': a differential base moves only along its heading (x) and turns on the
    spot; the planner keeps it still at its stop while the arm works (see ``plan``)."""
    base_height: float = 0.0
    """Height of the root body above the base frame (the floor), m."""
    base_lift: bool = False
    """A vertical slide ``base_lift`` carries the root body above the planar base joints (a legged body's height,
    ``robot_yaml.BASE_LIFT_JOINT``); it is a planning joint, the first of the arm's (a lift)."""
    base_pitch: bool = False
    """A hinge ``base_pitch`` about the root body's y pitches it on the planar base joints (a legged body,
    ``robot_yaml.BASE_PITCH_JOINT``); it is a planning joint listed with the arm's."""
    ee_body: str | None = None
    """Body the end-effector site was added to, if the model has no site for it."""
    masses: dict[str, float] = field(default_factory=dict)
    """Body -> mass replacing the model file's (inertia scaled alike) in every model built for the robot, kg."""
    couplings: dict[str, tuple[str, float]] = field(default_factory=dict)
    """Follower joint -> (leader, ratio): the follower's position is ratio times the leader's; every leader is a
    base, arm, gripper or held joint (chains of followers are resolved to their first leader)."""
    drop_actuators: tuple[str, ...] = ()
    """Actuators of the model left out of every model built for the robot."""
    q_postures: tuple[FloatArray, ...] = ()
    """(nq,) other home configurations the planner tries, in order, when the arm in ``q_home`` cannot hold the
    gripper at the handle within its effort limits (a 7-DoF arm reaches a grasp in many ways; with a heavy
    gripper only some keep the wrist's load low)."""

    def __post_init__(self) -> None:
        nq = len(self.joint_names)
        for field_name in ("q_home", "q_min", "q_max", "v_max", "a_max", "effort_max"):
            array = np.array(getattr(self, field_name), dtype=np.float64)
            if array.shape != (nq,):
                raise ValueError(f"{field_name}: shape {array.shape}, expected ({nq},)")
            array.setflags(write=False)
            object.__setattr__(self, field_name, array)
        T_ee_grasp = np.array(self.T_ee_grasp, dtype=np.float64)
        if T_ee_grasp.shape != (4, 4):
            raise ValueError(f"T_ee_grasp: shape {T_ee_grasp.shape}, expected (4, 4)")
        T_ee_grasp.setflags(write=False)
        postures = tuple(np.array(q, dtype=np.float64) for q in self.q_postures)
        for q in postures:
            if q.shape != (nq,):
                raise ValueError(f"q_postures: shape {q.shape}, expected ({nq},)")
            q.setflags(write=False)
        object.__setattr__(self, "q_postures", postures)
        object.__setattr__(self, "T_ee_grasp", T_ee_grasp)

    def stages(self, joint: str) -> float:
        """The joint's motion together with that of the joints coupled to it, per unit of its own (1 + the
        followers' ratios): a telescoping arm's leading stage moves the hand four times as far as itself."""
        return 1.0 + sum(abs(ratio) for leader, ratio in self.couplings.values() if leader == joint)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Planning joint names: base joints, then arm joints."""
        return self.base_joints + self.arm_joints

    @property
    def nq(self) -> int:
        """Number of planning joints."""
        return len(self.base_joints) + len(self.arm_joints)

    @property
    def base_type(self) -> BaseType:
        """'fixed', 'holonomic' (x, y and yaw) or the motions joined by '+', e.g. 'x+y'."""
        if not self.base_motions:
            return "fixed"
        if self.base_motions == BASE_MOTIONS:
            return "holonomic"
        return "+".join(self.base_motions)  # type: ignore[return-value]

    @property
    def grasp_site(self) -> str:
        """Site of the grasp frame in models from ``build_mujoco_model`` (before the robot prefix)."""
        if np.array_equal(self.T_ee_grasp, np.eye(4)):
            return self.ee_site
        return f"{self.ee_site}_grasp"


def _grasp_transform(file: RobotFile) -> FloatArray:
    z = np.asarray(file.approach_axis, dtype=np.float64)
    y = np.asarray(file.closing_axis, dtype=np.float64)
    if np.linalg.norm(z) < AXIS_TOLERANCE or np.linalg.norm(y) < AXIS_TOLERANCE:
        raise RobotDescriptionError(file.path, "ee: approach_axis and closing_axis must be non-zero")
    z, y = z / np.linalg.norm(z), y / np.linalg.norm(y)
    if abs(float(z @ y)) > AXIS_TOLERANCE:
        raise RobotDescriptionError(
            file.path,
            f"ee: approach_axis {file.approach_axis} and closing_axis {file.closing_axis} are not perpendicular",
        )
    T_ee_grasp = np.eye(4)
    T_ee_grasp[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T_ee_grasp[:3, 3] = file.offset
    return T_ee_grasp


def _check_names(file: RobotFile, key: str, names: Iterable[str], valid: Iterable[str]) -> None:
    valid = list(valid)
    for name in names:
        if name not in valid:
            raise UnknownNameError(file.path, key, "joint", name, valid)


def _check_groups(facts: ModelFacts, planning: tuple[str, ...]) -> None:
    """Every robot joint is in exactly one group, and every per-joint key names a joint it may name."""
    file = facts.file
    groups = {
        "base": tuple(file.base.values()),
        "arm_joints": file.arm_joints,
        "gripper.joints": file.gripper_joints,
        "held_joints": tuple(file.held_joints),
        "coupled_joints": tuple(file.coupled_joints),
    }
    for key, names in groups.items():
        _check_names(file, key, names, facts.joints)
    listed = [name for names in groups.values() for name in names]
    repeated = sorted({name for name in listed if listed.count(name) > 1})
    if repeated:
        raise RobotDescriptionError(file.path, f"joints listed in more than one group: {format_names(repeated)}")
    unlisted = [name for name in facts.joints if name not in listed]
    if unlisted:
        raise RobotDescriptionError(
            file.path,
            f"robot joints not listed: {format_names(unlisted)}; put each under base, arm_joints, gripper.joints, "
            "held_joints or coupled_joints",
        )
    _check_names(file, "coupled_joints (leaders)", (leader for leader, _ in file.coupled_joints.values()), facts.joints)
    multi = [name for name in listed if not facts.is_hinge_or_slide(name)]
    if multi:
        raise RobotDescriptionError(file.path, f"only hinge and slide joints are supported, not {format_names(multi)}")
    _check_names(file, "home", file.home, planning)
    for k, posture in enumerate(file.postures):
        _check_names(file, f"postures[{k}]", posture, planning)
    for key in ("position", "velocity", "acceleration"):
        _check_names(file, f"limits.{key}", getattr(file, f"{key}_limits"), planning)
    per_joint: tuple[tuple[str, Iterable[str]], ...] = (
        ("limits.effort", file.effort_limits),
        ("simulation.damping", file.damping),
        ("simulation.servos", file.servos),
    )
    for key, keyed in per_joint:
        _check_names(file, key, keyed, facts.joints)


def _couplings(file: RobotFile) -> dict[str, tuple[str, float]]:
    """``coupled_joints`` with each follower tied to its first leader that is no follower (ratios multiplied)."""
    out = {}
    for follower in file.coupled_joints:
        leader, ratio, seen = follower, 1.0, {follower}
        while leader in file.coupled_joints:
            leader, step = file.coupled_joints[leader]
            ratio *= step
            if leader in seen:
                raise RobotDescriptionError(file.path, f"coupled_joints: '{follower}' leads back to itself")
            seen.add(leader)
        out[follower] = (leader, ratio)
    return out


def _joint_range(facts: ModelFacts, name: str) -> tuple[float, float]:
    return facts.file.position_limits.get(name, facts.joint_range(name))


def _effort(facts: ModelFacts, name: str) -> float:
    return facts.file.effort_limits.get(name, facts.effort(name))


def _limits(facts: ModelFacts, planning: tuple[str, ...]) -> dict[str, Any]:
    """q_min, q_max, v_max, a_max, effort_max, q_home and q_postures, model values overridden by the YAML's."""
    file = facts.file
    ranges = [_joint_range(facts, n) for n in planning]
    limits = {
        "q_min": np.array([low for low, _ in ranges]),
        "q_max": np.array([high for _, high in ranges]),
        "v_max": np.array([file.velocity_limits.get(n, np.inf) for n in planning]),
        "a_max": np.array([file.acceleration_limits.get(n, np.inf) for n in planning]),
        "effort_max": np.array([_effort(facts, n) for n in planning]),
        "q_home": np.array([file.home.get(n, facts.reference(n)) for n in planning]),
    }
    for key, field_name in (("velocity", "v_max"), ("acceleration", "a_max"), ("effort", "effort_max")):
        missing = [n for n, v in zip(planning, limits[field_name]) if not np.isfinite(v)]
        if missing:
            raise RobotDescriptionError(
                file.path, f"limits.{key}: no {key} limit for {format_names(missing)} (the model has none)"
            )
    home = {n: float(q) for n, q in zip(planning, limits["q_home"])}
    limits["q_postures"] = tuple(np.array([{**home, **posture}[n] for n in planning]) for posture in file.postures)
    for key, q_key in (("home", limits["q_home"]), *((f"postures[{k}]", q) for k, q in enumerate(limits["q_postures"]))):
        outside = [n for n, (low, high), q in zip(planning, ranges, q_key) if not low <= q <= high]
        if outside:
            raise RobotDescriptionError(file.path, f"{key}: outside the position limits: {format_names(outside)}")
    for name, value in file.held_joints.items():
        low, high = _joint_range(facts, name)
        if not low <= value <= high:
            raise RobotDescriptionError(
                file.path, f"held_joints.{name}: {value:g} outside the joint range [{low:g}, {high:g}]"
            )
    return limits


def _gripper(facts: ModelFacts) -> GripperDescription:
    file = facts.file
    if file.gripper_actuator is not None:
        command_ranges = [facts.actuator_ctrlrange("gripper.actuator", file.gripper_actuator)]
    else:
        command_ranges = [_joint_range(facts, n) for n in file.gripper_joints]
    for key, value in (("open", file.gripper_open), ("closed", file.gripper_closed)):
        if any(not low <= value <= high for low, high in command_ranges):
            raise RobotDescriptionError(
                file.path, f"gripper.{key}: {value:g} outside the command range {command_ranges}"
            )
    for k, name in enumerate(file.gripper_extra_actuators):
        facts.actuator_ctrlrange(f"gripper.actuator[{k + 1}]", name)
    forces = [file.effort_limits[n] for n in file.gripper_joints if n in file.effort_limits]
    return GripperDescription(file.gripper_joints, file.gripper_actuator, file.gripper_open, file.gripper_closed,
                              file.gripper_extra_actuators, file.gripper_open_width, min(forces) if forces else None,
                              file.gripper_release_gap, file.gripper_release_sweep, file.gripper_release_time,
                              file.gripper_fall_rest_force, file.gripper_fall_retreat_scale)


def _servos(facts: ModelFacts) -> dict[str, ServoGains]:
    """Servos for exactly the listed joints no actuator drives (fingers count as driven by a gripper actuator)."""
    file = facts.file
    listed = [*file.base.values(), *file.arm_joints, *file.held_joints]
    if file.gripper_actuator is None:
        listed += file.gripper_joints
    extra = [n for n in file.servos if facts.joints[n] in facts.actuated]
    if extra:
        raise RobotDescriptionError(
            file.path, f"simulation.servos: these joints already have an actuator in the model: {format_names(extra)}"
        )
    missing = [n for n in listed if facts.joints[n] not in facts.actuated and n not in file.servos]
    if missing:
        raise RobotDescriptionError(
            file.path, f"simulation.servos: joints without an actuator need servo gains: {format_names(missing)}"
        )
    servos = {}
    for name, entry in file.servos.items():
        force = _effort(facts, name)
        if not np.isfinite(force):
            raise RobotDescriptionError(
                file.path, f"limits.effort: servo joint '{name}' needs an effort limit for its servo force"
            )
        servos[name] = ServoGains(entry.kp, entry.kv, force)
    return servos


def _check_urdf(file: RobotFile, planning: tuple[str, ...]) -> None:
    if file.urdf is None:
        return
    try:
        urdf_joints = [joint.get("name", "") for joint in ET.parse(file.urdf).getroot().iter("joint")]
    except ET.ParseError as exc:
        raise RobotDescriptionError(file.path, f"urdf: cannot parse {file.urdf}: {exc}") from exc
    _check_names(file, "urdf", planning, urdf_joints)


def load_robot(path: str | Path) -> RobotDescription:
    """Load a robot YAML file and check it against its model.

    Args:
        path: ``robots/<name>.yaml`` or any robot YAML file (format in this module's docstring).

    Returns:
        The checked description.

    Raises:
        RobotDescriptionError: the message names the YAML file and the key, and lists the valid names.
    """
    file = read_robot_yaml(path)
    facts = read_model_facts(file)
    base_motions = tuple(m for m in BASE_MOTIONS if m in file.base)
    base_joints = tuple(file.base[m] for m in base_motions)
    planning = base_joints + file.arm_joints
    _check_groups(facts, planning)
    check_base_axes(facts)
    limits = _limits(facts, planning)
    gripper = _gripper(facts)
    servos = _servos(facts)
    if file.ee_site not in facts.sites:
        raise UnknownNameError(file.path, "ee.site", "site", file.ee_site, facts.sites)
    _check_urdf(file, planning)
    bodies = object_names(facts.model, mujoco.mjtObj.mjOBJ_BODY, range(1, facts.model.nbody))
    for name in file.masses:
        if name not in bodies:
            raise UnknownNameError(file.path, "simulation.masses", "body", name, bodies)
    return RobotDescription(
        name=file.name,
        yaml_path=file.path.resolve(),
        model_path=file.model,
        urdf_path=file.urdf,
        root_body=facts.root_name,
        base_joints=base_joints,
        base_motions=base_motions,
        arm_joints=file.arm_joints,
        gripper=gripper,
        ee_site=file.ee_site,
        T_ee_grasp=_grasp_transform(file),
        held_joints=dict(file.held_joints),
        servos=servos,
        damping=dict(file.damping),
        gravity_compensation=file.gravity_compensation,
        planar_base=file.planar_base,
        drive=file.drive,
        base_height=file.base_height,
        base_lift=file.base_lift,
        base_pitch=file.base_pitch,
        ee_body=file.ee_body,
        masses=dict(file.masses),
        couplings=_couplings(file),
        drop_actuators=file.drop_actuators,
        **limits,
    )


__all__ = ["BaseType", "GripperDescription", "RobotDescription", "ServoGains", "load_robot"]
