"""Contact sheets of generated sequences for looking at: colour, depth, and ground truth
(part and hand masks, the handle and the joint axis projected into the image)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from funrec.formats.capture import load_capture, read_mask
from funrec.formats.ground_truth import read_ground_truth
from funrec.geometry.camera import project
from funrec.geometry.transforms import invert_transform, transform_points
from funrec.typed import UInt8Array

PART_COLORS = ((255, 80, 60), (60, 200, 255), (250, 220, 40), (200, 80, 255))
"""RGB overlay colour of part_0, part_1, ..."""
HAND_COLOR = (60, 255, 90)
"""RGB overlay colour of the hand."""


def _depth_colormap(depth_m: np.ndarray, max_m: float = 5.0) -> UInt8Array:
    scaled = np.clip(depth_m / max_m * 255.0, 0, 255).astype(np.uint8)
    colored = cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    colored[depth_m <= 0] = 0
    return colored


def contact_sheet(sequence_dir: str | Path, frame: int) -> UInt8Array:
    """One frame of a generated sequence as a 2x2 sheet: colour, depth (turbo, 0-5 m, black =
    no reading), ground-truth masks over the colour with each part's handle (circle) and
    axis (line, revolute) drawn at their true pose, and the raw masks.

    Args:
        sequence_dir: a folder written by ``generate_sequence``.
        frame: frame index.

    Returns:
        (2H, 2W, 3) uint8 RGB image.
    """
    root = Path(sequence_dir)
    capture = load_capture(root)
    gt = read_ground_truth(root / "gt")
    rgb = capture.rgb(frame)
    depth = capture.depth_m(frame)
    K = capture.intrinsics.K
    stem = f"{frame:06d}.png"
    overlay = (rgb * 0.5).astype(np.float64)
    masks = np.zeros_like(rgb)
    for k, part in enumerate(gt.parts):
        path = gt.root / "masks" / part.part.name / stem
        if path.is_file():
            mask = read_mask(path)
            color = np.asarray(PART_COLORS[k % len(PART_COLORS)])
            overlay[mask] = overlay[mask] * 0.4 + color * 0.6
            masks[mask] = color
    hand = read_mask(gt.root / "masks" / "hand" / stem)
    overlay[hand] = overlay[hand] * 0.4 + np.asarray(HAND_COLOR) * 0.6
    masks[hand] = HAND_COLOR
    overlay = overlay.astype(np.uint8)
    T_camera_world = invert_transform(gt.T_world_camera[frame])
    for k, part in enumerate(gt.parts):
        color = PART_COLORS[k % len(PART_COLORS)]
        T = part.part.T_world_part()[list(part.part.frames).index(frame)]
        handle = transform_points(T_camera_world @ T, part.handle_world[None])
        uv, z = project(handle, K)
        if z[0] > 0:
            cv2.circle(
                overlay, tuple(int(round(v)) for v in uv[0]), max(2, rgb.shape[1] // 160), color, -1, cv2.LINE_AA
            )
        if part.part.joint_type == "revolute" and part.part.pivot_world is not None:
            ends = part.part.pivot_world + np.outer([-0.5, 0.5], part.part.axis_world)
            ends = ends + part.part.axis_world * float(
                (part.handle_world - part.part.pivot_world) @ part.part.axis_world
            )
            uv, z = project(transform_points(T_camera_world, ends), K)
            if np.all(z > 0):
                cv2.line(
                    overlay,
                    *(tuple(int(round(c)) for c in p) for p in uv),
                    color,
                    max(1, rgb.shape[1] // 320),
                    cv2.LINE_AA,
                )
    top = np.concatenate([rgb, _depth_colormap(depth)], axis=1)
    bottom = np.concatenate([overlay, masks], axis=1)
    return np.concatenate([top, bottom], axis=0)


def write_contact_sheet(sequence_dir: str | Path, frame: int, path: str | Path) -> None:
    """Write :func:`contact_sheet` as a PNG file."""
    cv2.imwrite(str(path), cv2.cvtColor(contact_sheet(sequence_dir, frame), cv2.COLOR_RGB2BGR))


__all__ = ["contact_sheet", "write_contact_sheet"]
