"""Check a plan by executing it in MuJoCo: the robot's servos (realistic gains and force limits), an
admittance law on the measured handle wrench, and a grasp attachment that engages only when the closed
gripper is at the handle.

The grasp is an equality attachment, not friction: two ``connect`` constraints on the handle's free axis
(along a bar, or through the two pad contacts on a knob), i.e. a hinge about that axis, the way a bar can
roll between parallel pads. It engages when the gripper has closed and the grasp point is within
``engage_distance`` of the handle's geoms, and lets go once the opening fingers are clear of the handle; while it holds, the gripper
does not collide with the part (the attachment is the grasp).

Pass criteria (``CRITERIA``): the articulated joint ends within 5 deg / 2 cm of the target (states from the
canonical state; a reversed axis flips the sign); no contact between robot and scene other than the gripper
with the handle or the part near it (the floor does not collide: the robot stands on its planar base
joints); peak handle force below a bound (optional); no joint position, velocity or effort limit violated
(effort: a servo asking more than its limit for ``effort_time``); the grasp engaged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from funrec.errors import PlanningError
from funrec.geometry.joints import joint_transform
from funrec.typed import FloatArray
from funrec_robot.controller import Admittance, AdmittanceConfig, ServoModel
from funrec_robot.plan_file import Plan, release_offset
from funrec_robot.robot import RobotDescription
from funrec_robot.scene import bodies_geoms, floor_geoms, geom_boxes, part_geoms, part_joint, subtree_bodies
from funrec_robot.sim_model import apply_couplings, build_mujoco_spec, gripper_position, hand_bodies, robot_indices
from funrec_robot.video import FrameRecorder, check_camera, write_video

log = logging.getLogger(__name__)

CRITERIA = ("target", "collision", "handle_force", "joint_position", "joint_velocity", "joint_effort", "grasp")
"""Names of the pass criteria, as reported."""
CONNECT_HALF_SPAN_M = 0.02
"""The two connect points of the grasp attachment sit this far either side of the grasp point, m."""


@dataclass(frozen=True)
class CheckConfig:
    """Settings of plan checking."""

    revolute_tolerance: float = float(np.deg2rad(5.0))
    """Largest final error of a revolute joint, rad."""
    prismatic_tolerance: float = 0.02
    """Largest final error of a prismatic joint, m."""
    max_handle_force: float | None = 50.0
    """Largest handle force, N; None to not check it."""
    engage_distance: float = 0.02
    """The grasp engages only with the grasp point this close to the handle's geoms, m."""
    handle_radius: float = 0.03
    """Geoms of the part within this distance of the grasp point are the handle, m."""
    contact_radius: float = 0.06
    """Gripper contacts with the handle's geoms, or with the rest of the part within this distance of the
    grasp point, are allowed, m."""
    position_tolerance: float = 0.005
    """Excess over a joint's position limits still accepted, m or rad."""
    velocity_tolerance: float = 0.1
    """Excess over a joint's speed limit still accepted, as a fraction (servo tracking transients)."""
    effort_time: float = 0.1
    """A joint whose servo asks more than its effort limit for longer than this violates it, s."""
    settle_time: float = 1.0
    """Simulated time after the plan's last sample, s."""
    attachment_solref: tuple[float, float] = (0.02, 1.0)
    """MuJoCo solref (time constant s, damping ratio) of the grasp attachment: a stiff but not rigid hold."""
    admittance: AdmittanceConfig = field(default_factory=AdmittanceConfig)
    """Compliance of the controller."""
    compliant: bool = True
    """Use the admittance law (False: pure position tracking, for comparison)."""
    video_fps: float = 10.0
    """Frames per second of the video (software OpenGL renders a few frames a second)."""
    video_size: tuple[int, int] = (480, 360)
    """Video width and height, pixels."""
    record_every: float = 0.02
    """Period of the time series kept in the report, s."""


@dataclass(frozen=True)
class Failure:
    """A violated criterion: when it first happened and what."""

    criterion: str
    """One of ``CRITERIA``."""
    time: float
    """First time it happened, s."""
    detail: str
    """What happened, with numbers and names."""


