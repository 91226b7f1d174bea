"""The array types every module shares (one name, one meaning), importable without cost."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]  # stamps in ns, counts
IndexArray = NDArray[np.intp]  # positions into another array
ByteArray = NDArray[np.uint8]
Array = NDArray[Any]

__all__ = ["Array", "BoolArray", "ByteArray", "FloatArray", "IndexArray", "IntArray"]
