"""RealSense converter: a .db3 recorded by the RealSense SDK itself (pyrealsense2 software device and
recorder), checked against the SDK's own rs.align, and the older ROS 1 .bag layout written with rosbags."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("rosbags")
from funrec.convert import convert, detect_format  # noqa: E402
from funrec.errors import CaptureError  # noqa: E402
from funrec.formats.capture import load_capture  # noqa: E402

W, H = 64, 48
FRAMES = 4
R_COLOUR_DEPTH = Rotation.from_euler("xyz", [2, 4, -3], degrees=True).as_matrix()
t_COLOUR_DEPTH = np.array([0.015, 0.002, 0.001])
DEPTH_K = (50.0, 31.5, 23.5)  # fx = fy, cx, cy at W x H
COLOUR_K = (100.0, 63.5, 47.5)  # at 2W x 2H


def _depth_mm(k: int) -> np.ndarray:
    """A wall at (1000 + k) mm with a box at 600 mm covering columns 20-39, rows 12-35."""
    depth = np.full((H, W), 1000 + k, np.uint16)
    depth[12:36, 20:40] = 600
    return depth


def _colour(k: int) -> np.ndarray:
    rgb = np.zeros((2 * H, 2 * W, 3), np.uint8)
    rgb[:, :, 0] = 30 * k
    rgb[:, :, 1] = np.arange(2 * W, dtype=np.uint8)[None, :]
    return rgb


def record_with_sdk(path: Path) -> Path:
    """Record FRAMES frames with the RealSense SDK's recorder on a software device (the SDK writes .db3)."""
    rs = pytest.importorskip("pyrealsense2")
    device = rs.software_device()
    depth_sensor, colour_sensor = device.add_sensor("Depth"), device.add_sensor("Color")

    def stream(kind, uid, size, bpp, fmt, K):
        intrinsics = rs.intrinsics()
        intrinsics.width, intrinsics.height = size
        intrinsics.fx = intrinsics.fy = K[0]
        intrinsics.ppx, intrinsics.ppy = K[1], K[2]
        intrinsics.model, intrinsics.coeffs = rs.distortion.brown_conrady, [0.0] * 5
        s = rs.video_stream()
        s.type, s.index, s.uid, s.width, s.height, s.fps, s.bpp, s.fmt = kind, 0, uid, size[0], size[1], 30, bpp, fmt
        s.intrinsics = intrinsics
        return s

    depth_profile = depth_sensor.add_video_stream(stream(rs.stream.depth, 0, (W, H), 2, rs.format.z16, DEPTH_K))
    colour_profile = colour_sensor.add_video_stream(stream(rs.stream.color, 1, (2 * W, 2 * H), 3, rs.format.rgb8, COLOUR_K))
    depth_sensor.add_read_only_option(rs.option.depth_units, 0.001)
    extrinsics = rs.extrinsics()
    extrinsics.rotation = list(R_COLOUR_DEPTH.T.ravel())  # rs2_extrinsics rotation is column-major
    extrinsics.translation = list(t_COLOUR_DEPTH)
    depth_profile.register_extrinsics_to(colour_profile, extrinsics)
    recorder = rs.recorder(str(path), device)
    queue = rs.frame_queue(10)
    depth_sensor.open(depth_profile)
    colour_sensor.open(colour_profile)
    depth_sensor.start(queue)
    colour_sensor.start(queue)
    keep = []  # the SDK reads the pixel buffers later
    for k in range(FRAMES):
        for sensor, profile, pixels, bpp in (
            (depth_sensor, depth_profile, _depth_mm(k), 2),
            (colour_sensor, colour_profile, _colour(k), 3),
        ):
            keep.append(pixels)
            frame = rs.software_video_frame()
            frame.pixels, frame.bpp, frame.stride = pixels, bpp, bpp * pixels.shape[1]
            frame.timestamp, frame.domain, frame.frame_number = k * 33.3, rs.timestamp_domain.hardware_clock, k
            frame.profile = profile.as_video_stream_profile()
            sensor.on_video_frame(frame)
        time.sleep(0.033)  # the recorder stamps messages with the recording clock
    for sensor in (depth_sensor, colour_sensor):
        sensor.stop()
        sensor.close()
    del recorder
    return path


