"""ROS 1 and ROS 2 bags with sensor_msgs/Image (or CompressedImage) colour and depth registered to colour,
plus the colour sensor_msgs/CameraInfo; read with the pure-Python ``rosbags`` library."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from funrec.convert.association import associate_nearest, stream_pairs
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
from funrec.errors import CaptureError, FunrecError
from funrec.formats.capture import CaptureIntrinsics

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
_COLOUR_CODES = {"rgb8": (3, None), "bgr8": (3, cv2.COLOR_BGR2RGB), "rgba8": (4, cv2.COLOR_RGBA2RGB),
                 "bgra8": (4, cv2.COLOR_BGRA2RGB), "mono8": (1, cv2.COLOR_GRAY2RGB)}
_COMPRESSED_DEPTH_HEADER_BYTES = 12
"""compressed_depth_image_transport prefixes the PNG with its format enum and two float quantisation parameters."""


def open_bag(path: Path) -> Any:
    """An opened ``rosbags.highlevel.AnyReader`` on a ROS 1 .bag, a ROS 2 bag folder or a bare .db3/.mcap
    (ROS 2 types default to Humble where the bag carries no definitions)."""
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise FunrecError("reading ROS bags needs rosbags: pip install rosbags (or funrec[convert])") from None
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    try:
        reader.open()
    except (AnyReaderError, OSError, ValueError) as exc:
        raise CaptureError(path, f"not a readable ROS bag ({exc})") from None
    return reader


def stamp_s(message: Any) -> float:
    """Header stamp in seconds."""
    stamp = message.header.stamp
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def _rows(message: Any, channels: int, dtype: str) -> np.ndarray:
    """(H, W[, C]) view of an Image's data, honouring its row stride."""
    itemsize = np.dtype(dtype).itemsize
    data = np.frombuffer(np.asarray(message.data, dtype=np.uint8).tobytes(), dtype=np.uint8)
    if message.step < message.width * channels * itemsize or data.size < message.step * message.height:
        raise ValueError(f"{message.width}x{message.height} {message.encoding} image with step {message.step} has {data.size} bytes")
    rows = data[: message.step * message.height].reshape(message.height, message.step)[:, : message.width * channels * itemsize]
    image = np.ascontiguousarray(rows).view(dtype).reshape(message.height, message.width, channels)
    return image[:, :, 0] if channels == 1 else image


