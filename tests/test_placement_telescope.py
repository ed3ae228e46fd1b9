"""Base placement for a telescoping arm: its wrist targets lie at least ``reach_min`` out along its slide."""

from __future__ import annotations

import numpy as np
import pytest

from funrec.errors import PlanningError
from funrec_robot.robot_geometry import Circle
from funrec_robot.scene import polygon_from_points
from funrec_robot.trajopt import PlacementConfig, PlacementProblem, place_base

WALL_Y = -0.52
"""Far side of the corridor the base stands in (the targets lie on y = 0, a cabinet beyond them), m."""


def _problem(reach_min: float) -> PlacementProblem:
    # Stretch 3's numbers (``measure_robot``): the shoulder 0.145 m to the right of the base centre, a 0.47 m
    # telescope reaching out to the right (reach_yaw -pi/2); one disc of 0.17 m for the base. Two wrist targets
    # 0.6 m apart on a cabinet's front, one stop for both; behind the base a wall: its disc, kept 0.06 m clear,
    # stands no further than 0.29 m from the targets' line, its shoulder no further than 0.145 m.
    cabinet = polygon_from_points("cabinet", [[-1.0, 0.05], [1.0, 0.05], [1.0, 1.0], [-1.0, 1.0]])
    wall = polygon_from_points("wall", [[-1.0, -1.0], [1.0, -1.0], [1.0, WALL_Y], [-1.0, WALL_Y]])
    return PlacementProblem(
        wrist_world=np.array([[-0.3, 0.0, 0.9], [0.3, 0.0, 0.9]]),
        stretch=np.array([0, 0]),
        base_free=(True, True, True),
        base_fixed=np.zeros(3),
        p_base_shoulder=np.array([0.0, -0.145, 0.9]),
        reach=0.47,
        base_circles=(Circle(np.zeros(2), 0.17, (0.0, 1.4)),),
        arm_circles=(),
        static=(cabinet, wall),
        sweep=((),),
        start_part=(),
        reach_yaw=-np.pi / 2,
        reach_min=reach_min,
        rolling=True,
    )


def _along(problem: PlacementProblem, pose: np.ndarray) -> np.ndarray:
    """(K,) how far out along the reach direction each wrist target lies from the shoulder, m."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    shoulder = pose[:2] + np.array([[c, -s], [s, c]]) @ problem.p_base_shoulder[:2]
    direction = np.array([np.cos(pose[2] + problem.reach_yaw), np.sin(pose[2] + problem.reach_yaw)])
    return (problem.wrist_world[:, :2] - shoulder) @ direction


def test_a_stop_the_drawn_in_telescope_cannot_serve_is_no_placement() -> None:
    """Within the shoulder's reach window alone the base stands in the corridor with the targets 0.145 m out along
    the slide at most; a telescope drawn in to 0.2 m cannot bring its wrist there (Stretch 3's stops on
    dark_rev_fridge_00_r3 stood so, the telescope drew in to its limit and the IK missed the bar for the whole
    10 s budget). With the slide's own limit that is no placement; in a corridor 0.1 m wider the stop keeps every
    target 0.2 m out. Tolerance 2 mm: the placement's accepted violation (``PlacementConfig.violation_tolerance``,
    about a millimetre)."""
    config = PlacementConfig()
    sphere = _problem(0.0)
    assert _along(sphere, place_base(sphere, config).poses[0]).min() < 0.2 - 0.05
    with pytest.raises(PlanningError, match="base placement"):
        place_base(_problem(0.2), config)
    wider = _problem(0.2)
    wall = polygon_from_points("wall", [[-1.0, -1.0], [1.0, -1.0], [1.0, WALL_Y - 0.1], [-1.0, WALL_Y - 0.1]])
    wider = PlacementProblem(**{**wider.__dict__, "static": (wider.static[0], wall)})
    assert _along(wider, place_base(wider, config).poses[0]).min() >= 0.2 - 0.002
