"""Tests of funrec.camera.tracking: camera poses on rendered planar scenes with a moving door and
hand (tests/helpers/rendered_rooms.py), and on ten real TUM fr1_xyz Kinect frames against motion capture."""

from __future__ import annotations

import importlib.util
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.camera import tracking
from funrec.camera.tracking import CameraTrajectory, TrackingConfig, track_camera
from funrec.errors import ReconstructionError
from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, load_capture
from funrec.geometry.transforms import invert_transform
from tests.helpers.rendered_rooms import LABEL_HAND, Scene, make_scene, render, write_scene
from tests.helpers.tum import TUM_DIR, tum_ground_truth, write_tum_capture


def ate_m(T_world_camera_est: np.ndarray, T_world_camera_true: np.ndarray) -> tuple[float, float]:
    """(position RMSE metres, max rotation error degrees) after mapping both through frame 0."""
    T_est = invert_transform(T_world_camera_est[0]) @ T_world_camera_est
    T_true = invert_transform(T_world_camera_true[0]) @ T_world_camera_true
    position = np.linalg.norm(T_est[:, :3, 3] - T_true[:, :3, 3], axis=1)
    R_err = np.swapaxes(T_true[:, :3, :3], 1, 2) @ T_est[:, :3, :3]
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(R_err).as_rotvec(), axis=1))
    return float(np.sqrt(np.mean(position**2))), float(angle.max())


# ---------------------------------------------------------------------------------------
# Synthetic known-answer tests


FRAMES = 36


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, tuple[Scene, Path]]:
    root = tmp_path_factory.mktemp("tracking")
    plain = make_scene(FRAMES, hand=False)
    with_hand = make_scene(FRAMES, hand=True)
    return {
        "plain": (plain, write_scene(plain, root / "plain")),
        "hand": (with_hand, write_scene(with_hand, root / "hand")),
        "hand_masked": (with_hand, write_scene(with_hand, root / "hand_masked", hand_masks=True, object_masks=True)),
    }


def test_static_scene_tracks_to_millimetres(scenes):
    scene, root = scenes["plain"]
    calls = []
    trajectory = track_camera(load_capture(root), progress=lambda done, total: calls.append((done, total)))
    assert isinstance(trajectory, CameraTrajectory)
    assert calls[-1] == (FRAMES, FRAMES) and len(calls) == FRAMES
    assert trajectory.tracked.all()
    assert trajectory.keyframes[0] == 0
    np.testing.assert_allclose(trajectory.T_world_camera[0], np.eye(4), atol=1e-9)
    rmse, rot_deg = ate_m(trajectory.T_world_camera, scene.T_world_camera)
    # 0.3 m / 17 deg of motion with 1 mm * z^2 depth noise: measured ~1-2 mm, 0.1 deg.
    assert rmse < 0.01 and rot_deg < 0.5, (rmse, rot_deg)


def test_corners_lost_right_after_seeding_do_not_make_every_frame_a_keyframe(scenes, monkeypatch):
    """On plain paint most corners a keyframe seeds sit on sensor noise and are lost in the next
    frame. Simulated here: 70 % of every fresh seeding is lost at once. Counted from the seeds, the
    survivors (30 %) are already below the 40 % keyframe fraction, so every frame became a keyframe
    and the pose was chained frame to frame (plain_pri_wardrobe_00: 2 cm of drift over four
    frames); counted from the corners tracked into the next frame, keyframes come as the view moves
    on. The camera still tracks to the static test's centimetre."""
    scene, root = scenes["plain"]
    original = tracking.track_klt

    def lossy_klt(previous, current, uv, *args):
        tracked, ok = original(previous, current, uv, *args)
        if len(uv) > lossy_klt.last:  # corners were seeded since the last call (a keyframe)
            ok = ok & (np.arange(len(uv)) % 10 < 3)
        lossy_klt.last = int(ok.sum())
        return tracked, ok

    counts = {}
    for after_first_frame in (False, True):
        lossy_klt.last = 0
        monkeypatch.setattr(tracking, "track_klt", lossy_klt)
        # 300 corners are seeded at this 320x240 size (500 at 640x480): the keyframe inlier floor is
        # scaled with them, so that the 90 survivors are above it and below 40 % of the seeds
        config = TrackingConfig(keyframe_size_after_first_frame=after_first_frame, keyframe_min_inliers=60)
        trajectory = track_camera(load_capture(root), config)
        counts[after_first_frame] = len(trajectory.keyframes)
    assert counts[False] > 0.8 * FRAMES  # nearly every frame, as on the plain bench sequences
    assert counts[True] < 0.5 * counts[False], counts
    rmse, rot_deg = ate_m(trajectory.T_world_camera, scene.T_world_camera)
    assert rmse < 0.01 and rot_deg < 0.5, (rmse, rot_deg)


