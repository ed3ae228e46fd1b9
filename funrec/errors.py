"""Exceptions raised by FunREC; every message says what is wrong and where."""

from __future__ import annotations

from pathlib import Path


class FunrecError(Exception):
    """Root of all errors that FunREC raises on bad input or impossible requests."""


class CaptureError(FunrecError):
    """A capture folder (FORMATS.md section 1) is missing something or holds a bad file.

    The message names the file and, where there is one, the frame index:
    ``capture/depth/000137.png (frame 137): 8-bit image, expected 16-bit depth``.
    """

    def __init__(self, path: str | Path, problem: str, frame: int | None = None) -> None:
        self.path = Path(path)
        self.frame = frame
        self.problem = problem
        where = f"{self.path}" if frame is None else f"{self.path} (frame {frame})"
        super().__init__(f"{where}: {problem}")


class FormatError(FunrecError):
    """A twin or ground-truth file does not follow FORMATS.md; names the file and field."""

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class ReconstructionError(FunrecError):
    """A capture is valid but cannot be reconstructed (no texture, no depth, ...)."""


class ExportError(FunrecError):
    """A twin cannot be exported to a simulator format."""


class PlanningError(FunrecError):
    """A robot plan cannot be made or checked."""


__all__ = [
    "CaptureError",
    "ExportError",
    "FormatError",
    "FunrecError",
    "PlanningError",
    "ReconstructionError",
]
