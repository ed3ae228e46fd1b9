"""Build the MuJoCo model a robot is simulated with, alone or placed in a scene (twin.xml, scene.xml).

The robot's subtree is copied out of its model file (floors, tables and mocap bodies stay behind)
with MjSpec, gets the servos, damping overrides, gravity compensation and grasp site its YAML asks
for, and is attached at ``T_world_base``. Every robot element is renamed ``ROBOT_PREFIX + name``
(MuJoCo's attach needs a prefix to keep names unique); :func:`robot_indices` resolves them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from funrec.typed import FloatArray, IntArray
from funrec_robot.errors import RobotDescriptionError
from funrec_robot.model_facts import robot_spec
from funrec_robot.robot import RobotDescription

ROBOT_PREFIX = "robot/"
"""Prefix of every robot element name in a built model."""


@dataclass(frozen=True)
class RobotIndices:
    """Where the robot's joints, actuators and grasp site are in a model from :func:`build_mujoco_model`."""

    qpos: IntArray
    """(nq,) qpos addresses of the planning joints (base, then arm)."""
    dof: IntArray
    """(nq,) dof (qvel) addresses of the planning joints."""
    actuators: IntArray
    """(nq,) actuator driving each planning joint; its control is the joint position target, m or rad."""
    gripper_actuators: IntArray
    """(k,) actuators of the gripper; their control is the gripper command (open / closed)."""
    gripper_qpos: IntArray
    """(g,) qpos addresses of the finger joints."""
    held_qpos: IntArray
    """(h,) qpos addresses of the held joints."""
    held_actuators: IntArray
    """(h,) actuators holding them."""
    held_values: FloatArray
    """(h,) positions they are held at."""
    follower_qpos: IntArray
    """(c,) qpos addresses of the coupled joints (``RobotDescription.couplings``)."""
    leader_qpos: IntArray
    """(c,) qpos address of each one's leader."""
    follower_ratio: FloatArray
    """(c,) follower position per leader position."""
    grasp_site: int
    """Site id of the grasp frame."""
    grasp_site_name: str
    """Its name in the model (with ``ROBOT_PREFIX``), e.g. for ``mink.FrameTask``."""
    bodies: IntArray
    """(b,) body ids of the robot."""


RIGID_TOLERANCE = 1e-6
"""Largest deviation of R^T R from identity accepted in a placement transform."""


def _T_to_pos_quat(T: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(3,) translation and (4,) quat_wxyz of a (4, 4) rigid transform; raises ValueError on anything else."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"expected a (4, 4) rigid transform, got shape {T.shape}")
    R = T[:3, :3]
    if (
        not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0])
        or np.abs(R.T @ R - np.eye(3)).max() > RIGID_TOLERANCE
        or np.linalg.det(R) < 0.0
    ):
        raise ValueError(f"expected a (4, 4) rigid transform, got\n{np.round(T, 6)}")
    quat_xyzw = Rotation.from_matrix(R).as_quat()
    return T[:3, 3].copy(), np.roll(quat_xyzw, 1)  # MuJoCo wants quat_wxyz


def _limited(joint: mujoco.MjsJoint) -> bool:
    """Whether MuJoCo limits the joint's range (``limited`` true, or auto with a range set)."""
    return joint.limited == mujoco.mjtLimited.mjLIMITED_TRUE or (
        joint.limited == mujoco.mjtLimited.mjLIMITED_AUTO and joint.range[0] < joint.range[1]
    )


