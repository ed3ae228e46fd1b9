"""Trajectories of one sequence: the egocentric camera (walk-up, standing, natural head
motion), the joint states of the parts (minimum-jerk strokes) and the hand proxy
(reach, grasp, drive, release, withdraw).

Everything is in the world (scene) frame, z up; camera poses use the OpenCV camera frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from funrec.geometry.transforms import make_transform
from funrec.synth.handpath import hand_trajectory
from funrec.synth.part_geometry import PartGeometry
from funrec.synth.spec import SequenceSpec
from funrec.synth.timeline import Timeline, schedule
from funrec.typed import FloatArray

WALK_CURVE_M = 0.25
"""Largest sideways bulge of a walk, metres."""


@dataclass(frozen=True)
class Motion:
    """Per-frame poses and states of a whole sequence (F frames, P parts)."""

    T_world_camera: FloatArray
    """(F, 4, 4) camera-to-world, OpenCV camera frame."""
    states: FloatArray
    """(P, F) joint state of every part at every frame (0 = closed)."""
    T_world_grasp: FloatArray
    """(F, 4, 4) pose of the hand's grasp frame (see ``hand.py``)."""
    T_world_forearm: FloatArray
    """(F, 4, 4) pose of the forearm frame."""
    intervals: tuple[tuple[tuple[int, int], ...], ...]
    """Per part, [first, last] frame spans in which the hand holds it."""
    timeline: Timeline | None
    """The schedule (None for camera-only sequences)."""


