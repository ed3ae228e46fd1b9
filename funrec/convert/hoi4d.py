"""HOI4D sequences (``ZY*/H*/C*/N*/S*/s*/T*/``): colour ``align_rgb/image.mp4`` (or the ``00000.jpg`` frames
its ``utils/decode.py`` writes), depth registered to colour in ``align_depth/depth_video.avi`` (16-bit
millimetres; or ``00000.png`` frames), intrinsics ``camera_params/ZY*/intrin.npy``, and the annotations
(objpose, 3Dseg/output.log, action/color.json) turned into gt/ (see :mod:`funrec.convert.hoi4d_annotations`)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import zip_longest
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import trimesh

from funrec.convert.camera_model import resize_colour, resize_depth, scale_pinhole
from funrec.convert.config import ConvertConfig
from funrec.convert.hoi4d_annotations import (
    PartBoxes,
    camera_from_body,
    choose_base,
    fit_part,
    read_interactions,
    read_objpose,
    read_trajectory,
)
from funrec.convert.output import CaptureOutput
from funrec.convert.report import ConversionReport
from funrec.errors import CaptureError, FunrecError
from funrec.formats.capture import CaptureIntrinsics

HOI4D_DEPTH_SCALE = 1000.0
"""HOI4D depth holds millimetres."""
HOI4D_FPS = 15.0
"""Frame rate HOI4D's decode.py extracts at; used when action/color.json gives no duration."""
INTRINSICS_NAMES = ("intrin.npy", "intrinsics.npy", "color_intrin.npy")
"""Names of the (3, 3) colour intrinsics file, beside the sequence or in camera_params/<camera id>/."""


def is_hoi4d_sequence(path: Path) -> bool:
    """True for a folder holding align_rgb/ and align_depth/."""
    return path.is_dir() and (path / "align_rgb").is_dir() and (path / "align_depth").is_dir()


def annotation_dir(source: Path) -> Path | None:
    """Where the sequence's annotations are: the sequence itself, or the same relative path under a sibling
    ``HOI4D_annotations`` root when the videos sit under ``HOI4D_release`` (the data set's download layout)."""
    if any((source / name).exists() for name in ("objpose", "action", "3Dseg")):
        return source
    parts = source.resolve().parts
    for k, name in enumerate(parts):
        if name.startswith("HOI4D_") and name != "HOI4D_annotations":
            mirror = Path(*parts[:k], "HOI4D_annotations", *parts[k + 1 :])
            if mirror.is_dir():
                return mirror
    return None


def find_intrinsics(source: Path) -> Path:
    """The intrinsics file: beside the sequence, or ``<ancestor>/camera_params/<ZY camera id>/``."""
    for name in INTRINSICS_NAMES:
        if (source / name).is_file():
            return source / name
    camera_ids = [p for p in source.resolve().parts if p.startswith("ZY")]
    looked = [str(source / INTRINSICS_NAMES[0])]
    for ancestor in source.resolve().parents:
        for camera_id in camera_ids:
            for name in INTRINSICS_NAMES:
                candidate = ancestor / "camera_params" / camera_id / name
                if candidate.is_file():
                    return candidate
            looked.append(str(ancestor / "camera_params" / camera_id / INTRINSICS_NAMES[0]))
    raise CaptureError(source, f"no HOI4D intrinsics (intrin.npy); looked in {looked[:4]}{' ...' if len(looked) > 4 else ''}")


