"""A robot with a lift is measured again at the home its lift takes for each handle, on the model compiled once."""

from __future__ import annotations

import numpy as np
import pytest

from funrec_robot import robot_geometry
from funrec_robot.reach import lifted
from funrec_robot.robot import load_robot
from funrec_robot.robot_yaml import MODELS_ENV
from funrec_robot.sim_model import build_mujoco_model
from tests.helpers.robot_models import MODELS, ROBOTS


@pytest.mark.parametrize("name", ["tiago", "stretch3"])
def test_lifted_homes_are_measured_without_compiling_again(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Measured at three lifted homes, the robot is not compiled again (Stretch 3's compile took 0.16 s of every
    plan), and each geometry equals one measured on a freshly compiled model, to the bit."""
    if not MODELS.is_dir():
        pytest.skip(f"robot models not found in {MODELS}")
    monkeypatch.setenv(MODELS_ENV, str(MODELS))
    robot = load_robot(ROBOTS / f"{name}.yaml")
    geometry = robot_geometry.measure_robot(robot)
    assert geometry.lift_range is not None
    compiled: list[object] = []
    original = robot_geometry.build_mujoco_model
    monkeypatch.setattr(robot_geometry, "build_mujoco_model", lambda r: compiled.append(r) or original(r))
    for height in (0.45, 0.9, 1.35):
        up = lifted(robot, geometry, height, 0.01)
        measured = robot_geometry.measure_robot(up)
        fresh = robot_geometry._measure(up, build_mujoco_model(up))
        np.testing.assert_array_equal(measured.p_base_shoulder, fresh.p_base_shoulder)
        np.testing.assert_array_equal(measured.finger_corners, fresh.finger_corners)
        for ours, theirs in zip(measured.base_circles + measured.arm_circles, fresh.base_circles + fresh.arm_circles):
            np.testing.assert_array_equal(ours.centre_base, theirs.centre_base)
            assert (ours.radius, ours.z_band) == (theirs.radius, theirs.z_band)
        assert (measured.reach, measured.lift_range, measured.fingertip_depth) == (fresh.reach, fresh.lift_range, fresh.fingertip_depth)
    assert not compiled