def _prepare_robot_spec(robot: RobotDescription) -> mujoco.MjSpec:
    """The robot's model file as a spec, with servos, damping, gravity compensation and grasp site added."""
    try:
        spec = robot_spec(robot.model_path, robot.root_body, robot.planar_base, robot.ee_body, robot.ee_site, robot.drop_actuators,
                          robot.base_lift, robot.base_pitch)
    except ValueError as exc:
        raise RobotDescriptionError(robot.model_path, f"MuJoCo cannot load the model: {exc}") from exc
    for name, damping in robot.damping.items():
        # MuJoCo 4 stores damping as polynomial coefficients; the override is purely linear.
        coefficients = np.zeros_like(np.atleast_1d(spec.joint(name).damping))
        coefficients[0] = damping
        spec.joint(name).damping = coefficients if np.ndim(spec.joint(name).damping) else damping
    for name, lower, upper in zip(robot.joint_names, robot.q_min, robot.q_max):
        joint = spec.joint(name)
        if not _limited(joint) and np.isfinite(lower) and np.isfinite(upper):
            # A joint the model leaves free whose range the robot file gives (``base_lift``, ``base_pitch``, which funrec_robot adds):
            # the IK's limits and the servo's command range are the joint's range in the model.
            joint.range = [float(lower), float(upper)]
            joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    for name, gains in robot.servos.items():
        joint = spec.joint(name)
        actuator = spec.add_actuator(name=f"{name}_servo", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_position(kp=gains.kp, kv=gains.kv)
        if _limited(joint):
            actuator.ctrlrange = joint.range
            actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.forcerange = [-gains.force, gains.force]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        if joint.actfrclimited != mujoco.mjtLimited.mjLIMITED_TRUE:
            joint.actfrcrange = [-gains.force, gains.force]
            joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
    for name, mass in robot.masses.items():
        body = spec.body(name)
        body.inertia = np.asarray(body.inertia) * (mass / body.mass)
        body.mass = mass
    gripper = robot.gripper
    if gripper.force is not None and gripper.actuator is not None:
        for name in (gripper.actuator, *gripper.extra_actuators):
            actuator = spec.actuator(name)
            gear = abs(float(actuator.gear[0])) or 1.0
            actuator.forcerange = [-gripper.force / gear, gripper.force / gear]
            actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    _add_coupling_equalities(spec, robot)
    root = spec.body(robot.root_body)
    if robot.gravity_compensation:
        for body in [root, *root.find_all(mujoco.mjtObj.mjOBJ_BODY)]:
            body.gravcomp = 1.0
        actuated = {a.target for a in spec.actuators if a.trntype == mujoco.mjtTrn.mjTRN_JOINT}
        for joint in root.find_all(mujoco.mjtObj.mjOBJ_JOINT):
            if joint.name in actuated:
                # Gravity compensation then comes from the actuator and counts against its force limit.
                joint.actgravcomp = True
    if robot.grasp_site != robot.ee_site:
        body_name, pos, quat_wxyz = _grasp_site_pose(robot)
        spec.body(body_name).add_site(name=robot.grasp_site, pos=pos, quat=quat_wxyz, size=[0.01, 0.01, 0.01])
    return spec


_GRASP_SITES: dict[tuple, tuple[str, FloatArray, FloatArray]] = {}
"""``_grasp_site_pose`` per robot model and end-effector: every model build (one per plan and check) compiled the
robot alone once more for it, ~0.1 s for a robot of meshes."""


def _grasp_site_pose(robot: RobotDescription) -> tuple[str, FloatArray, FloatArray]:
    """(body, pos, quat wxyz) of the grasp site in the body of the end-effector site. The compiled model gives the
    site's pose in its body whatever orientation syntax the file used."""
    path = Path(robot.model_path)
    key = (str(path), path.stat().st_mtime_ns if path.is_file() else 0, robot.root_body, repr(robot.planar_base), robot.ee_body,
           robot.ee_site, tuple(robot.drop_actuators), robot.base_lift, robot.base_pitch, np.asarray(robot.T_ee_grasp).tobytes())
    if key not in _GRASP_SITES:
        compiled = robot_spec(
            robot.model_path, robot.root_body, robot.planar_base, robot.ee_body, robot.ee_site, robot.drop_actuators,
            robot.base_lift, robot.base_pitch,
        ).compile()
        site = compiled.site(robot.ee_site)
        T_body_ee = np.eye(4)
        T_body_ee[:3, :3] = Rotation.from_quat(np.roll(site.quat, -1)).as_matrix()
        T_body_ee[:3, 3] = site.pos
        pos, quat_wxyz = _T_to_pos_quat(T_body_ee @ robot.T_ee_grasp)
        _GRASP_SITES[key] = (compiled.body(site.bodyid[0]).name, pos, quat_wxyz)
    return _GRASP_SITES[key]


def _add_coupling_equalities(spec: mujoco.MjSpec, robot: RobotDescription) -> None:
    """A joint equality ``follower = ratio * leader`` for each coupling the model's joint equalities do not
    already tie (directly or through other joints)."""
    linked: dict[str, set[str]] = {}
    for equality in spec.equalities:
        if equality.type == mujoco.mjtEq.mjEQ_JOINT and equality.name2:
            linked.setdefault(equality.name1, set()).add(equality.name2)
            linked.setdefault(equality.name2, set()).add(equality.name1)
    for follower, (leader, ratio) in robot.couplings.items():
        reached, todo = {follower}, [follower]
        while todo:
            for other in linked.get(todo.pop(), ()):
                if other not in reached:
                    reached.add(other)
                    todo.append(other)
        if leader in reached:
            continue
        data = np.zeros(mujoco.mjNEQDATA)
        data[1] = ratio
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, name1=follower, name2=leader, data=data)
        linked.setdefault(follower, set()).add(leader)
        linked.setdefault(leader, set()).add(follower)


