"""Joint transforms of FORMATS.md section 2 (paper equations for prismatic and revolute)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from funrec.geometry.transforms import make_transform, rotation_about_axis
from funrec.typed import FloatArray

JOINT_TYPES = ("revolute", "prismatic")
"""The articulation types FunREC models."""


def closest_point_on_axis_to_origin(axis: npt.ArrayLike, point: npt.ArrayLike) -> FloatArray:
    """The point of the line through ``point`` along ``axis`` that is closest to the origin.

    This is the canonical pivot of FORMATS.md (``a^T p = 0``).

    Args:
        axis: (3,) direction (any length > 0).
        point: (3,) any point on the line.

    Returns:
        (3,) pivot ``p`` with ``a^T p = 0``.
    """
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    point = np.asarray(point, dtype=np.float64)
    return point - axis * float(axis @ point)


def joint_transforms(
    joint_type: str,
    axis: npt.ArrayLike,
    pivot: npt.ArrayLike | None,
    states: npt.ArrayLike,
) -> FloatArray:
    """Part poses for a sequence of joint states.

    ``T = [I, s a; 0, 1]`` (prismatic) or ``T = [R(a, s), (I - R(a, s)) p; 0, 1]``
    (revolute). Each maps the canonical part (state 0) to where it is at state ``s``,
    both in the same (world) frame.

    Args:
        joint_type: "revolute" or "prismatic".
        axis: (3,) joint axis in the world frame; normalised here.
        pivot: (3,) a point on the revolute axis in the world frame; ignored for
            prismatic joints (may be None).
        states: (F,) joint states, radians or metres.

    Returns:
        (F, 4, 4) transforms ``T_world_world`` from canonical to posed part.
    """
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    states = np.atleast_1d(np.asarray(states, dtype=np.float64))
    if joint_type == "prismatic":
        R = np.broadcast_to(np.eye(3), (len(states), 3, 3))
        return make_transform(R, states[:, None] * axis)
    if joint_type == "revolute":
        if pivot is None:
            raise ValueError("a revolute joint needs a pivot")
        p = np.asarray(pivot, dtype=np.float64)
        R = rotation_about_axis(axis, states)
        t = p - R @ p
        return make_transform(R, t)
    raise ValueError(f"unknown joint type {joint_type!r}; expected one of {JOINT_TYPES}")


def joint_transform(
    joint_type: str, axis: npt.ArrayLike, pivot: npt.ArrayLike | None, state: float
) -> FloatArray:
    """Single-state version of :func:`joint_transforms`; returns (4, 4)."""
    return joint_transforms(joint_type, axis, pivot, [state])[0]


__all__ = ["JOINT_TYPES", "closest_point_on_axis_to_origin", "joint_transform", "joint_transforms"]
