"""affordances.json: write and read (validated) the affordances of a twin; the layout is given in
:mod:`funrec.affordance.contacts`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FormatError
from funrec.formats.twin import read_json_object
from funrec.geometry.joints import JOINT_TYPES
from funrec.geometry.transforms import check_transform
from funrec.typed import FloatArray, IntArray

AFFORDANCES_FORMAT = "funrec-affordances/1"
"""Format tag written into and required from affordances.json."""
AFFORDANCES_FILE = "affordances.json"
"""File name of the affordances in a twin folder."""
TWIN_HAND_MASKS = "masks/hand"
"""Folder of a twin (relative) holding detected hand masks, one ``<frame:06d>.png`` per frame
(8-bit, >0 = hand), the layout of a capture's masks/hand/; scored by ``funrec eval``."""
HAND_SOURCES = ("capture", "detected")
"""Where a :class:`HandMasks` came from: the capture's masks/hand/ files or :func:`detect_hands`."""


@dataclass(frozen=True)
class Interaction:
    """One hold of a part: the demonstrated joint trajectory."""

    frames: IntArray
    """(n,) consecutive frame indices of the hold."""
    times_s: FloatArray
    """(n,) time of each frame from the capture start, seconds (frame / fps)."""
    states: FloatArray
    """(n,) joint state of the part at each frame, radians or metres from the canonical state."""

    def __post_init__(self) -> None:
        n = len(self.frames)
        if n == 0 or np.shape(self.frames) != (n,) or np.shape(self.times_s) != (n,) or np.shape(self.states) != (n,):
            raise ValueError(f"frames, times_s and states must be equal-length non-empty (n,), got "
                             f"{np.shape(self.frames)}, {np.shape(self.times_s)}, {np.shape(self.states)}")


@dataclass(frozen=True)
class PartAffordance:
    """Where and how the hand held one part (world frame, part at its canonical state)."""

    name: str
    """Part name, as in articulation.json."""
    joint_type: str
    """"revolute" or "prismatic"."""
    contact_point: FloatArray
    """(3,) robust centre of the contact, world frame at the canonical state, metres."""
    T_world_grasp: FloatArray
    """(4, 4) grasp frame at the canonical state (z approach, x along the handle, y = z x x)."""
    handle_found: bool
    """True when the contact point was snapped to protruding handle geometry."""
    interactions: tuple[Interaction, ...]
    """Holds in time order (at least one)."""
    region_points: FloatArray
    """(M, 3) part surface points in contact, world frame at the canonical state."""
    region_weights: FloatArray
    """(M,) contact weight of each region point in (0, 1]."""
    path_states: FloatArray
    """(S,) joint states sampled over the part's range, radians or metres."""
    path_points: FloatArray
    """(S, 3) the contact point at each of ``path_states``, world frame."""

    def __post_init__(self) -> None:
        if self.joint_type not in JOINT_TYPES:
            raise ValueError(f"joint_type must be one of {JOINT_TYPES}, got {self.joint_type!r}")
        if np.shape(self.contact_point) != (3,) or np.shape(self.T_world_grasp) != (4, 4):
            raise ValueError(f"contact_point must be (3,) and T_world_grasp (4, 4), got {np.shape(self.contact_point)}, {np.shape(self.T_world_grasp)}")
        M, S = len(self.region_points), len(self.path_states)
        if np.shape(self.region_points) != (M, 3) or np.shape(self.region_weights) != (M,):
            raise ValueError(f"region_points must be (M, 3) and region_weights (M,), got {np.shape(self.region_points)}, {np.shape(self.region_weights)}")
        if np.shape(self.path_states) != (S,) or np.shape(self.path_points) != (S, 3):
            raise ValueError(f"path_states must be (S,) and path_points (S, 3), got {np.shape(self.path_states)}, {np.shape(self.path_points)}")
        if not self.interactions:
            raise ValueError("a part affordance needs at least one interaction")


