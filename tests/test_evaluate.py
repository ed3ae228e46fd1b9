"""Tests of funrec.bench.evaluate and funrec.bench.baselines on a hand-built ground-truth sequence.

The fixture (``write_tiny_sequence``, tests/helpers/tiny_sequence.py) is written with numpy only, so
these tests do not depend on funrec.synth: a wall and a floor as static points, a revolute door and a prismatic drawer
front as part points, a moving camera whose frame 0 is not the world frame, and part masks
made by projecting the posed part points.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from funrec.bench.baselines import write_oracle_twin, write_trivial_twin
from funrec.bench.evaluate import EvalConfig, evaluate_twin, evaluation_to_json, format_evaluation
from funrec.formats.camera_poses import read_camera_poses, write_camera_poses
from funrec.formats.capture import write_mask
from funrec.formats.twin import TwinArticulation, make_part, read_articulation, write_articulation
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import invert_transform, make_transform, rotation_about_axis, transform_points
from tests.helpers.tiny_sequence import FRAME_COUNT, grid, write_tiny_sequence

# Tolerances of a perfect twin. Files store camera translations with 6 decimals (0.5 um) and
# quaternions with 7 (5e-8 rad, < 0.2 um at the 3 m lever arms here); PLY points are float32
# (relative 6e-8, < 0.2 um at 3 m). Ten micrometres is far above that round-off and far below
# any real error, so these bounds mean "exact".
EXACT_M = 1e-5
EXACT_DEG = 1e-3
EXACT_PERCENT = 1e-3


def transform_twin(src: Path, dst: Path, T_new_old: np.ndarray) -> Path:
    """Copy a twin with point-cloud meshes into another world frame: p_new = T_new_old @ p_old."""
    shutil.copytree(src, dst)
    articulation = read_articulation(src)
    parts = []
    for part in articulation.parts:
        pivot = None if part.pivot_world is None else transform_points(T_new_old, part.pivot_world[None])[0]
        parts.append(make_part(part.name, part.joint_type, T_new_old[:3, :3] @ part.axis_world, pivot, part.frames, part.states, part.state_range, part.mesh, part.masks))
    for mesh in [articulation.static_mesh, *(p.mesh for p in articulation.parts)]:
        p_old = np.asarray(trimesh.load(str(src / mesh), process=False).vertices, dtype=float)
        trimesh.PointCloud(transform_points(T_new_old, p_old)).export(str(dst / mesh))
    poses = read_camera_poses(src / "camera_poses.txt")
    write_camera_poses(dst / "camera_poses.txt", T_new_old @ poses.T_world_camera, poses.frames)
    write_articulation(dst / "articulation.json", TwinArticulation(articulation.frame_count, tuple(parts), articulation.static_mesh))
    return dst


def edit_part(twin: Path, name: str, **changes) -> None:
    """Rewrite one part of a twin's articulation.json with make_part fields replaced."""
    articulation = read_articulation(twin)
    parts = []
    for part in articulation.parts:
        fields = dict(
            name=part.name, joint_type=part.joint_type, axis_world=part.axis_world, pivot_world=part.pivot_world,
            frames=part.frames, states=part.states, state_range=None, mesh=part.mesh, masks=part.masks,
        )
        if part.name == name:
            fields.update(changes)
        parts.append(make_part(**fields))
    write_articulation(twin / "articulation.json", TwinArticulation(articulation.frame_count, tuple(parts), articulation.static_mesh))


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    return write_tiny_sequence(tmp_path_factory.mktemp("suite"))


@pytest.fixture(scope="module")
def oracle(capture, tmp_path_factory) -> Path:
    return write_oracle_twin(capture, tmp_path_factory.mktemp("twins") / "oracle")


def _copy(twin: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(twin, tmp_path / "twin"))


def assert_perfect(evaluation) -> None:
    assert evaluation.ok, evaluation.failure
    assert evaluation.invented_parts == ()
    assert len(evaluation.parts) == 2
    for part in evaluation.parts:
        assert not part.failed, part.failure
        assert part.predicted_name == part.true_name
        assert part.common_frames == FRAME_COUNT
        assert part.axis_error_deg < EXACT_DEG
        assert part.state_error < (EXACT_DEG if part.joint_type == "revolute" else EXACT_M)
        assert part.adds_auc > 100 - EXACT_PERCENT and part.add_auc > 100 - EXACT_PERCENT
        assert part.miou == pytest.approx(100.0)  # masks are copied: exact
    door = evaluation.parts[0]
    assert door.joint_type == "revolute" and door.pivot_error_m < EXACT_M
    assert evaluation.parts[1].pivot_error_m is None
    assert evaluation.chamfer_cm < 100 * EXACT_M
    assert evaluation.camera_ate_cm < 100 * EXACT_M


