"""Timing that the servos can follow: limits from what holding the arm leaves of each effort limit (the retreat), a
path spline that stays within its waypoints, and a final approach that comes straight onto the handle."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from funrec_robot import build_mujoco_model, default_robot_path, load_robot
from funrec_robot.feasibility import MIN_EFFORT_LEFT, dynamic_limits, holding_load
from funrec_robot.grasp import offset_along_approach
from funrec_robot.ik import WholeBodyIK
from funrec_robot.plan import PlanConfig
from funrec_robot.retime import RetimeConfig, retime_path
from funrec_robot.scene import gravity_load, part_joint
from funrec_robot.sim_model import robot_indices
from funrec_robot.task_sources import task_from_ground_truth
from funrec_robot.whole_body import _straight_approach, _strays
from tests.helpers.robot_scenes import PRISMATIC_CASE, write_gt_scene

FETCH_YAML = Path(__file__).resolve().parents[1] / "robots" / "fetch.yaml"
FOREARM = "robot0:forearm_roll_joint"


@pytest.fixture(scope="module")
def fetch():
    pytest.importorskip("gymnasium_robotics")
    robot = load_robot(FETCH_YAML)
    return robot, build_mujoco_model(robot)


def test_holding_load_counts_the_model_joint_springs(fetch) -> None:
    """Fetch's file puts a 10 N m/rad spring (rest at 0) on the forearm roll: with gravity off, holding the forearm
    at -2.38 rad takes exactly 23.8 N m there and nothing elsewhere; with gravity on, the spring adds to gravity's
    load (to round-off: both are the model's own numbers)."""
    robot, model = fetch
    j = robot.joint_names.index(FOREARM)
    q = robot.q_home.copy()
    q[j] = -2.38
    model.opt.gravity[:] = 0.0
    try:
        load = holding_load(robot, model, q[None])[0]
    finally:
        model.opt.gravity[:] = (0.0, 0.0, -9.81)
    np.testing.assert_allclose(load[j], -23.8, atol=1e-9)
    np.testing.assert_allclose(np.delete(load, j), 0.0, atol=1e-9)

    indices = robot_indices(robot, model)
    qpos = model.qpos0.copy()
    qpos[indices.qpos] = q
    qpos[indices.held_qpos] = indices.held_values
    gravity = gravity_load(model, mujoco.MjData(model), qpos)[indices.dof].copy()
    expected = gravity + np.where(np.arange(robot.nq) == j, 10.0 * q[j], 0.0)
    np.testing.assert_allclose(holding_load(robot, model, q[None])[0], expected, atol=1e-9)


def test_dynamic_limits_share_what_holding_leaves(fetch) -> None:
    """The forearm roll holding 27.15 of its 29.35 N m (light_harsh_rev_wall_00's retreat) may spend half of the
    2.2 N m left on its damping (3.5247 N m s/rad) and 0.3 of it on its armature (2.7538 kg m^2): 0.312 rad/s and
    0.240 rad/s^2 instead of its 1.571 and 1.5; other joints keep their limits where their load leaves enough."""
    robot, model = fetch
    j = robot.joint_names.index(FOREARM)
    config = PlanConfig()
    v0, a0 = dynamic_limits(robot, model, config.effort_share_damping, config.effort_share_inertia)
    load = np.zeros(robot.nq)
    load[j] = -27.15
    v, a = dynamic_limits(robot, model, config.effort_share_damping, config.effort_share_inertia, load)
    np.testing.assert_allclose(v[j], 0.5 * (29.35 - 27.15) / 3.5247, rtol=1e-9)
    np.testing.assert_allclose(a[j], 0.3 * (29.35 - 27.15) / 2.7538, rtol=1e-9)
    np.testing.assert_array_equal(np.delete(v, j), np.delete(v0, j))
    np.testing.assert_array_equal(np.delete(a, j), np.delete(a0, j))
    # A load at or over the limit leaves the floor share, not a zero or negative limit.
    load[j] = 40.0
    v, a = dynamic_limits(robot, model, config.effort_share_damping, config.effort_share_inertia, load)
    np.testing.assert_allclose(v[j], 0.5 * MIN_EFFORT_LEFT * 29.35 / 3.5247, rtol=1e-9)
    assert a[j] > 0.0


def test_timed_path_stays_within_its_waypoints() -> None:
    """One coordinate steps evenly while a slow one takes one large step: a clamped cubic on the resulting uneven
    path parameter swung the first from its [0, 0.08] range to [-0.60, 1.73]; timed now, every sample of each
    coordinate lies within its waypoints' range (1e-9: round-off), and the ends are met at rest."""
    waypoints = np.array([[0.0, 0.0], [0.02, 0.0], [0.04, 1.0], [0.06, 1.0], [0.08, 1.0]])
    v_max, a_max = np.array([1.0, 0.1]), np.array([1.0, 1.0])
    cubic = retime_path(waypoints, v_max, a_max, RetimeConfig(overshoot_share=1e9))
    assert cubic.q[:, 0].min() < -0.1  # what the fallback is for
    timed = retime_path(waypoints, v_max, a_max)
    assert np.all(timed.q >= waypoints.min(axis=0) - 1e-9) and np.all(timed.q <= waypoints.max(axis=0) + 1e-9)
    np.testing.assert_allclose(timed.q[[0, -1]], waypoints[[0, -1]], atol=1e-9)
    np.testing.assert_allclose(timed.qd[[0, -1]], 0.0, atol=1e-9)
    assert np.all(np.abs(timed.qd) <= v_max * (1.0 + 1e-6))


def test_even_paths_are_timed_as_before() -> None:
    """A path whose cubic stays within its waypoints (a smooth arc sampled evenly) is timed exactly as without the
    fallback."""
    s = np.linspace(0.0, 1.0, 12)
    waypoints = np.column_stack([np.cos(s), np.sin(s), 0.3 * s])
    v_max, a_max = np.full(3, 1.0), np.full(3, 2.0)
    timed = retime_path(waypoints, v_max, a_max)
    cubic = retime_path(waypoints, v_max, a_max, RetimeConfig(overshoot_share=1e9))
    np.testing.assert_array_equal(timed.q, cubic.q)


@pytest.fixture(scope="module")
def drawer_ik(tmp_path_factory):
    robot = load_robot(default_robot_path())
    gt = write_gt_scene(PRISMATIC_CASE, tmp_path_factory.mktemp("approach"))
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    joint = part_joint(model, task.part)
    ik = WholeBodyIK(robot, model, joint, np.zeros((1, 3)), [])
    return robot, ik, task


def test_straight_approach_keeps_the_hand_on_the_line(drawer_ik) -> None:
    """From a pre-grasp configuration 10 cm out, the approach's IK steps keep the grasp point within 1 mm of the
    line onto the grasp pose and the hand's orientation within 1 deg (the IK meets each step to 1 mm), end at the
    grasp pose (1 mm), and do not stray by the tracking tolerances; the same hand moved there by rolling the wrist
    0.5 rad on the way does."""
    robot, ik, task = drawer_ik
    config = PlanConfig()
    q_home = robot.q_home.copy()
    T_home = ik.grasp_pose(q_home, 0.0, robot.gripper.open)
    T_grasp = offset_along_approach(T_home, -config.pregrasp_distance)  # 10 cm further along the approach
    steps = _straight_approach(ik, task, T_grasp, q_home, 0.0, robot.gripper.open, False, config)
    assert len(steps) == 11
    for q in steps:
        T = ik.grasp_pose(q, 0.0, robot.gripper.open)
        offset = T[:3, 3] - T_grasp[:3, 3]
        off_line = offset - (offset @ T_grasp[:3, 2]) * T_grasp[:3, 2]
        assert np.linalg.norm(off_line) < 1e-3
        cos = (np.trace(T_grasp[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
        assert np.arccos(np.clip(cos, -1.0, 1.0)) < np.deg2rad(1.0)
    np.testing.assert_allclose(ik.grasp_pose(steps[-1], 0.0, robot.gripper.open)[:3, 3], T_grasp[:3, 3], atol=1e-3)
    assert not _strays(ik, steps, T_grasp, config.pregrasp_distance, 0.0, robot.gripper.open, config)

    wrist = robot.joint_names.index(robot.arm_joints[-1])
    swing = np.linspace(steps[0], steps[-1], 50)
    swing[:, wrist] += 0.5 * np.sin(np.linspace(0.0, np.pi, 50))
    assert _strays(ik, swing, T_grasp, config.pregrasp_distance, 0.0, robot.gripper.open, config)
