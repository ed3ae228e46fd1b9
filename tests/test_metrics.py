"""Known-answer and property tests of funrec.bench.metrics (FORMATS.md section 5)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from funrec.bench import metrics
from funrec.geometry.joints import joint_transforms
from funrec.geometry.transforms import invert_transform, make_transform, rotation_about_axis, transform_points

# Closed-form metrics on float64 inputs of order 1 agree with their known answers to ~1e-15;
# 1e-9 leaves room for arctan2 and square roots without hiding a real error.
ATOL = 1e-9

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
vectors = arrays(np.float64, (3,), elements=finite).filter(lambda v: np.linalg.norm(v) > 0.1)
rotvecs = arrays(np.float64, (3,), elements=st.floats(-3.0, 3.0))
translations = arrays(np.float64, (3,), elements=st.floats(-5.0, 5.0))
point_sets = arrays(np.float64, st.tuples(st.integers(3, 40), st.just(3)), elements=finite)


def _rigid(rotvec, translation):
    return make_transform(Rotation.from_rotvec(rotvec).as_matrix(), translation)


# ---- known answers ---------------------------------------------------------------------------


def test_axis_error_known_angles():
    axis_true = np.array([0.0, 0.0, 1.0])
    axis_pred = rotation_about_axis([1.0, 0.0, 0.0], np.radians(5.0)) @ axis_true
    assert metrics.axis_error_deg(axis_pred, axis_true) == pytest.approx(5.0, abs=ATOL)
    # A flipped axis is the same axis: min(e, 180 - e).
    assert metrics.axis_error_deg(-axis_pred, axis_true) == pytest.approx(5.0, abs=ATOL)
    assert metrics.axis_error_deg([1, 0, 0], [0, 1, 0]) == pytest.approx(90.0, abs=ATOL)
    assert metrics.axis_error_deg([0, 0, 2], [0, 0, 1]) == pytest.approx(0.0, abs=ATOL)
    assert metrics.axis_sign(-axis_pred, axis_true) == -1.0 and metrics.axis_sign(axis_pred, axis_true) == 1.0


def test_line_distance_known_lines():
    # x axis and a z-parallel line through (0, 2, 5): closest points (0,0,0) and (0,2,0).
    assert metrics.line_distance([0, 0, 0], [1, 0, 0], [0, 2, 5], [0, 0, 1]) == pytest.approx(2.0, abs=ATOL)
    # Skew at 45 degrees, offset 3 along z.
    assert metrics.line_distance([7, 0, 0], [1, 0, 0], [1, 1, 3], [1, 1, 0]) == pytest.approx(3.0, abs=ATOL)
    # Intersecting lines.
    assert metrics.line_distance([0, 0, 0], [1, 0, 0], [4, -1, 0], [0, 1, 0]) == pytest.approx(0.0, abs=ATOL)
    # Parallel (and anti-parallel) lines: distance between them, wherever the points sit.
    assert metrics.line_distance([0, 0, 0], [1, 0, 0], [9, 3, 4], [1, 0, 0]) == pytest.approx(5.0, abs=ATOL)
    assert metrics.line_distance([0, 0, 0], [1, 0, 0], [-9, 3, 4], [-2, 0, 0]) == pytest.approx(5.0, abs=ATOL)
    # Nearly parallel stays finite and close to the parallel answer near the points.
    assert metrics.line_distance([0, 0, 0], [1, 0, 0], [0, 3, 4], [1, 1e-12, 0]) == pytest.approx(5.0, abs=1e-6)


def test_state_error_known_answer_and_sign():
    states_true = np.array([0.2, 0.4, 0.7])
    # Canonical offset does not matter: only differences to the first common frame count.
    assert metrics.state_error(states_true + 5.0, states_true, 1.0) == pytest.approx(0.0, abs=ATOL)
    # A flipped axis with negated states is the same motion.
    assert metrics.state_error(-states_true, states_true, -1.0) == pytest.approx(0.0, abs=ATOL)
    # Errors of the relative states 0, 0.1, 0.2 -> mean 0.1.
    assert metrics.state_error([0.0, 0.3, 0.7], [0.0, 0.2, 0.5], 1.0) == pytest.approx(0.1, abs=ATOL)


def test_common_frames():
    frames, index_pred, index_true = metrics.common_frames([2, 3, 5, 8], [0, 1, 2, 3, 4, 5])
    assert frames.tolist() == [2, 3, 5] and index_pred.tolist() == [0, 1, 2] and index_true.tolist() == [2, 3, 5]


def test_auc_of_constant_error():
    for e in (0.0, 0.01, 0.037, 0.0999):
        assert metrics.auc_percent(np.full(7, e)) == pytest.approx(100.0 * (1.0 - e / 0.1), abs=ATOL)
    assert metrics.auc_percent([0.1, 0.5]) == 0.0
    assert metrics.auc_percent([0.0, 0.05]) == pytest.approx(75.0, abs=ATOL)


def test_add_known_answer_for_prismatic_overshoot():
    p_first = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    T_true = metrics.relative_part_poses("prismatic", [0, 0, 1], None, [0.0, 0.10])
    T_pred = metrics.relative_part_poses("prismatic", [0, 0, 1], None, [0.0, 0.12])
    np.testing.assert_allclose(metrics.add_errors(p_first, T_true, T_pred), [0.0, 0.02], atol=ATOL)
    np.testing.assert_allclose(T_true[0], np.eye(4), atol=ATOL)


def test_adds_is_symmetric_under_a_symmetry_of_the_points():
    # A ring of points about z: a wrong rotation about z by one ring step is invisible to ADD-S.
    angles = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(36)], axis=1)
    T_true = metrics.relative_part_poses("revolute", [0, 0, 1], [0, 0, 0], [0.0, 0.5])
    T_pred = metrics.relative_part_poses("revolute", [0, 0, 1], [0, 0, 0], [0.0, 0.5 + 2 * np.pi / 36])
    np.testing.assert_allclose(metrics.adds_errors(ring, T_true, T_pred), [0.0, 0.0], atol=1e-9)
    assert metrics.add_errors(ring, T_true, T_pred)[1] > 0.17  # chord of 10 degrees on a unit circle


def test_chamfer_of_parallel_grids():
    u, v = np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 11))
    grid = np.stack([u.ravel(), v.ravel(), np.zeros(121)], axis=1)
    assert metrics.chamfer_distance(grid, grid) == 0.0
    assert metrics.chamfer_distance(grid, grid + [0, 0, 0.03]) == pytest.approx(0.03, abs=ATOL)
    # Directed distances differ when one set is a subset: mean of 0 and of the other direction.
    half = grid[grid[:, 0] <= 0.5]
    expected = 0.5 * (0.0 + np.mean(np.clip(grid[:, 0] - 0.5, 0, None)))
    assert metrics.chamfer_distance(half, grid) == pytest.approx(expected, abs=ATOL)


def test_mask_iou_known_rectangles():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[0:4, 0:5] = True  # 20 px
    b[2:6, 0:5] = True  # 20 px, overlap 10 px
    assert metrics.mask_iou(a, b) == pytest.approx(10 / 30)
    assert metrics.mask_iou(a, a) == 1.0 and metrics.mask_iou(a, ~a) == 0.0
    assert metrics.mask_iou(np.zeros((3, 3)), np.zeros((3, 3))) == 1.0
    with pytest.raises(ValueError, match="masks must both be"):
        metrics.mask_iou(a, b[:5])


def test_camera_ate_known_offset():
    rng = np.random.default_rng(1)
    T_world_camera_true = np.stack([_rigid(rng.uniform(-1, 1, 3), rng.uniform(-2, 2, 3)) for _ in range(6)])
    # A different world frame alone gives zero ATE: both sides are mapped through frame 0.
    T_other_world = _rigid([0.3, -1.0, 2.0], [5.0, -1.0, 0.5])
    assert metrics.camera_ate(T_other_world @ T_world_camera_true, T_world_camera_true) == pytest.approx(0.0, abs=ATOL)
    # Every camera but the first displaced by 3 cm in the camera-0 frame: RMSE = 0.03 sqrt(5/6).
    T_camera0_camera = invert_transform(T_world_camera_true[0]) @ T_world_camera_true
    T_camera0_camera_pred = T_camera0_camera.copy()
    T_camera0_camera_pred[1:, :3, 3] += [0.0, 0.03, 0.0]
    ate = metrics.camera_ate(T_world_camera_true[0] @ T_camera0_camera_pred, T_world_camera_true)
    assert ate == pytest.approx(0.03 * np.sqrt(5 / 6), abs=ATOL)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="non-zero"):
        metrics.axis_error_deg([0, 0, 0], [1, 0, 0])
    with pytest.raises(ValueError, match="non-empty"):
        metrics.chamfer_distance(np.zeros((0, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="at least one"):
        metrics.auc_percent([])
    with pytest.raises(ValueError, match="equal-length"):
        metrics.state_error([0.0], [0.0, 1.0], 1.0)


# ---- properties ------------------------------------------------------------------------------


@settings(deadline=None, max_examples=50)
@given(a=vectors, b=vectors, rotvec=rotvecs)
def test_axis_error_is_rotation_invariant_and_symmetric(a, b, rotvec):
    R = Rotation.from_rotvec(rotvec).as_matrix()
    e = metrics.axis_error_deg(a, b)
    assert 0.0 <= e <= 90.0
    assert metrics.axis_error_deg(R @ a, R @ b) == pytest.approx(e, abs=1e-6)
    assert metrics.axis_error_deg(b, a) == pytest.approx(e, abs=1e-9)


@settings(deadline=None, max_examples=50)
@given(pa=translations, a=vectors, pb=translations, b=vectors, rotvec=rotvecs, t=translations)
def test_line_distance_is_rigid_invariant(pa, a, pb, b, rotvec, t):
    T = _rigid(rotvec, t)
    R = T[:3, :3]
    d = metrics.line_distance(pa, a, pb, b)
    moved = metrics.line_distance(transform_points(T, pa[None])[0], R @ a, transform_points(T, pb[None])[0], R @ b)
    # Coordinates up to ~10 m; 1e-6 m covers float64 rounding, also near the parallel switch.
    assert moved == pytest.approx(d, abs=1e-6)
    # The distance is at most the distance between the two given points.
    assert d <= np.linalg.norm(pa - pb) + 1e-9


@settings(deadline=None, max_examples=30)
@given(a=point_sets, b=point_sets, rotvec=rotvecs, t=translations)
def test_chamfer_is_rigid_invariant_and_symmetric(a, b, rotvec, t):
    T = _rigid(rotvec, t)
    d = metrics.chamfer_distance(a, b)
    assert metrics.chamfer_distance(transform_points(T, a), transform_points(T, b)) == pytest.approx(d, abs=1e-9)
    assert metrics.chamfer_distance(b, a) == pytest.approx(d, abs=1e-12)


@settings(deadline=None, max_examples=30)
@given(
    points=point_sets,
    axis=vectors,
    pivot=translations,
    states=arrays(np.float64, (5,), elements=st.floats(-1.5, 1.5)),
    state_noise=arrays(np.float64, (5,), elements=st.floats(-0.2, 0.2)),
    rotvec=rotvecs,
    t=translations,
)
def test_add_and_adds_are_rigid_invariant(points, axis, pivot, states, state_noise, rotvec, t):
    """Moving the whole scene (points, axis, pivot) by a rigid motion changes neither ADD nor ADD-S."""
    T_new_old = _rigid(rotvec, t)
    T_true = metrics.relative_part_poses("revolute", axis, pivot, states)
    T_pred = metrics.relative_part_poses("revolute", axis, pivot, states + state_noise)
    axis_new = T_new_old[:3, :3] @ axis
    pivot_new = transform_points(T_new_old, pivot[None])[0]
    T_true_new = metrics.relative_part_poses("revolute", axis_new, pivot_new, states)
    T_pred_new = metrics.relative_part_poses("revolute", axis_new, pivot_new, states + state_noise)
    # Relative poses conjugate: T_new = T_new_old T_old inv(T_new_old).
    np.testing.assert_allclose(T_true_new, T_new_old @ T_true @ invert_transform(T_new_old), atol=1e-9)
    points_new = transform_points(T_new_old, points)
    add = metrics.add_errors(points, T_true, T_pred)
    adds = metrics.adds_errors(points, T_true, T_pred)
    # Coordinates up to ~10 m after the motion; 1e-8 m covers the float64 products.
    np.testing.assert_allclose(metrics.add_errors(points_new, T_true_new, T_pred_new), add, atol=1e-8)
    np.testing.assert_allclose(metrics.adds_errors(points_new, T_true_new, T_pred_new), adds, atol=1e-8)
    assert np.all(adds <= add + 1e-12)  # the closest point is never farther than the corresponding one
    assert add[0] == pytest.approx(0.0, abs=1e-9)  # frame 0 is the reference


@settings(deadline=None, max_examples=30)
@given(
    rotvecs_cam=arrays(np.float64, (4, 3), elements=st.floats(-3.0, 3.0)),
    positions=arrays(np.float64, (4, 3), elements=st.floats(-3.0, 3.0)),
    noise=arrays(np.float64, (4, 3), elements=st.floats(-0.1, 0.1)),
    rotvec_a=rotvecs,
    t_a=translations,
    rotvec_b=rotvecs,
    t_b=translations,
)
def test_camera_ate_ignores_each_sides_world_frame(rotvecs_cam, positions, noise, rotvec_a, t_a, rotvec_b, t_b):
    T_true = make_transform(Rotation.from_rotvec(rotvecs_cam).as_matrix(), positions)
    T_pred = make_transform(T_true[:, :3, :3], positions + noise)
    ate = metrics.camera_ate(T_pred, T_true)
    moved = metrics.camera_ate(_rigid(rotvec_a, t_a) @ T_pred, _rigid(rotvec_b, t_b) @ T_true)
    assert moved == pytest.approx(ate, abs=1e-8)


@settings(deadline=None, max_examples=30)
@given(axis=vectors, pivot=translations, states=arrays(np.float64, (4,), elements=st.floats(-3.0, 3.0)))
def test_relative_poses_of_one_axis_compose(axis, pivot, states):
    """T(s_i) inv(T(s_0)) is the joint transform of s_i - s_0 (rotations about one axis commute)."""
    np.testing.assert_allclose(
        metrics.relative_part_poses("revolute", axis, pivot, states),
        joint_transforms("revolute", axis, pivot, states - states[0]),
        atol=1e-9,
    )