def apply_couplings(indices: RobotIndices, qpos: FloatArray) -> None:
    """Set the coupled joints of ``qpos`` (a full model configuration, changed in place) from their leaders."""
    if len(indices.follower_qpos):
        qpos[indices.follower_qpos] = indices.follower_ratio * qpos[indices.leader_qpos]


def build_mujoco_spec(
    robot: RobotDescription,
    scene_xml: str | Path | None = None,
    T_world_base: npt.ArrayLike | None = None,
) -> mujoco.MjSpec:
    """The robot, with its simulation additions, alone or attached to a scene.

    The integrator is set to implicitfast (the servos' velocity gains are then integrated
    implicitly) and the timestep to the smaller of the scene's and the robot model's.

    Args:
        robot: the robot.
        scene_xml: MJCF scene to place the robot in (e.g. a twin's twin.xml); None for an empty world.
        T_world_base: (4, 4) pose of the base frame (root body at zero base joints) in the scene's
            world frame; None for the identity.

    Returns:
        An uncompiled spec; robot element names carry ``ROBOT_PREFIX``.

    Raises:
        RobotDescriptionError: the model or the scene cannot be loaded.
    """
    robot_spec = _prepare_robot_spec(robot)
    if scene_xml is None:
        world = mujoco.MjSpec()
        world.modelname = robot.name
        world.option.timestep = robot_spec.option.timestep
    else:
        try:
            world = mujoco.MjSpec.from_file(str(scene_xml))
        except ValueError as exc:
            raise RobotDescriptionError(scene_xml, f"MuJoCo cannot load the scene: {exc}") from exc
        world.option.timestep = min(world.option.timestep, robot_spec.option.timestep)
    world.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # MuJoCo keeps the parent's physics options on attaching and printed a warning block to stderr for each one the
    # robot's file sets otherwise (Spot's impratio and cone, Stretch's noslip iterations), before every plan's and
    # check's one-line answer. The robot's spec takes the scene's options, which stand either way.
    for name in _OPTION_FIELDS:
        value = getattr(world.option, name)
        setattr(robot_spec.option, name, value.copy() if isinstance(value, np.ndarray) else value)
    pos, quat_wxyz = _T_to_pos_quat(np.eye(4) if T_world_base is None else T_world_base)
    frame = world.worldbody.add_frame(pos=pos, quat=quat_wxyz)
    body = frame.attach_body(robot_spec.body(robot.root_body), ROBOT_PREFIX, "")
    # The base frame is the root body's frame (lifted by base.height): drop the placement it had in its own model file.
    body.pos = [0.0, 0.0, robot.base_height]
    body.quat = [1.0, 0.0, 0.0, 0.0]
    return world


