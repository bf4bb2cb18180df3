"""Heights from matched ortho-image offsets by a local ray model: the two lines of sight of a
DEM tile as straight lines in the map CRS, their horizontal displacement per metre of height
sampled through the sensor models on a coarse lattice of nodes and interpolated between, and
each node's two rays intersected in closed form.

Why: the rigorous intersection of every node's rays
(:func:`carto.framework.geometry.intersection.intersect_sensors`: Gauss-Newton through both
sensor models) cost as much as the dense matching of the tile, for nodes whose rays differ
from their neighbours' by micro-radians. A pushbroom's line of sight turns slowly along and
across the image, so its *direction* is smooth over a tile even where its *position* is not
(attitude jitter moves where a ray lands, which the ortho-images carry, not where it points).
The lattice spacing (:data:`LATTICE_NODES`) keeps the interpolation error of the direction
below 1e-6 (tested against ``intersect_sensors``). Over the few hundred metres of height an
IOR update spans, a line of sight is straight in the map CRS to millimetres.

The geometry: a node ``p_n`` at height ``h_n`` is seen by the left ray ``X_L(h) = p_n + t_L
(h - h_n)``; the detail it shows lies ``d`` ortho pixels away in the right ortho-image, at ``p_r``
on the current surface (height ``h_r``), on the right ray ``X_R(h) = p_r + t_R (h - h_r)``
(``t``: horizontal displacement per metre of height, map units). The height where the two
rays are closest horizontally (least squares along the base ``t_L - t_R``) is

    ``h = (t_L - t_R) . (p_r - p_n + t_L h_n - t_R h_r) / |t_L - t_R|^2``

and the ground point the midpoint of ``X_L(h)`` and ``X_R(h)``.
"""

from __future__ import annotations

import attrs
import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import FloatArray
from carto.framework.sdk.dem import OrthoGrid
from carto.framework.sdk.sensors import Sensor

__all__ = ["LATTICE_NODES", "RayField", "closest_point", "intersect_offsets"]


LATTICE_NODES = 32
"""Spacing of the lattice on which ray directions are sampled through the models, nodes."""

_DH_M = 100.0
"""Height step of the sampled ray directions, metres."""


def _lattice(n: int, step: int) -> NDArray[np.int64]:
    return np.unique(np.r_[np.arange(0, n, step), n - 1])


def _extend(t_xy: FloatArray, rr: NDArray, cc: NDArray) -> FloatArray:
    """Lattice nodes a sensor cannot locate (beyond its image: a tile at the edge of the
    footprint) get the direction of a quadratic surface fitted to the located ones, so that
    the nodes of the tile that the image does see are not lost with their neighbours."""
    out = t_xy.copy()
    r = rr.ravel() / max(rr.max(), 1)
    c = cc.ravel() / max(cc.max(), 1)
    design = np.stack([np.ones_like(r), r, c, r * r, r * c, c * c], axis=1)
    for i in range(t_xy.shape[0]):
        known = np.isfinite(t_xy[i]).all(axis=0).ravel()
        if known.all() or not known.any():
            continue
        terms = design[:, : 6 if known.sum() >= 12 else 3 if known.sum() >= 3 else 1]
        for axis in range(2):
            v = t_xy[i, axis].ravel()
            coef = np.linalg.lstsq(terms[known], v[known], rcond=None)[0]
            out[i, axis].ravel()[~known] = terms[~known] @ coef
    return out


@attrs.frozen(eq=False)
class RayField:
    """The horizontal displacement per metre of height of each sensor's line of sight (map
    units per metre, ``(east, north)``) on a lattice of the nodes of ``grid``; NaN where a
    sensor cannot locate the node. :meth:`at` interpolates it bilinearly."""

    grid: OrthoGrid
    rows: NDArray[np.int64]
    cols: NDArray[np.int64]
    t_xy: FloatArray  # (n_sensors, 2, n_rows, n_cols)

    @classmethod
    def sample(
        cls,
        sensors: tuple[Sensor, ...],
        grid: OrthoGrid,
        heights: FloatArray,
        step: int = LATTICE_NODES,
    ) -> RayField:
        """Ray directions through ``sensors`` at the lattice nodes of ``grid`` on the surface
        ``heights`` (the grid's heights, finite)."""
        rows, cols = _lattice(grid.shape[0], step), _lattice(grid.shape[1], step)
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        h = np.asarray(heights, np.float64)[rr, cc]
        lon, lat = grid.lonlat(rr, cc)
        x0, y0 = grid.xy(rr, cc)
        out = np.full((len(sensors), 2, rows.size, cols.size), np.nan)
        for i, sensor in enumerate(sensors):
            line, sample = sensor.ground_to_image(lon, lat, h)
            lon_hi, lat_hi = sensor.image_to_ground(line, sample, h + _DH_M)
            x1, y1 = grid.map_xy(lon_hi, lat_hi)
            out[i, 0] = (x1 - x0) / _DH_M
            out[i, 1] = (y1 - y0) / _DH_M
        return cls(grid, rows, cols, _extend(out, rr, cc))

    def at(self, row: FloatArray, col: FloatArray) -> FloatArray:
        """``(n_sensors, 2, n)``: the directions at fractional node indices (bilinear
        between lattice nodes, clamped at the edges)."""
        r = np.clip(np.asarray(row, np.float64), self.rows[0], self.rows[-1])
        c = np.clip(np.asarray(col, np.float64), self.cols[0], self.cols[-1])
        i = np.clip(np.searchsorted(self.rows, r, side="right") - 1, 0, max(self.rows.size - 2, 0))
        j = np.clip(np.searchsorted(self.cols, c, side="right") - 1, 0, max(self.cols.size - 2, 0))
        i1 = np.minimum(i + 1, self.rows.size - 1)
        j1 = np.minimum(j + 1, self.cols.size - 1)
        span_r = np.maximum(self.rows[i1] - self.rows[i], 1)
        span_c = np.maximum(self.cols[j1] - self.cols[j], 1)
        fr = (r - self.rows[i]) / span_r
        fc = (c - self.cols[j]) / span_c
        t = self.t_xy
        return (
            t[..., i, j] * (1 - fr) * (1 - fc)
            + t[..., i, j1] * (1 - fr) * fc
            + t[..., i1, j] * fr * (1 - fc)
            + t[..., i1, j1] * fr * fc
        )

    def on_nodes(self, rows: slice, cols: slice) -> FloatArray:
        """``(n_sensors, 2, n_rows, n_cols)``: :meth:`at` every node of the block ``rows x
        cols`` of the grid, computed as two small matrix products (bilinear interpolation is
        separable on a regular grid) rather than four gathers per node."""
        wr = _interpolation_weights(self.rows, np.arange(rows.start, rows.stop))
        wc = _interpolation_weights(self.cols, np.arange(cols.start, cols.stop))
        return np.einsum("ra,...ab,cb->...rc", wr, self.t_xy, wc, optimize=True)


