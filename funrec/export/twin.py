"""The twin folder (FORMATS.md section 2), written into a temporary sibling folder and renamed
into place only when complete, so a failed run never leaves a half-written twin."""

from __future__ import annotations

import logging
from pathlib import Path
from types import TracebackType

import numpy.typing as npt

from funrec.errors import FunrecError
from funrec.formats.camera_poses import write_camera_poses
from funrec.formats.capture import write_mask
from funrec.formats.staged_folder import discard_folder, publish_folder, stage_folder
from funrec.formats.twin import TwinArticulation, write_articulation

log = logging.getLogger(__name__)


class TwinWriter:
    """Context manager that collects a twin's files in a temporary folder.

    On a clean exit the folder replaces ``out_dir`` (an existing twin there is replaced
    only with ``overwrite=True``); on an exception it is deleted and ``out_dir`` is left as
    it was.

    Example::

        with TwinWriter(out_dir) as twin:
            twin.write_mask("part_0", 12, mask)
            twin.write_articulation(articulation)
    """

    def __init__(self, out_dir: str | Path, overwrite: bool = False) -> None:
        self.out_dir = Path(out_dir)
        self.overwrite = overwrite
        self._tmp: Path | None = None

    def __enter__(self) -> TwinWriter:
        self._tmp = stage_folder(self.out_dir, self.overwrite)
        return self

    @property
    def root(self) -> Path:
        """The temporary folder being written (inside the context only)."""
        if self._tmp is None:
            raise RuntimeError("TwinWriter used outside its context")
        return self._tmp

    def write_mask(self, part_name: str, frame: int, mask: npt.ArrayLike) -> None:
        """Write ``masks/<part_name>/<frame:06d>.png`` from an (H, W) bool mask."""
        write_mask(self.root / "masks" / part_name / f"{frame:06d}.png", mask)

    def write_articulation(self, articulation: TwinArticulation) -> None:
        write_articulation(self.root / "articulation.json", articulation)

    def write_camera_poses(self, T_world_camera: npt.ArrayLike) -> None:
        """Write camera_poses.txt from (F, 4, 4) camera-to-world poses of every input frame."""
        write_camera_poses(self.root / "camera_poses.txt", T_world_camera)

    def path(self, relative: str) -> Path:
        """Absolute path of a file inside the twin being written, creating its folder."""
        path = self.root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        tmp, self._tmp = self._tmp, None
        assert tmp is not None
        if exc_type is not None:
            discard_folder(tmp)
            return
        if not (tmp / "articulation.json").is_file():
            discard_folder(tmp)
            raise FunrecError(f"{self.out_dir}: twin incomplete (no articulation.json written); nothing was changed")
        publish_folder(tmp, self.out_dir)
        log.info("twin written to %s", self.out_dir)
