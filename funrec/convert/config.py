"""Settings of ``funrec convert``: one frozen dataclass shared by every source format."""

from __future__ import annotations

from dataclasses import dataclass

from funrec.errors import FunrecError

FORMAT_NAMES = ("auto", "tum", "azure_kinect", "rosbag", "realsense", "record3d", "hoi4d")
"""Values of :attr:`ConvertConfig.format`."""


@dataclass(frozen=True)
class ConvertConfig:
    """How a recording is turned into a capture folder (FORMATS.md section 1)."""

    format: str = "auto"
    """Source format: auto (from the file suffix and folder contents), tum, azure_kinect, rosbag, realsense,
    record3d or hoi4d."""
    overwrite: bool = False
    """Replace an existing, non-empty output folder."""
    max_time_difference_s: float = 0.02
    """Largest colour-depth timestamp difference, seconds, for the two to form one frame (TUM's associate.py
    default; colour and depth of unsynchronised sensors are up to half a frame, 17 ms at 30 fps, apart)."""
    gap_factor: float = 1.5
    """A step between consecutive written frames longer than this many median frame periods is reported as a
    timestamp gap (1.5: at least one frame is missing)."""
    output_width: int | None = None
    """Width in pixels of the written images; None keeps the colour camera's width. Height and intrinsics scale
    with it (e.g. 640 turns Azure Kinect 1280x720 into 640x360)."""
    depth_scale: float | None = None
    """Raw depth value per metre in the written depth PNGs; None keeps the source's unit (TUM 5000, millimetre
    sensors 1000; float depth is written in millimetres)."""
    max_frames: int | None = None
    """Stop after writing this many frames (None: all)."""
    tum_camera: str = "auto"
    """TUM intrinsics: fr1, fr2, fr3 (official calibrations), ros (525/525/319.5/239.5, undistorted) or auto
    (from 'freiburgN'/'frN' in the folder name)."""
    record3d_min_confidence: int = 1
    """Record3D: keep LiDAR depth whose ARKit confidence (0 low, 1 medium, 2 high) is at least this; 0 keeps
    all. Low-confidence depth sits on edges and far surfaces and is often metres off."""
    rgb_topic: str | None = None
    """ROS bag topic of the colour images (sensor_msgs/Image or CompressedImage); None picks the only one."""
    depth_topic: str | None = None
    """ROS bag topic of the depth images (16UC1 millimetres or 32FC1 metres); None picks the only one."""
    camera_info_topic: str | None = None
    """ROS bag sensor_msgs/CameraInfo topic of the colour camera; None uses '<rgb topic's namespace>/camera_info'
    or the only one."""

    def __post_init__(self) -> None:
        if self.format not in FORMAT_NAMES:
            raise FunrecError(f"ConvertConfig.format: unknown format {self.format!r}; valid: {list(FORMAT_NAMES)}")
        if self.tum_camera not in ("auto", "fr1", "fr2", "fr3", "ros"):
            raise FunrecError(f"ConvertConfig.tum_camera: {self.tum_camera!r}; valid: auto, fr1, fr2, fr3, ros")
        for name in ("max_time_difference_s", "gap_factor"):
            if not getattr(self, name) > 0:
                raise FunrecError(f"ConvertConfig.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("output_width", "max_frames"):
            value = getattr(self, name)
            if value is not None and value <= 0:
                raise FunrecError(f"ConvertConfig.{name} must be a positive integer or None, got {value!r}")
        if self.record3d_min_confidence not in (0, 1, 2):
            raise FunrecError(f"ConvertConfig.record3d_min_confidence must be 0, 1 or 2, got {self.record3d_min_confidence!r}")
        if self.depth_scale is not None and not self.depth_scale > 0:
            raise FunrecError(f"ConvertConfig.depth_scale must be positive or None, got {self.depth_scale!r}")


__all__ = ["FORMAT_NAMES", "ConvertConfig"]