_OPTION_FIELDS = tuple(name for name in dir(mujoco.MjSpec().option) if not name.startswith("_"))
"""Physics options of a spec (``mjsOption``'s fields)."""


def build_mujoco_model(
    robot: RobotDescription,
    scene_xml: str | Path | None = None,
    T_world_base: npt.ArrayLike | None = None,
    textures: bool = True,
) -> mujoco.MjModel:
    """Compile :func:`build_mujoco_spec`; arguments as there. With ``textures`` False, a model never rendered (the
    planner's): each texture is one flat texel, so no image is read and decoded (the bench scenes' 8-10 textures,
    9-10 MB of texels, took 0.05-0.1 s of each plan's first build of its scene, 10-25 % of a plan; deleting them
    from the spec took 6-10 ms more than this).

    Raises:
        RobotDescriptionError: the model or the scene cannot be loaded, or the result does not compile.
    """
    spec = build_mujoco_spec(robot, scene_xml, T_world_base)
    if not textures:
        for texture in spec.textures:
            texture.file, texture.builtin, texture.width, texture.height = "", mujoco.mjtBuiltin.mjBUILTIN_FLAT, 1, 1
    try:
        return spec.compile()
    except ValueError as exc:
        where = scene_xml if scene_xml is not None else robot.yaml_path
        raise RobotDescriptionError(where, f"MuJoCo cannot compile robot '{robot.name}' here: {exc}") from exc


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    index = mujoco.mj_name2id(model, kind, ROBOT_PREFIX + name)
    if index < 0:
        raise ValueError(f"{kind.name} '{ROBOT_PREFIX + name}' not in the model; was it built by build_mujoco_model?")
    return index


def _joint_actuator(model: mujoco.MjModel, joint: int) -> int:
    for actuator in range(model.nu):
        if model.actuator_trntype[actuator] == mujoco.mjtTrn.mjTRN_JOINT and model.actuator_trnid[actuator, 0] == joint:
            return actuator
    raise ValueError(f"joint '{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)}' has no actuator")


def robot_indices(robot: RobotDescription, model: mujoco.MjModel) -> RobotIndices:
    """Addresses of the robot's joints, actuators, grasp site and bodies in a built model.

    Args:
        robot: the robot.
        model: a model from :func:`build_mujoco_model` for this robot.
    """
    joint = mujoco.mjtObj.mjOBJ_JOINT
    planning = [_id(model, joint, name) for name in robot.joint_names]
    fingers = [_id(model, joint, name) for name in robot.gripper.joints]
    held = [_id(model, joint, name) for name in robot.held_joints]
    if robot.gripper.actuator is not None:
        gripper_actuators = [_id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
                             for name in (robot.gripper.actuator, *robot.gripper.extra_actuators)]
    else:
        gripper_actuators = [_joint_actuator(model, j) for j in fingers]
    root = _id(model, mujoco.mjtObj.mjOBJ_BODY, robot.root_body)
    bodies = [b for b in range(root, model.nbody) if b == root or _ancestor(model, b, root)]
    site = _id(model, mujoco.mjtObj.mjOBJ_SITE, robot.grasp_site)
    followers = list(robot.couplings)
    leaders = [robot.couplings[f][0] for f in followers]
    return RobotIndices(
        qpos=np.array([model.jnt_qposadr[j] for j in planning], dtype=np.int64),
        dof=np.array([model.jnt_dofadr[j] for j in planning], dtype=np.int64),
        actuators=np.array([_joint_actuator(model, j) for j in planning], dtype=np.int64),
        gripper_actuators=np.array(gripper_actuators, dtype=np.int64),
        gripper_qpos=np.array([model.jnt_qposadr[j] for j in fingers], dtype=np.int64),
        held_qpos=np.array([model.jnt_qposadr[j] for j in held], dtype=np.int64),
        held_actuators=np.array([_joint_actuator(model, j) for j in held], dtype=np.int64),
        held_values=np.array(list(robot.held_joints.values()), dtype=np.float64),
        follower_qpos=np.array([model.jnt_qposadr[_id(model, joint, n)] for n in followers], dtype=np.int64),
        leader_qpos=np.array([model.jnt_qposadr[_id(model, joint, n)] for n in leaders], dtype=np.int64),
        follower_ratio=np.array([robot.couplings[f][1] for f in followers], dtype=np.float64),
        grasp_site=site,
        grasp_site_name=ROBOT_PREFIX + robot.grasp_site,
        bodies=np.array(bodies, dtype=np.int64),
    )


