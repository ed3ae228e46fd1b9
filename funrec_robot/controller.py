"""The robot's execution controller in simulation: plan tracking through the position servos, with an
admittance law on the grasp frame that yields to the measured handle wrench.

A plan made on a reconstructed twin puts the handle path a few centimetres and degrees off the real one.
Stiff servos would fight the real joint; instead the commanded grasp pose is shifted by an offset x that
obeys ``D dx/dt + K x = F`` (F the wrench the handle exerts on the hand, low-pass filtered), and the offset is
mapped to joint offsets through the grasp-site Jacobian (weighted damped least squares, the base moving less
than the arm). The mapping is closed on the kinematics: each step corrects the joint offsets by the difference
between the wanted offset and the one they realise at the plan's current configuration, so that the offset
stays a Cartesian one while the arm moves (a joint offset integrated once would turn into a different, even
along-the-path, displacement as the plan swings the arm, e.g. near a singularity). The servo target also
carries velocity feed-forward ``(kv / kp) qd_ref`` so the servos' damping does not make them lag the plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from funrec.typed import FloatArray, IntArray

LIMIT_MARGIN = 0.02
"""Servo targets stay this far inside the position limits of hinges, rad."""
LIMIT_MARGIN_M = 0.005
"""... and of slides, m. At 2 cm, as for hinges, TIAGo's torso servo never aimed above 0.33 of its 0.35 m, the hand
stood up to 1 cm below a plan made for the torso's top, and the arm pushed 30 N on the handle it took."""


@dataclass(frozen=True)
class AdmittanceConfig:
    """Admittance law on the grasp frame (world axes)."""

    damping: float = 250.0
    """Translational admittance damping D, N s/m: a 25 N push moves the commanded grasp 0.1 m/s."""
    stiffness: float = 300.0
    """Translational admittance stiffness K, N/m: a persistent 3 cm model error leaves 9 N; offsets relax
    with the time constant D / K (under a second)."""
    rotational_damping: float = 12.0
    """Rotational admittance damping, N m s/rad."""
    rotational_stiffness: float = 10.0
    """Rotational admittance stiffness, N m/rad."""
    filter_time: float = 0.02
    """Time constant of the first-order low-pass on the measured wrench, s."""
    max_offset: float = 0.12
    """Largest translational offset, m."""
    max_rotation: float = 0.35
    """Largest rotational offset, rad."""
    base_weight: float = 4.0
    """Cost of moving a base joint relative to an arm joint in the offset's least-squares mapping."""
    regularisation: float = 0.02
    """Damping of the least-squares mapping (m or rad)."""


