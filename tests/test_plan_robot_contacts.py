"""The robot touches nothing but the handle where the part moves into it or the jaw opens beside the scene: plans of
two reseed-3 bench scenes for Spot, replayed kinematically (``feasibility.kinematic_collisions``: every fifth sample,
the gripper allowed on the part within 6 cm of the handle). The models live outside the repository
(FUNREC_ROBOT_MODELS, default ../shared/robots next to the checkout); without them these tests skip."""

from __future__ import annotations

from pathlib import Path

import pytest

from funrec_robot.feasibility import kinematic_collisions
from funrec_robot.plan import plan_interaction
from funrec_robot.robot import load_robot
from funrec_robot.robot_yaml import MODELS_ENV
from funrec_robot.sim_model import build_mujoco_model
from funrec_robot.task_sources import task_from_ground_truth
from tests.helpers.robot_models import MODELS, ROBOTS, needs_models
from tests.helpers.robot_scenes import write_gt_scene

pytestmark = needs_models("boston_dynamics_spot")


def _spot_plan(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(MODELS_ENV, str(MODELS))
    robot = load_robot(ROBOTS / "spot_arm.yaml")
    gt = write_gt_scene(name, tmp_path, reseed=3)
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    return robot, model, plan_interaction(robot, gt / "scene.xml", task, "open", model=model)


def test_the_opening_jaw_keeps_off_the_scene_beside_a_sliding_door(tmp_path, monkeypatch) -> None:
    """plain_pri_wardrobe_00: the release opened Spot's jaw on the sliding door's bar 6 mm into the wardrobe's fixed
    door beside it (the part's own 8 mm allowance, ``gripper.release_sweep``, was applied to the whole scene): 42
    contacts from 14.7 s on, a collision in the check. The rest of the scene gets no allowance."""
    robot, model, plan = _spot_plan("plain_pri_wardrobe_00", tmp_path, monkeypatch)
    assert kinematic_collisions(robot, model, plan) == []


def test_a_door_swinging_towards_the_body_meets_no_leg(tmp_path, monkeypatch) -> None:
    """rev_fridge_01: the IK keeps the robot off the scene as the robot moves, not as the part moves into it. The base,
    trailing its three planned stops, left a front leg in the fridge door's swing (13 mm deep at 1.6 rad in the
    plan's own kinematics; 1367 N in the check). A handle path on which the robot but its hand touches the scene is
    now no plan, and the search goes on to one that is clear."""
    robot, model, plan = _spot_plan("rev_fridge_01", tmp_path, monkeypatch)
    assert plan.target_state > 1.7
    assert kinematic_collisions(robot, model, plan) == []
