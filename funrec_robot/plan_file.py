"""A robot plan as data (:class:`Plan`) and as plan.json.

plan.json (``"format": "funrec-plan/1"``), all in the scene's world frame, SI units:

- ``joint_names``: actuated planning joints (base, then arm); ``gripper``: joints, open and closed commands,
  ``grasp``, the command while holding the handle, and ``release_from_grip`` (optional, default false): when
  true the commands from the release segment on are relative to the grip, see :func:`release_offset`.
- ``t`` (T,), ``q`` and ``qd`` (T, n): time stamps, positions and velocities at a fixed period;
  ``gripper_command`` (T,): the gripper actuator's command (or finger position without one).
- ``segments``: ``[{"label", "start", "end", "t_start", "t_end"}]`` sample index ranges (end inclusive);
  labels ``approach``, ``grasp``, ``actuate``, ``release``, ``retreat``.
- ``part_state`` (T,): the part's joint state the plan expects at each sample (the model's).
- ``task``: part, joint type, axis, pivot, range, start and target states, ``T_world_grasp_start`` (grasp
  frame on the handle when the gripper closes), ``p_world_grasp_target`` (where the plan leaves it),
  ``grasp_free_axis`` (0 = x, 1 = y: the axis of the grasp frame the handle may turn about between the pads).
- ``base_poses``: (B, 3) planned base stops x, y, yaw.
- ``provenance``: robot, scene and task files with sha256 hashes, target, planner settings, timings.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FormatError
from funrec.typed import FloatArray

PLAN_FORMAT = "funrec-plan/1"
"""Format tag written into and required from plan.json."""
SEGMENT_LABELS = ("approach", "grasp", "actuate", "release", "retreat")
"""Segment labels, in the order a plan runs them."""


@dataclass(frozen=True)
class Segment:
    """A labelled stretch of a plan."""

    label: str
    """One of ``SEGMENT_LABELS``."""
    start: int
    """First sample index."""
    end: int
    """Last sample index (inclusive)."""
    t_start: float
    """Time of the first sample, s."""
    t_end: float
    """Time of the last sample, s."""


@dataclass(frozen=True)
class Plan:
    """A timed whole-body plan for one interaction."""

    robot_name: str
    """Robot name."""
    joint_names: tuple[str, ...]
    """Planning joints (base then arm), the columns of ``q`` and ``qd``."""
    gripper_joints: tuple[str, ...]
    """Finger joints."""
    gripper_open: float
    """Open gripper command."""
    gripper_closed: float
    """Closed gripper command."""
    grasp_command: float
    """Gripper command while holding the handle (closed onto its thickness)."""
    t: FloatArray
    """(T,) sample times from 0, s."""
    q: FloatArray
    """(T, n) joint positions, m or rad."""
    qd: FloatArray
    """(T, n) joint velocities, m/s or rad/s."""
    gripper_command: FloatArray
    """(T,) gripper command."""
    part_state: FloatArray
    """(T,) joint state of the part the plan expects, rad or m."""
    segments: tuple[Segment, ...]
    """Labelled segments in time order."""
    part: str
    """Part name (its joint in the planning scene)."""
    joint_type: str
    """"revolute" or "prismatic"."""
    axis_world: FloatArray
    """(3,) the part's joint axis as planned."""
    pivot_world: FloatArray | None
    """(3,) revolute pivot as planned; None for prismatic."""
    state_range: tuple[float, float]
    """The part's joint range as planned."""
    start_state: float
    """Part state at the start, rad or m."""
    target_state: float
    """Part state the plan moves the part to, rad or m."""
    T_world_grasp_start: FloatArray
    """(4, 4) grasp frame on the handle when the gripper closes."""
    p_world_grasp_target: FloatArray
    """(3,) where the grasp point is when the part is at the target."""
    grasp_free_axis: int
    """Grasp-frame axis (0 x, 1 y) about which the handle may turn between the finger pads."""
    base_poses: FloatArray
    """(B, 3) planned base stops: x, y (m), yaw (rad)."""
    provenance: dict[str, Any] = field(default_factory=dict)
    """Files and hashes, target, settings, timings."""
    release_from_grip: bool = False
    """The handle's thickness was unknown when planning: an executor adds to every gripper command from the
    release segment on the difference between where the fingers stopped on the handle (measured when the
    release starts) and ``grasp_command`` (see :func:`release_offset`)."""

    def segment(self, label: str) -> Segment:
        """The first segment with this label."""
        for segment in self.segments:
            if segment.label == label:
                return segment
        raise KeyError(f"plan has no '{label}' segment; segments: {[s.label for s in self.segments]}")

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    @property
    def release_start(self) -> float:
        """Start of the first release segment, s (inf without one): where ``release_offset`` starts to apply."""
        return next((s.t_start for s in self.segments if s.label == "release"), float("inf"))


def release_offset(plan: Plan, measured_grip: float) -> float:
    """What an executor adds to the plan's gripper commands from the start of the release segment on.

    A gripper closed on a handle of unknown thickness stops where the handle is, not at the planned command;
    a release planned as "a few millimetres looser than the grasp command" would then still press on the
    handle. With ``plan.release_from_grip`` the release is taken relative to ``measured_grip``, the gripper
    position (in command units) when the release starts; otherwise the commands stand (offset 0).
    """
    return float(measured_grip - plan.grasp_command) if plan.release_from_grip else 0.0


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _round(array: FloatArray, digits: int = 7) -> list[Any]:
    return np.round(np.asarray(array, dtype=np.float64), digits).tolist()


