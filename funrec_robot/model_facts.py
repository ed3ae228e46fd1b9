"""What a robot's compiled MuJoCo model says about it: the root body's subtree, its joints, sites and actuators.

Ranges come from the compiled model, so an MJCF written in degrees is read in radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from funrec_robot.errors import RobotDescriptionError, UnknownNameError, format_names
from funrec_robot.robot_yaml import BASE_LIFT_JOINT, BASE_PITCH_JOINT, PLANAR_JOINTS, RobotFile

AXIS_TOLERANCE = 1e-6
"""Largest deviation of a unit axis from the expected one (base axes, orthogonal grasp axes)."""


def object_names(model: mujoco.MjModel, kind: mujoco.mjtObj, ids: list[int] | range) -> list[str]:
    """Names of MuJoCo objects of one kind, ``<unnamed i>`` for those without."""
    return [mujoco.mj_id2name(model, kind, int(i)) or f"<unnamed {i}>" for i in ids]


@dataclass(frozen=True)
class ModelFacts:
    """The robot part of a compiled model file."""

    file: RobotFile
    """The robot YAML file that points at the model (its path is quoted in errors)."""
    model: mujoco.MjModel
    """The whole compiled model file."""
    root: int
    """Body id of the robot's root body."""
    joints: dict[str, int]
    """Robot joint name -> joint id, in tree order."""
    sites: tuple[str, ...]
    """Robot site names."""
    actuated: frozenset[int]
    """Ids of joints that an actuator drives directly (joint transmission)."""

    @property
    def root_name(self) -> str:
        """Name of the root body."""
        return mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_BODY, self.root) or ""

    def joint_range(self, name: str) -> tuple[float, float]:
        """(lower, upper) position limits of a robot joint; infinite when unlimited."""
        j = self.joints[name]
        if not self.model.jnt_limited[j]:
            return (-np.inf, np.inf)
        return (float(self.model.jnt_range[j, 0]), float(self.model.jnt_range[j, 1]))

    def reference(self, name: str) -> float:
        """The joint's reference position (qpos0)."""
        return float(self.model.qpos0[self.model.jnt_qposadr[self.joints[name]]])

    def effort(self, name: str) -> float:
        """Effort limit the model gives a joint: its actuatorfrcrange, else a force-limited actuator's, else inf."""
        model, joint = self.model, self.joints[name]
        if model.jnt_actfrclimited[joint]:
            return float(min(-model.jnt_actfrcrange[joint, 0], model.jnt_actfrcrange[joint, 1]))
        for actuator in range(model.nu):
            if (
                model.actuator_trntype[actuator] == mujoco.mjtTrn.mjTRN_JOINT
                and model.actuator_trnid[actuator, 0] == joint
            ):
                if model.actuator_forcelimited[actuator]:
                    low, high = model.actuator_forcerange[actuator]
                    return float(min(-low, high) * abs(model.actuator_gear[actuator, 0]))
        return float("inf")

    def actuator_ctrlrange(self, key: str, name: str) -> tuple[float, float]:
        """Control range of the actuator ``name`` (infinite when unlimited); ``key`` is the YAML key for errors."""
        actuator = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        if actuator < 0:
            valid = object_names(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR, range(self.model.nu))
            raise UnknownNameError(self.file.path, key, "actuator", name, valid)
        if not self.model.actuator_ctrllimited[actuator]:
            return (-np.inf, np.inf)
        low, high = self.model.actuator_ctrlrange[actuator]
        return (float(low), float(high))

    def is_hinge_or_slide(self, name: str) -> bool:
        """Whether a robot joint has one degree of freedom."""
        kind = int(self.model.jnt_type[self.joints[name]])
        return kind in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def robot_spec(
    model_path: Path,
    root_body: str,
    planar_base: bool = False,
    ee_body: str | None = None,
    ee_site: str = "",
    drop_actuators: tuple[str, ...] = (),
    base_lift: bool = False,
    base_pitch: bool = False,
) -> mujoco.MjSpec:
    """The model file as an MjSpec, with what a robot YAML adds to it: for ``planar_base`` the root body's free
    joint replaced by slides along its x and y and a hinge about its z (``PLANAR_JOINTS``; the file's
    keyframes, sized for the free joint, are dropped), and with ``base_lift`` a vertical slide after them
    (``BASE_LIFT_JOINT``), with ``base_pitch`` then a hinge about the body's y (``BASE_PITCH_JOINT``), for ``ee_body`` a site ``ee_site`` at that body's
    origin, and the actuators ``drop_actuators`` removed (with the keyframes, sized for them).

    Raises:
        ValueError: MuJoCo cannot load the file, the root body has no free joint to replace, or an actuator to
            drop is not in it.
    """
    spec = mujoco.MjSpec.from_file(str(model_path))
    if drop_actuators:
        for name in drop_actuators:
            actuator = spec.actuator(name)
            if actuator is None:
                raise ValueError(f"simulation.drop_actuators: no actuator '{name}'")
            spec.delete(actuator)
        for key in list(spec.keys):
            spec.delete(key)
    if planar_base:
        root = spec.body(root_body)
        free = [j for j in root.joints if j.type == mujoco.mjtJoint.mjJNT_FREE]
        if not free:
            raise ValueError(f"base.planar: root body '{root_body}' has no free joint to replace")
        spec.delete(free[0])
        for key in list(spec.keys):
            spec.delete(key)
        for (motion, name), axis in zip(PLANAR_JOINTS.items(), np.eye(3)):
            kind = mujoco.mjtJoint.mjJNT_HINGE if motion == "yaw" else mujoco.mjtJoint.mjJNT_SLIDE
            root.add_joint(name=name, type=kind, axis=axis)
        if base_lift:
            root.add_joint(name=BASE_LIFT_JOINT, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0.0, 0.0, 1.0])
        if base_pitch:
            root.add_joint(name=BASE_PITCH_JOINT, type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0.0, 1.0, 0.0])
    if ee_body is not None:
        body = spec.body(ee_body)
        if body is None:
            raise ValueError(f"ee.body: no body '{ee_body}'")
        body.add_site(name=ee_site, size=[0.01, 0.01, 0.01])
    return spec


