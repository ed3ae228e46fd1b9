"""Snapping of estimated joint axes to gravity or to the floor plane, an export option: a cabinet
door hinge is vertical and a drawer runs level, and a few degrees of estimation error make
gravity move a passive part in a simulator."""

from __future__ import annotations

import numpy as np

from funrec.typed import FloatArray

UP = np.array([0.0, 0.0, 1.0])
"""Up in the export frame (gravity along -z)."""


def snap_axis(axis: FloatArray, tolerance_deg: float) -> tuple[FloatArray, str]:
    """Snap a joint axis to vertical or to the horizontal plane when it is within a tolerance.

    Args:
        axis: (3,) joint axis, frame with z up (need not be unit length).
        tolerance_deg: largest angle (degrees) to the vertical, or to the horizontal plane, that
            is snapped; 0 snaps nothing.

    Returns:
        The (3,) unit axis, and "vertical", "horizontal" or "none" for what was done. A vertical
        snap keeps the sign of the z component; a horizontal snap drops the z component.
    """
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    elevation_deg = float(np.degrees(np.arcsin(np.clip(abs(a @ UP), 0.0, 1.0))))
    if tolerance_deg > 0.0 and 90.0 - elevation_deg <= tolerance_deg:
        return np.sign(a[2]) * UP, "vertical"
    if tolerance_deg > 0.0 and elevation_deg <= tolerance_deg:
        level = a - (a @ UP) * UP
        return level / np.linalg.norm(level), "horizontal"
    return a, "none"


__all__ = ["snap_axis"]
