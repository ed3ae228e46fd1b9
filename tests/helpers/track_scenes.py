"""Synthetic point tracks for stages 3 and 4: doors and drawers among static, outlier and hand tracks.

numpy only (no rendering). ``make_scene`` builds the tracks and the truth; ``errors`` measures a part
estimate against it (FORMATS.md section 5).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from funrec.geometry.camera import project
from funrec.geometry.joints import closest_point_on_axis_to_origin, joint_transforms
from funrec.geometry.transforms import invert_transform, make_transform
from funrec.parts.articulation import PartEstimate
from funrec.parts.point_tracks import PointTracks

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
"""Synthetic 640x480 camera."""


def smooth_step(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * t)


def open_profile(num_frames: int, max_state: float) -> np.ndarray:
    """0 (pause), open to max, pause, partial close to 60 %, pause: the (F,) true states."""
    t = np.linspace(0.0, 1.0, num_frames)
    return max_state * (smooth_step((t - 0.15) / 0.35) - 0.4 * smooth_step((t - 0.65) / 0.2))


@dataclass
class PartSpec:
    joint_type: str
    axis: np.ndarray
    pivot: np.ndarray | None
    states: np.ndarray
    corners: np.ndarray
    """(4, 3) panel corners at the canonical state (for the object mask)."""
    handle: np.ndarray
    track_indices: np.ndarray


@dataclass
class SyntheticScene:
    tracks: PointTracks
    parts: list[PartSpec]
    T_world_camera: np.ndarray
    static_tracks: np.ndarray
    outlier_tracks: np.ndarray
    hand_tracks: np.ndarray

    def object_mask_lookup(self, part: int = 0) -> Callable[[int, np.ndarray], np.ndarray]:
        """Evidence lookup: 1 where a pixel falls in the projected panel of ``part`` at a frame."""
        spec = self.parts[part]

        def lookup(frame: int, uv: np.ndarray) -> np.ndarray:
            T = joint_transforms(spec.joint_type, spec.axis, spec.pivot, spec.states[frame : frame + 1])[0]
            corners_world = spec.corners @ T[:3, :3].T + T[:3, 3]
            T_camera_world = invert_transform(self.T_world_camera[frame])
            poly, _ = project(corners_world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3], K)
            inside = np.ones(len(uv), dtype=bool)
            signs = []
            for k in range(4):
                a, b = poly[k], poly[(k + 1) % 4]
                signs.append((b[0] - a[0]) * (uv[:, 1] - a[1]) - (b[1] - a[1]) * (uv[:, 0] - a[0]))
            signs = np.stack(signs)
            inside = np.all(signs >= 0, axis=0) | np.all(signs <= 0, axis=0)
            return inside.astype(float)

        return lookup


def _part(rng: np.random.Generator, joint_type: str, num_frames: int, axis: np.ndarray | None, max_state: float, centre: np.ndarray):
    view = np.array([0.0, 0.0, 1.0])
    if joint_type == "revolute":
        if axis is None:
            axis = rng.normal(size=3)
        axis = axis / np.linalg.norm(axis)
        width_dir = np.cross(axis, view)
        if np.linalg.norm(width_dir) < 0.3:
            width_dir = np.cross(axis, [1.0, 0.0, 0.0])
        width_dir /= np.linalg.norm(width_dir)
        hinge = centre - 0.22 * width_dir
        corners = np.array([hinge + s * 0.3 * axis + w * 0.45 * width_dir for s, w in ((-1, 0), (-1, 1), (1, 1), (1, 0))])
        pivot = closest_point_on_axis_to_origin(axis, hinge)
        handle = hinge + 0.42 * width_dir
        sample = lambda n: hinge + rng.uniform(-0.3, 0.3, (n, 1)) * axis + rng.uniform(0.0, 0.45, (n, 1)) * width_dir  # noqa: E731
    else:
        if axis is None:
            axis = -view + 0.4 * rng.normal(size=3)
        axis = axis / np.linalg.norm(axis)
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        corners = np.array([centre + s * 0.25 * e1 + w * 0.12 * e2 for s, w in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        pivot = None
        handle = centre + 0.05 * axis
        sample = lambda n: centre + rng.uniform(-0.25, 0.25, (n, 1)) * e1 + rng.uniform(-0.12, 0.12, (n, 1)) * e2  # noqa: E731
    states = open_profile(num_frames, max_state)
    return axis, pivot, states, corners, handle, sample


def make_scene(
    rng: np.random.Generator,
    joint_types: tuple[str, ...] = ("revolute",),
    num_frames: int = 60,
    part_tracks: int = 150,
    static_tracks: int = 300,
    outlier_fraction: float = 0.07,
    hand_tracks: int = 30,
    noise_m: float = 0.003,
    axes: tuple[np.ndarray | None, ...] | None = None,
    max_states: tuple[float, ...] | None = None,
    reseed_fraction: float = 0.2,
) -> SyntheticScene:
    """Tracks of moving parts, static background, random-walk outliers and a non-rigid hand.

    Noise is Kinect-like: ``noise_m`` per axis at 1 m depth, growing with depth squared, twice as
    large along the camera ray. Tracks drop out at random, some have a 10-frame gap, and a
    ``reseed_fraction`` of part tracks is seeded mid-sequence.
    """
    F = num_frames
    axes = axes or (None,) * len(joint_types)
    centres = [np.array([0.0, 0.05, 1.2]), np.array([0.25, 0.35, 1.1])]
    T_world_camera = make_transform(
        Rotation.from_rotvec(rng.normal(0, 0.02, (F, 3)).cumsum(0) * 0.2).as_matrix(), rng.normal(0, 0.003, (F, 3)).cumsum(0)
    )
    p_true, starts, specs = [], [], []
    n = 0
    for k, joint_type in enumerate(joint_types):
        default_max = rng.uniform(np.deg2rad(60), np.deg2rad(90)) if joint_type == "revolute" else 0.3
        max_state = max_states[k] if max_states else default_max
        axis, pivot, states, corners, handle, sample = _part(rng, joint_type, F, axes[k], max_state, centres[k])
        if k == 1:  # a second part moves in the second half only
            states = np.concatenate([np.zeros(F // 2), open_profile(F - F // 2, max_state)])
        x = sample(part_tracks)
        T = joint_transforms(joint_type, axis, pivot, states)
        p_true.append(np.einsum("fij,nj->fni", T[:, :3, :3], x) + T[:, None, :3, 3])
        start = np.zeros(part_tracks, dtype=int)
        reseed = rng.random(part_tracks) < reseed_fraction
        start[reseed] = rng.integers(F // 3, 2 * F // 3, reseed.sum())
        starts.append(start)
        specs.append(PartSpec(joint_type, axis, pivot, states, corners, handle, np.arange(n, n + part_tracks)))
        n += part_tracks
    static = np.array([0.0, 0.0, 1.5]) + rng.uniform(-1, 1, (static_tracks, 3)) * [0.8, 0.5, 0.3]
    p_true.append(np.broadcast_to(static, (F, static_tracks, 3)))
    starts.append(np.zeros(static_tracks, dtype=int))
    static_idx = np.arange(n, n + static_tracks)
    n += static_tracks
    # Hand: approaches the handle of part 0, holds it while it moves, leaves; fingers wiggle.
    t = np.arange(F)
    spec = specs[0]
    T0 = joint_transforms(spec.joint_type, spec.axis, spec.pivot, spec.states)
    moving = np.flatnonzero(np.abs(spec.states) > 1e-3)
    i0, i1 = (max(moving[0] - 8, 0), min(moving[-1] + 8, F - 1)) if len(moving) else (0, F - 1)
    approach = smooth_step((t - i0) / 8.0) * (1 - smooth_step((t - (i1 - 8)) / 8.0))
    hand_centre = T0[:, :3, :3] @ spec.handle + T0[:, :3, 3] + (1 - approach)[:, None] * np.array([0.1, 0.2, -0.3])
    offsets = rng.normal(0, 0.04, (hand_tracks, 3))
    phase = rng.uniform(0, 2 * np.pi, (hand_tracks, 3))
    p_true.append(hand_centre[:, None, :] + offsets + 0.015 * np.sin(0.3 * t[:, None, None] + phase))
    starts.append(np.full(hand_tracks, i0))
    hand_idx = np.arange(n, n + hand_tracks)
    n += hand_tracks
    # Outliers: random walks with 1 cm steps.
    n_out = int(round(outlier_fraction * n))
    walk = rng.uniform(-0.5, 0.5, (n_out, 3)) + [0.0, 0.0, 1.3] + rng.normal(0, 0.01, (F, n_out, 3)).cumsum(0)
    p_true.append(walk)
    starts.append(rng.integers(0, F // 2, n_out))
    outlier_idx = np.arange(n, n + n_out)
    n += n_out
    p_world = np.concatenate(p_true, axis=1).copy()
    start = np.concatenate(starts)
    visible = (t[:, None] >= start) & (rng.random((F, n)) > 0.05)
    visible[i1 + 1 :, hand_idx] = False
    gap = rng.random(n) < 0.3
    gap_start = rng.integers(0, F - 10, n)
    in_gap = (t[:, None] >= gap_start) & (t[:, None] < gap_start + 10) & gap
    visible &= ~in_gap
    # Kinect-like noise in the camera frame.
    T_camera_world = invert_transform(T_world_camera)
    p_camera = np.einsum("fij,fnj->fni", T_camera_world[:, :3, :3], p_world) + T_camera_world[:, None, :3, 3]
    sigma = noise_m * (p_camera[..., 2:3] / 1.0) ** 2
    p_camera = p_camera + rng.normal(size=p_camera.shape) * sigma * np.array([1.0 / 3.0, 1.0 / 3.0, 1.0])
    p_world = np.einsum("fij,fnj->fni", T_world_camera[:, :3, :3], p_camera) + T_world_camera[:, None, :3, 3]
    uv = np.stack([project(p_camera[f], K)[0] for f in range(F)])
    p_world[~visible] = np.nan
    uv[~visible] = np.nan
    return SyntheticScene(PointTracks(p_world, uv, visible), specs, T_world_camera, static_idx, outlier_idx, hand_idx)


# ----------------------------------------------------------------------------------------------
# Error measures (FORMATS.md section 5).

def axis_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    e = np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))
    return float(min(e, 180.0 - e))


def line_distance(a1: np.ndarray, p1: np.ndarray, a2: np.ndarray, p2: np.ndarray) -> float:
    """Distance between two nearly parallel axis lines, measured in the pivot's neighbourhood."""
    d = p2 - p1
    return float(np.linalg.norm(d - a1 * (d @ a1)))


def state_error(part_frames: np.ndarray, states: np.ndarray, axis: np.ndarray, spec: PartSpec) -> float:
    sign = 1.0 if axis @ spec.axis > 0 else -1.0
    true = spec.states[part_frames] - spec.states[part_frames[0]]
    return float(np.mean(np.abs(sign * (states - states[0]) - true)))


def errors(part: PartEstimate, spec: PartSpec) -> dict[str, float]:
    out = {
        "axis_deg": axis_error_deg(part.axis_world, spec.axis),
        "state": state_error(part.frames, part.states, part.axis_world, spec),
    }
    if spec.joint_type == "revolute":
        assert part.pivot_world is not None and spec.pivot is not None
        out["pivot_m"] = line_distance(spec.axis, spec.pivot, part.axis_world, part.pivot_world)
    return out
