"""Camera tracking: camera-to-world poses of every frame, robust to the hand and moving parts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from funrec.typed import BoolArray, FloatArray, IntArray


@dataclass(frozen=True)
class CameraTrajectory:
    """Estimated camera poses of a capture."""

    T_world_camera: FloatArray
    """(F, 4, 4) camera-to-world transform of every frame; world = camera frame of frame 0
    unless stated otherwise."""
    keyframes: IntArray
    """(K,) frame indices used as keyframes in the pose graph."""
    tracked: BoolArray
    """(F,) True where the frame was registered; False where its pose was interpolated."""

    def __post_init__(self) -> None:
        F = len(self.T_world_camera)
        if np.shape(self.T_world_camera) != (F, 4, 4) or np.shape(self.tracked) != (F,):
            raise ValueError(
                f"T_world_camera must be (F, 4, 4) and tracked (F,), got {np.shape(self.T_world_camera)}, {np.shape(self.tracked)}"
            )
