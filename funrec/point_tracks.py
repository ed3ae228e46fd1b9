"""Sparse 3D point tracks in the world frame with per-frame visibility."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from funrec.typed import BoolArray, FloatArray


@dataclass(frozen=True)
class PointTracks:
    """N point tracks over F frames (a track exists from the frame it was seeded in)."""

    p_world: FloatArray
    """(F, N, 3) track positions in the world frame, metres; NaN where not visible."""
    uv: FloatArray
    """(F, N, 2) pixel positions (u column, v row); NaN where not visible."""
    visible: BoolArray
    """(F, N) True where the track was observed with valid depth."""

    def __post_init__(self) -> None:
        F, N = np.shape(self.visible)
        if np.shape(self.p_world) != (F, N, 3) or np.shape(self.uv) != (F, N, 2):
            raise ValueError(
                f"p_world must be (F, N, 3) and uv (F, N, 2) with visible (F, N) = {(F, N)}, "
                f"got {np.shape(self.p_world)}, {np.shape(self.uv)}"
            )

    @property
    def num_frames(self) -> int:
        return int(self.visible.shape[0])

    @property
    def num_tracks(self) -> int:
        return int(self.visible.shape[1])