def test_oracle_twin_scores_perfectly(capture, oracle):
    evaluation = evaluate_twin(oracle, capture / "gt")
    assert_perfect(evaluation)
    # The oracle's world is the true camera-0 frame, not the GT world: the mapping was needed.
    T_world_camera0_gt = read_camera_poses(capture / "gt" / "camera_poses.txt").T_world_camera[0]
    assert not np.allclose(T_world_camera0_gt, np.eye(4), atol=0.1)
    np.testing.assert_allclose(read_camera_poses(oracle / "camera_poses.txt").T_world_camera[0], np.eye(4), atol=1e-6)
    # Accepts the capture folder as well as its gt/ folder.
    assert_perfect(evaluate_twin(oracle, capture))


@settings(deadline=None, max_examples=4, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rotvec=st.tuples(*[st.floats(-3.0, 3.0)] * 3),
    translation=st.tuples(*[st.floats(-5.0, 5.0)] * 3),
)
def test_same_twin_in_another_world_frame_scores_the_same(capture, oracle, tmp_path_factory, rotvec, translation):
    T_new_old = make_transform(Rotation.from_rotvec(rotvec).as_matrix(), translation)
    moved = transform_twin(oracle, tmp_path_factory.mktemp("moved") / "twin", T_new_old)
    evaluation = evaluate_twin(moved, capture / "gt")
    assert_perfect(evaluation)


def test_axis_rotated_by_5_degrees_scores_5_degrees(capture, oracle, tmp_path):
    twin = _copy(oracle, tmp_path)
    door = read_articulation(twin).parts[0]
    # Tilt the axis about the door's normal through the pivot, so the lines still intersect.
    axis_tilted = rotation_about_axis(np.cross(door.axis_world, [1.0, 0.0, 0.0]), np.radians(5.0)) @ door.axis_world
    edit_part(twin, "door", axis_world=axis_tilted)
    part = evaluate_twin(twin, capture / "gt").parts[0]
    assert part.axis_error_deg == pytest.approx(5.0, abs=EXACT_DEG)
    assert part.pivot_error_m < EXACT_M  # the tilted axis still passes through the true pivot
    assert part.add_auc < 100.0 - 1.0  # a 5 degree tilt moves the door by centimetres


def test_flipped_axis_and_states_score_the_same(capture, oracle, tmp_path):
    twin = _copy(oracle, tmp_path)
    for part in read_articulation(twin).parts:
        edit_part(twin, part.name, axis_world=-part.axis_world, states=-part.states)
    assert_perfect(evaluate_twin(twin, capture / "gt"))


def test_canonical_state_convention_does_not_matter(capture, oracle, tmp_path):
    """A twin whose canonical door is the open door (state 1.2 rad) with shifted states is perfect."""
    twin = _copy(oracle, tmp_path)
    door = read_articulation(twin).parts[0]
    T_open_closed = joint_transform("revolute", door.axis_world, door.pivot_world, 1.2)
    p_closed = np.asarray(trimesh.load(str(twin / door.mesh), process=False).vertices, dtype=float)
    trimesh.PointCloud(transform_points(T_open_closed, p_closed)).export(str(twin / door.mesh))
    edit_part(twin, "door", states=door.states - 1.2)
    assert_perfect(evaluate_twin(twin, capture / "gt"))


def test_missing_predicted_masks_count_as_zero(capture, oracle, tmp_path):
    twin = _copy(oracle, tmp_path)
    true_frames = [f for f in range(FRAME_COUNT) if cv2.imread(str(capture / "gt/masks/door" / f"{f:06d}.png"), 0).any()]
    for frame in true_frames[:3]:
        (twin / "masks" / "door" / f"{frame:06d}.png").unlink()
    door, drawer = evaluate_twin(twin, capture / "gt").parts
    assert door.miou == pytest.approx(100.0 * (len(true_frames) - 3) / len(true_frames))
    assert drawer.miou == pytest.approx(100.0)  # its empty frame-0 true mask is ignored


