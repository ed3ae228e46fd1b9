"""Capture folders (FORMATS.md section 1): validated loading with lazy frame readers, and writing.

Raw depth is converted to metres here and nowhere else.
"""

from __future__ import annotations

import json
import math
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, fields
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
from PIL import Image, UnidentifiedImageError

from funrec.errors import CaptureError
from funrec.formats.camera_poses import read_camera_poses
from funrec.formats.intrinsics_check import intrinsics_problem
from funrec.geometry.camera import PinholeIntrinsics
from funrec.typed import BoolArray, FloatArray, UInt8Array

RGB_SUFFIXES = (".png", ".jpg", ".jpeg")
"""Colour image file types FORMATS.md allows."""
MASK_KINDS = ("hand", "object")
"""Optional mask folders under ``masks/``."""
_INTRINSICS_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "depth_scale", "fps")


@dataclass(frozen=True)
class CaptureIntrinsics(PinholeIntrinsics):
    """Intrinsics of a capture: the pinhole model of the colour camera plus depth encoding."""

    depth_scale: float = 1000.0
    """Raw depth value per metre (1000 = millimetres)."""
    fps: float = 15.0
    """Frame rate in frames per second."""

    def to_json(self) -> dict[str, float | int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def pinhole(self) -> PinholeIntrinsics:
        return PinholeIntrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy)


def read_intrinsics(path: str | Path) -> CaptureIntrinsics:
    """Read and validate ``intrinsics.json``.

    Raises:
        CaptureError: missing file, bad JSON, missing or unknown keys, non-positive
            size or focal length, non-positive depth scale or frame rate.
    """
    path = Path(path)
    if not path.is_file():
        raise CaptureError(path, "missing intrinsics file (FORMATS.md section 1 requires it)")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(path, f"not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise CaptureError(path, "expected a JSON object")
    missing = [k for k in _INTRINSICS_KEYS if k not in data]
    if missing:
        raise CaptureError(path, f"missing keys {missing}; expected {list(_INTRINSICS_KEYS)}")
    unknown = sorted(set(data) - set(_INTRINSICS_KEYS))
    if unknown:
        raise CaptureError(path, f"unknown keys {unknown}; expected {list(_INTRINSICS_KEYS)}")
    values = {}
    for key in _INTRINSICS_KEYS:
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise CaptureError(path, f"{key} must be a finite number, got {value!r}")
        values[key] = value
    for key in ("width", "height"):
        if int(values[key]) != values[key] or values[key] <= 0:
            raise CaptureError(path, f"{key} must be a positive integer, got {values[key]!r}")
        values[key] = int(values[key])
    for key in ("fx", "fy", "depth_scale", "fps"):
        if values[key] <= 0:
            raise CaptureError(path, f"{key} must be positive, got {values[key]!r}")
    intrinsics = CaptureIntrinsics(**{k: (v if k in ("width", "height") else float(v)) for k, v in values.items()})
    problem = intrinsics_problem(intrinsics)
    if problem is not None:
        raise CaptureError(path, f"implausible intrinsics: {problem}")
    return intrinsics


def _frame_files(folder: Path, suffixes: tuple[str, ...]) -> dict[int, Path]:
    """Map the integer file stem to the file for every image in ``folder``."""
    files: dict[int, Path] = {}
    for path in folder.iterdir():
        if path.suffix.lower() not in suffixes:
            continue
        try:
            number = int(path.stem)
        except ValueError:
            raise CaptureError(path, "file stem is not an integer frame number") from None
        if number in files:
            raise CaptureError(path, f"frame number {number} also used by {files[number].name}")
        files[number] = path
    return files


def _check_header(path: Path, frame: int, size: tuple[int, int], modes: tuple[str, ...], what: str) -> None:
    """Check an image's size and pixel mode from its header, without decoding it."""
    try:
        with Image.open(path) as image:
            mode, image_size = image.mode, image.size
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError) as exc:
        raise CaptureError(path, f"unreadable image ({exc})", frame) from None
    if mode not in modes:
        raise CaptureError(path, f"{what} has pixel mode {mode}, expected one of {list(modes)}", frame)
    if image_size != size:
        raise CaptureError(
            path, f"image is {image_size[0]}x{image_size[1]}, intrinsics say {size[0]}x{size[1]}", frame
        )


