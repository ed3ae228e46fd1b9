"""Where a robot takes a bar: ``reach.along_bar_to_lift`` (an upright bar, a robot with a lift) and
``reach.level_bar_ends`` (a level bar's ends) on plain geometry (no robot model)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from funrec_robot.reach import (
    BAR_END_CLEARANCE_M,
    LIFT_ABOVE_HANDLE_M,
    LIFT_MARGIN_M,
    along_bar_to_lift,
    handle_height,
    level_bar_ends,
)
from funrec_robot.task import ArticulationTask

MARGIN = 0.01
"""The whole-body IK's limit margin for a slide such as a lift (``IKConfig.limit_margin_m``), m."""

# A fridge door hinged about z at x = 0; its upright bar runs 0.97-1.47 m, the contact point at its middle (1.22 m,
# rev_fridge_01_r3's bar).
FRIDGE = ArticulationTask(
    part="door", joint_type="revolute", axis_world=[0, 0, 1], pivot_world=[0.0, 1.0, 0.0], state_range=(0.0, 1.8),
    state_current=0.0, p_world_contact=np.array([-0.6, 0.97, 1.22]), approach_world=np.array([0.0, 1.0, 0.0]),
    handle_axis_world=np.array([0.0, 0.0, 1.0]), surface_offset=0.032, handle_width=0.015, handle_extent=(-0.25, 0.25),
)
# Stretch 3 as ``measure_robot`` finds it: shoulder 0.769 m at home, the mast moving it -0.6 to +0.5 m, a telescope
# that raises nothing.
STRETCH = SimpleNamespace(lift_range=(-0.6, 0.5), p_base_shoulder=np.array([0.0, 0.0, 0.769]), reach=0.47, reach_up=0.0)
TOP = 0.769 + 0.5 - MARGIN - LIFT_MARGIN_M - LIFT_ABOVE_HANDLE_M
"""Highest handle the mast serves without ``lifted`` cutting it: 1.109 m."""


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_bar_above_the_mast_is_taken_lower_down_where_the_mast_serves(sign: float) -> None:
    # Without the move Stretch 3's mast stopped at its limit and the IK missed the pre-grasp by 47 mm. The bar's
    # axis may point either way (``part_front`` takes a box's axis as it comes).
    bar = replace(FRIDGE, handle_axis_world=sign * FRIDGE.handle_axis_world)
    task = along_bar_to_lift(STRETCH, bar, MARGIN)
    assert handle_height(task) == pytest.approx(TOP, abs=1e-9)
    np.testing.assert_allclose(task.p_world_contact[:2], FRIDGE.p_world_contact[:2], atol=1e-12)  # along the bar only
    shift = sign * (TOP - 1.22)
    assert task.handle_extent == pytest.approx((-0.25 - shift, 0.25 - shift), abs=1e-9)


def test_a_bar_that_does_not_reach_the_masts_band_within_the_clearance_is_taken_where_it_was() -> None:
    # Half a move leaves the lift cut all the same; TIAGo's 1.73 m wall-cabinet bar moved 1 cm and lost the floor
    # refusal it had (r3 geo_island_rev_wall_00: REFUSED -> NO PLAN).
    reaches = 1.22 - TOP + BAR_END_CLEARANCE_M
    task = replace(FRIDGE, handle_extent=(-reaches + 1e-4, 0.25))
    assert along_bar_to_lift(STRETCH, task, MARGIN) is task
    task = replace(FRIDGE, handle_extent=(-reaches - 1e-4, 0.25))
    assert handle_height(along_bar_to_lift(STRETCH, task, MARGIN)) == pytest.approx(TOP, abs=1e-9)


@pytest.mark.parametrize(
    "robot, task",
    [
        (SimpleNamespace(**{**vars(STRETCH), "lift_range": None}), FRIDGE),  # no lift
        (STRETCH, replace(FRIDGE, p_world_contact=np.array([-0.6, 0.97, 1.05]))),  # already within the mast's band
        (STRETCH, replace(FRIDGE, handle_axis_world=np.array([1.0, 0.0, 0.0]))),  # a level bar
        (STRETCH, replace(FRIDGE, handle_extent=None)),  # a twin's bar: its ends unknown
        (SimpleNamespace(**{**vars(STRETCH), "reach_up": None}), FRIDGE),  # an arm with a shoulder raises 0.47 m itself
    ],
)
def test_the_contact_point_stays_where_nothing_asks_to_move_it(robot, task) -> None:
    assert along_bar_to_lift(robot, task, MARGIN) is task


# A drop-down door hinged about x at its foot; its level bar runs 0.2079 m either side of the contact point, 0.6 m up
# the door (the reseed-3 ovens' bar).
OVEN = ArticulationTask(
    part="door", joint_type="revolute", axis_world=[1, 0, 0], pivot_world=[0.0, 2.0, 0.2], state_range=(0.0, 1.41),
    state_current=0.0, p_world_contact=np.array([-0.2, 1.97, 0.8]), approach_world=np.array([0.0, 1.0, 0.0]),
    handle_axis_world=np.array([1.0, 0.0, 0.0]), surface_offset=0.032, handle_width=0.015, handle_extent=(-0.2079, 0.2079),
)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_level_bar_is_offered_at_either_end_within_the_clearance(sign: float) -> None:
    # Stretch 3's base, kept clear of where the oven's door falls open, stands beside the door and reaches the bar
    # 0.148 m from its centre, not the centre. Tolerance 1e-12 m: additions of the shift alone.
    bar = replace(OVEN, handle_axis_world=sign * OVEN.handle_axis_world)
    ends = level_bar_ends(bar)
    shift = 0.2079 - BAR_END_CLEARANCE_M
    assert len(ends) == 2
    offsets = sorted(float((end.p_world_contact - OVEN.p_world_contact)[0]) for end in ends)
    np.testing.assert_allclose(offsets, [-shift, shift], atol=1e-12)
    for end in ends:
        np.testing.assert_allclose(end.p_world_contact[1:], OVEN.p_world_contact[1:], atol=1e-12)  # along the bar only
        along = float((end.p_world_contact - bar.p_world_contact) @ bar.handle_axis_world)
        assert end.handle_extent == pytest.approx((-0.2079 - along, 0.2079 - along), abs=1e-12)
        assert end.handle_extent[0] == pytest.approx(-BAR_END_CLEARANCE_M, abs=1e-12) or end.handle_extent[1] == pytest.approx(
            BAR_END_CLEARANCE_M, abs=1e-12)


def test_the_nearer_end_of_an_off_centre_contact_comes_first() -> None:
    task = replace(OVEN, handle_extent=(-0.10, 0.30))
    first, second = level_bar_ends(task)
    assert float(first.p_world_contact[0] - OVEN.p_world_contact[0]) == pytest.approx(-0.10 + BAR_END_CLEARANCE_M, abs=1e-12)
    assert float(second.p_world_contact[0] - OVEN.p_world_contact[0]) == pytest.approx(0.30 - BAR_END_CLEARANCE_M, abs=1e-12)


@pytest.mark.parametrize(
    "task",
    [
        FRIDGE,  # an upright bar (``along_bar_to_lift`` moves those)
        replace(OVEN, handle_extent=None),  # a twin's bar: its ends unknown
        replace(OVEN, handle_axis_world=None),  # a knob
        replace(OVEN, handle_extent=(-0.069, 0.069)),  # a bar whose ends lie within a centimetre of the clearance
    ],
)
def test_no_end_is_offered_where_there_is_no_level_bar_to_move_along(task) -> None:
    assert level_bar_ends(task) == ()
