"""The capture folder a converter writes: staged in a temporary sibling folder, validated with
``load_capture`` and renamed into place only when complete (:mod:`funrec.formats.staged_folder`, as ``export.twin.TwinWriter``)."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from funrec.convert.config import ConvertConfig
from funrec.convert.report import ConversionReport, DroppedFrame, find_gaps
from funrec.errors import CaptureError, FunrecError
from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.capture import CaptureIntrinsics, CaptureWriter, load_capture
from funrec.formats.ground_truth import GroundTruthPart, write_ground_truth_json
from funrec.formats.staged_folder import discard_folder, publish_folder, stage_folder
from funrec.typed import FloatArray

log = logging.getLogger(__name__)


class CaptureOutput:
    """Context manager that collects a converted capture in a temporary folder.

    Frames are written one at a time (nothing is held); on a clean exit the report is written to
    ``conversion.json``, the folder is validated with :func:`funrec.formats.capture.load_capture` and renamed
    to ``out_dir``. On an exception, or if no frame was written, the temporary folder is deleted and
    ``out_dir`` is left as it was.

    Example::

        with CaptureOutput(source, out_dir, "tum", config) as out:
            out.begin(intrinsics)
            out.write(rgb, depth_m, source_index=0, timestamp_s=0.0)
        report = out.report
    """

    def __init__(self, source: str | Path, out_dir: str | Path, format_name: str, config: ConvertConfig) -> None:
        self.source = Path(source)
        self.out_dir = Path(out_dir)
        self.format_name = format_name
        self.config = config
        self._tmp: Path | None = None
        self._writer: CaptureWriter | None = None
        self._source_frames: list[int] = []
        self._timestamps: list[float | None] = []
        self._T_world_camera_true: list[FloatArray | None] = []
        self._dropped: list[DroppedFrame] = []
        self._notes: list[str] = []
        self._report: ConversionReport | None = None
        self._gt_parts: tuple[GroundTruthPart, ...] = ()
        self._gt_extra: dict[str, Any] = {}

    def __enter__(self) -> CaptureOutput:
        if self.out_dir.resolve() == self.source.resolve():
            raise FunrecError(f"{self.out_dir}: the output folder cannot be the source")
        self._tmp = stage_folder(self.out_dir, self.config.overwrite)
        return self

    @property
    def root(self) -> Path:
        """The temporary folder being written (inside the context only)."""
        if self._tmp is None:
            raise RuntimeError("CaptureOutput used outside its context")
        return self._tmp

    @property
    def intrinsics(self) -> CaptureIntrinsics:
        if self._writer is None:
            raise RuntimeError("CaptureOutput.begin() has not been called")
        return self._writer.intrinsics

    @property
    def frames_written(self) -> int:
        return len(self._source_frames)

    @property
    def full(self) -> bool:
        """True once ``config.max_frames`` frames are written; converters stop reading then."""
        return self.config.max_frames is not None and self.frames_written >= self.config.max_frames

    def begin(self, intrinsics: CaptureIntrinsics) -> None:
        """Fix the intrinsics (written to intrinsics.json); the depth scale of ``config`` overrides the
        source's."""
        if self.config.depth_scale is not None:
            intrinsics = dataclasses.replace(intrinsics, depth_scale=float(self.config.depth_scale))
        self._writer = CaptureWriter(self.root, intrinsics)

    def note(self, text: str) -> None:
        """Record a decision in the report (and the log)."""
        log.info("%s: %s", self.source.name, text)
        self._notes.append(text)

    def ground_truth_parts(self, parts: tuple[GroundTruthPart, ...], extra: dict[str, Any]) -> None:
        """True articulated parts (written-frame indices, world frame of the true camera poses) and extra
        fields for gt/gt.json, written if every frame has a true camera pose."""
        self._gt_parts, self._gt_extra = tuple(parts), dict(extra)

    def drop(self, source_index: int, timestamp_s: float | None, reason: str) -> None:
        """Record a source frame that is not written."""
        log.info("%s: frame %d dropped: %s", self.source.name, source_index, reason)
        self._dropped.append(DroppedFrame(int(source_index), None if timestamp_s is None else float(timestamp_s), reason))

    def write(
        self,
        rgb: npt.ArrayLike,
        depth_m: npt.ArrayLike,
        source_index: int,
        timestamp_s: float | None = None,
        T_world_camera_true: npt.ArrayLike | None = None,
    ) -> int:
        """Write the next frame.

        Args:
            rgb: (H, W, 3) uint8 RGB, the size of the intrinsics.
            depth_m: (H, W) depth in metres registered to ``rgb``, 0 = no reading.
            source_index: index of the frame in the source's colour stream.
            timestamp_s: source timestamp in seconds, if any.
            T_world_camera_true: (4, 4) ground-truth camera-to-world pose (motion capture), if any;
                written to gt/camera_poses.txt, never to the capture's own camera_poses.txt.

        Returns:
            The written frame index (its file stem).
        """
        if self._writer is None:
            raise RuntimeError("CaptureOutput.begin() must be called before write()")
        rgb, depth_m = np.asarray(rgb), np.asarray(depth_m)
        size = (self._writer.intrinsics.height, self._writer.intrinsics.width)
        if rgb.shape != (*size, 3) or depth_m.shape != size:
            raise CaptureError(
                self.source, f"converted images are rgb {rgb.shape} and depth {depth_m.shape}, expected {size}", source_index
            )
        frame = self.frames_written
        self._writer.write_frame(frame, rgb, depth_m)
        self._source_frames.append(int(source_index))
        self._timestamps.append(None if timestamp_s is None else float(timestamp_s))
        self._T_world_camera_true.append(None if T_world_camera_true is None else np.asarray(T_world_camera_true, float))
        return frame

    @property
    def report(self) -> ConversionReport:
        """The report (after a clean exit)."""
        if self._report is None:
            raise RuntimeError("the conversion has not completed")
        return self._report

    def _finish(self, tmp: Path) -> ConversionReport:
        if self._writer is None or not self._source_frames:
            reasons = sorted({d.reason for d in self._dropped})
            detail = f"; {len(self._dropped)} frame(s) dropped: {'; '.join(reasons[:3])}" if reasons else ""
            raise CaptureError(self.source, f"no frame could be converted{detail}")
        intrinsics = self._writer.intrinsics
        timestamps = None
        gaps: tuple = ()
        if all(t is not None for t in self._timestamps):
            timestamps = tuple(float(t) for t in self._timestamps)  # type: ignore[arg-type]
            if np.any(np.diff(timestamps) <= 0):
                raise CaptureError(self.source, "written frame timestamps are not strictly increasing")
            gaps, period = find_gaps(np.array(timestamps), self.config.gap_factor)
            if period is not None:
                intrinsics = dataclasses.replace(intrinsics, fps=round(1.0 / period, 3))
                self.note(f"fps {intrinsics.fps:g} from the median step of the written frames' timestamps")
        if timestamps is None or len(timestamps) < 2:
            self.note(f"fps {intrinsics.fps:g} from the source's nominal rate (fewer than two frame timestamps)")
        (tmp / "intrinsics.json").write_text(json.dumps(intrinsics.to_json(), indent=2) + "\n")
        ground_truth = self._write_ground_truth(tmp)
        report = ConversionReport(
            source=self.source,
            format=self.format_name,
            capture_dir=self.out_dir,
            intrinsics=intrinsics,
            source_frames=tuple(self._source_frames),
            timestamps_s=timestamps,
            dropped=tuple(self._dropped),
            gaps=gaps,
            notes=tuple(self._notes),
            ground_truth=ground_truth,
        )
        (tmp / "conversion.json").write_text(json.dumps(report.to_json(), indent=2) + "\n")
        load_capture(tmp)
        return report

    def _write_ground_truth(self, tmp: Path) -> bool:
        frames = [i for i, T in enumerate(self._T_world_camera_true) if T is not None]
        if not frames:
            return False
        (tmp / "gt").mkdir(exist_ok=True)
        T_world_camera = np.stack([self._T_world_camera_true[i] for i in frames])
        write_camera_poses(tmp / "gt" / "camera_poses.txt", T_world_camera, frames)
        if len(frames) == self.frames_written:
            write_ground_truth_json(
                tmp / "gt" / "gt.json", self.frames_written, self._gt_parts, np.eye(4), {"source": self.format_name, **self._gt_extra}
            )
        else:
            self.note(
                f"ground-truth poses cover {len(frames)} of {self.frames_written} frames: gt/camera_poses.txt lists "
                "those frames only and gt/gt.json is not written"
            )
        return True

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        tmp, self._tmp = self._tmp, None
        assert tmp is not None
        if exc_type is not None:
            discard_folder(tmp)
            return
        try:
            self._report = self._finish(tmp)
        except BaseException:
            discard_folder(tmp)
            raise
        publish_folder(tmp, self.out_dir)
        log.info("capture written to %s", self.out_dir)


__all__ = ["CaptureOutput"]
