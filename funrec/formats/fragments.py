"""fragments.json: the static and dynamic fragments of a capture (docs/formats.md).

The layout is specified in docs/formats.md section 7.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from funrec.errors import FormatError
from funrec.formats.twin import read_json_object
from funrec.typed import FloatArray

FRAGMENTS_FORMAT = "funrec-fragments/2"
"""Format tag written into fragments.json (version 2 adds a dynamic fragment's ``reason``)."""
READABLE_FORMATS = ("funrec-fragments/1", FRAGMENTS_FORMAT)
"""Format tags :func:`read_fragments` accepts (version 1 has no ``reason``)."""
FRAGMENTS_FILE = "fragments.json"
"""File name of the fragment list in a twin folder."""
FRAGMENT_KINDS = ("static", "dynamic")
"""Kinds of fragments."""


@dataclass(frozen=True)
class Fragment:
    """A contiguous span of frames, static or dynamic."""

    index: int
    """Position in the fragment list."""
    kind: str
    """"static" or "dynamic"."""
    first: int
    """First frame (inclusive)."""
    last: int
    """Last frame (inclusive)."""
    part: str | None = None
    """For a dynamic fragment, the part that moved in it (None: not known or not explained)."""
    reason: str | None = None
    """For a dynamic fragment without a part, why no part was built from it (None otherwise)."""

    def __post_init__(self) -> None:
        if self.kind not in FRAGMENT_KINDS:
            raise ValueError(f"kind must be one of {FRAGMENT_KINDS}, got {self.kind!r}")
        if not 0 <= self.first <= self.last:
            raise ValueError(f"fragment {self.index}: need 0 <= first <= last, got {self.first}, {self.last}")
        if self.part is not None and self.kind != "dynamic":
            raise ValueError(f"fragment {self.index}: only a dynamic fragment names a part")
        if self.reason is not None and (self.kind != "dynamic" or self.part is not None):
            raise ValueError(f"fragment {self.index}: only a dynamic fragment without a part gives a reason")

    @property
    def frames(self) -> npt.NDArray[np.int64]:
        """(last - first + 1,) the fragment's frame indices."""
        return np.arange(self.first, self.last + 1, dtype=np.int64)


@dataclass(frozen=True)
class Fragments:
    """A capture split into consecutive fragments, and the evidence it was split on."""

    fragments: tuple[Fragment, ...]
    """Consecutive fragments covering every frame, in time order."""
    frame_count: int
    """Frames of the capture."""
    fps: float
    """Frame rate, frames per second."""
    evidence: FloatArray
    """(F,) scene-change fraction of the frame pair starting at each frame (see
    :func:`funrec.parts.scene_change.scene_change`)."""

    def __post_init__(self) -> None:
        expected = 0
        for k, f in enumerate(self.fragments):
            if f.index != k or f.first != expected:
                raise ValueError(f"fragment {k} must have index {k} and start at frame {expected}, got {f}")
            expected = f.last + 1
        if self.fragments and expected != self.frame_count:
            raise ValueError(f"fragments end at frame {expected - 1}, the capture has {self.frame_count} frames")

    @property
    def dynamic(self) -> tuple[Fragment, ...]:
        """The dynamic fragments, in time order."""
        return tuple(f for f in self.fragments if f.kind == "dynamic")


def fragments_to_json(fragments: Fragments) -> dict[str, Any]:
    """The fragments.json dictionary (see the module docstring)."""
    rows = []
    for f in fragments.fragments:
        row: dict[str, Any] = {"index": f.index, "kind": f.kind, "first": f.first, "last": f.last}
        if f.kind == "dynamic":
            row["part"] = f.part
            if f.reason is not None:
                row["reason"] = f.reason
        rows.append(row)
    return {"format": FRAGMENTS_FORMAT, "frame_count": fragments.frame_count, "fps": fragments.fps, "fragments": rows}


def write_fragments(path: str | Path, fragments: Fragments) -> None:
    """Write fragments.json (a file path, or a twin folder to write it into)."""
    path = Path(path)
    if path.is_dir():
        path = path / FRAGMENTS_FILE
    path.write_text(json.dumps(fragments_to_json(fragments), indent=1) + "\n")


def read_fragments(path: str | Path) -> Fragments:
    """Read fragments.json (a file path or a twin folder).

    Raises:
        FormatError: the file is not funrec-fragments/1 (names the file and the field).
    """
    path = Path(path)
    if path.is_dir():
        path = path / FRAGMENTS_FILE
    data = read_json_object(path)
    if data.get("format") not in READABLE_FORMATS:
        raise FormatError(path, f"format must be one of {list(READABLE_FORMATS)}, got {data.get('format')!r}")
    try:
        rows = data["fragments"]
        fragments = tuple(
            Fragment(int(r["index"]), str(r["kind"]), int(r["first"]), int(r["last"]), r.get("part"),
                     r.get("reason") if r.get("part") is None and r["kind"] == "dynamic" else None)
            for r in rows
        )
        return Fragments(fragments, int(data["frame_count"]), float(data["fps"]), np.zeros(int(data["frame_count"])))
    except (KeyError, TypeError, ValueError) as error:
        raise FormatError(path, f"bad fragment list: {error}") from error


__all__ = ["FRAGMENTS_FILE", "FRAGMENTS_FORMAT", "FRAGMENT_KINDS", "Fragment", "Fragments", "fragments_to_json", "read_fragments", "write_fragments"]
