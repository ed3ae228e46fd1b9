"""camera_poses.txt (FORMATS.md section 3): one ``i tx ty tz qx qy qz qw`` line per frame,
camera-to-world."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from funrec.errors import FormatError
from funrec.geometry.transforms import check_transform, make_transform
from funrec.typed import FloatArray, IntArray

QUATERNION_NORM_TOL = 1e-3
"""How far from unit length a written quaternion may be (6-decimal files round to ~1e-6)."""


@dataclass(frozen=True)
class CameraPoses:
    """Camera-to-world poses of a list of frames."""

    frames: IntArray
    """(F,) frame indices, increasing."""
    T_world_camera: FloatArray
    """(F, 4, 4) camera-to-world transforms."""


def read_camera_poses(path: str | Path) -> CameraPoses:
    """Read a camera_poses.txt file.

    Raises:
        FormatError: a line does not have 8 numbers, a quaternion is not unit length,
            or frame indices repeat or decrease; the message names the line.
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "missing camera poses file")
    frames, rows = [], []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        values = text.split()
        if len(values) != 8:
            raise FormatError(path, f"line {line_no}: expected 8 values 'i tx ty tz qx qy qz qw', got {len(values)}")
        try:
            numbers = [float(v) for v in values]
        except ValueError:
            raise FormatError(path, f"line {line_no}: not a number in {text!r}") from None
        if not np.all(np.isfinite(numbers)) or numbers[0] != int(numbers[0]):
            raise FormatError(path, f"line {line_no}: bad values {text!r}")
        quat_xyzw = np.array(numbers[4:8])
        if abs(np.linalg.norm(quat_xyzw) - 1.0) > QUATERNION_NORM_TOL:
            raise FormatError(path, f"line {line_no}: quaternion is not unit length")
        frames.append(int(numbers[0]))
        rows.append(numbers[1:])
    if not frames:
        raise FormatError(path, "no poses")
    frame_array = np.array(frames, dtype=np.int64)
    if np.any(np.diff(frame_array) <= 0):
        raise FormatError(path, "frame indices must be strictly increasing")
    data = np.array(rows)
    R = Rotation.from_quat(data[:, 3:7]).as_matrix()
    return CameraPoses(frames=frame_array, T_world_camera=make_transform(R, data[:, :3]))


def write_camera_poses(path: str | Path, T_world_camera: npt.ArrayLike, frames: npt.ArrayLike | None = None) -> None:
    """Write camera-to-world poses as TUM lines.

    Args:
        path: output file.
        T_world_camera: (F, 4, 4) camera-to-world transforms.
        frames: (F,) frame indices; defaults to 0..F-1.
    """
    T_world_camera = check_transform(T_world_camera, "T_world_camera")
    if T_world_camera.ndim != 3:
        raise ValueError(f"T_world_camera must be (F, 4, 4), got {T_world_camera.shape}")
    frames = np.arange(len(T_world_camera)) if frames is None else np.asarray(frames, dtype=np.int64)
    quat_xyzw = Rotation.from_matrix(T_world_camera[:, :3, :3]).as_quat()
    lines = [
        f"{int(i)} {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} {q[0]:.7f} {q[1]:.7f} {q[2]:.7f} {q[3]:.7f}"
        for i, t, q in zip(frames, T_world_camera[:, :3, 3], quat_xyzw)
    ]
    Path(path).write_text("\n".join(lines) + "\n")


__all__ = ["CameraPoses", "read_camera_poses", "write_camera_poses"]