@dataclass(frozen=True)
class ServoModel:
    """The position servos of the planning joints, read from a compiled model."""

    actuators: IntArray
    """(n,) actuator ids."""
    kp: FloatArray
    """(n,) position gains."""
    kv: FloatArray
    """(n,) velocity gains."""
    ctrl_low: FloatArray
    """(n,) lower control limits (-inf if unlimited)."""
    ctrl_high: FloatArray
    """(n,) upper control limits."""
    q_low: FloatArray
    """(n,) lower position limits of the joints (-inf if unlimited)."""
    q_high: FloatArray
    """(n,) upper position limits."""
    margin: FloatArray
    """(n,) how far inside those limits the servo targets stay: ``LIMIT_MARGIN`` (rad) for a hinge, ``LIMIT_MARGIN_M``
    (m) for a slide."""

    @staticmethod
    def of(model: mujoco.MjModel, actuators: npt.ArrayLike) -> ServoModel:
        """Gains and limits of the position servos ``actuators`` (each driving one joint)."""
        actuators = np.asarray(actuators, dtype=np.int64)
        joints = model.actuator_trnid[actuators, 0]
        joint_limited = model.jnt_limited[joints].astype(bool)
        q_low = np.where(joint_limited, model.jnt_range[joints, 0], -np.inf)
        q_high = np.where(joint_limited, model.jnt_range[joints, 1], np.inf)
        kp = model.actuator_gainprm[actuators, 0].copy()
        kv = -model.actuator_biasprm[actuators, 2].copy()
        limited = model.actuator_ctrllimited[actuators].astype(bool)
        low = np.where(limited, model.actuator_ctrlrange[actuators, 0], -np.inf)
        high = np.where(limited, model.actuator_ctrlrange[actuators, 1], np.inf)
        margin = np.where(model.jnt_type[joints] == mujoco.mjtJoint.mjJNT_SLIDE, LIMIT_MARGIN_M, LIMIT_MARGIN)
        return ServoModel(actuators, kp, kv, low, high, q_low, q_high, margin)

    def within_limits(self, q: FloatArray) -> FloatArray:
        """(n,) positions clipped to the joints' position limits less ``margin``."""
        return np.clip(q, self.q_low + self.margin, self.q_high - self.margin)

    def command(self, q_ref: FloatArray, qd_ref: FloatArray) -> FloatArray:
        """Servo targets that track (q_ref, qd_ref) without the lag of the velocity gain, never past the
        joints' position limits (less ``margin``) so that a compliant offset cannot drive a joint into
        its stop."""
        return np.clip(self.within_limits(q_ref) + self.kv / self.kp * qd_ref, self.ctrl_low, self.ctrl_high)

    def demanded_force(self, ctrl: FloatArray, q: FloatArray, qd: FloatArray) -> FloatArray:
        """Servo force before the force limit: kp (ctrl - q) - kv qd."""
        return self.kp * (ctrl - q) - self.kv * qd


def _rotation_vector(R: FloatArray) -> FloatArray:
    """(3,) axis times angle (rad) of a (3, 3) rotation matrix."""
    quat_wxyz = np.empty(4)
    mujoco.mju_mat2Quat(quat_wxyz, np.ascontiguousarray(R).ravel())
    w = np.empty(3)
    mujoco.mju_quat2Vel(w, quat_wxyz, 1.0)
    return w


def _rotation_matrix(w: FloatArray) -> FloatArray:
    """(3, 3) rotation of axis times angle ``w`` (3,), rad."""
    angle = float(np.linalg.norm(w))
    quat_wxyz = np.array([1.0, 0.0, 0.0, 0.0])
    if angle > 0.0:
        mujoco.mju_axisAngle2Quat(quat_wxyz, w / angle, angle)
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, quat_wxyz)
    return R.reshape(3, 3)