def _compile(file: RobotFile) -> mujoco.MjModel:
    try:
        return mujoco.MjModel.from_xml_path(str(file.model))
    except ValueError as exc:
        raise RobotDescriptionError(file.path, f"model: MuJoCo cannot compile {file.model}: {exc}") from exc


def _root_body(file: RobotFile, model: mujoco.MjModel) -> int:
    if file.root_body is not None:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, file.root_body)
        if body <= 0:
            valid = object_names(model, mujoco.mjtObj.mjOBJ_BODY, range(1, model.nbody))
            raise UnknownNameError(file.path, "root_body", "body", file.root_body, valid)
        return body
    top_level = [b for b in range(1, model.nbody) if model.body_parentid[b] == 0 and model.body_mocapid[b] < 0]
    if len(top_level) != 1:
        names = format_names(object_names(model, mujoco.mjtObj.mjOBJ_BODY, top_level))
        raise RobotDescriptionError(
            file.path, f"root_body: {file.model.name} has {len(top_level)} top-level bodies ({names}); name the robot's"
        )
    return top_level[0]


def read_model_facts(file: RobotFile) -> ModelFacts:
    """Compile the model file and find the robot in it.

    Raises:
        RobotDescriptionError: the model does not compile, or the root body is missing or ambiguous.
    """
    model = _compile(file)
    root = _root_body(file, model)
    if file.planar_base or file.ee_body is not None or file.drop_actuators:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, root)
        try:
            model = robot_spec(file.model, name, file.planar_base, file.ee_body, file.ee_site, file.drop_actuators,
                               file.base_lift, file.base_pitch).compile()
        except ValueError as exc:
            raise RobotDescriptionError(file.path, f"model: {exc}") from exc
        root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    bodies = {root}
    for body in range(root + 1, model.nbody):  # MuJoCo numbers bodies depth-first: parents come first
        if int(model.body_parentid[body]) in bodies:
            bodies.add(body)
    joints = {
        name: j
        for j, name in enumerate(object_names(model, mujoco.mjtObj.mjOBJ_JOINT, range(model.njnt)))
        if int(model.jnt_bodyid[j]) in bodies
    }
    site_ids = [s for s in range(model.nsite) if int(model.site_bodyid[s]) in bodies]
    actuated = frozenset(
        int(model.actuator_trnid[a, 0])
        for a in range(model.nu)
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
    )
    sites = tuple(object_names(model, mujoco.mjtObj.mjOBJ_SITE, site_ids))
    return ModelFacts(file, model, root, joints, sites, actuated)


def check_base_axes(facts: ModelFacts) -> None:
    """Base slides must run along the root body's x and y axes and the yaw hinge turn about its z, after them.

    Raises:
        RobotDescriptionError: naming the base motion, the joint and the axis it has.
    """
    file, model = facts.file, facts.model
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    R_world_root = data.xmat[facts.root].reshape(3, 3)
    expected = {"x": ("slide", 0), "y": ("slide", 1), "yaw": ("hinge", 2)}
    for motion, name in file.base.items():
        joint = facts.joints[name]
        kind, column = expected[motion]
        axis_root = R_world_root.T @ data.xaxis[joint]
        actual = mujoco.mjtJoint(int(model.jnt_type[joint])).name.removeprefix("mjJNT_").lower()
        if actual != kind or np.abs(axis_root - np.eye(3)[column]).max() > AXIS_TOLERANCE:
            raise RobotDescriptionError(
                file.path,
                f"base.{motion}: joint '{name}' must be a {kind} along the root body's {'xyz'[column]} axis; it is a "
                f"{actual} with axis {np.round(axis_root, 6).tolist()} in the frame of '{facts.root_name}'",
            )
    if "yaw" in file.base:
        yaw = facts.joints[file.base["yaw"]]
        if any(facts.joints[file.base[m]] > yaw for m in ("x", "y") if m in file.base):
            raise RobotDescriptionError(
                file.path, "base.yaw: the yaw joint must come after the x and y slides in the chain"
            )


__all__ = ["AXIS_TOLERANCE", "ModelFacts", "check_base_axes", "object_names", "read_model_facts", "robot_spec"]
