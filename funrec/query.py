"""Query a twin folder's affordances: its parts with their contact points, and the grasp frame of
a part at any joint state (the canonical grasp moved by the part's joint)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.errors import FunrecError
from funrec.formats.affordances import AFFORDANCES_FILE, Affordances, read_affordances
from funrec.formats.twin import ArticulatedPart, read_articulation
from funrec.geometry.joints import joint_transform
from funrec.typed import FloatArray

RANGE_TOL = 1e-6
"""States this far (rad or m) outside a part's range still count as inside it (JSON round-off)."""


class QueryError(FunrecError):
    """A query names a part the twin does not have, a part without an affordance, or a state
    outside the part's range; the message lists what is available."""


@dataclass(frozen=True)
class PartRow:
    """One part of a twin as :func:`list_parts` reports it."""

    name: str
    """Part name, as in articulation.json."""
    joint_type: str
    """"revolute" or "prismatic"."""
    state_range: tuple[float, float]
    """Observed joint interval (lower, upper), radians or metres."""
    contact_point: FloatArray | None
    """(3,) contact point at the canonical state, world frame; None without an affordance."""
    holds: int
    """Number of demonstrated holds (0 without an affordance)."""
    note: str
    """Why the part has no affordance ("" when it has one)."""


def load_affordances(twin_dir: str | Path) -> Affordances:
    """Read ``affordances.json`` of a twin folder.

    Raises:
        FormatError: missing or malformed file (names the file and field).
    """
    return read_affordances(Path(twin_dir) / AFFORDANCES_FILE)


def list_parts(twin_dir: str | Path) -> tuple[PartRow, ...]:
    """Every articulated part of a twin, in articulation.json order, with its contact point.

    Raises:
        FormatError: articulation.json or affordances.json is missing or malformed.
    """
    articulation = read_articulation(Path(twin_dir) / "articulation.json")
    affordances = load_affordances(twin_dir)
    missing = dict(affordances.missing)
    rows = []
    for part in articulation.parts:
        affordance = affordances.part(part.name)
        if affordance is None:
            rows.append(PartRow(part.name, part.joint_type, part.state_range, None, 0, missing.get(part.name, "not in affordances.json")))
        else:
            rows.append(PartRow(part.name, part.joint_type, part.state_range, affordance.contact_point.copy(), len(affordance.interactions), ""))
    return tuple(rows)


def _part(twin_dir: Path, name: str) -> ArticulatedPart:
    articulation = read_articulation(twin_dir / "articulation.json")
    for part in articulation.parts:
        if part.name == name:
            return part
    raise QueryError(f"{twin_dir}: no part {name!r}; the twin has {[p.name for p in articulation.parts]}")


def grasp_frame(twin_dir: str | Path, part: str, state: float) -> FloatArray:
    """The grasp frame of a part at a joint state: ``joint_transform(state) @ T_world_grasp``.

    Args:
        twin_dir: the twin folder.
        part: part name, as in articulation.json.
        state: joint state from the canonical state, radians (revolute) or metres (prismatic),
            within the part's range.

    Returns:
        (4, 4) ``T_world_grasp`` at ``state``, the twin's world frame (z approach, x along the
        handle, y across it; see :mod:`funrec.affordance.contacts`).

    Raises:
        QueryError: unknown part, part without an affordance, or state outside the range.
        FormatError: a twin file is missing or malformed.
    """
    twin_dir = Path(twin_dir)
    articulated = _part(twin_dir, part)
    affordances = load_affordances(twin_dir)
    affordance = affordances.part(part)
    if affordance is None:
        reason = dict(affordances.missing).get(part, "not in affordances.json")
        held = [p.name for p in affordances.parts]
        raise QueryError(f"{twin_dir}: part {part!r} has no affordance ({reason}); parts with one: {held}")
    lower, upper = articulated.state_range
    if not math.isfinite(state) or not lower - RANGE_TOL <= state <= upper + RANGE_TOL:
        unit = "rad" if articulated.joint_type == "revolute" else "m"
        raise QueryError(f"{twin_dir}: state {state} of {part!r} is outside its range [{lower:.4g}, {upper:.4g}] {unit}")
    T = joint_transform(articulated.joint_type, articulated.axis_world, articulated.pivot_world, state)
    return T @ affordance.T_world_grasp


