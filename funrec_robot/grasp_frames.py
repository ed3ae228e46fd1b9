"""The grasp frame on a task's handle: its axes (z = approach, x = handle axis), where it sits at the part's
canonical state and how the part carries it, and the rolls about its axes that keep a held orientation.

Pure geometry on an :class:`~funrec_robot.task.ArticulationTask`; the grasp itself (depth, tilt, opening) is
``grasp.py``'s.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from funrec.typed import FloatArray
from funrec_robot.task import ArticulationTask, T_world_part, unit_vector


def grasp_rotation(approach_world: npt.ArrayLike, handle_axis_world: npt.ArrayLike | None) -> FloatArray:
    """(3, 3) R_world_grasp with z = approach and x = handle axis (the fingers close along y = z cross x).

    For a knob (no handle axis) x is the projection of world -z, so the fingers close horizontally; for a
    vertical approach, world x.
    """
    z = unit_vector("approach", approach_world)
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


__all__ = [
    "T_world_grasp_canonical",
    "T_world_grasp_path",
    "grasp_free_axis",
    "grasp_rotation",
    "knob_rotation",
    "roll_to_hold",
    "rotation_about_grasp_axis",
]