def decode_colour(message: Any, msgtype: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an Image or CompressedImage message; ValueError if it cannot be decoded."""
    if msgtype.endswith("CompressedImage"):
        image = cv2.imdecode(np.asarray(message.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"compressed colour image ({message.format}) cannot be decoded")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    encoding = message.encoding.lower()
    if encoding not in _COLOUR_CODES:
        raise ValueError(f"colour encoding {message.encoding!r}; supported: {sorted(_COLOUR_CODES)}")
    channels, code = _COLOUR_CODES[encoding]
    image = _rows(message, channels, "u1")
    return np.ascontiguousarray(image) if code is None else cv2.cvtColor(image, code)


def decode_depth_m(message: Any, msgtype: str, depth_unit_m: float = 0.001) -> np.ndarray:
    """(H, W) depth in metres (0 = no reading) of an Image (16UC1/mono16 in ``depth_unit_m``, 32FC1 in
    metres) or a compressedDepth PNG; ValueError if it cannot be decoded."""
    if msgtype.endswith("CompressedImage"):
        data = np.asarray(message.data, dtype=np.uint8)
        if "compresseddepth" in message.format.lower():
            data = data[_COMPRESSED_DEPTH_HEADER_BYTES:]
        raw = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
            raise ValueError(f"compressed depth ({message.format}) is not a 16-bit single-channel PNG")
        return raw * depth_unit_m
    encoding = message.encoding.upper()
    endian = ">" if message.is_bigendian else "<"
    if encoding in ("16UC1", "MONO16"):
        return _rows(message, 1, endian + "u2") * depth_unit_m
    if encoding == "32FC1":
        depth = _rows(message, 1, endian + "f4").astype(np.float64)
        return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    raise ValueError(f"depth encoding {message.encoding!r}; supported: 16UC1, mono16 (millimetres), 32FC1 (metres)")


def camera_from_info(message: Any) -> LensCamera:
    """The camera of a sensor_msgs/CameraInfo (ROS 1 'K'/'D' or ROS 2 'k'/'d' fields)."""
    K = np.asarray(getattr(message, "k", None) if hasattr(message, "k") else message.K, dtype=np.float64).reshape(3, 3)
    D = np.asarray(getattr(message, "d", None) if hasattr(message, "d") else message.D, dtype=np.float64).ravel()
    model = message.distortion_model
    if np.any(D != 0) and model not in ("plumb_bob", "rational_polynomial"):
        raise ValueError(f"distortion model {model!r} is not supported (plumb_bob, rational_polynomial)")
    if D.size not in (0, 4, 5, 8, 12, 14):
        D = D[:5] if D.size > 5 and not np.any(D[5:] != 0) else D
    return LensCamera(int(message.width), int(message.height), K, D if np.any(D != 0) else np.zeros(0))


@dataclass(frozen=True)
class _Topics:
    colour: Any
    depth: Any
    info: Any


def _pick_topics(path: Path, reader: Any, config: ConvertConfig) -> _Topics:
    images = {c.topic: c for c in reader.connections if c.msgtype in IMAGE_TYPES}
    infos = {c.topic: c for c in reader.connections if c.msgtype == CAMERA_INFO_TYPE}
    listing = f"image topics: {sorted(images) or 'none'}"

    def chosen(name: str | None, want_depth: bool) -> Any:
        if name is not None:
            if name not in images:
                raise CaptureError(path, f"topic {name!r} is not a sensor_msgs Image/CompressedImage topic; {listing}")
            return images[name]
        candidates = [t for t in images if ("depth" in t.lower()) == want_depth]
        if len(candidates) != 1:
            option = "depth_topic (--depth-topic)" if want_depth else "rgb_topic (--rgb-topic)"
            raise CaptureError(path, f"cannot choose the {'depth' if want_depth else 'colour'} topic among "
                               f"{candidates or 'none'}; set {option}; {listing}")
        return images[candidates[0]]

    colour, depth = chosen(config.rgb_topic, False), chosen(config.depth_topic, True)
    if config.camera_info_topic is not None:
        if config.camera_info_topic not in infos:
            raise CaptureError(path, f"{config.camera_info_topic!r} is not a CameraInfo topic; CameraInfo topics: {sorted(infos)}")
        return _Topics(colour, depth, infos[config.camera_info_topic])
    namespace = colour.topic
    while "/" in namespace.strip("/"):
        namespace = namespace.rsplit("/", 1)[0]
        if f"{namespace}/camera_info" in infos:
            return _Topics(colour, depth, infos[f"{namespace}/camera_info"])
    raise CaptureError(path, f"no CameraInfo beside {colour.topic!r}; set camera_info_topic; CameraInfo topics: {sorted(infos) or 'none'}")


def _first(reader: Any, connection: Any) -> Any:
    for _, _, raw in reader.messages(connections=[connection]):
        return reader.deserialize(raw, connection.msgtype)
    raise CaptureError(Path(str(connection.topic)), "topic has no message")


def read_stamps(path: Path, reader: Any, colour: Any, depth: Any) -> tuple[list[float], list[float]]:
    """Header stamps in seconds of every colour and depth message, in bag order (a pass without decoding images).

    Raises:
        CaptureError: the stamps of a topic do not increase.
    """
    times: dict[str, list[float]] = {colour.topic: [], depth.topic: []}
    for connection, _, raw in reader.messages(connections=[colour, depth]):
        times[connection.topic].append(stamp_s(reader.deserialize(raw, connection.msgtype)))
    for topic, stamps in times.items():
        steps = np.diff(stamps)
        if np.any(steps <= 0):
            k = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise CaptureError(path, f"{topic}: header stamps do not increase at message {k} ({stamps[k - 1]:.6f} then {stamps[k]:.6f} s)", k)
    return times[colour.topic], times[depth.topic]


def message_pairs(reader: Any, colour: Any, depth: Any, match: np.ndarray) -> Any:
    """Stream ``(colour index, (msgtype, raw colour), (msgtype, raw depth) or None)`` in colour order; see
    :func:`funrec.convert.association.stream_pairs`. Messages stay serialised until used."""
    messages = (
        (connection.topic == colour.topic, (connection.msgtype, raw))
        for connection, _, raw in reader.messages(connections=[colour, depth])
    )
    return stream_pairs(messages, match)


def convert_rosbag(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert a ROS bag into a capture folder.

    The depth topic must be registered to the colour camera (same header frame_id, e.g.
    ``depth_registered`` or ``aligned_depth_to_color``); a depth image of another size is resampled
    (nearest) to the colour size. Both are undistorted with the colour CameraInfo when it has distortion.
    Colour and depth are paired by header stamp within ``config.max_time_difference_s``.

    Raises:
        CaptureError: topics cannot be chosen, depth is not registered to colour, or no frame converted.
        FunrecError: rosbags is not installed.
    """
    source = Path(source)
    reader = open_bag(source)
    try:
        topics = _pick_topics(source, reader, config)
        try:
            camera = camera_from_info(_first(reader, topics.info))
        except ValueError as exc:
            raise CaptureError(source, f"{topics.info.topic}: {exc}") from None
        first_colour, first_depth = _first(reader, topics.colour), _first(reader, topics.depth)
        if first_depth.header.frame_id != first_colour.header.frame_id:
            raise CaptureError(
                source, f"depth topic {topics.depth.topic} (frame {first_depth.header.frame_id!r}) is not registered to "
                f"colour {topics.colour.topic} (frame {first_colour.header.frame_id!r}); record a depth topic aligned to "
                "colour (depth_registered / aligned_depth_to_color)"
            )
        t_colour, t_depth = read_stamps(source, reader, topics.colour, topics.depth)
        match = associate_nearest(t_colour, t_depth, config.max_time_difference_s)
        K_out, size_out = scale_pinhole(camera.K, camera.size, config.output_width)
        maps = camera.undistort_maps(camera.K, camera.size) if camera.has_distortion else None
        with CaptureOutput(source, out_dir, "rosbag", config) as out:
            out.begin(CaptureIntrinsics(size_out[0], size_out[1], K_out[0, 0], K_out[1, 1], K_out[0, 2], K_out[1, 2],
                                        depth_scale=1000.0, fps=30.0))
            out.note(f"topics: colour {topics.colour.topic}, depth {topics.depth.topic}, camera info {topics.info.topic}")
            if maps is not None:
                out.note(f"undistorted ({camera.distortion.tolist()}) into a pinhole image with the same K")
            unmatched = len(t_depth) - int(np.sum(match >= 0))
            if unmatched:
                out.note(f"{unmatched} of {len(t_depth)} depth images matched no colour image")
            resampled = False
            for i, (colour_type, colour_raw), depth_item in message_pairs(reader, topics.colour, topics.depth, match):
                if out.full:
                    break
                if depth_item is None:
                    out.drop(i, t_colour[i], f"no unused depth image within {config.max_time_difference_s:.3f} s")
                    continue
                try:
                    rgb = decode_colour(reader.deserialize(colour_raw, colour_type), colour_type)
                    depth_m = decode_depth_m(reader.deserialize(depth_item[1], depth_item[0]), depth_item[0])
                except ValueError as exc:
                    out.drop(i, t_colour[i], str(exc))
                    continue
                if rgb.shape[:2] != (camera.height, camera.width):
                    out.drop(i, t_colour[i], f"colour is {rgb.shape[1]}x{rgb.shape[0]}, camera info says {camera.width}x{camera.height}")
                    continue
                if depth_m.shape != (camera.height, camera.width) and not resampled:
                    resampled = True
                    out.note(f"depth {depth_m.shape[1]}x{depth_m.shape[0]} resampled (nearest) to the colour size")
                depth_m = resize_depth(depth_m, camera.size)
                if maps is not None:
                    rgb, depth_m = remap_colour(rgb, maps), remap_depth(depth_m, maps)
                out.write(resize_colour(rgb, size_out), resize_depth(depth_m, size_out), i, t_colour[i])
    finally:
        reader.close()
    return out.report


__all__ = [
    "camera_from_info",
    "convert_rosbag",
    "decode_colour",
    "decode_depth_m",
    "message_pairs",
    "open_bag",
    "read_stamps",
    "stamp_s",
]
