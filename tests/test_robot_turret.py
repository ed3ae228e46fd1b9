"""An arm's first link turning about a vertical axis (a turret: Spot's ``arm_link_sh0``) keeps clear of the part's
sweep as the base does. The models live outside the repository (FUNREC_ROBOT_MODELS, default ../shared/robots next
to the checkout); without them these tests skip."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from funrec_robot.robot import load_robot
from funrec_robot.robot_geometry import measure_robot
from funrec_robot.robot_yaml import MODELS_ENV
from tests.helpers.robot_models import MODELS, ROBOTS, needs_models

pytestmark = needs_models("boston_dynamics_spot")


@pytest.fixture(autouse=True)
def models_folder(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(MODELS_ENV, str(MODELS))


def test_spots_shoulder_is_a_base_disc_above_its_body() -> None:
    """Spot's arm_link_sh0 stands on the body, above the band of the body's discs (up to 0.57 m): one more base disc
    about the arm_sh0 axis holds every corner of its geoms' boxes however the joint turns it (1e-9 m: the same
    corners). Robots whose first arm link the base's discs already hold (Fetch's shoulder pan), or whose first arm
    joint is not a turret (TIAGo's and Stretch 3's lifts, funrec_mm's horizontal first axis), get none."""
    from funrec_robot.robot_geometry import _corners
    from funrec_robot.sim_model import build_mujoco_model, reset_to_home

    robot = load_robot(ROBOTS / "spot_arm.yaml")
    geometry = measure_robot(robot)
    body = [c for c in geometry.base_circles if c.z_band[1] < 0.6]
    turret = [c for c in geometry.base_circles if c.z_band[1] >= 0.6]
    assert len(turret) == 1 and len(body) == len(geometry.base_circles) - 1
    disc = turret[0]
    model = build_mujoco_model(robot)
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    data.qpos[[model.joint(f"robot/{name}").qposadr[0] for name in robot.base_joints]] = 0.0
    shoulder = model.body("robot/arm_link_sh0").id
    geoms = np.flatnonzero((model.geom_bodyid == shoulder) & ((model.geom_contype != 0) | (model.geom_conaffinity != 0)))
    for turn in np.linspace(-2.5, 2.5, 6):
        data.qpos[model.joint("robot/arm_sh0").qposadr[0]] = turn
        mujoco.mj_kinematics(model, data)
        corners = _corners(model, data, geoms)
        assert np.linalg.norm(corners[:, :2] - disc.centre_base, axis=1).max() <= disc.radius + 1e-9
        assert disc.z_band[0] - 1e-9 <= corners[:, 2].min() and corners[:, 2].max() <= disc.z_band[1] + 1e-9
    assert max(c.z_band[1] for c in body) < disc.z_band[1]
    for name in ("fetch", "tiago", "stretch3", "funrec_mm"):
        other = measure_robot(load_robot(ROBOTS / f"{name}.yaml"))
        assert len({c.z_band for c in other.base_circles}) == 1, name


def test_spot_keeps_its_shoulder_off_a_fridge_door_swinging_above_its_body(tmp_path) -> None:
    """plain_rev_fridge_00 (reseed 3): the fridge door hangs above Spot's body. Kept clear of it only where the
    door starts (an arm disc), the shoulder stood in the door's swing, the door came 18 mm into arm_link_sh0 in
    the plan's own kinematics from 1.2 rad on, and in the check the arm pushed on it with up to 1025 N. With the
    shoulder a base disc the plan, replayed kinematically (every fifth sample), touches nothing but the handle."""
    from funrec_robot.feasibility import kinematic_collisions
    from funrec_robot.plan import plan_interaction
    from funrec_robot.sim_model import build_mujoco_model
    from funrec_robot.task_sources import task_from_ground_truth
    from tests.helpers.robot_scenes import write_gt_scene

    robot = load_robot(ROBOTS / "spot_arm.yaml")
    gt = write_gt_scene("plain_rev_fridge_00", tmp_path, reseed=3)
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    plan = plan_interaction(robot, gt / "scene.xml", task, "open", model=model)
    assert plan.target_state > 1.7
    assert kinematic_collisions(robot, model, plan) == []
