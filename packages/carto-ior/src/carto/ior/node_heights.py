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
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from carto.framework.sdk.common import FloatArray
from carto.framework.sdk.dem import OrthoGrid
from carto.ior.rays import RayField, intersect_offsets

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
    per node; ``valid`` matches only): see the module docstring. An intersection more than
    500 m beyond ``h_range`` is no point."""
    n_r, n_c = grid.shape
    surface = np.asarray(surface_m, np.float64)
    g_row, g_col = np.gradient(surface) if min(surface.shape) > 1 else (surface * 0, surface * 0)
    px, py = grid.resolution
    slope_x, slope_y = g_col / px, -g_row / py
    height = np.full((n_r, n_c), np.nan)
    count = np.zeros((n_r, n_c), np.int32)
    spread = np.full((n_r, n_c), np.nan, np.float32)
    node_score = np.full((n_r, n_c), np.nan, np.float32)
    band = max(1, BAND_PIXELS // max(n_c * k * k, 1))
    ok_all = valid & np.isfinite(d_row_px) & np.isfinite(d_col_px)
    for a in range(0, n_r, band):
        b = min(n_r, a + band)
        ok = ok_all[a * k : b * k]
        pr, pc = np.nonzero(ok)
        if pr.size == 0:
            continue
        pr = pr + a * k
        dr = np.asarray(d_row_px, np.float64)[pr, pc]
        dc = np.asarray(d_col_px, np.float64)[pr, pc]
        # the pixel as a fractional node index, and its match
        fr, fc = (pr + 0.5) / k - 0.5, (pc + 0.5) / k - 0.5
        mr, mc = (pr + dr + 0.5) / k - 0.5, (pc + dc + 0.5) / k - 0.5
        h_pix = ndimage.map_coordinates(surface, [fr, fc], order=1, mode="nearest")
        h_match = ndimage.map_coordinates(surface, [mr, mc], order=1, mode="nearest")
        x_m, y_m = grid.xy(mr, mc)
        # the rays' directions of the node a pixel lies in (they turn by micro-radians
        # across a node)
        nr, nc = pr // k, pc // k
        at_nodes = rays.on_nodes(slice(a, b), slice(0, n_c))
        directions = at_nodes[:, :, nr - a, nc]
        x_p, y_p, h_p = intersect_offsets(
            rays, fr, fc, h_pix, x_m, y_m, h_match, directions=directions
        )
        # to the centre of the node the pixel lies in, along the current surface
        x_n, y_n = grid.xy(nr, nc)
        h_n = h_p - slope_x[nr, nc] * (x_p - x_n) - slope_y[nr, nc] * (y_p - y_n)
        keep = (h_n >= h_range[0] - 500.0) & (h_n <= h_range[1] + 500.0)
        # the points back on their ortho pixels: a node's points are its k x k block
        points = np.full(((b - a) * k, n_c * k), np.nan)
        points[pr[keep] - a * k, pc[keep]] = h_n[keep]
        cnt, (q25, q50, q75) = block_quantiles(points, k, (0.25, 0.5, 0.75))
        scores = np.full(points.shape, np.nan)
        scores[pr[keep] - a * k, pc[keep]] = np.asarray(score, np.float64)[pr, pc][keep]
        height[a:b] = q50
        count[a:b] = cnt
        with np.errstate(invalid="ignore", divide="ignore"):
            spread[a:b] = np.where(cnt >= 3, (q75 - q25) * IQR_TO_SIGMA, np.nan)
            total = np.nansum(scores.reshape(b - a, k, n_c, k), axis=(1, 3))
            node_score[a:b] = np.where(cnt > 0, total / np.maximum(cnt, 1), np.nan)
    return NodeHeights(height, count, spread, node_score)
