"""Tests of funrec.camera.features.sample_depth: the robust window depth against a direct nanmedian."""

from __future__ import annotations

import numpy as np

from funrec.camera.features import sample_depth


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