def format_parts(rows: tuple[PartRow, ...]) -> str:
    """A text table of :func:`list_parts` rows (for the CLI)."""
    header = ("part", "joint", "range", "holds", "contact point (world, m)")
    lines = []
    for row in rows:
        if row.joint_type == "revolute":
            span = f"{math.degrees(row.state_range[0]):.1f} .. {math.degrees(row.state_range[1]):.1f} deg"
        else:
            span = f"{row.state_range[0]:.3f} .. {row.state_range[1]:.3f} m"
        contact = "-  (" + row.note + ")" if row.contact_point is None else " ".join(f"{v:+.3f}" for v in row.contact_point)
        lines.append((row.name, row.joint_type, span, str(row.holds), contact))
    widths = [max(len(r[i]) for r in [header, *lines]) for i in range(len(header))]
    text = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in [header, *lines]]
    text.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(text) if rows else "\n".join(text + ["(no articulated parts)"])


def format_grasp(part: str, state: float, T_world_grasp: FloatArray) -> str:
    """The grasp frame of a part at a state as text: the 4x4, then position and axes (for the CLI)."""
    T = np.asarray(T_world_grasp, dtype=np.float64)
    lines = [f"{part} at state {state:g}: T_world_grasp (z approach, x along the handle, y across)"]
    lines += ["  " + " ".join(f"{v + 0.0:+.4f}" for v in row) for row in T]
    for label, column in (("position (m)", 3), ("approach (z)", 2), ("handle axis (x)", 0), ("finger axis (y)", 1)):
        lines.append(f"  {label + ':':17s}" + " ".join(f"{v + 0.0:+.4f}" for v in T[:3, column]))
    return "\n".join(lines)


def grasp_to_json(part: str, state: float, T_world_grasp: FloatArray) -> dict[str, Any]:
    """The grasp frame of a part at a state as a JSON-ready dictionary (world frame, metres)."""
    T = np.asarray(T_world_grasp, dtype=np.float64)
    return {
        "part": part,
        "state": float(state),
        "T_world_grasp": T.tolist(),
        "position": T[:3, 3].tolist(),
        "approach": T[:3, 2].tolist(),
        "handle_axis": T[:3, 0].tolist(),
        "finger_axis": T[:3, 1].tolist(),
    }


def parts_to_json(rows: tuple[PartRow, ...]) -> list[dict[str, Any]]:
    """:func:`list_parts` rows as JSON-ready dictionaries (``contact_point`` null without one)."""
    return [
        {
            "name": row.name,
            "joint_type": row.joint_type,
            "range": list(row.state_range),
            "range_unit": "rad" if row.joint_type == "revolute" else "m",
            "holds": row.holds,
            "contact_point": None if row.contact_point is None else row.contact_point.tolist(),
            "note": row.note,
        }
        for row in rows
    ]


def query_text(twin_dir: str | Path, part: str | None = None, state: float | None = None, as_json: bool = False) -> str:
    """What ``funrec query TWIN [--part NAME] [--state S] [--json]`` prints: the parts table, or
    the grasp frame of ``part`` at ``state`` (default 0, the canonical state); with ``as_json``
    the same as JSON (a list of parts, or one grasp object).

    Raises:
        QueryError: a state without a part, or see :func:`grasp_frame`.
    """
    if part is None:
        rows = list_parts(twin_dir)
        if state is not None:
            raise QueryError(f"a state ({state}) needs a part; the twin has {[r.name for r in rows]}")
        return json.dumps(parts_to_json(rows), indent=1) if as_json else format_parts(rows)
    state = 0.0 if state is None else float(state)
    T_world_grasp = grasp_frame(twin_dir, part, state)
    return json.dumps(grasp_to_json(part, state, T_world_grasp), indent=1) if as_json else format_grasp(part, state, T_world_grasp)


__all__ = [
    "RANGE_TOL",
    "PartRow",
    "QueryError",
    "format_grasp",
    "format_parts",
    "grasp_frame",
    "grasp_to_json",
    "parts_to_json",
    "list_parts",
    "load_affordances",
    "query_text",
]