def sdk_aligned_depth_m(path: Path) -> np.ndarray:
    """Depth of the first frameset aligned to colour by the SDK's rs.align, metres."""
    import pyrealsense2 as rs

    pipeline, config = rs.pipeline(), rs.config()
    config.enable_device_from_file(str(path), repeat_playback=False)
    profile = pipeline.start(config)
    profile.get_device().as_playback().set_real_time(False)
    try:
        frames = rs.align(rs.stream.color).process(pipeline.wait_for_frames())
        return np.asanyarray(frames.get_depth_frame().get_data()).astype(np.float64) / 1000
    finally:
        pipeline.stop()


def test_sdk_recording_matches_the_sdk_alignment(tmp_path):
    bag = record_with_sdk(tmp_path / "sdk.db3")
    assert detect_format(bag) == "realsense"
    report = convert(bag, tmp_path / "capture")
    capture = load_capture(tmp_path / "capture")
    K = capture.intrinsics
    assert len(capture) == FRAMES and report.dropped == ()
    assert (K.width, K.height, K.fx, K.cx, K.cy, K.depth_scale) == (2 * W, 2 * H, 100.0, 63.5, 47.5, 1000.0)
    ours = capture.depth_m(0)
    sdk = sdk_aligned_depth_m(bag)
    # rs.align places depth pixels in the colour image but keeps their depth-camera z; we write the
    # colour-camera z that FORMATS.md needs (the 4-degree tilt changes z by up to ~5 cm here). So the SDK
    # is the reference for where things land: the box (600 mm) and the wall (~1 m) must cover the same pixels.
    both = (ours > 0) & (sdk > 0)
    assert both.sum() > 0.95 * max((ours > 0).sum(), (sdk > 0).sum())
    box_ours, box_sdk = both & (ours < 0.8), both & (sdk < 0.8)
    iou = (box_ours & box_sdk).sum() / (box_ours | box_sdk).sum()
    assert iou > 0.9, iou
    # Values: the box centre moved by the extrinsics has the colour-camera z of the transformed point.
    p_colour = R_COLOUR_DEPTH @ (np.array([(30 - DEPTH_K[1]) / DEPTH_K[0], (24 - DEPTH_K[2]) / DEPTH_K[0], 1.0]) * 0.6) + t_COLOUR_DEPTH
    u, v = COLOUR_K[0] * p_colour[:2] / p_colour[2] + COLOUR_K[1:]
    assert ours[int(round(v)), int(round(u))] == pytest.approx(p_colour[2], abs=0.0011)
    np.testing.assert_array_equal(capture.rgb(0)[5, :, 1], np.arange(2 * W))


