"""Stage 3 on synthetic point tracks: a door or drawer among static, outlier and hand tracks.

The track generator is tests/helpers/track_scenes.py (numpy only, no rendering).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from funrec.geometry.transforms import invert_transform, make_transform
from funrec.parts.articulation import ArticulationConfig, InteractionEvidence, PartEstimate, estimate_articulation
from funrec.parts.point_tracks import PointTracks
from tests.helpers.track_scenes import PartSpec, SyntheticScene, errors, line_distance, make_scene

# ----------------------------------------------------------------------------------------------
# The tolerances the error measures (tests/helpers/track_scenes.py) are checked against.

AXIS_TOL_DEG = 1.0
"""3 mm noise over ~150 tracks spread over a 0.45 m door: the stage-3 axis error is ~0.2 deg."""
PIVOT_TOL_M = 0.01
"""Pivot line distance: ~2 mm expected at 3 mm noise."""
STATE_TOL_RAD = np.deg2rad(1.0)
STATE_TOL_M = 0.005
"""Mean state error: per-frame rigid fits of ~100 points at 3 mm noise give ~0.1 deg / ~0.5 mm."""


def check_part(part: PartEstimate, spec: PartSpec) -> None:
    assert part.joint_type == spec.joint_type
    err = errors(part, spec)
    assert err["axis_deg"] < AXIS_TOL_DEG, err
    if spec.joint_type == "revolute":
        assert err["pivot_m"] < PIVOT_TOL_M, err
        assert err["state"] < STATE_TOL_RAD, err
    else:
        assert err["state"] < STATE_TOL_M, err
    assert part.states[0] == 0.0
    assert np.isfinite(part.states).all()


def membership(part: PartEstimate, spec: PartSpec) -> tuple[float, float]:
    """(precision, recall) of the part's tracks against the true part tracks."""
    hit = np.isin(part.track_indices, spec.track_indices)
    return float(hit.mean()), float(hit.sum() / len(spec.track_indices))


@pytest.mark.parametrize(
    ("joint_type", "axis", "seed"),
    [
        ("revolute", np.array([0.0, 1.0, 0.0]), 0),  # vertical hinge (camera y is down)
        ("revolute", np.array([1.0, 0.0, 0.0]), 1),  # horizontal hinge (oven door, top flap)
        ("revolute", None, 2),  # random axis
        ("prismatic", None, 3),
    ],
)
def test_estimates_joint_among_static_outliers_and_hand(joint_type: str, axis: np.ndarray | None, seed: int) -> None:
    scene = make_scene(np.random.default_rng(seed), (joint_type,), axes=(axis,))
    estimate = estimate_articulation(scene.tracks)
    assert len(estimate.parts) == 1, [p.joint_type for p in estimate.parts]
    part = estimate.interacted
    assert part is not None
    check_part(part, scene.parts[0])
    precision, recall = membership(part, scene.parts[0])
    # Recall misses only tracks near a hinge that move less than eps_s, and re-seeded tracks
    # seen for fewer than min_track_frames frames.
    assert precision > 0.97 and recall > 0.75, (precision, recall)
    assert not np.isin(part.track_indices, scene.hand_tracks).any()
    assert part.state_range[1] > 0.0  # signed so that opening is positive
    if joint_type == "revolute":
        assert abs(part.pivot_world @ part.axis_world) < 1e-9  # pivot closest to the origin


def test_static_scene_with_outliers_has_no_part() -> None:
    # Camera-only video: the part never moves, there is no hand, random-walk outliers remain.
    scene = make_scene(np.random.default_rng(4), ("revolute",), max_states=(0.0,), hand_tracks=0, outlier_fraction=0.1)
    estimate = estimate_articulation(scene.tracks)
    assert estimate.parts == ()
    assert estimate.interacted is None


def test_small_door_motion_is_still_revolute() -> None:
    # A 12 deg opening: each track's arc looks almost straight, but the rigid rotation of the
    # whole cluster (0.21 rad) is ~100 noise sigmas.
    scene = make_scene(np.random.default_rng(5), ("revolute",), max_states=(np.deg2rad(12.0),))
    part = estimate_articulation(scene.tracks).interacted
    assert part is not None and part.joint_type == "revolute"
    assert part.evidence.residual_revolute_m < part.evidence.residual_prismatic_m
    err = errors(part, scene.parts[0])
    # Less motion, less leverage on the axis: 3 deg and 2 cm (an axis through a 0.45 m door).
    assert err["axis_deg"] < 3.0 and err["pivot_m"] < 0.02, err


