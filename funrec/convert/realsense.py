"""Intel RealSense SDK recordings: the ROS 1 .bag of SDK versions up to 2.55 and the ROS 2 .db3 of later ones
(topics /device_0/sensor_S/{Depth,Color}_0/...); depth is registered into the colour camera."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from funrec.convert.association import associate_nearest
from funrec.convert.camera_model import LensCamera, remap_colour, resize_colour, scale_pinhole
from funrec.convert.config import ConvertConfig
from funrec.convert.output import CaptureOutput
from funrec.convert.registration import register_depth
from funrec.convert.report import ConversionReport
from funrec.convert.rosbag import (
    IMAGE_TYPES,
    decode_colour,
    decode_depth_m,
    message_pairs,
    open_bag,
    read_stamps,
)
from funrec.errors import CaptureError
from funrec.formats.capture import CaptureIntrinsics
from funrec.geometry.transforms import invert_transform, make_transform
from funrec.typed import FloatArray

_IMAGE_TOPIC = re.compile(r"^(/device_\d+/sensor_\d+/(Depth|Color)_\d+)/image/data(/compressed|/compressedDepth)?$")
_OPENCV_MODELS = ("plumb_bob", "Brown Conrady")
"""RealSense distortion models that are OpenCV's radial-tangential model (others are refused unless all zero)."""


def is_realsense_bag(path: Path) -> bool:
    """True for a bag with RealSense SDK image topics."""
    reader = open_bag(path)
    try:
        return any(_IMAGE_TOPIC.match(c.topic) for c in reader.connections)
    finally:
        reader.close()


@dataclass(frozen=True)
class _Stream:
    prefix: str
    """Topic prefix, e.g. /device_0/sensor_1/Color_0."""
    image: Any
    """Connection of the image topic."""


def _streams(path: Path, reader: Any) -> tuple[_Stream, _Stream]:
    found: dict[str, list[_Stream]] = {"Color": [], "Depth": []}
    for connection in reader.connections:
        match = _IMAGE_TOPIC.match(connection.topic)
        if match and connection.msgtype in IMAGE_TYPES:
            found[match.group(2)].append(_Stream(match.group(1), connection))
    for kind, streams in found.items():
        if len(streams) != 1:
            topics = sorted(s.image.topic for v in found.values() for s in v)
            raise CaptureError(path, f"expected one {kind} image stream, found {len(streams)}; image topics: {topics}")
    return found["Color"][0], found["Depth"][0]


def _messages(reader: Any, topic: str) -> list[Any]:
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:  # rosbags reads every topic for an empty list
        return []
    return [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)][:1]


def _string_fields(text: str) -> dict[str, str]:
    return dict(part.split("=", 1) for part in text.strip().strip(";").split(";") if "=" in part)


def _camera(path: Path, reader: Any, stream: _Stream) -> LensCamera:
    for suffix in ("/info/camera_info", "/image/camera_info"):
        messages = _messages(reader, stream.prefix + suffix)
        if messages:
            info = messages[0]
            D = np.asarray(info.d if hasattr(info, "d") else info.D, dtype=np.float64)
            if np.any(D != 0) and info.distortion_model not in _OPENCV_MODELS:
                raise CaptureError(path, f"{stream.prefix}: distortion model {info.distortion_model!r} is not supported")
            K = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=np.float64).reshape(3, 3)
            return LensCamera(int(info.width), int(info.height), K, D if np.any(D != 0) else np.zeros(0))
    messages = _messages(reader, stream.prefix + "/camera_info")
    if not messages:
        raise CaptureError(path, f"{stream.prefix}: no camera_info topic (intrinsics are required)")
    fields = _string_fields(messages[0].data)
    coeffs = np.array([float(c) for c in fields.get("coeffs", "").split(",") if c], dtype=np.float64)
    if np.any(coeffs != 0) and fields.get("model") not in _OPENCV_MODELS:
        raise CaptureError(path, f"{stream.prefix}: distortion model {fields.get('model')!r} is not supported")
    K = [[float(fields["fx"]), 0, float(fields["ppx"])], [0, float(fields["fy"]), float(fields["ppy"])], [0, 0, 1]]
    return LensCamera(int(fields["width"]), int(fields["height"]), K, coeffs if np.any(coeffs != 0) else np.zeros(0))