class Admittance:
    """Offset of the commanded grasp pose that yields to the handle wrench, mapped to joint offsets.

    Args:
        model: the simulation model.
        site: grasp site id.
        dofs: (n,) dof addresses of the planning joints (hinge or slide joints).
        n_base: how many of them are base joints (first).
        config: gains.
        servos: the planning joints' servos, whose position limits bound the joint offsets (default: none).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        site: int,
        dofs: npt.ArrayLike,
        n_base: int,
        config: AdmittanceConfig,
        servos: ServoModel | None = None,
    ) -> None:
        self.model = model
        self.site = site
        self.dofs = np.asarray(dofs, dtype=np.int64)
        self.qpos = model.jnt_qposadr[model.dof_jntid[self.dofs]]
        self.config = config
        self.servos = servos
        weights = np.ones(len(self.dofs))
        weights[:n_base] = config.base_weight
        self.inverse_weights = 1.0 / weights
        self.wrench = np.zeros(6)
        self.offset = np.zeros(6)
        self.q_offset = np.zeros(len(self.dofs))
        self._scratch = mujoco.MjData(model)
        self._jp = np.zeros((3, model.nv))
        self._jr = np.zeros((3, model.nv))

    def update(
        self,
        data: mujoco.MjData,
        q_ref: FloatArray,
        measured_wrench: FloatArray,
        dt: float,
        active: bool,
        path_direction: npt.ArrayLike | None = None,
    ) -> FloatArray:
        """Advance the admittance by one step and return the (n,) joint offset to add to the plan.

        Args:
            data: simulation data after the step (the configuration of everything but the planning joints).
            q_ref: (n,) the plan's configuration of the planning joints now.
            measured_wrench: (6,) force (N) and torque (N m) the handle exerts on the hand, world frame.
            dt: step, s.
            active: whether the offset may change (the gripper holds the handle); when not, the grasp-frame
                offset is frozen, and still realised at the plan's configuration.
            path_direction: (3,) unit direction in which the plan moves the handle, world frame; the force
                along it (the part's inertia and friction as it is dragged) is not yielded to, so that the
                hand neither lags nor overshoots the plan: model errors show up across the path.
        """
        cfg = self.config
        alpha = dt / (cfg.filter_time + dt)
        self.wrench += alpha * (np.asarray(measured_wrench) - self.wrench)
        if active:
            wrench = self.wrench.copy()
            if path_direction is not None:
                u = np.asarray(path_direction, dtype=np.float64)
                wrench[:3] -= u * float(wrench[:3] @ u)
            D = np.array([cfg.damping] * 3 + [cfg.rotational_damping] * 3)
            K = np.array([cfg.stiffness] * 3 + [cfg.rotational_stiffness] * 3)
            new = self.offset + dt * (wrench - K * self.offset) / D
            new[:3] *= min(1.0, cfg.max_offset / max(np.linalg.norm(new[:3]), 1e-12))
            new[3:] *= min(1.0, cfg.max_rotation / max(np.linalg.norm(new[3:]), 1e-12))
            self.offset = new
        if not np.any(self.offset) and not np.any(self.q_offset):
            return self.q_offset
        return self._realise(data, np.asarray(q_ref, dtype=np.float64))

    def _site_pose(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Grasp-site position (3,) and rotation (3, 3), world frame, with the planning joints at ``q``."""
        scratch = self._scratch
        scratch.qpos[self.qpos] = q
        mujoco.mj_kinematics(self.model, scratch)
        return scratch.site_xpos[self.site].copy(), scratch.site_xmat[self.site].reshape(3, 3).copy()

    def _realise(self, data: mujoco.MjData, q_ref: FloatArray) -> FloatArray:
        """One Gauss-Newton step of the joint offset towards realising ``self.offset`` at ``q_ref``: the
        kinematics of the commanded configuration, not an integral of Jacobian steps taken at configurations
        the plan has left, decide where the grasp goes."""
        cfg, model, scratch = self.config, self.model, self._scratch
        scratch.qpos[:] = data.qpos
        p_ref, R_ref = self._site_pose(q_ref)
        q_cmd = q_ref + self.q_offset
        if self.servos is not None:
            q_cmd = self.servos.within_limits(q_cmd)
        p_cmd, R_cmd = self._site_pose(q_cmd)
        error = np.concatenate([
            self.offset[:3] - (p_cmd - p_ref),
            _rotation_vector(_rotation_matrix(self.offset[3:]) @ R_ref @ R_cmd.T),
        ])
        mujoco.mj_comPos(model, scratch)
        mujoco.mj_jacSite(model, scratch, self._jp, self._jr, self.site)
        J = np.vstack([self._jp, self._jr])[:, self.dofs]
        JW = J * self.inverse_weights
        A = JW @ J.T + cfg.regularisation**2 * np.eye(6)
        q_cmd = q_cmd + JW.T @ np.linalg.solve(A, error)
        if self.servos is not None:
            # A joint at its limit takes no more of the offset (no wind-up); the others take it next step.
            q_cmd = self.servos.within_limits(q_cmd)
        self.q_offset = q_cmd - q_ref
        return self.q_offset


__all__ = ["Admittance", "AdmittanceConfig", "ServoModel"]
