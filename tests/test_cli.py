"""The funrec command line as a user meets it: help, exit codes, error messages."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from funrec.formats.capture import CaptureIntrinsics, CaptureWriter
from tests.helpers.twins import oracle_twin_with_contact


def _funrec(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "funrec", *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def test_help_is_fast_and_lists_commands() -> None:
    start = time.perf_counter()
    result = _funrec("--help")
    # The stage modules (Open3D, scikit-learn) take seconds to import; --help must not load them.
    assert time.perf_counter() - start < 5.0
    assert result.returncode == 0
    for command in ("reconstruct", "synth", "check", "eval", "bench", "demo", "query", "view"):
        assert command in result.stdout


def test_reconstruct_help_documents_stage_options() -> None:
    result = _funrec("reconstruct", "--help-all")  # --help lists the common ones (tests/test_cli_habits.py)
    assert result.returncode == 0
    assert "--tracking-max-features" in result.stdout and "--no-use-hand-masks" in result.stdout


def test_bad_capture_exits_2_naming_file_and_frame(tmp_path: Path) -> None:
    writer = CaptureWriter(tmp_path / "cap", CaptureIntrinsics(16, 12, 10.0, 10.0, 8.0, 6.0))
    for frame in range(3):
        writer.write_frame(frame, np.zeros((12, 16, 3), np.uint8), np.ones((12, 16)))
    cv2.imwrite(str(tmp_path / "cap" / "depth" / "000001.png"), np.zeros((12, 16), np.uint8))
    result = _funrec("check", str(tmp_path / "cap"))
    assert result.returncode == 2
    assert "depth/000001.png (frame 1)" in result.stderr and "16-bit" in result.stderr
    assert "Traceback" not in result.stderr
    result = _funrec("reconstruct", str(tmp_path / "cap"), "-o", str(tmp_path / "twin"))
    assert result.returncode == 2 and "depth/000001.png (frame 1)" in result.stderr
    assert not (tmp_path / "twin").exists(), "a failed reconstruction must not leave a twin folder"


def test_check_reads_every_frame(tiny_capture: Path) -> None:
    result = _funrec("check", str(tiny_capture))
    assert result.returncode == 0, result.stderr
    assert "all frames readable" in result.stdout


def test_eval_of_the_oracle_twin_is_perfect(tiny_capture: Path, tmp_path: Path) -> None:
    from funrec.bench.baselines import write_oracle_twin

    twin = write_oracle_twin(tiny_capture, tmp_path / "oracle")
    result = _funrec("eval", str(twin), str(tiny_capture / "gt"), "--json", str(tmp_path / "eval.json"))
    assert result.returncode == 0, result.stderr
    evaluation = json.loads((tmp_path / "eval.json").read_text())
    assert evaluation["parts"][0]["axis_error_deg"] < 1e-6


def test_query_lists_parts_and_gives_grasps(tiny_capture: Path, tmp_path: Path) -> None:
    twin, name, contact = oracle_twin_with_contact(tiny_capture, tmp_path / "twin")
    result = _funrec("query", str(twin))
    assert result.returncode == 0, result.stderr
    assert name in result.stdout and " ".join(f"{v:+.3f}" for v in contact) in result.stdout
    result = _funrec("query", str(twin), "--json")
    (row,) = json.loads(result.stdout)
    np.testing.assert_allclose(row["contact_point"], contact, atol=1e-9)  # JSON keeps float64 digits
    result = _funrec("query", str(twin), "--part", name, "--state", "0", "--json")
    assert result.returncode == 0, result.stderr
    grasp = json.loads(result.stdout)
    np.testing.assert_allclose(grasp["position"], contact, atol=1e-9)
    np.testing.assert_allclose(np.array(grasp["T_world_grasp"])[:3, 2], grasp["approach"], atol=0)
    text = _funrec("query", str(twin), "--part", name).stdout
    assert "T_world_grasp" in text and "approach (z)" in text and "handle axis (x)" in text
    result = _funrec("query", str(twin), "--part", "part_9")
    assert result.returncode == 2 and "no part 'part_9'" in result.stderr and name in result.stderr
    result = _funrec("query", str(tmp_path / "nothing"))
    assert result.returncode == 2 and "articulation.json" in result.stderr and "Traceback" not in result.stderr


def test_eval_scores_the_contact_point(tiny_capture: Path, tmp_path: Path) -> None:
    twin, _, _ = oracle_twin_with_contact(tiny_capture, tmp_path / "twin")
    result = _funrec("eval", str(twin), str(tiny_capture / "gt"), "--json", str(tmp_path / "eval.json"))
    assert result.returncode == 0, result.stderr
    assert "contact 0.0 cm" in result.stdout
    evaluation = json.loads((tmp_path / "eval.json").read_text())
    # Oracle poses and states: only camera_poses.txt round-off (~1 um) remains.
    assert evaluation["parts"][0]["contact_error_m"] < 1e-5
    assert evaluation["hand_iou"] is None  # the twin holds no detected hand masks


def test_view_without_viser_says_how_to_install_it(tmp_path: Path) -> None:
    (tmp_path / "block").mkdir()
    (tmp_path / "block" / "viser.py").write_text("raise ImportError('blocked for the test')\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "block")}
    result = subprocess.run([sys.executable, "-m", "funrec", "view", str(tmp_path)], capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 2 and "pip install funrec[view]" in result.stderr, result.stderr