@dataclass(frozen=True)
class CheckReport:
    """Outcome of executing a plan in simulation."""

    passed: bool
    """All criteria met."""
    failures: tuple[Failure, ...]
    """Violated criteria, first occurrence each."""
    joint: str
    """Joint of the checked scene that was operated."""
    start_state: float
    """Its state at the start: the plan's, with the sign flipped if the plan's axis points the other way
    (states count from the canonical, closed, state in both), rad or m."""
    target_state: float
    """The plan's target mapped the same way, rad or m."""
    final_state: float
    """Where it ended, rad or m."""
    target_error: float
    """|final - target|, rad or m."""
    peak_handle_force: float
    """Largest handle force, N."""
    peak_handle_force_time: float
    """When, s."""
    grasp_engaged_time: float | None
    """When the grasp attachment engaged, s (None: never)."""
    collisions: tuple[tuple[float, str, str], ...]
    """First forbidden contacts: (time s, robot geom, scene geom), at most 20."""
    max_velocity_ratio: float
    """Largest |qd| / v_max over the planning joints."""
    simulated_time: float
    """Simulated duration, s."""
    series: dict[str, list[float]]
    """Time series every ``record_every``: t, part_state, handle_force, grasp_error (distance of the grasp
    point from the material handle point, m)."""
    video: str | None = None
    """Path of the video, if one was written."""
    scene_file: str = ""
    """The scene (MJCF) the plan was checked in."""
    robot_file: str = ""
    """The robot YAML file it was checked with."""

    def to_json(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "failures": [{"criterion": f.criterion, "time": round(f.time, 4), "detail": f.detail} for f in self.failures],
            "failed_criteria": sorted({f.criterion for f in self.failures}),
            "joint": self.joint,
            "start_state": self.start_state,
            "target_state": self.target_state,
            "final_state": self.final_state,
            "target_error": self.target_error,
            "peak_handle_force_N": self.peak_handle_force,
            "peak_handle_force_time": self.peak_handle_force_time,
            "grasp_engaged_time": self.grasp_engaged_time,
            "collisions": [list(c) for c in self.collisions],
            "max_velocity_ratio": self.max_velocity_ratio,
            "simulated_time": self.simulated_time,
            "video": self.video,
            "series": self.series,
        }


def _transform_point(T: FloatArray, p: FloatArray) -> FloatArray:
    return T[:3, :3] @ p + T[:3, 3]


def _body_T(data: mujoco.MjData, body: int) -> FloatArray:
    T = np.eye(4)
    T[:3, :3] = data.xmat[body].reshape(3, 3)
    T[:3, 3] = data.xpos[body]
    return T


def _point_box_distance(model: mujoco.MjModel, data: mujoco.MjData, geoms: npt.ArrayLike, p: FloatArray) -> float:
    """Distance (m) from ``p`` to the nearest of the geoms' boxes; inf without geoms."""
    if len(geoms) == 0:  # a twin's grasp point far from every piece of the true part: nothing to hold
        return float("inf")
    centre, R, half = geom_boxes(model, data, geoms)
    local = np.einsum("kji,kj->ki", R, p - centre)
    return float(np.min(np.linalg.norm(np.maximum(np.abs(local) - half, 0.0), axis=1)))


def check_plan(
    plan: Plan,
    robot: RobotDescription,
    scene_xml: str | Path,
    joint: str | None = None,
    T_scene_plan: npt.ArrayLike | None = None,
    config: CheckConfig = CheckConfig(),
    video: str | Path | None = None,
) -> CheckReport:
    """Execute a plan in a MuJoCo scene and judge it.

    Args:
        plan: the plan (from ``plan_interaction`` or ``read_plan``).
        robot: the robot it was made for.
        scene_xml: the scene to check in (e.g. the true scene of a synthetic capture).
        joint: the scene joint the plan operates (default: the plan's part name).
        T_scene_plan: (4, 4) maps the plan's world frame into the scene's (default identity); the robot's base
            frame is placed there, so the plan's joint trajectories apply unchanged.
        config: settings.
        video: write an MP4 (or GIF, by suffix) of the execution here.

    Raises:
        PlanningError: the plan does not fit the robot or the scene (joint names, missing joint).
    """
    if tuple(plan.joint_names) != tuple(robot.joint_names):
        raise PlanningError(f"plan joints {list(plan.joint_names)} differ from robot '{robot.name}' joints {list(robot.joint_names)}")
    T_sp = np.eye(4) if T_scene_plan is None else np.asarray(T_scene_plan, dtype=np.float64)
    spec = build_mujoco_spec(robot, scene_xml, T_sp)
    spec.visual.global_.offwidth = max(config.video_size[0], spec.visual.global_.offwidth)
    spec.visual.global_.offheight = max(config.video_size[1], spec.visual.global_.offheight)
    joint_name = plan.part if joint is None else joint
    probe = spec.compile()
    jid = part_joint(probe, joint_name)
    part_body = probe.body(int(probe.jnt_bodyid[jid])).name
    indices = robot_indices(robot, probe)
    hand_body = probe.body(int(probe.site_bodyid[indices.grasp_site])).name
    for _ in range(2):
        eq = spec.add_equality()
        eq.type = mujoco.mjtEq.mjEQ_CONNECT
        eq.objtype = mujoco.mjtObj.mjOBJ_BODY
        eq.name1, eq.name2 = hand_body, part_body
        eq.active = False
        eq.solref = list(config.attachment_solref)
    model = spec.compile()
    report = _Execution(plan, robot, model, joint_name, T_sp, config).run(video)
    return replace(report, scene_file=str(Path(scene_xml).resolve()), robot_file=str(robot.yaml_path))


