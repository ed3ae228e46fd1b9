"""Whole-body IK: the planned motion keeps the grasp on the handle path, and targets are reached."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from funrec.geometry.joints import joint_transforms
from funrec_robot import build_mujoco_model, default_robot_path, load_robot, robot_indices
from funrec_robot.ik import WholeBodyIK
from funrec_robot.plan import plan_interaction
from funrec_robot.scene import part_joint
from funrec_robot.task_sources import task_from_ground_truth
from tests.helpers.robot_scenes import PRISMATIC_CASE, REVOLUTE_CASE, write_gt_scene

TRACK_TOL_M = 0.005
"""The handle path is tracked within 5 mm (the issue's bound): IK converges to 1 mm at the waypoints,
and the timed spline between waypoints 2 cm apart adds at most a few mm."""


@pytest.fixture(scope="module")
def robot():
    return load_robot(default_robot_path())


@pytest.mark.parametrize("case", [REVOLUTE_CASE, PRISMATIC_CASE])
def test_planned_grasp_point_follows_the_handle_within_5_mm(robot, tmp_path_factory, case: str) -> None:
    gt = write_gt_scene(case, tmp_path_factory.mktemp("ik"))
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    plan = plan_interaction(robot, gt / "scene.xml", task, "open", model=model)
    indices = robot_indices(robot, model)
    data = mujoco.MjData(model)
    depth = plan.provenance["grasp"]["depth_m"]
    T0 = plan.T_world_grasp_start
    p_contact_start = T0[:3, 3] + depth * T0[:3, 2]
    actuate = plan.segment("actuate")
    samples = np.arange(actuate.start, actuate.end + 1)
    moves = joint_transforms(plan.joint_type, plan.axis_world, plan.pivot_world, plan.part_state[samples] - plan.start_state)
    errors = []
    for i, T_move in zip(samples, moves):
        data.qpos[indices.qpos] = plan.q[i]
        mujoco.mj_kinematics(model, data)
        site = data.site_xpos[indices.grasp_site] + depth * data.site_xmat[indices.grasp_site].reshape(3, 3)[:, 2]
        errors.append(np.linalg.norm(site - (T_move[:3, :3] @ p_contact_start + T_move[:3, 3])))
    assert max(errors) < TRACK_TOL_M, max(errors)
    assert plan.provenance["ik_max_position_error_m"] < 0.002


def test_solve_reaches_a_reachable_target_and_reports_an_unreachable_one(robot, tmp_path_factory) -> None:
    gt = write_gt_scene(PRISMATIC_CASE, tmp_path_factory.mktemp("ik_solve"))
    model = build_mujoco_model(robot, gt / "scene.xml")
    joint = part_joint(model, "part_0")
    ik = WholeBodyIK(robot, model, joint, np.zeros((1, 3)), [])
    data = mujoco.MjData(model)
    indices = robot_indices(robot, model)
    q_target = robot.q_home + np.r_[0.1, -0.05, 0.2, 0.3, -0.2, 0.1, 0.2, 0.1, 0.3, -0.2]
    data.qpos[:] = ik.full_q(q_target, 0.0, robot.gripper.open)
    mujoco.mj_kinematics(model, data)
    T = np.eye(4)
    T[:3, :3] = data.site_xmat[indices.grasp_site].reshape(3, 3)
    T[:3, 3] = data.site_xpos[indices.grasp_site]
    q, e_pos, e_rot = ik.solve(T, robot.q_home, robot.q_home, 0.0, robot.gripper.open)
    assert e_pos < 1e-3 and e_rot < 1e-2
    far = T.copy()
    far[:3, 3] += [5.0, 0.0, 0.0]  # beyond the base's speed limit within the iteration budget: not reached
    _, e_pos, _ = ik.solve(far, robot.q_home, robot.q_home, 0.0, robot.gripper.open, max_iterations=20)
    assert e_pos > 0.5


def test_tracking_gives_up_at_the_first_missed_target(robot, tmp_path_factory) -> None:
    """A path whose second target is 5 m away stops there with ``give_up`` (the third, reachable, is not
    solved: a path with a miss is no plan), and is followed to its end without."""
    gt = write_gt_scene(PRISMATIC_CASE, tmp_path_factory.mktemp("ik_track"))
    model = build_mujoco_model(robot, gt / "scene.xml")
    ik = WholeBodyIK(robot, model, part_joint(model, "part_0"), np.zeros((1, 3)), [])
    T = ik.grasp_pose(robot.q_home, 0.0, robot.gripper.open)
    far = T.copy()
    far[:3, 3] += [5.0, 0.0, 0.0]
    targets = np.stack([T, far, T])
    postures = np.tile(robot.q_home, (3, 1))
    full = ik.track(targets, np.zeros(3), robot.q_home, postures, robot.gripper.open)
    cut = ik.track(targets, np.zeros(3), robot.q_home, postures, robot.gripper.open, give_up=(0.005, 0.05))
    assert len(full.q) == 3 and full.position_error[1] > 0.5
    assert len(cut.q) == 2 and cut.position_error[1] > 0.5 and cut.position_error[0] < 0.005
