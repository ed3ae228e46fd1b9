"""Record3D .r3d exports (iPhone/iPad LiDAR): a zip of a JSON ``metadata`` (K column-major, colour w x h,
depth dw x dh, fps), ``rgbd/N.jpg`` colour, ``rgbd/N.depth`` LZFSE-compressed float32 depth in metres and
optional ``rgbd/N.conf`` LZFSE-compressed uint8 ARKit confidence, both at the depth resolution."""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from funrec.convert.camera_model import resize_colour, resize_depth, scale_pinhole
from funrec.convert.config import ConvertConfig
from funrec.convert.output import CaptureOutput
from funrec.convert.report import ConversionReport
from funrec.errors import CaptureError, FunrecError
from funrec.formats.capture import CaptureIntrinsics

_FRAME = re.compile(r"^rgbd/(\d+)\.(jpg|depth|conf)$")


def _lzfse() -> Any:
    try:
        import lzfse
    except ImportError:
        raise FunrecError("reading Record3D depth needs LZFSE: pip install lzfse (or funrec[convert])") from None
    return lzfse


def _metadata(path: Path, archive: zipfile.ZipFile) -> dict[str, Any]:
    try:
        data = json.loads(archive.read("metadata"))
        for key in ("K", "w", "h", "dw", "dh"):
            data[key]
    except KeyError as exc:
        raise CaptureError(path, f"metadata lacks {exc} (needs K, w, h, dw, dh)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(path, f"metadata is not valid JSON ({exc})") from None
    return data


def convert_record3d(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert a Record3D .r3d export into a capture folder.

    ARKit's depth is registered to the colour camera at a lower resolution; it is resampled (nearest)
    to the colour size, or to ``config.output_width``. Depth below ``config.record3d_min_confidence``
    is removed. Frames without depth, or with unreadable files, are dropped and reported.

    Raises:
        CaptureError: not a zip, bad metadata, or no frame converted.
        FunrecError: the lzfse package is not installed.
    """
    source = Path(source)
    lzfse = _lzfse()
    try:
        archive = zipfile.ZipFile(source)
    except (zipfile.BadZipFile, OSError) as exc:
        raise CaptureError(source, f"not a Record3D .r3d archive (zip) ({exc})") from None
    with archive:
        meta = _metadata(source, archive)
        K = np.asarray(meta["K"], dtype=np.float64).reshape(3, 3).T  # stored column-major
        size, depth_size = (int(meta["w"]), int(meta["h"])), (int(meta["dw"]), int(meta["dh"]))
        fps = float(meta.get("fps", 30.0))
        files: dict[int, dict[str, str]] = {}
        for name in archive.namelist():
            match = _FRAME.match(name)
            if match:
                files.setdefault(int(match.group(1)), {})[match.group(2)] = name
        stamps = meta.get("frameTimestamps")
        K_out, size_out = scale_pinhole(K, size, config.output_width)
        with CaptureOutput(source, out_dir, "record3d", config) as out:
            out.begin(CaptureIntrinsics(size_out[0], size_out[1], K_out[0, 0], K_out[1, 1], K_out[0, 2], K_out[1, 2],
                                        depth_scale=1000.0, fps=fps))
            out.note(f"colour {size[0]}x{size[1]}; depth {depth_size[0]}x{depth_size[1]} resampled (nearest) to "
                     f"{size_out[0]}x{size_out[1]}; depth of ARKit confidence < {config.record3d_min_confidence} removed")
            out.note("ARKit camera poses in the metadata are not written (they are estimates, not ground truth)")
            for index, number in enumerate(sorted(files)):
                if out.full:
                    break
                entry = files[number]
                stamp = float(stamps[number]) if isinstance(stamps, list) and number < len(stamps) else None
                if "jpg" not in entry or "depth" not in entry:
                    out.drop(index, stamp, f"rgbd/{number}: {'no depth' if 'jpg' in entry else 'no colour image'}")
                    continue
                try:
                    frame = _read_frame(archive, entry, lzfse, size, depth_size, config.record3d_min_confidence)
                except ValueError as exc:
                    out.drop(index, stamp, f"rgbd/{number}: {exc}")
                    continue
                rgb, depth_m = frame
                out.write(resize_colour(rgb, size_out), resize_depth(depth_m, size_out), index, stamp)
    return out.report


def _read_frame(archive: zipfile.ZipFile, entry: dict[str, str], lzfse: Any, size: tuple[int, int],
                depth_size: tuple[int, int], min_confidence: int) -> tuple[np.ndarray, np.ndarray]:
    image = cv2.imdecode(np.frombuffer(archive.read(entry["jpg"]), np.uint8), cv2.IMREAD_COLOR)
    if image is None or (image.shape[1], image.shape[0]) != size:
        raise ValueError(f"colour image unreadable or not {size[0]}x{size[1]}")
    try:
        depth = np.frombuffer(lzfse.decompress(archive.read(entry["depth"])), dtype=np.float32)
    except lzfse.error as exc:
        raise ValueError(f"depth is not LZFSE data ({exc})") from None
    if depth.size != depth_size[0] * depth_size[1]:
        raise ValueError(f"depth has {depth.size} values, metadata says {depth_size[0]}x{depth_size[1]}")
    depth_m = depth.reshape(depth_size[1], depth_size[0]).astype(np.float64)
    depth_m = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0)
    if "conf" in entry and min_confidence > 0:
        confidence = np.frombuffer(lzfse.decompress(archive.read(entry["conf"])), dtype=np.uint8)
        if confidence.size == depth.size:
            depth_m[confidence.reshape(depth_m.shape) < min_confidence] = 0.0
    depth_m = resize_depth(depth_m, size)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB), depth_m


__all__ = ["convert_record3d"]
