"""The robot's execution controller in simulation: plan tracking through the position servos, with an
admittance law on the grasp frame that yields to the measured handle wrench.

A plan made on a reconstructed twin puts the handle path a few centimetres and degrees off the real one.
Stiff servos would fight the real joint; instead the commanded grasp pose is shifted by an offset x that
obeys ``D dx/dt + K x = F`` (F the wrench the handle exerts on the hand, low-pass filtered), and the offset is
mapped to joint offsets through the grasp-site Jacobian (weighted damped least squares, the base moving less
than the arm). The servo target also carries velocity feed-forward ``(kv / kp) qd_ref`` so the servos'
damping does not make them lag the plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from funrec.typed import FloatArray, IntArray

LIMIT_MARGIN = 0.02
"""Servo targets stay this far inside the joints' position limits, rad or m."""


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
        return ServoModel(actuators, kp, kv, low, high, q_low, q_high)

    def command(self, q_ref: FloatArray, qd_ref: FloatArray) -> FloatArray:
        """Servo targets that track (q_ref, qd_ref) without the lag of the velocity gain, never past the
        joints' position limits (less ``LIMIT_MARGIN``) so that a compliant offset cannot drive a joint into
        its stop."""
        q = np.clip(q_ref, self.q_low + LIMIT_MARGIN, self.q_high - LIMIT_MARGIN)
        return np.clip(q + self.kv / self.kp * qd_ref, self.ctrl_low, self.ctrl_high)

    def demanded_force(self, ctrl: FloatArray, q: FloatArray, qd: FloatArray) -> FloatArray:
        """Servo force before the force limit: kp (ctrl - q) - kv qd."""
        return self.kp * (ctrl - q) - self.kv * qd


class Admittance:
    """Offset of the commanded grasp pose that yields to the handle wrench, mapped to joint offsets.

    Args:
        model: the simulation model.
        site: grasp site id.
        dofs: (n,) dof addresses of the planning joints.
        n_base: how many of them are base joints (first).
        config: gains.
    """

    def __init__(self, model: mujoco.MjModel, site: int, dofs: npt.ArrayLike, n_base: int, config: AdmittanceConfig) -> None:
        self.model = model
        self.site = site
        self.dofs = np.asarray(dofs, dtype=np.int64)
        self.config = config
        weights = np.ones(len(self.dofs))
        weights[:n_base] = config.base_weight
        self.inverse_weights = 1.0 / weights
        self.wrench = np.zeros(6)
        self.offset = np.zeros(6)
        self.q_offset = np.zeros(len(self.dofs))
        self._jp = np.zeros((3, model.nv))
        self._jr = np.zeros((3, model.nv))

    def update(
        self,
        data: mujoco.MjData,
        measured_wrench: FloatArray,
        dt: float,
        active: bool,
        path_direction: npt.ArrayLike | None = None,
    ) -> FloatArray:
        """Advance the admittance by one step and return the (n,) joint offset to add to the plan.

        Args:
            data: simulation data after the step (Jacobians are taken at its configuration).
            measured_wrench: (6,) force (N) and torque (N m) the handle exerts on the hand, world frame.
            dt: step, s.
            active: whether the gripper holds the handle; when not, the offset is frozen.
            path_direction: (3,) unit direction in which the plan moves the handle, world frame; the force
                along it (the part's inertia and friction as it is dragged) is not yielded to, so that the
                hand neither lags nor overshoots the plan: model errors show up across the path.
        """
        cfg = self.config
        alpha = dt / (cfg.filter_time + dt)
        self.wrench += alpha * (np.asarray(measured_wrench) - self.wrench)
        if not active:
            return self.q_offset
        wrench = self.wrench.copy()
        if path_direction is not None:
            u = np.asarray(path_direction, dtype=np.float64)
            wrench[:3] -= u * float(wrench[:3] @ u)
        D = np.array([cfg.damping] * 3 + [cfg.rotational_damping] * 3)
        K = np.array([cfg.stiffness] * 3 + [cfg.rotational_stiffness] * 3)
        step = dt * (wrench - K * self.offset) / D
        new = self.offset + step
        new[:3] *= min(1.0, cfg.max_offset / max(np.linalg.norm(new[:3]), 1e-12))
        new[3:] *= min(1.0, cfg.max_rotation / max(np.linalg.norm(new[3:]), 1e-12))
        step = new - self.offset
        self.offset = new
        mujoco.mj_jacSite(self.model, data, self._jp, self._jr, self.site)
        J = np.vstack([self._jp, self._jr])[:, self.dofs]
        JW = J * self.inverse_weights
        A = JW @ J.T + cfg.regularisation**2 * np.eye(6)
        self.q_offset = self.q_offset + JW.T @ np.linalg.solve(A, step)
        return self.q_offset


__all__ = ["Admittance", "AdmittanceConfig", "ServoModel"]