def test_corners_that_leap_where_no_head_goes_lose_to_the_depth_fit(scenes, monkeypatch):
    """On a plain fridge front filling the view (person_fast_rev_fridge_00) 27 corners dragged along its
    outline put the camera 15.5 cm from where it was going in one frame and refuted the depth fit, and the
    camera stayed there (ATE 13 cm). Simulated: in one frame the corners' pose is 15 cm off and they always
    refute the depth fit. A leap beyond ``max_camera_acceleration_m_s2`` (8.7 cm from the constant-velocity
    prediction in one frame at 15 fps) is not the corners' to make: the depth fit, started from the
    prediction, gives that frame's pose, and the camera tracks to the static test's centimetre; with the bound
    lifted, the leap stays in the trajectory."""
    scene, root = scenes["plain"]
    original = tracking._refine
    calls = {"n": 0}

    def leaping_refine(fit, *args):
        calls["n"] += 1
        T = original(fit, *args)
        if calls["n"] == FRAMES // 2:  # one frame's corners: 15 cm off along the camera's x axis
            T = T @ np.array([[1.0, 0, 0, 0.15], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        return T

    monkeypatch.setattr(tracking, "_refine", leaping_refine)
    monkeypatch.setattr(tracking, "_corners_refute", lambda *args: True)
    # every frame is weak (the depth fit runs beside the corners), as on the plain front
    errors = {}
    for bound in (TrackingConfig().max_camera_acceleration_m_s2, 1e9):
        calls["n"] = 0
        config = TrackingConfig(keyframe_min_inliers=10_000, max_camera_acceleration_m_s2=bound)
        errors[bound], _ = ate_m(track_camera(load_capture(root), config).T_world_camera, scene.T_world_camera)
    assert errors[TrackingConfig().max_camera_acceleration_m_s2] < 0.01, errors
    assert errors[1e9] > 0.03, errors


def test_hand_covering_a_quarter_of_the_view_does_not_drag_the_camera(scenes):
    """The hand (~25 % of the image) and the opening door move independently; without
    masks RANSAC must still pick the static majority, and with masks it must do no worse."""
    plain_scene, plain_root = scenes["plain"]
    scene, root = scenes["hand"]
    _, masked_root = scenes["hand_masked"]
    hand_fraction = np.mean([render(scene.rects, scene.T_world_camera[i], scene.K, scene.width, scene.height, i)[2]
                             == LABEL_HAND for i in (0, FRAMES // 2)])
    assert 0.15 < hand_fraction < 0.35
    rmse_plain, _ = ate_m(track_camera(load_capture(plain_root)).T_world_camera, plain_scene.T_world_camera)
    rmse_hand, rot_hand = ate_m(track_camera(load_capture(root)).T_world_camera, scene.T_world_camera)
    rmse_masked, rot_masked = ate_m(track_camera(load_capture(masked_root)).T_world_camera, scene.T_world_camera)
    # A dragged camera would be off by centimetres (the hand moves ~0.15 m); the robust
    # estimate stays within a few millimetres of the hand-free run.
    assert rmse_hand < rmse_plain + 0.005 and rot_hand < 0.5, (rmse_plain, rmse_hand)
    assert rmse_masked < rmse_plain + 0.005 and rot_masked < 0.5, (rmse_plain, rmse_masked)


def test_failed_frames_are_interpolated_and_flagged(scenes, tmp_path):
    """Frames with no depth cannot be registered: they are flagged and interpolated."""
    scene, root = scenes["plain"]
    broken = tmp_path / "broken"
    shutil.copytree(root, broken)
    for i in (10, 11):
        cv2.imwrite(str(broken / "depth" / f"{i:06d}.png"), np.zeros((scene.height, scene.width), np.uint16))
    trajectory = track_camera(load_capture(broken))
    assert not trajectory.tracked[10] and not trajectory.tracked[11]
    assert trajectory.tracked.sum() == FRAMES - 2
    rmse, _ = ate_m(trajectory.T_world_camera, scene.T_world_camera)
    assert rmse < 0.01
    # The interpolated pose lies between its neighbours.
    t = trajectory.T_world_camera[:, :3, 3]
    assert np.linalg.norm(t[10] - t[9]) < np.linalg.norm(t[12] - t[9]) + 1e-9


def test_without_pose_graph_no_loop_is_closed(scenes, monkeypatch):
    """The pose-graph ablation: chained odometry only (no ORB loop closure, no optimisation),
    which still tracks this short, texture-rich sweep to the same tolerance."""
    scene, root = scenes["plain"]

    def forbidden(*args, **kwargs):
        raise AssertionError("the pose graph is off")

    monkeypatch.setattr(tracking, "_register_orb", forbidden)
    monkeypatch.setattr(tracking, "_optimise", forbidden)
    trajectory = track_camera(load_capture(root), TrackingConfig(use_pose_graph=False))
    assert trajectory.tracked.all()
    rmse, rot_deg = ate_m(trajectory.T_world_camera, scene.T_world_camera)
    assert rmse < 0.01 and rot_deg < 0.5, (rmse, rot_deg)


def test_depth_closes_the_loops_that_orb_cannot(scenes, monkeypatch):
    """Plain and dark views give ORB too few matches for a loop closure; the keyframes' depth closes
    them. Simulated: ORB never matches and every corner pose is 3 mm off along the camera's x axis,
    so the chain of keyframes (one per 3 cm of motion) drifts. Measured: 4.7 cm of ATE without
    depth closures, 0.8 cm with them (53 of 75 tried accepted)."""
    scene, root = scenes["plain"]
    monkeypatch.setattr(tracking, "_register_orb", lambda *args, **kwargs: None)
    corners_pose = tracking._refine

    def biased(*args, **kwargs):
        T = corners_pose(*args, **kwargs).copy()
        T[0, 3] += 0.003
        return T

    monkeypatch.setattr(tracking, "_refine", biased)
    ate = {}
    for closures in (False, True):
        config = TrackingConfig(depth_loop_closures=closures, keyframe_max_translation_m=0.03)
        trajectory = track_camera(load_capture(root), config)
        ate[closures] = ate_m(trajectory.T_world_camera, scene.T_world_camera)[0]
    assert ate[False] > 0.03, ate  # the drift is there to correct
    assert ate[True] < 0.015 and ate[True] < ate[False] / 3, ate


def _covered(scene: Scene, root: Path, tmp_path: Path) -> Path:
    """The scene with frames 14-16 black (lens covered; depth still recorded)."""
    covered = tmp_path / "covered"
    shutil.copytree(root, covered)
    for i in (14, 15, 16):
        cv2.imwrite(str(covered / "rgb" / f"{i:06d}.png"), np.zeros((scene.height, scene.width, 3), np.uint8))
    return covered


def test_relocalises_after_losing_every_track(scenes, tmp_path):
    """Three black frames (lens covered) lose every KLT track, and their depth (a plain wall and
    door) leaves a slide free, so the depth fallback must refuse them too; ORB relocalisation
    against the stored keyframes must bring the camera back without a jump."""
    scene, root = scenes["plain"]
    trajectory = track_camera(load_capture(_covered(scene, root, tmp_path)))
    assert not trajectory.tracked[14:17].any()
    assert trajectory.tracked[17:].all()
    assert 17 in trajectory.keyframes  # relocalised frames start a new keyframe
    tracked = trajectory.tracked
    rmse, rot_deg = ate_m(trajectory.T_world_camera[tracked], scene.T_world_camera[tracked])
    assert rmse < 0.01 and rot_deg < 0.5, (rmse, rot_deg)
    # The covered frames are interpolated across 4 frames of curved motion: looser.
    rmse_all, rot_all_deg = ate_m(trajectory.T_world_camera, scene.T_world_camera)
    assert rmse_all < 0.015 and rot_all_deg < 2.0, (rmse_all, rot_all_deg)


def test_a_part_that_jumps_from_the_prediction_does_not_take_the_camera_even_with_more_corners():
    """60 corners on a drawer pulled 4 cm towards the camera, 40 on the room: the largest rigid motion is the
    drawer's, and the camera's is the room's, which continues the predicted motion (1 cm sideways). The
    room must win (``TrackingConfig.second_motion``); with the prediction on the drawer's motion, the drawer
    does (the rule follows the prediction, not the larger or the smaller set)."""
    rng = np.random.default_rng(1)
    config = TrackingConfig()
    p_keyframe = np.concatenate([rng.uniform([-1.0, -0.8, 2.0], [1.0, 0.8, 3.0], (40, 3)),  # room
                                 rng.uniform([-0.3, -0.2, 1.2], [0.3, 0.2, 1.3], (60, 3))])  # drawer front
    T_room = np.eye(4)
    T_room[0, 3] = 0.01  # the camera moved 1 cm sideways: T_keyframe_camera
    T_drawer = T_room.copy()
    T_drawer[2, 3] += 0.04  # the drawer came 4 cm closer as well
    p_camera = np.concatenate([p_keyframe[:40] - T_room[:3, 3], p_keyframe[40:] - T_drawer[:3, 3]])
    p_camera += rng.normal(0.0, 0.001, p_camera.shape)
    tolerance, weights = np.full(100, 0.006), np.ones(100)
    largest = tracking.rigid_ransac(p_camera, p_keyframe, tolerance, weights, rng, 256)
    assert largest.inliers[40:].all() and not largest.inliers[:40].any()  # the drawer outnumbers the room
    camera = tracking._continuing_motion(largest, p_camera, p_keyframe, tolerance, weights, T_room, rng, config)
    assert camera.inliers[:40].all() and not camera.inliers[40:].any()
    assert np.allclose(camera.T_dst_src[:3, 3], T_room[:3, 3], atol=0.002)
    kept = tracking._continuing_motion(largest, p_camera, p_keyframe, tolerance, weights, T_drawer, rng, config)
    assert kept.inliers[40:].all()


def test_depth_decides_between_two_motions_even_against_the_prediction():
    """The drawer of the test above, with the prediction already on the drawer's motion (a door that started to
    move pulls the corners' pose, and the constant-velocity prediction follows it: rev_fridge_01_r7 followed a
    textured fridge door 24 deg, camera ATE 29.6 cm). The depth says which motion is the camera's: a dense
    surface model, 900 room points and 100 on the drawer front (area, not corners), moved by each motion, lands
    on the keyframe's surface where that motion is its own. The room must win whatever the prediction
    (``TrackingConfig.second_motion_by_depth``); without depth (agreement None) the prediction decides."""
    rng = np.random.default_rng(1)
    config = TrackingConfig()
    p_keyframe = np.concatenate([rng.uniform([-1.0, -0.8, 2.0], [1.0, 0.8, 3.0], (40, 3)),
                                 rng.uniform([-0.3, -0.2, 1.2], [0.3, 0.2, 1.3], (60, 3))])
    T_room = np.eye(4)
    T_room[0, 3] = 0.01
    T_drawer = T_room.copy()
    T_drawer[2, 3] += 0.04
    p_camera = np.concatenate([p_keyframe[:40] - T_room[:3, 3], p_keyframe[40:] - T_drawer[:3, 3]])
    p_camera += rng.normal(0.0, 0.001, p_camera.shape)
    tolerance, weights = np.full(100, 0.006), np.ones(100)
    largest = tracking.rigid_ransac(p_camera, p_keyframe, tolerance, weights, rng, 256)
    surface_keyframe = np.concatenate([rng.uniform([-1.0, -0.8, 2.0], [1.0, 0.8, 3.0], (900, 3)),
                                       rng.uniform([-0.3, -0.2, 1.2], [0.3, 0.2, 1.3], (100, 3))])
    surface_camera = np.concatenate([surface_keyframe[:900] - T_room[:3, 3], surface_keyframe[900:] - T_drawer[:3, 3]])

    def agreement(T_keyframe_camera):
        moved = surface_camera @ T_keyframe_camera[:3, :3].T + T_keyframe_camera[:3, 3]
        return float((np.linalg.norm(moved - surface_keyframe, axis=1) < 0.006).mean())

    camera = tracking._continuing_motion(largest, p_camera, p_keyframe, tolerance, weights, T_drawer, rng, config,
                                         agreement)
    assert camera.inliers[:40].all() and not camera.inliers[40:].any()
    unseen = tracking._continuing_motion(largest, p_camera, p_keyframe, tolerance, weights, T_drawer, rng, config,
                                         lambda T: None)
    assert unseen.inliers[40:].all()


def test_a_door_turning_near_the_prediction_does_not_take_a_camera_that_barely_moved():
    """100 corners on the room, which the camera saw move 2.3 cm from the prediction (a slow head's jitter), 40 on
    a door turning by 8 deg, whose motion, as a rigid motion of the camera frame, is a 2.0 cm translation from
    the prediction and an 8 deg turn (about a line 14 cm from the camera's centre, as measured). By translation alone the door's is nearer (and took the
    camera, person_slow_rev_cabinet_00_r3); by how far each motion carries the corners, the room's is. The
    larger set is the room's here so that the rule, not the count, is tested: the room must be kept."""
    rng = np.random.default_rng(2)
    config = TrackingConfig()
    p_room = rng.uniform([-1.0, -0.8, 2.0], [1.0, 0.8, 3.0], (100, 3))
    p_door = rng.uniform([0.1, -0.3, 1.3], [0.5, 0.3, 1.35], (40, 3))
    T_predicted = np.eye(4)
    T_room = np.eye(4)
    T_room[0, 3] = 0.023
    T_door = np.eye(4)  # 8 deg about the vertical line x = 0.1 m, z = 0.1 m
    T_door[:3, :3] = Rotation.from_euler("y", 8.0, degrees=True).as_matrix()
    hinge = np.array([0.1, 0.0, 0.1])
    T_door[:3, 3] = hinge - T_door[:3, :3] @ hinge
    door_offset = np.linalg.norm(T_door[:3, 3] - T_predicted[:3, 3])
    assert door_offset < 0.023  # nearer the prediction than the room by translation
    p_keyframe = np.concatenate([p_room + T_room[:3, 3], p_door @ T_door[:3, :3].T + T_door[:3, 3]])
    p_camera = np.concatenate([p_room, p_door]) + rng.normal(0.0, 0.001, (140, 3))
    tolerance, weights = np.full(140, 0.006), np.ones(140)
    largest = tracking.rigid_ransac(p_camera, p_keyframe, tolerance, weights, rng, 256)
    assert largest.inliers[:100].all() and not largest.inliers[100:].any()
    camera = tracking._continuing_motion(largest, p_camera, p_keyframe, tolerance, weights, T_predicted, rng, config)
    assert camera.inliers[:100].all() and not camera.inliers[100:].any()


def test_untrackable_capture_raises_with_reason(tmp_path):
    intrinsics = CaptureIntrinsics(64, 48, 50.0, 50.0, 31.5, 23.5, depth_scale=1000.0, fps=15.0)
    writer = CaptureWriter(tmp_path / "flat", intrinsics)
    for i in range(3):
        writer.write_frame(i, np.full((48, 64, 3), 128, np.uint8), np.ones((48, 64)))
    with pytest.raises(ReconstructionError, match=r"frame 0\): only 0 corners with valid depth"):
        track_camera(load_capture(tmp_path / "flat"))


def test_lost_view_raises_when_most_frames_fail(scenes, tmp_path):
    scene, root = scenes["plain"]
    broken = tmp_path / "nodepth"
    shutil.copytree(root, broken)
    for i in range(1, FRAMES):
        cv2.imwrite(str(broken / "depth" / f"{i:06d}.png"), np.zeros((scene.height, scene.width), np.uint16))
    with pytest.raises(ReconstructionError, match=r"only 1 of 36 frames could be registered.*too few tracked features"):
        track_camera(load_capture(broken))


# ---------------------------------------------------------------------------------------
# Real data: ten TUM fr1_xyz frames against motion capture


@pytest.fixture(scope="module")
def tum_capture(tmp_path_factory):
    if not TUM_DIR.is_dir():
        pytest.skip(f"real data not present at {TUM_DIR}")
    return load_capture(write_tum_capture(tmp_path_factory.mktemp("tum") / "capture"))


def test_tum_fr1_xyz_ate_under_one_centimetre(tum_capture):
    trajectory = track_camera(tum_capture)
    assert trajectory.tracked.all()
    rmse, rot_deg = ate_m(trajectory.T_world_camera, tum_ground_truth())
    # Measured 5.9 mm RMSE / 0.86 deg max over 0.11 m and 5.3 deg of motion. The residual is
    # mostly along the viewing direction, the size expected from fr1's unsynchronised
    # colour and depth (~15 ms apart at ~0.45 m/s); 1 cm is the target.
    assert rmse < 0.010, rmse
    assert rot_deg < 1.5, rot_deg
    relative = invert_transform(trajectory.T_world_camera[:-1]) @ trajectory.T_world_camera[1:]
    gt = tum_ground_truth()
    relative_true = invert_transform(gt[:-1]) @ gt[1:]
    R_err = np.swapaxes(relative_true[:, :3, :3], 1, 2) @ relative[:, :3, :3]
    rpe_deg = np.degrees(np.linalg.norm(Rotation.from_matrix(R_err).as_rotvec(), axis=1))
    assert rpe_deg.max() < 1.0, rpe_deg


def test_config_defaults_are_documented():
    assert TrackingConfig().min_inliers < TrackingConfig().keyframe_min_inliers
    assert math.isclose(TrackingConfig().keyframe_max_rotation_rad, math.radians(20.0))


@pytest.mark.slow
def test_synthetic_smoke_suite(tmp_path_factory):
    """The project's generator (rooms with a hand opening a door or drawer, Kinect-v1 depth
    noise, ~8 cm of camera motion per frame): measured ATE 3.5 / 10.7 / 13.0 mm."""
    if importlib.util.find_spec("funrec.synth") is None:
        pytest.skip("synthetic generator not available")
    from funrec.formats.camera_poses import read_camera_poses
    from funrec.synth import generate_suite

    for root in generate_suite(tmp_path_factory.mktemp("smoke"), suite="smoke"):
        trajectory = track_camera(load_capture(root))
        rmse, rot_deg = ate_m(trajectory.T_world_camera, read_camera_poses(root / "gt" / "camera_poses.txt").T_world_camera)
        assert trajectory.tracked.all(), root.name
        assert rmse < 0.025 and rot_deg < 1.5, (root.name, rmse, rot_deg)
