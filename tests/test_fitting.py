"""Known-answer and finite-difference tests of funrec.geometry.fitting."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.geometry.fitting import (
    _circle_residual_jacobian,
    fit_circles,
    fit_lines,
    fit_prismatic_motions,
    fit_revolute_motions,
    fit_rigid,
    ransac_rigid,
)
from funrec.geometry.joints import closest_point_on_axis_to_origin, joint_transforms
from funrec.geometry.transforms import make_transform

EXACT_ATOL = 1e-9
"""Noise-free fits are closed form or converge quadratically: only float64 round-off remains."""


def _random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _angle_up_to_sign(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), 0.0, 1.0)))


def test_fit_lines_known_answer_with_nan_gaps() -> None:
    rng = np.random.default_rng(0)
    direction = _random_unit(rng)
    p0 = rng.normal(size=3)
    t = np.linspace(-0.2, 0.3, 40)
    p_world = p0 + t[:, None] * direction
    weights = np.ones(40)
    weights[5:9] = 0.0
    p_world[5:9] = np.nan  # invisible samples carry NaN and zero weight
    centroid, fitted = fit_lines(p_world[None], weights[None])
    assert _angle_up_to_sign(fitted[0], direction) < EXACT_ATOL
    # The centroid lies on the true line.
    off = centroid[0] - p0
    assert np.linalg.norm(off - direction * (off @ direction)) < EXACT_ATOL


def test_fit_circles_known_answer_short_arc_and_batch() -> None:
    rng = np.random.default_rng(1)
    normals, centres, radii, batch = [], [], [], []
    for arc in (np.deg2rad(15.0), np.deg2rad(90.0), np.deg2rad(300.0)):
        n = _random_unit(rng)
        c = rng.normal(size=3)
        r = rng.uniform(0.1, 0.6)
        e1 = np.cross(n, _random_unit(rng))
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        phi = np.linspace(0.0, arc, 30)
        batch.append(c + r * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))
        normals.append(n)
        centres.append(c)
        radii.append(r)
    centre, normal, radius = fit_circles(np.stack(batch), np.ones((3, 30)))
    for k in range(3):
        assert _angle_up_to_sign(normal[k], normals[k]) < 1e-7
        np.testing.assert_allclose(centre[k], centres[k], atol=1e-7)
        np.testing.assert_allclose(radius[k], radii[k], atol=1e-7)


def test_fit_circles_noisy_accuracy() -> None:
    # 3 mm noise on a 0.4 m radius, 80 deg arc, 60 samples: the radius standard error is ~1 mm,
    # so 5 mm is a 5-sigma bound.
    rng = np.random.default_rng(2)
    n = np.array([0.0, 1.0, 0.0])
    phi = np.linspace(0.0, np.deg2rad(80.0), 60)
    p = np.stack([0.4 * np.cos(phi), np.zeros_like(phi), 0.4 * np.sin(phi)], axis=-1) + rng.normal(0, 0.003, (60, 3))
    centre, normal, radius = fit_circles(p[None], np.ones((1, 60)))
    assert abs(radius[0] - 0.4) < 0.005
    assert np.linalg.norm(centre[0]) < 0.01
    assert _angle_up_to_sign(normal[0], n) < np.deg2rad(2.0)


def test_circle_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    q = rng.normal(size=(2, 7, 2))
    centre = rng.normal(size=(2, 2)) * 0.1
    radius = np.array([0.8, 1.2])
    _, jac = _circle_residual_jacobian(q, centre, radius)
    h = 1e-6
    params = np.concatenate([centre, radius[:, None]], axis=-1)
    for k in range(3):
        dp = np.zeros(3)
        dp[k] = h
        plus = params + dp
        minus = params - dp
        r_plus, _ = _circle_residual_jacobian(q, plus[:, :2], plus[:, 2])
        r_minus, _ = _circle_residual_jacobian(q, minus[:, :2], minus[:, 2])
        # Central differences are O(h^2) ~ 1e-12 accurate; round-off ~ eps/h ~ 1e-10.
        np.testing.assert_allclose((r_plus - r_minus) / (2 * h), jac[..., k], atol=1e-8)


def test_fit_rigid_weighted_known_answer() -> None:
    rng = np.random.default_rng(4)
    T_dst_src = make_transform(Rotation.random(random_state=5).as_matrix(), rng.normal(size=3))
    p_src = rng.normal(size=(20, 3))
    p_dst = p_src @ T_dst_src[:3, :3].T + T_dst_src[:3, 3]
    weights = rng.uniform(0.1, 1.0, 20)
    # Zero-weight correspondences may be arbitrarily wrong.
    p_dst[:5] += rng.normal(size=(5, 3))
    weights[:5] = 0.0
    np.testing.assert_allclose(fit_rigid(p_src, p_dst, weights), T_dst_src, atol=EXACT_ATOL)


def test_fit_rigid_batched_and_reflection_safe() -> None:
    rng = np.random.default_rng(5)
    T = make_transform(Rotation.random(4, random_state=6).as_matrix(), rng.normal(size=(4, 3)))
    p_src = rng.normal(size=(4, 10, 3))
    p_dst = np.einsum("kij,knj->kni", T[:, :3, :3], p_src) + T[:, None, :3, 3]
    fitted = fit_rigid(p_src, p_dst, np.ones((4, 10)))
    np.testing.assert_allclose(fitted, T, atol=EXACT_ATOL)
    assert np.all(np.linalg.det(fitted[:, :3, :3]) > 0)


def test_ransac_rigid_forty_percent_outliers() -> None:
    rng = np.random.default_rng(6)
    T_dst_src = make_transform(Rotation.from_rotvec([0.1, -0.3, 0.2]).as_matrix(), [0.2, 0.0, -0.1])
    p_src = rng.uniform(-0.3, 0.3, (200, 3))
    p_dst = p_src @ T_dst_src[:3, :3].T + T_dst_src[:3, 3] + rng.normal(0, 0.002, (200, 3))
    outliers = rng.random(200) < 0.4
    p_dst[outliers] = rng.uniform(-0.5, 0.5, (int(outliers.sum()), 3))
    fit = ransac_rigid(p_src, p_dst, np.ones(200), 0.01, rng, iterations=128)
    # 2 mm noise on ~120 inliers with 0.25 m rms lever arm: rotation error ~ 0.002 / sqrt(120 * 0.06)
    # ~ 7e-4 rad per axis (1.2e-3 in norm), translation error ~ 0.2 mm; the bounds are ~4 sigma.
    dR = Rotation.from_matrix(fit.T_dst_src[:3, :3] @ T_dst_src[:3, :3].T).magnitude()
    assert dR < 5e-3
    assert np.linalg.norm(fit.T_dst_src[:3, 3] - T_dst_src[:3, 3]) < 5e-3
    assert np.mean(fit.inliers[~outliers]) > 0.95
    assert np.mean(fit.inliers[outliers]) < 0.05
    assert fit.rms_m < 0.01


def test_ransac_rigid_rejects_too_few() -> None:
    with pytest.raises(ValueError, match="at least 3"):
        ransac_rigid(np.zeros((2, 3)), np.zeros((2, 3)), np.ones(2), 0.01, np.random.default_rng(0))


@pytest.mark.parametrize("joint_type", ["revolute", "prismatic"])
def test_joint_fit_from_motions_known_answer(joint_type: str) -> None:
    rng = np.random.default_rng(7)
    axis = _random_unit(rng)
    pivot = closest_point_on_axis_to_origin(axis, rng.normal(size=3))
    states = np.linspace(0.0, 1.2 if joint_type == "revolute" else 0.3, 25)
    T = joint_transforms(joint_type, axis, pivot, states)
    weights = np.ones(25)
    centre = pivot + rng.normal(size=3) * 0.3
    if joint_type == "revolute":
        fitted_axis, fitted_pivot, fitted_states = fit_revolute_motions(T, weights, centre)
        np.testing.assert_allclose(fitted_pivot, pivot, atol=EXACT_ATOL)
    else:
        fitted_axis, fitted_states = fit_prismatic_motions(T, weights, centre)
    sign = np.sign(fitted_axis @ axis)
    np.testing.assert_allclose(sign * fitted_axis, axis, atol=EXACT_ATOL)
    np.testing.assert_allclose(sign * fitted_states, states, atol=EXACT_ATOL)