def _T_stream_reference(path: Path, reader: Any, stream: _Stream) -> FloatArray:
    """The extrinsics the SDK records per stream: the reference stream's points into this stream's frame
    (rs2_extrinsics from the reference, rotation column-major in the ROS 2 string form)."""
    for connection in reader.connections:
        if not connection.topic.startswith(stream.prefix + "/tf/"):
            continue
        message = reader.deserialize(next(iter(reader.messages(connections=[connection])))[2], connection.msgtype)
        if hasattr(message, "translation"):  # geometry_msgs/Transform (ROS 1 layout)
            q, t = message.rotation, message.translation
            return make_transform(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), [t.x, t.y, t.z])
        fields = _string_fields(message.data)
        R = np.array([float(v) for v in fields["rotation"].split(",")]).reshape(3, 3).T
        return make_transform(R, [float(v) for v in fields["translation"].split(",")])
    raise CaptureError(path, f"{stream.prefix}: no tf (extrinsics) topic; cannot register depth to colour")


def _depth_unit_m(path: Path, reader: Any, depth: _Stream) -> float:
    sensor = depth.prefix.rsplit("/", 1)[0]
    for name in ("Depth Units", "Depth_Units"):
        messages = _messages(reader, f"{sensor}/option/{name}/value")
        if messages:
            return float(messages[0].data)
    raise CaptureError(path, f"{sensor}: no 'Depth Units' option recorded; the depth scale is unknown")


def convert_realsense(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert a RealSense SDK recording into a capture folder.

    Colour is undistorted into a pinhole image with its K when it has distortion (optionally shrunk to
    ``config.output_width``); depth pixels are unprojected with the depth intrinsics, moved by the recorded
    extrinsics and z-buffered into it. Frames are paired by header stamp.

    Raises:
        CaptureError: missing streams, intrinsics, extrinsics or depth units, or no frame converted.
        FunrecError: rosbags is not installed.
    """
    source = Path(source)
    reader = open_bag(source)
    try:
        colour, depth = _streams(source, reader)
        colour_camera, depth_camera = _camera(source, reader, colour), _camera(source, reader, depth)
        T_colour_depth = _T_stream_reference(source, reader, colour) @ invert_transform(_T_stream_reference(source, reader, depth))
        depth_unit_m = _depth_unit_m(source, reader, depth)
        t_colour, t_depth = read_stamps(source, reader, colour.image, depth.image)
        match = associate_nearest(t_colour, t_depth, config.max_time_difference_s)
        xy_depth, valid_depth = depth_camera.rays()
        K_out, size_out = scale_pinhole(colour_camera.K, colour_camera.size, config.output_width)
        maps = colour_camera.undistort_maps(colour_camera.K, colour_camera.size) if colour_camera.has_distortion else None
        splat_2x2 = K_out[0, 0] > depth_camera.K[0, 0]
        with CaptureOutput(source, out_dir, "realsense", config) as out:
            out.begin(CaptureIntrinsics(size_out[0], size_out[1], K_out[0, 0], K_out[1, 1], K_out[0, 2], K_out[1, 2],
                                        depth_scale=float(f"{1.0 / depth_unit_m:.6g}"), fps=30.0))  # float32 units
            out.note(f"colour {colour.image.topic}, depth {depth.image.topic} ({depth_unit_m:g} m per unit) registered "
                     f"into the colour camera with the recorded extrinsics (|t| = {np.linalg.norm(T_colour_depth[:3, 3]):.4f} m)")
            if maps is not None:
                out.note(f"colour undistorted ({colour_camera.distortion.tolist()}) into a pinhole with its K")
            unmatched = len(t_depth) - int(np.sum(match >= 0))
            if unmatched:
                out.note(f"{unmatched} of {len(t_depth)} depth images matched no colour image")
            for i, (colour_type, colour_raw), depth_item in message_pairs(reader, colour.image, depth.image, match):
                if out.full:
                    break
                if depth_item is None:
                    out.drop(i, t_colour[i], f"no unused depth image within {config.max_time_difference_s:.3f} s")
                    continue
                try:
                    rgb = decode_colour(reader.deserialize(colour_raw, colour_type), colour_type)
                    depth_m = decode_depth_m(reader.deserialize(depth_item[1], depth_item[0]), depth_item[0], depth_unit_m)
                except ValueError as exc:
                    out.drop(i, t_colour[i], str(exc))
                    continue
                if rgb.shape[:2] != (colour_camera.height, colour_camera.width) or depth_m.shape != (depth_camera.height, depth_camera.width):
                    out.drop(i, t_colour[i], f"image sizes {rgb.shape[:2]} / {depth_m.shape} differ from the camera infos")
                    continue
                if maps is not None:
                    rgb = remap_colour(rgb, maps)
                registered = register_depth(depth_m, xy_depth, valid_depth, T_colour_depth, K_out, size_out, splat_2x2)
                out.write(resize_colour(rgb, size_out), registered, i, t_colour[i])
    finally:
        reader.close()
    return out.report


__all__ = ["convert_realsense", "is_realsense_bag"]