class _Execution:
    """One simulated execution of a plan (state of the run; see ``check_plan``)."""

    def __init__(self, plan: Plan, robot: RobotDescription, model: mujoco.MjModel, joint: str, T_sp: FloatArray, config: CheckConfig) -> None:
        self.plan, self.robot, self.model, self.config = plan, robot, model, config
        self.T_sp = T_sp
        self.data = mujoco.MjData(model)
        self.indices = robot_indices(robot, model)
        self.joint = part_joint(model, joint)
        self.joint_name = joint
        self.part_body = int(model.jnt_bodyid[self.joint])
        self.qadr = int(model.jnt_qposadr[self.joint])
        self.dadr = int(model.jnt_dofadr[self.joint])
        self.hand_body = int(model.site_bodyid[self.indices.grasp_site])
        self.equalities = np.arange(model.neq - 2, model.neq)
        self.servos = ServoModel.of(model, self.indices.actuators)
        self.admittance = Admittance(model, self.indices.grasp_site, self.indices.dof, len(robot.base_joints), config.admittance, self.servos)
        robot_geoms = bodies_geoms(model, self.indices.bodies)
        self.robot_geoms = set(robot_geoms.tolist())
        self._gripper_array = bodies_geoms(model, hand_bodies(robot, model, self.indices.grasp_site))
        self.gripper_geoms = set(self._gripper_array.tolist())
        self.part_geoms = part_geoms(model, self.joint)
        scene = np.setdiff1d(np.arange(model.ngeom), robot_geoms)
        self.floor = set(floor_geoms(model, scene).tolist())
        # The robot stands on its planar base joints, not on the floor: a chassis mesh resting on the floor
        # (Fetch's) would add friction its wheels do not have. Nothing else of a scene touches the floor.
        for g in self.floor:
            model.geom_contype[g] = model.geom_conaffinity[g] = 0
        self.depth = float(plan.provenance.get("grasp", {}).get("depth_m", 0.0))
        self.free_axis = plan.grasp_free_axis
        # The grasp point on the handle, in the plan's model: at the start state, and at state 0 of the
        # plan's model; then as a point fixed to the checked part at its reference configuration.
        T_start = T_sp @ plan.T_world_grasp_start
        self.p_start = T_start[:3, 3] + self.depth * T_start[:3, 2]
        T_back = joint_transform(plan.joint_type, plan.axis_world, plan.pivot_world, -plan.start_state)
        p0 = _transform_point(T_sp @ T_back @ np.linalg.inv(T_sp), self.p_start)
        ref = mujoco.MjData(model)
        mujoco.mj_kinematics(model, ref)
        self.p_body = _transform_point(np.linalg.inv(_body_T(ref, self.part_body)), p0)
        # States count from the canonical (closed) state in both models; a reversed axis flips their sign
        # (the convention of the FORMATS.md section 5 state error).
        axis_plan = T_sp[:3, :3] @ plan.axis_world
        self.sign = 1.0 if float(ref.xaxis[self.joint] @ axis_plan) >= 0.0 else -1.0
        self.start_state = self.sign * plan.start_state
        self.target_state = self.sign * plan.target_state
        self.handle = self._handle_geoms()
        self._handle_set = set(self.handle.tolist())
        touched = np.concatenate([self._gripper_array, self.part_geoms])
        self._saved_bits = {int(g): (int(model.geom_contype[g]), int(model.geom_conaffinity[g])) for g in touched}

    def _handle_geoms(self) -> FloatArray:
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.model.qpos0
        data.qpos[self.qadr] = self.start_state
        mujoco.mj_kinematics(self.model, data)
        centre, R, half = geom_boxes(self.model, data, self.part_geoms)
        local = np.einsum("kji,kj->ki", R, self.p_start - centre)
        distance = np.linalg.norm(np.maximum(np.abs(local) - half, 0.0), axis=1)
        self._handle_miss_m = float(distance.min()) if len(distance) else float("inf")
        return self.part_geoms[distance <= self.config.handle_radius]

    def _reset(self) -> None:
        model, data, plan = self.model, self.data, self.plan
        mujoco.mj_resetData(model, data)
        data.qpos[self.indices.qpos] = plan.q[0]
        data.qpos[self.indices.held_qpos] = self.indices.held_values
        data.ctrl[self.indices.held_actuators] = self.indices.held_values
        if self.robot.gripper.actuator is None:
            data.qpos[self.indices.gripper_qpos] = plan.gripper_command[0]
        data.qpos[self.qadr] = self.start_state
        apply_couplings(self.indices, data.qpos)
        data.ctrl[self.indices.actuators] = plan.q[0]
        data.ctrl[self.indices.gripper_actuators] = plan.gripper_command[0]
        data.eq_active[self.equalities] = 0
        mujoco.mj_forward(model, data)
        self.p_world_base = data.xpos[self.indices.bodies[0]].copy()

    def _path_tangent(self, state: float) -> FloatArray:
        """(3,) unit direction of the planned handle path at a plan state, scene frame: along the axis for a
        prismatic part, axis x (point - pivot) for a revolute one."""
        plan = self.plan
        axis = self.T_sp[:3, :3] @ plan.axis_world
        if plan.joint_type == "prismatic":
            return axis
        pivot = _transform_point(self.T_sp, plan.pivot_world)
        T_move = joint_transform(plan.joint_type, axis, pivot, state - plan.start_state)
        tangent = np.cross(axis, _transform_point(T_move, self.p_start) - pivot)
        return tangent / max(np.linalg.norm(tangent), 1e-9)

    def _grasp_point(self) -> FloatArray:
        site = self.indices.grasp_site
        return self.data.site_xpos[site] + self.depth * self.data.site_xmat[site].reshape(3, 3)[:, 2]

    def _set_grasp_contacts(self, attached: bool) -> None:
        """While attached the attachment is the grasp: the gripper stops colliding with the part (but not with
        anything else) by moving both onto contact bits no other geom uses (type 4 / 2, affinity 1 / 3)."""
        model = self.model
        for g, (contype, conaffinity) in self._saved_bits.items():
            model.geom_contype[g], model.geom_conaffinity[g] = contype, conaffinity
        if attached:
            for g in self._gripper_array:
                if model.geom_contype[g] or model.geom_conaffinity[g]:
                    model.geom_contype[g], model.geom_conaffinity[g] = 4, 1
            for g in self.part_geoms:
                if model.geom_contype[g] or model.geom_conaffinity[g]:
                    model.geom_contype[g], model.geom_conaffinity[g] = 2, 3

    def _handle_overlap(self) -> float:
        """Deepest penetration of a collidable gripper geom into a handle geom, m (0 when they do not overlap)."""
        model, data = self.model, self.data
        fromto = np.zeros(6)
        depth = 0.0
        for g in self._gripper_array:
            if not self._saved_bits[int(g)][0] and not self._saved_bits[int(g)][1]:
                continue
            for h in self.handle:
                depth = max(depth, -mujoco.mj_geomDistance(model, data, int(g), int(h), 0.01, fromto))
        return depth

    def _gripper_clear_of_part(self) -> bool:
        """Whether no collidable gripper geom overlaps a handle geom (signed distance >= 0)."""
        return self._handle_overlap() == 0.0

    def _gripper_stop(self) -> float:
        """Where the gripper would stand had its fingers stopped on the handle, in command units: while attached
        they pass through it (their contacts with the part are off), so the measured gripper position is moved
        outwards by their deepest penetration into a handle geom (along the contact normal, which for a pad
        pressing on a handle is the fingers' closing direction)."""
        outwards = 1.0 if self.robot.gripper.open >= self.robot.gripper.closed else -1.0
        return gripper_position(self.indices, self.data) + outwards * self._handle_overlap()

    def _fell_to_stop(self, final: float) -> bool:
        """Whether a part the plan let go to fall open came to rest at the scene joint's stop beyond the plan's
        target: the target of such a plan is where the part rests, which a twin knows only as far as the
        person opened it."""
        capped = self.plan.provenance.get("target_capped_by_reach") or {}
        if not capped.get("released_to_fall") or not self.model.jnt_limited[self.joint]:
            return False
        low, high = self.model.jnt_range[self.joint]
        tolerance = self.config.revolute_tolerance if self.model.jnt_type[self.joint] == mujoco.mjtJoint.mjJNT_HINGE else self.config.prismatic_tolerance
        opening = self.target_state - self.start_state
        stop = high if opening > 0.0 else low
        beyond = (final - self.target_state) * np.sign(opening) > 0.0
        return bool(beyond and abs(final - stop) <= tolerance)

    def _engage(self) -> None:
        data, model = self.data, self.model
        R_site = data.site_xmat[self.indices.grasp_site].reshape(3, 3)
        p = self._grasp_point()
        T_hand = np.linalg.inv(_body_T(data, self.hand_body))
        T_part = np.linalg.inv(_body_T(data, self.part_body))
        for k, sign in zip(self.equalities, (-1.0, 1.0)):
            point = p + sign * CONNECT_HALF_SPAN_M * R_site[:, self.free_axis]
            model.eq_data[k, 0:3] = _transform_point(T_hand, point)
            model.eq_data[k, 3:6] = _transform_point(T_part, point)
        data.eq_active[self.equalities] = 1
        self._set_grasp_contacts(True)

    def _handle_wrench(self, attached: bool) -> FloatArray:
        """(6,) force and torque (about the grasp point) that the part exerts on the hand, world frame."""
        data, model = self.data, self.model
        wrench = np.zeros(6)
        p = self._grasp_point()
        if attached:
            for k in self.equalities:
                rows = np.flatnonzero((data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY) & (data.efc_id == k))
                if len(rows) == 3:
                    force = data.efc_force[rows]
                    point = _transform_point(_body_T(data, self.hand_body), model.eq_data[k, 0:3])
                    wrench[:3] += force
                    wrench[3:] += np.cross(point - p, force)
        f6 = np.zeros(6)
        part = set(self.part_geoms.tolist())
        for i in range(data.ncon):
            c = data.contact[i]
            g1, g2 = int(c.geom1), int(c.geom2)
            if g1 in self.gripper_geoms and g2 in part:
                sign = -1.0  # force on geom2 (the part) is +; on the hand it is -
            elif g2 in self.gripper_geoms and g1 in part:
                sign = 1.0
            else:
                continue
            mujoco.mj_contactForce(model, data, i, f6)
            force = sign * (c.frame.reshape(3, 3).T @ f6[:3])
            wrench[:3] += force
            wrench[3:] += np.cross(c.pos - p, force)
        return wrench

    def _forbidden_contacts(self, p_handle: FloatArray) -> list[tuple[str, str]]:
        data, model = self.data, self.model
        part = set(self.part_geoms.tolist())
        out = []
        for i in range(data.ncon):
            c = data.contact[i]
            g1, g2 = int(c.geom1), int(c.geom2)
            in1, in2 = g1 in self.robot_geoms, g2 in self.robot_geoms
            if in1 == in2:
                continue
            r, s = (g1, g2) if in1 else (g2, g1)
            if s in self.floor:
                continue
            if r in self.gripper_geoms and (s in self._handle_set or (s in part and np.linalg.norm(c.pos - p_handle) < self.config.contact_radius)):
                continue
            out.append((model.geom(r).name, model.geom(s).name))
        return out

    def run(self, video: str | Path | None) -> CheckReport:
        """Simulate the plan step by step (references, grasp attachment, control, judging) and report."""
        self._reset()
        dt = self.model.opt.timestep
        self._grasp_segment = self.plan.segment("grasp")
        self._actuate_end = self.plan.segment("actuate").t_end
        self._release = next((s for s in self.plan.segments if s.label == "release"), None)
        run = _Run(t_end=self.plan.duration + self.config.settle_time, over_effort=np.zeros(self.robot.nq),
                   recorder=self._recorder(video))
        for step in range(int(np.ceil(run.t_end / dt)) + 1):
            t = step * dt
            q_ref, qd_ref, command = self._references(t, run)
            self._update_grasp(t, command, run)
            wrench, ctrl = self._actuate(t, q_ref, qd_ref, command, run)
            mujoco.mj_step(self.model, self.data)
            self._judge(t, wrench, ctrl, run)
        if run.recorder is not None:
            run.recorder.close()
        self._set_grasp_contacts(False)
        return self._report(run, video)

    def _recorder(self, video: str | Path | None) -> FrameRecorder | None:
        """A frame recorder looking at the robot, the part and the handle's target, if a video is asked for."""
        if video is None:
            return None
        seen = np.concatenate([self.indices.bodies, subtree_bodies(self.model, self.part_body)])
        p_end = _transform_point(self.T_sp, self.plan.p_world_grasp_target)
        camera = check_camera(self.p_world_base, self.p_start, self.model, self.data, seen, [p_end])
        return FrameRecorder(self.model, camera, *self.config.video_size)

    def _references(self, t: float, run: _Run) -> tuple[FloatArray, FloatArray, float]:
        """The plan at time t: joint positions, velocities (zero after its end) and the gripper command, the
        latter moved by where the fingers stopped on the handle once the release starts."""
        plan, nq = self.plan, self.robot.nq
        q_ref = np.array([np.interp(t, plan.t, plan.q[:, j]) for j in range(nq)])
        qd_ref = np.array([np.interp(t, plan.t, plan.qd[:, j]) for j in range(nq)]) if t <= plan.duration else np.zeros(nq)
        command = float(np.interp(t, plan.t, plan.gripper_command))
        if t >= plan.release_start:
            if run.grip_offset is None:
                run.grip_offset = release_offset(plan, self._gripper_stop())
            command += run.grip_offset
        return q_ref, qd_ref, command

    def _update_grasp(self, t: float, command: float, run: _Run) -> None:
        """Engage the attachment when the closed gripper is at the handle; let go when the opening fingers are
        clear of it (or the release ends); give the gripper its contacts with the part back once clear."""
        plan, data, release = self.plan, self.data, self._release
        closed = plan.grasp_command
        if not run.attached and run.engaged_at is None and self._grasp_segment.t_start <= t <= self._actuate_end and abs(command - closed) < 1e-6:
            p = self._grasp_point()
            if _point_box_distance(self.model, data, self.handle, p) <= self.config.engage_distance:
                self._engage()
                run.attached, run.engaged_at = True, t
        if run.attached and release is not None and t >= plan.release_start and abs(command - closed - run.grip_offset) > 1e-6:
            # The pads let go when they stop touching the handle: the attachment holds until the opening
            # fingers are clear of it (the part then rests on them, if gravity pulls it that way).
            clear = self._gripper_clear_of_part()
            if clear or t >= release.t_end:
                data.eq_active[self.equalities] = 0
                run.attached = False
                run.separating = not clear
                if clear:
                    self._set_grasp_contacts(False)
        if run.separating and self._gripper_clear_of_part():
            # Contacts come back only once the opening fingers no longer overlap the handle, else the
            # penetration they resolve would shove the part.
            self._set_grasp_contacts(False)
            run.separating = False

    def _actuate(self, t: float, q_ref: FloatArray, qd_ref: FloatArray, command: float, run: _Run) -> tuple[FloatArray, FloatArray]:
        """Set the servo and gripper commands for this step (admittance on the handle wrench); returns the
        wrench and the servo commands."""
        data, cfg = self.data, self.config
        wrench = self._handle_wrench(run.attached)
        state = float(np.interp(t, self.plan.t, self.plan.part_state))
        # Anti-windup: while a servo is saturated, yielding further would only load it more.
        integrate = run.attached and cfg.compliant and not np.any(run.over_effort > 0.0)
        q_offset = self.admittance.update(data, q_ref, wrench, self.model.opt.timestep, integrate, self._path_tangent(state))
        ctrl = self.servos.command(q_ref + q_offset, qd_ref)
        data.ctrl[self.indices.actuators] = ctrl
        data.ctrl[self.indices.gripper_actuators] = command
        if self.robot.gripper.actuator is None:
            data.ctrl[self.indices.gripper_actuators] = command
        return wrench, ctrl

    def _judge(self, t: float, wrench: FloatArray, ctrl: FloatArray, run: _Run) -> None:
        """After a step: peak force, joint velocity, position and effort limits, forbidden contacts; the time
        series and the video frame."""
        data, cfg, robot = self.data, self.config, self.robot
        force = float(np.linalg.norm(wrench[:3]))
        if force > run.peak[0]:
            run.peak = (force, t)
        q = data.qpos[self.indices.qpos]
        qd = data.qvel[self.indices.dof]
        ratio = np.abs(qd) / robot.v_max
        run.max_v_ratio = max(run.max_v_ratio, float(ratio.max()))
        if np.any(ratio > 1.0 + cfg.velocity_tolerance):
            j = int(np.argmax(ratio))
            run.fail("joint_velocity", t, f"{robot.joint_names[j]} at {qd[j]:.3f} (limit {robot.v_max[j]:.3f})")
        low = q < robot.q_min - cfg.position_tolerance
        high = q > robot.q_max + cfg.position_tolerance
        if np.any(low | high):
            j = int(np.flatnonzero(low | high)[0])
            run.fail("joint_position", t, f"{robot.joint_names[j]} at {q[j]:.4f} outside [{robot.q_min[j]:.4f}, {robot.q_max[j]:.4f}]")
        demanded = self.servos.demanded_force(ctrl, q, qd) + data.qfrc_gravcomp[self.indices.dof]
        over = np.abs(demanded) > robot.effort_max
        run.over_effort = np.where(over, run.over_effort + self.model.opt.timestep, 0.0)
        if np.any(run.over_effort > cfg.effort_time):
            j = int(np.argmax(run.over_effort))
            run.fail("joint_effort", t, f"{robot.joint_names[j]} asked {demanded[j]:.1f} beyond {robot.effort_max[j]:.1f} for {cfg.effort_time} s")
        T_part = _body_T(data, self.part_body)
        p_handle = _transform_point(T_part, self.p_body)
        bad = self._forbidden_contacts(p_handle)
        if bad:
            if "collision" not in run.failures:
                run.fail("collision", t, f"{bad[0][0]} touches {bad[0][1]}")
            if len(run.collisions) < 20:
                run.collisions.extend((round(t, 4), r, s) for r, s in bad[: 20 - len(run.collisions)])
        if t >= run.next_record:
            run.series["t"].append(round(t, 4))
            run.series["part_state"].append(round(float(data.qpos[self.qadr]), 5))
            run.series["handle_force"].append(round(force, 3))
            run.series["grasp_error"].append(round(float(np.linalg.norm(self._grasp_point() - p_handle)), 5))
            run.next_record += cfg.record_every
        if run.recorder is not None and t >= run.next_frame:
            run.recorder.capture(data)
            run.next_frame += 1.0 / cfg.video_fps

    def _report(self, run: _Run, video: str | Path | None) -> CheckReport:
        """The end-of-run criteria (target reached, peak force, grasp engaged) and the report."""
        model, cfg = self.model, self.config
        final = float(self.data.qpos[self.qadr])
        error = abs(final - self.target_state)
        hinge = model.jnt_type[self.joint] == mujoco.mjtJoint.mjJNT_HINGE
        tolerance = cfg.revolute_tolerance if hinge else cfg.prismatic_tolerance
        unit = "rad" if hinge else "m"
        if error > tolerance and self._fell_to_stop(final):
            log.info("part '%s' was let go to fall and came to rest at its stop %.4f %s, beyond the planned %.4f",
                     self.joint_name, final, unit, self.target_state)
        elif error > tolerance:
            run.fail("target", run.t_end, f"joint '{self.joint_name}' ended at {final:.4f} {unit}, target {self.target_state:.4f} (error {error:.4f} > {tolerance:.4f})")
        if cfg.max_handle_force is not None and run.peak[0] > cfg.max_handle_force:
            run.fail("handle_force", run.peak[1], f"peak handle force {run.peak[0]:.1f} N > {cfg.max_handle_force:.1f} N")
        if run.engaged_at is None and len(self.handle) == 0:
            run.fail("grasp", self.plan.segment("grasp").t_end,
                     f"the plan's grasp point is {self._handle_miss_m:.3f} m from the nearest piece of part "
                     f"'{self.joint_name}' in the checked scene (none within {cfg.handle_radius} m): nothing to hold")
        elif run.engaged_at is None:
            run.fail("grasp", self.plan.segment("grasp").t_end, f"the gripper never closed within {cfg.engage_distance} m of the handle")
        video_path = None
        if run.recorder is not None:
            video_path = str(write_video(video, run.recorder.frames, cfg.video_fps))
        ordered = tuple(sorted(run.failures.values(), key=lambda f: (f.time, CRITERIA.index(f.criterion))))
        return CheckReport(
            passed=not ordered,
            failures=ordered,
            joint=self.joint_name,
            start_state=self.start_state,
            target_state=self.target_state,
            final_state=final,
            target_error=error,
            peak_handle_force=run.peak[0],
            peak_handle_force_time=run.peak[1],
            grasp_engaged_time=run.engaged_at,
            collisions=tuple(run.collisions),
            max_velocity_ratio=run.max_v_ratio,
            simulated_time=run.t_end,
            series=run.series,
            video=video_path,
        )


