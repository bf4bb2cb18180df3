"""Input checks shared by the matching modules, and NaN (no-data) windows.

* :func:`as_image`, :func:`as_points`, :func:`check_int`: an image, points or an integer
  option checked and converted for the matching functions, or
  :class:`~carto.framework.errors.InputError`.
* :func:`nan_integral`, :func:`windows_clean`: whether square windows of an image hold NaN, from
  a summed-area table of its NaN pixels (the matchers drop points whose windows touch no data).

Points are ``(N, 2)`` arrays of continuous ``(line, sample)``, the centre of the first pixel at
``(0.5, 0.5)`` (see :mod:`carto.framework.geometry.sensor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError


def as_image(image: ArrayLike, name: str) -> NDArray[np.float32]:
    """A 2-D float32 C-contiguous image (OpenCV's input), or InputError."""
    array = np.asarray(image)
    if array.ndim != 2 or min(array.shape) < 1:
        raise InputError(f"{name} image must be a non-empty 2-D array, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
        raise InputError(f"{name} image dtype {array.dtype} is not real numeric")
    return np.ascontiguousarray(array, dtype=np.float32)


def as_points(points: ArrayLike, name: str) -> NDArray[np.float64]:
    """An ``(N, 2)`` float64 array of ``(line, sample)`` (one ``(2,)`` point becomes
    ``(1, 2)``), or InputError."""
    array = np.asarray(points, dtype=np.float64)
    if array.ndim == 1 and array.size == 2:
        array = array[None]
    if array.ndim != 2 or array.shape[1] != 2:
        raise InputError(f"{name} must be an (N, 2) array of (line, sample), got {array.shape}")
    return array


def check_int(value: Any, name: str, minimum: int) -> int:
    """``value`` as an int when it is an integer (not a bool) >= ``minimum``, or InputError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def nan_integral(image: NDArray[np.float32]) -> NDArray[np.integer] | None:
    """Summed-area table of the NaN pixels, ``(rows + 1, cols + 1)`` (``None`` when there is
    none)."""
    import cv2

    nan = np.isnan(image)
    if not nan.any():
        return None
    if image.size < 2**31:  # OpenCV's 32-bit integral image holds the count
        return cv2.integral(nan.view(np.uint8))
    table = np.zeros((image.shape[0] + 1, image.shape[1] + 1), np.int64)
    table[1:, 1:] = nan.cumsum(0).cumsum(1)
    return table


def windows_clean(
    table: NDArray[np.integer] | None, r0: NDArray[np.intp], c0: NDArray[np.intp], size: int
) -> NDArray[np.bool_]:
    """True where the ``size x size`` windows at ``(r0, c0)`` hold no NaN."""
    if table is None:
        return np.ones(r0.shape, bool)
    r1, c1 = r0 + size, c0 + size
    count = table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0]
    return count == 0
