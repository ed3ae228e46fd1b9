"""Tests of funrec.camera.depth_odometry on ray-cast planes: a room corner seen from two poses is
registered to a millimetre; a single plain wall, which leaves a slide free, is refused."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from funrec.camera.depth_odometry import depth_view, register_depth

W, H = 320, 240
K = np.array([[260.0, 0.0, 160.0], [0.0, 260.0, 120.0], [0.0, 0.0, 1.0]])


def _render(T_world_camera: np.ndarray, planes: list[tuple[np.ndarray, float]], shade) -> tuple[np.ndarray, np.ndarray]:
    """Depth (m) and grey image of the nearest of the planes n.x = d (world frame)."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    rays_world = rays @ R.T
    best = np.full((H, W), np.inf)
    for n, d in planes:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (d - n @ t) / (rays_world @ n)
        best = np.where((s > 0) & (s < best), s, best)
    depth = np.where(np.isfinite(best), best, 0.0)
    p_world = t + rays_world * depth[..., None]
    return depth, (255 * shade(p_world)).astype(np.uint8)


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def _stripes(p: np.ndarray) -> np.ndarray:
    """A few broad grey bands (paint edges, shadows), not a texture: ~5 edges across the view."""
    return 0.5 + 0.2 * np.sign(np.sin(p[..., 0] * 9.0)) * np.sign(np.sin(p[..., 1] * 7.0 + 0.3))


CORNER = [(np.array([0.0, 0.0, -1.0]), -2.0), (np.array([1.0, 0.0, 0.0]), 0.8), (np.array([0.0, -1.0, 0.0]), -0.6)]
"""A back wall at z = 2 m, a side wall at x = 0.8 m and a floor at y = 0.6 m (camera looks along +z)."""


def test_room_corner_registers_to_a_millimetre():
    T_world_a = _pose([0, 0, 0], [0, 0, 0])
    T_world_b = _pose([0.01, -0.03, 0.005], [0.03, -0.01, 0.02])
    depth_a, grey_a = _render(T_world_a, CORNER, _stripes)
    depth_b, grey_b = _render(T_world_b, CORNER, _stripes)
    usable = np.ones((H, W), bool)
    target, source = depth_view(grey_a, depth_a, usable, K), depth_view(grey_b, depth_b, usable, K)
    fit = register_depth(source, target, np.eye(4))  # the guess is 3.7 cm and 1.8 deg off
    assert fit is not None
    T_true = np.linalg.inv(T_world_a) @ T_world_b
    # noise-free depth: 1 mm and 0.05 deg leave room for the 4-pixel sampling of the source
    assert np.linalg.norm(fit.T_target_source[:3, 3] - T_true[:3, 3]) < 1e-3
    R_err = fit.T_target_source[:3, :3].T @ T_true[:3, :3]
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(R_err).as_rotvec())) < 0.05
    assert fit.fitness > 0.9


def test_plain_wall_is_refused():
    """One flat, evenly painted wall pins only depth and two tilts: a registration would slide."""
    wall = [(np.array([0.0, 0.0, -1.0]), -1.5)]
    depth_a, grey_a = _render(_pose([0, 0, 0], [0, 0, 0]), wall, lambda p: np.full(p.shape[:2], 0.6))
    depth_b, grey_b = _render(_pose([0, 0, 0], [0.02, 0.0, 0.0]), wall, lambda p: np.full(p.shape[:2], 0.6))
    usable = np.ones((H, W), bool)
    fit = register_depth(depth_view(grey_b, depth_b, usable, K), depth_view(grey_a, depth_a, usable, K), np.eye(4))
    assert fit is None
