"""Tests of funrec.camera.features: sample_depth (the robust window depth against a direct nanmedian),
rigid_ransac (per-correspondence tolerances, outliers), the image noise estimate and the corners' SNR."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from funrec.camera.features import corner_snr, image_noise_sigma, rigid_ransac, sample_depth, visible_offset_px
from funrec.geometry.fitting import RigidFit
from funrec.geometry.transforms import make_transform


def _reference(depth_m: np.ndarray, uv: np.ndarray, window_px: int, max_spread: float) -> np.ndarray:
    """Window median of the valid readings with np.nanmedian, point by point (the definition)."""
    H, W = depth_m.shape
    half = window_px // 2
    out = np.full(len(uv), np.nan)
    for i, (u, v) in enumerate(np.rint(uv).astype(int)):
        if not (half <= u < W - half and half <= v < H - half):
            continue
        patch = depth_m[v - half : v + half + 1, u - half : u + half + 1].ravel()
        patch = np.where(patch > 0, patch, np.nan)
        if np.isfinite(patch).sum() * 2 < patch.size:
            continue
        median = np.nanmedian(patch)
        if np.nanmax(patch) - np.nanmin(patch) <= max_spread * median:
            out[i] = median
    return out


def test_sample_depth_is_the_window_nanmedian() -> None:
    rng = np.random.default_rng(3)
    depth = rng.uniform(1.0, 1.03, size=(60, 80))
    depth[rng.uniform(size=depth.shape) < 0.3] = 0.0  # holes: odd and even valid counts, some too few
    depth[:, 40:] += 0.5  # a depth edge: windows across it are rejected by the spread test
    uv = rng.uniform(-3.0, 83.0, size=(400, 2)) * [1.0, 0.75]  # some outside the image or its border
    got = sample_depth(depth, uv, 5, 0.05)
    want = _reference(depth, uv, 5, 0.05)
    # Exact: the same readings, the median of an even count as the mean of the two middle ones.
    np.testing.assert_array_equal(got, want)
    assert np.isfinite(got).sum() > 100 and np.isnan(got).sum() > 50  # both outcomes exercised


def test_rigid_ransac_per_point_tolerances_and_outliers() -> None:
    """Points 1-4 m away with noise growing with range (as depth noise does), 30 % outliers: the
    camera RANSAC recovers the motion and returns the shared RigidFit with its inlier rms."""
    rng = np.random.default_rng(0)
    T_dst_src = make_transform(Rotation.from_rotvec([0.02, -0.05, 0.01]).as_matrix(), [0.05, -0.02, 0.03])
    p_src = np.column_stack([rng.uniform(-1, 1, 300), rng.uniform(-0.8, 0.8, 300), rng.uniform(1, 4, 300)])
    sigma = 0.001 * p_src[:, 2] ** 2
    p_dst = p_src @ T_dst_src[:3, :3].T + T_dst_src[:3, 3] + rng.normal(size=(300, 3)) * sigma[:, None]
    outliers = rng.random(300) < 0.3
    p_dst[outliers] += rng.uniform(-0.3, 0.3, (int(outliers.sum()), 3))
    fit = rigid_ransac(p_src, p_dst, 3 * np.sqrt(3) * sigma, np.ones(300), rng, hypotheses=100)
    assert isinstance(fit, RigidFit)
    # ~200 inliers, a few mm of noise over a 1-4 m lever: errors ~1e-4 rad and ~1 mm; bounds ~5x.
    assert Rotation.from_matrix(fit.T_dst_src[:3, :3] @ T_dst_src[:3, :3].T).magnitude() < 1e-3
    assert np.linalg.norm(fit.T_dst_src[:3, 3] - T_dst_src[:3, 3]) < 5e-3
    assert np.mean(fit.inliers[outliers]) < 0.05 and np.mean(fit.inliers[~outliers]) > 0.8
    residual = np.linalg.norm(p_src @ fit.T_dst_src[:3, :3].T + fit.T_dst_src[:3, 3] - p_dst, axis=1)
    assert np.isclose(fit.rms_m, np.sqrt(np.mean(residual[fit.inliers] ** 2)), rtol=1e-12, atol=0.0)
    assert rigid_ransac(p_src[:2], p_dst[:2], sigma[:2], np.ones(2), rng, hypotheses=10) is None


def test_visible_offset_sees_across_an_edge_not_along_it() -> None:
    """A point on a straight edge shows an offset across the edge in full and one along it not at
    all (the aperture problem); a point at a square's corner shows both in full. Tolerance 5 %:
    Sobel gradients of a blurred step are symmetric, the residue comes from the square's other
    edges entering the window at the corner."""
    gray = np.zeros((120, 160), np.uint8)
    gray[20:100, 40:120] = 200  # a bright square, corners at (40, 20) and (119, 99) in (u, v)
    gray = cv2.GaussianBlur(gray, (5, 5), 1.0)
    on_edge = np.array([[40.0, 60.0]])  # middle of the square's left edge (vertical)
    corner = np.array([[40.0, 20.0]])
    for offset, expected_edge in (([0.0, 3.0], 0.0), ([3.0, 0.0], 3.0), ([2.0, 2.0], 2.0)):
        seen_edge = visible_offset_px(gray, on_edge, on_edge - offset, 21)[0]
        seen_corner = visible_offset_px(gray, corner, corner - offset, 21)[0]
        assert abs(seen_edge - expected_edge) < 0.05 * 3.0, (offset, seen_edge)
        assert np.linalg.norm(offset) * 0.7 < seen_corner <= np.linalg.norm(offset) + 1e-9, (offset, seen_corner)
    assert visible_offset_px(gray, np.zeros((0, 2)), np.zeros((0, 2)), 21).shape == (0,)


def test_noise_is_measured_on_shaded_paint_and_bare_paint_patches_score_about_one() -> None:
    """A plain wall: smooth shading, a few painted squares (real corners), and 8-bit noise of a known sigma.
    The estimate must come within 10 % of the sigma (the shading and the squares' edges must not count as
    noise); a patch of bare paint must score within the 0.5-2 that noise alone gives (its smaller
    eigenvalue fluctuates around the noise's mean), and the squares' corners (30 grey levels of contrast, 9-10
    at sigma 2.5) well above the tracker's floor of 3 (``TrackingConfig.min_corner_snr``)."""
    rng = np.random.default_rng(0)
    v, u = np.mgrid[0:240, 0:320].astype(np.float32)
    image = 120.0 + 40.0 * (u / 320.0) + 15.0 * np.sin(v / 60.0)  # shading: no corner, no noise
    for x in (60, 160, 260):
        image[100:140, x - 20 : x + 20] -= 30.0  # squares 30 grey levels darker
    for sigma in (1.0, 2.5):
        gray = np.clip(np.rint(image + rng.normal(0.0, sigma, image.shape)), 0, 255).astype(np.uint8)
        measured = image_noise_sigma(gray)
        assert abs(measured - sigma) < 0.1 * sigma, (sigma, measured)
        bare = np.array([[30.0, 30.0], [200.0, 40.0], [110.0, 200.0], [300.0, 210.0]])
        corners = np.array([[40.0, 100.0], [180.0, 140.0], [280.0, 100.0]])
        snr_bare = corner_snr(gray, bare, 21, measured)
        snr_corners = corner_snr(gray, corners, 21, measured)
        assert np.all((snr_bare > 0.5) & (snr_bare < 2.0)), snr_bare
        assert np.all(snr_corners > 5.0), snr_corners
