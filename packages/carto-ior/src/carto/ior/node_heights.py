"""Heights of DEM nodes from every matched ortho pixel that falls in them: each valid match
is intersected on its own (:func:`carto.ior.rays.intersect_offsets`), carried to its node's
centre along the current surface, and the node takes the median of its points, with how many
there were and how far they spread.

Why a median of points rather than one intersection of the mean offset: a node of a 10 m DEM
holds ``k x k`` ortho pixels (16 at 2.5 m); where a correlation window straddles a cliff edge
or a roof, some of them match the wrong surface. The mean offset blends both surfaces into a
height that neither has; the median follows the majority, and the spread tells where the
node is uncertain (the quality layers).

The work runs by bands of node rows so that the temporary point arrays of a tile stay small.
"""

from __future__ import annotations

import attrs
import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import FloatArray
from carto.framework.sdk.dem import OrthoGrid
from carto.ior.rays import RayField, closest_point

__all__ = ["NodeHeights", "block_quantiles", "node_heights"]


BAND_PIXELS = 2_000_000
"""Ortho pixels per band of the computation (about 20 arrays of this length at once)."""

IQR_TO_SIGMA = 1.0 / 1.349
"""Scale of the interquartile range that estimates a Gaussian standard deviation."""


@attrs.frozen(eq=False)
class NodeHeights:
    """Per node of a tile window: ``height_m`` (median of the points; NaN: no point),
    ``count`` (points), ``spread_m`` (interquartile range / 1.349 of the points; NaN under
    three points), ``score`` (mean correlation score of the points)."""

    height_m: FloatArray
    count: NDArray[np.int32]
    spread_m: NDArray[np.float32]
    score: NDArray[np.float32]


def block_quantiles(
    values: FloatArray, k: int, quantiles: tuple[float, ...]
) -> tuple[NDArray[np.int32], list[FloatArray]]:
    """Counts of the finite values of each ``k x k`` block of ``values`` (rows and columns
    multiples of ``k``) and their quantiles (linear interpolation between order statistics,
    as ``numpy.nanquantile``); NaN for a block without a value. One pixel a block (``k`` 1:
    ortho-images at the DEM's posting) is the values themselves, without the sort."""
    if k == 1:
        finite = np.isfinite(values)
        return finite.astype(np.int32), [
            np.where(finite, np.asarray(values, np.float64), np.nan) for _ in quantiles
        ]
    n_r, n_c = values.shape[0] // k, values.shape[1] // k
    blocks = values.reshape(n_r, k, n_c, k).transpose(0, 2, 1, 3).reshape(n_r, n_c, k * k)
    blocks = np.sort(blocks, axis=-1)  # NaN last
    count = np.isfinite(blocks).sum(axis=-1).astype(np.int32)
    has = count > 0
    out = []
    for q in quantiles:
        rank = q * np.maximum(count - 1, 0)
        lo = np.floor(rank).astype(np.int64)
        hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
        a = np.take_along_axis(blocks, lo[..., None], axis=-1)[..., 0]
        b = np.take_along_axis(blocks, hi[..., None], axis=-1)[..., 0]
        with np.errstate(invalid="ignore"):
            out.append(np.where(has, a + (b - a) * (rank - lo), np.nan))
    return count, out