def test_small_drawer_motion_is_still_prismatic() -> None:
    scene = make_scene(np.random.default_rng(6), ("prismatic",), max_states=(0.06,))
    part = estimate_articulation(scene.tracks).interacted
    assert part is not None and part.joint_type == "prismatic"
    assert part.evidence.max_rotation_rad < ArticulationConfig().min_rotation_rad


def two_part_scene() -> SyntheticScene:
    # A door (150 tracks) opened in the first half, a drawer (100 tracks) in the second half.
    return make_scene(np.random.default_rng(7), ("revolute", "prismatic"), part_tracks=150, static_tracks=250)


def test_two_parts_ranked_by_size_without_evidence() -> None:
    scene = two_part_scene()
    estimate = estimate_articulation(scene.tracks)
    assert sorted(p.joint_type for p in estimate.parts) == ["prismatic", "revolute"]
    assert estimate.parts[0].size_score >= estimate.parts[1].size_score
    for part in estimate.parts:
        spec = next(s for s in scene.parts if s.joint_type == part.joint_type)
        check_part(part, spec)
        assert membership(part, spec)[0] > 0.97
        assert part.evidence_score is None


@pytest.mark.parametrize("masked", [0, 1])
def test_interaction_evidence_selects_the_masked_part(masked: int) -> None:
    scene = two_part_scene()
    evidence = InteractionEvidence(scene.object_mask_lookup(part=masked), np.ones(scene.tracks.num_frames))
    estimate = estimate_articulation(scene.tracks, evidence)
    assert estimate.parts[0].joint_type == scene.parts[masked].joint_type
    assert estimate.parts[0].evidence_score > 5 * estimate.parts[1].evidence_score


def test_evidence_from_mask_images_reads_one_frame_at_a_time() -> None:
    scene = two_part_scene()
    lookup = scene.object_mask_lookup(part=1)
    v, u = np.mgrid[0:480:4, 0:640:4]
    grid = np.stack([u.ravel(), v.ravel()], -1).astype(float)
    reads: list[int] = []

    def mask_at(frame: int) -> np.ndarray:
        reads.append(frame)
        coarse = lookup(frame, grid).reshape(u.shape) > 0
        return np.kron(coarse, np.ones((4, 4), dtype=bool))  # (480, 640) bool image

    confidence = np.zeros(scene.tracks.num_frames)
    confidence[::3] = 0.8  # masks on every third frame only
    estimate = estimate_articulation(scene.tracks, InteractionEvidence.from_masks(mask_at, confidence))
    assert estimate.parts[0].joint_type == "prismatic"
    assert sorted(reads) == list(range(0, scene.tracks.num_frames, 3))


def _equivariance_scene() -> SyntheticScene:
    return make_scene(np.random.default_rng(8), ("revolute",), num_frames=30, part_tracks=80, static_tracks=80, hand_tracks=10)


EQUIVARIANCE_SCENE = _equivariance_scene()
EQUIVARIANCE_BASE = estimate_articulation(EQUIVARIANCE_SCENE.tracks).interacted


@settings(deadline=None, max_examples=8)
@given(
    rotvec=arrays(np.float64, 3, elements=st.floats(-3.0, 3.0)),
    translation=arrays(np.float64, 3, elements=st.floats(-2.0, 2.0)),
)
def test_axis_estimate_is_equivariant_under_rigid_motion(rotvec: np.ndarray, translation: np.ndarray) -> None:
    T_new_world = make_transform(Rotation.from_rotvec(rotvec).as_matrix(), translation)
    tracks = EQUIVARIANCE_SCENE.tracks
    p_new = tracks.p_world @ T_new_world[:3, :3].T + T_new_world[:3, 3]
    moved = estimate_articulation(PointTracks(p_new, tracks.uv, tracks.visible)).interacted
    base = EQUIVARIANCE_BASE
    assert moved is not None and base is not None and moved.joint_type == base.joint_type
    # Every step is rigid-invariant and the rng is re-seeded identically, so only round-off
    # separates the two runs; the joint is refined by iterative least squares (scipy
    # least_squares, stopping at relative tolerances of 1e-8 or an evaluation cap), whose
    # stopping point round-off moves by up to ~1e-4 (rad, m; 1.1e-4 m seen for the pivot):
    # 1e-3 still fails any frame-dependent step, which would move the axis by degrees.
    np.testing.assert_allclose(moved.axis_world, T_new_world[:3, :3] @ base.axis_world, atol=1e-3)
    pivot_new = T_new_world[:3, :3] @ base.pivot_world + T_new_world[:3, 3]
    assert line_distance(moved.axis_world, moved.pivot_world, moved.axis_world, pivot_new) < 1e-3
    np.testing.assert_allclose(moved.states, base.states, atol=1e-3)
    np.testing.assert_array_equal(moved.track_indices, base.track_indices)


