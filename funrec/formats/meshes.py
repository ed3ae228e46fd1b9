"""PLY meshes and point sets of a twin or of ground truth (docs/formats.md sections 2 and 4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from funrec.errors import FormatError
from funrec.typed import FloatArray


def load_ply(path: str | Path) -> trimesh.Trimesh | FloatArray:
    """A twin or ground-truth PLY: a mesh with faces as a Trimesh, a PLY with vertices only as
    (N, 3) points.

    Raises:
        FormatError: missing or unreadable file, or no (or non-finite) vertices.
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "file is missing")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types on corrupt files
        raise FormatError(path, f"cannot read mesh ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):
        loaded = loaded.to_geometry() if hasattr(loaded, "to_geometry") else loaded.dump(concatenate=True)
    if isinstance(loaded, trimesh.Trimesh) and len(loaded.faces) > 0:
        return loaded
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    if len(vertices) == 0 or not np.all(np.isfinite(vertices)):
        raise FormatError(path, "no vertices, or non-finite vertices")
    return vertices



def as_written(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh as its PLY file holds it once written by trimesh: float32 vertices (trimesh writes
    ``property float``), the same faces. What a reader of the file gets, without the round trip."""
    return trimesh.Trimesh(mesh.vertices.astype(np.float32).astype(np.float64), mesh.faces.copy(), process=False)


__all__ = ["as_written", "load_ply"]
