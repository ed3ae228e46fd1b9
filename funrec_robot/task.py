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


def _unit(name: str, v: npt.ArrayLike) -> FloatArray:
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
    handle_depth: float | None = None
    """Extent of the handle along the approach, m (it crosses the pads when the grasp is tilted); None if
    unknown (taken equal to the width)."""
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
        object.__setattr__(self, "axis_world", _unit("axis_world", self.axis_world))
        object.__setattr__(self, "approach_world", _unit("approach_world", self.approach_world))
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
            h = _unit("handle_axis_world", self.handle_axis_world)
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


def grasp_rotation(approach_world: npt.ArrayLike, handle_axis_world: npt.ArrayLike | None) -> FloatArray:
    """(3, 3) R_world_grasp with z = approach and x = handle axis (the fingers close along y = z cross x).

    For a knob (no handle axis) x is the projection of world -z, so the fingers close horizontally; for a
    vertical approach, world x.
    """
    z = _unit("approach", approach_world)
    if handle_axis_world is None:
        x = np.array([0.0, 0.0, -1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    else:
        x = np.asarray(handle_axis_world, dtype=np.float64)
    x = x - z * float(x @ z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def T_world_grasp_canonical(task: ArticulationTask, depth: float = 0.0, flip: bool = False) -> FloatArray:
    """(4, 4) grasp frame on the handle at state 0.

    Args:
        task: the task.
        depth: how far the grasp frame's origin sits before the contact point, against the approach, m.
        flip: turn the frame half a turn about its z (the gripper is symmetric; the planner tries both).
    """
    R = grasp_rotation(task.approach_world, task.handle_axis_world) if task.handle_axis_world is not None else knob_rotation(task)
    if flip:
        R = R @ np.diag([-1.0, -1.0, 1.0])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = task.p_world_contact - depth * task.approach_world
    return T


def T_world_grasp_path(task: ArticulationTask, states: npt.ArrayLike, T_world_grasp0: npt.ArrayLike) -> FloatArray:
    """(N, 4, 4) grasp frames carried by the part: ``T_world_part(s) @ T_world_grasp0``."""
    return T_world_part(task, states) @ np.asarray(T_world_grasp0, dtype=np.float64)


def grasp_free_axis(task: ArticulationTask) -> int:
    """Axis of the grasp frame about which the handle can turn between the finger pads: 0 (x, along a bar,
    which rolls between the pads) or 1 (y, the line through the two pad contacts on a knob)."""
    return 0 if task.handle_axis_world is not None else 1


def knob_rotation(task: ArticulationTask) -> FloatArray:
    """(3, 3) R_world_grasp for a knob: fingers close along the revolute axis (so the knob can turn about the
    finger axis as the part swings) or, for a prismatic part, horizontally (so the approach can pitch about
    the finger axis with only the narrow side of the fingers towards the front)."""
    z = task.approach_world
    y = task.axis_world if task.joint_type == "revolute" else np.cross([0.0, 0.0, 1.0], z)
    y = y - z * float(y @ z)
    if np.linalg.norm(y) < 0.1:
        y = np.cross(z, [1.0, 0.0, 0.0])
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def roll_to_hold(R_world_grasp: FloatArray, R_world_held: FloatArray, axis: int, max_roll: float) -> FloatArray:
    """(N,) roll about a grasp axis that keeps frames closest to a held orientation, clipped to +-max_roll.

    Maximises trace(R_held^T R Rot_axis(phi)) = tr(M) + sin(phi) tr(M [u]x) + (1 - cos(phi)) tr(M [u]x^2)
    with M = R_held^T R: phi* = atan2(tr(M [u]x), -tr(M [u]x^2)).

    Args:
        R_world_grasp: (N, 3, 3) grasp frames the part carries.
        R_world_held: (3, 3) orientation the gripper would rather keep.
        axis: 0, 1 or 2, the grasp axis of the roll.
        max_roll: largest roll either way, rad.
    """
    u = np.eye(3)[axis]
    ux = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    M = np.einsum("ji,njk->nik", R_world_held, R_world_grasp)
    c = np.einsum("nij,ji->n", M, ux)
    b = -np.einsum("nij,ji->n", M, ux @ ux)
    return np.clip(np.arctan2(c, b), -max_roll, max_roll)


def rotation_about_grasp_axis(axis: int, angles: npt.ArrayLike) -> FloatArray:
    """(N, 3, 3) rotations by ``angles`` (rad) about grasp axis 0, 1 or 2 (applied on the right of R_world_grasp)."""
    angles = np.atleast_1d(np.asarray(angles, dtype=np.float64))
    c, s = np.cos(angles), np.sin(angles)
    R = np.tile(np.eye(3), (len(angles), 1, 1))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[:, i, i], R[:, i, j], R[:, j, i], R[:, j, j] = c, -s, s, c
    return R


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
    "T_world_grasp_canonical",
    "T_world_grasp_path",
    "T_world_part",
    "grasp_free_axis",
    "grasp_rotation",
    "knob_rotation",
    "roll_to_hold",
    "rotation_about_grasp_axis",
    "path_states",
    "resolve_target",
]
