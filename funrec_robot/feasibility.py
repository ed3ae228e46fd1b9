"""Robot-physics feasibility of a plan, checked kinematically on the robot-in-scene model: collisions along
joint motions, gravity loads against effort limits, speeds the simulated joints can sustain, where a part
runs into the rest of the scene.
"""

from __future__ import annotations

from collections.abc import Iterable

import mujoco
import numpy as np

from funrec.errors import PlanningError
from funrec.geometry.joints import joint_transform, joint_transforms
from funrec.typed import BoolArray, FloatArray
from funrec_robot.budget import check_time_limit
from funrec_robot.ik import WholeBodyIK
from funrec_robot.plan_file import Plan
from funrec_robot.robot import RobotDescription
from funrec_robot.scene import (
    bodies_geoms,
    floor_geoms,
    gravity_load,
    part_geoms,
    part_joint,
    robot_bodies,
    spring_load,
)
from funrec_robot.sim_model import apply_couplings, hand_bodies, robot_indices


class GravityOverload(PlanningError):
    """A planned configuration needs more of a joint's effort limit than allowed just to hold the arm up."""

    def __init__(self, message: str, joint: str | None = None) -> None:
        super().__init__(message)
        self.joint = joint
        """The planning joint overloaded; None if not told."""


MIN_EFFORT_LEFT = 0.05
"""Share of a joint's effort limit :func:`dynamic_limits` counts on at the least for moving it, however much of
it holding the robot still takes (the gravity check refuses plans that leave less than a tenth of it)."""


def dynamic_limits(
    robot: RobotDescription, model: mujoco.MjModel, share_damping: float, share_inertia: float,
    load: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """(nq,) speed and (nq,) acceleration limits for timing: the robot's, lowered where the simulated joint's
    damping or armature would take more than a share of its effort limit (``share_damping`` at full speed,
    ``share_inertia`` at full acceleration), so that the servos can follow the plan.

    Args:
        load: (nq,) effort the joints spend holding the robot still over the motion to be timed
            (:func:`holding_load`, N or N m): the shares are then of what is left of each effort limit
            (at least ``MIN_EFFORT_LEFT`` of it). None: of the whole limit.
    """
    indices = robot_indices(robot, model)
    damping = model.dof_damping[indices.dof]
    armature = model.dof_armature[indices.dof]
    effort = robot.effort_max
    if load is not None:
        effort = np.maximum(effort - np.abs(load), MIN_EFFORT_LEFT * effort)
    with np.errstate(divide="ignore"):
        v_cap = np.where(damping > 0, share_damping * effort / damping, np.inf)
        a_cap = np.where(armature > 0, share_inertia * effort / armature, np.inf)
    return np.minimum(robot.v_max, v_cap), np.minimum(robot.a_max, a_cap)


def holding_load(robot: RobotDescription, model: mujoco.MjModel, q: FloatArray) -> FloatArray:
    """(K, nq) effort each planning joint spends holding the robot still at (K, nq) configurations, N or N m:
    gravity (gravity compensation is delivered by the actuators within their limits, so it counts) and the
    model's joint springs. Fetch's file puts a 10 N m/rad spring on its forearm roll: at -2.38 rad it takes 23.8
    of the joint's 29.35 N m, and a retreat timed at the full limits asked 33 N m."""
    indices = robot_indices(robot, model)
    data = mujoco.MjData(model)
    loads = np.empty((len(q), robot.nq))
    for k, qk in enumerate(np.atleast_2d(q)):
        qpos = model.qpos0.copy()
        qpos[indices.qpos] = qk
        qpos[indices.held_qpos] = indices.held_values
        apply_couplings(indices, qpos)
        loads[k] = gravity_load(model, data, qpos)[indices.dof] + spring_load(model, qpos, indices.dof)
    return loads


def gravity_overload(
    robot: RobotDescription,
    model: mujoco.MjModel,
    ik: WholeBodyIK,
    q: FloatArray,
    states: FloatArray,
    fingers: float,
    share: float,
    joint: int | None = None,
) -> tuple[str, float, float] | None:
    """The first planning joint that must hold more than ``share`` of its effort limit at one of the (K, nq)
    configurations, as (joint, load, limit) in N or N m; None if none does. The load is gravity on the robot, the
    robot's own joint springs (:func:`~funrec_robot.scene.spring_load`: Fetch's forearm roll, turned 4.4 rad by a
    fridge door's swing, asked 44 N m of its 29.35 N m in the check of reseed-4 rev_fridge_00) and, with a scene
    ``joint``, the part's weight on the hand (:func:`handle_load`): a drop-down door hangs on the hand it is held
    by (TIAGo's arm_5_joint, 3.0 N m, held plain_rev_dishwasher_00's door at 3.2 N m with 11-22 N on the handle; a
    check of the arm's weight alone passed it)."""
    indices = ik.indices
    data = mujoco.MjData(model)
    allowed = share * robot.effort_max
    for qk, state in zip(q, states):
        qpos = ik.full_q(qk, float(state), fingers)
        full = gravity_load(model, data, qpos)
        bias = full[indices.dof].copy()
        if robot.gravity_compensation:
            bias = bias * model.body_gravcomp[model.dof_bodyid[indices.dof]]
        bias = bias + spring_load(model, qpos, indices.dof)
        load = np.abs(bias)
        if joint is not None:  # data's kinematics and bias are at qpos: the part's load read off them
            load = np.abs(bias + _handle_load_here(model, data, joint, int(indices.grasp_site),
                                                   float(full[model.jnt_dofadr[joint]]))[indices.dof])
        over = np.flatnonzero(load > allowed)
        if len(over):
            j = int(over[0])
            return robot.joint_names[j], float(load[j]), float(robot.effort_max[j])
    return None


def handle_load(model: mujoco.MjModel, data: mujoco.MjData, joint: int, qpos: FloatArray, site: int) -> FloatArray:
    """(nv,) generalised force the robot spends holding a scene joint's part still by its grasp ``site`` at
    ``qpos``, N or N m: ``J_site^T f``, with f the least force at the site that holds the part against its
    gravity and spring (as ``joint_loads``), along the direction the site moves with the part. Overwrites ``data``."""
    bias = gravity_load(model, data, qpos)
    return _handle_load_here(model, data, joint, site, float(bias[model.jnt_dofadr[joint]]))


def _handle_load_here(model: mujoco.MjModel, data: mujoco.MjData, joint: int, site: int, joint_bias: float) -> FloatArray:
    """:func:`handle_load` with ``data``'s kinematics already at the configuration and ``joint_bias`` the gravity
    load on the joint there (``gravity_load``'s entry at its dof): no second forward pass and no new MjData for
    each configuration the planner checks."""
    p_site = data.site_xpos[site].copy()
    axis = data.xaxis[joint].copy()
    if model.jnt_type[joint] == mujoco.mjtJoint.mjJNT_HINGE:
        v = np.cross(axis, p_site - data.xanchor[joint])
    else:
        v = axis
    speed2 = float(v @ v)
    if speed2 < 1e-8:
        return np.zeros(model.nv)
    load = joint_bias + _spring(model, joint, float(data.qpos[model.jnt_qposadr[joint]]))
    force = load * v / speed2  # f . v = load, the least such f
    jacp = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, None, site)
    return jacp.T @ force


