"""Pictures of a check: an offscreen MuJoCo renderer with a free camera, and MP4/GIF writing.

Works whether or not MuJoCo was imported with an offscreen backend (``funrec.offscreen`` makes a current
EGL or OSMesa context either way).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import numpy.typing as npt

from funrec.errors import PlanningError
from funrec.offscreen import offscreen_context

CAMERA_DISTANCE_M = 2.6
"""Distance of the video camera from the point it looks at, m."""
CAMERA_ELEVATION_DEG = -28.0
"""Elevation of the video camera, degrees (negative: looking down)."""
CAMERA_SIDE_DEG = 35.0
"""The camera looks from this far to the side of the robot-to-handle line, degrees."""
LOOKAT_HEIGHT_M = 0.8
"""Height of the point the camera looks at, m."""


def check_camera(p_world_base: npt.ArrayLike, p_world_handle: npt.ArrayLike) -> mujoco.MjvCamera:
    """A free camera behind and to the side of the robot, looking between its base and the handle."""
    base = np.asarray(p_world_base, dtype=np.float64)[:2]
    handle = np.asarray(p_world_handle, dtype=np.float64)[:2]
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = [*(base + handle) / 2, LOOKAT_HEIGHT_M]
    toward = handle - base  # MuJoCo's azimuth is the direction the camera looks in: from behind the robot
    camera.azimuth = float(np.rad2deg(np.arctan2(toward[1], toward[0]))) + CAMERA_SIDE_DEG
    camera.elevation = CAMERA_ELEVATION_DEG
    camera.distance = CAMERA_DISTANCE_M
    return camera


class FrameRecorder:
    """Renders RGB frames of a model's state from a free camera.

    Args:
        model: the model (its offscreen buffer must be at least ``width`` x ``height``).
        camera: the camera.
        width, height: image size, pixels.
    """

    def __init__(self, model: mujoco.MjModel, camera: mujoco.MjvCamera, width: int, height: int) -> None:
        self.model, self.camera = model, camera
        self.frames: list[np.ndarray] = []
        self._gl = offscreen_context(width, height)
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        # Software OpenGL (llvmpipe) is the usual headless backend: shadows and reflections cost most of a frame.
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self._option = mujoco.MjvOption()
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)

    def capture(self, data: mujoco.MjData) -> None:
        """Render the current state of ``data`` and keep the frame."""
        self._gl.make_current()
        mujoco.mjv_updateScene(self.model, data, self._option, None, self.camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        mujoco.mjr_render(self._rect, self._scene, self._context)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._context)
        self.frames.append(np.flipud(self._rgb).copy())  # OpenGL rows run bottom-up

    def close(self) -> None:
        """Release the GL context (idempotent)."""
        if getattr(self, "_context", None) is not None:
            self._context.free()
            self._context = None
        if getattr(self, "_gl", None) is not None:
            self._gl.free()
            self._gl = None


def write_video(path: str | Path, frames: list[np.ndarray], fps: float) -> Path:
    """Write RGB frames as MP4 (cv2, mp4v) or, for a .gif path, as an animated GIF (Pillow)."""
    path = Path(path)
    if not frames:
        raise PlanningError(f"{path}: no frames to write")
    if path.suffix.lower() == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
        return path
    import cv2

    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise PlanningError(f"{path}: cv2 cannot open an mp4v video writer")
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[..., ::-1]))  # RGB -> BGR
    writer.release()
    return path



__all__ = ["FrameRecorder", "check_camera", "write_video"]