def _interpolation_weights(lattice: NDArray[np.int64], at: NDArray[np.int64]) -> FloatArray:
    """``(len(at), len(lattice))``: the linear interpolation weights of the lattice values at
    the indices ``at`` (clamped at the ends), as :meth:`RayField.at` weighs them."""
    x = np.clip(at.astype(np.float64), lattice[0], lattice[-1])
    i = np.clip(np.searchsorted(lattice, x, side="right") - 1, 0, max(lattice.size - 2, 0))
    i1 = np.minimum(i + 1, lattice.size - 1)
    f = (x - lattice[i]) / np.maximum(lattice[i1] - lattice[i], 1)
    w = np.zeros((x.size, lattice.size))
    n = np.arange(x.size)
    np.add.at(w, (n, i), 1.0 - f)
    np.add.at(w, (n, i1), f)
    return w


def intersect_offsets(
    rays: RayField,
    node_row: FloatArray,
    node_col: FloatArray,
    h_node_m: FloatArray,
    match_x: FloatArray,
    match_y: FloatArray,
    h_match_m: FloatArray,
    directions: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Intersect the left ray through each node (its map position at ``h_node_m``) with the
    right ray through its match (map ``match_x, match_y`` at ``h_match_m``), see the module
    docstring (:func:`closest_point`). ``directions``: the rays' directions at the points,
    ``(n_sensors, 2, n)`` (default: :meth:`RayField.at` the points). Returns ``(x, y, h)``
    of the ground points (map units, metres); NaN where a ray direction is unknown or the
    two rays are parallel."""
    t = rays.at(node_row, node_col) if directions is None else directions
    x_n, y_n = rays.grid.xy(node_row, node_col)
    arrays = np.broadcast_arrays(
        t[0][0], t[0][1], t[1][0], t[1][1], x_n, y_n, h_node_m, match_x, match_y, h_match_m
    )
    flat = [np.ascontiguousarray(a, np.float64).ravel() for a in arrays]
    x, y, h = _closest_points(*flat)
    shape = arrays[0].shape
    return x.reshape(shape), y.reshape(shape), h.reshape(shape)


@numba.njit(cache=True, nogil=True, inline="always")
def closest_point(
    lx: float,
    ly: float,
    rx: float,
    ry: float,
    x_n: float,
    y_n: float,
    h_n: float,
    x_m: float,
    y_m: float,
    h_m: float,
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """The module docstring's intersection of one node's rays: the left ray through the
    node ``(x_n, y_n)`` at ``h_n`` (direction ``(lx, ly)`` per metre), the right one through
    its match ``(x_m, y_m)`` at ``h_m`` (``(rx, ry)``): ``(x, y, h)`` of the ground point,
    NaN where the rays are parallel."""
    bx, by = lx - rx, ly - ry
    norm2 = bx**2 + by**2
    if not norm2 > 1e-12:
        return np.nan, np.nan, np.nan
    rhs_x = x_m - x_n + lx * h_n - rx * h_m
    rhs_y = y_m - y_n + ly * h_n - ry * h_m
    h = (bx * rhs_x + by * rhs_y) / norm2
    x = 0.5 * (x_n + lx * (h - h_n) + x_m + rx * (h - h_m))
    y = 0.5 * (y_n + ly * (h - h_n) + y_m + ry * (h - h_m))
    return x, y, h


@numba.njit(cache=True, nogil=True)
def _closest_points(
    lx: NDArray,
    ly: NDArray,
    rx: NDArray,
    ry: NDArray,
    x_n: NDArray,
    y_n: NDArray,
    h_n: NDArray,
    x_m: NDArray,
    y_m: NDArray,
    h_m: NDArray,
) -> tuple[NDArray, NDArray, NDArray]:  # pragma: no cover - compiled
    """:func:`closest_point` of every point (flat arrays)."""  # fmt: skip
    n = lx.size
    x, y, h = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        x[i], y[i], h[i] = closest_point(
            lx[i], ly[i], rx[i], ry[i], x_n[i], y_n[i], h_n[i], x_m[i], y_m[i], h_m[i]
        )
    return x, y, h
