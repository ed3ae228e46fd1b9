"""The handle path's posture references start from the grasp's base (funrec_robot.whole_body._from_grasp) and the
approach onto a round bar far off its part is level (funrec_robot.task_sources._level_approach)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import cast

import numpy as np

from funrec_robot.robot import RobotDescription
from funrec_robot.task_sources import _level_approach
from funrec_robot.whole_body import _from_grasp


def test_the_base_offset_at_the_grasp_fades_along_the_handle_path() -> None:
    """The approach left Fetch's base 19 cm off its planned pose; pulled back at the first target, it swept 9 cm and
    its shoulder 0.22 rad while the door turned 0.02 rad. The offset now fades linearly to zero at the path's end;
    the arm's references are untouched, and a heading offset is taken the short way round (+-pi)."""
    robot = cast(RobotDescription, SimpleNamespace(base_joints=("x", "y", "yaw"), base_motions=("x", "y", "yaw")))
    posture = np.zeros((5, 5))
    posture[:, 0] = np.linspace(0.0, 0.4, 5)  # the planned base rolls 40 cm along x
    posture[:, 2] = np.pi - 0.05
    posture[:, 3:] = 0.7
    q_grasp = np.array([-0.19, 0.05, -np.pi + 0.05, 1.0, 1.0])
    out = _from_grasp(robot, posture, q_grasp)
    np.testing.assert_allclose(out[0, :2], q_grasp[:2])
    assert abs(float(np.angle(np.exp(1j * (out[0, 2] - q_grasp[2]))))) < 1e-12 and abs(out[0, 2] - posture[0, 2]) < 0.11
    np.testing.assert_allclose(out[-1], posture[-1])
    np.testing.assert_allclose(out[2, 0], posture[2, 0] - 0.19 / 2)
    np.testing.assert_allclose(out[:, 3:], 0.7)


def test_a_round_bar_far_off_its_part_is_approached_level_from_the_hand_side() -> None:
    """The affordance's approach onto mw_drawer_00's bar came from above, 51 degrees down: turned about the bar's axis
    to level, into the part (the side the hand came from). A bar more than 30 degrees off level keeps its approach."""
    approach = np.array([0.01, 0.631, -0.776])
    approach /= np.linalg.norm(approach)
    bar = np.array([-1.0, 0.01, -0.005])
    bar /= np.linalg.norm(bar)
    level = _level_approach(approach, bar)
    assert abs(level[2]) < 1e-3 and abs(level @ bar) < 1e-12 and level[1] > 0.99
    assert np.isclose(np.linalg.norm(level), 1.0)
    np.testing.assert_allclose(_level_approach(-approach, bar), -level)
    upright = np.array([0.0, np.sin(0.6), np.cos(0.6)])  # 56 degrees off level
    assert _level_approach(approach, upright) is approach
