"""Transforms, cameras and joint transforms: round trips and known answers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from funrec.geometry import (
    backproject,
    check_transform,
    closest_point_on_axis_to_origin,
    invert_transform,
    joint_transform,
    joint_transforms,
    make_transform,
    project,
    rotation_about_axis,
    transform_points,
)

# Float64 round-off through a handful of 4x4 products stays below 1e-12 for unit-scale
# inputs; 1e-9 leaves room for the metre-scale translations used here.
ATOL = 1e-9

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
vectors = arrays(np.float64, 3, elements=finite)
unit_quats = arrays(np.float64, 4, elements=st.floats(-1.0, 1.0)).filter(lambda q: np.linalg.norm(q) > 0.1)


def _transform(quat_xyzw: np.ndarray, t: np.ndarray) -> np.ndarray:
    return make_transform(Rotation.from_quat(quat_xyzw).as_matrix(), t)


@settings(deadline=None, max_examples=50)
@given(unit_quats, vectors)
def test_transform_times_inverse_is_identity(quat_xyzw: np.ndarray, t: np.ndarray) -> None:
    T_a_b = _transform(quat_xyzw, t)
    np.testing.assert_allclose(T_a_b @ invert_transform(T_a_b), np.eye(4), atol=ATOL)
    np.testing.assert_allclose(check_transform(T_a_b), T_a_b)


@settings(deadline=None, max_examples=50)
@given(arrays(np.float64, (5, 2), elements=st.floats(0.0, 63.0)), arrays(np.float64, 5, elements=st.floats(0.3, 8.0)))
def test_project_then_backproject(uv: np.ndarray, z: np.ndarray) -> None:
    K = np.array([[50.0, 0, 31.5], [0, 52.0, 23.5], [0, 0, 1]])
    depth_m = np.zeros((48, 64))
    cols, rows = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int) % 48
    depth_m[rows, cols] = z
    p_camera = backproject(depth_m, K).reshape(48, 64, 3)[rows, cols]
    uv_back, z_back = project(p_camera, K)
    valid = depth_m[rows, cols] > 0
    np.testing.assert_allclose(uv_back[valid], np.stack([cols, rows], 1)[valid], atol=1e-9)
    np.testing.assert_allclose(z_back[valid], depth_m[rows, cols][valid], atol=1e-12)


def test_backproject_marks_missing_depth_nan() -> None:
    depth_m = np.array([[0.0, 2.0]])
    p_camera = backproject(depth_m, np.eye(3))
    assert np.all(np.isnan(p_camera[0])) and np.allclose(p_camera[1], [2.0, 0.0, 2.0])


def test_known_rotation_moves_known_point() -> None:
    R_world_door = rotation_about_axis([0, 0, 1], np.pi / 2)
    p_world = transform_points(make_transform(R_world_door, [1.0, 0, 0]), np.array([[1.0, 0, 0]]))
    np.testing.assert_allclose(p_world, [[1.0, 1.0, 0.0]], atol=ATOL)


@settings(deadline=None, max_examples=50)
@given(vectors.filter(lambda a: np.linalg.norm(a) > 0.1), vectors, st.floats(-3.0, 3.0), st.sampled_from(["revolute", "prismatic"]))
def test_joint_moved_by_s_then_minus_s(axis: np.ndarray, pivot: np.ndarray, s: float, joint_type: str) -> None:
    T_forward = joint_transform(joint_type, axis, pivot, s)
    T_back = joint_transform(joint_type, axis, pivot, -s)
    np.testing.assert_allclose(T_back @ T_forward, np.eye(4), atol=ATOL)


def test_revolute_joint_fixes_its_axis_and_rotates_other_points() -> None:
    axis, pivot = np.array([0.0, 0.0, 1.0]), np.array([0.5, 0.2, 0.0])
    T = joint_transforms("revolute", axis, pivot, [0.0, np.pi])
    np.testing.assert_allclose(T[0], np.eye(4), atol=ATOL)
    on_axis = pivot + 0.7 * axis
    np.testing.assert_allclose(transform_points(T[1], on_axis[None]), on_axis[None], atol=ATOL)
    np.testing.assert_allclose(transform_points(T[1], np.array([[1.5, 0.2, 0.0]])), [[-0.5, 0.2, 0.0]], atol=ATOL)


def test_prismatic_joint_translates_along_axis() -> None:
    T = joint_transform("prismatic", [0, 2.0, 0], None, 0.3)
    np.testing.assert_allclose(T[:3, 3], [0, 0.3, 0])


def test_pivot_closest_to_origin() -> None:
    pivot = closest_point_on_axis_to_origin([0, 0, 2.0], [1.0, 2.0, 5.0])
    np.testing.assert_allclose(pivot, [1.0, 2.0, 0.0])


def test_check_transform_quotes_bad_shape() -> None:
    with pytest.raises(ValueError, match=r"T_world_camera must have shape \(\.\.\., 4, 4\), got \(3, 4\)"):
        check_transform(np.zeros((3, 4)), "T_world_camera")
    with pytest.raises(ValueError, match="not a proper rotation"):
        check_transform(np.diag([1.0, 1.0, -1.0, 1.0]))
