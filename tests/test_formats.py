"""Write, then read, every FORMATS.md file: camera poses, articulation.json, gt.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from funrec.errors import FormatError
from funrec.formats.camera_poses import read_camera_poses, write_camera_poses
from funrec.formats.ground_truth import GroundTruthPart, read_ground_truth, write_ground_truth_json
from funrec.formats.twin import TwinArticulation, make_part, read_articulation, write_articulation
from funrec.geometry import make_transform

# camera_poses.txt keeps 6 decimals of translation (1 micrometre) and 7 of quaternion
# (rotation error ~1e-7 rad): 2e-6 covers both after the matrix conversion.
FILE_ATOL = 2e-6


@settings(deadline=None, max_examples=25, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    arrays(np.float64, (4, 4), elements=st.floats(-1.0, 1.0)).filter(lambda q: np.all(np.linalg.norm(q, axis=1) > 0.1)),
    arrays(np.float64, (4, 3), elements=st.floats(-20.0, 20.0)),
)
def test_camera_poses_round_trip(tmp_path: Path, quat_xyzw: np.ndarray, t: np.ndarray) -> None:
    T_world_camera = make_transform(Rotation.from_quat(quat_xyzw).as_matrix(), t)
    path = tmp_path / "camera_poses.txt"
    write_camera_poses(path, T_world_camera, frames=[0, 3, 4, 9])
    poses = read_camera_poses(path)
    np.testing.assert_array_equal(poses.frames, [0, 3, 4, 9])
    np.testing.assert_allclose(poses.T_world_camera, T_world_camera, atol=FILE_ATOL)


def test_camera_poses_errors_name_the_line(tmp_path: Path) -> None:
    path = tmp_path / "camera_poses.txt"
    path.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match="line 2: expected 8 values"):
        read_camera_poses(path)
    path.write_text("0 0 0 0 0 0 0 2\n")
    with pytest.raises(FormatError, match="line 1: quaternion is not unit length"):
        read_camera_poses(path)


def _twin() -> TwinArticulation:
    door = make_part("part_0", "revolute", [0, 0, 2.0], [1.0, 2.0, 0.7], [3, 4, 5], [0.0, 0.1, 0.25], mesh="meshes/part_0.ply", masks="masks/part_0")
    drawer = make_part("part_1", "prismatic", [1.0, 0, 0], None, [7, 8], [0.0, 0.2])
    return TwinArticulation(frame_count=10, parts=(door, drawer))


def test_articulation_round_trip(tmp_path: Path) -> None:
    twin = _twin()
    write_articulation(tmp_path / "articulation.json", twin)
    data = json.loads((tmp_path / "articulation.json").read_text())
    assert data["format"] == "funrec-twin/2" and "pivot" not in data["parts"][1]
    assert data["parts"][0]["pivot"] == [1.0, 2.0, 0.0]  # moved to the point closest to the origin
    back = read_articulation(tmp_path)
    assert back.frame_count == 10 and [p.name for p in back.parts] == ["part_0", "part_1"]
    for a, b in zip(twin.parts, back.parts):
        np.testing.assert_allclose(a.T_world_part(), b.T_world_part(), atol=1e-12)
        assert a.state_range == b.state_range and a.mesh == b.mesh


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format="funrec-twin/9"), "format is 'funrec-twin/9'"),
        (lambda d: d["parts"][0].pop("pivot"), r"parts\[0\] is revolute but has no 'pivot'"),
        (lambda d: d["parts"][0].update(axis=[0, 0, 2]), r"parts\[0\]\.axis must be a unit vector"),
        (lambda d: d["parts"][1].update(states=[0.0]), r"parts\[1\]: 2 frames but 1 states"),
        (lambda d: d["parts"][1].update(joint_type="ball"), r"parts\[1\]\.joint_type is 'ball'"),
        (lambda d: d["parts"][1].update(frames=[8, 7]), "frames must be increasing"),
        (lambda d: d.update(frame_count=8), "frame 8 >= frame_count 8"),
    ],
)
def test_malformed_articulation_names_the_field(tmp_path: Path, edit, message: str) -> None:
    write_articulation(tmp_path / "articulation.json", _twin())
    data = json.loads((tmp_path / "articulation.json").read_text())
    edit(data)
    (tmp_path / "articulation.json").write_text(json.dumps(data))
    with pytest.raises(FormatError, match=message):
        read_articulation(tmp_path / "articulation.json")


def test_ground_truth_round_trip(tmp_path: Path) -> None:
    part = make_part("part_0", "prismatic", [0, 1.0, 0], None, [0, 1, 2], [0.0, 0.1, 0.2], state_range=(0.0, 0.4))
    gt_part = GroundTruthPart(part, np.array([0.1, 0.2, 0.3]), ((1, 2),))
    T_scene_world = make_transform(np.eye(3), [1.0, 0, 0])
    write_ground_truth_json(tmp_path / "gt.json", 3, (gt_part,), T_scene_world, {"kind": "drawer"})
    write_camera_poses(tmp_path / "camera_poses.txt", np.broadcast_to(np.eye(4), (3, 4, 4)))
    gt = read_ground_truth(tmp_path)
    assert gt.frame_count == 3 and gt.extra["kind"] == "drawer"
    assert gt.parts[0].intervals == ((1, 2),) and gt.parts[0].part.state_range == (0.0, 0.4)
    np.testing.assert_allclose(gt.T_scene_world, T_scene_world)
    np.testing.assert_allclose(gt.parts[0].handle_world, [0.1, 0.2, 0.3])
