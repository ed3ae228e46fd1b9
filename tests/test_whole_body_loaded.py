"""Whether a part's weight presses on the hand at the end of its path (funrec_robot.whole_body._presses_on_hand)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from funrec_robot import whole_body
from funrec_robot.plan_config import PlanConfig
from funrec_robot.robot import GripperDescription


@pytest.mark.parametrize(("file_rest_force", "pressing"), [(7.0, True), (None, False)])
def test_the_hand_is_loaded_by_the_robots_own_rest_force(monkeypatch, file_rest_force, pressing) -> None:
    """A door holding 10 N on the hand presses on it for a robot whose file lets at most 7 N rest on a finger
    (Stretch 3's ``gripper.fall_rest_force``), and not for one that keeps the planner's 20 N: the check that tries
    both ways round for the shallower finger used the planner's 20 N for every robot, while the planner lets such a
    door go to fall by the robot's own value."""
    monkeypatch.setattr(whole_body, "_weight_on_hand", lambda model, joint, task, state: 10.0)
    gripper = GripperDescription(joints=("finger",), actuator=None, open=0.05, closed=0.0, fall_rest_force=file_rest_force)
    robot = SimpleNamespace(gripper=gripper)
    config = PlanConfig()
    assert config.fall_rest_force == pytest.approx(20.0)
    assert whole_body._presses_on_hand(robot, None, 0, None, 0.5, config) is pressing
