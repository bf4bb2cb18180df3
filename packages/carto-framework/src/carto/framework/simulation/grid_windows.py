"""Reading a grid that is evaluated window by window (a procedural terrain or texture): the span
of its node centres and bilinear heights at any points, each group of nearby points from one
window, so that no caller needs the whole grid."""

from __future__ import annotations

from typing import Any

import numpy as np
from affine import Affine
from numpy.typing import NDArray

__all__ = ["bilinear_heights", "centre_bounds"]

FloatArray = NDArray[np.float64]
Bounds = tuple[float, float, float, float]


def centre_bounds(transform: Affine, shape: tuple[int, int]) -> Bounds:
    n_rows, n_cols = shape
    t = transform
    west, north = t.c + 0.5 * t.a, t.f + 0.5 * t.e
    return (west, north + (n_rows - 1) * t.e, west + (n_cols - 1) * t.a, north)


def bilinear_heights(terrain: Any, lon_deg: Any, lat_deg: Any) -> FloatArray:
    """Bilinear heights of a windowed terrain at WGS84 lon/lat (NaN outside the node
    centres): the points are taken in groups of nearby rows, each from one window."""
    lon, lat = np.broadcast_arrays(np.asarray(lon_deg, np.float64), np.asarray(lat_deg, np.float64))
    shape_out = lon.shape
    lon, lat = lon.ravel(), lat.ravel()
    t = terrain.transform
    n_rows, n_cols = terrain.shape
    row = (lat - t.f) / t.e - 0.5
    col = (lon - t.c) / t.a - 0.5
    out = np.full(lon.size, np.nan)
    ok = np.flatnonzero(
        np.isfinite(row)
        & np.isfinite(col)
        & (row >= 0)
        & (row <= n_rows - 1)
        & (col >= 0)
        & (col <= n_cols - 1)
    )
    if ok.size == 0:
        return out.reshape(shape_out)
    i = np.clip(np.floor(row[ok]).astype(np.intp), 0, max(n_rows - 2, 0))
    j = np.clip(np.floor(col[ok]).astype(np.intp), 0, max(n_cols - 2, 0))
    order = np.argsort(i, kind="stable")
    start = 0
    while start < order.size:
        first = i[order[start]]
        stop = int(np.searchsorted(i[order], first + 62, side="left"))
        sel = order[start:stop]
        r0, r1 = int(first), min(int(i[sel].max()) + 2, n_rows)
        c0, c1 = int(j[sel].min()), min(int(j[sel].max()) + 2, n_cols)
        h = terrain.window(r0, r1, c0, c1)
        ii, jj = i[sel] - r0, j[sel] - c0
        fr, fc = row[ok][sel] - i[sel], col[ok][sel] - j[sel]
        i1, j1 = np.minimum(ii + 1, h.shape[0] - 1), np.minimum(jj + 1, h.shape[1] - 1)
        out[ok[sel]] = (1.0 - fr) * ((1.0 - fc) * h[ii, jj] + fc * h[ii, j1]) + fr * (
            (1.0 - fc) * h[i1, jj] + fc * h[i1, j1]
        )
        start = stop
    return out.reshape(shape_out)
