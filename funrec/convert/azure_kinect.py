"""Azure Kinect DK recordings (.mkv as k4arecorder writes them): colour, 16-bit depth and the factory
calibration attachment; depth is registered into the undistorted colour camera."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from funrec.convert.association import associate_nearest, stream_pairs
from funrec.convert.camera_model import LensCamera, remap_colour, resize_colour, scale_pinhole
from funrec.convert.config import ConvertConfig
from funrec.convert.output import CaptureOutput
from funrec.convert.registration import register_depth
from funrec.convert.report import ConversionReport
from funrec.errors import CaptureError, FunrecError
from funrec.formats.capture import CaptureIntrinsics
from funrec.geometry.transforms import invert_transform, make_transform
from funrec.typed import FloatArray

AZURE_DEPTH_SCALE = 1000.0
"""Azure Kinect depth is in millimetres."""

# (binned calibration resolution, crop offset, output resolution) per mode, from the Azure Kinect
# SDK's mode_specific_calibration.c: the factory calibration is normalised to the full sensor.
_DEPTH_MODES = {
    "NFOV_2X2BINNED": ((512, 512), (96, 90), (320, 288)),
    "NFOV_UNBINNED": ((1024, 1024), (192, 180), (640, 576)),
    "WFOV_2X2BINNED": ((512, 512), (0, 0), (512, 512)),
    "WFOV_UNBINNED": ((1024, 1024), (0, 0), (1024, 1024)),
}
_COLOUR_MODES = {
    720: ((1280, 960), (0, 120), (1280, 720)),
    1080: ((1920, 1440), (0, 180), (1920, 1080)),
    1440: ((2560, 1920), (0, 240), (2560, 1440)),
    1536: ((2048, 1536), (0, 0), (2048, 1536)),
    2160: ((3840, 2880), (0, 360), (3840, 2160)),
    3072: ((4096, 3072), (0, 0), (4096, 3072)),
}


@dataclass(frozen=True)
class AzureCalibration:
    """Depth and colour cameras of one recording mode, from the calibration.json attachment."""

    depth: LensCamera
    """Depth camera at the recording's depth mode resolution."""
    colour: LensCamera
    """Colour camera at the recording's colour resolution."""
    T_colour_depth: FloatArray
    """(4, 4) maps depth-camera points to colour-camera points, metres."""


def _camera(path: Path, data: dict[str, Any], purpose: str) -> dict[str, Any]:
    cameras = data.get("CalibrationInformation", {}).get("Cameras", [])
    for camera in cameras:
        if camera.get("Purpose") == purpose:
            return camera
    raise CaptureError(path, f"calibration has no camera with Purpose {purpose}; found {[c.get('Purpose') for c in cameras]}")


def _lens(path: Path, camera: dict[str, Any], mode: tuple) -> LensCamera:
    """Mode-specific OpenCV camera from a raw (unitised, 0-cornered) Brown-Conrady calibration."""
    intrinsics = camera["Intrinsics"]
    if intrinsics.get("ModelType") != "CALIBRATION_LensDistortionModelBrownConrady":
        raise CaptureError(path, f"lens model {intrinsics.get('ModelType')}; only Brown-Conrady is supported")
    cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, _codx, _cody, p2, p1 = (float(v) for v in intrinsics["ModelParameters"][:14])
    (bw, bh), (ox, oy), (w, h) = mode
    # Pixelised, zero-centred OpenCV convention, as the SDK's transformation_get_mode_specific_camera_calibration.
    K = [[fx * bw, 0.0, cx * bw - ox - 0.5], [0.0, fy * bh, cy * bh - oy - 0.5], [0.0, 0.0, 1.0]]
    radius = float(camera.get("MetricRadius", 0.0))
    return LensCamera(w, h, K, [k1, k2, p1, p2, k3, k4, k5, k6], radius if radius > 0 else None)


def _T_camera_world(camera: dict[str, Any]) -> FloatArray:
    Rt = camera["Rt"]
    return make_transform(np.array(Rt["Rotation"], dtype=np.float64).reshape(3, 3), np.array(Rt["Translation"], float))


