"""ROS bag converter on bags written with rosbags' own ROS 1 and ROS 2 writers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from funrec.convert import ConvertConfig, convert, detect_format  # noqa: E402
from funrec.errors import CaptureError  # noqa: E402
from funrec.formats.capture import load_capture  # noqa: E402

W, H = 64, 48
K = [50.0, 0.0, 31.5, 0.0, 50.0, 23.5, 0.0, 0.0, 1.0]


def _header(types, stamp_s: float, frame_id: str, ros1: bool):
    Time = types["builtin_interfaces/msg/Time"]
    Header = types["std_msgs/msg/Header"]
    time = Time(sec=int(stamp_s), nanosec=int(round((stamp_s % 1) * 1e9)))
    return Header(seq=0, stamp=time, frame_id=frame_id) if ros1 else Header(stamp=time, frame_id=frame_id)


def _image(types, stamp_s, frame_id, encoding, array, ros1):
    Image = types["sensor_msgs/msg/Image"]
    data = np.ascontiguousarray(array)
    step = data.strides[0]
    return Image(header=_header(types, stamp_s, frame_id, ros1), height=data.shape[0], width=data.shape[1],
                 encoding=encoding, is_bigendian=0, step=step, data=data.view(np.uint8).ravel())


def _camera_info(types, frame_id, ros1, D=(0.0, 0.0, 0.0, 0.0, 0.0)):
    CameraInfo = types["sensor_msgs/msg/CameraInfo"]
    ROI = types["sensor_msgs/msg/RegionOfInterest"]
    roi = ROI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    fields = dict(header=_header(types, 0.0, frame_id, ros1), height=H, width=W, distortion_model="plumb_bob",
                  binning_x=0, binning_y=0, roi=roi)
    arrays = dict(D=np.array(D), K=np.array(K), R=np.eye(3).ravel(), P=np.array(K[:3] + [0] + K[3:6] + [0] + K[6:] + [0]))
    return CameraInfo(**fields, **({k: v for k, v in arrays.items()} if ros1 else {k.lower(): v for k, v in arrays.items()}))


def _frames(skip_depth=(), depth_encoding="16UC1"):
    """(stamp, rgb, depth) per frame k: colour grey 20 k in the red channel only, depth (1000 + k) mm, depth 5 ms later."""
    for k in range(5):
        rgb = np.zeros((H, W, 3), np.uint8)
        rgb[:, :, 0] = 20 * k
        depth_mm = np.full((H, W), 1000 + k, np.uint16)
        depth = depth_mm if depth_encoding == "16UC1" else (depth_mm / 1000).astype(np.float32)
        yield 10.0 + k / 30, rgb, (None if k in skip_depth else depth)


def write_ros1_bag(path: Path, depth_frame="camera_rgb_optical_frame", extra_colour_topic=False) -> Path:
    store = get_typestore(Stores.ROS1_NOETIC)
    types = store.types
    with Writer1(path) as writer:
        c_rgb = writer.add_connection("/camera/rgb/image_raw", "sensor_msgs/msg/Image", typestore=store)
        c_depth = writer.add_connection("/camera/depth_registered/image_raw", "sensor_msgs/msg/Image", typestore=store)
        c_info = writer.add_connection("/camera/rgb/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        c_extra = writer.add_connection("/camera/ir/image_raw", "sensor_msgs/msg/Image", typestore=store) if extra_colour_topic else None
        for stamp, rgb, depth in _frames(skip_depth=(3,)):
            t_ns = int(stamp * 1e9)
            bgr = rgb[:, :, ::-1]
            writer.write(c_info, t_ns, store.serialize_ros1(_camera_info(types, "camera_rgb_optical_frame", True), "sensor_msgs/msg/CameraInfo"))
            writer.write(c_rgb, t_ns, store.serialize_ros1(_image(types, stamp, "camera_rgb_optical_frame", "bgr8", bgr, True), "sensor_msgs/msg/Image"))
            if c_extra is not None:
                writer.write(c_extra, t_ns, store.serialize_ros1(_image(types, stamp, "ir", "mono8", rgb[:, :, 0], True), "sensor_msgs/msg/Image"))
            if depth is not None:
                msg = _image(types, stamp + 0.005, depth_frame, "16UC1", depth, True)
                writer.write(c_depth, t_ns + 5_000_000, store.serialize_ros1(msg, "sensor_msgs/msg/Image"))
    return path


def test_ros1_bag_pairs_colour_and_depth_by_stamp(tmp_path):
    bag = write_ros1_bag(tmp_path / "kitchen.bag")
    assert detect_format(bag) == "rosbag"
    report = convert(bag, tmp_path / "capture")
    capture = load_capture(tmp_path / "capture")
    assert len(capture) == 4 and report.source_frames == (0, 1, 2, 4)
    assert [d.source_index for d in report.dropped] == [3] and "no unused depth" in report.dropped[0].reason
    assert [(g.after_frame, g.missing_frames) for g in report.gaps] == [(2, 1)]
    K_capture = capture.intrinsics
    assert (K_capture.width, K_capture.height, K_capture.fx, K_capture.cx, K_capture.depth_scale) == (W, H, 50.0, 31.5, 1000.0)
    assert K_capture.fps == pytest.approx(30.0, rel=1e-3)
    assert capture.depth_m(3)[10, 20] == pytest.approx(1.004)  # written frame 3 = source frame 4, its depth
    np.testing.assert_array_equal(capture.rgb(3)[10, 20], [80, 0, 0])  # bgr8 turned into RGB
    assert any("/camera/rgb/camera_info" in n for n in report.notes)


def test_ros2_bag_with_float_depth_and_distortion(tmp_path):
    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    bag = tmp_path / "ros2_bag"
    with Writer2(bag, version=9) as writer:
        c_rgb = writer.add_connection("/cam/color/image_raw", "sensor_msgs/msg/Image", typestore=store)
        c_depth = writer.add_connection("/cam/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image", typestore=store)
        c_info = writer.add_connection("/cam/color/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        for stamp, rgb, depth in _frames(depth_encoding="32FC1"):
            t_ns = int(stamp * 1e9)
            info = _camera_info(types, "color", False, D=(0.1, 0.0, 0.0, 0.0, 0.0))
            writer.write(c_info, t_ns, store.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
            writer.write(c_rgb, t_ns, store.serialize_cdr(_image(types, stamp, "color", "rgb8", rgb, False), "sensor_msgs/msg/Image"))
            writer.write(c_depth, t_ns + 1, store.serialize_cdr(_image(types, stamp + 0.003, "color", "32FC1", depth, False), "sensor_msgs/msg/Image"))
    assert detect_format(bag) == "rosbag"
    report = convert(bag, tmp_path / "capture", ConvertConfig(format="rosbag"))
    capture = load_capture(tmp_path / "capture")
    assert len(capture) == 5 and report.dropped == ()
    assert any("undistorted ([0.1" in n for n in report.notes)
    # Barrel distortion k1 = 0.1 leaves the centre pixel in place; uniform depth stays uniform (nearest sampling).
    depth = capture.depth_m(2)
    assert depth[23, 31] == pytest.approx(1.002)
    assert set(np.unique(depth)) <= {0.0, 1.002}


def test_topic_choice_errors_name_the_option_and_the_topics(tmp_path):
    bag = write_ros1_bag(tmp_path / "two.bag", extra_colour_topic=True)
    with pytest.raises(CaptureError, match=r"two.bag: cannot choose the colour topic.*set rgb_topic \(--rgb-topic\)"):
        convert(bag, tmp_path / "capture")
    report = convert(bag, tmp_path / "capture", ConvertConfig(rgb_topic="/camera/rgb/image_raw"))
    assert report.frames_written == 4
    with pytest.raises(CaptureError, match=r"'/nope' is not a sensor_msgs Image/CompressedImage topic"):
        convert(bag, tmp_path / "capture2", ConvertConfig(rgb_topic="/nope"))


def test_unregistered_depth_is_refused(tmp_path):
    bag = write_ros1_bag(tmp_path / "raw.bag", depth_frame="camera_depth_optical_frame")
    with pytest.raises(CaptureError, match=r"raw.bag: depth topic .* is not registered to colour"):
        convert(bag, tmp_path / "capture")