def _read_K(path: Path) -> np.ndarray:
    try:
        K = np.asarray(np.load(path), dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise CaptureError(path, f"not a .npy array ({exc})") from None
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CaptureError(path, f"expected a (3, 3) intrinsic matrix, got shape {K.shape}")
    return K


def _numbered(folder: Path, suffix: str) -> list[Path]:
    files = [p for p in folder.glob(f"*{suffix}") if p.stem.isdigit()]
    return sorted(files, key=lambda p: int(p.stem))


def _av() -> Any:
    try:
        import av
    except ImportError:
        raise FunrecError("reading HOI4D videos needs PyAV: pip install av (or funrec[convert])") from None
    return av


def _video_frames(path: Path, depth: bool) -> Iterator[np.ndarray | CaptureError]:
    """Decoded frames of a video: (H, W, 3) uint8 RGB, or (H, W) uint16 for the depth video."""
    av = _av()
    try:
        container = av.open(str(path))
    except av.error.FFmpegError as exc:
        raise CaptureError(path, f"not a readable video ({exc})") from None
    with container:
        for index, frame in enumerate(container.decode(video=0)):
            if not depth:
                yield frame.to_ndarray(format="rgb24")
            elif frame.format.name in ("gray16le", "gray16be"):
                yield frame.to_ndarray()
            else:
                yield CaptureError(path, f"depth frame is {frame.format.name}, expected 16-bit grey (gray16le)", index)


def _image_frames(files: list[Path], depth: bool) -> Iterator[np.ndarray | CaptureError]:
    for index, path in enumerate(files):
        if depth:
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if image is None or image.dtype != np.uint16 or image.ndim != 2:
                yield CaptureError(path, "missing, unreadable or not 16-bit single-channel depth", index)
                continue
            yield image
        else:
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            yield CaptureError(path, "unreadable colour image", index) if image is None else cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _stream(folder: Path, video: str, suffix: str, depth: bool) -> tuple[Iterator[np.ndarray | CaptureError], int | None, str]:
    """Frames of a stream (decoded image files first, else the video), their count if known, and a description."""
    files = _numbered(folder, suffix)
    if files:
        return _image_frames(files, depth), len(files), f"{len(files)} {folder.name}/*{suffix} images"
    if (folder / video).is_file():
        return _video_frames(folder / video, depth), None, f"{folder.name}/{video}"
    raise CaptureError(folder, f"neither {video} nor numbered *{suffix} frames")


def convert_hoi4d(source: str | Path, out_dir: str | Path, config: ConvertConfig = ConvertConfig()) -> ConversionReport:  # noqa: B008 (frozen, immutable default)
    """Convert one HOI4D sequence into a capture folder, with ground truth in gt/ when annotated.

    Colour and depth are already registered (same size, same camera); both are resized to
    ``config.output_width`` if set (HOI4D is 1920x1080; 640 is a good choice). Colour frame i and
    depth frame i form frame i; a frame missing or unreadable in either stream is dropped and reported.

    Raises:
        CaptureError: no intrinsics, unreadable streams or annotations, or no frame converted.
        FunrecError: PyAV is missing and the sequence holds only videos.
    """
    source = Path(source)
    if not is_hoi4d_sequence(source):
        raise CaptureError(source, "not a HOI4D sequence (needs align_rgb/ and align_depth/)")
    K_path = find_intrinsics(source)
    K = _read_K(K_path)
    colour, n_colour, colour_what = _stream(source / "align_rgb", "image.mp4", ".jpg", depth=False)
    depth, n_depth, depth_what = _stream(source / "align_depth", "depth_video.avi", ".png", depth=True)
    annotations = annotation_dir(source)
    with CaptureOutput(source, out_dir, "hoi4d", config) as out:
        out.note(f"intrinsics from {K_path}; colour {colour_what}; depth {depth_what} (millimetres, registered to colour)")
        truth = _Annotations.read(out, annotations, n_colour or n_depth or _video_length(source))
        frame_of: dict[int, int] = {}
        size = size_out = (0, 0)
        for index, (rgb, depth_mm) in enumerate(zip_longest(colour, depth)):
            if out.full:
                break
            problem = next((x for x in (rgb, depth_mm) if isinstance(x, CaptureError)), None)
            if rgb is None or depth_mm is None or problem is not None:
                reason = str(problem) if problem else ("no depth frame" if depth_mm is None else "no colour frame")
                out.drop(index, None, reason)
                continue
            if size == (0, 0):  # the first frame fixes the size and the intrinsics
                size = (rgb.shape[1], rgb.shape[0])
                K_out, size_out = scale_pinhole(K, size, config.output_width)
                out.begin(CaptureIntrinsics(size_out[0], size_out[1], K_out[0, 0], K_out[1, 1], K_out[0, 2], K_out[1, 2],
                                            depth_scale=HOI4D_DEPTH_SCALE, fps=truth.fps))
            if depth_mm.shape != rgb.shape[:2] or (rgb.shape[1], rgb.shape[0]) != size:
                out.drop(index, None, f"colour {rgb.shape[:2]} and depth {depth_mm.shape} differ from the first frame {size[::-1]}")
                continue
            depth_m = resize_depth(depth_mm / HOI4D_DEPTH_SCALE, size_out)
            frame_of[index] = out.write(resize_colour(rgb, size_out), depth_m, index, None, truth.T_world_camera.get(index))
        truth.write_parts(out, frame_of)
    return out.report


def _video_length(source: Path) -> int | None:
    """Frame count the colour video declares (None if it does not)."""
    video = source / "align_rgb" / "image.mp4"
    if not video.is_file():
        return None
    with _av().open(str(video)) as container:
        return int(container.streams.video[0].frames) or None


@dataclass
class _Annotations:
    """What the annotations say, by source frame."""

    fps: float
    T_world_camera: dict[int, np.ndarray]
    boxes: dict[str, PartBoxes]
    base: str | None
    spans: list[tuple[int, int]]

    @staticmethod
    def read(out: CaptureOutput, folder: Path | None, source_count: int | None) -> _Annotations:
        if folder is None:
            out.note("no annotations (objpose/, action/, 3Dseg/) beside the sequence or under HOI4D_annotations: no gt/")
            return _Annotations(HOI4D_FPS, {}, {}, None, [])
        fps, spans = HOI4D_FPS, []
        action = folder / "action" / "color.json"
        if action.is_file() and source_count:
            spans, duration = read_interactions(action, source_count)
            fps = source_count / duration
            out.note(f"{len(spans)} interaction event(s) in action/color.json; fps {fps:.3g} = {source_count} frames / its duration")
        boxes = read_objpose(folder / "objpose") if (folder / "objpose").is_dir() else {}
        T_world_camera: dict[int, np.ndarray] = {}
        if (folder / "3Dseg" / "output.log").is_file():
            T_world_camera = dict(enumerate(read_trajectory(folder / "3Dseg" / "output.log")))
            out.note(f"true camera poses from 3Dseg/output.log ({len(T_world_camera)} poses)")
        base = choose_base(boxes, T_world_camera) if boxes else None
        if base is not None and not T_world_camera:
            T_world_camera = camera_from_body(boxes[base])
            out.note(f"no 3Dseg/output.log: camera poses derived from the static body box '{base}' (world = its first camera)")
        if not boxes:
            out.note("no objpose annotations: no articulated parts in gt/")
        return _Annotations(fps, T_world_camera, boxes, base, spans)

    def write_parts(self, out: CaptureOutput, frame_of: dict[int, int]) -> None:
        """Fit each moving part and hand it to ``out`` for gt/gt.json; box samples go to gt/points/."""
        if self.base is None:
            return
        parts, labels = [], {}
        for label, boxes in self.boxes.items():
            if label == self.base:
                continue
            name = f"part_{len(parts)}"
            fitted = fit_part(name, self.boxes[self.base], boxes, self.T_world_camera, frame_of, self.spans)
            if fitted is None:
                out.note(f"'{label}' does not move relative to '{self.base}' (or has < 2 annotated frames): not a gt part")
                continue
            out.note(f"{name} is '{label}' ({fitted[0].part.joint_type}), fitted to its box motion relative to '{self.base}'")
            parts.append(fitted[0])
            labels[name] = label
            (out.root / "gt" / "points").mkdir(parents=True, exist_ok=True)
            trimesh.PointCloud(fitted[1]).export(out.root / "gt" / "points" / f"{name}.ply")
        out.ground_truth_parts(tuple(parts), {"hoi4d": {
            "body": self.base,
            "labels": labels,
            "handle": "not annotated in HOI4D; 'handle' holds the part box centre at the canonical state",
            "points": "gt/points/part_k.ply samples the annotated part box surface, not the true surface",
            "masks": "2Dseg colour masks are not converted (their palette-to-part mapping is per category)",
        }})
