"""HOI4D converter on sequences written here the way HOI4D stores them (H.264 colour video, FFV1 16-bit depth
video or the decoded jpg/png frames, intrin.npy, objpose JSON, Open3D trajectory log, action JSON); HOI4D has
no library of its own, so its files are the format."""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from funrec.bench.baselines import write_oracle_twin
from funrec.bench.evaluate import evaluate_twin
from funrec.cli import main
from funrec.convert import ConvertConfig, convert, detect_format
from funrec.errors import CaptureError
from funrec.formats.capture import load_capture
from funrec.formats.ground_truth import read_ground_truth
from funrec.geometry.joints import joint_transform
from funrec.geometry.transforms import invert_transform, make_transform

W, H, FRAMES, FPS = 96, 64, 20, 15.0
K = np.array([[80.0, 0, 47.5], [0, 80.0, 31.5], [0, 0, 1]])
SEQUENCE = "ZY20210800001/H1/C4/N01/S1/s1/T1"
# The true joints, world frame: a door on a vertical hinge (world y is down-ish in the log's world, any frame
# works), opened 0 -> 1.0 rad over frames 3-10; a drawer pulled 0 -> 0.25 m along x over frames 11-18.
DOOR_AXIS, DOOR_PIVOT = np.array([0.0, -1.0, 0.0]), np.array([0.3, 0.0, 2.0])
DRAWER_AXIS = np.array([0.0, 0.0, -1.0])
T_WORLD_BODY = make_transform(Rotation.from_euler("y", 0.2).as_matrix(), [0.0, 0.1, 2.2])


def _door_state(k: int) -> float:
    return float(np.clip((k - 3) / 7, 0, 1)) * 1.0


def _drawer_state(k: int) -> float:
    return float(np.clip((k - 11) / 7, 0, 1)) * 0.25


def _T_world_camera(k: int) -> np.ndarray:
    return make_transform(Rotation.from_euler("xy", [0.01 * k, -0.02 * k]).as_matrix(), [0.02 * k, 0.0, 0.01 * k])


def _box(label: str, T_camera_box: np.ndarray) -> dict:
    x, y, z = Rotation.from_matrix(T_camera_box[:3, :3]).as_euler("XYZ")
    c = T_camera_box[:3, 3]
    return {"label": label, "center": {"x": c[0], "y": c[1], "z": c[2]}, "rotation": {"x": x, "y": y, "z": z},
            "dimensions": {"length": 0.4, "width": 0.02, "height": 0.6}}


