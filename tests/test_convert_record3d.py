"""Record3D converter on an .r3d archive written here with zipfile and the lzfse package."""

from __future__ import annotations

import json
import zipfile

import cv2
import numpy as np
import pytest

lzfse = pytest.importorskip("lzfse")
from funrec.convert import ConvertConfig, convert, detect_format  # noqa: E402
from funrec.errors import CaptureError  # noqa: E402
from funrec.formats.capture import load_capture  # noqa: E402

W, H, DW, DH = 128, 96, 32, 24
FX, FY, CX, CY = 110.0, 111.0, 63.2, 47.9


def write_r3d(path, frames=4, skip_depth=(2,)):
    with zipfile.ZipFile(path, "w") as archive:
        metadata = {"w": W, "h": H, "dw": DW, "dh": DH, "fps": 60, "K": [FX, 0, 0, 0, FY, 0, CX, CY, 1],
                    "poses": [[0, 0, 0, 1, 0, 0, 0]] * frames}
        archive.writestr("metadata", json.dumps(metadata))
        for k in range(frames):
            rgb = np.zeros((H, W, 3), np.uint8)
            rgb[:, :, 2] = 200  # blue
            archive.writestr(f"rgbd/{k}.jpg", cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes())
            depth = np.full((DH, DW), 1.0 + 0.1 * k, np.float32)
            depth[:, DW // 2 :] = 2.5  # right half farther
            confidence = np.full((DH, DW), 2, np.uint8)
            confidence[0, :] = 0  # top row low confidence
            if k not in skip_depth:
                archive.writestr(f"rgbd/{k}.depth", lzfse.compress(depth.tobytes()))
                archive.writestr(f"rgbd/{k}.conf", lzfse.compress(confidence.tobytes()))
    return path


def test_r3d_converts_with_depth_resampled_to_colour(tmp_path):
    r3d = write_r3d(tmp_path / "scan.r3d")
    assert detect_format(r3d) == "record3d"
    report = convert(r3d, tmp_path / "capture")
    capture = load_capture(tmp_path / "capture")
    K = capture.intrinsics
    assert (K.width, K.height, K.fx, K.fy, K.cx, K.cy, K.fps, K.depth_scale) == (W, H, FX, FY, CX, CY, 60.0, 1000.0)
    assert len(capture) == 3 and report.source_frames == (0, 1, 3)
    assert report.dropped[0].source_index == 2 and "no depth" in report.dropped[0].reason
    depth = capture.depth_m(2)  # source frame 3
    # Each depth pixel covers 4x4 colour pixels; the half boundary stays at the centre column, the
    # low-confidence top depth row (4 colour rows) is removed.
    assert depth[50, 10] == pytest.approx(1.3) and depth[50, W - 10] == pytest.approx(2.5)
    assert depth[50, W // 2 - 1] == pytest.approx(1.3) and depth[50, W // 2] == pytest.approx(2.5)
    assert np.all(depth[:4] == 0) and np.all(depth[4:] > 0)
    assert abs(int(capture.rgb(0)[40, 40, 2]) - 200) <= 3  # JPEG


def test_r3d_downscaled_and_confidence_kept(tmp_path):
    r3d = write_r3d(tmp_path / "scan.r3d", skip_depth=())
    convert(r3d, tmp_path / "capture", ConvertConfig(output_width=64, record3d_min_confidence=0))
    capture = load_capture(tmp_path / "capture")
    assert (capture.intrinsics.width, capture.intrinsics.height) == (64, 48)
    assert capture.intrinsics.fx == pytest.approx(FX / 2)
    assert np.all(capture.depth_m(0) > 0)


def test_corrupt_depth_is_dropped_by_name(tmp_path):
    r3d = write_r3d(tmp_path / "scan.r3d", frames=2, skip_depth=())
    with zipfile.ZipFile(r3d, "a") as archive:
        archive.writestr("rgbd/2.jpg", b"not a jpeg")
        archive.writestr("rgbd/2.depth", b"xx")
    report = convert(r3d, tmp_path / "capture")
    assert report.frames_written == 2
    assert report.dropped[0].reason.startswith("rgbd/2: colour image unreadable")
    with pytest.raises(CaptureError, match=r"not_a_zip.r3d: not a Record3D .r3d archive"):
        (tmp_path / "not_a_zip.r3d").write_text("hello")
        convert(tmp_path / "not_a_zip.r3d", tmp_path / "c2")