def write_ros1_layout(path: Path) -> Path:
    """The ROS 1 layout of RealSense SDK <= 2.55, written with rosbags."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types

    def header(stamp_s, frame_id):
        return T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=int(stamp_s), nanosec=int(stamp_s % 1 * 1e9)), frame_id=frame_id)

    def info(size, K):
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        Km = np.array([K[0], 0, K[1], 0, K[0], K[2], 0, 0, 1.0])
        return T["sensor_msgs/msg/CameraInfo"](header=header(0, ""), height=size[1], width=size[0], distortion_model="Brown Conrady",
                                                D=np.zeros(5), K=Km, R=np.eye(3).ravel(), P=np.zeros(12), binning_x=0, binning_y=0, roi=roi)

    def transform(R, t):
        q = Rotation.from_matrix(R).as_quat()
        return T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                                                rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))

    def image(stamp_s, encoding, array):
        data = np.ascontiguousarray(array)
        return T["sensor_msgs/msg/Image"](header=header(stamp_s, "0"), height=data.shape[0], width=data.shape[1], encoding=encoding,
                                          is_bigendian=0, step=data.strides[0], data=data.view(np.uint8).ravel())

    with Writer(path) as writer:
        def add(topic, msgtype):
            return writer.add_connection(topic, msgtype, typestore=store)

        topics = {
            "units": add("/device_0/sensor_0/option/Depth Units/value", "std_msgs/msg/Float32"),
            "d_info": add("/device_0/sensor_0/Depth_0/info/camera_info", "sensor_msgs/msg/CameraInfo"),
            "c_info": add("/device_0/sensor_1/Color_0/info/camera_info", "sensor_msgs/msg/CameraInfo"),
            "d_tf": add("/device_0/sensor_0/Depth_0/tf/0", "geometry_msgs/msg/Transform"),
            "c_tf": add("/device_0/sensor_1/Color_0/tf/0", "geometry_msgs/msg/Transform"),
            "depth": add("/device_0/sensor_0/Depth_0/image/data", "sensor_msgs/msg/Image"),
            "colour": add("/device_0/sensor_1/Color_0/image/data", "sensor_msgs/msg/Image"),
        }

        def write(key, t_ns, message):
            writer.write(topics[key], t_ns, store.serialize_ros1(message, topics[key].msgtype))

        write("units", 0, T["std_msgs/msg/Float32"](data=0.001))
        write("d_info", 0, info((W, H), DEPTH_K))
        write("c_info", 0, info((2 * W, 2 * H), COLOUR_K))
        write("d_tf", 0, transform(np.eye(3), np.zeros(3)))
        write("c_tf", 0, transform(R_COLOUR_DEPTH, t_COLOUR_DEPTH))
        for k in range(FRAMES):
            stamp = 1.0 + k / 30
            write("depth", int(stamp * 1e9), image(stamp, "mono16", _depth_mm(k)))
            write("colour", int(stamp * 1e9) + 1000, image(stamp + 0.002, "rgb8", _colour(k)))
    return path


def test_ros1_layout_gives_the_same_capture_as_the_sdk_recording(tmp_path):
    bag = write_ros1_layout(tmp_path / "old.bag")
    assert detect_format(bag) == "realsense"
    report = convert(bag, tmp_path / "old")
    old = load_capture(tmp_path / "old")
    assert len(old) == FRAMES and report.intrinsics.depth_scale == 1000.0
    assert report.intrinsics.fps == pytest.approx(30.0, rel=1e-3)
    record_with_sdk(tmp_path / "sdk.db3")
    convert(tmp_path / "sdk.db3", tmp_path / "new")
    new = load_capture(tmp_path / "new")
    for k in range(FRAMES):
        # The SDK's string form rounds the rotation to 1e-6, the ROS 1 quaternion does not: 1 mm steps may differ.
        np.testing.assert_allclose(old.depth_m(k), new.depth_m(k), atol=0.0021)
        np.testing.assert_array_equal(old.depth_m(k) > 0, new.depth_m(k) > 0)
        np.testing.assert_array_equal(old.rgb(k), new.rgb(k))
    # The box (600 mm) lands where the extrinsics put it: its centre pixel, moved, is box depth.
    p_depth = np.array([(30 - DEPTH_K[1]) / DEPTH_K[0], (24 - DEPTH_K[2]) / DEPTH_K[0], 1.0]) * 0.6
    p_colour = R_COLOUR_DEPTH @ p_depth + t_COLOUR_DEPTH
    u, v = COLOUR_K[0] * p_colour[:2] / p_colour[2] + COLOUR_K[1:]
    assert old.depth_m(0)[int(round(v)), int(round(u))] == pytest.approx(p_colour[2], abs=0.0011)


def test_missing_colour_intrinsics_is_an_error(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    bag = tmp_path / "noext.bag"
    with Writer(bag) as writer:
        for topic in ("/device_0/sensor_0/Depth_0/image/data", "/device_0/sensor_1/Color_0/image/data"):
            writer.add_connection(topic, "sensor_msgs/msg/Image", typestore=store)
        c = writer.add_connection("/device_0/sensor_0/Depth_0/info/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        header = store.types["std_msgs/msg/Header"](seq=0, stamp=store.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="")
        info = store.types["sensor_msgs/msg/CameraInfo"](header=header, height=H, width=W, distortion_model="Brown Conrady", D=np.zeros(5),
                                                         K=np.array([50.0, 0, 31.5, 0, 50, 23.5, 0, 0, 1]), R=np.eye(3).ravel(),
                                                         P=np.zeros(12), binning_x=0, binning_y=0, roi=roi)
        writer.write(c, 0, store.serialize_ros1(info, "sensor_msgs/msg/CameraInfo"))
    with pytest.raises(CaptureError, match=r"noext.bag: /device_0/sensor_1/Color_0: no camera_info"):
        convert(bag, tmp_path / "capture")
