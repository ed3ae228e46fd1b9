"""Synthetic benchmark generator: procedural rooms with articulated furniture rendered with
MuJoCo on the CPU, written as capture folders with exact ground truth (FORMATS.md 1 and 4)."""

from funrec.synth.render import ensure_gl_backend

ensure_gl_backend()  # MuJoCo reads MUJOCO_GL once, when first imported

from funrec.synth.sequence import generate_sequence, is_complete  # noqa: E402
from funrec.synth.spec import Interaction, PartRequest, SequenceSpec  # noqa: E402
from funrec.synth.suite import bench_suite, generate_suite, smoke_suite, tiny_spec  # noqa: E402

__all__ = [
    "Interaction",
    "PartRequest",
    "SequenceSpec",
    "bench_suite",
    "generate_sequence",
    "generate_suite",
    "is_complete",
    "smoke_suite",
    "tiny_spec",
]
