"""Whether a robot can reach a part's handle at all, decided in microseconds before any optimisation, and
the lift height (torso, mast) the planner starts from.

The model is the one base placement uses (``robot_geometry``), taken at its most generous: the hand reaches
a handle at heights within the arm's full reach plus the wrist-to-grasp length of the shoulder (the gripper
may point down onto a low handle), and a lift moves the shoulder up and down within its range. A handle
outside that band cannot be reached whatever the optimisation does; it is refused with one sentence.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from funrec.typed import FloatArray
from funrec_robot.robot import RobotDescription
from funrec_robot.robot_geometry import RobotGeometry
from funrec_robot.task import ArticulationTask

LIFT_ABOVE_HANDLE_M = 0.1
"""A lift puts the shoulder this far above the handle (the arm pulls best from slightly above), m."""
LIFT_MARGIN_M = 0.01
"""... and stays this far inside the range the whole-body IK keeps joints in (``IKConfig.limit_margin`` inside
the lift's limits): a lift started within that margin made the IK's QP infeasible from its first step, m."""


@dataclass(frozen=True)
class ReachBand:
    """Heights a robot's hand reaches a handle at, with the base on the floor."""

    low: float
    """Lowest handle height, m (not below the floor)."""
    high: float
    """Highest handle height, m."""
    shoulder: tuple[float, float]
    """Lowest and highest shoulder height (equal without a lift), m."""

    def sentence(self, robot: RobotDescription, height: float) -> str:
        """Why a handle at ``height`` is out of reach, in one sentence."""
        lift = ""
        if self.shoulder[1] > self.shoulder[0]:
            joint = robot.arm_joints[0]
            k = len(robot.base_joints)
            lift = f" with its {joint} at {robot.q_min[k]:.2f}-{robot.q_max[k]:.2f} m (shoulder at {self.shoulder[0]:.2f}-{self.shoulder[1]:.2f} m)"
        return f"handle at {height:.2f} m; {robot.name} reaches {self.low:.2f}-{self.high:.2f} m{lift}"


def reach_band(geometry: RobotGeometry) -> ReachBand:
    """The band of handle heights within the arm's reach plus the wrist-to-grasp length of the shoulder (for a
    telescoping arm, what its slide moves the wrist up or down, ``RobotGeometry.reach_up``, in place of its
    reach: a horizontal telescope raises nothing)."""
    z = float(geometry.p_base_shoulder[2])
    down, up = geometry.lift_range if geometry.lift_range is not None else (0.0, 0.0)
    r = (geometry.reach if geometry.reach_up is None else geometry.reach_up) + geometry.wrist_to_grasp
    return ReachBand(max(z + down - r, 0.0), z + up + r, (z + down, z + up))


def handle_height(task: ArticulationTask) -> float:
    """Height of the handle where the hand takes it (the part at its current state), m."""
    from funrec_robot.task import T_world_part

    T = T_world_part(task, [task.state_current])[0]
    return float(T[2, :3] @ task.p_world_contact + T[2, 3])


def reach_refusal(robot: RobotDescription, geometry: RobotGeometry, task: ArticulationTask) -> str | None:
    """One sentence on why the robot cannot reach the task's handle, or None if it may."""
    band = reach_band(geometry)
    height = handle_height(task)
    if band.low <= height <= band.high:
        return None
    return band.sentence(robot, height)


def lifted(robot: RobotDescription, geometry: RobotGeometry, height: float, limit_margin: float) -> RobotDescription:
    """The robot with its lift's home position putting the shoulder ``LIFT_ABOVE_HANDLE_M`` above a handle at
    ``height``, within the lift's range less ``limit_margin`` (the IK's) and ``LIFT_MARGIN_M``; the robot
    unchanged without a lift."""
    if geometry.lift_range is None:
        return robot
    down, up = geometry.lift_range
    inside = limit_margin + LIFT_MARGIN_M
    move = float(np.clip(height + LIFT_ABOVE_HANDLE_M - geometry.p_base_shoulder[2], down + inside, up - inside))
    q_home: FloatArray = robot.q_home.copy()
    q_home[len(robot.base_joints)] += geometry.lift_sign * move
    postures = tuple(np.where(np.arange(robot.nq) == len(robot.base_joints), q_home, q) for q in robot.q_postures)
    return replace(robot, q_home=q_home, q_postures=postures)


@dataclass(frozen=True)
class ReachRow:
    """Whether each robot can reach one part's handle."""

    part: str
    """Part name."""
    height: float
    """Handle height where the hand takes it, m."""
    refusals: tuple[str | None, ...]
    """Per robot: None if it may reach the handle, else why not (one sentence)."""


def reach_table(scene: str | Path, robot_paths: Sequence[str | Path]) -> tuple[tuple[str, ...], tuple[ReachRow, ...]]:
    """For every part of a scene (twin folder, gt/ or capture folder, or their MJCF) and every robot file,
    whether the robot can reach its handle (``reach_refusal``); returns the robot names and one row per part.

    Raises:
        FunrecError: an unreadable scene or robot file (naming it).
    """
    from funrec_robot.robot import load_robot
    from funrec_robot.robot_geometry import measure_robot
    from funrec_robot.task_sources import load_task, locate_scene, part_names

    source = locate_scene(scene)
    robots = [load_robot(path) for path in robot_paths]
    geometries = [measure_robot(robot) for robot in robots]
    rows = []
    for name in part_names(source):
        task = load_task(source, name)
        rows.append(ReachRow(name, handle_height(task), tuple(reach_refusal(r, g, task) for r, g in zip(robots, geometries))))
    return tuple(r.name for r in robots), tuple(rows)


__all__ = ["LIFT_ABOVE_HANDLE_M", "ReachBand", "ReachRow", "handle_height", "lifted", "reach_band", "reach_refusal", "reach_table"]
