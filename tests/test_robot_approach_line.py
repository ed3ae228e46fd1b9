"""The approach to a low handle under other furniture: where the joint moves to the via pose swing the hand out
through the furniture above it, the hand goes to the via along a straight line (``whole_body._line_to``)."""

from __future__ import annotations

from funrec_robot import build_mujoco_model, default_robot_path, load_robot
from funrec_robot.feasibility import kinematic_collisions
from funrec_robot.plan import plan_interaction
from funrec_robot.task_sources import task_from_ground_truth
from tests.helpers.robot_scenes import write_gt_scene


def test_the_hand_reaches_a_low_drawer_along_a_line_clear_of_the_drawer_above(tmp_path) -> None:
    """Reseed-8 plain_pri_drawer_01: the handle at 0.40 m, another drawer's front 11.5 cm tall at 0.69 m above it.
    From home (the hand at 1.12 m) the joint moves to the via pose 0.25 m out swung the hand 7 cm beyond the upper
    drawer's front at 0.8 m high, and the plan failed ("runs into chest_drawer0_g0 (also through a via pose)"). Now
    it is planned through the via poses of the line (more than one), and its kinematic replay touches nothing but
    the handle."""
    robot = load_robot(default_robot_path())
    gt = write_gt_scene("plain_pri_drawer_01", tmp_path, reseed=8)
    model = build_mujoco_model(robot, gt / "scene.xml")
    task = task_from_ground_truth(gt, "part_0", model)
    plan = plan_interaction(robot, gt / "scene.xml", task, "open", model=model)
    assert plan.provenance["grasp"]["approach_vias"] > 1
    assert kinematic_collisions(robot, model, plan) == []