def _spring(model: mujoco.MjModel, joint: int, state: float) -> float:
    """The scene joint's spring load at ``state``, N m or N."""
    return model.jnt_stiffness[joint] * (state - model.qpos_spring[model.jnt_qposadr[joint]])


def _geom_mask(model: mujoco.MjModel, *geoms: Iterable[int]) -> BoolArray:
    """(ngeom,) True for the geoms in any of ``geoms``."""
    mask = np.zeros(model.ngeom, dtype=bool)
    for group in geoms:
        mask[np.fromiter(group, dtype=np.int64)] = True
    return mask


def first_blocked_state(
    model: mujoco.MjModel, joint: int, start: float, target: float, step: float
) -> tuple[float, str] | None:
    """First state between start and target (scanned every ``step``, rad or m) where the part of a scene joint
    penetrates the rest of the scene (not counting contacts it already has at the start), and the geom it
    meets; None if it moves freely."""
    states = np.linspace(start, target, max(2, int(np.ceil(abs(target - start) / step)) + 1))
    part = _geom_mask(model, part_geoms(model, joint))
    others = np.isin(model.geom_bodyid, robot_bodies(model), invert=True) & ~part
    data = mujoco.MjData(model)
    resting: set[tuple[int, int]] = set()
    for k, state in enumerate(states):
        check_time_limit("the handle path (collision scan of the part's range)")
        data.qpos[:] = model.qpos0
        data.qpos[model.jnt_qposadr[joint]] = state
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        # From MuJoCo's contact arrays at once (looping over its contact structs took a tenth of a plan).
        geom = data.contact.geom[: data.ncon]
        hit = ((part[geom[:, 0]] & others[geom[:, 1]]) | (part[geom[:, 1]] & others[geom[:, 0]])) & (data.contact.dist[: data.ncon] < 0.0)
        pairs = {(int(g1), int(g2)) for g1, g2 in geom[hit]}
        if k == 0:
            resting = pairs
            continue
        new = pairs - resting
        if new:
            g1, g2 = next(iter(new))
            return float(state), model.geom(g2 if part[g1] else g1).name
    return None