def _ancestor(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > 0:
        body = int(model.body_parentid[body])
        if body == ancestor:
            return True
    return False


def hand_bodies(robot: RobotDescription, model: mujoco.MjModel, grasp_site: int) -> IntArray:
    """(k,) bodies of the robot's hand: the subtree of the grasp site's body, or, when the site hangs on a body of
    its own beside the fingers (Stretch 3's grasp centre beside its finger slide), of the deepest body that
    carries both the site and the finger joints. The IK keeps these geoms only millimetres off the scene and lets
    them touch the handle, as the check does."""
    def chain(body: int) -> list[int]:
        out = [body]
        while out[-1] > 0:
            out.append(int(model.body_parentid[out[-1]]))
        return out[::-1]

    fingers = [int(model.jnt_bodyid[model.joint(ROBOT_PREFIX + name).id]) for name in robot.gripper.joints]
    chains = [chain(int(model.site_bodyid[grasp_site]))] + [chain(b) for b in fingers]
    hand = 0
    for level in zip(*chains):
        if len(set(level)) > 1:
            break
        hand = level[0]
    inside = np.zeros(model.nbody, dtype=bool)
    inside[hand] = True
    for b in range(hand + 1, model.nbody):  # MuJoCo numbers children after their parents
        inside[b] = inside[model.body_parentid[b]]
    return np.flatnonzero(inside)


def reset_to_home(
    robot: RobotDescription, model: mujoco.MjModel, data: mujoco.MjData, gripper_open: bool = True
) -> None:
    """Put the robot at rest at its home pose with every servo targeting it, then run ``mj_forward``.

    Scene joints keep their reference positions. With a gripper actuator the fingers start at the
    model's reference and the actuator is commanded open (or closed); without one they start there.

    Args:
        robot: the robot.
        model: a model from :func:`build_mujoco_model`.
        data: its data, overwritten.
        gripper_open: open (True) or closed (False) gripper command.
    """
    indices = robot_indices(robot, model)
    mujoco.mj_resetData(model, data)
    data.qpos[indices.qpos] = robot.q_home
    data.ctrl[indices.actuators] = robot.q_home
    data.qpos[indices.held_qpos] = indices.held_values
    data.ctrl[indices.held_actuators] = indices.held_values
    command = robot.gripper.open if gripper_open else robot.gripper.closed
    if robot.gripper.actuator is None:
        data.qpos[indices.gripper_qpos] = command
    data.ctrl[indices.gripper_actuators] = command
    apply_couplings(indices, data.qpos)
    mujoco.mj_forward(model, data)


def gripper_position(indices: RobotIndices, data: mujoco.MjData) -> float:
    """Where the gripper is, in the units of its command: the length of its (position) actuator."""
    return float(data.actuator_length[indices.gripper_actuators[0]])


__all__ = ["ROBOT_PREFIX", "apply_couplings", "gripper_position", "hand_bodies", "RobotIndices", "build_mujoco_model", "build_mujoco_spec", "reset_to_home", "robot_indices"]