def parse_calibration(path: Path, text: str | bytes, depth_mode: str, colour_height: int) -> AzureCalibration:
    """Read the k4a calibration JSON for one depth mode and colour resolution.

    Args:
        path: where the JSON came from (for messages).
        text: the JSON.
        depth_mode: k4a depth mode name, e.g. 'NFOV_UNBINNED'.
        colour_height: colour image height (720, 1080, 1440, 1536, 2160 or 3072).
    """
    try:
        data = json.loads(text.rstrip(b"\x00") if isinstance(text, bytes) else text)
        depth_raw = _camera(path, data, "CALIBRATION_CameraPurposeDepth")
        colour_raw = _camera(path, data, "CALIBRATION_CameraPurposePhotoVideo")
        if depth_mode not in _DEPTH_MODES:
            raise CaptureError(path, f"depth mode {depth_mode!r} has no depth image; supported: {sorted(_DEPTH_MODES)}")
        if colour_height not in _COLOUR_MODES:
            raise CaptureError(path, f"colour height {colour_height} is no k4a colour mode; expected one of {sorted(_COLOUR_MODES)}")
        if int(colour_raw["SensorWidth"]) * 3 != int(colour_raw["SensorHeight"]) * 4:
            raise CaptureError(path, "legacy 16:9 colour calibration is not supported")
        depth = _lens(path, depth_raw, _DEPTH_MODES[depth_mode])
        colour = _lens(path, colour_raw, _COLOUR_MODES[colour_height])
        # Rt of each camera maps the calibration's world (the depth camera) into that camera.
        T_colour_depth = _T_camera_world(colour_raw) @ invert_transform(_T_camera_world(depth_raw))
    except (KeyError, TypeError, ValueError) as exc:
        raise CaptureError(path, f"malformed Azure Kinect calibration ({type(exc).__name__}: {exc})") from None
    return AzureCalibration(depth, colour, T_colour_depth)


def _open(source: Path) -> Any:
    try:
        import av
    except ImportError:
        raise FunrecError("reading Azure Kinect .mkv files needs PyAV: pip install av (or funrec[convert])") from None
    try:
        return av.open(str(source))
    except av.error.FFmpegError as exc:
        raise CaptureError(source, f"not a readable Matroska file ({exc})") from None


def _tracks(source: Path, container: Any) -> tuple[Any, Any, Any]:
    """The colour, depth and calibration-attachment streams, by their k4arecorder names."""
    by_title = {s.metadata.get("title", "").upper(): s for s in container.streams if s.type == "video"}
    colour, depth = by_title.get("COLOR"), by_title.get("DEPTH")
    calibration = next(
        (s for s in container.streams if s.type == "attachment" and "K4A_CALIBRATION_FILE" in s.metadata), None
    )
    if depth is None:
        raise CaptureError(
            source, "no DEPTH track: this .mkv is not an Azure Kinect RGB-D recording (a plain video has no depth, and "
            f"FunREC needs RGB-D); tracks: {sorted(by_title) or 'none'}"
        )
    if colour is None:
        raise CaptureError(source, f"no COLOR track (recorded with the colour camera off?); tracks: {sorted(by_title)}")
    if calibration is None:
        raise CaptureError(source, "no calibration.json attachment (K4A_CALIBRATION_FILE); cannot register depth")
    return colour, depth, calibration