def test_wrong_joint_type_is_a_failure(capture, oracle, tmp_path):
    twin = _copy(oracle, tmp_path)
    edit_part(twin, "drawer", joint_type="revolute", pivot_world=[0.0, 0.0, 1.0])
    door, drawer = evaluate_twin(twin, capture / "gt").parts
    assert not door.failed
    assert drawer.failed and "wrong joint type" in drawer.failure
    assert drawer.axis_error_deg is None


def test_invented_part_is_counted_and_leaves_scores_alone(capture, oracle, tmp_path):
    twin = _copy(oracle, tmp_path)
    articulation = read_articulation(twin)
    trimesh.PointCloud(grid([3, 3, 3], [0.3, 0, 0], [0, 0.3, 0], 0.05)).export(str(twin / "meshes/ghost.ply"))
    ghost = make_part("ghost", "prismatic", [1, 0, 0], None, [3, 4], [0.0, 0.1], mesh="meshes/ghost.ply")
    write_articulation(twin / "articulation.json", TwinArticulation(FRAME_COUNT, (*articulation.parts, ghost), articulation.static_mesh))
    evaluation = evaluate_twin(twin, capture / "gt")
    assert evaluation.invented_parts == ("ghost",)
    assert all(not p.failed and p.axis_error_deg < EXACT_DEG for p in evaluation.parts)
    assert evaluation.chamfer_cm > 1.0  # the ghost's points are metres from any true point


@pytest.mark.parametrize(
    ("breakage", "expected"),
    [
        (lambda twin: (twin / "articulation.json").unlink(), "articulation.json: file is missing"),
        (lambda twin: (twin / "articulation.json").write_text("{not json"), "not valid JSON"),
        (lambda twin: (twin / "articulation.json").write_text(json.dumps({"format": "funrec-twin/1", "frame_count": 12, "parts": [{"name": "x"}]})), "missing 'joint_type'"),
        (lambda twin: (twin / "camera_poses.txt").unlink(), "camera_poses.txt: missing camera poses file"),
        (lambda twin: (twin / "meshes" / "door.ply").unlink(), "door.ply: file is missing"),
        (lambda twin: shutil.rmtree(twin), "file is missing"),
    ],
)
def test_broken_twin_is_a_failure_with_the_reason(capture, oracle, tmp_path, breakage, expected):
    twin = _copy(oracle, tmp_path)
    breakage(twin)
    evaluation = evaluate_twin(twin, capture / "gt")
    assert not evaluation.ok and expected in evaluation.failure
    assert [p.true_name for p in evaluation.parts] == ["door", "drawer"]
    assert all(p.failed and expected in p.failure for p in evaluation.parts)
    assert "FAILED" in format_evaluation(evaluation)
    json.dumps(evaluation_to_json(evaluation), allow_nan=False)


def test_unreadable_ground_truth_is_a_failure(oracle, tmp_path):
    evaluation = evaluate_twin(oracle, tmp_path / "nowhere")
    assert not evaluation.ok and "ground truth unreadable" in evaluation.failure and evaluation.parts == ()


def test_trivial_twin_scores_badly_without_crashing(capture, tmp_path):
    twin = write_trivial_twin(capture, tmp_path / "trivial")
    evaluation = evaluate_twin(twin, capture / "gt")
    assert evaluation.ok, evaluation.failure
    assert evaluation.camera_ate_cm > 1.0  # the true camera moves by decimetres
    assert evaluation.chamfer_cm > 10.0  # one small plane against a wall, floor and furniture
    matched = [p for p in evaluation.parts if p.predicted_name is not None]
    assert len(evaluation.invented_parts) + len(matched) == 1
    for part in matched:  # if the plane happens to match, its zero states still score badly
        assert part.failed or part.state_error > 1.0 and part.miou == 0.0
    text = format_evaluation(evaluation)
    assert "door (revolute)" in text and "camera ATE" in text
    json.dumps(evaluation_to_json(evaluation), allow_nan=False)


def test_existing_non_twin_folder_is_not_overwritten(capture, tmp_path):
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("keep me")
    with pytest.raises(Exception, match="not a twin folder"):
        write_trivial_twin(capture, precious)
    assert (precious / "notes.txt").read_text() == "keep me"


