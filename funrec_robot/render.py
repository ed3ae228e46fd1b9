"""Offscreen MuJoCo picture of a robot at its home pose (needs an OpenGL backend: MUJOCO_GL=egl or osmesa)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from funrec_robot.robot import RobotDescription
from funrec_robot.sim_model import build_mujoco_spec, reset_to_home

CAMERA_DISTANCE = 3.0
"""Distance from the camera to the point it looks at, m; frames a 1.5-2 m tall robot."""
CAMERA_LOOKAT_HEIGHT = 0.75
"""Height of the point the camera looks at, above the base frame, m."""


def render_robot(robot: RobotDescription, path: str | Path, width: int = 640, height: int = 480) -> Path:
    """Render the robot at its home pose, on a floor, from the front left, and write a PNG.

    Args:
        robot: the robot.
        path: output PNG file.
        width: image width, pixels.
        height: image height, pixels.

    Returns:
        ``path``.
    """
    from PIL import Image

    spec = build_mujoco_spec(robot)
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3.0, 3.0, 0.05], rgba=[0.85, 0.85, 0.82, 1.0])
    spec.worldbody.add_light(pos=[1.0, 1.0, 3.0], dir=[-0.3, -0.3, -1.0], diffuse=[0.8, 0.8, 0.8])
    spec.visual.global_.offwidth = max(width, 640)
    spec.visual.global_.offheight = max(height, 480)
    model = spec.compile()
    data = mujoco.MjData(model)
    reset_to_home(robot, model, data)
    camera = mujoco.MjvCamera()
    camera.lookat[:] = [0.0, 0.0, CAMERA_LOOKAT_HEIGHT]
    camera.distance = CAMERA_DISTANCE
    camera.azimuth = -145.0
    camera.elevation = -15.0
    with mujoco.Renderer(model, height=height, width=width) as renderer:
        renderer.update_scene(data, camera)
        pixels = renderer.render()
    path = Path(path)
    Image.fromarray(np.asarray(pixels)).save(path)
    return path


__all__ = ["render_robot"]