@dataclass
class _Run:
    """What one simulated run accumulates step by step (mutable: it is the loop's state)."""

    t_end: float
    """Simulated duration, s."""
    over_effort: FloatArray
    """(nq,) how long each servo has been asking more than its effort limit, s."""
    recorder: FrameRecorder | None = None
    failures: dict[str, Failure] = field(default_factory=dict)
    collisions: list[tuple[float, str, str]] = field(default_factory=list)
    engaged_at: float | None = None
    grip_offset: float | None = None
    attached: bool = False
    separating: bool = False
    peak: tuple[float, float] = (0.0, 0.0)
    max_v_ratio: float = 0.0
    series: dict[str, list[float]] = field(default_factory=lambda: {"t": [], "part_state": [], "handle_force": [], "grasp_error": []})
    next_record: float = 0.0
    next_frame: float = 0.0

    def fail(self, criterion: str, t: float, detail: str) -> None:
        """Record a violated criterion (its first occurrence only)."""
        self.failures.setdefault(criterion, Failure(criterion, t, detail))


GRAVITY_TILT_TOLERANCE = float(np.deg2rad(2.0))
"""Largest tilt of a twin's z axis from the scene's accepted when placing a robot planned on the twin."""
FLOOR_HEIGHT_TOLERANCE = 0.03
"""Largest height of a twin's floor above or below the scene's accepted when placing a robot planned on the
twin, m (bench twins whose floor was seen: within 7 mm)."""