def _decode_colour(packet_bytes: bytes, codec: str, tag: str, size: tuple[int, int]) -> np.ndarray | None:
    """(H, W, 3) RGB of one colour block, or None if it cannot be decoded."""
    W, H = size
    buffer = np.frombuffer(packet_bytes, dtype=np.uint8)
    if codec == "mjpeg":
        image = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
        return None if image is None or image.shape[:2] != (H, W) else cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    conversions = {"BGRA": (4 * W * H, (H, W, 4), cv2.COLOR_BGRA2RGB), "NV12": (3 * W * H // 2, (H * 3 // 2, W), cv2.COLOR_YUV2RGB_NV12),
                   "YUY2": (2 * W * H, (H, W, 2), cv2.COLOR_YUV2RGB_YUY2)}
    if tag not in conversions or buffer.size != conversions[tag][0]:
        return None
    _, shape, code = conversions[tag]
    return cv2.cvtColor(buffer.reshape(shape), code)


def _packet_times(container: Any, streams: tuple[Any, Any]) -> tuple[list[float], list[float]]:
    """Timestamps in seconds of every non-empty colour and depth block (a demux pass, no decoding)."""
    times: tuple[list[float], list[float]] = ([], [])
    for packet in container.demux(streams):
        if packet.size and packet.pts is not None:
            times[0 if packet.stream is streams[0] else 1].append(float(packet.pts * packet.time_base))
    return times


def convert_azure_kinect(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert an Azure Kinect .mkv recording into a capture folder.

    Colour is undistorted (Brown-Conrady, bilinear) into a pinhole image with the colour camera's K,
    optionally shrunk to ``config.output_width``. Depth pixels are unprojected with the depth camera's
    distortion, moved by the depth-to-colour extrinsics and z-buffered into that pinhole image.

    Raises:
        CaptureError: no depth track or calibration, an unsupported mode, or no frame converted.
        FunrecError: PyAV is not installed.
    """
    source = Path(source)
    container = _open(source)
    try:
        colour_stream, depth_stream, attachment = _tracks(source, container)
        depth_mode = depth_stream.metadata.get("K4A_DEPTH_MODE", "")
        colour_codec = colour_stream.codec_context.name
        colour_tag = str(colour_stream.codec_context.codec_tag)
        size_colour = (colour_stream.codec_context.width, colour_stream.codec_context.height)
        size_depth = (depth_stream.codec_context.width, depth_stream.codec_context.height)
        calibration = parse_calibration(source / "calibration.json", bytes(attachment.data), depth_mode, size_colour[1])
        if calibration.depth.size != size_depth:
            raise CaptureError(source, f"depth track is {size_depth}, mode {depth_mode} implies {calibration.depth.size}")
        if str(depth_stream.codec_context.codec_tag) != "b16g":
            raise CaptureError(source, f"depth track codec {depth_stream.codec_context.codec_tag!r}, expected b16g (16-bit big-endian)")
        t_colour, t_depth = _packet_times(container, (colour_stream, depth_stream))
        container.seek(0)
        match = associate_nearest(t_colour, t_depth, config.max_time_difference_s)
        xy_depth, valid_depth = calibration.depth.rays()
        K_out, size_out = scale_pinhole(calibration.colour.K, calibration.colour.size, config.output_width)
        colour_maps = calibration.colour.undistort_maps(calibration.colour.K, calibration.colour.size)
        splat_2x2 = K_out[0, 0] > calibration.depth.K[0, 0]
        with CaptureOutput(source, out_dir, "azure_kinect", config) as out:
            out.begin(CaptureIntrinsics(size_out[0], size_out[1], K_out[0, 0], K_out[1, 1], K_out[0, 2], K_out[1, 2],
                                        depth_scale=AZURE_DEPTH_SCALE, fps=float(colour_stream.average_rate or 30.0)))  # from timestamps when >= 2 frames
            out.note(
                f"colour {colour_codec} {size_colour[0]}x{size_colour[1]} undistorted (Brown-Conrady) into a pinhole with its K"
                + (f", shrunk to {size_out[0]}x{size_out[1]}" if size_out != size_colour else "")
            )
            out.note(
                f"depth {depth_mode} {size_depth[0]}x{size_depth[1]} registered into the colour camera with the attached "
                f"calibration ({int((~valid_depth).sum())} depth pixels outside the lens model's valid radius ignored; "
                f"{'2x2' if splat_2x2 else 'nearest-pixel'} z-buffer splatting)"
            )
            out.note(f"depth delay {container.metadata.get('K4A_DEPTH_DELAY_NS', '?')} ns; IR and IMU tracks ignored")
            unmatched = len(t_depth) - int(np.sum(match >= 0))
            if unmatched:
                out.note(f"{unmatched} of {len(t_depth)} depth images matched no colour image")
            blocks = (
                (packet.stream is colour_stream, bytes(packet))
                for packet in container.demux((colour_stream, depth_stream))
                if packet.size and packet.pts is not None
            )
            for i, colour_bytes, depth_bytes in stream_pairs(blocks, match):
                if out.full:
                    break
                if depth_bytes is None:
                    out.drop(i, t_colour[i], f"no unused depth image within {config.max_time_difference_s:.3f} s")
                    continue
                rgb = _decode_colour(colour_bytes, colour_codec, colour_tag, size_colour)
                if rgb is None:
                    out.drop(i, t_colour[i], f"colour block ({colour_codec} {colour_tag}) cannot be decoded")
                    continue
                if len(depth_bytes) != 2 * size_depth[0] * size_depth[1]:
                    out.drop(i, t_colour[i], f"depth block has {len(depth_bytes)} bytes, expected {2 * size_depth[0] * size_depth[1]}")
                    continue
                depth_m = np.frombuffer(depth_bytes, dtype=">u2").reshape(size_depth[1], size_depth[0]) / AZURE_DEPTH_SCALE
                depth_out = register_depth(
                    depth_m, xy_depth, valid_depth, calibration.T_colour_depth, K_out, size_out, splat_2x2
                )
                out.write(resize_colour(remap_colour(rgb, colour_maps), size_out), depth_out, i, t_colour[i])
    finally:
        container.close()
    return out.report


__all__ = ["AZURE_DEPTH_SCALE", "AzureCalibration", "convert_azure_kinect", "parse_calibration"]
