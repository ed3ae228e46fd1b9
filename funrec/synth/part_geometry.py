"""A ground-truth part as the motion planner of a sequence sees it: joint, handle and front."""

from __future__ import annotations

from dataclasses import dataclass

from funrec.geometry.joints import joint_transforms
from funrec.typed import FloatArray


@dataclass(frozen=True)
class PartGeometry:
    """A ground-truth part at its canonical (closed) state, world frame."""

    joint_type: str
    """"revolute" or "prismatic"."""
    axis: FloatArray
    """(3,) unit joint axis; positive states open the part."""
    pivot: FloatArray | None
    """(3,) a point on the revolute axis; None for prismatic parts."""
    upper: float
    """Upper joint limit (radians or metres); the closed state is 0."""
    handle: FloatArray
    """(3,) handle centre."""
    grip_axis: FloatArray
    """(3,) unit direction of the handle bar (sign irrelevant)."""
    centre: FloatArray
    """(3,) centre of the front panel."""
    normal: FloatArray
    """(3,) unit outward normal of the front (towards the room), horizontal."""
    width: float
    """Width of the front, metres (door swing clearance)."""
    handle_standoff: float
    """Distance from the front surface to the handle centre, metres."""

    def poses(self, states: FloatArray) -> FloatArray:
        """(F, 4, 4) joint transforms (canonical -> posed, world frame) at (F,) states."""
        return joint_transforms(self.joint_type, self.axis, self.pivot, states)


__all__ = ["PartGeometry"]
