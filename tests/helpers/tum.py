"""Ten real TUM RGB-D fr1_xyz frames (Kinect v1; ../shared/realdata/tum_fr1_xyz_10) as a FunREC capture folder,
with their motion-capture ground truth: real sensor data for the tests of camera tracking and of the
intrinsics check."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

TUM_DIR = Path("/work/shared/realdata/tum_fr1_xyz_10")
TUM_K = np.array([[517.3, 0.0, 318.6], [0.0, 516.5, 255.3], [0.0, 0.0, 1.0]])
"""Official TUM fr1 colour intrinsics (cy 255.3, not the ROS default 239.5)."""
TUM_DISTORTION = np.array([0.2624, -0.9531, -0.0054, 0.0026, 1.1633])
"""fr1 radial-tangential distortion (k1, k2, p1, p2, k3): up to ~8 px at the image corners."""


def write_tum_capture(root: Path) -> Path:
    """Copy the TUM frames into a FunREC capture folder, undistorted.

    The images are undistorted (colour bilinear, depth nearest so that no depth is mixed
    across edges) with the same K, because the pinhole model of FORMATS.md has no
    distortion and fr1's k1 = 0.26 moves corner pixels by several pixels.
    """
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    intrinsics = {"width": 640, "height": 480, "fx": TUM_K[0, 0], "fy": TUM_K[1, 1], "cx": TUM_K[0, 2],
                  "cy": TUM_K[1, 2], "depth_scale": 5000.0, "fps": 30.0}
    (root / "intrinsics.json").write_text(json.dumps(intrinsics))
    map_u, map_v = cv2.initUndistortRectifyMap(TUM_K, TUM_DISTORTION, None, TUM_K, (640, 480), cv2.CV_32FC1)
    for n in range(1, 11):
        rgb = cv2.imread(str(TUM_DIR / "rgb" / f"{n}.png"), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(TUM_DIR / "depth" / f"{n}.png"), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(root / "rgb" / f"{n - 1:06d}.png"), cv2.remap(rgb, map_u, map_v, cv2.INTER_LINEAR))
        cv2.imwrite(str(root / "depth" / f"{n - 1:06d}.png"), cv2.remap(depth, map_u, map_v, cv2.INTER_NEAREST))
    return root


def tum_ground_truth() -> np.ndarray:
    data = json.loads((TUM_DIR / "ground_truth.json").read_text())
    return np.array([data[str(n)]["transformation"] for n in range(1, 11)], dtype=np.float64)
