"""What the robot is asked to do with one articulated part: its joint, where to grasp it and how far to move it.

:class:`ArticulationTask` is plain data built by a loader (``task_sources.py``: from a synthetic capture's
ground truth now, from a twin's articulation.json + affordances.json later); the planner reads nothing else.
Every vector is in the frame of the scene the robot plans in, called ``world`` here (z up).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from funrec.errors import PlanningError
from funrec.geometry.joints import JOINT_TYPES, joint_transforms
from funrec.typed import FloatArray

UNIT_TOLERANCE = 1e-6
"""Largest deviation from unit length / orthogonality accepted for task directions."""
PATH_STEP_M = 0.02
"""Longest motion of the grasp point between two samples of the handle path, m (IK waypoint spacing)."""
PATH_STEP_RAD = np.deg2rad(4.0)
"""Largest rotation of the grasp frame between two samples of the handle path, rad."""
TARGET_WORDS = ("open", "close", "demo")
"""Symbolic targets: the upper end of the range, the lower end, the demonstrated interaction."""


def unit_vector(name: str, v: npt.ArrayLike) -> FloatArray:
    """``v`` scaled to unit length; ValueError naming ``name`` if it is not a finite non-zero (3,) vector."""
    v = np.asarray(v, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: expected a finite (3,) vector, got shape {v.shape}")
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise ValueError(f"{name}: zero vector")
    return v / n


@dataclass(frozen=True)
class ArticulationTask:
    """One articulated part to operate, in the scene's world frame (z up).

    States are joint positions from the part's canonical state (0), in rad (revolute) or m (prismatic),
    with the sign convention of ``axis_world``: the part at state s is the canonical part moved by
    ``joint_transforms(joint_type, axis_world, pivot_world, s)``.
    """

    part: str
    """Part name; also the name of its joint in the scene's MJCF."""
    joint_type: str
    """"revolute" or "prismatic"."""
    axis_world: FloatArray
    """(3,) unit joint axis."""
    pivot_world: FloatArray | None
    """(3,) a point on the revolute axis, m; None for a prismatic joint."""
    state_range: tuple[float, float]
    """(lower, upper) feasible joint states, rad or m."""
    state_current: float
    """State of the part in the scene when the robot arrives, rad or m."""
    p_world_contact: FloatArray
    """(3,) contact point (handle centre) with the part at state 0, m."""
    approach_world: FloatArray
    """(3,) unit direction in which the gripper moves onto the handle at state 0 (into the part; the
    grasp frame's z); minus the outward normal of the part's front."""
    handle_axis_world: FloatArray | None
    """(3,) unit long axis of the handle at state 0, perpendicular to ``approach_world`` (the grasp frame's
    x: the fingers close across it); None for a knob (the planner then closes the fingers horizontally)."""
    surface_offset: float | None = None
    """Distance from the contact point to the part's front surface along ``approach_world``, m; None if
    unknown. The planner keeps the fingertips clear of that surface."""
    handle_width: float | None = None
    """Thickness of the handle between the finger pads, m; None if unknown (the gripper then opens fully)."""
    handle_width_max: float | None = None
    """At most this thick between the finger pads, m, when ``handle_width`` is unknown: measured on a twin's part
    mesh (``handle_geometry.HandleShape.thickness_max``); None if not told. A fixed jaw is placed off a handle
    that thick (``grasp.jaw_offset``) rather than off the thickest one expected."""
    handle_width_min: float | None = None
    """At least this thick between the finger pads at any tilt, m, when ``handle_width`` is unknown: a round bar
    fitted on a twin's part mesh (``handle_geometry.bar_thickness_min``); None if not told. Jaws that open
    narrower than that cannot take the handle (the planner refuses it)."""
    handle_depth: float | None = None
    """Extent of the handle along the approach, m (it crosses the pads when the grasp is tilted); None if
    unknown (taken equal to the width)."""
    handle_extent: tuple[float, float] | None = None
    """Where a bar ends either way of ``p_world_contact`` along ``handle_axis_world``: (below 0, above 0), m; None
    if unknown (the hand takes the bar at the contact point)."""
    demo_times: FloatArray = field(default_factory=lambda: np.zeros(0))
    """(K,) times of the demonstrated interaction, s from its start; empty if none."""
    demo_states: FloatArray = field(default_factory=lambda: np.zeros(0))
    """(K,) joint states of the demonstrated interaction, rad or m."""
    source: str = ""
    """Where the task came from, e.g. ``gt:bench_suite/rev_fridge_00/gt`` (recorded in plans)."""
    grasp_source: str = "geometry"
    """Where the contact point and grasp axes came from: 'geometry' (a scene's geoms), 'affordances'
    (a twin's affordances.json) or 'mesh fallback (why)' (guessed from a twin's part mesh; recorded in plans)."""
    source_files: tuple[Path, ...] = ()
    """Files the task was read from (hashed into a plan's provenance)."""

    def __post_init__(self) -> None:
        if self.joint_type not in JOINT_TYPES:
            raise ValueError(f"joint_type must be one of {JOINT_TYPES}, got {self.joint_type!r}")
        object.__setattr__(self, "axis_world", unit_vector("axis_world", self.axis_world))
        object.__setattr__(self, "approach_world", unit_vector("approach_world", self.approach_world))
        if self.joint_type == "revolute":
            if self.pivot_world is None:
                raise ValueError("a revolute task needs pivot_world")
            object.__setattr__(self, "pivot_world", np.asarray(self.pivot_world, dtype=np.float64).reshape(3))
        else:
            object.__setattr__(self, "pivot_world", None)
        p = np.asarray(self.p_world_contact, dtype=np.float64)
        if p.shape != (3,):
            raise ValueError(f"p_world_contact: expected (3,), got {p.shape}")
        object.__setattr__(self, "p_world_contact", p)
        if self.handle_axis_world is not None:
            h = unit_vector("handle_axis_world", self.handle_axis_world)
            h = h - self.approach_world * float(h @ self.approach_world)
            if np.linalg.norm(h) < 0.1:
                raise ValueError("handle_axis_world is parallel to approach_world")
            object.__setattr__(self, "handle_axis_world", h / np.linalg.norm(h))
        low, high = (float(v) for v in self.state_range)
        if not low <= high:
            raise ValueError(f"state_range: lower {low} > upper {high}")
        object.__setattr__(self, "state_range", (low, high))
        times = np.asarray(self.demo_times, dtype=np.float64).reshape(-1)
        states = np.asarray(self.demo_states, dtype=np.float64).reshape(-1)
        if times.shape != states.shape:
            raise ValueError(f"demo_times {times.shape} and demo_states {states.shape} differ in length")
        object.__setattr__(self, "demo_times", times)
        object.__setattr__(self, "demo_states", states)

    @property
    def unit(self) -> str:
        """Unit of the joint state: 'rad' or 'm'."""
        return "rad" if self.joint_type == "revolute" else "m"


