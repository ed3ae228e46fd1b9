"""The default robot in MuJoCo: holds its home pose, tracks steps, reaches handle heights, drops into scenes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mink
import mujoco
import numpy as np
import pytest

from funrec_robot import (
    ROBOT_PREFIX,
    RobotDescriptionError,
    build_mujoco_model,
    default_robot_path,
    load_robot,
    reset_to_home,
    robot_indices,
)

HOLD_TOL_M = 1e-3
"""Largest drift of a base slide at rest over 2 s, m."""
HOLD_TOL_RAD = 0.01
"""Largest drift of a hinge at rest over 2 s, rad."""


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


@pytest.fixture(scope="module")
def model(robot) -> mujoco.MjModel:
    return build_mujoco_model(robot)


def _step(model: mujoco.MjModel, data: mujoco.MjData, seconds: float) -> None:
    for _ in range(round(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)


def _tolerances(robot) -> np.ndarray:
    return np.array(
        [HOLD_TOL_M if motion in ("x", "y") else HOLD_TOL_RAD for motion in robot.base_motions]
        + [HOLD_TOL_RAD] * len(robot.arm_joints)
    )


def test_built_model_has_servos_and_names(robot, model) -> None:
    indices = robot_indices(robot, model)
    assert model.nu == robot.nq + 1  # one servo per planning joint, one for the gripper
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert indices.grasp_site_name == ROBOT_PREFIX + "grasp_site"
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, model.actuator_trnid[a, 0]) for a in indices.actuators]
    assert names == [ROBOT_PREFIX + name for name in robot.joint_names]
    assert np.all(model.body_gravcomp[indices.bodies] == 1.0)


def test_holds_home_pose_under_gravity(robot, model) -> None:
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    indices = robot_indices(robot, model)
    assert data.ncon == 0  # no self-contact at home
    p_world_grasp = data.site_xpos[indices.grasp_site].copy()
    _step(model, data, 2.0)
    drift = np.abs(data.qpos[indices.qpos] - robot.q_home)
    assert np.all(drift < _tolerances(robot)), drift
    assert np.linalg.norm(data.site_xpos[indices.grasp_site] - p_world_grasp) < HOLD_TOL_M


def test_without_gravity_compensation_the_arm_sags(robot) -> None:
    """The servos alone leave a steady gravity error; compensation (as real arm controllers do) removes it."""
    robot = dataclasses.replace(robot, gravity_compensation=False)
    model = build_mujoco_model(robot)
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    _step(model, data, 2.0)
    sag = np.abs(data.qpos[robot_indices(robot, model).qpos] - robot.q_home).max()
    assert 1e-3 < sag < 0.05


def test_tracks_a_joint_step(robot, model) -> None:
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    indices = robot_indices(robot, model)
    step = np.where(np.arange(robot.nq) < 2, 0.05, 0.1)  # m for the base slides, rad otherwise
    target = robot.q_home + step
    data.ctrl[indices.actuators] = target
    history = []
    for _ in range(round(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        history.append(data.qpos[indices.qpos] - target)
    errors = np.array(history)
    assert np.all(np.isfinite(errors))
    overshoot = (errors * np.sign(step)).max(axis=0) / np.abs(step)
    assert np.all(overshoot < 0.05), overshoot
    one_second = round(1.0 / model.opt.timestep)
    assert np.all(np.abs(errors[one_second]) < 0.02 * np.abs(step)), errors[one_second]
    assert np.all(np.abs(errors[-1]) < 1e-4)


def test_gripper_closes_and_opens(robot, model) -> None:
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    indices = robot_indices(robot, model)
    _step(model, data, 0.5)
    np.testing.assert_allclose(data.qpos[indices.gripper_qpos], robot.gripper.open, atol=1e-3)
    data.ctrl[indices.gripper_actuators] = robot.gripper.closed
    _step(model, data, 0.5)
    np.testing.assert_allclose(data.qpos[indices.gripper_qpos], robot.gripper.closed, atol=1e-3)


@pytest.mark.parametrize("height", [0.3, 0.4, 0.9, 1.5, 1.6])
def test_reaches_handle_heights_with_a_level_gripper(robot, model, height: float) -> None:
    """Base fixed at the origin: the grasp frame reaches 0.6 m ahead at the height, approaching along +x."""
    indices = robot_indices(robot, model)
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    configuration = mink.Configuration(model, data.qpos.copy())
    task = mink.FrameTask(indices.grasp_site_name, "site", position_cost=1.0, orientation_cost=0.5)
    T_world_grasp = np.eye(4)
    T_world_grasp[:3, :3] = np.column_stack([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # z = +x
    T_world_grasp[:3, 3] = [0.6, 0.0, height]
    task.set_target(mink.SE3.from_matrix(T_world_grasp))
    posture = mink.PostureTask(model, cost=1e-3)
    posture.set_target(data.qpos.copy())
    freeze_base = mink.DofFreezingTask(model, dof_indices=[int(i) for i in indices.dof[:3]])
    for _ in range(200):
        velocity = mink.solve_ik(
            configuration, [task, posture], 0.05, "daqp", damping=1e-3,
            limits=[mink.ConfigurationLimit(model)], constraints=[freeze_base],
        )  # fmt: skip
        configuration.integrate_inplace(velocity, 0.05)
        error = task.compute_error(configuration)
        if np.linalg.norm(error[:3]) < 1e-4 and np.linalg.norm(error[3:]) < 1e-3:
            break
    assert np.linalg.norm(error[:3]) < 1e-3 and np.linalg.norm(error[3:]) < 1e-2, error
    q = configuration.q[indices.qpos]
    np.testing.assert_allclose(q[:3], 0.0, atol=1e-9)
    assert np.all(q >= robot.q_min - 1e-6) and np.all(q <= robot.q_max + 1e-6)
    data.qpos[:] = configuration.q
    mujoco.mj_forward(model, data)
    assert data.ncon == 0  # the arm clears the base and torso there


CABINET_XML = """
<mujoco>
  <!-- no compiler angle: this scene's ranges are in degrees, the robot's stay in radians -->
  <option timestep="0.004"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="cabinet" pos="2 0 0.5">
      <geom type="box" size="0.3 0.3 0.5"/>
      <body name="door" pos="-0.31 0.3 0">
        <joint name="part_0" type="hinge" axis="0 0 1" range="0 90"/>
        <geom type="box" size="0.01 0.3 0.5" pos="0 -0.3 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_robot_placed_in_a_scene(robot, model, tmp_path: Path) -> None:
    scene_xml = tmp_path / "scene.xml"
    scene_xml.write_text(CABINET_XML)
    yaw = 0.5 * np.pi
    T_world_base = np.eye(4)
    T_world_base[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    T_world_base[:3, 3] = [1.0, -0.5, 0.0]
    merged = build_mujoco_model(robot, scene_xml, T_world_base)
    assert merged.opt.timestep == model.opt.timestep  # the smaller of scene and robot
    np.testing.assert_allclose(merged.jnt_range[merged.joint("part_0").id], [0.0, 0.5 * np.pi])
    for name in robot.joint_names:
        np.testing.assert_array_equal(
            merged.jnt_range[merged.joint(ROBOT_PREFIX + name).id], model.jnt_range[model.joint(ROBOT_PREFIX + name).id]
        )
    alone, placed = mujoco.MjData(model), mujoco.MjData(merged)
    reset_to_home(robot, model, alone)
    reset_to_home(robot, merged, placed)
    grasp = robot_indices(robot, merged).grasp_site
    T_base_grasp = np.eye(4)
    T_base_grasp[:3, :3] = alone.site_xmat[robot_indices(robot, model).grasp_site].reshape(3, 3)
    T_base_grasp[:3, 3] = alone.site_xpos[robot_indices(robot, model).grasp_site]
    T_world_grasp = T_world_base @ T_base_grasp
    np.testing.assert_allclose(placed.site_xpos[grasp], T_world_grasp[:3, 3], atol=1e-9)
    np.testing.assert_allclose(placed.site_xmat[grasp].reshape(3, 3), T_world_grasp[:3, :3], atol=1e-9)
    indices = robot_indices(robot, merged)
    robot_contacts = [
        c
        for c in placed.contact[: placed.ncon]
        if {merged.geom_bodyid[c.geom1], merged.geom_bodyid[c.geom2]} & set(indices.bodies)
    ]
    assert robot_contacts == []  # the chassis floats 5 cm above the floor
    _step(merged, placed, 1.0)
    assert np.all(np.abs(placed.qpos[indices.qpos] - robot.q_home) < _tolerances(robot))


def test_broken_scene_is_reported(robot, tmp_path: Path) -> None:
    scene_xml = tmp_path / "twin.xml"
    scene_xml.write_text("<mujoco><worldbody><geom type='box'/></worldbody>")
    with pytest.raises(RobotDescriptionError, match=r"twin\.xml: MuJoCo cannot load the scene"):
        build_mujoco_model(robot, scene_xml)


def test_placement_must_be_rigid(robot) -> None:
    T_world_base = np.diag([2.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="expected a \\(4, 4\\) rigid transform"):
        build_mujoco_model(robot, None, T_world_base)