def test_mesh_surface_is_sampled_for_chamfer(capture, oracle, tmp_path):
    """A twin whose static 'mesh' is a real triangle mesh is sampled uniformly over its faces."""
    twin = _copy(oracle, tmp_path)
    # Replace the point-cloud static mesh by the wall and floor as four triangles 2 cm in front of
    # the true points: CD = 2 cm up to sampling (the true grids end at the same borders).
    T_world_camera0 = read_camera_poses(capture / "gt" / "camera_poses.txt").T_world_camera[0]
    T_twin_gt = invert_transform(T_world_camera0)
    corners = np.array([[-1, 0.98, 0], [1, 0.98, 0], [1, 0.98, 2], [-1, 0.98, 2], [-1, -1, 0.02], [1, -1, 0.02], [1, 1, 0.02], [-1, 1, 0.02]])
    mesh = trimesh.Trimesh(transform_points(T_twin_gt, corners), [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], process=False)
    mesh.export(str(twin / "meshes" / "static.ply"))
    evaluation = evaluate_twin(twin, capture / "gt", EvalConfig(surface_spacing_m=0.01))
    # Bounds: every sample lies 2 cm off the true planes, whose points are on a 5 cm grid, so
    # pred->true is between 2 cm and sqrt(2^2 + 3.54^2) = 4.06 cm (farthest from a grid node).
    # true->pred is 2 cm (+ < 0.5 cm sampling gap at 1 cm spacing) for the 79 % static points
    # and 0 for the exactly reproduced part points. So 0.5 (2 + 0.79 * 2) = 1.79 < CD <
    # 0.5 (4.06 + 2.5) = 3.28 cm; the expected value is about 2.2 cm.
    assert 1.79 < evaluation.chamfer_cm < 3.28


def test_twin_tracking_only_some_frames_is_scored_on_those(capture, oracle, tmp_path):
    """A part tracked in frames 3-8 only (masks only there) is perfect on its common frames."""
    twin = _copy(oracle, tmp_path)
    door = read_articulation(twin).parts[0]
    edit_part(twin, "door", frames=door.frames[3:9], states=door.states[3:9])
    for frame in [*range(3), *range(9, FRAME_COUNT)]:
        (twin / "masks" / "door" / f"{frame:06d}.png").unlink(missing_ok=True)
    door_eval = evaluate_twin(twin, capture / "gt").parts[0]
    assert door_eval.common_frames == 6 and not door_eval.failed
    assert door_eval.state_error < EXACT_DEG and door_eval.add_auc > 100 - EXACT_PERCENT
    assert door_eval.miou == pytest.approx(100.0)


def test_oracle_on_a_synth_sequence_if_available(tmp_path):
    """With funrec.synth present, the oracle of its tiny sequence scores perfectly too."""
    import importlib.util

    if importlib.util.find_spec("funrec.synth") is None:
        pytest.skip("funrec.synth is not available")
    from funrec.synth import generate_sequence, tiny_spec

    capture_dir = generate_sequence(tiny_spec(0), tmp_path)
    evaluation = evaluate_twin(write_oracle_twin(capture_dir, tmp_path / "oracle"), capture_dir / "gt")
    assert evaluation.ok and evaluation.invented_parts == ()
    for part in evaluation.parts:
        assert not part.failed and part.axis_error_deg < EXACT_DEG and part.add_auc > 100 - EXACT_PERCENT
        assert part.miou is None or part.miou == pytest.approx(100.0)
    assert evaluation.chamfer_cm < 100 * EXACT_M and evaluation.camera_ate_cm < 100 * EXACT_M


# --------------------------------------------------------------------------------------------
# Affordance scores: contact_error_m per part and hand_iou per sequence
# --------------------------------------------------------------------------------------------


def _write_contact(twin: Path, contacts: dict[str, np.ndarray], hand_source: str = "detected") -> None:
    """affordances.json with one held part per entry, contact point (twin world, canonical state)."""
    from funrec.formats.affordances import Affordances, Interaction, PartAffordance, write_affordances

    parts = []
    for name, contact in contacts.items():
        joint_type = "revolute" if name == "door" else "prismatic"
        frames = np.arange(2, 8)
        parts.append(PartAffordance(name, joint_type, contact, make_transform(np.eye(3), contact), True,
                                    (Interaction(frames, frames / 15.0, np.zeros(len(frames))),), np.zeros((0, 3)), np.zeros(0),
                                    np.zeros(2), np.tile(contact, (2, 1))))
    write_affordances(twin, Affordances(tuple(parts), (), hand_source, 15.0))


def _true_handles_in(twin: Path, capture: Path) -> dict[str, np.ndarray]:
    """The true handle centres mapped into a twin's world frame through frame 0 (canonical state)."""
    from funrec.formats.ground_truth import read_ground_truth

    gt = read_ground_truth(capture / "gt")
    T_twin_gt = read_camera_poses(twin / "camera_poses.txt").T_world_camera[0] @ invert_transform(gt.T_world_camera[0])
    return {p.part.name: transform_points(T_twin_gt, p.handle_world[None])[0] for p in gt.parts}


