"""The handle path's posture references start from the grasp's base (funrec_robot.whole_body._from_grasp) and the
approach onto a round bar far off its part is level (funrec_robot.task_sources._level_approach)."""

from __future__ import annotations

import time
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


def test_a_base_off_the_line_of_its_placed_heading_is_measured_across_it() -> None:
    """Stretch 3's base ended its pre-grasp solve 4.8 cm across the line of its placed heading (rolling back and
    forth while it turned); a roll along the heading is no offset, and a base that does not turn has none."""
    from funrec_robot.whole_body import _sideways

    diff = cast(RobotDescription, SimpleNamespace(drive="differential", base_motions=("x", "y", "yaw")))
    holo = cast(RobotDescription, SimpleNamespace(drive="holonomic", base_motions=("x", "y")))
    yaw = -2.984
    placed = np.array([0.016, 1.031, yaw, 0.5])
    heading = np.array([np.cos(yaw), np.sin(yaw)])
    rolled = placed + np.r_[0.18 * heading, 0.2, 0.0]
    assert _sideways(diff, placed, rolled) < 1e-12
    across = placed + np.r_[0.048 * np.array([-heading[1], heading[0]]), 0.0, 0.0]
    assert abs(_sideways(diff, placed, across) - 0.048) < 1e-12
    assert _sideways(holo, placed[:2], across[:2]) == 0.0


def test_a_lift_overloaded_by_gravity_ends_the_search_at_once(monkeypatch) -> None:  # noqa: ANN001
    """A lift holds the weight above it and the part's pull on the hand in every posture, grasp and placement: a
    gravity overload naming it ends the search with that error (Stretch 3 spent its 10 s budget on
    plain_rev_oven_00's twin at 63.0-63.9 N of 70 N each time). One naming a wrist joint tries the next posture."""
    import pytest

    from funrec_robot import plan
    from funrec_robot.feasibility import GravityOverload
    from funrec_robot.plan_config import PlanConfig

    calls: list[str] = []

    def overloaded(joint: str):  # noqa: ANN202
        def configurations(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            calls.append(joint)
            raise GravityOverload(f"at the planned grasp {joint} must hold too much", joint)
        return configurations

    monkeypatch.setattr(plan, "place_base", lambda problem, config: SimpleNamespace(poses=np.zeros((1, 3))))
    monkeypatch.setattr(plan, "_placement_problem", lambda *args: None)
    robot = SimpleNamespace(arm_joints=("joint_lift", "joint_wrist"), q_postures=(np.zeros(2),), q_home=np.zeros(2))
    config = PlanConfig()
    handle = SimpleNamespace(config=config, candidates=[SimpleNamespace(frames=np.eye(4)[None])] * 2,
                             states=np.linspace(0.0, 1.0, 5), final_state=None, target_state=1.0, placed={})
    task = SimpleNamespace(part="door")
    lifted = SimpleNamespace(lift_range=(0.0, 1.0), fingertip_depth=0.05)
    monkeypatch.setattr(plan, "whole_body_configurations", overloaded("joint_lift"))
    with pytest.raises(GravityOverload, match="joint_lift"):
        plan._search(robot, None, 0, task, lifted, handle, time.process_time())
    assert calls == ["joint_lift"]
    calls.clear()
    monkeypatch.setattr(plan, "whole_body_configurations", overloaded("joint_wrist"))
    monkeypatch.setattr(plan, "replace", lambda obj, **changes: obj)
    with pytest.raises(GravityOverload, match="joint_wrist"):
        plan._search(robot, None, 0, task, lifted, handle, time.process_time())
    assert len(calls) > 1


def test_a_twin_piece_seen_above_the_base_is_taken_to_stand_on_the_floor() -> None:
    """A twin's worktop seen at 0.76-0.9 m (nothing under it: light_harsh_rev_wall_00) lies above a base band of
    0.05-0.5 m: placed clear of what the twin holds, robots stood in the true lower cabinets. Taken to stand on the
    floor (``standing``), it is an obstacle; a ceiling piece at 2.6 m is not, nor is anything on a true scene."""
    from funrec_robot.scene import _footprints, box_corners

    def box(z_low: float, z_high: float) -> np.ndarray:
        centre, half = np.array([1.0, 0.0, (z_low + z_high) / 2]), np.array([0.3, 0.3, (z_high - z_low) / 2])
        return box_corners(centre[None], np.eye(3)[None], half[None])[0]

    corners = np.stack([box(0.76, 0.9), box(2.6, 2.7)])
    band = (0.05, 0.5)
    assert _footprints(corners, ["worktop", "ceiling"], band) == []
    kept = _footprints(corners, ["worktop", "ceiling"], band, standing=True)
    assert [p.name for p in kept] == ["worktop"]
