"""Look at what the twin says about one frame: each part's estimated mask (green) and its joint axis
(red; a revolute hinge as a line through the pivot, a slide as an arrow from the part's mask centre)
drawn over the capture's RGB, beside the ground-truth masks (blue) when the capture has them.

    python demos/mask_overlay.py CAPTURE TWIN --frame 80 -o overlay.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np


def _project(p_world: np.ndarray, T_world_camera: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of world points (N, 3)."""
    from funrec.geometry.camera import project
    from funrec.geometry.transforms import invert_transform, transform_points

    return project(transform_points(invert_transform(T_world_camera), p_world), K)[0]


def _tint(image: np.ndarray, mask: np.ndarray, bgr: tuple[int, int, int]) -> None:
    image[mask] = (0.5 * image[mask] + 0.5 * np.array(bgr)).astype(np.uint8)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(image, contours, -1, bgr, 2)


def overlay(capture_dir: Path, twin_dir: Path, frame: int) -> np.ndarray:
    """The picture: estimate on the left, ground truth (if any) on the right."""
    from funrec.formats.camera_poses import read_camera_poses
    from funrec.formats.capture import load_capture, read_mask
    from funrec.formats.twin import read_articulation
    from funrec.geometry.transforms import transform_points

    capture = load_capture(capture_dir)
    if not 0 <= frame < len(capture):
        raise SystemExit(f"{capture_dir}: frame {frame} is outside 0-{len(capture) - 1}")
    rgb = cv2.cvtColor(capture.rgb(frame), cv2.COLOR_RGB2BGR)
    poses = read_camera_poses(twin_dir / "camera_poses.txt")
    T_world_camera = poses.T_world_camera[int(np.searchsorted(poses.frames, frame))]
    K = capture.intrinsics.K
    estimate = rgb.copy()
    for row, part in enumerate(read_articulation(twin_dir / "articulation.json").parts):
        mask_path = twin_dir / (part.masks or f"masks/{part.name}") / f"{Path(capture.rgb_paths[frame]).stem}.png"
        mask = read_mask(mask_path) if mask_path.is_file() else np.zeros(rgb.shape[:2], bool)
        if mask.any():
            _tint(estimate, mask, (0, 200, 0))
        if part.joint_type == "revolute":
            ends = _project(part.pivot_world + np.outer([-0.6, 0.6], part.axis_world), T_world_camera, K)
            cv2.line(estimate, tuple(ends[0].astype(int)), tuple(ends[1].astype(int)), (0, 0, 255), 3)
        elif mask.any():
            v, u = np.nonzero(mask)
            depth = capture.depth_m(frame)[v, u]
            centre_uv = np.array([u[depth > 0].mean(), v[depth > 0].mean()]) if (depth > 0).any() else None
            if centre_uv is not None:
                z = float(np.median(depth[depth > 0]))
                p_camera = z * np.linalg.solve(K, [centre_uv[0], centre_uv[1], 1.0])  # the pixel lifted to depth z
                p_world = transform_points(T_world_camera, p_camera[None])[0]
                ends = _project(np.stack([p_world, p_world + 0.3 * part.axis_world]), T_world_camera, K)
                cv2.arrowedLine(estimate, tuple(ends[0].astype(int)), tuple(ends[1].astype(int)), (0, 0, 255), 3)
        cv2.putText(estimate, f"{part.name}: {part.joint_type}", (10, 30 + 28 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.8,
                    (0, 0, 255), 2)
    truth_dir = capture_dir / "gt" / "masks"
    if not truth_dir.is_dir():
        return estimate
    truth = rgb.copy()
    for mask_path in sorted(truth_dir.glob(f"part_*/{Path(capture.rgb_paths[frame]).stem}.png")):
        _tint(truth, read_mask(mask_path), (200, 0, 0))
    cv2.putText(truth, "ground truth", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (200, 0, 0), 2)
    return np.hstack([estimate, truth])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("capture", type=Path, help="capture folder (FORMATS.md section 1)")
    parser.add_argument("twin", type=Path, help="twin folder reconstructed from it")
    parser.add_argument("--frame", type=int, required=True, help="frame index")
    parser.add_argument("-o", "--output", type=Path, required=True, help="PNG to write")
    args = parser.parse_args()
    picture = overlay(args.capture, args.twin, args.frame)
    if not cv2.imwrite(str(args.output), picture):
        raise SystemExit(f"could not write {args.output}")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