def T_scene_plan_from_gt(plan: Plan, gt_dir: str | Path) -> FloatArray:
    """(4, 4) map from a plan's world frame into the ground-truth scene of a synthetic capture.

    A plan made on ground truth is already in the scene's frame (identity). A plan made on a twin is mapped
    through camera 0 (FORMATS.md section 4): ``T_scene_twin = T_scene_world @ T_world_camera0(gt) @
    inv(T_twin_camera0(twin))``.

    Raises:
        PlanningError: the twin's frame is not gravity-aligned with the scene, or its floor is not the scene's
            (the robot cannot stand in it).
    """
    from funrec.formats.camera_poses import read_camera_poses
    from funrec.formats.ground_truth import read_ground_truth
    from funrec.formats.twin_gravity import read_twin_gravity

    gt = read_ground_truth(gt_dir)
    source = str(plan.provenance.get("task_source", ""))
    if not source.startswith("twin:"):
        return np.eye(4)
    twin_dir = Path(source.split(":", 1)[1])
    T_twin_camera = read_camera_poses(twin_dir / "camera_poses.txt").T_world_camera[0]
    T = gt.T_scene_world @ gt.T_world_camera[0] @ np.linalg.inv(T_twin_camera)
    lift = float(T[2, 3])  # the height in the scene of the twin's floor under camera 0 (the scene's floor: z = 0)
    if abs(lift) > FLOOR_HEIGHT_TOLERANCE:
        gravity = read_twin_gravity(twin_dir)
        why = "was the floor seen in the capture?" if gravity is None else f"the twin says its floor was {gravity.floor}"
        raise PlanningError(
            f"{twin_dir}: the twin's floor lies {lift:+.2f} m off the scene's; a robot planned in it would stand "
            f"in the air or in the floor of the true scene ({why})"
        )
    tilt = float(np.arccos(np.clip(T[2, 2], -1.0, 1.0)))
    if tilt > GRAVITY_TILT_TOLERANCE:
        raise PlanningError(
            f"{twin_dir}: the twin's z axis is {np.rad2deg(tilt):.1f} deg off the scene's vertical; a robot "
            "planned in it cannot stand in the true scene (export the twin gravity-aligned)"
        )
    return T


