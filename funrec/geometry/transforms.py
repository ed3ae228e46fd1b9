"""Rigid transforms as (4, 4) float64 matrices; ``T_a_b`` maps coordinates in b to a."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from funrec.typed import FloatArray

ORTHONORMAL_ATOL = 1e-6
"""Tolerance on |R^T R - I| and |det R - 1| when validating a rotation block; float64
round-off after a few hundred compositions stays far below it."""


def check_transform(T: npt.ArrayLike, name: str = "T") -> FloatArray:
    """Convert to float64 and check that ``T`` is one rigid transform or a stack of them.

    Args:
        T: (..., 4, 4) homogeneous rigid transforms.
        name: name used in the error message.

    Returns:
        (..., 4, 4) float64 copy of ``T``.

    Raises:
        ValueError: the shape is wrong, a value is not finite, the last row is not
            [0, 0, 0, 1] or the rotation block is not a proper rotation.
    """
    T = np.array(T, dtype=np.float64)
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name} contains NaN or infinite values")
    if not np.allclose(T[..., 3, :], [0.0, 0.0, 0.0, 1.0], atol=ORTHONORMAL_ATOL):
        raise ValueError(f"{name} last row must be [0, 0, 0, 1], got {T[..., 3, :]}")
    R = T[..., :3, :3]
    RtR = np.swapaxes(R, -1, -2) @ R
    if not np.allclose(RtR, np.eye(3), atol=ORTHONORMAL_ATOL) or not np.allclose(
        np.linalg.det(R), 1.0, atol=ORTHONORMAL_ATOL
    ):
        raise ValueError(f"{name} rotation block is not a proper rotation matrix")
    return T


def make_transform(R: npt.ArrayLike, t: npt.ArrayLike) -> FloatArray:
    """Stack a rotation and a translation into homogeneous transforms.

    Args:
        R: (..., 3, 3) rotation ``R_a_b``.
        t: (..., 3) translation ``t_a_b`` (origin of b in frame a).

    Returns:
        (..., 4, 4) ``T_a_b``.
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros((*batch, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T_a_b: npt.ArrayLike) -> FloatArray:
    """Invert rigid transforms in closed form.

    Args:
        T_a_b: (..., 4, 4) rigid transforms.

    Returns:
        (..., 4, 4) ``T_b_a``.
    """
    T_a_b = np.asarray(T_a_b, dtype=np.float64)
    R_b_a = np.swapaxes(T_a_b[..., :3, :3], -1, -2)
    t_b_a = -np.einsum("...ij,...j->...i", R_b_a, T_a_b[..., :3, 3])
    return make_transform(R_b_a, t_b_a)


def transform_points(T_a_b: npt.ArrayLike, p_b: npt.ArrayLike) -> FloatArray:
    """Apply a rigid transform to points.

    Args:
        T_a_b: (4, 4) transform, or (N, 4, 4) with one transform per point.
        p_b: (N, 3) points in frame b.

    Returns:
        (N, 3) points ``p_a``.
    """
    T_a_b = np.asarray(T_a_b, dtype=np.float64)
    p_b = np.asarray(p_b, dtype=np.float64)
    if T_a_b.ndim == 2:
        return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]
    return np.einsum("nij,nj->ni", T_a_b[:, :3, :3], p_b) + T_a_b[:, :3, 3]


def pose_difference(T_a: npt.ArrayLike, T_b: npt.ArrayLike) -> tuple[float, float]:
    """(translation metres, rotation angle radians) of ``T_a^-1 T_b``: how far two poses of one
    frame are apart."""
    T = invert_transform(T_a) @ np.asarray(T_b, dtype=np.float64)
    cos = float(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    return float(np.linalg.norm(T[:3, 3])), math.acos(cos)


def rotation_about_axis(axis: npt.ArrayLike, angle: npt.ArrayLike) -> FloatArray:
    """Rotation matrices about a unit axis (right-hand rule).

    Args:
        axis: (3,) axis; normalised here.
        angle: scalar or (F,) angles in radians.

    Returns:
        (3, 3) or (F, 3, 3) rotation matrices.
    """
    axis = np.asarray(axis, dtype=np.float64)
    norm = np.linalg.norm(axis)
    if not norm > 0.0:
        raise ValueError(f"rotation axis must be non-zero, got {axis}")
    angle = np.asarray(angle, dtype=np.float64)
    rotvec = (axis / norm) * angle[..., None]
    return Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_matrix().reshape(*angle.shape, 3, 3)


__all__ = [
    "check_transform",
    "invert_transform",
    "make_transform",
    "pose_difference",
    "rotation_about_axis",
    "transform_points",
]