def test_contact_error_is_the_distance_to_the_true_handle(capture, oracle, tmp_path):
    twin = transform_twin(oracle, tmp_path / "twin", make_transform(Rotation.from_rotvec([0.3, -0.8, 0.2]).as_matrix(), [1.0, -2.0, 0.5]))
    handles = _true_handles_in(twin, capture)
    offset = np.array([0.012, -0.016, 0.0])  # 2 cm
    _write_contact(twin, {"door": handles["door"] + offset})
    door, drawer = evaluate_twin(twin, capture / "gt").parts
    # The oracle's states are the true ones, so both sides move together: only file round-off.
    assert door.contact_error_m == pytest.approx(0.02, abs=EXACT_M)
    assert drawer.contact_error_m is None  # no affordance for it
    assert evaluation_to_json(evaluate_twin(twin, capture / "gt"))["parts"][0]["contact_error_m"] == pytest.approx(0.02, abs=EXACT_M)


def test_contact_error_does_not_depend_on_the_canonical_state(capture, oracle, tmp_path):
    """A twin whose canonical state is the door's state at frame 5: its contact point is the
    true handle moved there, and still scores 0."""
    from funrec.formats.ground_truth import read_ground_truth

    twin = _copy(oracle, tmp_path)
    door = next(p for p in read_articulation(twin).parts if p.name == "door")
    shift = float(door.states[5])
    T_world_shift = joint_transform("revolute", door.axis_world, door.pivot_world, shift)
    edit_part(twin, "door", states=door.states - shift)
    mesh = twin / door.mesh
    trimesh.PointCloud(transform_points(T_world_shift, np.asarray(trimesh.load(str(mesh), process=False).vertices))).export(str(mesh))
    gt = read_ground_truth(capture / "gt")
    assert gt.parts[0].part.name == "door"
    handle = transform_points(T_world_shift, _true_handles_in(twin, capture)["door"][None])[0]
    _write_contact(twin, {"door": handle})
    evaluation = evaluate_twin(twin, capture / "gt")
    assert evaluation.parts[0].contact_error_m == pytest.approx(0.0, abs=EXACT_M)
    assert "contact 0.0 cm" in format_evaluation(evaluation)


def test_malformed_affordances_are_a_warning_not_a_failure(capture, oracle, tmp_path):
    twin = _copy(oracle, tmp_path)
    (twin / "affordances.json").write_text('{"format": "funrec-affordances/0"}')
    evaluation = evaluate_twin(twin, capture / "gt")
    assert evaluation.ok and all(p.contact_error_m is None for p in evaluation.parts)
    assert any("affordances.json" in w and "format" in w for w in evaluation.warnings)


def test_hand_iou_scores_detected_hand_masks(capture, oracle, tmp_path):
    gt_dir = Path(shutil.copytree(capture / "gt", tmp_path / "gt"))
    twin = _copy(oracle, tmp_path)
    square = np.zeros((48, 64), bool)
    square[10:20, 10:20] = True
    for frame in range(FRAME_COUNT):
        write_mask(gt_dir / "masks" / "hand" / f"{frame:06d}.png", square if frame == 3 else np.zeros_like(square))
    # Frame 3: the predicted square is shifted by 5 columns, IoU 50 / 150. Frame 8: a detection
    # where there is no hand, IoU 0. Other frames: both empty, not scored. Missing files are empty.
    write_mask(twin / "masks" / "hand" / f"{3:06d}.png", np.roll(square, 5, axis=1))
    write_mask(twin / "masks" / "hand" / f"{8:06d}.png", square)
    write_mask(twin / "masks" / "hand" / f"{9:06d}.png", np.zeros_like(square))
    evaluation = evaluate_twin(twin, gt_dir)
    assert evaluation.hand_iou == pytest.approx(100.0 * (50 / 150 + 0.0) / 2)  # exact pixel counts
    assert evaluation_to_json(evaluation)["hand_iou"] == evaluation.hand_iou
    assert "hand IoU 16.7 %" in format_evaluation(evaluation)
    # Masks copied from the capture are no estimate: not scored.
    _write_contact(twin, {}, hand_source="capture")
    assert evaluate_twin(twin, gt_dir).hand_iou is None
    assert evaluate_twin(oracle, gt_dir).hand_iou is None  # no masks/hand/ in the twin
