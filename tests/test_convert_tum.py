"""TUM RGB-D converter: the benchmark layout (generated here) and the real fr1_xyz frames in shared/realdata,
tracked and scored against motion capture."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from funrec.bench.evaluate import evaluate_twin
from funrec.bench.metrics import camera_ate
from funrec.camera.tracking import track_camera
from funrec.cli import main
from funrec.convert import ConvertConfig, convert, detect_format
from funrec.convert.association import associate_nearest
from funrec.errors import CaptureError, FunrecError
from funrec.formats.capture import load_capture
from funrec.formats.ground_truth import read_ground_truth

TUM_DIR = Path("/work/shared/realdata/tum_fr1_xyz_10")


def _write_tum_sequence(root: Path, depth_stamps: list[float], rgb_stamps: list[float]) -> Path:
    """A TUM-layout folder; depth image k is uniform (1000 + k) raw units, colour image k is uniform grey 10 k."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for k, t in enumerate(rgb_stamps):
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), np.full((480, 640, 3), 10 * k, np.uint8))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
    for k, t in enumerate(depth_stamps):
        cv2.imwrite(str(root / "depth" / f"{t:.6f}.png"), np.full((480, 640), 1000 + k, np.uint16))
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    # Ground truth at 100 Hz: the camera moves along x at 1 m/s, rotating about z at 1 rad/s.
    t_gt = np.arange(rgb_stamps[0] - 0.05, rgb_stamps[-1] + 0.05, 0.01)
    quat_xyzw = Rotation.from_rotvec(np.outer(t_gt - t_gt[0], [0, 0, 1.0])).as_quat()
    lines = ["# ground truth trajectory"] + [
        f"{t:.4f} {t - t_gt[0]:.4f} 0.0 1.0 {q[0]:.6f} {q[1]:.6f} {q[2]:.6f} {q[3]:.6f}" for t, q in zip(t_gt, quat_xyzw)
    ]
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return root


def test_benchmark_layout_associates_drops_and_reports_gaps(tmp_path):
    # Colour at 30 Hz with frames 5-7 missing (a gap); depth 8 ms after colour, except that frame 2 has none.
    rgb_stamps = [100.0 + k / 30 for k in range(12) if k not in (5, 6, 7)]
    depth_stamps = [t + 0.008 for k, t in enumerate(rgb_stamps) if k != 2]
    source = _write_tum_sequence(tmp_path / "rgbd_dataset_freiburg3_test", depth_stamps, rgb_stamps)
    assert detect_format(source) == "tum"
    report = convert(source, tmp_path / "capture")
    capture = load_capture(tmp_path / "capture")
    assert len(capture) == report.frames_written == 8
    assert [d.source_index for d in report.dropped] == [2]
    assert "no unused depth image within 0.020 s" in report.dropped[0].reason
    # The dropped frame leaves a one-frame gap after written frame 1; the missing colour frames one after 3.
    assert [(g.after_frame, g.missing_frames) for g in report.gaps] == [(1, 1), (3, 3)]
    K = capture.intrinsics
    assert (K.fx, K.fy, K.cx, K.cy, K.depth_scale) == (535.4, 539.2, 320.1, 247.6, 5000.0)  # fr3, no distortion
    assert K.fps == pytest.approx(30.0, rel=1e-3)
    # Written frame 2 is source colour frame 3, whose depth is depth image 2 (raw 1002): association held.
    assert report.source_frames[2] == 3
    assert capture.depth_m(2)[100, 200] == pytest.approx(1002 / 5000)
    assert capture.rgb(2)[0, 0, 0] == 30
    gt = read_ground_truth(tmp_path / "capture")
    t_written = np.array(report.timestamps_s)
    np.testing.assert_allclose(gt.T_world_camera[:, 0, 3], t_written - (rgb_stamps[0] - 0.05), atol=2e-4)
    saved = json.loads((tmp_path / "capture" / "conversion.json").read_text())
    assert saved["dropped"][0]["source_index"] == 2


def test_fr1_images_are_undistorted_with_the_same_K(tmp_path):
    source = _write_tum_sequence(tmp_path / "rgbd_dataset_freiburg1_test", [0.0, 0.033], [0.001, 0.034])
    capture = load_capture(convert(source, tmp_path / "capture").capture_dir)
    assert (capture.intrinsics.fx, capture.intrinsics.cy) == (517.3, 255.3)
    depth = capture.depth_m(0)
    # Uniform depth stays uniform (nearest sampling mixes nothing); fr1's pincushion leaves corners unseen.
    assert set(np.unique(depth)) <= {0.0, 1000 / 5000}
    assert depth[255, 318] == pytest.approx(0.2) and depth[0, 0] == 0.0


