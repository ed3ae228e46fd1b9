"""Whole-body inverse kinematics with mink: base and arm together put the grasp frame on a target.

One :class:`WholeBodyIK` works on the robot-in-scene MuJoCo model (``build_mujoco_model``): a FrameTask on
the grasp site, a PostureTask towards a reference (home arm, planned base pose), configuration and
velocity limits, and collision avoidance between robot geoms and the scene geoms near the task. Scene
joints (the articulated part at the state being planned), fingers and held joints are frozen.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial

import mink
import mujoco
import numpy as np
import numpy.typing as npt

from funrec.errors import PlanningError
from funrec.typed import FloatArray, IntArray
from funrec_robot.budget import check_time_limit
from funrec_robot.collision_limit import BoxedCollisionLimit, shared_boxes
from funrec_robot.robot import RobotDescription
from funrec_robot.scene import bodies_geoms, floor_geoms, gravity_load, spring_load, subtree_bodies
from funrec_robot.sim_model import ROBOT_PREFIX, apply_couplings, hand_bodies, robot_indices

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class IKConfig:
    """Settings of the whole-body IK."""

    position_tolerance: float = 0.001
    """A target counts as reached within this distance of the grasp site, m."""
    orientation_tolerance: float = 0.01
    """... and within this angle of its orientation, rad."""
    max_iterations: int = 250
    """Differential-IK steps per target before giving up."""
    stall_iterations: int = 8
    """Stop early when the error has not dropped by ``stall_fraction`` over this many steps."""
    stall_fraction: float = 0.02
    """Relative error decrease that counts as progress over ``stall_iterations`` steps."""
    step_time: float = 0.02
    """Time of one differential-IK step, s: velocity limits bound each step to v_max * step_time, which keeps
    a step (a few cm at the hand) shorter than ``collision_detection``."""
    position_cost: float = 1.0
    """FrameTask position weight, 1/m."""
    orientation_cost: float = 0.5
    """FrameTask orientation weight, 1/rad."""
    posture_cost_arm: float = 0.01
    """PostureTask weight on the arm joints (towards the reference posture)."""
    posture_cost_base: float = 0.2
    """PostureTask weight on the base joints (towards the planned base pose), and on a legged body's height and pitch
    (``base_lift``, ``base_pitch``: towards the previous solution along a path, home elsewhere)."""
    posture_cost_rolling_base: float = 0.005
    """The same for a differential-drive base: low, so that it turns and rolls with the handle before the arm
    winds into its joint limits (TIAGo on a cabinet door opened 90 degrees: tracked at 0.005, 24 cm off at 0.2)."""
    posture_cost_rolling_yaw: float = 0.005
    """The same for a differential-drive base's heading (the planner raises it to ``posture_cost_base`` for a
    telescoping arm, see ``plan``)."""
    hold_line: bool = False
    """Solve a pre-grasp pose again with a differential base held where it was placed (turning on the spot) when the
    rolling solve left it off the line of its placed heading (``whole_body``); the planner sets it for a telescoping
    arm, whose reach runs across that line (TIAGo's jointed arm lost 2 of 17 ground-truth parts with it)."""
    limit_margin: float = 0.05
    """Planned positions of hinges stay this far inside the position limits (room for the compliant controller
    to move the arm either way), rad."""
    limit_margin_m: float = 0.01
    """The same for slides (a lift, a telescope's leading stage), m: the check's servos aim no closer than
    ``controller.LIMIT_MARGIN_M`` (5 mm), and 5 mm more is the compliant controller's room. At 0.05 m, as for hinges,
    TIAGo's torso stopped 5 cm of its 35 cm below its top, and its pre-grasp missed wall-cabinet handles at 1.6 m by
    8-59 mm."""
    damping: float = 1e-3
    """Levenberg-Marquardt damping of the QP."""
    collision_distance: float = 0.05
    """Smallest gap kept between the robot's base and torso and the scene, m (the heavy base tracks its
    plan least closely)."""
    arm_collision_distance: float = 0.02
    """Smallest gap kept between the arm and the scene or the robot's body, m."""
    gripper_collision_distance: float = 0.0015
    """Smallest gap kept between the gripper and the scene, m (it works millimetres from the part's front)."""
    wrist_collision_distance: float = 0.005
    """Smallest gap kept between the last arm link with the hand and the arm's links before the wrist, and between
    the upper arm and the body, m (TIAGo flexing its wrist by 77 degrees at the end of a door's swing put its wrist
    into its forearm, Fetch's shoulder lift link met its torso: the servos then pushed against the contact beyond
    their effort limits)."""
    collision_detection: float = 0.1
    """Gap below which a pair of geoms enters the QP, m."""
    collision_gain: float = 0.5
    """Fraction of a gap a step may close (mink CollisionAvoidanceLimit gain)."""
    scene_radius: float = 0.8
    """Scene geoms within this distance of the region of interest are avoided, m."""
    solver: str = "daqp"
    """QP solver used through qpsolvers."""
    release_iterations: int = 60
    """Differential-IK steps after a stall short of the target with the posture reference moved to the stalled
    configuration (0: none): the posture task no longer pulls the hand off the target (Stretch 3 stalled 4-6 mm
    off with its base rolled 0.4 m from the planned stop)."""
    gravity_cost: float = 0.5
    """Weight of the task that keeps each arm joint's gravity load below ``gravity_free_share`` of its effort
    limit (0 turns it off): the arm's null space (elbow, base) is used to unload weak wrist joints."""
    gravity_free_share: float = 0.6
    """Share of a joint's effort limit that gravity may take before that task pulls, 1."""
    gravity_iterations: int = 15
    """Differential-IK steps spent unloading the arm after a target is reached."""


def joint_margins(robot: RobotDescription, model: mujoco.MjModel, config: IKConfig) -> FloatArray:
    """(nq,) how far inside its position limits the whole-body IK keeps each planning joint, rad or m:
    ``limit_margin_m`` for a slide, the leader of a telescope's stages included (its servo's own margin is in
    metres of that joint), ``limit_margin`` for a hinge, divided among a leader's coupled stages."""
    slide = [model.jnt_type[model.joint(ROBOT_PREFIX + name).id] == mujoco.mjtJoint.mjJNT_SLIDE for name in robot.joint_names]
    return np.array([config.limit_margin_m if s else config.limit_margin / robot.stages(name)
                     for s, name in zip(slide, robot.joint_names)])


@dataclass(frozen=True)
class IKResult:
    """Joint positions reaching a sequence of targets."""

    q: FloatArray
    """(N, nq) planning-joint positions (robot.joint_names order), m or rad."""
    position_error: FloatArray
    """(N,) distance from grasp site to target, m."""
    orientation_error: FloatArray
    """(N,) angle between grasp site and target orientations, rad."""


class HeadingConstraint(mink.Task):
    """A differential drive's rolling constraint, as an equality constraint of the IK's QP: the base moves only
    along its heading, ``-sin(yaw) dx + cos(yaw) dy = 0`` (it may turn on the spot). Each differential-IK step
    satisfies it exactly; a path of steps drifts sideways only to second order in the step length."""

    def __init__(self, model: mujoco.MjModel, dof_x: int, dof_y: int, qpos_yaw: int) -> None:
        super().__init__(cost=np.zeros(1), gain=1.0)
        self.nv, self.dof_x, self.dof_y, self.qpos_yaw = model.nv, dof_x, dof_y, qpos_yaw

    def compute_error(self, configuration: mink.Configuration) -> FloatArray:
        return np.zeros(1)

    def compute_jacobian(self, configuration: mink.Configuration) -> FloatArray:
        yaw = float(configuration.q[self.qpos_yaw])
        J = np.zeros((1, self.nv))
        J[0, self.dof_x], J[0, self.dof_y] = -np.sin(yaw), np.cos(yaw)
        return J


class CouplingConstraint(mink.Task):
    """Coupled joints as equality constraints of the IK's QP: each follower moves ``ratio`` times as fast as its
    leader (``RobotDescription.couplings``), so a telescoping arm's stages extend together."""

    def __init__(self, model: mujoco.MjModel, pairs: list[tuple[int, int, float]]) -> None:
        super().__init__(cost=np.zeros(len(pairs)), gain=1.0)
        self.J = np.zeros((len(pairs), model.nv))
        for row, (follower_dof, leader_dof, ratio) in enumerate(pairs):
            self.J[row, follower_dof], self.J[row, leader_dof] = 1.0, -ratio

    def compute_error(self, configuration: mink.Configuration) -> FloatArray:
        return np.zeros(self.J.shape[0])

    def compute_jacobian(self, configuration: mink.Configuration) -> FloatArray:
        return self.J


class GravityLoadTask(mink.Task):
    """Keeps arm joints' gravity loads below a share of their effort limits.

    The error of joint j is the part of its gravity load tau_j / limit_j beyond +-``free_share`` (zero below,
    so a robot whose arm is strong enough for its weight is not affected); its Jacobian is a forward
    difference of ``mj_rne`` over the arm joints (mink has no gravity task, and MuJoCo's ``mjd_inverseFD``
    would difference every joint of the scene too), projected onto the null space of ``frame_task`` over
    the ``planning`` dofs: to first order the task only moves the arm in ways that keep the grasp frame where
    it is, so it never pulls the hand off its target (a plain weighted task would). With gravity
    compensation the load is ``qfrc_bias * body_gravcomp`` as in ``feasibility.gravity_overload``; the joints' own
    springs count in full, as there (Fetch's forearm roll: the task turns it back towards its spring's rest).
    """

    def __init__(
        self, model: mujoco.MjModel, frame_task: mink.FrameTask, planning: IntArray, dofs: IntArray, qpos: IntArray,
        limits: FloatArray, compensated: bool, free_share: float, cost: float, step: float = 1e-5,
    ) -> None:
        super().__init__(cost=np.full(len(dofs), cost), gain=1.0)
        self.model, self.dofs, self.qpos = model, np.asarray(dofs), np.asarray(qpos)
        self.spring_scale = 1.0 / np.asarray(limits, dtype=np.float64)
        self.scale = self.spring_scale
        if compensated:
            self.scale = self.scale * model.body_gravcomp[model.dof_bodyid[self.dofs]]
        self.free_share, self.step = free_share, step
        self.frame_task, self.planning = frame_task, np.asarray(planning)
        self.data = mujoco.MjData(model)

    def _load(self, qpos: FloatArray) -> FloatArray:
        return (gravity_load(self.model, self.data, qpos)[self.dofs] * self.scale
                + spring_load(self.model, qpos, self.dofs) * self.spring_scale)

    def compute_error(self, configuration: mink.Configuration) -> FloatArray:
        load = self._load(configuration.q)
        return np.sign(load) * np.maximum(np.abs(load) - self.free_share, 0.0)

    def compute_jacobian(self, configuration: mink.Configuration) -> FloatArray:
        jacobian = np.zeros((len(self.dofs), self.model.nv))
        q = configuration.q.copy()
        load = self._load(q)
        active = np.abs(load) > self.free_share
        if not active.any():
            return jacobian
        for dof, adr in zip(self.dofs, self.qpos):
            q[adr] += self.step
            jacobian[:, dof] = (self._load(q) - load) / self.step
            q[adr] -= self.step
        jacobian[~active] = 0.0
        frame = self.frame_task.compute_jacobian(configuration)[:, self.planning]
        null = np.eye(len(self.planning)) - np.linalg.pinv(frame, rcond=1e-4) @ frame
        projected = np.zeros_like(jacobian)
        projected[:, self.planning] = jacobian[:, self.planning] @ null
        return projected


def _dofs(model: mujoco.MjModel, joints: IntArray) -> list[int]:
    return [int(model.jnt_dofadr[j]) for j in joints]


class WholeBodyIK:
    """Differential IK for one robot in one scene, reused for every target of a plan.

    Args:
        robot: the robot.
        model: robot-in-scene model from ``build_mujoco_model``.
        part_joint: id of the articulated part's joint (its state is set per target and frozen).
        region_world: (N, 3) points where the robot works (handle path, base poses); scene geoms near them
            are avoided.
        allowed_geoms: scene geoms the gripper may touch (the handle).
        config: settings.
        freeze_base: a differential-drive base: :meth:`solve` keeps its x and y where the solve starts (it
            may turn on the spot), unless asked to let it roll along its heading (``rolling``, as
            :meth:`track` always does; ``HeadingConstraint``).
    """

    def __init__(
        self,
        robot: RobotDescription,
        model: mujoco.MjModel,
        part_joint: int,
        region_world: npt.ArrayLike,
        allowed_geoms: npt.ArrayLike,
        config: IKConfig = IKConfig(),
        freeze_base: bool = False,
    ) -> None:
        self.robot = robot
        self.model = model
        self.config = config
        self.indices = robot_indices(robot, model)
        self.part_joint = int(part_joint)
        self.part_qpos = int(model.jnt_qposadr[part_joint])
        self.configuration = mink.Configuration(model)
        self.n_base = len(robot.base_joints)

        planning = set(int(d) for d in self.indices.dof)
        coupled = self._coupled_dofs(planning)
        frozen = [d for d in range(model.nv) if d not in planning and d not in {f for f, _, _ in coupled}]
        coupling: list[mink.Task] = [CouplingConstraint(model, coupled)] if coupled else []
        self.constraints = ([mink.DofFreezingTask(model, dof_indices=frozen)] if frozen else []) + coupling
        self.rolling_constraints = self.constraints
        self._active = self.constraints
        self._holding_path = False
        self.differential = freeze_base
        if freeze_base and set(robot.base_motions) == {"x", "y", "yaw"}:
            dof = dict(zip(robot.base_motions, self.indices.dof))
            still = frozen + [int(dof["x"]), int(dof["y"])]
            self.constraints = [mink.DofFreezingTask(model, dof_indices=sorted(still)), *coupling]
            yaw_qpos = int(self.indices.qpos[robot.base_motions.index("yaw")])
            self.rolling_constraints = [*self.rolling_constraints, HeadingConstraint(model, int(dof["x"]), int(dof["y"]), yaw_qpos)]
        elif freeze_base:
            translating = [int(d) for m, d in zip(robot.base_motions, self.indices.dof) if m in ("x", "y")]
            self.constraints = self.rolling_constraints = [
                mink.DofFreezingTask(model, dof_indices=sorted(frozen + translating)), *coupling
            ]
        self.frame_task = mink.FrameTask(
            self.indices.grasp_site_name, "site", position_cost=config.position_cost, orientation_cost=config.orientation_cost
        )
        posture_cost = np.zeros(model.nv)
        posture_cost[self.indices.dof[: self.n_base]] = config.posture_cost_rolling_base if freeze_base else config.posture_cost_base
        if freeze_base and "yaw" in robot.base_motions:
            posture_cost[self.indices.dof[robot.base_motions.index("yaw")]] = config.posture_cost_rolling_yaw
        posture_cost[self.indices.dof[self.n_base :]] = config.posture_cost_arm
        # A legged body's height and pitch (``base_lift``, ``base_pitch``: joints of the root body) carry the whole
        # robot: they move as reluctantly as the base does, not as freely as the arm (weighted as the arm, Spot's body
        # pitched back and forth at up to 0.23 rad/s while a dishwasher door moved 0.08 rad, and its hand pushed the
        # door back: 63 N, rev_dishwasher_00_r3).
        body = [k for k, name in enumerate(robot.arm_joints) if self._joint_body(name) == int(self.indices.bodies[0])]
        posture_cost[self.indices.dof[self.n_base + np.array(body, dtype=int)]] = config.posture_cost_base
        self.posture_task = mink.PostureTask(model, cost=posture_cost)
        self.tasks: list[mink.Task] = [self.frame_task, self.posture_task]
        if config.gravity_cost > 0.0:
            arm = slice(self.n_base, None)
            self.tasks.append(GravityLoadTask(
                model, self.frame_task, self.indices.dof, self.indices.dof[arm], self.indices.qpos[arm], robot.effort_max[self.n_base :],
                robot.gravity_compensation, config.gravity_free_share, config.gravity_cost,
            ))
        velocities = {ROBOT_PREFIX + name: float(v) for name, v in zip(robot.joint_names, robot.v_max)}
        position_limit = mink.ConfigurationLimit(model, min_distance_from_limits=config.limit_margin)
        # Only the planning joints are limited: a frozen scene joint may be set past its range (a twin's
        # range can be wrong) and must not make the QP infeasible.
        others = np.setdiff1d(np.arange(model.nq), self.indices.qpos)
        position_limit.lower[others] = -mujoco.mjMAXVAL
        position_limit.upper[others] = mujoco.mjMAXVAL
        # Each planning joint keeps ``joint_margins``: a slide its margin in metres (``limit_margin_m``), a hinge
        # ``limit_margin``, its share of it for a hinge that leads coupled joints (the same room for the hand).
        for k, margin in enumerate(joint_margins(robot, model, config)):
            joint = int(model.joint(ROBOT_PREFIX + robot.joint_names[k]).id)
            if model.jnt_limited[joint]:
                qadr = self.indices.qpos[k]
                position_limit.lower[qadr] = model.jnt_range[joint, 0] + margin
                position_limit.upper[qadr] = model.jnt_range[joint, 1] - margin
        self.limits: list[mink.Limit] = [position_limit, mink.VelocityLimit(model, velocities)]
        groups = self._collision_pairs(
            np.atleast_2d(np.asarray(region_world, dtype=np.float64)), np.asarray(allowed_geoms, dtype=np.int64)
        )
        distances = (config.collision_distance, config.arm_collision_distance, config.gripper_collision_distance,
                     config.wrist_collision_distance)
        # The last group's pairs are the robot's own links (``_collision_pairs``): those kept off each other open up
        # again when the IK's steps have let them creep inside their distance, or inside where they started a solve
        # or a path (``BoxedCollisionLimit.recover``).
        collision = [
            BoxedCollisionLimit(model, pairs, recover=k == len(groups) - 1, gain=config.collision_gain,
                                minimum_distance_from_collisions=distance, collision_detection_distance=config.collision_detection)
            for k, (pairs, distance) in enumerate(zip(groups, distances)) if pairs
        ]
        self.limits += shared_boxes(model, collision) if collision else []
        self._own_links = [limit for limit in collision if limit.recover]
        """The limits that keep the robot's own links apart (``BoxedCollisionLimit.recover``)."""

    def _coupled_dofs(self, planning: set[int]) -> list[tuple[int, int, float]]:
        """(follower dof, leader dof, ratio) of the coupled joints whose leader the IK moves."""
        model = self.model
        qpos_to_dof = {int(model.jnt_qposadr[j]): int(model.jnt_dofadr[j]) for j in range(model.njnt)}
        out = []
        for follower, leader, ratio in zip(self.indices.follower_qpos, self.indices.leader_qpos, self.indices.follower_ratio):
            if qpos_to_dof[int(leader)] in planning:
                out.append((qpos_to_dof[int(follower)], qpos_to_dof[int(leader)], float(ratio)))
        return out

    def _collision_pairs(
        self, region: FloatArray, allowed: IntArray
    ) -> tuple[list[tuple[list[int], list[int]]], ...]:
        """Pairs of (base and torso vs scene), (arm vs scene, forearm vs body), (gripper vs scene but the handle),
        (hand and last arm link vs the arm before the wrist, upper arm vs body; mink leaves out parent and child
        links)."""
        model, robot = self.model, self.robot
        collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        robot_geoms = bodies_geoms(model, self.indices.bodies)
        robot_geoms = robot_geoms[collides[robot_geoms]]
        gripper = np.intersect1d(robot_geoms, bodies_geoms(model, hand_bodies(robot, model, self.indices.grasp_site)))
        # A legged body's height and pitch (``base_lift``, ``base_pitch``) move the root body itself: the arm's links
        # are those of its joints on bodies of their own.
        joints = [name for name in robot.arm_joints if self._joint_body(name) != int(self.indices.bodies[0])]
        arm_root = self._joint_body(joints[0])
        arm = np.intersect1d(robot_geoms, bodies_geoms(model, subtree_bodies(model, arm_root)))
        body = np.setdiff1d(robot_geoms, arm)
        forearm_root = self._joint_body(joints[min(3, len(joints) - 1)])
        forearm = np.intersect1d(robot_geoms, bodies_geoms(model, subtree_bodies(model, forearm_root)))

        scene = np.flatnonzero(collides & ~np.isin(model.geom_bodyid, self.indices.bodies))
        scene = np.setdiff1d(scene, floor_geoms(model, scene))
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        reach = self.config.scene_radius
        distance = np.linalg.norm(data.geom_xpos[scene][:, None, :] - region[None, :, :], axis=2).min(axis=1)
        scene = scene[distance - model.geom_rbound[scene] < reach]
        arm = np.setdiff1d(arm, gripper)
        body_pairs = [(body.tolist(), scene.tolist())]
        arm_pairs = [(arm.tolist(), scene.tolist()), (np.setdiff1d(forearm, gripper).tolist(), body.tolist())]
        gripper_pairs = [(gripper.tolist(), np.setdiff1d(scene, allowed).tolist()), (gripper.tolist(), body.tolist())]
        hand = np.intersect1d(robot_geoms, bodies_geoms(model, subtree_bodies(model, self._joint_body(joints[-1]))))
        wrist = bodies_geoms(model, subtree_bodies(model, self._joint_body(joints[max(len(joints) - 2, 0)])))
        upper = bodies_geoms(model, subtree_bodies(model, self._joint_body(joints[min(1, len(joints) - 1)])))
        upper_arm = np.setdiff1d(np.intersect1d(robot_geoms, upper), np.union1d(forearm, gripper))
        wrist_pairs = [(hand.tolist(), np.setdiff1d(arm, wrist).tolist()), (upper_arm.tolist(), body.tolist())]
        return tuple([(a, b) for a, b in pairs if a and b] for pairs in (body_pairs, arm_pairs, gripper_pairs, wrist_pairs))

    def _joint_body(self, joint: str) -> int:
        return int(self.model.jnt_bodyid[self.model.joint(ROBOT_PREFIX + joint).id])

    def full_q(self, q: npt.ArrayLike, part_state: float, fingers: float) -> FloatArray:
        """(model.nq,) model configuration for planning joints ``q``, the part at ``part_state`` and the finger
        joints at ``fingers`` (m or rad), other joints at their reference or held values."""
        qpos = self.model.qpos0.copy()
        qpos[self.indices.qpos] = q
        qpos[self.indices.held_qpos] = self.indices.held_values
        qpos[self.indices.gripper_qpos] = fingers
        qpos[self.part_qpos] = part_state
        apply_couplings(self.indices, qpos)
        return qpos

    def grasp_pose(self, q: npt.ArrayLike, part_state: float, fingers: float) -> FloatArray:
        """(4, 4) T_world_grasp of the grasp site at planning-joint positions ``q``."""
        self.configuration.update(self.full_q(q, part_state, fingers))
        data = self.configuration.data
        T = np.eye(4)
        T[:3, :3] = data.site_xmat[self.indices.grasp_site].reshape(3, 3)
        T[:3, 3] = data.site_xpos[self.indices.grasp_site]
        return T

    def solve(
        self,
        T_world_grasp: npt.ArrayLike,
        q_seed: npt.ArrayLike,
        q_posture: npt.ArrayLike,
        part_state: float,
        fingers: float,
        max_iterations: int | None = None,
        unload: bool = False,
        rolling: bool = False,
    ) -> tuple[FloatArray, float, float]:
        """Move the grasp site onto one target from a seed configuration. With ``unload``, where that leaves an
        arm joint holding more than ``gravity_free_share`` of its effort against gravity, then move the arm
        through its null space to unload it (kept only if the target is still reached within the tolerances):
        ``whole_body`` asks for it when the plain solutions overload a joint. With ``rolling`` a
        differential-drive base may roll along its heading (see ``freeze_base``).

        Returns:
            (nq,) planning-joint positions, position error (m), orientation error (rad). Not raising: the
            caller decides what residual is acceptable.
        """
        cfg = self.config
        self.configuration.update(self.full_q(q_seed, part_state, fingers))
        if not self._holding_path:
            self._hold_own_links()
        self.posture_task.set_target(self.full_q(q_posture, part_state, fingers))
        self.frame_task.set_target(mink.SE3.from_matrix(np.asarray(T_world_grasp, dtype=np.float64)))
        iterations = cfg.max_iterations if max_iterations is None else max_iterations
        self._active = self.rolling_constraints if rolling else self.constraints
        position_error, orientation_error = self._iterate([self.frame_task, self.posture_task], iterations)
        if not self._reached(position_error, orientation_error) and cfg.release_iterations > 0:
            # Stalled short of the target: the posture task's pull towards its reference (the planned base
            # stop, home) balances the frame task's millimetres. Released (its reference moved to where the
            # robot is), only the limits hold the hand back.
            self.posture_task.set_target(self.configuration.q.copy())
            position_error, orientation_error = self._iterate([self.frame_task, self.posture_task], cfg.release_iterations)
        q = self.configuration.q[self.indices.qpos].copy()
        gravity = self.tasks[2:]
        if not unload or not gravity or not self._reached(position_error, orientation_error):
            return q, position_error, orientation_error
        excess = float(np.abs(gravity[0].compute_error(self.configuration)).max())
        if excess == 0.0:
            return q, position_error, orientation_error
        self._iterate(self.tasks, cfg.gravity_iterations, gravity[0])
        # The null-space moves are first-order: the hand drifts by millimetres, taken back from the unloaded arm.
        self.posture_task.set_target(self.configuration.q.copy())
        e_p, e_r = self._iterate([self.frame_task, self.posture_task], cfg.gravity_iterations)
        if self._reached(e_p, e_r) and float(np.abs(gravity[0].compute_error(self.configuration)).max()) < excess:
            return self.configuration.q[self.indices.qpos].copy(), e_p, e_r
        return q, position_error, orientation_error

    def _hold_own_links(self) -> None:
        """Hold the robot's own pairs (``BoxedCollisionLimit.recover``) at their distance, or where they lie closer
        now (``BoxedCollisionLimit.hold_from``)."""
        for limit in self._own_links:
            limit.hold_from(self.configuration.data)

    def _step(self, tasks: list[mink.Task]) -> FloatArray:
        """One QP step's joint velocities. Where the robot's own links, inside their distance, cannot open up again
        within the other limits (``BoxedCollisionLimit.recover``), the step only keeps them from closing further."""
        cfg = self.config
        solve = partial(mink.solve_ik, self.configuration, tasks, cfg.step_time, cfg.solver, damping=cfg.damping,
                        limits=self.limits, constraints=self._active)
        try:
            return solve()
        except mink.NoSolutionFound:
            if not self._own_links:
                raise
        for limit in self._own_links:
            limit.recover = False
        try:
            return solve()
        finally:
            for limit in self._own_links:
                limit.recover = True

    def _reached(self, position_error: float, orientation_error: float) -> bool:
        return position_error < self.config.position_tolerance and orientation_error < self.config.orientation_tolerance

    def _iterate(self, tasks: list[mink.Task], iterations: int, unload: mink.Task | None = None) -> tuple[float, float]:
        """Differential-IK steps on ``self.configuration`` until the frame target is reached (and, with
        ``unload``, that task's error is zero) or progress stalls; returns the final frame errors."""
        cfg = self.config
        configuration = self.configuration
        history: list[float] = []
        for _ in range(iterations):
            check_time_limit("whole-body IK")
            error = self.frame_task.compute_error(configuration)
            position_error, orientation_error = float(np.linalg.norm(error[:3])), float(np.linalg.norm(error[3:]))
            remaining = 0.0 if unload is None else float(np.abs(unload.compute_error(configuration)).max())
            if self._reached(position_error, orientation_error) and remaining == 0.0:
                break
            history.append(position_error + 0.1 * orientation_error + remaining)
            if len(history) > cfg.stall_iterations and history[-1] > (1.0 - cfg.stall_fraction) * history[-1 - cfg.stall_iterations]:
                break  # stalled: a limit (collision, joint range) holds the frame off its target
            try:
                velocity = self._step(tasks)
            except mink.NoSolutionFound as exc:
                raise PlanningError(f"whole-body IK: the QP has no solution ({exc}); the robot may start in collision") from None
            configuration.integrate_inplace(velocity, cfg.step_time)
        error = self.frame_task.compute_error(configuration)
        return float(np.linalg.norm(error[:3])), float(np.linalg.norm(error[3:]))

    def track(
        self,
        T_world_grasp: npt.ArrayLike,
        part_states: npt.ArrayLike,
        q_start: npt.ArrayLike,
        q_posture: npt.ArrayLike,
        fingers: float,
        unload: bool = False,
        give_up: tuple[float, float] | None = None,
    ) -> IKResult:
        """Follow a path of targets, each solved from the previous solution.

        The arm's posture reference is the previous solution (the arm moves as little as it can, instead of
        swinging through its null space back towards home); the base's is the planned base pose.

        Args:
            T_world_grasp: (N, 4, 4) targets.
            part_states: (N,) part state at each target (the part moves with the handle).
            q_start: (nq,) seed of the first target.
            q_posture: (N, nq) posture reference per target (its base joints are used).
            fingers: finger joint position held throughout, m or rad.
            unload: unload the arm against gravity at each target (see :meth:`solve`).
            give_up: (m, rad) residuals beyond which a target counts as missed: the path stops there (the
                result then has fewer rows than targets; a path with a missed target is no plan, and each
                further target, solved from a miss, costs the full iteration limit).
        """
        T_world_grasp = np.asarray(T_world_grasp, dtype=np.float64)
        states = np.asarray(part_states, dtype=np.float64)
        q_posture = np.asarray(q_posture, dtype=np.float64)
        q = np.asarray(q_start, dtype=np.float64)
        out, pos_err, rot_err = [], [], []
        # The robot's own links are held where they start the path all along it: solve by solve, a pair creeping
        # 0.1 mm per step would be held afresh wherever the last solve left it.
        self.configuration.update(self.full_q(q, float(states[0]) if len(states) else 0.0, fingers))
        self._hold_own_links()
        self._holding_path = True
        try:
            for T, state, posture in zip(T_world_grasp, states, q_posture):
                check_time_limit("whole-body IK along the handle path")
                reference = np.concatenate([posture[: self.n_base], q[self.n_base :]])
                q, e_p, e_r = self.solve(T, q, reference, float(state), fingers, unload=unload, rolling=True)
                out.append(q)
                pos_err.append(e_p)
                rot_err.append(e_r)
                if give_up is not None and (e_p > give_up[0] or e_r > give_up[1]):
                    break
        finally:
            self._holding_path = False
        return IKResult(np.array(out), np.array(pos_err), np.array(rot_err))


__all__ = ["IKConfig", "IKResult", "WholeBodyIK", "joint_margins"]