PREFETCH_FRAMES = 3
"""Frames decoded ahead of a stage that reads a capture in order (see :class:`_Prefetcher`)."""
_PREFETCH_MAX_STEP = 8
"""Largest frame step a sequential read may have for prefetching to follow it."""
_executor: ThreadPoolExecutor | None = None
_executor_lock = threading.Lock()


def _reset_executor() -> None:
    global _executor, _executor_lock
    _executor, _executor_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_reset_executor)


def _prefetch_executor() -> ThreadPoolExecutor:
    """One background decoding thread for the process (created on first use, and anew in a
    forked child, which does not inherit the parent's thread)."""
    global _executor
    with _executor_lock:
        if _executor is None:
            _executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="funrec-capture-prefetch")
        return _executor


class _Prefetcher:
    """Decodes the next frames of an in-order read in a background thread.

    Every stage streams the capture and decodes each PNG itself (about 10 ms per frame at
    640x480); cv2 and numpy release the GIL while decoding and converting, so the decoding of
    frames i+1.. overlaps the stage's work on frame i on a second core. Prefetching starts only
    once two consecutive reads of one kind (rgb, grey, depth, a mask) have the same step, so random
    access decodes nothing extra (not even after a fork: a child starts afresh). A decoded frame is handed out once and forgotten: at most
    PREFETCH_FRAMES frames per kind are held, whatever the capture's length.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: dict[tuple[str, int], Future] = {}
        self._last: dict[str, tuple[int, int]] = {}
        self._pid = os.getpid()

    def __reduce__(self) -> tuple[type, tuple]:
        return (_Prefetcher, ())  # a copy (pickled, e.g. for a worker process) starts empty

    def get(self, kind: str, frame: int, count: int, read: Callable[[int], object]) -> object:
        """``read(frame)``, decoded ahead of time if the reads of ``kind`` are sequential."""
        with self._lock:
            if self._pid != os.getpid():  # a forked child: the parent's decoding thread is not here
                self._pending, self._last, self._pid = {}, {}, os.getpid()
            future = self._pending.pop((kind, frame), None)
            last, last_step = self._last.get(kind, (None, 0))
            step = 0 if last is None else frame - last
            if step != 0 or last is None:  # the same frame again keeps the read pattern
                self._last[kind] = (frame, step)
                self._schedule(kind, frame, step if step == last_step else 0, count, read)
        return read(frame) if future is None else future.result()

    def _schedule(self, kind: str, frame: int, step: int, count: int, read: Callable[[int], object]) -> None:
        """Decode frames frame + step, frame + 2 step, .. of ``kind`` ahead; drop other pending ones."""
        wanted = set()
        if 0 < step <= _PREFETCH_MAX_STEP:
            wanted = {ahead for j in range(1, PREFETCH_FRAMES + 1) if (ahead := frame + j * step) < count}
        for key in [key for key in self._pending if key[0] == kind and key[1] not in wanted]:
            self._pending.pop(key).cancel()
        if wanted:
            executor = _prefetch_executor()
            for ahead in sorted(wanted):
                if (kind, ahead) not in self._pending:
                    self._pending[(kind, ahead)] = executor.submit(read, ahead)


DECODED_CACHE_BYTES = 512 * 2**20
"""Decoded colour and depth files a capture keeps (the first ones read, until this many bytes).
The stages read every depth image ~13 times and every colour image ~8 times (measured on
plain_rev_cabinet_right_00), and decoding a 640x480 PNG costs 6-7 ms of CPU: 20 of a run's 125
CPU-seconds. 512 MB holds the colour and depth of ~340 frames at 640x480; later frames of a
longer capture are decoded at each read as before."""


class _DecodedFiles:
    """Decoded colour and depth files of a capture, by path: shared with its sub-captures (a
    dataclass field that ``dataclasses.replace`` passes on), read-only, bounded by a byte budget.
    Masks are not kept: a run writes and rereads its detected hand masks under one path."""

    def __init__(self, budget_bytes: int = DECODED_CACHE_BYTES) -> None:
        self._budget = budget_bytes
        self._images: dict[Path, np.ndarray] = {}
        self._bytes = 0
        self._lock = threading.Lock()
        self._pid = os.getpid()

    def __reduce__(self) -> tuple[type, tuple]:
        return (_DecodedFiles, (self._budget,))  # a copy (pickled, e.g. for a worker process) starts empty

    def get(self, path: Path) -> np.ndarray | None:
        return self._images.get(path)

    def put(self, path: Path, image: np.ndarray) -> None:
        if self._pid != os.getpid():  # a forked child: the lock may have been held by a thread not here
            self._lock, self._pid = threading.Lock(), os.getpid()
        with self._lock:
            if path not in self._images and self._bytes + image.nbytes <= self._budget:
                image.setflags(write=False)
                self._images[path] = image
                self._bytes += image.nbytes


_DEPTH_MODES = ("I;16", "I;16B", "I;16L", "I")
_RGB_MODES = ("RGB", "RGBA", "L", "P")
_MASK_MODES = ("L", "1", "P", "RGB", "RGBA")


@dataclass(frozen=True)
class Capture:
    """A validated capture folder with lazy per-frame readers; nothing is decoded up front."""

    root: Path
    """The capture folder."""
    intrinsics: CaptureIntrinsics
    """Colour camera intrinsics and depth encoding."""
    stems: tuple[int, ...]
    """(F,) integer file stems in frame order; frame index i reads files of stems[i]."""
    rgb_paths: tuple[Path, ...]
    """(F,) colour image of each frame."""
    depth_paths: tuple[Path, ...]
    """(F,) depth image of each frame."""
    mask_paths: dict[str, tuple[Path | None, ...]]
    """Optional masks per kind ("hand", "object"): (F,) path or None where a frame has none."""
    T_world_camera_known: FloatArray | None
    """(F, 4, 4) known camera-to-world poses from the capture's camera_poses.txt, or None."""
    _prefetcher: _Prefetcher = field(default_factory=_Prefetcher, init=False, repr=False, compare=False)
    _decoded: _DecodedFiles = field(default_factory=_DecodedFiles, repr=False, compare=False)
    """Decoded colour and depth files, shared with sub-captures (an init field, so that
    ``dataclasses.replace`` passes it on)."""

    def __len__(self) -> int:
        return len(self.stems)

    @property
    def has_hand_masks(self) -> bool:
        return "hand" in self.mask_paths

    @property
    def has_object_masks(self) -> bool:
        return "object" in self.mask_paths

    def _decode_kept(self, path: Path, frame: int) -> np.ndarray:
        """:meth:`_decode`, kept in (and read from) :attr:`_decoded`: read-only, callers convert it."""
        image = self._decoded.get(path)
        if image is None:
            image = self._decode(path, frame)
            self._decoded.put(path, image)
        return image

    def _decode(self, path: Path, frame: int) -> np.ndarray:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise CaptureError(path, "cannot decode image (truncated or corrupt)", frame)
        expected = (self.intrinsics.height, self.intrinsics.width)
        if image.shape[:2] != expected:
            raise CaptureError(path, f"decoded size {image.shape[:2]} differs from intrinsics {expected}", frame)
        return image

    def rgb(self, frame: int) -> UInt8Array:
        """(H, W, 3) uint8 RGB colour image of frame ``frame``."""
        return self._prefetcher.get("rgb", frame, len(self), self._read_rgb)  # type: ignore[return-value]

    def gray(self, frame: int) -> UInt8Array:
        """(H, W) uint8 grey image of frame ``frame`` (the same as converting :meth:`rgb` with
        ``cv2.COLOR_RGB2GRAY``, made straight from the decoded image)."""
        return self._prefetcher.get("gray", frame, len(self), self._read_gray)  # type: ignore[return-value]

    def depth_m(self, frame: int) -> FloatArray:
        """(H, W) float64 depth in metres of frame ``frame``; 0 marks no reading."""
        return self._prefetcher.get("depth", frame, len(self), self._read_depth_m)  # type: ignore[return-value]

    def mask(self, kind: str, frame: int) -> BoolArray | None:
        """(H, W) bool mask of ``kind`` ("hand" or "object") at ``frame``, or None if absent."""
        paths = self.mask_paths.get(kind)
        if paths is None or paths[frame] is None:
            return None
        return self._prefetcher.get(f"mask/{kind}", frame, len(self), lambda i: self._read_mask(kind, i))  # type: ignore[return-value]

    def _read_colour(self, frame: int) -> np.ndarray:
        """The decoded 8-bit colour file of ``frame`` as cv2 reads it (grey, BGR or BGRA)."""
        path = self.rgb_paths[frame]
        image = self._decode_kept(path, frame)
        if image.dtype != np.uint8:
            raise CaptureError(path, f"colour image is {image.dtype}, expected 8-bit", frame)
        return image

    def _read_rgb(self, frame: int) -> UInt8Array:
        image = self._read_colour(frame)
        if image.ndim == 2:
            return np.repeat(image[:, :, None], 3, axis=2)
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)

    def _read_gray(self, frame: int) -> UInt8Array:
        image = self._read_colour(frame)
        if image.ndim == 2:
            return image.copy()  # the kept file stays as decoded
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY)

    def _read_depth_m(self, frame: int) -> FloatArray:
        path = self.depth_paths[frame]
        image = self._decode_kept(path, frame)
        if image.dtype != np.uint16 or image.ndim != 2:
            raise CaptureError(path, f"depth is {image.dtype} with shape {image.shape}, expected 16-bit single channel", frame)
        return image.astype(np.float64) / self.intrinsics.depth_scale

    def _read_mask(self, kind: str, frame: int) -> BoolArray | None:
        path = self.mask_paths[kind][frame]
        if path is None:
            return None
        image = self._decode(path, frame)
        return (image if image.ndim == 2 else image.max(axis=2)) > 0

    def frames(self, start: int = 0, stop: int | None = None, step: int = 1) -> Iterator[tuple[int, UInt8Array, FloatArray]]:
        """Stream ``(frame, rgb, depth_m)`` one frame at a time."""
        for frame in range(start, len(self) if stop is None else min(stop, len(self)), step):
            yield frame, self.rgb(frame), self.depth_m(frame)


