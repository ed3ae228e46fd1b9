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
from funrec.typed import FloatArray

CAMERA_DISTANCE_M = 2.6
"""Distance of the video camera from the point it looks at, m (the first choice; see ``CAMERA_VIEWS``)."""
CAMERA_ELEVATION_DEG = -28.0
"""Elevation of the video camera, degrees (negative: looking down)."""
CAMERA_SIDE_DEG = 35.0
"""The camera looks from this far to the side of the robot-to-handle line, degrees."""
LOOKAT_HEIGHT_M = 0.8
"""Height of the point the camera looks at, m."""
CAMERA_VIEWS = tuple(
    (side, elevation, distance)
    for distance in (CAMERA_DISTANCE_M, 1.9, 1.4)
    for elevation in (CAMERA_ELEVATION_DEG, -50.0)
    for side in (CAMERA_SIDE_DEG, -CAMERA_SIDE_DEG, 70.0, -70.0, 0.0)
)
"""Viewpoints tried in order, as (side deg, elevation deg, distance m): the first from which the handle and
the robot are in plain sight is used (a room's walls often stand behind the robot)."""
VISIBLE_GROUPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)
"""Geom groups that the renderer draws (MuJoCo's default visual option): only these block the view."""


def _camera(lookat: FloatArray, azimuth: float, elevation: float, distance: float) -> mujoco.MjvCamera:
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = lookat
    camera.azimuth, camera.elevation, camera.distance = azimuth, elevation, distance
    return camera


def camera_position(camera: mujoco.MjvCamera) -> FloatArray:
    """(3,) where a free camera is: ``distance`` back from its look-at point against its viewing direction
    (MuJoCo's azimuth and elevation give the direction it looks in)."""
    azimuth, elevation = np.deg2rad(camera.azimuth), np.deg2rad(camera.elevation)
    forward = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    return np.asarray(camera.lookat, dtype=np.float64) - camera.distance * forward


def blocked_sight(
    model: mujoco.MjModel, data: mujoco.MjData, eye: FloatArray, targets: FloatArray, seen: set[int]
) -> int:
    """How many of the (K, 3) targets a visible geom other than the bodies in ``seen`` hides from ``eye``
    (a ray cast per target with ``mujoco.mj_ray``; geoms of ``seen`` bodies are looked through)."""
    hidden = 0
    geom = np.zeros(1, dtype=np.int32)
    for target in targets:
        start, length = eye.copy(), float(np.linalg.norm(target - eye))
        direction = (target - eye) / max(length, 1e-9)
        while length > 1e-3:
            distance = mujoco.mj_ray(model, data, start, direction, VISIBLE_GROUPS, 1, -1, geom)
            if geom[0] < 0 or distance >= length:
                break
            if int(model.geom_bodyid[geom[0]]) not in seen:
                hidden += 1
                break
            start, length = start + (distance + 1e-3) * direction, length - distance - 1e-3
    return hidden


def check_camera(
    p_world_base: npt.ArrayLike,
    p_world_handle: npt.ArrayLike,
    model: mujoco.MjModel | None = None,
    data: mujoco.MjData | None = None,
    seen_bodies: npt.ArrayLike = (),
    also_seen: npt.ArrayLike = (),
) -> mujoco.MjvCamera:
    """A free camera to the side of the robot, looking between its base and the handle.

    With ``model`` and ``data`` (the scene at the start of the check), the first of ``CAMERA_VIEWS`` from
    which rays to the handle, the look-at point, the robot's base and the (K, 3) points ``also_seen`` (e.g.
    where the handle ends up) reach them past every visible geom not of ``seen_bodies`` (the robot and the
    part); else the one hiding the fewest of them.
    """
    base = np.asarray(p_world_base, dtype=np.float64)
    handle = np.asarray(p_world_handle, dtype=np.float64)
    lookat = np.array([*(base[:2] + handle[:2]) / 2, LOOKAT_HEIGHT_M])
    toward = handle[:2] - base[:2]  # MuJoCo's azimuth is the direction the camera looks in: from behind the robot
    heading = float(np.rad2deg(np.arctan2(toward[1], toward[0])))
    views = CAMERA_VIEWS if model is not None and data is not None else CAMERA_VIEWS[:1]
    targets = np.vstack([[handle, lookat, [base[0], base[1], LOOKAT_HEIGHT_M / 2]], np.reshape(also_seen, (-1, 3))])
    seen = {int(b) for b in np.asarray(seen_bodies, dtype=int).ravel()}
    best = None
    for side, elevation, distance in views:
        camera = _camera(lookat, heading + side, elevation, distance)
        if model is None or data is None:
            return camera
        hidden = blocked_sight(model, data, camera_position(camera), targets, seen)
        if hidden == 0:
            return camera
        if best is None or hidden < best[0]:
            best = (hidden, camera)
    assert best is not None
    return best[1]


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
    from funrec.formats.staged_folder import staged_file

    with staged_file(path) as tmp:  # Ctrl-C while encoding leaves no half-written video
        if path.suffix.lower() == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            images[0].save(tmp, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
            return path
        import cv2

        height, width = frames[0].shape[:2]
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
        if not writer.isOpened():
            raise PlanningError(f"{path}: cv2 cannot open an mp4v video writer")
        for frame in frames:
            writer.write(np.ascontiguousarray(frame[..., ::-1]))  # RGB -> BGR
        writer.release()
    return path



__all__ = ["CAMERA_VIEWS", "FrameRecorder", "blocked_sight", "camera_position", "check_camera", "write_video"]
