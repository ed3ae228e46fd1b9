"""articulation.json (FORMATS.md section 2): the functional model of a twin, read and written
with validation that names the file and the field."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from funrec.errors import FormatError
from funrec.geometry.joints import JOINT_TYPES, closest_point_on_axis_to_origin, joint_transforms
from funrec.typed import FloatArray, IntArray

TWIN_FORMAT = "funrec-twin/1"
"""Format tag written into articulation.json (docs/formats.md section 2, the scorers' contract).
The optional config.json beside it has a tag of its own (funrec-config/1, section 10): a new
file in the twin folder, not a change of articulation.json, which outside scorers read as /1."""
READABLE_TWIN_FORMATS = (TWIN_FORMAT,)
"""Format tags read_articulation accepts."""
AXIS_NORM_TOL = 1e-3
"""How far from unit length a stored axis may be before the file is rejected."""


@dataclass(frozen=True)
class ArticulatedPart:
    """One articulated part: its joint, its tracked states and where its files are."""

    name: str
    """Part name, e.g. "part_0"."""
    joint_type: str
    """"revolute" or "prismatic"."""
    axis_world: FloatArray
    """(3,) unit joint axis, world frame."""
    pivot_world: FloatArray | None
    """(3,) revolute pivot, world frame, the axis point closest to the origin; None if prismatic."""
    frames: IntArray
    """(F_k,) frame indices the part is tracked in, increasing."""
    states: FloatArray
    """(F_k,) joint state at each tracked frame from the canonical state (rad or m)."""
    state_range: tuple[float, float]
    """Feasible joint interval observed (lower, upper), rad or m."""
    mesh: str | None = None
    """Mesh path relative to the twin folder (canonical state, world frame)."""
    masks: str | None = None
    """Mask folder relative to the twin folder."""

    def __post_init__(self) -> None:
        if self.joint_type not in JOINT_TYPES:
            raise ValueError(f"joint_type must be one of {JOINT_TYPES}, got {self.joint_type!r}")
        if np.shape(self.axis_world) != (3,):
            raise ValueError(f"axis_world must be (3,), got {np.shape(self.axis_world)}")
        if self.joint_type == "revolute" and (self.pivot_world is None or np.shape(self.pivot_world) != (3,)):
            raise ValueError("a revolute part needs a (3,) pivot_world")
        if np.shape(self.frames) != np.shape(self.states) or np.ndim(self.frames) != 1:
            raise ValueError(f"frames {np.shape(self.frames)} and states {np.shape(self.states)} must be equal-length (F_k,)")

    def T_world_part(self) -> FloatArray:
        """(F_k, 4, 4) part pose at every tracked frame: canonical part -> posed part, world frame."""
        return joint_transforms(self.joint_type, self.axis_world, self.pivot_world, self.states)


@dataclass(frozen=True)
class TwinArticulation:
    """Contents of articulation.json."""

    frame_count: int
    """Number of input frames of the capture."""
    parts: tuple[ArticulatedPart, ...]
    """Articulated parts found (may be empty)."""
    static_mesh: str | None = "meshes/static.ply"
    """Static mesh path relative to the twin folder."""


def make_part(
    name: str,
    joint_type: str,
    axis_world: npt.ArrayLike,
    pivot_world: npt.ArrayLike | None,
    frames: npt.ArrayLike,
    states: npt.ArrayLike,
    state_range: tuple[float, float] | None = None,
    mesh: str | None = None,
    masks: str | None = None,
) -> ArticulatedPart:
    """Build an :class:`ArticulatedPart`, normalising the axis and moving the pivot to the
    axis point closest to the origin; the range defaults to the span of the states."""
    axis = np.asarray(axis_world, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    pivot = None
    if joint_type == "revolute":
        if pivot_world is None:
            raise ValueError("a revolute part needs a pivot")
        pivot = closest_point_on_axis_to_origin(axis, pivot_world)
    states_array = np.asarray(states, dtype=np.float64)
    if state_range is None:
        state_range = (float(states_array.min()), float(states_array.max())) if len(states_array) else (0.0, 0.0)
    return ArticulatedPart(
        name=name,
        joint_type=joint_type,
        axis_world=axis,
        pivot_world=pivot,
        frames=np.asarray(frames, dtype=np.int64),
        states=states_array,
        state_range=(float(state_range[0]), float(state_range[1])),
        mesh=mesh,
        masks=masks,
    )


def part_to_json(part: ArticulatedPart) -> dict[str, Any]:
    """The FORMATS.md dictionary of one part."""
    data: dict[str, Any] = {
        "name": part.name,
        "joint_type": part.joint_type,
        "axis": [float(v) for v in part.axis_world],
    }
    if part.joint_type == "revolute":
        assert part.pivot_world is not None
        data["pivot"] = [float(v) for v in part.pivot_world]
    data["frames"] = [int(v) for v in part.frames]
    data["states"] = [float(v) for v in part.states]
    data["range"] = [float(part.state_range[0]), float(part.state_range[1])]
    if part.mesh is not None:
        data["mesh"] = part.mesh
    if part.masks is not None:
        data["masks"] = part.masks
    return data


def _vector(path: Path, where: str, value: Any, length: int) -> FloatArray:
    array = np.asarray(value, dtype=object)
    if array.shape != (length,) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in array
    ):
        raise FormatError(path, f"{where} must be a list of {length} finite numbers, got {value!r}")
    return np.asarray(value, dtype=np.float64)


def _number_list(path: Path, where: str, value: Any) -> FloatArray:
    if not isinstance(value, list) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
    ):
        raise FormatError(path, f"{where} must be a list of finite numbers")
    return np.asarray(value, dtype=np.float64)


def part_from_json(path: Path, index: int, data: Any) -> ArticulatedPart:
    """Parse and validate one part dictionary; ``path`` and ``index`` name it in errors."""
    where = f"parts[{index}]"
    if not isinstance(data, dict):
        raise FormatError(path, f"{where} must be an object")
    for key in ("name", "joint_type", "axis", "frames", "states", "range"):
        if key not in data:
            raise FormatError(path, f"{where} is missing '{key}'")
    name = data["name"]
    if not isinstance(name, str) or not name:
        raise FormatError(path, f"{where}.name must be a non-empty string")
    joint_type = data["joint_type"]
    if joint_type not in JOINT_TYPES:
        raise FormatError(path, f"{where}.joint_type is {joint_type!r}, expected one of {list(JOINT_TYPES)}")
    axis = _vector(path, f"{where}.axis", data["axis"], 3)
    if abs(np.linalg.norm(axis) - 1.0) > AXIS_NORM_TOL:
        raise FormatError(path, f"{where}.axis must be a unit vector, has norm {np.linalg.norm(axis):.4f}")
    pivot = None
    if joint_type == "revolute":
        if "pivot" not in data:
            raise FormatError(path, f"{where} is revolute but has no 'pivot'")
        pivot = _vector(path, f"{where}.pivot", data["pivot"], 3)
    frames = _number_list(path, f"{where}.frames", data["frames"])
    if np.any(frames != np.round(frames)) or np.any(frames < 0) or np.any(np.diff(frames) <= 0):
        raise FormatError(path, f"{where}.frames must be increasing non-negative integers")
    states = _number_list(path, f"{where}.states", data["states"])
    if len(states) != len(frames):
        raise FormatError(path, f"{where}: {len(frames)} frames but {len(states)} states")
    state_range = _vector(path, f"{where}.range", data["range"], 2)
    if state_range[0] > state_range[1]:
        raise FormatError(path, f"{where}.range lower bound exceeds upper bound")
    for key in ("mesh", "masks"):
        if key in data and not isinstance(data[key], str):
            raise FormatError(path, f"{where}.{key} must be a relative path string")
    return ArticulatedPart(
        name=name,
        joint_type=joint_type,
        axis_world=axis / np.linalg.norm(axis),
        pivot_world=pivot,
        frames=frames.astype(np.int64),
        states=states,
        state_range=(float(state_range[0]), float(state_range[1])),
        mesh=data.get("mesh"),
        masks=data.get("masks"),
    )


def read_json_object(path: Path) -> dict[str, Any]:
    """Read a JSON file that must hold an object; FormatError names the file otherwise."""
    if not path.is_file():
        raise FormatError(path, "file is missing")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise FormatError(path, "expected a JSON object at the top level")
    return data


def read_articulation(path: str | Path) -> TwinArticulation:
    """Read and validate articulation.json (a file path, or a twin folder holding it)."""
    path = Path(path)
    if path.is_dir():
        path = path / "articulation.json"
    data = read_json_object(path)
    if data.get("format") not in READABLE_TWIN_FORMATS:
        raise FormatError(path, f"format is {data.get('format')!r}, expected one of {list(READABLE_TWIN_FORMATS)}")
    frame_count = data.get("frame_count")
    if not isinstance(frame_count, int) or isinstance(frame_count, bool) or frame_count <= 0:
        raise FormatError(path, f"frame_count must be a positive integer, got {frame_count!r}")
    parts_data = data.get("parts")
    if not isinstance(parts_data, list):
        raise FormatError(path, "parts must be a list (empty when nothing moved)")
    parts = tuple(part_from_json(path, k, p) for k, p in enumerate(parts_data))
    for part in parts:
        if len(part.frames) and part.frames[-1] >= frame_count:
            raise FormatError(path, f"part {part.name}: frame {part.frames[-1]} >= frame_count {frame_count}")
    names = [p.name for p in parts]
    if len(set(names)) != len(names):
        raise FormatError(path, f"part names repeat: {names}")
    static_mesh = data.get("static_mesh")
    if static_mesh is not None and not isinstance(static_mesh, str):
        raise FormatError(path, "static_mesh must be a relative path string")
    return TwinArticulation(frame_count=frame_count, parts=parts, static_mesh=static_mesh)


def articulation_to_json(twin: TwinArticulation) -> dict[str, Any]:
    """The FORMATS.md dictionary of articulation.json."""
    data: dict[str, Any] = {"format": TWIN_FORMAT, "frame_count": int(twin.frame_count)}
    if twin.static_mesh is not None:
        data["static_mesh"] = twin.static_mesh
    data["parts"] = [part_to_json(p) for p in twin.parts]
    return data


def write_articulation(path: str | Path, twin: TwinArticulation) -> None:
    """Write articulation.json."""
    Path(path).write_text(json.dumps(articulation_to_json(twin), indent=2) + "\n")


__all__ = [
    "READABLE_TWIN_FORMATS",
    "TWIN_FORMAT",
    "ArticulatedPart",
    "TwinArticulation",
    "articulation_to_json",
    "make_part",
    "part_from_json",
    "part_to_json",
    "read_articulation",
    "read_json_object",
    "write_articulation",
]