def load_capture(root: str | Path, check_headers: bool = True) -> Capture:
    """Open and validate a capture folder (FORMATS.md section 1).

    Every image header is checked (size and pixel type) without decoding the pixels;
    pixels are decoded lazily by the readers of the returned :class:`Capture`, which
    raise :class:`CaptureError` naming the file and frame when a file is corrupt.

    Args:
        root: the capture folder.
        check_headers: read every image header (fast; on by default).

    Raises:
        CaptureError: anything that does not follow the contract, naming file and frame.
    """
    root = Path(root)
    if not root.is_dir():
        raise CaptureError(root, "capture folder does not exist")
    intrinsics = read_intrinsics(root / "intrinsics.json")
    for sub in ("rgb", "depth"):
        if not (root / sub).is_dir():
            raise CaptureError(root / sub, "missing folder (FORMATS.md section 1 requires rgb/ and depth/)")
    rgb = _frame_files(root / "rgb", RGB_SUFFIXES)
    depth = _frame_files(root / "depth", (".png",))
    only_rgb, only_depth = sorted(set(rgb) - set(depth)), sorted(set(depth) - set(rgb))
    if only_rgb or only_depth:
        parts = []
        if only_rgb:
            parts.append(f"rgb stems without depth: {only_rgb[:5]}{' ...' if len(only_rgb) > 5 else ''}")
        if only_depth:
            parts.append(f"depth stems without rgb: {only_depth[:5]}{' ...' if len(only_depth) > 5 else ''}")
        raise CaptureError(root, "rgb and depth stems differ: " + "; ".join(parts))
    if not rgb:
        raise CaptureError(root / "rgb", "no frames (a capture needs at least one rgb/depth pair)")
    stems = tuple(sorted(rgb))
    size = (intrinsics.width, intrinsics.height)
    mask_paths: dict[str, tuple[Path | None, ...]] = {}
    for kind in MASK_KINDS:
        folder = root / "masks" / kind
        if not folder.is_dir():
            continue
        masks = _frame_files(folder, (".png",))
        extra = sorted(set(masks) - set(stems))
        if extra:
            raise CaptureError(folder, f"mask stems without a frame: {extra[:5]}")
        mask_paths[kind] = tuple(masks.get(stem) for stem in stems)
    if check_headers:
        for frame, stem in enumerate(stems):
            _check_header(rgb[stem], frame, size, _RGB_MODES, "colour image")
            _check_header(depth[stem], frame, size, _DEPTH_MODES, "depth image (must be 16-bit)")
            for paths in mask_paths.values():
                if paths[frame] is not None:
                    _check_header(paths[frame], frame, size, _MASK_MODES, "mask")
    T_world_camera = None
    poses_path = root / "camera_poses.txt"
    if poses_path.is_file():
        poses = read_camera_poses(poses_path)
        if tuple(poses.frames) != tuple(range(len(stems))):
            raise CaptureError(poses_path, f"expected one pose per frame 0..{len(stems) - 1}, got {len(poses.frames)} lines")
        T_world_camera = poses.T_world_camera
    return Capture(
        root=root,
        intrinsics=intrinsics,
        stems=stems,
        rgb_paths=tuple(rgb[s] for s in stems),
        depth_paths=tuple(depth[s] for s in stems),
        mask_paths=mask_paths,
        T_world_camera_known=T_world_camera,
    )


