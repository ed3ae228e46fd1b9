"""Plausibility of an articulation task before any planning: a part's range and states must be what a
household part can do, so that a corrupt twin (a range of [-1e6, 1e6]) is refused at once instead of
driving the planner through an unbounded search."""

from __future__ import annotations

import math

from funrec.errors import PlanningError
from funrec_robot.task import ArticulationTask

MAX_REVOLUTE_RANGE_RAD = 2.0 * math.pi
"""Widest revolute range planned (a full turn)."""
MAX_PRISMATIC_RANGE_M = 2.0
"""Longest prismatic travel planned, m (a drawer or sliding door)."""


def check_task_bounds(task: ArticulationTask, start_state: float, target_state: float) -> None:
    """Refuse a task whose range or states no household part has.

    Raises:
        PlanningError: naming the part, the value and the bound.
    """
    low, high = task.state_range
    bound, unit = (MAX_REVOLUTE_RANGE_RAD, "rad") if task.joint_type == "revolute" else (MAX_PRISMATIC_RANGE_M, "m")
    if not (math.isfinite(low) and math.isfinite(high)) or high - low > bound:
        raise PlanningError(f"part '{task.part}': {task.joint_type} range [{low:g}, {high:g}] {unit} is implausible "
                            f"(wider than {bound:g} {unit}); the twin's articulation is corrupt")
    for name, state in (("start", start_state), ("target", target_state)):
        if not math.isfinite(state) or abs(state - 0.5 * (low + high)) > bound:
            raise PlanningError(f"part '{task.part}': {name} state {state:g} {unit} is implausible for its range [{low:g}, {high:g}]")


__all__ = ["MAX_PRISMATIC_RANGE_M", "MAX_REVOLUTE_RANGE_RAD", "check_task_bounds"]
