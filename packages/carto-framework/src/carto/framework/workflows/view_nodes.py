"""Where a multi-view run's views see the nodes of its pairs' DEMs: each node's imaging time in
every view and the view's along-track displacement per metre of height
(:func:`locate_in_view`), and the nodes the views' along-track fit uses, sampled from the
pairs' DEM folders tile by tile (:func:`sample_nodes`; see
:mod:`carto.framework.workflows.view_jitter`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.attitude_terms import line_scanner_of
from carto.framework.adjustment.view_jitter import NodeSamples
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho_grid import lonlat_transformer
from carto.framework.merging.fused_files import DEFAULT_SIGMA_M, PairLayers, pair_layers
from carto.framework.merging.grid import GridWindow, MosaicGrid, read_window, union_grid

FloatArray = NDArray[np.float64]

__all__ = ["MAX_DESIGN_VALUES", "locate_in_view", "sample_nodes"]

MAX_DESIGN_VALUES = 6_000_000
"""The fit's design (pairs x nodes x coefficients) holds at most this many values (48 MB):
the nodes are sampled to fit (every grid row while it can, columns strided)."""
TILE_PX = 512
"""Grid nodes read at a time while sampling (a tile's side)."""
RATE_STRIDE = 25
"""Every this-many-th sampled node measures the views' line rate along the ground."""


def _to_lon_lat(grid: MosaicGrid, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Map coordinates of ``grid``'s CRS to WGS84 longitude and latitude (degrees)."""
    lon, lat = lonlat_transformer(grid.crs_wkt).transform(x, y)
    return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)


def locate_in_view(
    sensor: Sensor, lon: FloatArray, lat: FloatArray, h_m: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The view's imaging time of each point (s) and its line rate with height (lines/m)."""
    scanner = line_scanner_of(sensor)
    if scanner is None:
        raise TypeError(f"{type(sensor).__name__}: not a line scanner")
    line, _ = sensor.ground_to_image(lon, lat, h_m)
    above, _ = sensor.ground_to_image(lon, lat, h_m + 1.0)
    t_s = np.asarray(scanner.timing.time(line), dtype=np.float64)
    return t_s, np.asarray(above - line, dtype=np.float64)


def _line_rate_along_ground(
    sensor: Sensor, grid: MosaicGrid, x: FloatArray, y: FloatArray, h_m: FloatArray
) -> float:
    """The view's lines per metre along the ground (the norm of the line's gradient over the
    grid's projected coordinates; median of the points)."""
    lines = [
        sensor.ground_to_image(*_to_lon_lat(grid, x + dx, y + dy), h_m)[0]
        for dx, dy in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))
    ]
    rate = np.hypot(lines[1] - lines[0], lines[2] - lines[0])
    return float(np.nanmedian(rate)) if np.isfinite(rate).any() else 1.0


