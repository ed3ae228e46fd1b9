"""Grasp frames of a drop-down door let go to fall: the gripper turns on the bar until its fingers point along
the door towards the hinge, about the contact point, only over the last part of the path."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec_robot.grasp import GraspConfig, handle_frames
from funrec_robot.task import ArticulationTask

# An oven door: hinge along x at 0.1 m height, a horizontal bar 3.2 cm in front of it at 0.68 m; opening turns
# the top towards -y (the room), where the robot stands.
DOOR = ArticulationTask(
    part="door",
    joint_type="revolute",
    axis_world=np.array([1.0, 0.0, 0.0]),
    pivot_world=np.array([0.0, 0.0, 0.1]),
    state_range=(0.0, 1.45),
    state_current=0.0,
    p_world_contact=np.array([0.0, -0.032, 0.68]),
    approach_world=np.array([0.0, 1.0, 0.0]),
    handle_axis_world=np.array([1.0, 0.0, 0.0]),
    surface_offset=0.031,
    handle_width=0.015,
)
DEPTH = 0.01
RELEASE = 0.85
STATES = np.linspace(0.0, RELEASE, 18)


def _contact(frames: np.ndarray) -> np.ndarray:
    return frames[:, :3, 3] + DEPTH * frames[:, :3, 2]


def test_gripper_turns_edge_on_to_the_door_by_the_release_state() -> None:
    held = handle_frames(DOOR, STATES, DEPTH, 0.0, GraspConfig())
    falling = handle_frames(DOOR, STATES, DEPTH, 0.0, GraspConfig(fall_state=RELEASE))
    # Up to fall_roll_from (half) of the path nothing changes (1e-12: the same arithmetic).
    early = STATES <= 0.5 * RELEASE
    np.testing.assert_allclose(falling[early], held[early], atol=1e-12)
    # The turn is about the contact point: the fingers stay on the bar (1e-9 m: round-off).
    np.testing.assert_allclose(_contact(falling), _contact(held), atol=1e-9)
    # At the release state the approach lies in the door's plane (its outward normal is the canonical one,
    # -approach, turned with the door; 1e-9: round-off) and points towards the hinge.
    normal = Rotation.from_rotvec(RELEASE * DOOR.axis_world).apply(-DOOR.approach_world)
    z = falling[-1, :3, 2]
    assert abs(z @ normal) < 1e-9
    assert z @ (DOOR.pivot_world - _contact(falling)[-1]) > 0.0
    # Held to the end instead, the gripper faces the front within max_roll (45 deg) of level: not edge-on.
    assert abs(held[-1, :3, 2] @ normal) > 0.5


def _door_front(rng: np.random.Generator, recess: bool) -> np.ndarray:
    """Points of a door front in the plane y = 0 (the approach is +y, into the door), 0.6 x 0.8 m, 2 mm noise;
    with ``recess`` its middle (beyond 8 cm of the handle) is a glass panel 1.5 cm deeper, larger than the
    frame around the handle."""
    p = np.column_stack([rng.uniform(-0.3, 0.3, 40000), np.zeros(40000), rng.uniform(-0.4, 0.4, 40000)])
    if recess:
        glass = np.hypot(p[:, 0], p[:, 2]) > 0.08
        p[glass, 1] += 0.015
    return p + rng.normal(0.0, 0.002, p.shape)


def test_front_standoff_is_the_nearest_surface_around_the_handle() -> None:
    """Measured on a twin's part mesh, the handle's standoff lets a low handle be grasped pitched. It must not
    be overestimated (fingertips planned into the front): it is the near edge of a 5 mm bin, so it lies
    within 5 mm below the truth; a deeper recessed panel filling most of the ring does not count."""
    from funrec_robot.handle_geometry import front_standoff

    rng = np.random.default_rng(0)
    approach = np.array([0.0, 1.0, 0.0])
    for standoff in (0.012, 0.031):
        contact = np.array([0.02, -standoff, 0.05])
        for recess in (False, True):
            measured = front_standoff(_door_front(rng, recess), contact, approach)
            assert measured is not None and standoff - 0.005 - 0.002 <= measured <= standoff
    # A contact behind the front, or without points around it: no estimate.
    assert front_standoff(_door_front(rng, False), np.array([0.0, 0.02, 0.0]), approach) is None
    assert front_standoff(np.zeros((10, 3)), np.zeros(3), approach) is None


def test_measure_handle_tells_a_knob_from_a_bar_and_centres_a_knob() -> None:
    """Knobs of the bench twins measure 1.7-3.2 cm along the affordance's handle axis, bars 14-40 cm; a knob is
    grasped with the fingers closing horizontally (more pitch for low drawers), and its contact point is
    moved to the knob's centre (the hand's contact is off by 1-2 cm)."""
    from funrec_robot.handle_geometry import measure_handle

    rng = np.random.default_rng(1)
    approach, axis = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    front = _door_front(rng, False)
    centre = np.array([0.1, -0.03, 0.2])  # a handle 3 cm proud of the front (y = 0)
    knob = centre + rng.uniform(-0.015, 0.015, (400, 3)) * [1.0, 0.0, 1.0] + rng.normal(0.0, 0.002, (400, 3))
    bar = centre + np.column_stack([rng.uniform(-0.15, 0.15, 2000), np.zeros(2000), rng.uniform(-0.005, 0.005, 2000)])
    contact = centre + [0.012, 0.0, -0.01]
    shape = measure_handle(np.vstack([front, knob]), contact, approach, axis)
    assert shape.is_knob and shape.standoff is not None and 0.023 <= shape.standoff <= 0.03
    # Centred to within 3 mm (uniform 3 cm knob, 400 points) and left at the contact's depth.
    assert shape.p_centre is not None and np.linalg.norm(shape.p_centre - (centre + [0.0, contact[1] - centre[1], 0.0])) < 0.003
    assert not measure_handle(np.vstack([front, bar]), contact, approach, axis).is_knob
    assert measure_handle(front, contact, approach, axis).length is None  # no handle proud of the front


def test_measure_handle_centres_a_bar_across_but_not_along() -> None:
    """An affordance's contact can miss a bar sideways (4.4 cm on a twin of plain_rev_cabinet_left_00: the
    fingertip struck the bar at 157 N); the grasp is moved across the bar onto its middle, and left where the
    hand held it along the bar and in depth. Within 2 mm: the 8 mm bar's points are uniform across it, 2000 of
    them. Proud points spread wider than a bar (a hand fused into the part) leave the contact alone."""
    from funrec_robot.handle_geometry import measure_handle

    rng = np.random.default_rng(2)
    approach, axis = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])  # a vertical bar, across it is x
    front = _door_front(rng, False)
    centre = np.array([0.1, -0.024, 0.1])
    bar = centre + np.column_stack([rng.uniform(-0.004, 0.004, 2000), rng.uniform(-0.012, 0.0, 2000),
                                    rng.uniform(-0.07, 0.07, 2000)])
    contact = centre + [-0.044, 0.01, 0.05]
    shape = measure_handle(np.vstack([front, bar]), contact, approach, axis)
    assert not shape.is_knob and shape.p_bar is not None
    np.testing.assert_allclose(shape.p_bar, [centre[0], contact[1], contact[2]], atol=0.002)
    # Within the part mesh's 5 mm grid of the bar's middle, the contact stays exactly where it was.
    near = measure_handle(np.vstack([front, bar]), contact + [0.044 - 0.003, 0.0, 0.0], approach, axis)
    assert near.p_bar is not None and np.array_equal(near.p_bar, contact + [0.041, 0.0, 0.0])
    blob = centre + rng.uniform(-0.045, 0.045, (2000, 3)) * [1.0, 0.0, 1.0] - [0.0, 0.01, 0.0]
    assert measure_handle(np.vstack([front, blob]), centre + [0.0, 0.0, 0.0], approach, axis).p_bar is None


def _one_jaw_geometry():
    """A hand like Spot's as grasping sees it: finger boxes from 11 cm behind the grasp frame to 3.9 cm ahead of
    it, 7 cm apart, and a palm box (the wrist housing) up to 3 mm ahead of the grasp frame."""
    from funrec_robot.robot_geometry import RobotGeometry
    from funrec_robot.scene import box_corners

    def corners(low, high):
        centre, half = (np.array(low) + high) / 2.0, (np.array(high) - low) / 2.0
        return box_corners(centre[None], np.eye(3)[None], half[None]).reshape(-1, 3)

    fingers = np.vstack([corners([-0.01, 0.035, -0.11], [0.01, 0.045, 0.039]), corners([-0.01, -0.045, -0.11], [0.01, -0.035, 0.039])])
    return RobotGeometry(
        p_base_shoulder=np.array([0.3, 0.0, 0.65]), wrist_to_grasp=0.2, reach=0.75, base_circles=(), arm_circles=(),
        fingertip_depth=0.039, finger_depth_range=(-0.11, 0.039), finger_corners=fingers,
        palm_corners=corners([-0.04, -0.06, -0.18], [0.04, 0.1, 0.003]),
    )


def test_a_thick_bar_is_taken_further_out_on_the_pads_clear_of_the_palm() -> None:
    """Meta-World's drawer bar: 51 mm thick, 18 cm in front of the drawer. Taken where the fingertips keep their
    12 mm off the front (depth 0: the front is far), it reaches 28.5 mm (its radius and the 3 mm pad margin) back
    into the palm, which ends 3 mm ahead of the grasp frame; it is taken out to the first 1 mm step clear of it,
    0.032 m, within the pads (0.036 m: their 0.039 m less the margin), when asked to (``graspable_tilts`` asks
    only when no tilt takes the bar the usual way). A 71 mm bar would need 0.042 m: refused."""
    from dataclasses import replace

    from funrec_robot.grasp import grasp_depth

    drawer = replace(DOOR, joint_type="prismatic", axis_world=np.array([0.0, -1.0, 0.0]), pivot_world=None,
                     state_range=(0.0, 0.4), surface_offset=0.18, handle_width=0.051)
    geometry, config = _one_jaw_geometry(), GraspConfig()
    assert grasp_depth(drawer, geometry, 0.0, 0.0, config) is None  # the usual grasp only
    assert grasp_depth(drawer, geometry, 0.0, 0.0, config, clear_palm=True) == pytest.approx(0.032, abs=1e-9)
    assert grasp_depth(replace(drawer, handle_width=0.071), geometry, 0.0, 0.0, config, clear_palm=True) is None
    # A thin bar near the front is taken where the fingertips keep their clearance, as before: 0.039 - 0.031 +
    # 0.012 = 0.02 m, and its 10.5 mm reach back stays clear of the palm.
    thin = replace(drawer, surface_offset=0.031, handle_width=0.015)
    assert grasp_depth(thin, geometry, 0.0, 0.0, config, clear_palm=True) == pytest.approx(0.02, abs=1e-9)


def test_a_handle_wider_than_the_jaws_is_refused_naming_its_thickness_and_the_gap() -> None:
    """Meta-World's safe door (mw_door_00) at 2.4x: a round lever bar 109 mm across (radius 54.5 mm, measured on
    its mesh), 0.42 m deep along the approach as ``scene.part_front`` boxes it with its post. Across the pads it
    is at least 109 mm at every tilt, wider than any of the five robots' jaws (funrec_mm's 85 mm here): no tilt,
    and the refusal names both numbers. A flat bar (100 x 10 mm) is narrower tilted, 54 mm at 1.1 rad: the
    refusal names that too against 40 mm jaws; with 60 mm jaws it fits there, and what fails is the palm or the
    front. Sizes are exact arithmetic; the messages round to the millimetre."""
    from dataclasses import replace
    from types import SimpleNamespace
    from typing import cast

    from funrec_robot.grasp import graspable_tilts, ungraspable_reason
    from funrec_robot.robot import GripperDescription, RobotDescription

    def robot(gripper: GripperDescription) -> RobotDescription:
        return cast(RobotDescription, SimpleNamespace(gripper=gripper))  # grasping reads only the gripper

    slides = GripperDescription(joints=("left", "right"), actuator=None, open=0.0425, closed=0.0)
    hinged = replace(slides, open=-1.0, open_width=0.075)  # Spot's: a jaw on a hinge, its gap given
    assert slides.open_gap == pytest.approx(0.085, abs=1e-12) and hinged.open_gap == pytest.approx(0.075, abs=1e-12)
    door = replace(DOOR, surface_offset=0.264, handle_width=0.109, handle_depth=0.422)
    config = GraspConfig()
    assert graspable_tilts(robot(slides), door, _one_jaw_geometry(), config) == []
    assert ungraspable_reason(robot(slides), door, config) == "its bar is 109 mm thick, wider than the jaws open (85 mm)"
    assert ungraspable_reason(robot(hinged), door, config) == "its bar is 109 mm thick, wider than the jaws open (75 mm)"
    flat = replace(DOOR, handle_width=0.1, handle_depth=0.01)
    narrow = replace(slides, open=0.02)
    assert ungraspable_reason(robot(narrow), flat, config) == (
        "its bar is 100 mm thick and 54 mm across the pads at its narrowest tilt, wider than the jaws open (40 mm)"
    )
    assert ungraspable_reason(robot(replace(slides, open=0.03)), flat, config).startswith(
        "its bar (100 mm thick) fits between the jaws (60 mm open), but wherever it does"
    )


def _round_bar(rng: np.random.Generator, diameter: float, noise: float = 0.002) -> np.ndarray:
    """Surface points of a round bar along x through the origin, 0.3 m long, ``noise`` m of noise."""
    angle, along = rng.uniform(0.0, 2.0 * np.pi, 20000), rng.uniform(-0.15, 0.15, 20000)
    p = np.column_stack([along, diameter / 2 * np.cos(angle), diameter / 2 * np.sin(angle)])
    return p + rng.normal(0.0, noise, p.shape)


def test_a_twin_bar_far_off_its_front_is_told_at_least_its_fitted_diameter_less_the_margin() -> None:
    """A twin's contact with no front near it (Meta-World's lever, 26 cm off the door) is held on a bar whose
    section the part mesh shows: a circle fitted across the handle axis gives its diameter, and the bar is at
    least that less ``BAR_FIT_MARGIN_M`` (12 mm). A 109 mm bar with 2 mm noise: 97 +- 3 mm; a 51 mm bar 39 +- 3 mm.
    A flat front (no circle within the 6 cm fitted) or too few points: not told. The planner then refuses the
    109 mm bar for jaws 85 mm open, naming the least thickness, and leaves the 51 mm one to be tried."""
    from dataclasses import replace
    from types import SimpleNamespace
    from typing import cast

    from funrec_robot.grasp import graspable_tilts, ungraspable_reason
    from funrec_robot.handle_geometry import BAR_FIT_MARGIN_M, bar_thickness_min
    from funrec_robot.robot import GripperDescription, RobotDescription

    rng = np.random.default_rng(3)
    axis = np.array([1.0, 0.0, 0.0])
    for diameter in (0.109, 0.051):
        measured = bar_thickness_min(_round_bar(rng, diameter), np.zeros(3), axis)
        assert measured is not None and measured == pytest.approx(diameter - BAR_FIT_MARGIN_M, abs=0.003)
    flat = np.column_stack([rng.uniform(-0.1, 0.1, 5000), np.full(5000, 0.03), rng.uniform(-0.1, 0.1, 5000)])
    assert bar_thickness_min(flat, np.zeros(3), axis) is None
    assert bar_thickness_min(_round_bar(rng, 0.109)[:10], np.zeros(3), axis) is None

    slides = GripperDescription(joints=("left", "right"), actuator=None, open=0.0425, closed=0.0)
    robot = cast(RobotDescription, SimpleNamespace(gripper=slides))
    lever = replace(DOOR, surface_offset=None, handle_width=None, handle_width_min=0.095)
    config = GraspConfig()
    assert graspable_tilts(robot, lever, _one_jaw_geometry(), config) == []
    assert ungraspable_reason(robot, lever, config) == (
        "its bar is at least 95 mm thick at any tilt (a round bar fitted to the part's mesh), wider than the jaws open (85 mm)"
    )
    assert graspable_tilts(robot, replace(lever, handle_width_min=0.039), _one_jaw_geometry(), config) != []