def _robot_scene_contacts(data: mujoco.MjData, robot: BoolArray, ignored: BoolArray):
    """(robot geom, scene geom, distance) of each contact ``mj_collision`` left in ``data`` between the robot's
    geoms (mask ``robot``) and the scene's, other than the ``ignored`` ones (the handle, the floor), in contact
    order. Read from the contact arrays at once: looping over MuJoCo's contact structs took a third of Stretch 3's
    approach checks."""
    geom = data.contact.geom[: data.ncon]
    in_robot = robot[geom]
    first = in_robot[:, 0]
    r = np.where(first, geom[:, 0], geom[:, 1])
    other = np.where(first, geom[:, 1], geom[:, 0])
    keep = (first != in_robot[:, 1]) & ~ignored[other]
    dist = data.contact.dist[: data.ncon]
    for k in np.flatnonzero(keep):
        yield int(r[k]), int(other[k]), float(dist[k])


def first_collision(
    model: mujoco.MjModel,
    ik: WholeBodyIK,
    q: FloatArray,
    part_state: float,
    fingers: float,
    allowed: set[int],
    floor: set[int],
) -> tuple[str, str] | None:
    """First robot-scene contact along (K, nq) planning-joint samples (kinematic, penetration only), other
    than the gripper with the handle."""
    data = mujoco.MjData(model)
    robot_geoms = _geom_mask(model, bodies_geoms(model, ik.indices.bodies))
    ignored = _geom_mask(model, allowed, floor)
    for qk in q:
        data.qpos[:] = ik.full_q(qk, part_state, fingers)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        for r, other, _ in _robot_scene_contacts(data, robot_geoms, ignored):
            return model.geom(r).name, model.geom(other).name
    return None


def path_collision(
    model: mujoco.MjModel, ik: WholeBodyIK, q: FloatArray, states: FloatArray, fingers: float, floor: set[int],
) -> tuple[float, str, str] | None:
    """First contact (kinematic, penetration only) between the robot but its hand and the scene, the floor aside,
    along (K, nq) planning-joint positions with the part at (K,) ``states``: (state, robot body, scene geom), or
    None. The hand's contacts with the part are the grasp's (``clear_release``, the IK's gripper distance)."""
    data = mujoco.MjData(model)
    hand = bodies_geoms(model, hand_bodies(ik.robot, model, ik.indices.grasp_site))
    robot_geoms = _geom_mask(model, np.setdiff1d(bodies_geoms(model, ik.indices.bodies), hand))
    ignored = _geom_mask(model, floor, hand)
    for qk, state in zip(q, states):
        data.qpos[:] = ik.full_q(qk, float(state), fingers)
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        for r, other, _ in _robot_scene_contacts(data, robot_geoms, ignored):
            return float(state), model.body(int(model.geom_bodyid[r])).name, model.geom(other).name
    return None


def release_sweep_depth(
    model: mujoco.MjModel,
    ik: WholeBodyIK,
    q: FloatArray,
    part_state: float,
    commands: FloatArray,
    allowed: set[int],
    floor: set[int],
) -> tuple[FloatArray, tuple[str, str] | None]:
    """How deep the robot lies in the scene (other than the ``allowed`` geoms, the handle, and the floor) at
    planning-joint positions ``q`` with the fingers at each of ``commands`` (kinematic; the gripper opening on
    the handle at the end of the path), m.

    Returns:
        (K,) deepest penetration at each command (0 where nothing is touched), and the (robot geom, scene geom)
        of the deepest of all; None if nothing is touched.
    """
    data = mujoco.MjData(model)
    robot_geoms = _geom_mask(model, bodies_geoms(model, ik.indices.bodies))
    ignored = _geom_mask(model, allowed, floor)
    depths, deepest, names = [], 0.0, None
    for fingers in commands:
        data.qpos[:] = ik.full_q(q, part_state, float(fingers))
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        depth = 0.0
        for r, other, dist in _robot_scene_contacts(data, robot_geoms, ignored):
            if dist >= 0.0:
                continue
            depth = max(depth, -dist)
            if -dist > deepest:
                deepest, names = -dist, (model.geom(r).name, model.geom(other).name)
        depths.append(depth)
    return np.array(depths), names