def _strides(grid: MosaicGrid, max_nodes: int) -> tuple[int, int]:
    """Row and column strides that sample at most ``max_nodes`` nodes, rows kept while the
    columns can thin (at least 4 columns a row)."""
    step = max(1, math.ceil(grid.width * grid.height / max_nodes))
    if step <= max(grid.width // 4, 1):
        return 1, step
    row_step = max(1, math.ceil(step / max(grid.width // 4, 1)))
    return row_step, max(1, math.ceil(step / row_step))


def _window_values(
    pairs: Sequence[PairLayers], grid: MosaicGrid, window: GridWindow, geoid: Any
) -> tuple[FloatArray, FloatArray]:
    """Each pair's measured heights (NaN where filled or absent; ellipsoidal with ``geoid``)
    and weights ``1 / sigma^2`` on ``window``."""
    heights, weights = [], []
    for layers in pairs:
        h = read_window(layers.dem, grid, window, geoid=geoid)
        if layers.filled is not None:
            source, band = layers.filled
            flag = read_window(source, grid, window, band=band, resampling="nearest")
            h = np.where(flag >= 0.5, np.nan, h)
        if layers.sigma is not None:
            sigma = read_window(layers.sigma[0], grid, window, band=layers.sigma[1])
        else:
            sigma = np.full(h.shape, DEFAULT_SIGMA_M)
        heights.append(h)
        weights.append(np.where(np.isfinite(h), 1.0 / np.maximum(sigma, 0.05) ** 2, 0.0))
    return np.stack(heights), np.nan_to_num(np.stack(weights))


def sample_nodes(
    folders: Sequence[tuple[str, str, Path]],
    sensors: Mapping[str, Sensor],
    geoid: Any = None,
    max_nodes: int = 50_000,
) -> NodeSamples:
    """The nodes of the pairs' DEM folders (``(left, right, folder)``) the fit uses: on the
    union grid of their DEMs, at most ``max_nodes`` (strided), read tile by tile, each
    located in every view at the pairs' weighted mean height (ellipsoidal: ``geoid`` turns
    geoid heights); ``per_m`` over each view's line rate along the ground."""
    layers = [pair_layers(folder) for _, _, folder in folders]
    grid = union_grid([p.dem for p in layers])
    images = tuple(sorted({n for left, right, _ in folders for n in (left, right)}))
    row_step, col_step = _strides(grid, max_nodes)
    parts = []
    for window in grid.windows(TILE_PX):
        rows = np.arange(-window.row0 % row_step, window.n_rows, row_step)
        cols = np.arange((col_step // 2 - window.col0) % col_step, window.n_cols, col_step)
        if rows.size and cols.size:
            heights, weights = _window_values(layers, grid, window, geoid)
            rr, cc = np.meshgrid(rows + window.row0, cols + window.col0, indexing="ij")
            pick = np.ix_(np.arange(len(layers)), rows, cols)
            parts.append(_located(grid, sensors, images, rr, cc, heights[pick], weights[pick]))
    if not parts:
        parts = [
            (np.zeros((len(images), 0)),) * 2
            + (np.zeros((len(layers), 0)),) * 2
            + (np.zeros(0),) * 5
        ]
    t_s, per_m, h, w, row, col, x, y, mean_h = (
        np.concatenate(v, axis=-1) for v in zip(*parts, strict=True)
    )
    few = slice(None, None, RATE_STRIDE)
    rates = [_line_rate_along_ground(sensors[n], grid, x[few], y[few], mean_h[few]) for n in images]
    index = {n: k for k, n in enumerate(images)}
    pairs = tuple((index[left], index[right]) for left, right, _ in folders)
    per_m = per_m / np.asarray(rates)[:, None]
    return NodeSamples(
        images, pairs, t_s, per_m, h, w, row.astype(np.int64), col.astype(np.int64), tuple(rates)
    )


def _located(
    grid: MosaicGrid,
    sensors: Mapping[str, Sensor],
    images: Sequence[str],
    rows: NDArray[np.int64],
    cols: NDArray[np.int64],
    heights: FloatArray,
    weights: FloatArray,
) -> tuple[FloatArray, ...]:
    heights = heights.reshape(len(heights), -1)
    weights = np.where(np.isfinite(heights), weights.reshape(len(weights), -1), 0.0)
    total = weights.sum(axis=0)
    keep = total > 0
    h = (weights * np.nan_to_num(heights)).sum(axis=0)[keep] / total[keep]
    x, y = grid.transform @ (cols.ravel()[keep] + 0.5, rows.ravel()[keep] + 0.5)
    lon, lat = _to_lon_lat(grid, x, y)
    located = [locate_in_view(sensors[n], lon, lat, h) for n in images]
    t_s = np.stack([t for t, _ in located])
    per_m = np.stack([s for _, s in located])
    rc = (rows.ravel()[keep], cols.ravel()[keep])
    return t_s, per_m, heights[:, keep], weights[:, keep], *rc, x, y, h