def test_unknown_tum_camera_is_an_error(tmp_path):
    source = _write_tum_sequence(tmp_path / "my_recording", [0.0], [0.0])
    with pytest.raises(CaptureError, match=r"my_recording: cannot tell which TUM camera.*tum_camera"):
        convert(source, tmp_path / "capture")
    report = convert(source, tmp_path / "capture", ConvertConfig(tum_camera="ros"))
    assert report.intrinsics.fx == 525.0


def test_existing_output_is_kept_and_a_failed_conversion_leaves_nothing(tmp_path):
    source = _write_tum_sequence(tmp_path / "fr3_x", [5.0], [0.0])  # depth 5 s away: no frame at all
    (tmp_path / "capture").mkdir()
    (tmp_path / "capture" / "keep.txt").write_text("x")
    with pytest.raises(FunrecError, match="output exists and is not empty"):
        convert(source, tmp_path / "capture")
    with pytest.raises(CaptureError, match=r"fr3_x: no frame could be converted; 1 frame\(s\) dropped: no unused depth"):
        convert(source, tmp_path / "capture", ConvertConfig(overwrite=True))
    assert (tmp_path / "capture" / "keep.txt").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["capture", "fr3_x"]


def test_association_is_one_to_one_and_closest_first():
    t_rgb = np.array([0.0, 0.010, 0.033, 0.100])
    t_depth = np.array([0.008, 0.034, 0.2])
    # depth 0 is closer to rgb 1 (2 ms) than to rgb 0 (8 ms); rgb 3 has nothing within 20 ms.
    np.testing.assert_array_equal(associate_nearest(t_rgb, t_depth, 0.02), [-1, 0, 1, -1])


@pytest.fixture(scope="module")
def tum_real(tmp_path_factory):
    if not TUM_DIR.is_dir():
        pytest.skip(f"real data not present at {TUM_DIR}")
    out = tmp_path_factory.mktemp("tum_real") / "capture"
    return convert(TUM_DIR, out), out


def test_real_tum_frames_convert_with_the_official_calibration(tum_real):
    report, out = tum_real
    capture = load_capture(out)
    assert len(capture) == 10 and report.dropped == ()
    K = capture.intrinsics
    assert (K.width, K.height, K.fx, K.fy, K.cx, K.cy, K.depth_scale) == (640, 480, 517.3, 516.5, 318.6, 255.3, 5000.0)
    assert any("camera_intrinsics.yaml ignored" in n for n in report.notes)
    # The raw value at the principal point survives undistortion unchanged (the map is the identity there).
    raw = cv2.imread(str(TUM_DIR / "depth" / "1.png"), cv2.IMREAD_UNCHANGED)
    assert capture.depth_m(0)[255, 319] * 5000 == pytest.approx(raw[255, 319])


def test_real_tum_tracking_ate_against_motion_capture(tum_real):
    """Measured 5.9 mm RMSE (5.88) over 0.11 m of motion, the tracking engineer's number with their own
    undistortion; 1 cm is the issue's target, and fr1's colour-depth offset (~15 ms at ~0.45 m/s, ~7 mm)
    sets the floor, so a threshold much below 1 cm would test the sensor, not the converter."""
    _, out = tum_real
    capture = load_capture(out)
    trajectory = track_camera(capture)
    gt = read_ground_truth(out)
    assert gt.frame_count == 10 and trajectory.tracked.all()
    ate = camera_ate(trajectory.T_world_camera, gt.T_world_camera)
    assert ate < 0.010, ate


def test_real_tum_frames_reconstruct_into_a_static_twin(tum_real, tmp_path):
    """The whole reconstruction on real Kinect frames of a desk that nobody touches: no articulated part may be
    invented from sensor noise, and the twin's camera trajectory (the full pipeline, gravity-aligned world)
    must still match motion capture within the issue's 1 cm (measured 5.9 mm, as tracking alone)."""
    _, capture = tum_real
    twin = tmp_path / "twin"
    assert main(["reconstruct", str(capture), "-o", str(twin)]) == 0
    evaluation = evaluate_twin(twin, capture / "gt")
    assert evaluation.ok and evaluation.parts == () and evaluation.invented_parts == ()
    assert evaluation.camera_ate_cm < 1.0, evaluation.camera_ate_cm
    assert (twin / "meshes" / "static.ply").stat().st_size > 10_000  # a desk, not an empty mesh