def kinematic_collisions(
    robot: RobotDescription, model: mujoco.MjModel, plan: Plan, every: int = 5, allowed_radius: float = 0.06
) -> list[tuple[float, str, str]]:
    """Robot-scene contacts of a plan replayed kinematically (no physics), other than the gripper touching
    the part within ``allowed_radius`` of the handle.

    Returns:
        (time s, robot geom, scene geom) for each sampled contact.
    """
    indices = robot_indices(robot, model)
    joint = part_joint(model, plan.part)
    qadr = model.jnt_qposadr[joint]
    part = set(part_geoms(model, joint).tolist())
    robot_set = set(bodies_geoms(model, indices.bodies).tolist())
    gripper = set(bodies_geoms(model, hand_bodies(robot, model, indices.grasp_site)).tolist())
    data = mujoco.MjData(model)
    out = []
    T0 = plan.T_world_grasp_start
    p_contact0 = T0[:3, 3] + plan.provenance.get("grasp", {}).get("depth_m", 0.0) * T0[:3, 2]
    scene = np.flatnonzero(~np.isin(model.geom_bodyid, indices.bodies))
    floor = set(floor_geoms(model, scene).tolist())
    for i in range(0, len(plan.t), every):
        data.qpos[:] = model.qpos0
        data.qpos[indices.qpos] = plan.q[i]
        data.qpos[indices.held_qpos] = indices.held_values
        data.qpos[indices.gripper_qpos] = plan.gripper_command[i]
        data.qpos[qadr] = plan.part_state[i]
        apply_couplings(indices, data.qpos)
        mujoco.mj_forward(model, data)
        T_move = joint_transform(plan.joint_type, plan.axis_world, plan.pivot_world, plan.part_state[i] - plan.start_state)
        p_handle = T_move[:3, :3] @ p_contact0 + T_move[:3, 3]
        for c in data.contact[: data.ncon]:
            g1, g2 = int(c.geom1), int(c.geom2)
            if (g1 in robot_set) == (g2 in robot_set):
                continue
            r, s = (g1, g2) if g1 in robot_set else (g2, g1)
            if s in floor:
                continue
            if r in gripper and s in part and np.linalg.norm(c.pos - p_handle) < allowed_radius:
                continue
            out.append((float(plan.t[i]), model.geom(r).name, model.geom(s).name))
    return out


def resting_state(model: mujoco.MjModel, joint: int, state: float, duration: float, settled_speed: float) -> float:
    """Where a scene joint's part, put at ``state`` with the rest of the scene at its reference, comes to rest
    under gravity and its contacts with the scene (the robot collides with nothing here), rad or m.

    A part that overlaps the rest of the scene at ``state`` (a true scene's microwave door sunk 6.9 mm into the
    counter below it) is pushed out by MuJoCo's contact solver as soon as the simulation starts: the door stood
    0.049 rad open before the hand arrived and the jaw struck its front. Where it goes depends on the solver, so it
    is simulated (``mj_step``), for up to ``duration`` s, stopping once the part moves slower than
    ``settled_speed`` (rad/s or m/s) after the first 0.1 s.
    """
    # The robot's geoms are switched off in ``model`` itself and switched back on after: a copy of the model (all of
    # a robot's meshes) took 17-27 ms of each plan of Spot or Stretch 3, the simulation 2 ms.
    robot = bodies_geoms(model, robot_bodies(model))
    contype, conaffinity = model.geom_contype[robot].copy(), model.geom_conaffinity[robot].copy()
    try:
        model.geom_contype[robot] = 0
        model.geom_conaffinity[robot] = 0
        data = mujoco.MjData(model)
        qadr, dof = int(model.jnt_qposadr[joint]), int(model.jnt_dofadr[joint])
        data.qpos[qadr] = state
        for step in range(int(np.ceil(duration / model.opt.timestep))):
            mujoco.mj_step(model, data)
            if step * model.opt.timestep >= 0.1 and abs(float(data.qvel[dof])) < settled_speed:
                break
    finally:
        model.geom_contype[robot] = contype
        model.geom_conaffinity[robot] = conaffinity
    return float(data.qpos[qadr])


def joint_loads(model: mujoco.MjModel, joint: int, states: FloatArray, qpos: FloatArray | None = None) -> FloatArray:
    """(N,) generalised force that holding a scene joint's part still at each state takes against gravity and
    the joint's spring (minus what they exert on it; the rest of the model at ``qpos``, default its reference),
    N m or N."""
    dof = int(model.jnt_dofadr[joint])
    data = mujoco.MjData(model)
    out = []
    qpos = (model.qpos0 if qpos is None else np.asarray(qpos, dtype=np.float64)).copy()
    for state in states:
        qpos[model.jnt_qposadr[joint]] = state
        bias = gravity_load(model, data, qpos)
        out.append(float(bias[dof] + _spring(model, joint, state)))
    return np.array(out)