@dataclass(frozen=True)
class Affordances:
    """Hand-contact affordances of a twin (contents of affordances.json)."""

    parts: tuple[PartAffordance, ...]
    """One entry per part the hand was seen holding while it moved."""
    missing: tuple[tuple[str, str], ...]
    """(part name, reason) of each articulated part without an affordance."""
    hand_source: str
    """"capture" or "detected": where the hand masks came from."""
    fps: float
    """Capture frame rate, frames per second (times_s = frame / fps)."""

    def __post_init__(self) -> None:
        if self.hand_source not in HAND_SOURCES:
            raise ValueError(f"hand_source must be one of {HAND_SOURCES}, got {self.hand_source!r}")
        names = [p.name for p in self.parts] + [name for name, _ in self.missing]
        if len(set(names)) != len(names):
            raise ValueError(f"part names repeat: {names}")

    def part(self, name: str) -> PartAffordance | None:
        """The affordance of part ``name``, or None if it has none."""
        return next((p for p in self.parts if p.name == name), None)




def affordances_to_json(affordances: Affordances) -> dict[str, Any]:
    """The affordances.json dictionary (layout: :mod:`funrec.affordance.contacts`)."""

    def rows(a: FloatArray) -> list[Any]:
        return np.asarray(a, dtype=np.float64).tolist()

    parts = []
    for p in affordances.parts:
        parts.append({
            "name": p.name,
            "joint_type": p.joint_type,
            "contact_point": rows(p.contact_point),
            "T_world_grasp": rows(p.T_world_grasp),
            "handle_found": bool(p.handle_found),
            "interactions": [
                {"frames": [int(f) for f in i.frames], "times_s": rows(i.times_s), "states": rows(i.states)} for i in p.interactions
            ],
            "contact_region": {"points": rows(p.region_points), "weights": rows(p.region_weights)},
            "contact_path": {"states": rows(p.path_states), "points": rows(p.path_points)},
        })
    return {
        "format": AFFORDANCES_FORMAT,
        "hand_source": affordances.hand_source,
        "fps": float(affordances.fps),
        "parts": parts,
        "missing": [{"name": name, "reason": reason} for name, reason in affordances.missing],
    }


def write_affordances(path: str | Path, affordances: Affordances) -> None:
    """Write affordances.json (a file path, or a twin folder to write it into)."""
    path = Path(path)
    if path.is_dir():
        path = path / AFFORDANCES_FILE
    path.write_text(json.dumps(affordances_to_json(affordances), indent=1) + "\n")


