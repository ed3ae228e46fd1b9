"""Array type aliases used in signatures across FunREC."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
"""Float64 array; the docstring of each use gives its shape, unit and frame."""
Float32Array = npt.NDArray[np.float32]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
UInt8Array = npt.NDArray[np.uint8]
UInt16Array = npt.NDArray[np.uint16]

__all__ = ["BoolArray", "Float32Array", "FloatArray", "IntArray", "UInt8Array", "UInt16Array"]
