"""Capture folder loading and validation (FORMATS.md section 1)."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from funrec.errors import CaptureError
from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, load_capture, read_intrinsics

W, H = 32, 24


def _write_capture(root: Path, frames: int = 3, hand_masks: bool = False) -> Path:
    rng = np.random.default_rng(0)
    intrinsics = CaptureIntrinsics(W, H, 30.0, 30.0, W / 2, H / 2, depth_scale=1000.0, fps=15.0)
    writer = CaptureWriter(root, intrinsics)
    for i in range(frames):
        rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
        depth_m = rng.uniform(0.5, 3.0, (H, W))
        depth_m[0, 0] = 0.0
        hand = rng.random((H, W)) > 0.5 if hand_masks else None
        writer.write_frame(i, rgb, depth_m, hand_mask=hand)
    return root


@pytest.fixture
def capture_dir(tmp_path: Path) -> Path:
    return _write_capture(tmp_path / "capture", hand_masks=True)


def test_round_trip_quantises_depth_to_millimetres(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    intrinsics = CaptureIntrinsics(W, H, 30.0, 31.0, 15.5, 11.5)
    writer = CaptureWriter(tmp_path / "c", intrinsics)
    rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    depth_m = rng.uniform(0.3, 5.0, (H, W))
    writer.write_frame(7, rgb, depth_m)
    capture = load_capture(tmp_path / "c")
    assert capture.stems == (7,)
    np.testing.assert_array_equal(capture.rgb(0), rgb)
    # depth_scale 1000 stores whole millimetres: the round trip error is at most half of one.
    np.testing.assert_allclose(capture.depth_m(0), depth_m, atol=0.5e-3 + 1e-12)
    assert capture.intrinsics == intrinsics
    assert capture.mask("hand", 0) is None


def test_frames_stream_in_stem_order(capture_dir: Path) -> None:
    capture = load_capture(capture_dir)
    assert len(capture) == 3 and capture.has_hand_masks and not capture.has_object_masks
    frames = [frame for frame, _, _ in capture.frames()]
    assert frames == [0, 1, 2]
    assert capture.depth_m(0)[0, 0] == 0.0
    assert capture.mask("hand", 1).dtype == bool


def test_missing_intrinsics_names_the_file(capture_dir: Path) -> None:
    (capture_dir / "intrinsics.json").unlink()
    with pytest.raises(CaptureError, match=r"intrinsics\.json: missing intrinsics file"):
        load_capture(capture_dir)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [("fx", 0.0, "fx must be positive"), ("fy", -3.0, "fy must be positive"), ("width", 31.5, "width must be a positive integer")],
)
def test_bad_intrinsics_values(capture_dir: Path, key: str, value: float, message: str) -> None:
    path = capture_dir / "intrinsics.json"
    data = json.loads(path.read_text())
    data[key] = value
    path.write_text(json.dumps(data))
    with pytest.raises(CaptureError, match=message):
        read_intrinsics(path)


def test_unknown_intrinsics_key_is_rejected(capture_dir: Path) -> None:
    path = capture_dir / "intrinsics.json"
    data = json.loads(path.read_text())
    data["fxx"] = 1.0
    path.write_text(json.dumps(data))
    with pytest.raises(CaptureError, match=r"unknown keys \['fxx'\]"):
        load_capture(capture_dir)


def test_stems_that_do_not_match(capture_dir: Path) -> None:
    (capture_dir / "depth" / "000001.png").unlink()
    with pytest.raises(CaptureError, match=r"rgb stems without depth: \[1\]"):
        load_capture(capture_dir)


def test_eight_bit_depth_names_file_and_frame(capture_dir: Path) -> None:
    cv2.imwrite(str(capture_dir / "depth" / "000002.png"), np.zeros((H, W), np.uint8))
    with pytest.raises(CaptureError, match=r"depth/000002\.png \(frame 2\): depth image \(must be 16-bit\) has pixel mode L"):
        load_capture(capture_dir)


def test_size_mismatch_names_file_and_frame(capture_dir: Path) -> None:
    cv2.imwrite(str(capture_dir / "rgb" / "000001.png"), np.zeros((H, W + 2, 3), np.uint8))
    with pytest.raises(CaptureError, match=r"rgb/000001\.png \(frame 1\): image is 34x24, intrinsics say 32x24"):
        load_capture(capture_dir)


def test_truncated_image_fails_when_read_and_names_frame(capture_dir: Path) -> None:
    path = capture_dir / "depth" / "000001.png"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    capture = load_capture(capture_dir)  # the header is intact, so loading succeeds
    capture.depth_m(0)
    with pytest.raises(CaptureError, match=r"depth/000001\.png \(frame 1\): cannot decode image"):
        capture.depth_m(1)


def test_garbage_file_is_unreadable(capture_dir: Path) -> None:
    (capture_dir / "rgb" / "000000.png").write_bytes(b"not an image")
    with pytest.raises(CaptureError, match=r"rgb/000000\.png \(frame 0\): unreadable image"):
        load_capture(capture_dir)


def test_empty_capture_is_an_error(tmp_path: Path) -> None:
    root = _write_capture(tmp_path / "c", frames=1)
    for sub in ("rgb", "depth"):
        shutil.rmtree(root / sub)
        (root / sub).mkdir()
    with pytest.raises(CaptureError, match="no frames"):
        load_capture(root)


def test_non_integer_stem(capture_dir: Path) -> None:
    shutil.copy(capture_dir / "rgb" / "000000.png", capture_dir / "rgb" / "frame_a.png")
    with pytest.raises(CaptureError, match=r"frame_a\.png: file stem is not an integer"):
        load_capture(capture_dir)


def test_mask_without_frame(capture_dir: Path) -> None:
    shutil.copy(capture_dir / "masks" / "hand" / "000000.png", capture_dir / "masks" / "hand" / "000009.png")
    with pytest.raises(CaptureError, match=r"mask stems without a frame: \[9\]"):
        load_capture(capture_dir)


def test_known_camera_poses_must_cover_every_frame(capture_dir: Path) -> None:
    (capture_dir / "camera_poses.txt").write_text("0 0 0 0 0 0 0 1\n")
    with pytest.raises(CaptureError, match="expected one pose per frame 0..2"):
        load_capture(capture_dir)


def test_prefetched_frames_equal_direct_reads_and_stay_bounded(tmp_path: Path) -> None:
    from funrec.formats.capture import PREFETCH_FRAMES

    capture = load_capture(_write_capture(tmp_path / "c", frames=12, hand_masks=True))
    fresh = load_capture(tmp_path / "c")
    # In order, then every other frame backwards-free (step 2), then random access: every read
    # must equal a direct decode bit for bit (prefetching may not change a pixel).
    order = list(range(12)) + list(range(0, 12, 2)) + [5, 1, 9, 3]
    for frame in order:
        np.testing.assert_array_equal(capture.rgb(frame), fresh._read_rgb(frame))
        np.testing.assert_array_equal(capture.gray(frame), cv2.cvtColor(fresh._read_rgb(frame), cv2.COLOR_RGB2GRAY))
        np.testing.assert_array_equal(capture.depth_m(frame), fresh._read_depth_m(frame))
        np.testing.assert_array_equal(capture.mask("hand", frame), fresh._read_mask("hand", frame))
        # At most PREFETCH_FRAMES decoded frames per kind wait at any time (memory stays bounded).
        assert len(capture._prefetcher._pending) <= 4 * PREFETCH_FRAMES
    # After random access nothing is decoded ahead.
    assert not capture._prefetcher._pending


def test_prefetched_corrupt_frame_raises_naming_it(tmp_path: Path) -> None:
    capture = load_capture(_write_capture(tmp_path / "c", frames=6))
    # Frame 4 is decoded ahead (reads 0, 1, 2 start prefetching); its error reaches the reader.
    (tmp_path / "c" / "depth" / "000004.png").write_bytes(b"not a png")
    with pytest.raises(CaptureError, match="000004.png"):
        for frame in range(6):
            capture.depth_m(frame)


def test_forked_child_reads_frames_decoded_ahead_in_the_parent(tmp_path: Path) -> None:
    import os

    capture = load_capture(_write_capture(tmp_path / "c", frames=8))
    for frame in range(3):  # the parent now has frames 3.. pending in its decoding thread
        capture.depth_m(frame)
    pid = os.fork()
    if pid == 0:  # the child has no decoding thread: it must decode afresh, not wait forever
        ok = all(np.array_equal(capture.depth_m(f), capture._read_depth_m(f)) for f in range(3, 8))
        os._exit(0 if ok else 1)
    for _ in range(200):  # up to 20 s: a child stuck on the parent's futures is killed, not awaited
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        time.sleep(0.1)
    else:
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        pytest.fail("the forked child hung reading frames the parent had queued for decoding")
    assert os.waitstatus_to_exitcode(status) == 0


def test_decoded_files_are_kept_within_budget_shared_with_sub_captures_and_unchanged_by_readers(tmp_path: Path) -> None:
    import dataclasses

    from funrec.formats.capture import _DecodedFiles

    capture = load_capture(_write_capture(tmp_path / "c", frames=4, hand_masks=True))
    fresh = load_capture(tmp_path / "c")
    depth = capture.depth_m(1)
    depth[:] = -1.0  # a reader may write into what it was handed: the kept file stays as decoded
    capture.rgb(1)[:] = 0
    np.testing.assert_array_equal(capture.depth_m(1), fresh._read_depth_m(1))
    np.testing.assert_array_equal(capture.rgb(1), fresh._read_rgb(1))
    sub = dataclasses.replace(capture, stems=capture.stems[1:], rgb_paths=capture.rgb_paths[1:],
                              depth_paths=capture.depth_paths[1:])
    assert sub._decoded is capture._decoded  # sub-captures share what was decoded
    (tmp_path / "c" / "depth" / "000001.png").unlink()
    np.testing.assert_array_equal(sub.depth_m(0), fresh._read_depth_m(1))  # decoded once, not again
    # Masks are never kept: a run rewrites its detected hand masks under the same path.
    assert capture.mask("hand", 2).any()
    write_mask = cv2.imwrite(str(capture.mask_paths["hand"][2]), np.zeros((H, W), np.uint8))
    assert write_mask and not capture.mask("hand", 2).any()
    # Within the budget only: room for one depth image keeps the first one read.
    small = dataclasses.replace(fresh, _decoded=_DecodedFiles(budget_bytes=H * W * 2))
    for frame in (2, 3):
        small.depth_m(frame)
    assert list(small._decoded._images) == [small.depth_paths[2]]