def check_plan_file(
    plan_path: str | Path,
    scene: str | Path | None = None,
    joint: str | None = None,
    gt_dir: str | Path | None = None,
    robot_path: str | Path | None = None,
    config: CheckConfig = CheckConfig(),
    video: str | Path | None = None,
) -> CheckReport:
    """Read plan.json and check it: in ``scene`` (default: the ground truth's scene.xml with ``gt_dir``, else
    the scene the plan was made in), on ``joint`` (default: the plan's part), with the robot of the plan's
    provenance unless ``robot_path`` is given."""
    from funrec_robot.plan_file import read_plan
    from funrec_robot.robot import load_robot
    from funrec_robot.task_sources import locate_scene

    plan = read_plan(plan_path)
    robot_file = robot_path if robot_path is not None else plan.provenance.get("robot_file")
    if robot_file is None:
        raise PlanningError(f"{plan_path}: no robot file in the plan's provenance; pass --robot")
    robot = load_robot(robot_file)
    T_scene_plan = None
    if gt_dir is not None:
        T_scene_plan = T_scene_plan_from_gt(plan, gt_dir)
        scene_xml = Path(scene) if scene is not None else locate_scene(gt_dir).scene_xml
    elif scene is not None:
        scene_xml = Path(scene) if Path(scene).is_file() else locate_scene(scene).scene_xml
    else:
        scene_xml = Path(plan.provenance.get("scene_file", ""))
        if not scene_xml.is_file():
            raise PlanningError(f"{plan_path}: the plan's scene {scene_xml} is missing; pass --scene or --gt")
    return check_plan(plan, robot, scene_xml, joint, T_scene_plan, config, video)


__all__ = [
    "CRITERIA",
    "CheckConfig",
    "CheckReport",
    "Failure",
    "T_scene_plan_from_gt",
    "check_plan",
    "check_plan_file",
]
