"""Array types shared by every module (one definition each)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: Float64 array: coordinates in mm, angles in radians, weights.
FloatArray = NDArray[np.float64]
#: Int64 array: tile, hinge, gap or vertex ids.
IntArray = NDArray[np.int64]
#: Boolean mask.
BoolArray = NDArray[np.bool_]