class CaptureWriter:
    """Writes a capture folder frame by frame (FORMATS.md section 1); stems are zero-padded
    six-digit frame indices."""

    def __init__(self, root: str | Path, intrinsics: CaptureIntrinsics) -> None:
        self.root = Path(root)
        self.intrinsics = intrinsics
        (self.root / "rgb").mkdir(parents=True, exist_ok=True)
        (self.root / "depth").mkdir(parents=True, exist_ok=True)
        (self.root / "intrinsics.json").write_text(json.dumps(intrinsics.to_json(), indent=2) + "\n")

    def write_frame(
        self,
        frame: int,
        rgb: npt.ArrayLike,
        depth_m: npt.ArrayLike,
        hand_mask: npt.ArrayLike | None = None,
        object_mask: npt.ArrayLike | None = None,
    ) -> None:
        """Write one frame.

        Args:
            frame: frame index (file stem).
            rgb: (H, W, 3) uint8 RGB.
            depth_m: (H, W) depth in metres, 0 = no reading; quantised by depth_scale.
            hand_mask, object_mask: optional (H, W) bool masks.
        """
        stem = f"{frame:06d}.png"
        rgb = np.asarray(rgb, dtype=np.uint8)
        cv2.imwrite(str(self.root / "rgb" / stem), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        raw = np.round(np.asarray(depth_m, dtype=np.float64) * self.intrinsics.depth_scale)
        cv2.imwrite(str(self.root / "depth" / stem), np.clip(raw, 0, 65535).astype(np.uint16))
        for kind, mask in (("hand", hand_mask), ("object", object_mask)):
            if mask is not None:
                write_mask(self.root / "masks" / kind / stem, mask)


def write_mask(path: str | Path, mask: npt.ArrayLike) -> None:
    """Write a bool (H, W) mask as an 8-bit PNG (255 = inside), creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.asarray(mask, dtype=bool).astype(np.uint8) * 255)


def read_mask(path: str | Path) -> BoolArray:
    """Read an 8-bit mask PNG as (H, W) bool (>0 = inside)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise CaptureError(path, "cannot decode mask image")
    return (image if image.ndim == 2 else image.max(axis=2)) > 0


__all__ = [
    "Capture",
    "CaptureIntrinsics",
    "CaptureWriter",
    "load_capture",
    "read_intrinsics",
    "read_mask",
    "write_mask",
]