def plan_to_json(plan: Plan) -> dict[str, Any]:
    """The plan.json dictionary."""
    return {
        "format": PLAN_FORMAT,
        "robot": plan.robot_name,
        "joint_names": list(plan.joint_names),
        "gripper": {
            "joints": list(plan.gripper_joints),
            "open": plan.gripper_open,
            "closed": plan.gripper_closed,
            "grasp": plan.grasp_command,
            "release_from_grip": plan.release_from_grip,
        },
        "t": _round(plan.t, 6),
        "q": _round(plan.q),
        "qd": _round(plan.qd),
        "gripper_command": _round(plan.gripper_command),
        "part_state": _round(plan.part_state),
        "segments": [
            {"label": s.label, "start": s.start, "end": s.end, "t_start": round(s.t_start, 6), "t_end": round(s.t_end, 6)}
            for s in plan.segments
        ],
        "task": {
            "part": plan.part,
            "joint_type": plan.joint_type,
            "axis": _round(plan.axis_world, 9),
            "pivot": None if plan.pivot_world is None else _round(plan.pivot_world, 9),
            "range": list(plan.state_range),
            "start_state": plan.start_state,
            "target_state": plan.target_state,
            "T_world_grasp_start": _round(plan.T_world_grasp_start, 9),
            "p_world_grasp_target": _round(plan.p_world_grasp_target, 9),
            "grasp_free_axis": plan.grasp_free_axis,
        },
        "base_poses": _round(plan.base_poses),
        "provenance": plan.provenance,
    }


def write_plan(path: str | Path, plan: Plan) -> Path:
    """Write plan.json (via a temporary file renamed into place)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(plan_to_json(plan), indent=1) + "\n")
    tmp.replace(path)
    return path


def _array(path: Path, data: dict[str, Any], key: str, shape: tuple[int, ...] | None = None) -> FloatArray:
    if key not in data:
        raise FormatError(path, f"missing '{key}'")
    try:
        array = np.asarray(data[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(path, f"'{key}' is not numeric") from None
    if shape is not None and (array.ndim != len(shape) or any(s >= 0 and a != s for a, s in zip(array.shape, shape))):
        raise FormatError(path, f"'{key}': shape {array.shape}, expected {shape} (-1 = any)")
    return array


def read_plan(path: str | Path) -> Plan:
    """Read and validate plan.json.

    Raises:
        FormatError: the file is not a funrec-plan/1 file or a field has the wrong shape; names the field.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise FormatError(path, f"cannot read plan: {exc}") from None
    return plan_from_json(data, path)


def plan_from_json(data: Any, path: str | Path = "<plan>") -> Plan:
    """Validate a plan.json dictionary (e.g. received over the network) and build the :class:`Plan`.

    Raises:
        FormatError: not a funrec-plan/1 dictionary or a field of the wrong shape; names ``path`` and the field.
    """
    path = Path(path)
    if not isinstance(data, dict) or data.get("format") != PLAN_FORMAT:
        raise FormatError(path, f"not a plan file: format {data.get('format') if isinstance(data, dict) else None!r}, expected {PLAN_FORMAT!r}")
    names = tuple(data.get("joint_names", ()))
    n = len(names)
    t = _array(path, data, "t", (-1,))
    T = len(t)
    task = data.get("task", {})
    gripper = data.get("gripper", {})
    q = _array(path, data, "q", (T, n))
    qd = _array(path, data, "qd", (T, n))
    gripper_command = _array(path, data, "gripper_command", (T,))
    part_state = _array(path, data, "part_state", (T,))
    try:
        segments = tuple(
            Segment(str(s["label"]), int(s["start"]), int(s["end"]), float(s["t_start"]), float(s["t_end"]))
            for s in data["segments"]
        )
        pivot = task.get("pivot")
        plan = Plan(
            robot_name=str(data.get("robot", "")),
            joint_names=names,
            gripper_joints=tuple(gripper["joints"]),
            gripper_open=float(gripper["open"]),
            gripper_closed=float(gripper["closed"]),
            grasp_command=float(gripper["grasp"]),
            t=t,
            q=q,
            qd=qd,
            gripper_command=gripper_command,
            part_state=part_state,
            segments=segments,
            part=str(task["part"]),
            joint_type=str(task["joint_type"]),
            axis_world=_array(path, task, "axis", (3,)),
            pivot_world=None if pivot is None else _array(path, task, "pivot", (3,)),
            state_range=(float(task["range"][0]), float(task["range"][1])),
            start_state=float(task["start_state"]),
            target_state=float(task["target_state"]),
            T_world_grasp_start=_array(path, task, "T_world_grasp_start", (4, 4)),
            p_world_grasp_target=_array(path, task, "p_world_grasp_target", (3,)),
            grasp_free_axis=int(task["grasp_free_axis"]),
            base_poses=_array(path, data, "base_poses", (-1, 3)),
            provenance=dict(data.get("provenance", {})),
            release_from_grip=bool(gripper.get("release_from_grip", False)),
        )
    except KeyError as exc:
        raise FormatError(path, f"missing field {exc}") from None
    except (TypeError, IndexError, ValueError) as exc:
        raise FormatError(path, f"malformed plan field: {exc!r}") from None
    unknown = [s.label for s in segments if s.label not in SEGMENT_LABELS]
    if unknown:
        raise FormatError(path, f"unknown segment labels {unknown}; expected {list(SEGMENT_LABELS)}")
    return plan


__all__ = [
    "PLAN_FORMAT",
    "SEGMENT_LABELS",
    "Plan",
    "Segment",
    "plan_from_json",
    "plan_to_json",
    "read_plan",
    "release_offset",
    "sha256_file",
    "write_plan",
]
