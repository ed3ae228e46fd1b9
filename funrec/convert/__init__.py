"""Converters from recording formats into FunREC capture folders (FORMATS.md section 1).

``convert(source, out_dir, config)`` picks the converter from ``config.format`` or the source itself.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from funrec.convert.config import FORMAT_NAMES, ConvertConfig
from funrec.convert.report import ConversionReport, DroppedFrame, TimestampGap
from funrec.errors import CaptureError
from funrec.formats.staged_folder import refuse_output_over_input

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv")
"""Plain video files: colour only, refused (FunREC needs depth)."""
SUPPORTED = (
    "TUM RGB-D folder (rgb.txt + depth.txt, or ground_truth.json), Azure Kinect .mkv, ROS 1 .bag / ROS 2 bag folder, "
    "RealSense .bag / .db3, Record3D .r3d, HOI4D sequence folder (align_rgb/ + align_depth/)"
)


def detect_format(source: str | Path) -> str:
    """Name of the converter for ``source`` (one of FORMAT_NAMES other than 'auto').

    Raises:
        CaptureError: a plain video (no depth), or nothing recognisable; the message lists what is supported.
    """
    source = Path(source)
    if not source.exists():
        raise CaptureError(source, "source does not exist")
    suffix = source.suffix.lower()
    if source.is_file():
        if suffix in VIDEO_SUFFIXES:
            raise CaptureError(
                source, f"a plain video has no depth and FunREC needs RGB-D; record with a depth camera. Supported: {SUPPORTED}"
            )
        if suffix == ".mkv":
            return "azure_kinect"
        if suffix == ".r3d":
            return "record3d"
        if suffix in (".bag", ".db3", ".mcap"):
            from funrec.convert.realsense import is_realsense_bag

            return "realsense" if is_realsense_bag(source) else "rosbag"
    elif source.is_dir():
        from funrec.convert.hoi4d import is_hoi4d_sequence
        from funrec.convert.tum import is_tum_folder

        if is_tum_folder(source):
            return "tum"
        if is_hoi4d_sequence(source):
            return "hoi4d"
        if (source / "metadata.yaml").is_file():
            from funrec.convert.realsense import is_realsense_bag

            return "realsense" if is_realsense_bag(source) else "rosbag"
    raise CaptureError(source, f"unrecognised recording; supported: {SUPPORTED} (or set the format explicitly)")


def _converter(name: str) -> Callable[[Path, Path, ConvertConfig], ConversionReport]:
    # Each converter module imports its optional dependency itself, so a missing one only matters when used.
    if name == "tum":
        from funrec.convert.tum import convert_tum as run
    elif name == "azure_kinect":
        from funrec.convert.azure_kinect import convert_azure_kinect as run
    elif name == "rosbag":
        from funrec.convert.rosbag import convert_rosbag as run
    elif name == "realsense":
        from funrec.convert.realsense import convert_realsense as run
    elif name == "hoi4d":
        from funrec.convert.hoi4d import convert_hoi4d as run
    else:
        from funrec.convert.record3d import convert_record3d as run
    return run


def convert(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert a recording into a capture folder.

    The folder is written to a temporary sibling, validated with ``funrec.formats.capture.load_capture`` and
    renamed to ``out_dir`` only when complete; ``out_dir/conversion.json`` holds the report.

    Args:
        source: the recording (file or folder).
        out_dir: the capture folder to write.
        config: conversion settings; ``config.format`` 'auto' detects the format.

    Returns:
        What was written, dropped and decided.

    Raises:
        CaptureError: unreadable or unsupported source, naming the file and frame.
        FunrecError: a missing optional dependency (naming the pip package) or an existing output.
    """
    source = Path(source)
    refuse_output_over_input(out_dir, source)
    name = detect_format(source) if config.format == "auto" else config.format
    if source.is_file() and source.suffix.lower() in VIDEO_SUFFIXES:
        detect_format(source)  # refuses plain videos whatever the format says
    return _converter(name)(source, Path(out_dir), config)


__all__ = [
    "FORMAT_NAMES",
    "ConversionReport",
    "ConvertConfig",
    "DroppedFrame",
    "TimestampGap",
    "convert",
    "detect_format",
]
