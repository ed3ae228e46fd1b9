"""`funrec-robot robots` and `funrec-robot describe`: output, exit codes, offscreen render."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from funrec_robot.cli import main

ROBOTS = Path(__file__).resolve().parents[1] / "robots"


def test_robots_lists_each_yaml_with_its_dof(capsys) -> None:
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    assert "funrec_mm: 10 DoF (3 base, 7 arm), base holonomic" in out
    assert "fetch: " in out  # either its DoF, or 'unavailable' without gymnasium-robotics


def test_robots_reports_a_broken_file_without_hiding_the_others(tmp_path: Path, capsys) -> None:
    (tmp_path / "a_broken.yaml").write_text("model: nowhere.xml\n")
    (tmp_path / "funrec_mm.yaml").write_text(
        (ROBOTS / "funrec_mm.yaml")
        .read_text()
        .replace("model: funrec_mm/", f"model: {ROBOTS}/funrec_mm/")
        .replace("urdf: funrec_mm/", f"urdf: {ROBOTS}/funrec_mm/")
    )
    assert main(["robots", "--dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "a_broken: unavailable: " in out and "missing key 'arm_joints'" in out
    assert "funrec_mm: 10 DoF" in out and "2 robot files" in out


def test_describe_prints_joints_limits_and_gripper(capsys) -> None:
    assert main(["describe", "funrec_mm"]) == 0
    out = capsys.readouterr().out
    assert "arm_joint4  arm       -2.57   2.57   2.175  10     87      2.4" in out
    assert "base_yaw    base yaw" in out
    assert "end effector: site 'grasp_site'" in out
    assert "gripper: joints finger_left, finger_right; actuator 'gripper'; open 0.0425, closed 0" in out


def test_describe_error_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: x.xml\narm_joints: []\ngripper: {joints: [], open: 0, closed: 0}\nee: {site: s}\nspeed: 1\n")
    assert main(["describe", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("funrec-robot describe: ") and "bad.yaml: (top level): unknown key 'speed'" in err
    assert main(["describe", "no_such_robot"]) == 2
    assert "no such robot YAML file or robot name" in capsys.readouterr().err


def test_describe_renders_the_home_pose(tmp_path: Path) -> None:
    png = tmp_path / "home.png"
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run(
        [sys.executable, "-m", "funrec_robot.cli", "describe", "funrec_mm", "--render", str(png), "--width", "160", "--height", "120"],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    if result.returncode != 0 and re.search(r"\b(EGL|OpenGL|OSMesa|GLFW|PyOpenGL)\b|gl_context", result.stderr):
        pytest.skip(f"no offscreen OpenGL here: {result.stderr.strip().splitlines()[-1]}")
    assert result.returncode == 0, result.stderr
    import numpy as np
    from PIL import Image

    with Image.open(png) as image:
        pixels = np.asarray(image.convert("RGB"))
    assert pixels.shape == (120, 160, 3)
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 20  # a picture, not a blank frame