# ----------------------------------------------------------------------------------------------
# Rendered captures: stages 1, 2, 3 and 5 on funrec.synth's smoke door and drawer.

RENDERED_TOL = {
    # Measured on these two captures: door 3.8-5.3 deg, 1-10 mm, 0.3 deg; drawer 1.2-1.9 deg,
    # 1-2 mm. The door turns edge-on to the camera after 0.42 rad, so its axis rests on ~0.4 rad
    # of arc seen by ~40 short tracks; the limits leave ~1.5x margin over the measurements.
    "revolute": {"axis_deg": 8.0, "pivot_m": 0.03, "state": np.deg2rad(2.0)},
    "prismatic": {"axis_deg": 3.0, "state": 0.01},
}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["smoke_rev_00", "smoke_pri_00"])
def test_rendered_capture_joint_against_ground_truth(smoke_captures, name: str) -> None:
    from funrec.bench import metrics
    from funrec.camera.tracking import track_camera
    from funrec.formats.capture import load_capture
    from funrec.formats.ground_truth import read_ground_truth
    from funrec.parts.part_motion import refine_part_motion
    from funrec.parts.point_tracks import track_points

    capture = load_capture(smoke_captures[name])
    truth = read_ground_truth(smoke_captures[name] / "gt")
    tracks = track_points(capture, track_camera(capture))
    evidence = InteractionEvidence.from_hand_masks(lambda frame: capture.mask("hand", frame), np.ones(len(capture)))
    estimate = estimate_articulation(tracks, evidence)
    assert estimate.parts, "no part found"
    motion = refine_part_motion(tracks, estimate.parts[0])
    true_part = truth.parts[0].part
    # The pipeline's world is camera 0; the ground truth's is its own: map through frame 0.
    T_camera0_world = invert_transform(truth.T_world_camera[0])
    axis_true = T_camera0_world[:3, :3] @ true_part.axis_world
    pivot_true = None if true_part.pivot_world is None else T_camera0_world[:3, :3] @ true_part.pivot_world + T_camera0_world[:3, 3]
    spec = PartSpec(true_part.joint_type, axis_true, pivot_true, np.asarray(true_part.states), np.zeros((4, 3)), np.zeros(3),
                    np.zeros(0, np.int64))
    assert motion.joint_type == spec.joint_type
    err = errors(motion, spec)
    if spec.joint_type == "revolute":  # FORMATS.md section 5: the distance between the two axis lines
        err["pivot_m"] = metrics.line_distance(motion.pivot_world, motion.axis_world, pivot_true, axis_true)
    tol = RENDERED_TOL[spec.joint_type]
    assert all(err[key] < tol[key] for key in tol), (err, tol)
    # Tracked while it moved: the drawer's front is hidden by the arm until it has come out a
    # little, so the part may start inside the interaction, not before it.
    first, last = truth.parts[0].intervals[0]
    assert motion.frames[0] < last and motion.frames[-1] > first, (motion.frames[[0, -1]], (first, last))


@pytest.mark.slow
def test_rendered_camera_only_capture_has_no_part(smoke_captures) -> None:
    # Without hand masks, KLT drift of static tracks under a fast-walking camera (0.25 m per frame
    # in smoke_static_00) forms a coherent 6 cm "drawer"; its seed does not follow it
    # (min_seed_coherence), so the whole capture's tracks, not only its dynamic fragments, yield
    # no part.
    from funrec.camera.tracking import track_camera
    from funrec.formats.capture import load_capture
    from funrec.parts.point_tracks import track_points

    capture = load_capture(smoke_captures["smoke_static_00"])
    assert estimate_articulation(track_points(capture, track_camera(capture))).parts == ()
