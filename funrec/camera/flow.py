"""Dense optical flow (OpenCV's DIS) between two frames, and points carried along it with a
forward-backward check: motion that needs no corner, for surfaces with little texture.

Pyramidal Lucas-Kanade (:func:`funrec.camera.features.track_klt`) locks on to a point's own
texture; on a plain painted door it has none, and its tracks die or slide. DIS fits one smooth
flow field to the whole image, so a flat door panel moves with its outline, its handle and its
shading. A learned dense matcher (the paper's RoMa) would fill the same signature.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from funrec.typed import BoolArray, FloatArray, UInt8Array

_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
            "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


@dataclass(frozen=True)
class FlowConfig:
    """Settings of :func:`dense_flow`."""

    preset: str = "fast"
    """DIS preset: "ultrafast", "fast" or "medium" (OpenCV's speed/accuracy trade-offs)."""
    work_width_px: int = 320
    """Flow is computed on images scaled to about this width (never upscaled) and scaled back:
    a door edge moves 5-30 px per frame at 640 px, well inside DIS's coarse-to-fine range at half
    size, and the cost drops four-fold."""

    def __post_init__(self) -> None:
        if self.preset not in _PRESETS:
            raise ValueError(f"FlowConfig.preset must be one of {sorted(_PRESETS)}, got {self.preset!r}")
        if self.work_width_px < 16:
            raise ValueError(f"FlowConfig.work_width_px must be >= 16, got {self.work_width_px}")


def dense_flow(gray0: UInt8Array, gray1: UInt8Array, config: FlowConfig = FlowConfig()) -> FloatArray:  # noqa: B008
    """Optical flow from frame 0 to frame 1.

    Args:
        gray0, gray1: (H, W) uint8 grey images.
        config: flow settings.

    Returns:
        (H, W, 2) float32 flow in pixels at full resolution: pixel (u, v) of frame 0 moves to
        (u + flow[v, u, 0], v + flow[v, u, 1]) in frame 1.
    """
    H, W = gray0.shape
    scale = min(1.0, config.work_width_px / W)
    if scale < 1.0:
        size = (max(8, int(round(W * scale))), max(8, int(round(H * scale))))
        gray0 = cv2.resize(gray0, size, interpolation=cv2.INTER_AREA)
        gray1 = cv2.resize(gray1, size, interpolation=cv2.INTER_AREA)
    dis = cv2.DISOpticalFlow_create(_PRESETS[config.preset])
    flow = dis.calc(gray0, gray1, None)
    if scale < 1.0:
        flow = cv2.resize(flow, (W, H), interpolation=cv2.INTER_LINEAR)
        flow[..., 0] *= W / gray0.shape[1]
        flow[..., 1] *= H / gray0.shape[0]
    return flow


def sample_flow(flow: FloatArray, uv: FloatArray) -> FloatArray:
    """(N, 2) flow at sub-pixel positions uv (N, 2), bilinear; points outside read the border."""
    if len(uv) == 0:
        return np.zeros((0, 2))
    map_u = uv[:, 0].astype(np.float32).reshape(-1, 1)
    map_v = uv[:, 1].astype(np.float32).reshape(-1, 1)
    return cv2.remap(flow, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 2).astype(np.float64)


def track_flow(flow_forward: FloatArray, flow_backward: FloatArray, uv0: FloatArray,
               max_forward_backward_px: float) -> tuple[FloatArray, BoolArray]:
    """Carry points along a forward flow field, kept where the backward field brings them home.

    Args:
        flow_forward: (H, W, 2) flow from frame 0 to frame 1 (:func:`dense_flow`).
        flow_backward: (H, W, 2) flow from frame 1 to frame 0.
        uv0: (N, 2) pixel positions in frame 0.
        max_forward_backward_px: a round trip that misses its start by more than this fails
            (occlusion: the surface is hidden in frame 1, so the two fields disagree there).

    Returns:
        uv1: (N, 2) positions in frame 1; ok: (N,) round trip within the bound and uv1 inside the image.
    """
    if len(uv0) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    uv1 = uv0 + sample_flow(flow_forward, uv0)
    back = uv1 + sample_flow(flow_backward, uv1)
    H, W = flow_forward.shape[:2]
    inside = (uv1[:, 0] >= 0) & (uv1[:, 0] <= W - 1) & (uv1[:, 1] >= 0) & (uv1[:, 1] <= H - 1)
    ok = inside & (np.linalg.norm(back - uv0, axis=1) < max_forward_backward_px)
    return uv1, ok


__all__ = ["FlowConfig", "dense_flow", "sample_flow", "track_flow"]
