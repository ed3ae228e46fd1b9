"""The part's weight on the hand counts in the planner's effort check (``feasibility.handle_load``)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from funrec_robot import build_mujoco_model, default_robot_path, load_robot
from funrec_robot.feasibility import handle_load, joint_loads
from funrec_robot.scene import part_joint
from funrec_robot.sim_model import robot_indices
from tests.helpers.robot_scenes import write_gt_scene


def test_a_drop_down_doors_weight_reaches_the_joints_through_the_hand(tmp_path: Path) -> None:
    """plain_rev_oven_00's door, 1.0 rad open, held by funrec_mm's grasp site: the least force that holds it acts
    along the site's path (f . v = the door's holding torque), and the base slides (world x and y at yaw 0)
    carry its horizontal part exactly. Before, the effort check counted the arm's own weight only (TIAGo's
    arm_5_joint asked 3.2 of its 3.0 N m on plain_rev_dishwasher_00's door, 11-22 N on the handle).
    Tolerance 1e-9 N: the same Jacobian, no simulation."""
    robot = load_robot(default_robot_path())
    gt = write_gt_scene("plain_rev_oven_00", tmp_path)
    model = build_mujoco_model(robot, gt / "scene.xml")
    joint = part_joint(model, "part_0")
    indices = robot_indices(robot, model)
    data = mujoco.MjData(model)
    qpos = model.qpos0.copy()
    qpos[model.jnt_qposadr[joint]] = 1.0
    site = int(indices.grasp_site)
    tau = handle_load(model, data, joint, qpos, site)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    v = np.cross(data.xaxis[joint], data.site_xpos[site] - data.xanchor[joint])
    load = joint_loads(model, joint, np.array([1.0]), qpos)[0]
    assert abs(load) > 1.0  # the door hangs on its hinge: a real load to carry
    force = load * v / (v @ v)
    base = indices.dof[:2]
    np.testing.assert_allclose(tau[base], force[:2], atol=1e-9)
    assert float(np.linalg.norm(tau[indices.dof])) > 0.0
    assert force @ v == pytest.approx(load, abs=1e-9)