class _Reader:
    """Typed field access that raises FormatError naming the file and field (private)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> FormatError:
        return FormatError(self.path, f"{where} {problem}")

    def get(self, data: dict[str, Any], key: str, where: str) -> Any:
        if key not in data:
            raise self.fail(where, f"is missing '{key}'")
        return data[key]

    def array(self, value: Any, where: str, shape: tuple[int | None, ...]) -> FloatArray:
        """Finite float array of ``shape`` (None: any length)."""
        try:
            a = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.fail(where, f"must be an array of numbers of shape {_shape_text(shape)}") from None
        if _contains_bool(value):
            raise self.fail(where, "must hold numbers, not booleans")
        if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
            raise self.fail(where, f"has shape {a.shape}, expected {_shape_text(shape)}")
        if not np.all(np.isfinite(a)):
            raise self.fail(where, "contains NaN or infinite values")
        return a


def _shape_text(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def _contains_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    return isinstance(value, list) and any(_contains_bool(v) for v in value)


def _interaction_from_json(r: _Reader, data: Any, where: str) -> Interaction:
    if not isinstance(data, dict):
        raise r.fail(where, "must be an object")
    frames = r.array(r.get(data, "frames", where), f"{where}.frames", (None,))
    if len(frames) == 0 or np.any(frames != np.round(frames)) or np.any(frames < 0) or np.any(np.diff(frames) <= 0):
        raise r.fail(f"{where}.frames", "must be non-empty increasing non-negative integers")
    times = r.array(r.get(data, "times_s", where), f"{where}.times_s", (len(frames),))
    states = r.array(r.get(data, "states", where), f"{where}.states", (len(frames),))
    return Interaction(frames.astype(np.int64), times, states)


def _part_from_json(r: _Reader, data: Any, where: str) -> PartAffordance:
    if not isinstance(data, dict):
        raise r.fail(where, "must be an object")
    name = r.get(data, "name", where)
    if not isinstance(name, str) or not name:
        raise r.fail(f"{where}.name", "must be a non-empty string")
    joint_type = r.get(data, "joint_type", where)
    if joint_type not in JOINT_TYPES:
        raise r.fail(f"{where}.joint_type", f"is {joint_type!r}, expected one of {list(JOINT_TYPES)}")
    contact = r.array(r.get(data, "contact_point", where), f"{where}.contact_point", (3,))
    try:
        T_world_grasp = check_transform(r.array(r.get(data, "T_world_grasp", where), f"{where}.T_world_grasp", (4, 4)), "T_world_grasp")
    except ValueError as exc:
        raise r.fail(f"{where}.T_world_grasp", f"is not a rigid transform ({exc})") from None
    handle_found = r.get(data, "handle_found", where)
    if not isinstance(handle_found, bool):
        raise r.fail(f"{where}.handle_found", "must be true or false")
    interactions_data = r.get(data, "interactions", where)
    if not isinstance(interactions_data, list) or not interactions_data:
        raise r.fail(f"{where}.interactions", "must be a non-empty list")
    interactions = tuple(_interaction_from_json(r, d, f"{where}.interactions[{i}]") for i, d in enumerate(interactions_data))
    region = r.get(data, "contact_region", where)
    path = r.get(data, "contact_path", where)
    if not isinstance(region, dict) or not isinstance(path, dict):
        raise r.fail(where, "contact_region and contact_path must be objects")
    region_points = r.array(r.get(region, "points", f"{where}.contact_region"), f"{where}.contact_region.points", (None, 3)) if region.get("points") else np.zeros((0, 3))
    region_weights = r.array(r.get(region, "weights", f"{where}.contact_region"), f"{where}.contact_region.weights", (len(region_points),))
    if np.any(region_weights <= 0) or np.any(region_weights > 1):
        raise r.fail(f"{where}.contact_region.weights", "must lie in (0, 1]")
    path_states = r.array(r.get(path, "states", f"{where}.contact_path"), f"{where}.contact_path.states", (None,))
    path_points = r.array(r.get(path, "points", f"{where}.contact_path"), f"{where}.contact_path.points", (len(path_states), 3)) if len(path_states) else np.zeros((0, 3))
    return PartAffordance(name, joint_type, contact, T_world_grasp, handle_found, interactions, region_points, region_weights, path_states, path_points)


def read_affordances(path: str | Path) -> Affordances:
    """Read and validate affordances.json (a file path, or a twin folder holding it).

    Raises:
        FormatError: missing file, bad JSON, wrong format tag, or a field of the wrong type,
            shape or value; the message names the file and the field.
    """
    path = Path(path)
    if path.is_dir():
        path = path / AFFORDANCES_FILE
    data = read_json_object(path)
    r = _Reader(path)
    if data.get("format") != AFFORDANCES_FORMAT:
        raise r.fail("format", f"is {data.get('format')!r}, expected {AFFORDANCES_FORMAT!r}")
    hand_source = r.get(data, "hand_source", "the file")
    if hand_source not in HAND_SOURCES:
        raise r.fail("hand_source", f"is {hand_source!r}, expected one of {list(HAND_SOURCES)}")
    fps = r.get(data, "fps", "the file")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps) or fps <= 0:
        raise r.fail("fps", f"must be a positive number, got {fps!r}")
    parts_data = r.get(data, "parts", "the file")
    missing_data = r.get(data, "missing", "the file")
    if not isinstance(parts_data, list) or not isinstance(missing_data, list):
        raise r.fail("parts and missing", "must be lists")
    parts = tuple(_part_from_json(r, d, f"parts[{k}]") for k, d in enumerate(parts_data))
    missing = []
    for k, d in enumerate(missing_data):
        if not isinstance(d, dict) or not isinstance(d.get("name"), str) or not isinstance(d.get("reason"), str):
            raise r.fail(f"missing[{k}]", "must be an object with string 'name' and 'reason'")
        missing.append((d["name"], d["reason"]))
    try:
        return Affordances(parts, tuple(missing), hand_source, float(fps))
    except ValueError as exc:
        raise r.fail("parts", str(exc)) from None


__all__ = ["AFFORDANCES_FILE", "AFFORDANCES_FORMAT", "HAND_SOURCES", "TWIN_HAND_MASKS", "Affordances", "Interaction", "PartAffordance", "affordances_to_json", "read_affordances", "write_affordances"]
