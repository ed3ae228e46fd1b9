"""gravity.json of a twin folder (funrec-gravity/1, optional; docs/formats.md section 11): where the twin's
up and floor came from, so that a robot planned in it knows whether it stands on a floor the capture showed
or on a guess."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from funrec.errors import FormatError

TWIN_GRAVITY_FILE = "gravity.json"
"""Name of the file inside the twin folder."""
TWIN_GRAVITY_FORMAT = "funrec-gravity/1"
"""Format tag written into gravity.json."""
FLOOR_SEEN_SOURCES = ("floor_plane",)
"""Sources whose floor was seen; with the others the floor's height is assumed."""
SOURCES = ("floor_plane", "worktop_plane", "ceiling_plane", "camera_axes")
"""Where up and the floor can come from (``funrec.surfaces.gravity.GravityAlignment.source``)."""


@dataclass(frozen=True)
class TwinGravity:
    """What gravity.json says."""

    source: str
    """One of ``SOURCES``: the plane (or the cameras) that gave up."""
    floor: str
    """How the floor's height was found, in words (seen, or what it was assumed from)."""

    @property
    def floor_seen(self) -> bool:
        return self.source in FLOOR_SEEN_SOURCES


def write_twin_gravity(path: str | Path, gravity: TwinGravity) -> None:
    """Write gravity.json."""
    if gravity.source not in SOURCES:
        raise ValueError(f"gravity source must be one of {SOURCES}, got {gravity.source!r}")
    record = {"format": TWIN_GRAVITY_FORMAT, "source": gravity.source, "floor_seen": gravity.floor_seen,
              "floor": gravity.floor}
    Path(path).write_text(json.dumps(record, indent=2) + "\n")


def read_twin_gravity(twin_dir: str | Path) -> TwinGravity | None:
    """gravity.json of a twin folder, or None when the twin has none (made before the file existed).

    Raises:
        FormatError: the file is there but malformed.
    """
    path = Path(twin_dir) / TWIN_GRAVITY_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
        if record.get("format") != TWIN_GRAVITY_FORMAT or record.get("source") not in SOURCES:
            raise FormatError(path, f"expected format {TWIN_GRAVITY_FORMAT!r} with a source of {SOURCES}")
        return TwinGravity(str(record["source"]), str(record["floor"]))
    except (ValueError, KeyError, TypeError) as exc:
        raise FormatError(path, f"cannot read gravity.json: {exc}") from None


__all__ = ["FLOOR_SEEN_SOURCES", "SOURCES", "TWIN_GRAVITY_FILE", "TWIN_GRAVITY_FORMAT", "TwinGravity",
           "read_twin_gravity", "write_twin_gravity"]
