"""TUM RGB-D sequences: the benchmark's own layout (rgb.txt, depth.txt, optional groundtruth.txt) and the
frame-numbered layout of shared/realdata (rgb/N.png, depth/N.png, ground_truth.json)."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from funrec.convert.association import associate_nearest
from funrec.convert.camera_model import (
    LensCamera,
    remap_colour,
    remap_depth,
    resize_colour,
    resize_depth,
    scale_pinhole,
)
from funrec.convert.config import ConvertConfig
from funrec.convert.output import CaptureOutput
from funrec.convert.report import ConversionReport
from funrec.errors import CaptureError
from funrec.formats.capture import CaptureIntrinsics
from funrec.geometry.transforms import check_transform, make_transform
from funrec.typed import FloatArray

TUM_DEPTH_SCALE = 5000.0
"""TUM depth PNGs hold 5000 per metre."""
TUM_FPS = 30.0
"""Nominal Kinect v1 frame rate, used when a layout has no timestamps."""


@dataclass(frozen=True)
class _TumCamera:
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...]


TUM_CAMERAS = {
    "fr1": _TumCamera(517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": _TumCamera(520.9, 521.0, 325.1, 249.7, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": _TumCamera(535.4, 539.2, 320.1, 247.6, ()),
    "ros": _TumCamera(525.0, 525.0, 319.5, 239.5, ()),
}
"""Colour calibrations published with the benchmark (fr3 images are already undistorted); 'ros' is the ROS
default TUM recommends for undistorted use. Distortion is OpenCV k1 k2 p1 p2 k3."""


def is_tum_folder(path: Path) -> bool:
    """True for a folder in either TUM layout."""
    return path.is_dir() and (
        ((path / "rgb.txt").is_file() and (path / "depth.txt").is_file()) or (path / "ground_truth.json").is_file()
    )


def _camera_name(source: Path, config: ConvertConfig) -> str:
    if config.tum_camera != "auto":
        return config.tum_camera
    match = re.search(r"(?:freiburg|fr)([123])(?![0-9])", source.resolve().name.lower())
    if match is None:
        raise CaptureError(
            source,
            "cannot tell which TUM camera recorded this folder (no 'freiburg1/2/3' or 'fr1/2/3' in its name); "
            "set tum_camera to fr1, fr2, fr3 or ros",
        )
    return f"fr{match.group(1)}"


def _read_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """Read a TUM 'timestamp filename' list."""
    stamps, names = [], []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        try:
            stamps.append(float(parts[0]))
        except (ValueError, IndexError):
            raise CaptureError(path, f"line {line_no}: expected 'timestamp filename', got {text!r}") from None
        if len(parts) < 2:
            raise CaptureError(path, f"line {line_no}: expected 'timestamp filename', got {text!r}")
        names.append(parts[1])
    t = np.array(stamps)
    if len(t) and np.any(np.diff(t) <= 0):
        raise CaptureError(path, "timestamps are not strictly increasing")
    return t, names


def _read_groundtruth(path: Path) -> tuple[np.ndarray, FloatArray]:
    """Read groundtruth.txt ('timestamp tx ty tz qx qy qz qw', camera-to-world)."""
    rows = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        try:
            values = [float(v) for v in text.split()]
        except ValueError:
            raise CaptureError(path, f"line {line_no}: not a number in {text!r}") from None
        if len(values) != 8:
            raise CaptureError(path, f"line {line_no}: expected 8 values 'timestamp tx ty tz qx qy qz qw'")
        rows.append(values)
    if len(rows) < 2:
        raise CaptureError(path, "fewer than two poses")
    data = np.array(rows)
    return data[:, 0], make_transform(Rotation.from_quat(data[:, 4:8]).as_matrix(), data[:, 1:4])


def _interpolate_poses(t_gt: np.ndarray, T_world_camera: FloatArray, t_query: float, max_gap_s: float) -> FloatArray | None:
    """Camera-to-world pose at ``t_query`` (position linear, rotation slerp) from the two bracketing samples,
    or None outside the samples or where they are more than ``2 * max_gap_s`` apart (tracking lost)."""
    k = int(np.searchsorted(t_gt, t_query))
    if k == 0 or k == len(t_gt):
        return None
    t0, t1 = t_gt[k - 1], t_gt[k]
    if t1 - t0 > 2 * max_gap_s:
        return None
    a = (t_query - t0) / (t1 - t0)
    slerp = Slerp([t0, t1], Rotation.from_matrix(T_world_camera[k - 1 : k + 1, :3, :3]))
    t = (1 - a) * T_world_camera[k - 1, :3, 3] + a * T_world_camera[k, :3, 3]
    return make_transform(slerp([t_query]).as_matrix()[0], t)


def _read_colour(path: Path, frame: int) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise CaptureError(path, "missing or unreadable colour image", frame)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _read_depth(path: Path, frame: int) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise CaptureError(path, "missing or unreadable depth image", frame)
    if image.dtype != np.uint16 or image.ndim != 2:
        raise CaptureError(path, f"depth is {image.dtype} with shape {image.shape}, expected 16-bit single channel", frame)
    return image


def _frames_with_timestamps(source: Path, config: ConvertConfig, out: CaptureOutput) -> Iterator[tuple]:
    """(source_index, timestamp, rgb path, depth path, T_world_camera_true) of the TUM benchmark layout."""
    t_rgb, rgb_names = _read_list(source / "rgb.txt")
    t_depth, depth_names = _read_list(source / "depth.txt")
    match = associate_nearest(t_rgb, t_depth, config.max_time_difference_s)
    unused_depth = len(t_depth) - int(np.sum(match >= 0))
    if unused_depth:
        out.note(f"{unused_depth} of {len(t_depth)} depth images matched no colour image")
    gt = None
    if (source / "groundtruth.txt").is_file():
        gt = _read_groundtruth(source / "groundtruth.txt")
        out.note("ground truth from groundtruth.txt, interpolated to the colour timestamps")
    for i, (t, name) in enumerate(zip(t_rgb, rgb_names)):
        j = int(match[i])
        if j < 0:
            out.drop(i, t, f"no unused depth image within {config.max_time_difference_s:.3f} s")
            continue
        T_true = None if gt is None else _interpolate_poses(gt[0], gt[1], t, config.max_time_difference_s)
        yield i, float(t), source / name, source / depth_names[j], T_true


def _frames_numbered(source: Path, out: CaptureOutput) -> Iterator[tuple]:
    """The same for the frame-numbered layout with ground_truth.json."""
    path = source / "ground_truth.json"
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(path, f"not valid JSON ({exc})") from None
    try:
        numbers = sorted(data, key=int)
    except (TypeError, ValueError):
        raise CaptureError(path, "keys must be frame numbers") from None
    out.note(f"frame-numbered layout without timestamps: frames {numbers[0]}..{numbers[-1]} in number order, fps {TUM_FPS:g}")
    for i, key in enumerate(numbers):
        entry = data[key]
        try:
            T_true = check_transform(entry["transformation"], f"frame {key} transformation")
            rgb_name, depth_name = entry["rgb"], entry["depth"]
        except (KeyError, TypeError, ValueError) as exc:
            raise CaptureError(path, f"frame {key}: needs 'rgb', 'depth' and a 4x4 'transformation' ({exc})", i) from None
        yield i, None, source / rgb_name, source / depth_name, T_true


def convert_tum(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert a TUM RGB-D folder into a capture folder.

    Colour and depth (already registered to colour by the Kinect driver) are undistorted into a
    pinhole image with the same K (colour bilinear, depth nearest); depth keeps TUM's scale of 5000
    per metre unless ``config.depth_scale`` says otherwise. Motion-capture poses go to gt/ (FORMATS.md
    sections 3 and 4), never to the capture's own camera_poses.txt.

    Raises:
        CaptureError: unknown camera, unreadable lists, or no frame could be converted.
    """
    source = Path(source)
    if not is_tum_folder(source):
        raise CaptureError(source, "not a TUM RGB-D folder (needs rgb.txt and depth.txt, or ground_truth.json)")
    name = _camera_name(source, config)
    camera = TUM_CAMERAS[name]
    lens = LensCamera(640, 480, [[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]], camera.distortion)
    K_out, size_out = scale_pinhole(lens.K, lens.size, config.output_width)
    maps = lens.undistort_maps(lens.K, lens.size) if lens.has_distortion else None
    with CaptureOutput(source, out_dir, "tum", config) as out:
        out.note(
            f"intrinsics: TUM {name} fx {camera.fx} fy {camera.fy} cx {camera.cx} cy {camera.cy}"
            + (f", undistorted (k1 k2 p1 p2 k3 = {list(camera.distortion)}) into a pinhole image with the same K" if maps else "")
        )
        if (source / "camera_intrinsics.yaml").is_file():
            out.note(f"camera_intrinsics.yaml ignored: the official {name} calibration is used")
        out.begin(CaptureIntrinsics(size_out[0], size_out[1], K_out[0, 0], K_out[1, 1], K_out[0, 2], K_out[1, 2],
                                    depth_scale=TUM_DEPTH_SCALE, fps=TUM_FPS))
        frames = _frames_with_timestamps(source, config, out) if (source / "rgb.txt").is_file() else _frames_numbered(source, out)
        for index, timestamp, rgb_path, depth_path, T_true in frames:
            if out.full:
                break
            try:
                rgb, depth = _read_colour(rgb_path, index), _read_depth(depth_path, index)
            except CaptureError as exc:
                out.drop(index, timestamp, str(exc))
                continue
            if rgb.shape[:2] != (480, 640) or depth.shape != (480, 640):
                out.drop(index, timestamp, f"image size {rgb.shape[:2]} / {depth.shape}, TUM images are 480x640")
                continue
            if maps is not None:
                rgb, depth = remap_colour(rgb, maps), remap_depth(depth, maps)
            rgb, depth = resize_colour(rgb, size_out), resize_depth(depth, size_out)
            out.write(rgb, depth / TUM_DEPTH_SCALE, index, timestamp, T_true)
    return out.report


__all__ = ["TUM_CAMERAS", "TUM_DEPTH_SCALE", "convert_tum", "is_tum_folder"]