def _write_video(path: Path, frames: list[np.ndarray], codec: str, pix_fmt: str, in_fmt: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=int(FPS))
        stream.width, stream.height, stream.pix_fmt = W, H, pix_fmt
        for image in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format=in_fmt)):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _write_hoi4d(root: Path, decoded: bool, depth_frames: int = FRAMES) -> Path:
    """The data set's download layout: HOI4D_release/<seq> (videos), HOI4D_annotations/<seq>, camera_params/."""
    seq = root / "HOI4D_release" / SEQUENCE
    notes = root / "HOI4D_annotations" / SEQUENCE
    (root / "camera_params" / "ZY20210800001").mkdir(parents=True)
    np.save(root / "camera_params" / "ZY20210800001" / "intrin.npy", K)
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    colour = [np.roll(texture, k, axis=1) for k in range(FRAMES)]
    depth = [np.full((H, W), 1000 + 7 * k, np.uint16) for k in range(depth_frames)]  # frame k: (1000 + 7k) mm
    if decoded:
        (seq / "align_rgb").mkdir(parents=True)
        (seq / "align_depth").mkdir(parents=True)
        for k, image in enumerate(colour):
            cv2.imwrite(str(seq / "align_rgb" / f"{k:05d}.jpg"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        for k, image in enumerate(depth):
            cv2.imwrite(str(seq / "align_depth" / f"{k:05d}.png"), image)
    else:
        _write_video(seq / "align_rgb" / "image.mp4", colour, "libx264", "yuv420p", "rgb24")
        _write_video(seq / "align_depth" / "depth_video.avi", depth, "ffv1", "gray16le", "gray16le")
    trajectory = o3d.camera.PinholeCameraTrajectory()
    params = []
    for k in range(FRAMES):
        p = o3d.camera.PinholeCameraParameters()
        p.intrinsic = o3d.camera.PinholeCameraIntrinsic(W, H, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        p.extrinsic = invert_transform(_T_world_camera(k))
        params.append(p)
        T_world_door = joint_transform("revolute", DOOR_AXIS, DOOR_PIVOT, _door_state(k)) @ T_WORLD_BODY @ make_transform(np.eye(3), [0.2, 0, -0.3])
        T_world_drawer = joint_transform("prismatic", DRAWER_AXIS, None, _drawer_state(k)) @ T_WORLD_BODY
        T_camera_world = invert_transform(_T_world_camera(k))
        boxes = [_box("Lockerbody", T_camera_world @ T_WORLD_BODY), _box("Lockerdoor", T_camera_world @ T_world_door),
                 _box("Lockerdrawer", T_camera_world @ T_world_drawer)]
        (notes / "objpose").mkdir(parents=True, exist_ok=True)
        (notes / "objpose" / f"{k}.json").write_text(json.dumps({"dataList": boxes}))
    trajectory.parameters = params
    (notes / "3Dseg").mkdir(parents=True)
    assert o3d.io.write_pinhole_camera_trajectory(str(notes / "3Dseg" / "output.log"), trajectory)
    (notes / "action").mkdir()
    events = [{"id": 0, "event": "Reachout", "startTime": 0.0, "endTime": 3 / FPS},
              {"id": 1, "event": "Open", "startTime": 3 / FPS, "endTime": 11 / FPS},
              {"id": 2, "event": "Pull", "startTime": 11 / FPS, "endTime": 19 / FPS}]
    (notes / "action" / "color.json").write_text(json.dumps({"info": {"duration": FRAMES / FPS}, "events": events}))
    return seq


@pytest.mark.parametrize("decoded", [False, True], ids=["videos", "decoded-frames"])
def test_hoi4d_sequence_converts_with_articulated_ground_truth(tmp_path, decoded):
    source = _write_hoi4d(tmp_path, decoded)
    assert detect_format(source) == "hoi4d"
    report = convert(source, tmp_path / "capture")
    capture = load_capture(tmp_path / "capture")
    assert len(capture) == FRAMES and report.dropped == ()
    assert (capture.intrinsics.fx, capture.intrinsics.cx, capture.intrinsics.depth_scale) == (80.0, 47.5, 1000.0)
    assert capture.intrinsics.fps == pytest.approx(FPS)
    # FFV1 and PNG are lossless: frame k holds exactly (1000 + 7k) mm, so colour and depth stay paired.
    for k in (0, 13, FRAMES - 1):
        assert capture.depth_m(k)[10, 20] == pytest.approx((1000 + 7 * k) / 1000)
    gt = read_ground_truth(tmp_path / "capture")
    np.testing.assert_allclose(gt.T_world_camera, [_T_world_camera(k) for k in range(FRAMES)], atol=1e-6)
    door, drawer = gt.parts
    assert gt.extra["hoi4d"]["labels"] == {"part_0": "Lockerdoor", "part_1": "Lockerdrawer"}
    # Box poses go through JSON as floats and XYZ Euler angles: the joints come back to ~1e-6.
    assert door.part.joint_type == "revolute" and drawer.part.joint_type == "prismatic"
    np.testing.assert_allclose(door.part.axis_world, DOOR_AXIS, atol=1e-6)
    np.testing.assert_allclose(door.part.pivot_world, [0.3, 0.0, 2.0], atol=1e-6)  # already closest to the origin
    np.testing.assert_allclose(door.part.states, [_door_state(k) for k in range(FRAMES)], atol=1e-6)
    np.testing.assert_allclose(drawer.part.axis_world, DRAWER_AXIS, atol=1e-6)
    np.testing.assert_allclose(drawer.part.states, [_drawer_state(k) for k in range(FRAMES)], atol=1e-6)
    # Open (3/15 .. 11/15 s) covers frames 3-10 and acts on the door; Pull covers 11-18 and acts on the drawer.
    assert door.intervals == ((3, 10),) and drawer.intervals == ((11, 18),)
    assert (tmp_path / "capture" / "gt" / "points" / "part_0.ply").is_file()


def test_funrec_eval_scores_a_twin_against_converted_hoi4d_ground_truth(tmp_path, capsys):
    source = _write_hoi4d(tmp_path, decoded=True)
    assert main(["convert", str(source), "-o", str(tmp_path / "capture"), "--format", "hoi4d"]) == 0
    write_oracle_twin(tmp_path / "capture", tmp_path / "twin")
    assert main(["eval", str(tmp_path / "twin"), str(tmp_path / "capture")]) == 0
    assert "part_0" in capsys.readouterr().out
    evaluation = evaluate_twin(tmp_path / "twin", tmp_path / "capture" / "gt")
    # The oracle twin is the ground truth in camera-0 coordinates: every error is float round-off.
    assert evaluation.ok and len(evaluation.parts) == 2
    for part in evaluation.parts:
        assert not part.failed and part.axis_error_deg < 1e-3 and part.state_error < 1e-6


def test_missing_depth_frames_are_dropped_and_reported(tmp_path):
    source = _write_hoi4d(tmp_path, decoded=False, depth_frames=FRAMES - 2)
    report = convert(source, tmp_path / "capture")
    assert report.frames_written == FRAMES - 2
    assert [(d.source_index, d.reason) for d in report.dropped] == [(18, "no depth frame"), (19, "no depth frame")]
    gt = read_ground_truth(tmp_path / "capture")
    assert gt.frame_count == FRAMES - 2 and gt.parts[1].part.frames[-1] == FRAMES - 3


def test_missing_intrinsics_names_where_it_looked(tmp_path):
    source = _write_hoi4d(tmp_path, decoded=True)
    (tmp_path / "camera_params" / "ZY20210800001" / "intrin.npy").unlink()
    with pytest.raises(CaptureError, match=r"no HOI4D intrinsics \(intrin.npy\); looked in .*T1/intrin.npy"):
        convert(source, tmp_path / "capture", ConvertConfig(format="hoi4d"))
