"""What a conversion did: frames written, frames dropped and why, timestamp gaps and the decisions taken."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from funrec.formats.capture import CaptureIntrinsics


@dataclass(frozen=True)
class DroppedFrame:
    """A source frame that was not written."""

    source_index: int
    """Index of the frame in the source's own colour stream (0-based)."""
    timestamp_s: float | None
    """Its source timestamp in seconds, if the source has timestamps."""
    reason: str
    """Why it was dropped, e.g. 'no depth within 0.020 s'."""


@dataclass(frozen=True)
class TimestampGap:
    """A step between consecutive written frames longer than ``gap_factor`` frame periods."""

    after_frame: int
    """Written frame index before the gap; the gap ends at ``after_frame + 1``."""
    duration_s: float
    """Time between the two frames, seconds."""
    missing_frames: int
    """Frames the nominal rate would have had in between (rounded)."""


@dataclass(frozen=True)
class ConversionReport:
    """Summary of one conversion; also written as ``conversion.json`` in the capture folder."""

    source: Path
    """The converted recording."""
    format: str
    """Source format name (see ConvertConfig.format)."""
    capture_dir: Path
    """The capture folder written."""
    intrinsics: CaptureIntrinsics
    """Intrinsics written to intrinsics.json."""
    source_frames: tuple[int, ...]
    """(F,) source colour-frame index of each written frame; written frame i has stem i."""
    timestamps_s: tuple[float, ...] | None
    """(F,) source timestamp of each written frame in seconds, or None if the source has none."""
    dropped: tuple[DroppedFrame, ...]
    """Source frames not written, with the reason."""
    gaps: tuple[TimestampGap, ...]
    """Timestamp gaps between written frames."""
    notes: tuple[str, ...]
    """Decisions taken on the way (intrinsics source, undistortion, resampling, ignored streams)."""
    ground_truth: bool
    """True if camera poses from the source were written to gt/ (FORMATS.md section 4)."""

    @property
    def frames_written(self) -> int:
        return len(self.source_frames)

    def summary(self) -> str:
        """One line for the command line."""
        K = self.intrinsics
        text = (
            f"{self.capture_dir}: {self.frames_written} frames {K.width}x{K.height} at {K.fps:.3g} fps "
            f"from {self.format} {self.source.name}, {len(self.dropped)} dropped, {len(self.gaps)} gap(s)"
        )
        return text + (", ground truth in gt/" if self.ground_truth else "")

    def to_json(self) -> dict[str, Any]:
        return {
            "source": str(self.source),
            "format": self.format,
            "intrinsics": self.intrinsics.to_json(),
            "frames_written": self.frames_written,
            "source_frames": list(self.source_frames),
            "timestamps_s": None if self.timestamps_s is None else [round(t, 6) for t in self.timestamps_s],
            "dropped": [
                {"source_index": d.source_index, "timestamp_s": d.timestamp_s, "reason": d.reason} for d in self.dropped
            ],
            "gaps": [
                {"after_frame": g.after_frame, "duration_s": round(g.duration_s, 6), "missing_frames": g.missing_frames}
                for g in self.gaps
            ],
            "notes": list(self.notes),
            "ground_truth": self.ground_truth,
        }


def find_gaps(timestamps_s: np.ndarray, gap_factor: float) -> tuple[tuple[TimestampGap, ...], float | None]:
    """Find steps longer than ``gap_factor`` median periods.

    Args:
        timestamps_s: (F,) increasing timestamps of the written frames, seconds.
        gap_factor: threshold in median frame periods.

    Returns:
        The gaps and the median frame period in seconds (None for fewer than two frames).
    """
    if len(timestamps_s) < 2:
        return (), None
    steps = np.diff(timestamps_s)
    period = float(np.median(steps))
    if period <= 0:
        return (), None
    gaps = tuple(
        TimestampGap(int(i), float(steps[i]), int(round(steps[i] / period)) - 1)
        for i in np.flatnonzero(steps > gap_factor * period)
    )
    return gaps, period


__all__ = ["ConversionReport", "DroppedFrame", "TimestampGap", "find_gaps"]