def node_heights(
    d_row_px: FloatArray,
    d_col_px: FloatArray,
    valid: NDArray[np.bool_],
    score: FloatArray,
    surface_m: FloatArray,
    grid: OrthoGrid,
    k: int,
    rays: RayField,
    h_range: tuple[float, float],
) -> NodeHeights:
    """The heights of the nodes of ``grid`` (a tile window of the DEM grid, heights
    ``surface_m``) from the offsets right minus left of the ortho grid (``k`` ortho pixels
    per node; ``valid`` matches only; ``rays`` sampled on ``grid``): see the module
    docstring. An intersection more than 500 m beyond ``h_range`` is no point."""
    n_r, n_c = grid.shape
    surface = np.ascontiguousarray(surface_m, np.float64)
    g_row, g_col = np.gradient(surface) if min(surface.shape) > 1 else (surface * 0, surface * 0)
    px, py = grid.resolution
    slope_x = np.ascontiguousarray(g_col / px)
    slope_y = np.ascontiguousarray(-g_row / py)
    height = np.full((n_r, n_c), np.nan)
    count = np.zeros((n_r, n_c), np.int32)
    spread = np.full((n_r, n_c), np.nan, np.float32)
    node_score = np.full((n_r, n_c), np.nan, np.float32)
    band = max(1, BAND_PIXELS // max(n_c * k * k, 1))
    ok_all = valid & np.isfinite(d_row_px) & np.isfinite(d_col_px)
    t = grid.transform
    frame = np.array([t.a, t.c, t.e, t.f, h_range[0] - 500.0, h_range[1] + 500.0])
    for a in range(0, n_r, band):
        b = min(n_r, a + band)
        rows = slice(a * k, b * k)
        if not ok_all[rows].any():
            continue
        # the points back on their ortho pixels: a node's points are its k x k block
        points, scores = _pixel_heights(
            np.ascontiguousarray(d_row_px[rows], np.float64),
            np.ascontiguousarray(d_col_px[rows], np.float64),
            np.ascontiguousarray(ok_all[rows]),
            np.ascontiguousarray(score[rows], np.float64),
            a * k,
            surface,
            slope_x,
            slope_y,
            np.ascontiguousarray(rays.on_nodes(slice(a, b), slice(0, n_c))),
            frame,
            k,
        )
        cnt, (q25, q50, q75) = block_quantiles(points, k, (0.25, 0.5, 0.75))
        height[a:b] = q50
        count[a:b] = cnt
        with np.errstate(invalid="ignore", divide="ignore"):
            spread[a:b] = np.where(cnt >= 3, (q75 - q25) * IQR_TO_SIGMA, np.nan)
            total = np.nansum(scores.reshape(b - a, k, n_c, k), axis=(1, 3))
            node_score[a:b] = np.where(cnt > 0, total / np.maximum(cnt, 1), np.nan)
    return NodeHeights(height, count, spread, node_score)


@numba.njit(cache=True, nogil=True, parallel=True)
def _pixel_heights(
    d_row: NDArray,
    d_col: NDArray,
    ok: NDArray,
    score: NDArray,
    row0: int,
    surface: NDArray,
    slope_x: NDArray,
    slope_y: NDArray,
    t_nodes: NDArray,
    frame: NDArray,
    k: int,
) -> tuple[NDArray, NDArray]:  # pragma: no cover - compiled
    """One band of :func:`node_heights`, ortho rows ``row0`` on (``d_row`` ... ``score``:
    the band's rows): each valid match intersected (:func:`carto.ior.rays.closest_point`,
    the rays of the node a pixel lies in, ``t_nodes``: the band's
    :meth:`~carto.ior.rays.RayField.on_nodes`), carried to its node's centre along the
    surface's slope; ``(heights, scores)`` on the band's pixels, NaN where no point or beyond
    ``frame[4:6]`` (``frame``: the grid transform's ``a, c, e, f``, then those bounds)."""
    n_rows, n_cols = d_row.shape
    a_x, c_x, e_y, f_y, low, high = frame[0], frame[1], frame[2], frame[3], frame[4], frame[5]
    heights = np.full((n_rows, n_cols), np.nan)
    scores = np.full((n_rows, n_cols), np.nan)
    node0 = row0 // k
    for i in numba.prange(n_rows):
        pr = row0 + i
        for pc in range(n_cols):
            if not ok[i, pc]:
                continue
            fr, fc = (pr + 0.5) / k - 0.5, (pc + 0.5) / k - 0.5
            mr = (pr + d_row[i, pc] + 0.5) / k - 0.5
            mc = (pc + d_col[i, pc] + 0.5) / k - 0.5
            h_pix = _bilinear_nearest(surface, fr, fc)
            h_match = _bilinear_nearest(surface, mr, mc)
            x_m, y_m = c_x + a_x * (mc + 0.5), f_y + e_y * (mr + 0.5)
            x_n, y_n = c_x + a_x * (fc + 0.5), f_y + e_y * (fr + 0.5)
            nr, nc = pr // k, pc // k
            lx, ly = t_nodes[0, 0, nr - node0, nc], t_nodes[0, 1, nr - node0, nc]
            rx, ry = t_nodes[1, 0, nr - node0, nc], t_nodes[1, 1, nr - node0, nc]
            x, y, h = closest_point(lx, ly, rx, ry, x_n, y_n, h_pix, x_m, y_m, h_match)
            x_c, y_c = c_x + a_x * (nc + 0.5), f_y + e_y * (nr + 0.5)
            h_n = h - slope_x[nr, nc] * (x - x_c) - slope_y[nr, nc] * (y - y_c)
            if h_n >= low and h_n <= high:  # False where the rays are parallel (NaN)
                heights[i, pc] = h_n
                scores[i, pc] = score[i, pc]
    return heights, scores


@numba.njit(cache=True, nogil=True, inline="always")
def _bilinear_nearest(values: NDArray, row: float, col: float) -> float:  # pragma: no cover
    """``values`` at a fractional ``(row, col)``, bilinear, the edge values beyond the edges
    (``scipy.ndimage.map_coordinates(order=1, mode="nearest")``)."""
    n_r, n_c = values.shape
    r = min(max(row, 0.0), n_r - 1.0)
    c = min(max(col, 0.0), n_c - 1.0)
    i = min(int(np.floor(r)), max(n_r - 2, 0))
    j = min(int(np.floor(c)), max(n_c - 2, 0))
    i1, j1 = min(i + 1, n_r - 1), min(j + 1, n_c - 1)
    u, v = r - i, c - j
    top = values[i, j] * (1.0 - v) + values[i, j1] * v
    bottom = values[i1, j] * (1.0 - v) + values[i1, j1] * v
    return top * (1.0 - u) + bottom * u
