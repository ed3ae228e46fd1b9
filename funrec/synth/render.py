"""Offscreen MuJoCo rendering on the CPU: colour, metric depth and per-pixel geom ids from
one model camera, plus the pinhole intrinsics MuJoCo's projection implies.

The OpenGL backend is chosen before MuJoCo is first imported (see :func:`ensure_gl_backend`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING

import numpy as np

from funrec.errors import FunrecError
from funrec.geometry.camera import PinholeIntrinsics
from funrec.offscreen import ensure_gl_backend, offscreen_context
from funrec.synth.scene import SEE_THROUGH_GROUP
from funrec.typed import FloatArray, UInt8Array

if TYPE_CHECKING:
    import mujoco

LOGGER = logging.getLogger(__name__)

NEAR_M = 0.02
"""Near clipping plane, metres (nothing the camera sees is closer)."""
FAR_M = 30.0
"""Far clipping plane, metres; pixels at the far plane read as depth 0 (no surface)."""
def fovy_for_focal(height: int, focal_px: float) -> float:
    """Vertical field of view (degrees) of a camera with focal length ``focal_px`` pixels."""
    return math.degrees(2.0 * math.atan(height / 2.0 / focal_px))


def intrinsics_from_fovy(width: int, height: int, fovy_deg: float) -> PinholeIntrinsics:
    """Pinhole intrinsics of a MuJoCo camera, exactly as MuJoCo projects.

    MuJoCo's frustum spans the image edges, so the optical axis hits the image centre, which
    is pixel (W/2 - 0.5, H/2 - 0.5) when pixel centres are integers; pixels are square.
    """
    focal = height / 2.0 / math.tan(math.radians(fovy_deg) / 2.0)
    return PinholeIntrinsics(width, height, focal, focal, width / 2.0 - 0.5, height / 2.0 - 0.5)


R_MUJOCO_OPENCV = np.diag([1.0, -1.0, -1.0])
"""(3, 3) rotation from the OpenCV camera frame to MuJoCo's (x right, y up, looking along -z):
``R_world_mujococam = R_world_camera @ R_MUJOCO_OPENCV`` (it is its own inverse)."""


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered view."""

    rgb: UInt8Array
    """(H, W, 3) uint8 colour."""
    depth_m: FloatArray
    """(H, W) exact depth along the optical axis, metres; 0 where no surface."""
    geom_id: np.ndarray
    """(H, W) int32 MuJoCo geom id of the visible surface, -1 where none."""


class OffscreenRenderer:
    """Renders a model from one of its cameras into numpy arrays.

    Two passes per frame: a lit colour pass, and a segmentation pass whose id colours and
    depth buffer are read together. Geoms of ``scene.SEE_THROUGH_GROUP`` (clear glass) appear
    only in the colour pass, so depth and ids show what lies behind them.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, camera: str) -> None:
        import mujoco

        self._mujoco = mujoco
        self._model = model
        self._width, self._height = width, height
        camera_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if camera_id < 0:
            raise FunrecError(f"render model has no camera {camera!r}")
        if model.vis.global_.offwidth < width or model.vis.global_.offheight < height:
            raise FunrecError(f"render model offscreen buffer is smaller than {width}x{height}")
        model.vis.map.znear = NEAR_M / model.stat.extent
        model.vis.map.zfar = FAR_M / model.stat.extent
        self._near, self._far = NEAR_M, FAR_M
        self._gl = offscreen_context(width, height)
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZERONEAR
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = camera_id
        self._option = mujoco.MjvOption()
        self._has_glass = bool(np.any(model.geom_group == SEE_THROUGH_GROUP))
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._ids = np.empty((height, width, 3), np.uint8)
        self._depth = np.empty((height, width), np.float32)

    def render(self, data: mujoco.MjData) -> RenderedFrame:
        """Render the current state of ``data`` (run mj_forward first)."""
        mujoco = self._mujoco
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self._model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        flags = self._scene.flags
        mujoco.mjr_render(self._rect, self._scene, self._context)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._context)
        if self._has_glass:  # the label and depth pass leaves clear glass out
            self._option.geomgroup[SEE_THROUGH_GROUP] = 0
            mujoco.mjv_updateScene(
                self._model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
            )
            self._option.geomgroup[SEE_THROUGH_GROUP] = 1
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            mujoco.mjr_render(self._rect, self._scene, self._context)
            mujoco.mjr_readPixels(self._ids, self._depth, self._rect, self._context)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        # Segment id colours encode (scene geom index + 1); map them to model geom ids.
        lookup = np.full(self._scene.ngeom + 2, -1, np.int32)
        for k in range(self._scene.ngeom):
            geom = self._scene.geoms[k]
            if geom.segid >= 0 and geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[geom.segid + 1] = geom.objid
        ids = self._ids.astype(np.int32)
        segment = ids[..., 0] + (ids[..., 1] << 8) + (ids[..., 2] << 16)
        geom_id = lookup[np.clip(segment, 0, len(lookup) - 1)]
        # Zero-near depth map: z = f n / (f - d (f - n)); d = 1 is the far plane (nothing hit).
        d = self._depth.astype(np.float64)
        depth_m = self._far * self._near / (self._far - d * (self._far - self._near))
        depth_m[(d >= 1.0) | (geom_id < 0)] = 0.0
        # OpenGL rows run bottom-up.
        return RenderedFrame(np.flipud(self._rgb).copy(), np.flipud(depth_m).copy(), np.flipud(geom_id).copy())

    def close(self) -> None:
        """Release the GL context (idempotent)."""
        if getattr(self, "_context", None) is not None:
            self._context.free()
            self._context = None
        if getattr(self, "_gl", None) is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> OffscreenRenderer:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


__all__ = [
    "FAR_M",
    "NEAR_M",
    "R_MUJOCO_OPENCV",
    "OffscreenRenderer",
    "RenderedFrame",
    "ensure_gl_backend",
    "fovy_for_focal",
    "intrinsics_from_fovy",
]
