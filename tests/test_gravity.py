"""Gravity alignment recovers z up from a floor, and from camera axes without one."""

from __future__ import annotations

import numpy as np
import pytest

from funrec.geometry import make_transform, rotation_about_axis, transform_points
from funrec.surfaces.gravity import estimate_gravity

# The floor's normal is fitted to thousands of points with 3 mm noise: well under 1 degree.
UP_TOLERANCE_DEG = 1.0


def _room(rng: np.random.Generator) -> np.ndarray:
    """Floor at z=0, a wall at y=2, a countertop at z=0.9 and a cabinet front at y=1.4 (scene frame)."""
    floor = np.c_[rng.uniform(-2, 2, (6000, 2)), np.zeros(6000)]
    wall = np.c_[rng.uniform(-2, 2, 3000), np.full(3000, 2.0), rng.uniform(0, 2.5, 3000)]
    counter = np.c_[rng.uniform(-1, 1, 2000), rng.uniform(1.4, 2.0, 2000), np.full(2000, 0.9)]
    front = np.c_[rng.uniform(-1, 1, 2000), np.full(2000, 1.4), rng.uniform(0.1, 0.9, 2000)]
    return np.vstack([floor, wall, counter, front]) + rng.normal(0, 0.003, (13000, 3))


def _head_cameras(rng: np.random.Generator, pitch_deg: float, yaw_span: float = 0.6) -> np.ndarray:
    """Head-mounted cameras at 1.6 m looking at +y, pitched down, turning by +-yaw_span rad, a few
    degrees of roll noise (scene frame)."""
    R_scene_level = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # OpenCV camera looking along +y
    poses = []
    for yaw in np.linspace(-yaw_span, yaw_span, 20):
        R = rotation_about_axis([0, 0, 1], yaw) @ R_scene_level @ rotation_about_axis([1, 0, 0], -np.radians(pitch_deg))
        R = R @ rotation_about_axis([0, 0, 1], np.radians(rng.normal(0, 2.0)))
        poses.append(make_transform(R, [rng.uniform(-0.5, 0.5), rng.uniform(-1, 0), 1.6]))
    return np.stack(poses)


@pytest.mark.parametrize(("pitch_deg", "yaw_span"), [(10.0, 0.6), (35.0, 0.6), (45.0, 0.0), (55.0, 0.05)])
def test_floor_gives_up_and_height(pitch_deg: float, yaw_span: float) -> None:
    """Also when the person faces one way looking down (bench kitchens): the camera prior is then the
    pitched -y axis, 45-55 deg off, and the floor must still be found (it was not: twins came out
    38-55 deg tilted)."""
    rng = np.random.default_rng(1)
    T_scene_camera = _head_cameras(rng, pitch_deg, yaw_span)
    # The pipeline's world is camera 0's frame.
    T_world_scene = np.linalg.inv(T_scene_camera[0])
    points_world = transform_points(T_world_scene, _room(rng))
    alignment = estimate_gravity(points_world, T_world_scene @ T_scene_camera)
    assert alignment.source == "floor_plane"
    T_aligned_scene = alignment.T_aligned_world @ T_world_scene
    up_in_aligned = T_aligned_scene[:3, :3] @ [0.0, 0.0, 1.0]
    angle = np.degrees(np.arccos(np.clip(up_in_aligned[2], -1, 1)))
    assert angle < UP_TOLERANCE_DEG
    # Camera 0 stands 1.6 m above the floor, the origin is on the floor below it.
    p_camera0 = (alignment.T_aligned_world @ T_world_scene @ T_scene_camera[0])[:3, 3]
    np.testing.assert_allclose(p_camera0, [0.0, 0.0, 1.6], atol=0.01)


def test_without_floor_uses_camera_axes() -> None:
    rng = np.random.default_rng(2)
    T_scene_camera = _head_cameras(rng, 20.0)
    wall = np.c_[rng.uniform(-2, 2, 3000), np.full(3000, 2.0), rng.uniform(0.5, 2.5, 3000)]
    alignment = estimate_gravity(wall, T_scene_camera)
    assert alignment.source == "camera_axes"
    up = alignment.T_aligned_world[:3, :3] @ [0.0, 0.0, 1.0]
    # Roll noise of 2 degrees per camera averages down over 20 cameras spread in yaw.
    assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) < 3.0
    # The robot stands on the floor: without one it is put a standing adult's eye height below camera 0.
    p_camera0 = (alignment.T_aligned_world @ T_scene_camera[0])[:3, 3]
    assert p_camera0[2] == pytest.approx(1.55, abs=0.05)


