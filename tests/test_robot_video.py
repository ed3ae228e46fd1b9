"""The check video's camera: a viewpoint from which the handle and the robot are not hidden behind a wall."""

from __future__ import annotations

import mujoco
import numpy as np

from funrec_robot.video import CAMERA_SIDE_DEG, blocked_sight, camera_position, check_camera

P_BASE = np.array([0.0, 0.0, 0.0])
P_HANDLE = np.array([1.0, 0.0, 0.8])

# A wall on the -y side behind the robot (x = -1 m, y from -3 to 0 m): the default view, 35 deg to the left of
# the robot-to-handle line and 2.6 m back, stands behind it; the mirrored view does not.
WALL_SCENE = """
<mujoco>
  <worldbody>
    <body name="robot" pos="0 0 0.4"><geom type="box" size="0.25 0.25 0.4"/></body>
    <geom name="wall" type="box" pos="-1.0 -1.5 1.5" size="0.05 1.5 1.5"/>
    <geom name="hidden_helper" type="box" pos="0.5 0.0 0.8" size="0.02 0.02 0.02" group="3"/>
  </worldbody>
</mujoco>
"""


def _targets() -> np.ndarray:
    lookat = np.array([*(P_BASE[:2] + P_HANDLE[:2]) / 2, 0.8])
    return np.array([P_HANDLE, lookat])


def test_camera_steps_around_a_wall_behind_the_robot() -> None:
    model = mujoco.MjModel.from_xml_string(WALL_SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    robot = {model.body("robot").id}
    default = check_camera(P_BASE, P_HANDLE)
    assert default.azimuth == CAMERA_SIDE_DEG  # no model: the fixed viewpoint, as before
    # The wall hides both targets from the default viewpoint (this is what the choice must avoid) ...
    assert blocked_sight(model, data, camera_position(default), _targets(), robot) == 2
    chosen = check_camera(P_BASE, P_HANDLE, model, data, sorted(robot))
    # ... and the camera moves to the other side, where nothing is in the way: the robot's own geoms are
    # looked through, and so is the helper box in group 3 around the look-at point (the renderer hides it).
    assert chosen.azimuth == -CAMERA_SIDE_DEG
    assert blocked_sight(model, data, camera_position(chosen), _targets(), robot) == 0


def test_camera_position_is_distance_back_along_the_view() -> None:
    camera = check_camera(P_BASE, P_HANDLE)
    eye = camera_position(camera)
    # The eye is exactly ``distance`` from the look-at point (1e-9: float round-off) and above it (looking down).
    assert abs(np.linalg.norm(eye - np.asarray(camera.lookat)) - camera.distance) < 1e-9
    assert eye[2] > camera.lookat[2]
