"""FunREC: functional digital twins of rooms from egocentric RGB-D interaction videos."""

from funrec.errors import CaptureError, FormatError, FunrecError
from funrec.formats.capture import Capture, CaptureIntrinsics, CaptureWriter, load_capture
from funrec.formats.twin import ArticulatedPart, TwinArticulation, read_articulation, write_articulation

__version__ = "0.1.0"

__all__ = [
    "ArticulatedPart",
    "Capture",
    "CaptureError",
    "CaptureIntrinsics",
    "CaptureWriter",
    "FormatError",
    "FunrecError",
    "TwinArticulation",
    "load_capture",
    "read_articulation",
    "write_articulation",
]
