"""The video checked against intrinsics.json (funrec.camera.intrinsics_consistency): intrinsics that look
plausible but are wrong (fx off by 30 %, the principal point's coordinates swapped) are refused before a
twin is written, measured from the camera's own motion; true intrinsics pass, on a rendered room and on
real Kinect v1 frames (TUM fr1_xyz)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from funrec.camera.intrinsics_consistency import check_intrinsics_in_video
from funrec.cli import main
from funrec.formats.capture import load_capture
from tests.helpers.rendered_rooms import make_scene, write_scene
from tests.helpers.tum import TUM_DIR, write_tum_capture


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """24 frames, 240x180, of a rendered room; the camera turns by up to 9 degrees about two axes."""
    return write_scene(make_scene(24, width=240, height=180, door_max_rad=0.0), tmp_path_factory.mktemp("room") / "capture")


def _with_intrinsics(capture: Path, out: Path, **changes: float) -> Path:
    out.mkdir()
    for sub in ("rgb", "depth", "masks"):
        if (capture / sub).exists():
            (out / sub).symlink_to(capture / sub)
    intrinsics = json.loads((capture / "intrinsics.json").read_text())
    (out / "intrinsics.json").write_text(json.dumps({**intrinsics, **changes}))
    return out


def test_true_intrinsics_agree_with_the_video(room) -> None:
    verdict = check_intrinsics_in_video(load_capture(room))
    assert verdict.verdict == "consistent", verdict
    fx = verdict.given[0]
    assert abs(verdict.estimated[0] / fx - 1.0) < 0.05 and abs(verdict.estimated[2] - verdict.given[2]) < 5.0, verdict


def _wrong(room: Path, case: str) -> dict[str, float]:
    k = json.loads((room / "intrinsics.json").read_text())
    return {"fx x 1.3": {"fx": k["fx"] * 1.3}, "fx x 0.7": {"fx": k["fx"] * 0.7}, "f x 0.8": {"fx": k["fx"] * 0.8, "fy": k["fy"] * 0.8},
            "principal point swapped": {"cx": k["cy"], "cy": k["cx"]}}[case]


@pytest.mark.parametrize("case", ["fx x 0.7", "f x 0.8", "principal point swapped"])
def test_the_video_measures_silently_wrong_intrinsics(room, tmp_path, case) -> None:
    verdict = check_intrinsics_in_video(load_capture(_with_intrinsics(room, tmp_path / "wrong", **_wrong(room, case))))
    assert verdict.verdict == "inconsistent", verdict
    assert ("fx" if case.startswith("f") else "cx") in verdict.reason, verdict


def test_silently_wrong_intrinsics_are_refused_before_a_twin_is_written(room, tmp_path, capsys) -> None:
    """The issue's case: fx off by 30 %, plausible on its own (aspect 1.3, field of view 49 degrees)."""
    wrong = _with_intrinsics(room, tmp_path / "wrong", **_wrong(room, "fx x 1.3"))
    assert main(["reconstruct", str(wrong), "-o", str(tmp_path / "twin")]) == 2
    err = capsys.readouterr().err
    assert f"{wrong / 'intrinsics.json'}: the video disagrees with these intrinsics: fx " in err, err
    assert "(or pass --no-intrinsics-check-enabled to use them anyway)" in err, err
    assert not (tmp_path / "twin").exists() and not list(tmp_path.glob(".twin*"))
    assert main(["check", str(wrong)]) == 2
    assert "the video disagrees with these intrinsics" in capsys.readouterr().err


def test_the_check_can_be_turned_off(room, tmp_path) -> None:
    from funrec.camera.intrinsics_consistency import IntrinsicsCheckConfig, require_consistent_intrinsics

    wrong = _with_intrinsics(room, tmp_path / "wrong", fx=json.loads((room / "intrinsics.json").read_text())["fx"] * 1.3)
    assert require_consistent_intrinsics(load_capture(wrong), IntrinsicsCheckConfig(enabled=False)) is None


@pytest.mark.skipif(not TUM_DIR.is_dir(), reason=f"real data not present at {TUM_DIR}")
@pytest.mark.parametrize("intrinsics", ["official fr1", "ROS default 525"])
def test_real_kinect_frames_with_true_intrinsics_are_not_refused(tmp_path, intrinsics) -> None:
    """Ten frames, 5 degrees of rotation: too little to pin down every parameter, never a false alarm."""
    capture = write_tum_capture(tmp_path / "tum")
    if intrinsics == "ROS default 525":
        capture = _with_intrinsics(capture, tmp_path / "ros", fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    verdict = check_intrinsics_in_video(load_capture(capture))
    print(verdict)
    assert verdict.verdict in ("consistent", "cannot tell"), verdict
    assert abs(verdict.estimated[0] / 517.3 - 1.0) < 0.05, verdict  # fx is pinned down, and right within 5 %
