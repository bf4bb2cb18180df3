"""Focal (moving-window) filters of rasters: a Gaussian (:func:`gaussian_nearest`, and at
chosen nodes only: :func:`gaussian_nearest_at`) and the median of rasters with voids
(:func:`focal_nanmedian`), compiled, by a sorting network (branch-free, vectorised): work
proportional to the pixels, memory of the output and one row's windows (a
``sliding_window_view`` with ``numpy.nanmedian`` makes a copy of ``window`` values per
pixel)."""

from __future__ import annotations

import functools

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.raster.grid_window import GridWindow

__all__ = ["focal_nanmedian", "gaussian_nearest", "gaussian_nearest_at", "sorting_network"]


@functools.lru_cache(maxsize=8)
def sorting_network(n_items: int) -> NDArray[np.intp]:
    """The compare-exchange pairs ``(i, j)``, ``i < j``, of Batcher's odd-even merge sort of
    ``n_items`` values: applied in order (the smaller value to ``i``), they sort any
    values. Built for the next power of two, without the pairs that reach beyond
    ``n_items`` (values there would be +inf: those pairs never exchange)."""
    n = 1
    while n < n_items:
        n *= 2
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    a, b = i + j, i + j + k
                    if a // (2 * p) == b // (2 * p) and b < n_items:
                        pairs.append((a, b))
            k //= 2
        p *= 2
    out = np.array(pairs, np.intp).reshape(-1, 2)
    out.flags.writeable = False  # shared by every caller (cached)
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def _nanmedian_kernel(
    values: NDArray, radius: int, pairs: NDArray, out: NDArray
) -> None:  # pragma: no cover
    # Row by row: the window's values of every column in a (side², columns) buffer, a NaN
    # made +inf and -inf in turn (so the middle of the sorted window stays the valid
    # values' middle: their upper middle when the count of voids is odd), the buffer sorted
    # by the network, a column at a time in the inner loop (branch-free, vectorised).
    n_r, n_c = values.shape
    side = 2 * radius + 1
    size = side * side
    mid = size // 2
    for r in numba.prange(n_r):
        buf = np.empty((size, n_c), np.float64)
        voids = np.zeros(n_c, np.int64)
        k = 0
        for dr in range(-radius, radius + 1):
            rr = min(max(r + dr, 0), n_r - 1)  # edge values repeated
            for dc in range(-radius, radius + 1):
                for c in range(n_c):
                    v = values[rr, min(max(c + dc, 0), n_c - 1)]
                    if v != v:  # NaN (an inf is a value)
                        v = np.inf if voids[c] % 2 == 0 else -np.inf
                        voids[c] += 1
                    buf[k, c] = v
                k += 1
        for p in range(pairs.shape[0]):
            i, j = pairs[p, 0], pairs[p, 1]
            for c in range(n_c):
                a, b = buf[i, c], buf[j, c]
                buf[i, c] = min(a, b)
                buf[j, c] = max(a, b)
        for c in range(n_c):
            if voids[c] == size:
                out[r, c] = np.nan
            elif voids[c] % 2 == 1:  # an even count of values: the mean of the middle two
                out[r, c] = 0.5 * (buf[mid - 1, c] + buf[mid, c])
            else:
                out[r, c] = buf[mid, c]


def focal_nanmedian(values: ArrayLike, radius: int = 2) -> NDArray[np.float64]:
    """The median of the non-NaN values in the ``(2 radius + 1)²`` window around each pixel
    (the edge pixels repeated beyond the raster, like ``numpy.pad(mode="edge")``); NaN where
    the window holds none. Equals ``numpy.nanmedian`` over ``sliding_window_view`` of the
    edge-padded raster.

    Raises:
        InputError: not a 2-D array, or a radius < 0."""
    array = np.ascontiguousarray(values, dtype=np.float64)
    if array.ndim != 2:
        raise InputError(f"focal median: values must be 2-D, got shape {array.shape}")
    if isinstance(radius, bool) or int(radius) != radius or radius < 0:
        raise InputError(f"focal median: radius must be an integer >= 0, got {radius!r}")
    out = np.empty_like(array)
    if array.size:
        side = 2 * int(radius) + 1
        _nanmedian_kernel(array, int(radius), sorting_network(side * side), out)
    return out


def gaussian_nearest(
    values: ArrayLike, sigma: float, dtype: type[np.floating] = np.float64
) -> NDArray[np.floating]:
    """``scipy.ndimage.gaussian_filter(values, sigma, mode="nearest")`` (truncated at 4
    sigma, the edge pixels repeated beyond the raster) by OpenCV's separable filter, which
    runs on every core: the same kernel, equal to rounding in ``dtype`` (float64, or float32
    at about three times the speed of a wide kernel and a relative precision of 1e-6)."""
    import cv2

    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise InputError(f"gaussian filter: dtype must be float32 or float64, got {dtype}")
    array = np.ascontiguousarray(values, dtype=dtype)
    if array.ndim != 2:
        raise InputError(f"gaussian filter: values must be 2-D, got shape {array.shape}")
    if not sigma > 0:
        raise InputError(f"gaussian filter: sigma must be > 0, got {sigma!r}")
    radius = int(4.0 * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / float(sigma)) ** 2)
    kernel = (kernel / kernel.sum()).astype(dtype)
    if array.size == 0:
        return array.copy()
    depth = cv2.CV_32F if dtype == np.float32 else cv2.CV_64F
    return cv2.sepFilter2D(array, depth, kernel, kernel, borderType=cv2.BORDER_REPLICATE).reshape(
        array.shape
    )


def gaussian_nearest_at(
    values: ArrayLike,
    where: NDArray[np.bool_],
    sigma: float,
    tile: int = 512,
    dtype: type[np.floating] = np.float64,
) -> NDArray[np.float64]:
    """``values`` with :func:`gaussian_nearest` (computed in ``dtype``) at the nodes
    ``where``: the filter run only on the tiles of ``tile`` nodes holding such a node, each
    with the filter's reach (4 sigma) around it, so every node sees the neighbourhood (the
    grid's edges repeated beyond it) the whole grid's filter gives it; on the whole grid when
    those cut-outs would cover more."""
    array = np.asarray(values, dtype=np.float64)
    height, width = array.shape
    reach = int(4.0 * float(sigma) + 0.5)
    cuts = [
        (t, t.grown(reach, height, width))
        for t in GridWindow(0, 0, height, width).tiles(max(1, int(tile)))
        if where[t.slices].any()
    ]
    if sum(o.n_rows * o.n_cols for _, o in cuts) >= array.size:
        return np.where(where, gaussian_nearest(array, sigma, dtype), array)
    out = array.copy()
    for inner, outer in cuts:
        blurred = gaussian_nearest(array[outer.slices], sigma, dtype)[inner.inner(outer)]
        out[inner.slices] = np.where(where[inner.slices], blurred, array[inner.slices])
    return out
