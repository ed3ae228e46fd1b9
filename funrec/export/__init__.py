"""Writers of the twin folder (FORMATS.md section 2) and its simulator exports."""

from funrec.export.twin import TwinWriter

__all__ = ["TwinWriter"]