def min_jerk(t: FloatArray, t0: float, t1: float) -> FloatArray:
    """Minimum-jerk ramp from 0 (t <= t0) to 1 (t >= t1): 10 s^3 - 15 s^4 + 6 s^5."""
    s = np.clip((np.asarray(t, dtype=np.float64) - t0) / max(t1 - t0, 1e-9), 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def look_at(p_world_camera: FloatArray, target_world: FloatArray) -> FloatArray:
    """(F, 3, 3) R_world_camera (OpenCV) of cameras at (F, 3) positions looking at (F, 3)
    targets with no roll: image x stays horizontal (world z up)."""
    z = target_world - p_world_camera
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def smooth_noise(rng: np.random.Generator, frames: int, channels: int, std: float, sigma_frames: float) -> FloatArray:
    """(F, C) low-pass filtered (Gaussian kernel, ``sigma_frames``) noise with standard deviation ``std``."""
    pad = int(4 * sigma_frames) + 1
    white = rng.standard_normal((frames + 2 * pad, channels))
    smooth = gaussian_filter1d(white, sigma_frames, axis=0)[pad : pad + frames]
    return smooth / max(float(smooth.std()), 1e-9) * std


class _Path:
    """A piecewise minimum-jerk path: a start point plus a sum of timed displacements."""

    def __init__(self, start: FloatArray) -> None:
        self.start = np.asarray(start, dtype=np.float64).copy()
        self.end = self.start.copy()
        self.moves: list[tuple[float, float, FloatArray, FloatArray]] = []

    def move(self, t0: float, t1: float, to: FloatArray, bulge: FloatArray | None = None) -> None:
        delta = np.asarray(to, dtype=np.float64) - self.end
        self.moves.append((t0, t1, delta, np.zeros_like(delta) if bulge is None else bulge))
        self.end = self.end + delta

    def sample(self, t: FloatArray) -> FloatArray:
        out = np.repeat(self.start[None], len(t), axis=0)
        for t0, t1, delta, bulge in self.moves:
            s = min_jerk(t, t0, t1)
            out += s[:, None] * delta + np.sin(np.pi * s)[:, None] * bulge
        return out


def _look_point(part: PartGeometry) -> FloatArray:
    return 0.5 * (part.handle + part.centre)


def _standpoint(
    part: PartGeometry,
    opening: float,
    walk_area: tuple[float, float, float, float],
    head_m: float,
    rng: np.random.Generator,
) -> FloatArray:
    """Where the eyes are while operating a part: off to a door's free side and out of its
    swing, lower (bending) for low handles, and 0.78-1.2 m from the handle over the whole
    stroke up to ``opening`` (the best of a few random candidates)."""
    n = part.normal
    lateral_axis = np.array([-n[1], n[0], 0.0])
    side_hinged = part.joint_type == "revolute" and part.pivot is not None and abs(part.axis[2]) > 0.9
    T = part.poses(np.linspace(0.0, opening, 9))
    handles = T[:, :3, :3] @ part.handle + T[:, :3, 3]
    x0, x1, y0, y1 = walk_area
    best, best_violation = None, np.inf
    for _ in range(24):
        if side_hinged:
            assert part.pivot is not None
            side = float(np.sign((part.handle - part.pivot) @ lateral_axis)) or 1.0
            lateral = side * float(rng.uniform(0.1, 0.3))
        else:
            lateral = float(rng.uniform(-0.1, 0.1))
        height = float(np.clip(handles[:, 2].min() + rng.uniform(0.8, 1.0), 1.2, head_m))
        p = part.handle + n * float(rng.uniform(0.55, 1.1)) + lateral_axis * lateral
        if side_hinged:
            assert part.pivot is not None
            offset = (p - part.pivot)[:2]
            reach = part.width + 0.2
            if np.linalg.norm(offset) < reach:  # step back out of the disc the door sweeps
                across = float(offset @ lateral_axis[:2])
                p[:2] += n[:2] * (np.sqrt(max(reach**2 - across**2, 0.0)) - float(offset @ n[:2]))
        p = np.array([np.clip(p[0], x0, x1), np.clip(p[1], y0, y1), height])
        distance = np.linalg.norm(handles - p, axis=1)
        violation = max(0.0, distance.max() - 1.2) + max(0.0, 0.78 - distance.min())
        if violation < best_violation:
            best, best_violation = p, violation
        if violation == 0.0:
            break
    assert best is not None
    return best


def _start(
    focus: FloatArray,
    normal: FloatArray,
    walk_area: tuple[float, float, float, float],
    head_m: float,
    rng: np.random.Generator,
    distance: tuple[float, float] = (1.5, 3.0),
) -> FloatArray:
    """A starting point 1.5-3 m in front of ``focus`` (within 35 degrees of the normal)."""
    angle = float(rng.uniform(-0.6, 0.6))
    direction = np.array(
        [np.cos(angle) * normal[0] - np.sin(angle) * normal[1], np.sin(angle) * normal[0] + np.cos(angle) * normal[1]]
    )
    p = focus[:2] + direction * float(rng.uniform(*distance))
    x0, x1, y0, y1 = walk_area
    return np.array([np.clip(p[0], x0, x1), np.clip(p[1], y0, y1), head_m])


def _bulge(a: FloatArray, b: FloatArray, rng: np.random.Generator) -> FloatArray:
    d = b[:2] - a[:2]
    length = float(np.linalg.norm(d))
    if length < 0.3:
        return np.zeros(3)
    return np.array([-d[1], d[0], 0.0]) / length * float(rng.uniform(-1, 1)) * min(WALK_CURVE_M, 0.15 * length)


def _interaction_paths(
    spec: SequenceSpec,
    parts: tuple[PartGeometry, ...],
    walk_area: tuple[float, float, float, float],
    head_m: float,
    rng: np.random.Generator,
) -> tuple[_Path, _Path, Timeline]:
    """Body position and gaze paths for a sequence with interactions."""
    stands: list[FloatArray] = []
    for i, interaction in enumerate(spec.interactions):
        same = i > 0 and spec.interactions[i - 1].part == interaction.part
        part = parts[interaction.part]
        opening = max(max(other.targets) for other in spec.interactions if other.part == interaction.part) * part.upper
        stands.append(stands[-1] if same else _standpoint(part, opening, walk_area, head_m, rng))
    first = parts[spec.interactions[0].part]
    far = _start(first.handle, first.normal, walk_area, head_m, rng)
    joint_types, uppers = tuple(p.joint_type for p in parts), tuple(p.upper for p in parts)
    for shrink in (1.0, 0.6, 0.3, 0.0):  # short sequences start closer to the first part
        start = stands[0] + (far - stands[0]) * shrink
        start[2] = head_m
        lengths = tuple(float(np.linalg.norm((s - p)[:2])) for s, p in zip(stands, [start, *stands[:-1]]))
        try:
            timeline = schedule(spec, joint_types, uppers, lengths, np.random.default_rng(rng.integers(1 << 32)))
            break
        except ValueError:
            if shrink == 0.0:
                raise
    body = _Path(start)
    gaze = _Path(_look_point(first) + rng.normal(0.0, 0.08, 3))
    for i, interaction in enumerate(spec.interactions):
        t0, t1 = timeline.walks[i]
        if lengths[i] > 0.0:
            target = np.array([stands[i][0], stands[i][1], body.end[2]])
            body.move(t0, t1, target, _bulge(body.end, target, rng))
        if abs(stands[i][2] - body.end[2]) > 1e-6:  # bend (or straighten) near the end of the walk
            body.move(max(t0, t1 - 1.0), t1 + 0.3, np.array([body.end[0], body.end[1], stands[i][2]]))
        gaze.move(t0, t1, _look_point(parts[interaction.part]) + rng.normal(0.0, 0.03, 3))
    last = spec.interactions[-1]
    part = parts[last.part]
    T_end = part.poses(np.array([last.targets[-1] * part.upper]))[0]
    # Look between the opened front and the interior it reveals.
    opened = T_end[:3, :3] @ part.centre + T_end[:3, 3]
    inside = 0.5 * opened + 0.5 * (part.centre - part.normal * float(rng.uniform(0.15, 0.3)))
    t_obs = timeline.t_observe
    gaze.move(t_obs, t_obs + 1.0, inside + rng.normal(0.0, 0.05, 3))
    back = body.end + part.normal * float(rng.uniform(0.05, 0.3))
    back[2] = max(body.end[2], min(head_m, body.end[2] + 0.2))
    x0, x1, y0, y1 = walk_area
    back[:2] = np.clip(back[:2], [x0, y0], [x1, y1])
    body.move(t_obs + 0.2, t_obs + 0.2 + max(1.0, 0.6 * (timeline.duration - t_obs)), back)
    return body, gaze, timeline


def _static_paths(
    spec: SequenceSpec,
    points: FloatArray,
    walk_area: tuple[float, float, float, float],
    head_m: float,
    rng: np.random.Generator,
) -> tuple[_Path, _Path]:
    """Walk up to the furniture, look along it, sidestep and step back; nothing is touched.
    The furniture rows of ``layout.py`` face -y."""
    normal = np.array([0.0, -1.0, 0.0])
    focus = points[int(rng.integers(len(points)))]
    start = _start(focus, normal, walk_area, head_m, rng, (2.2, 3.0))
    near = _start(focus, normal, walk_area, head_m, rng, (1.1, 1.5))
    side = near + np.array([float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.7, 1.3)), 0.0, 0.0])
    x0, x1, y0, y1 = walk_area
    side[:2] = np.clip(side[:2], [x0, y0], [x1, y1])
    back = side + np.array([0.0, -float(rng.uniform(0.2, 0.5)), 0.0])
    back[:2] = np.clip(back[:2], [x0, y0], [x1, y1])
    waypoints = [near, side, back]
    lengths = np.array([np.linalg.norm((b - a)[:2]) + 0.3 for a, b in zip([start, near, side], waypoints)])
    dwell = 0.15 * spec.num_frames / spec.fps
    moving = spec.num_frames / spec.fps - dwell * 3
    spans = moving * lengths / lengths.sum()
    body, gaze = _Path(start), _Path(focus + rng.normal(0.0, 0.05, 3))
    t = 0.5 * dwell
    for span, waypoint in zip(spans, waypoints):
        body.move(t, t + span, waypoint, _bulge(body.end, waypoint, rng))
        target = points[int(rng.integers(len(points)))] + rng.normal(0.0, 0.1, 3)
        gaze.move(t + 0.3 * span, t + span + 0.5 * dwell, target)
        t += span + dwell
    return body, gaze