def test_counter_top_is_not_the_floor_but_puts_it_a_worktop_height_below() -> None:
    """A wall cabinet seen from 1.6 m with the counter below it but no floor in view: the counter top (0.7 m
    below the cameras) was taken for the floor, and robots planned on such twins stood 0.9 m in the air.
    It is a worktop: the floor goes 0.90 m below it (the _room counter is at 0.9 m: 1 cm of 3 mm noise)."""
    rng = np.random.default_rng(3)
    T_scene_camera = _head_cameras(rng, 10.0)
    room = _room(rng)
    no_floor = room[room[:, 2] > 0.05]
    alignment = estimate_gravity(no_floor, T_scene_camera)
    assert alignment.source == "worktop_plane"
    p_camera0 = (alignment.T_aligned_world @ T_scene_camera[0])[:3, 3]
    assert p_camera0[2] == pytest.approx(1.6, abs=0.01)


def test_ceiling_gives_up_when_neither_floor_nor_worktop_is_seen() -> None:
    """Filmed under wall cabinets (geo_island_rev_wall_00): no floor, no worktop, but the ceiling. The camera axes
    alone tilted that twin 9.4 degrees (a person who looks up and barely turns); the ceiling, level as a floor,
    gives up within UP_TOLERANCE_DEG. The floor's height stays a guess: assumed_camera_height_m below camera 0.
    Here the prior is 10 degrees off (cameras pitched up 10 degrees, not turning)."""
    rng = np.random.default_rng(4)
    T_scene_camera = _head_cameras(rng, -10.0, yaw_span=0.0)
    wall = np.c_[rng.uniform(-2, 2, 3000), np.full(3000, 2.0), rng.uniform(1.4, 2.6, 3000)]
    ceiling = np.c_[rng.uniform(-2, 2, 5000), rng.uniform(-1, 2, 5000), np.full(5000, 2.6)]
    points = np.vstack([wall, ceiling]) + rng.normal(0, 0.003, (8000, 3))
    from_cameras = estimate_gravity(wall, T_scene_camera)
    assert from_cameras.source == "camera_axes"
    tilt = np.degrees(np.arccos(np.clip((from_cameras.T_aligned_world[:3, :3].T @ [0.0, 0.0, 1.0])[2], -1, 1)))
    assert tilt > 5.0  # what the ceiling mends
    alignment = estimate_gravity(points, T_scene_camera)
    assert alignment.source == "ceiling_plane"
    up = alignment.T_aligned_world[:3, :3].T @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) < UP_TOLERANCE_DEG
    p_camera0 = (alignment.T_aligned_world @ T_scene_camera[0])[:3, 3]
    assert p_camera0[2] == pytest.approx(1.55, abs=1e-6)


def test_gravity_json_round_trip_says_whether_the_floor_was_seen(tmp_path) -> None:
    from funrec.errors import FormatError
    from funrec.formats.twin_gravity import TWIN_GRAVITY_FILE, TwinGravity, read_twin_gravity, write_twin_gravity

    assert read_twin_gravity(tmp_path) is None  # twins made before the file
    write_twin_gravity(tmp_path / TWIN_GRAVITY_FILE, TwinGravity("ceiling_plane", "not seen: assumed 1.55 m below camera 0"))
    read = read_twin_gravity(tmp_path)
    assert read == TwinGravity("ceiling_plane", "not seen: assumed 1.55 m below camera 0") and not read.floor_seen
    assert TwinGravity("floor_plane", "seen").floor_seen
    (tmp_path / TWIN_GRAVITY_FILE).write_text('{"format": "funrec-gravity/1", "source": "guess"}')
    with pytest.raises(FormatError, match="gravity.json"):
        read_twin_gravity(tmp_path)
    with pytest.raises(ValueError, match="gravity source"):
        write_twin_gravity(tmp_path / TWIN_GRAVITY_FILE, TwinGravity("guess", "?"))


def test_a_second_level_beside_the_floor_does_not_tilt_it() -> None:
    """A narrow strip of floor seen beside a level 4.7 cm up (a plinth, a bottom panel; the twin of
    plain_rev_fridge_00): at RANSAC's 2 cm a plane tilted 4-5 degrees takes in most of both and beats the level
    floor, and its fit through both put that twin's floor 2.7 degrees off. The fit again at 1 cm among its
    inliers keeps the larger level, the floor: up within UP_TOLERANCE_DEG, camera 0 at its 1.6 m."""
    rng = np.random.default_rng(5)
    T_scene_camera = _head_cameras(rng, 35.0)
    floor = np.c_[rng.uniform(-1, 1, 5000), rng.uniform(0.4, 1.2, 5000), np.zeros(5000)]
    step = np.c_[rng.uniform(-1, 1, 1500), rng.uniform(1.2, 1.6, 1500), np.full(1500, 0.047)]
    wall = np.c_[rng.uniform(-2, 2, 3000), np.full(3000, 2.0), rng.uniform(0.05, 2.5, 3000)]
    points = np.vstack([floor, step, wall]) + rng.normal(0, 0.003, (9500, 3))
    alignment = estimate_gravity(points, T_scene_camera)
    assert alignment.source == "floor_plane"
    up = alignment.T_aligned_world[:3, :3].T @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) < UP_TOLERANCE_DEG
    p_camera0 = (alignment.T_aligned_world @ T_scene_camera[0])[:3, 3]
    assert p_camera0[2] == pytest.approx(1.6, abs=0.01)
