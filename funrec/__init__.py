"""FunREC: functional digital twins of rooms from egocentric RGB-D interaction videos.

``funrec.reconstruct("capture", "twin")`` runs the whole reconstruction. Names are imported on
first use, so reading a twin (:mod:`funrec.formats`) never loads the reconstruction's OpenCV,
Open3D or scikit-learn.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from funrec.errors import CaptureError, FormatError, FunrecError, ReconstructionError
    from funrec.formats.affordances import Affordances, PartAffordance, read_affordances
    from funrec.formats.capture import Capture, CaptureIntrinsics, CaptureWriter, load_capture
    from funrec.formats.fragments import Fragments, read_fragments
    from funrec.formats.twin import ArticulatedPart, TwinArticulation, read_articulation, write_articulation
    from funrec.pipeline import ReconstructConfig, ReconstructionSummary, reconstruct

from funrec.version import SOURCE_VERSION as __version__  # noqa: E402, F401 (re-exported; version.py needs only the standard library)

_MODULE_OF = {
    "CaptureError": "errors",
    "FormatError": "errors",
    "FunrecError": "errors",
    "ReconstructionError": "errors",
    "Affordances": "formats.affordances",
    "PartAffordance": "formats.affordances",
    "read_affordances": "formats.affordances",
    "Capture": "formats.capture",
    "CaptureIntrinsics": "formats.capture",
    "CaptureWriter": "formats.capture",
    "load_capture": "formats.capture",
    "Fragments": "formats.fragments",
    "read_fragments": "formats.fragments",
    "ArticulatedPart": "formats.twin",
    "TwinArticulation": "formats.twin",
    "read_articulation": "formats.twin",
    "write_articulation": "formats.twin",
    "ReconstructConfig": "pipeline",
    "ReconstructionSummary": "pipeline",
    "reconstruct": "pipeline",
}


def __getattr__(name: str) -> Any:
    if name not in _MODULE_OF:
        raise AttributeError(f"module 'funrec' has no attribute {name!r}")
    return getattr(importlib.import_module(f"funrec.{_MODULE_OF[name]}"), name)


__all__ = [
    "Affordances",
    "ArticulatedPart",
    "Capture",
    "CaptureError",
    "CaptureIntrinsics",
    "CaptureWriter",
    "FormatError",
    "Fragments",
    "FunrecError",
    "PartAffordance",
    "ReconstructConfig",
    "ReconstructionError",
    "ReconstructionSummary",
    "TwinArticulation",
    "load_capture",
    "read_affordances",
    "read_articulation",
    "read_fragments",
    "reconstruct",
    "write_articulation",
]