def plan_motion(
    spec: SequenceSpec,
    parts: tuple[PartGeometry, ...],
    points_of_interest: FloatArray,
    walk_area: tuple[float, float, float, float],
    rng: np.random.Generator,
) -> Motion:
    """Plan camera, joint and hand trajectories for a sequence.

    Args:
        spec: the sequence (interactions, frame count, frame rate).
        parts: geometry of parts[k] = part_k at the canonical state.
        points_of_interest: (N, 3) points the camera may look at when nothing is opened
            (handles of every front), world frame.
        walk_area: (x_min, x_max, y_min, y_max) free floor, metres.
        rng: random generator.

    Returns:
        Per-frame trajectories.

    Raises:
        ValueError: the interactions do not fit into ``spec.num_frames``.
    """
    frames, fps = spec.num_frames, spec.fps
    t = np.arange(frames) / fps
    head_m = float(rng.uniform(1.5, 1.7))
    states = np.zeros((len(parts), frames))
    timeline = None
    if spec.interactions:
        body, gaze_path, timeline = _interaction_paths(spec, parts, walk_area, head_m, rng)
        for stroke in timeline.strokes:
            states[stroke.part] += (stroke.end - stroke.start) * min_jerk(t, stroke.t0, stroke.t1)
    else:
        body, gaze_path = _static_paths(spec, np.asarray(points_of_interest), walk_area, head_m, rng)
    position, gaze = body.sample(t), gaze_path.sample(t)
    if timeline is not None:
        # While the hand works the eyes follow the moving part.
        for hold in timeline.holds:
            part = parts[hold.part]
            T = part.poses(states[hold.part])
            live = T[:, :3, :3] @ _look_point(part) + T[:, :3, 3]
            weight = min_jerk(t, hold.t_reach - 0.3, hold.t_approach) * (
                1.0 - min_jerk(t, hold.t_back, hold.t_clear + 0.5)
            )
            gaze = gaze * (1.0 - weight[:, None]) + live * weight[:, None]
    gaze = gaussian_filter1d(gaze, 0.15 * fps, axis=0, mode="nearest")
    step = np.gradient(position[:, :2], axis=0) * fps
    speed = np.linalg.norm(step, axis=1)
    gait = np.clip(speed / 0.8, 0.0, 1.0)
    step_hz = float(rng.uniform(1.7, 2.1))
    sideways = np.stack([-step[:, 1], step[:, 0], np.zeros(frames)], axis=1) / np.maximum(speed, 1e-6)[:, None]
    position[:, 2] += 0.012 * gait * np.cos(2.0 * np.pi * step_hz * t)
    position += (0.01 * gait * np.sin(np.pi * step_hz * t))[:, None] * sideways
    position += smooth_noise(rng, frames, 3, float(rng.uniform(0.005, 0.01)), 0.5 * fps)
    angles = smooth_noise(rng, frames, 3, np.radians(float(rng.uniform(0.8, 1.6))), 0.4 * fps) * [1.0, 1.0, 0.6]
    R_world_camera = look_at(position, gaze) @ Rotation.from_euler("xyz", angles).as_matrix()
    T_world_camera = make_transform(R_world_camera, position)
    if timeline is None:
        hidden = make_transform(np.eye(3), np.array([0.0, 0.0, -10.0]))
        T_world_grasp = np.repeat(hidden[None], frames, axis=0)
        return Motion(T_world_camera, states, T_world_grasp, T_world_grasp.copy(), tuple(() for _ in parts), None)
    T_world_grasp, T_world_forearm = hand_trajectory(timeline, parts, states, T_world_camera, t)
    intervals = tuple(
        tuple(
            (int(np.ceil(h.t_grasp * fps - 1e-9)), min(frames - 1, int(np.floor(h.t_release * fps + 1e-9))))
            for h in timeline.holds
            if h.part == k
        )
        for k in range(len(parts))
    )
    return Motion(T_world_camera, states, T_world_grasp, T_world_forearm, intervals, timeline)


__all__ = ["Motion", "look_at", "min_jerk", "plan_motion", "smooth_noise"]
