"""The handle-path target a failed tracking reports (funrec_robot.whole_body._worst_target)."""

from __future__ import annotations

import numpy as np

from funrec_robot.plan_config import PlanConfig
from funrec_robot.whole_body import _worst_target


def test_the_missed_target_is_reported_not_the_largest_sum_of_ratios() -> None:
    """Target 1 is within both tolerances at 0.9 of each (sum 1.8); target 2, where the tracking gave up, is
    1.1 of the position tolerance with no orientation error (sum 1.1). The missed one must be reported, so
    that the plan stops with its message instead of a short path reaching the refinement (IndexError)."""
    config = PlanConfig()
    p, r = config.track_position_tolerance, config.track_orientation_tolerance
    position = np.array([0.1 * p, 0.9 * p, 1.1 * p])
    orientation = np.array([0.1 * r, 0.9 * r, 0.0])
    assert _worst_target(position, orientation, config) == 2
    # all within: the largest sum of ratios, as before
    assert _worst_target(position[:2], orientation[:2], config) == 1