def falls_to(model: mujoco.MjModel, joint: int, start: float, target: float, step: float, friction: bool = True) -> bool:
    """Whether gravity alone carries a scene joint's part from ``start`` to ``target`` (a drop-down door let go
    part-way): its gravity torque or force, at every state between them scanned every ``step``, points towards
    ``target`` and exceeds the joint's dry friction (with ``friction``; without, any load towards it counts)."""
    if abs(target - start) < 1e-9:
        return True
    states = np.linspace(start, target, max(2, int(np.ceil(abs(target - start) / step)) + 1))[:-1]
    direction = np.sign(target - start)
    holding = model.dof_frictionloss[int(model.jnt_dofadr[joint])] if friction else 0.0
    return bool(np.all(-direction * joint_loads(model, joint, states) > holding))


def holding_force(model: mujoco.MjModel, joint: int, states: FloatArray, p_contact: FloatArray, axis: FloatArray,
                  pivot: FloatArray) -> FloatArray:
    """(N, 3) least force, world, N, that a hand at a revolute part's contact point (``p_contact`` (3,) at state 0,
    on the joint of ``axis`` through ``pivot``) applies to hold the part still at each of ``states`` against its
    gravity and spring: along the direction the point moves, with the joint load over the lever arm (as
    :func:`handle_load`)."""
    axis = np.asarray(axis, dtype=np.float64)
    T = joint_transforms("revolute", axis, pivot, states)
    points = T[:, :3, :3] @ np.asarray(p_contact, dtype=np.float64) + T[:, :3, 3]
    v = np.cross(axis, points - np.asarray(pivot, dtype=np.float64))
    speed2 = np.einsum("ij,ij->i", v, v)
    scale = np.divide(joint_loads(model, joint, states), speed2, out=np.zeros(len(v)), where=speed2 > 1e-8)
    return scale[:, None] * v


def hand_capacity(robot: RobotDescription, model: mujoco.MjModel, share: float) -> float:
    """Largest force at the grasp point, N, that no arm hinge must spend more than ``share`` of its effort limit on
    (less what the arm's own weight takes of it at home), whatever the force's direction: each hinge's effort over
    its distance to the grasp point at home, the longest lever such a force can have there. A drop-down door let go
    to fall rests on a finger with its weight while the hand slides off the bar: TIAGo's wrist (arm_5_joint, 3 N m,
    0.39 m from the grasp point) held 25 N that way only beyond its limit."""
    indices = robot_indices(robot, model)
    data = mujoco.MjData(model)
    qpos = model.qpos0.copy()
    qpos[indices.qpos] = robot.q_home
    qpos[indices.held_qpos] = indices.held_values
    apply_couplings(indices, qpos)
    own = gravity_load(model, data, qpos)[indices.dof].copy()  # data's kinematics are at home after this
    if robot.gravity_compensation:
        own = own * model.body_gravcomp[model.dof_bodyid[indices.dof]]
    p_grasp = data.site_xpos[indices.grasp_site]
    capacity = np.inf
    for k, name in enumerate(robot.joint_names):
        joint = int(model.dof_jntid[indices.dof[k]])
        if name not in robot.arm_joints or model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_HINGE:
            continue
        lever = float(np.linalg.norm(p_grasp - data.xanchor[joint]))
        if lever > 1e-3:
            capacity = min(capacity, max(share * float(robot.effort_max[k]) - abs(float(own[k])), 0.0) / lever)
    return float(capacity)


def resting_force(model: mujoco.MjModel, joint: int, states: FloatArray, radius: float) -> FloatArray:
    """(N,) force with which a scene joint's part, let go at each of ``states``, presses on what supports it
    ``radius`` (m) from a revolute axis: its gravity and spring torque over that radius, N."""
    return np.abs(joint_loads(model, joint, states)) / max(radius, 1e-3)


__all__ = [
    "GravityOverload",
    "dynamic_limits",
    "falls_to",
    "first_blocked_state",
    "first_collision",
    "gravity_overload",
    "hand_capacity",
    "handle_load",
    "holding_force",
    "joint_loads",
    "kinematic_collisions",
    "path_collision",
    "release_sweep_depth",
    "resting_force",
    "resting_state",
]
