"""Issue 15's data and time safety in funrec: an output over its input is refused before anything is
written, replacing a file leaves nothing behind, image sizes are bounded before decoding, and `funrec check`
fails captures that no reconstruction can use."""

from __future__ import annotations

from pathlib import Path

import pytest

from funrec.cli import main
from funrec.errors import FunrecError
from funrec.formats.staged_folder import publish_folder, refuse_output_over_input, stage_folder


def test_reconstruct_refuses_an_output_equal_to_or_inside_its_capture(tmp_path: Path, capsys) -> None:
    capture = tmp_path / "cap"
    (capture / "rgb").mkdir(parents=True)
    (capture / "rgb" / "000000.jpg").write_bytes(b"keep me")
    assert main(["reconstruct", str(capture), "-o", str(capture), "--overwrite"]) == 2
    assert "the output is the input" in capsys.readouterr().err
    assert main(["reconstruct", str(capture), "-o", str(capture / "twin"), "--overwrite"]) == 2
    assert "the output is inside the input" in capsys.readouterr().err
    assert (capture / "rgb" / "000000.jpg").read_bytes() == b"keep me"
    with pytest.raises(FunrecError, match="the output contains the input"):
        refuse_output_over_input(tmp_path, capture)
    refuse_output_over_input(tmp_path / "twin", capture)  # a sibling is fine


def test_replacing_a_file_with_a_folder_leaves_no_old_copy(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.write_text("a file")
    staged = stage_folder(out, overwrite=True)
    (staged / "x.json").write_text("{}")
    publish_folder(staged, out)
    assert (out / "x.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def _copy(capture: Path, tmp_path: Path, name: str) -> Path:
    import shutil

    return Path(shutil.copytree(capture, tmp_path / name, ignore=shutil.ignore_patterns("gt")))


def _png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` 8-bit RGB pixels and holds none (a decompression bomb's header)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)) + chunk(b"IEND", b"")


def _rewrite_depth(capture: Path, transform) -> None:
    import cv2

    for path in sorted((capture / "depth").glob("*.png")):
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), transform(depth).astype("uint16"))


def test_check_fails_captures_no_reconstruction_can_use(tiny_capture: Path, tmp_path: Path, capsys) -> None:
    import json
    import re

    import cv2

    assert main(["check", str(tiny_capture)]) == 0
    zero = _copy(tiny_capture, tmp_path, "zero")
    _rewrite_depth(zero, lambda d: d * 0)
    assert main(["check", str(zero)]) == 2
    assert "zero/depth/000000.png (frame 0): fewer than 1% of its pixels have a depth reading; so are 24 of 24" in capsys.readouterr().err
    metres = _copy(tiny_capture, tmp_path, "metres")
    _rewrite_depth(metres, lambda d: (d / 1000.0).round())  # millimetres written as whole metres
    assert main(["check", str(metres)]) == 2
    assert re.search(r"metres/depth/000000.png: median depth reading 0.00[1-3] m with depth_scale 1000 is not a room-scale", capsys.readouterr().err)
    black = _copy(tiny_capture, tmp_path, "black")
    for path in sorted((black / "rgb").iterdir()):
        cv2.imwrite(str(path), cv2.imread(str(path)) * 0)
    assert main(["check", str(black)]) == 2
    assert "black/rgb/000000" in (err := capsys.readouterr().err) and "black (no pixel brighter than 8)" in err
    short = _copy(tiny_capture, tmp_path, "short")
    for sub in ("rgb", "depth", "masks/hand"):
        for path in sorted((short / sub).iterdir())[2:] if (short / sub).is_dir() else []:
            path.unlink()
    (short / "camera_poses.txt").unlink(missing_ok=True)
    assert main(["check", str(short)]) == 2
    assert "short/rgb: 2 frames; a reconstruction needs at least 3" in capsys.readouterr().err
    bomb = _copy(tiny_capture, tmp_path, "bomb")
    first = sorted((bomb / "rgb").iterdir())[0]
    first.write_bytes(_png_header(20000, 20000))
    assert main(["check", str(bomb)]) == 2
    assert f"{first} (frame 0): unreadable image" in capsys.readouterr().err
    squashed = _copy(tiny_capture, tmp_path, "squashed")  # the silently wrong twin: fy = fx / 10
    intrinsics = json.loads((squashed / "intrinsics.json").read_text())
    intrinsics["fy"] = intrinsics["fx"] / 10.0
    (squashed / "intrinsics.json").write_text(json.dumps(intrinsics))
    for command in (["check", str(squashed)], ["reconstruct", str(squashed), "-o", str(tmp_path / "twin")]):
        assert main(command) == 2
        assert "intrinsics.json: implausible intrinsics: fx" in capsys.readouterr().err
    assert not (tmp_path / "twin").exists()


def test_an_implausible_part_range_is_refused_before_planning() -> None:
    import dataclasses

    import numpy as np

    from funrec.errors import PlanningError
    from funrec_robot.task import ArticulationTask
    from funrec_robot.task_bounds import check_task_bounds

    fields = {f.name: f for f in dataclasses.fields(ArticulationTask)}
    assert "state_range" in fields
    task = object.__new__(ArticulationTask)  # only the fields the check reads
    for name, value in (("part", "door"), ("joint_type", "revolute"), ("state_range", (-1e6, 1e6))):
        object.__setattr__(task, name, value)
    with pytest.raises(PlanningError, match=r"part 'door': revolute range \[-1e\+06, 1e\+06\] rad is implausible"):
        check_task_bounds(task, 0.0, 1.0)
    object.__setattr__(task, "state_range", (0.0, 1.5))
    check_task_bounds(task, 0.0, 1.4)
    with pytest.raises(PlanningError, match="target state nan rad is implausible"):
        check_task_bounds(task, 0.0, float(np.nan))


def test_ctrl_c_acts_within_a_long_native_call() -> None:
    """coacd's decomposition runs in a worker thread: SIGINT interrupts the export at once, not when it ends."""
    import signal
    import threading
    import time

    from funrec.export.collision import interruptible

    # a shell's background job (`make test &`) starts with SIGINT ignored: restore Python's handler here
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.2, signal.raise_signal, args=(signal.SIGINT,))
    started = time.monotonic()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            interruptible(time.sleep, 10.0)  # a call that releases the GIL, as coacd's does
    finally:
        signal.signal(signal.SIGINT, previous)
    assert time.monotonic() - started < 1.0
    assert interruptible(sum, [1, 2]) == 3
    with pytest.raises(ZeroDivisionError):
        interruptible(lambda: 1 / 0)


def test_ctrl_c_while_writing_a_file_leaves_the_old_file_and_no_partial_one(tmp_path) -> None:
    """staged_file (check records, videos, rerun recordings, reports): either the old file or the new whole one."""
    import numpy as np

    from funrec.formats.staged_folder import staged_file, write_text_staged
    from funrec_robot.video import write_video

    report = write_text_staged(tmp_path / "report.json", "old\n")
    with pytest.raises(KeyboardInterrupt), staged_file(report) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert report.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]

    class Interrupted(list):
        def __iter__(self):
            yield from self[:3]
            raise KeyboardInterrupt

    frames = Interrupted([np.zeros((48, 64, 3), np.uint8)] * 10)
    for name in ("check.mp4", "check.gif"):
        with pytest.raises(KeyboardInterrupt):
            write_video(tmp_path / name, frames, 10.0)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"], name
    write_video(tmp_path / "whole.mp4", list(frames[:3]), 10.0)
    assert (tmp_path / "whole.mp4").stat().st_size > 0