def T_world_part(task: ArticulationTask, states: npt.ArrayLike) -> FloatArray:
    """(N, 4, 4) motion of the part from state 0 to each state (maps canonical points to posed ones)."""
    return joint_transforms(task.joint_type, task.axis_world, task.pivot_world, states)


def resolve_target(task: ArticulationTask, target: str | float) -> float:
    """Joint state for a target: a number (rad or m), 'open' (upper end of the range), 'close' (lower end)
    or 'demo' (last state of the demonstration).

    Raises:
        PlanningError: an unknown word, a number outside the part's range, or 'demo' without a demonstration.
    """
    low, high = task.state_range
    if isinstance(target, str):
        word = target.strip().lower()
        if word == "open":
            return high
        if word == "close":
            return low
        if word == "demo":
            if task.demo_states.size == 0:
                raise PlanningError(f"part '{task.part}' ({task.source}): no demonstrated interaction for --to demo")
            return float(task.demo_states[-1])
        try:
            value = float(word)
        except ValueError:
            raise PlanningError(
                f"target '{target}': expected a joint state in {task.unit} or one of {', '.join(TARGET_WORDS)}"
            ) from None
    else:
        value = float(target)
    if not low - 1e-9 <= value <= high + 1e-9:
        raise PlanningError(
            f"part '{task.part}': target {value:.4g} {task.unit} outside the part's range [{low:.4g}, {high:.4g}]"
        )
    return value


def path_states(task: ArticulationTask, start: float, target: float, T_world_grasp0: npt.ArrayLike) -> FloatArray:
    """(N,) joint states from ``start`` to ``target`` sampled densely enough for IK waypoints.

    Consecutive samples move the grasp frame by at most ``PATH_STEP_M`` and turn it by at most
    ``PATH_STEP_RAD``; N >= 2.
    """
    T0 = np.asarray(T_world_grasp0, dtype=np.float64)
    span = abs(target - start)
    if task.joint_type == "prismatic":
        n = int(np.ceil(span / PATH_STEP_M))
    else:
        radius = float(np.linalg.norm(np.cross(task.axis_world, T0[:3, 3] - task.pivot_world)))
        n = int(np.ceil(max(span * radius / PATH_STEP_M, span / PATH_STEP_RAD)))
    return np.linspace(start, target, max(n, 1) + 1)


__all__ = [
    "PATH_STEP_M",
    "PATH_STEP_RAD",
    "TARGET_WORDS",
    "ArticulationTask",
    "T_world_part",
    "path_states",
    "resolve_target",
    "unit_vector",
]
