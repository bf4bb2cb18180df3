"""Array conventions shared by every layer: float64 arrays that broadcast together."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def as_float_arrays(*values: ArrayLike) -> tuple[FloatArray, ...]:
    """Broadcast the arguments together as float64 arrays (the sensors' input convention)."""
    arrays = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in values))
    return tuple(np.array(a, dtype=np.float64) for a in arrays)
