"""Orthorectification: a sensor's raw image resampled onto a north-up map grid over a DEM.

* :class:`~carto.framework.imaging.ortho_grid.OrthoGrid`: the output grid (CRS, north-up
  affine transform, shape), in :mod:`carto.framework.imaging.ortho_grid`;
  ``OrthoGrid.covering`` builds the grid that covers one or several images (their borders
  located on the DEM) or given bounds, snapped to the resolution.
* :func:`ortho_mapping` (and the :class:`OrthoMapper` behind it): the image coordinates
  ``(line, sample)`` of every ortho pixel centre.
* :func:`orthorectify`: the raw image resampled at those coordinates with ``cv2.remap``, tile
  by tile. :func:`write_ortho` writes the result as a GeoTIFF, atomically.

Mapping method
    The exact mapping of the ortho pixel ``(row, col)`` is: pixel centre ``(x, y)`` in the grid
    CRS -> WGS84 ``(lon, lat)`` (pyproj) -> ``h`` from the DEM (bilinear) ->
    ``sensor.ground_to_image(lon, lat, h)``. It is computed exactly on coarse nodes every
    ``coarse_step`` pixels only. Interpolating image coordinates between nodes is valid only
    where the terrain between them is smooth, which a rough DEM is not; so the height is kept
    as a variable: at each node the image coordinates are evaluated at the node's DEM height
    ``h0`` and at ``h0 +- 50 m``, giving a second-order expansion ``v(h) = v0 + v1 (h - h0) +
    v2 (h - h0)^2 / 2`` (the image coordinates of a fixed ``(x, y)`` are very nearly linear in
    ``h``: the quadratic term is about ``1e-7 px/m^2`` for a 600 km orbit, the cubic one is
    below ``1e-4 px`` for a kilometre of relief). The polynomial coefficients are interpolated
    bilinearly to every pixel and evaluated at the pixel's **own** DEM height: the DEM is
    sampled bilinearly at each pixel, at DEM pixel coordinates interpolated between the nodes
    (the map projection is smooth: an error below a micrometre). The coefficients vary as
    smoothly as the sensor geometry does, however rough the terrain. The per-pixel evaluation
    is one compiled (numba) pass, parallel over rows
    (:func:`carto.framework.imaging.ortho_kernel.evaluate_kernel`).

    Measured (``benchmarks/ortho_speed.py``, ``tests/framework/test_ortho.py``): 1e-5 px from
    the exact per-pixel mapping at ``coarse_step=16`` (1.4e-4 px at 64) on 4000-6000 m
    mountains with 35-45 degree slopes, where interpolating the image coordinates themselves
    errs by more than half a pixel; a 4000 x 4000 image is orthorectified in about 1.4 s.

    The check: the exact mapping is computed at the centre pixel of **every** coarse cell (the
    point where bilinear interpolation is worst) and compared with the interpolated one. Cells
    where they differ by more than ``tol_px`` (default 0.01 px), or where a node has no image
    coordinates (a sensor that does not extrapolate beyond its image), are computed exactly at
    every pixel. When more than a fifth of the cells of a block fail, the block is redone with
    half the coarse step (down to 2 px). :attr:`OrthoMapper.stats` reports the check.

Conventions
    * Ortho pixels are areas: the transform maps pixel corners; pixel ``(row, col)`` stands at
      its centre ``(col + 0.5, row + 0.5)``. Grids are north-up (no rotation).
    * Image coordinates follow the project convention (first pixel centre at ``(0.5, 0.5)``);
      ``cv2.remap`` takes 0-based pixel indices, so ``index = coordinate - 0.5``.
    * The DEM holds ellipsoidal heights (:class:`carto.framework.raster.dem.DEM`).
    Orthorectification
      is pointwise: terrain hidden from the sensor (occlusions) is not detected, it shows the
      occluding terrain's image twice.
    * Ortho pixels whose ground point falls outside the image (``0 <= line <= n_lines``,
      ``0 <= sample <= n_samples``) or outside the DEM are ``nodata`` (NaN by default); the
      output is float32.
    * ``cv2.remap`` with float32 maps interpolates at the exact coordinates (OpenCV 5; older
      versions quantised them to 1/32 pixel): ``tests/framework/test_ortho_gdal.py`` finds
      our orthos and GDAL's ``RPC_DEM`` warp within 1e-4 px of each other.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho_grid import (
    OrthoGrid,
    check_dem,
    check_sensor,
    dem_transformer,
    lonlat_transformer,
)
from carto.framework.imaging.ortho_kernel import (
    cell_any,
    cell_centres,
    cell_positions,
    evaluate_kernel,
    node_positions,
)
from carto.framework.raster.dem import DEM

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

RESAMPLING_METHODS = ("nearest", "linear", "cubic", "lanczos")
"""Names accepted by :func:`orthorectify` (OpenCV ``INTER_NEAREST`` ... ``INTER_LANCZOS4``)."""
_KERNEL_MARGIN_PX = {"nearest": 2, "linear": 2, "cubic": 3, "lanczos": 5}
_DH_M = 50.0  # height step of the finite differences d(line, sample)/dh at the coarse nodes
_REFINE_FRACTION = 0.2  # a block whose failed cells exceed this fraction halves its step
_MIN_STEP = 2
_CV_MAX_SIDE = 32767  # cv2.remap works with source images smaller than SHRT_MAX


# ----------------------------------------------------------------------------- helpers
def _project(
    sensor: Sensor, lon: FloatArray, lat: FloatArray, h: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Image coordinates, extrapolated beyond the image where the sensor can (``project``)."""
    project = getattr(sensor, "project", None)
    if project is not None:
        line, sample, _inside = project(lon, lat, h)
    else:  # pragma: no cover - every Sensor has project; kept for duck-typed models
        line, sample = sensor.ground_to_image(lon, lat, h)
    return np.asarray(line, np.float64), np.asarray(sample, np.float64)


# ----------------------------------------------------------------------------- mapping
@attrs.define
class MappingStats:
    """What the check of :class:`OrthoMapper` found (accumulated over the mapped blocks).

    Attributes:
        cells_checked: coarse cells whose centre pixel was computed exactly and compared.
        cells_exact: cells computed exactly at every pixel (check failed or node missing).
        pixels_exact: pixels computed exactly (in those cells).
        max_check_error_px: largest ``|interpolated - exact|`` at the checked cell centres
            (before the failed cells were recomputed), pixels.
        sum_sq_check_error: sum of the squared check errors (for :attr:`rms_check_error_px`).
        refinements: blocks redone with half the coarse step.
        min_step: the smallest coarse step used.
    """

    cells_checked: int = 0
    cells_exact: int = 0
    pixels_exact: int = 0
    max_check_error_px: float = 0.0
    sum_sq_check_error: float = 0.0
    refinements: int = 0
    min_step: int = 0

    @property
    def rms_check_error_px(self) -> float:
        """RMS of the check errors at the cell centres, pixels."""
        if self.cells_checked == 0:
            return float("nan")
        return math.sqrt(self.sum_sq_check_error / self.cells_checked)

    def as_dict(self) -> dict[str, float]:
        out = attrs.asdict(self)
        out["rms_check_error_px"] = self.rms_check_error_px
        return out


class OrthoMapper:
    """Image coordinates of ortho pixel centres by checked coarse-grid interpolation.

    See the module docstring for the method. ``map`` can be called block by block (tiles
    aligned on multiples of ``coarse_step`` give seamless results); :attr:`stats` accumulates
    what the check found.

    Args:
        sensor: the image's model.
        grid: the ortho grid.
        dem: DEM with ellipsoidal heights.
        coarse_step: spacing of the exactly computed nodes, pixels (>= 1; 1 = exact).
        tol_px: largest accepted interpolation error at the checked cell centres, pixels.
        block: largest block mapped at once (bounds the memory of :meth:`map`), pixels.
    """

    def __init__(
        self,
        sensor: Sensor,
        grid: OrthoGrid,
        dem: DEM,
        *,
        coarse_step: int = 16,
        tol_px: float = 0.01,
        block: int = 1024,
    ) -> None:
        self.sensor = check_sensor(sensor)
        if not isinstance(grid, OrthoGrid):
            raise InputError(f"grid must be an OrthoGrid, got {type(grid).__name__}")
        self.grid = grid
        self.dem = check_dem(dem)
        if isinstance(coarse_step, bool) or not isinstance(coarse_step, (int, np.integer)):
            raise InputError(f"coarse_step must be an integer >= 1, got {coarse_step!r}")
        if coarse_step < 1:
            raise InputError(f"coarse_step must be an integer >= 1, got {coarse_step}")
        if not (math.isfinite(tol_px) and tol_px > 0):
            raise InputError(f"tol_px must be > 0, got {tol_px}")
        self.coarse_step = int(coarse_step)
        self.tol_px = float(tol_px)
        self.block = max(self.coarse_step, -(-int(block) // self.coarse_step) * self.coarse_step)
        self.stats = MappingStats(min_step=self.coarse_step)
        self._to_lonlat = lonlat_transformer(grid.crs.to_wkt())
        self._n_lines, self._n_samples = sensor.image_shape
        self._box: tuple[float, float, float, float] | None = None
        self._heights = np.ascontiguousarray(dem.heights, dtype=np.float64)

    # ------------------------------------------------------------------ public
    def map(
        self, row0: int = 0, col0: int = 0, n_rows: int | None = None, n_cols: int | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """``(line, sample)`` of the pixels ``[row0, row0 + n_rows) x [col0, col0 + n_cols)``.

        NaN where the ground point has no DEM height or falls outside the image.
        """
        rows, cols = self.grid.shape
        n_rows = rows - row0 if n_rows is None else int(n_rows)
        n_cols = cols - col0 if n_cols is None else int(n_cols)
        if not (row0 >= 0 and col0 >= 0 and n_rows >= 1 and n_cols >= 1) or (
            row0 + n_rows > rows or col0 + n_cols > cols
        ):
            raise InputError(
                f"ortho mapping: window ({row0}, {col0}, {n_rows}, {n_cols}) is not inside "
                f"the grid {rows} x {cols}"
            )
        line = np.empty((n_rows, n_cols))
        sample = np.empty((n_rows, n_cols))
        b = self.block
        for r in range(row0, row0 + n_rows, b):
            r1 = min(r + b, row0 + n_rows)
            for c in range(col0, col0 + n_cols, b):
                c1 = min(c + b, col0 + n_cols)
                out_l, out_s = self._block(r, r1, c, c1, self.coarse_step)
                line[r - row0 : r1 - row0, c - col0 : c1 - col0] = out_l
                sample[r - row0 : r1 - row0, c - col0 : c1 - col0] = out_s
        outside = ~(
            (line >= 0.0) & (line <= self._n_lines) & (sample >= 0.0) & (sample <= self._n_samples)
        )
        line[outside] = np.nan
        sample[outside] = np.nan
        return line, sample

    def exact(self, row: ArrayLike, col: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """The exact mapping of pixels (0-based indices), extrapolated beyond the image."""
        x, y = self.grid.xy(row, col)
        lon, lat = self._to_lonlat.transform(x, y)
        lon, lat = np.asarray(lon, np.float64), np.asarray(lat, np.float64)
        h = self.dem.height(lon, lat)
        return _project(self.sensor, lon, lat, h)

    # ------------------------------------------------------------------ internals
    def _image_box(self) -> tuple[float, float, float, float]:
        """``(row_min, row_max, col_min, col_max)`` of the grid pixels that may see the image:
        the box of its border located at the DEM's lowest and highest heights (a line of sight
        meets the terrain between them), widened by two coarse steps."""
        if self._box is None:
            lo, hi = self.dem.height_range
            t = np.linspace(0.0, 1.0, 65)
            n_l, n_s = self._n_lines, self._n_samples
            line = np.concatenate([0 * t, t * n_l, 0 * t + n_l, t * n_l])
            sample = np.concatenate([t * n_s, 0 * t, t * n_s, 0 * t + n_s])
            line, sample = np.tile(line, 2), np.tile(sample, 2)
            h = np.repeat([lo - 10.0, hi + 10.0], line.size // 2)
            lon, lat = self.sensor.image_to_ground(line, sample, h)
            ok = np.isfinite(lon) & np.isfinite(lat)
            box = (-math.inf, math.inf, -math.inf, math.inf)
            if ok.any():
                row, col = self.grid.rowcol(lon[ok], lat[ok])
                m = 2.0 * self.coarse_step
                if np.isfinite(row).all() and np.isfinite(col).all():
                    box = (row.min() - m, row.max() + m, col.min() - m, col.max() + m)
            self._box = box
        return self._box

    def _nodes(
        self, rows: IntArray, cols: IntArray, check_rows: IntArray, check_cols: IntArray
    ) -> tuple[FloatArray, FloatArray, float, FloatArray, FloatArray]:
        """Everything computed exactly for a block, in one ``project`` call.

        Returns:
            polynomial coefficients in ``u = h - h_ref`` at the nodes ``(2, 3, n_r, n_c)``
            (line/sample; order 0, 1, 2), the nodes' DEM pixel coordinates ``(2, n_r, n_c)``
            (row, col centre indices), ``h_ref``, and the exact ``(line, sample)`` of the check
            pixels ``check_rows x check_cols``.
        """
        lon, lat = self.grid.lonlat(rows[:, None], cols[None, :])
        lon_c, lat_c = self.grid.lonlat(check_rows[:, None], check_cols[None, :])
        h0 = self.dem.height(lon, lat)
        h_c = self.dem.height(lon_c, lat_c)
        valid = np.isfinite(h0)
        if valid.any():
            h_ref = float(np.mean(h0[valid]))
        else:
            lo, hi = self.dem.height_range
            h_ref = 0.5 * (lo + hi)
        h0 = np.where(valid, h0, h_ref)
        shape = h0.shape
        n = h0.size
        lines, samples = _project(
            self.sensor,
            np.concatenate([lon.ravel()] * 3 + [lon_c.ravel()]),
            np.concatenate([lat.ravel()] * 3 + [lat_c.ravel()]),
            np.concatenate([(h0 - _DH_M).ravel(), h0.ravel(), (h0 + _DH_M).ravel(), h_c.ravel()]),
        )
        coeffs = np.empty((2, 3, *shape))
        d0 = h0 - h_ref
        for k, values in enumerate((lines, samples)):
            lo_, mid, hi_ = (values[m * n : (m + 1) * n].reshape(shape) for m in range(3))
            v1 = (hi_ - lo_) / (2.0 * _DH_M)
            v2 = (hi_ - 2.0 * mid + lo_) / _DH_M**2
            coeffs[k, 0] = mid - v1 * d0 + 0.5 * v2 * d0**2
            coeffs[k, 1] = v1 - v2 * d0
            coeffs[k, 2] = 0.5 * v2
        check_shape = lon_c.shape
        return (
            coeffs,
            np.stack(self._dem_pixel(lon, lat)),
            h_ref,
            lines[3 * n :].reshape(check_shape),
            samples[3 * n :].reshape(check_shape),
        )

    def _dem_pixel(self, lon: FloatArray, lat: FloatArray) -> tuple[FloatArray, FloatArray]:
        """DEM centre indices ``(row, col)`` (0 = first pixel centre) of WGS84 lon/lat, the
        convention of :meth:`DEM.height` (longitudes wrapped into the DEM's 360 degrees)."""
        dem = self.dem
        x, y = dem_transformer(dem.crs.to_wkt()).transform(lon, lat)
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        t = dem.transform
        if dem.crs.is_geographic:
            n_rows, n_cols = dem.shape
            start = t.c + 0.5 * (t.a * n_cols + t.b * n_rows) - 180.0 - 1e-12
            x = start + np.mod(x - start, 360.0)
        inv = ~t
        col = inv.a * x + inv.b * y + inv.c - 0.5
        row = inv.d * x + inv.e * y + inv.f - 0.5
        return row, col

    def _block(
        self, r0: int, r1: int, c0: int, c1: int, step: int
    ) -> tuple[FloatArray, FloatArray]:
        n_rows, n_cols = self.grid.shape
        node_r = node_positions(r0, r1, step, n_rows)
        node_c = node_positions(c0, c1, step, n_cols)
        cr, cc = cell_centres(node_r), cell_centres(node_c)
        coeffs, dem_rc, h_ref, exact_l, exact_s = self._nodes(node_r, node_c, cr, cc)
        ir, fr = cell_positions(node_r, np.arange(r0, r1))
        ic, fc = cell_positions(node_c, np.arange(c0, c1))
        line = np.empty((r1 - r0, c1 - c0))
        sample = np.empty((r1 - r0, c1 - c0))
        evaluate_kernel()(coeffs, dem_rc, ir, fr, ic, fc, self._heights, h_ref, line, sample)

        # check: exact mapping at the centre pixel of every cell
        got_l = line[np.ix_(cr - r0, cc - c0)]
        got_s = sample[np.ix_(cr - r0, cc - c0)]
        error = np.hypot(got_l - exact_l, got_s - exact_s)
        finite = np.isfinite(error)
        missing_node = cell_any(~np.isfinite(coeffs).all(axis=(0, 1)))
        if missing_node.any():  # cells away from the image cannot see it: skip them
            row_min, row_max, col_min, col_max = self._image_box()
            rows_c = node_r if node_r.size == 1 else node_r[:-1]
            rows_c1 = node_r if node_r.size == 1 else node_r[1:]
            cols_c = node_c if node_c.size == 1 else node_c[:-1]
            cols_c1 = node_c if node_c.size == 1 else node_c[1:]
            near_r = (rows_c1 >= row_min) & (rows_c <= row_max)
            near_c = (cols_c1 >= col_min) & (cols_c <= col_max)
            missing_node &= near_r[:, None] & near_c[None, :]
        failed = finite & (error > self.tol_px)
        disagree = np.isfinite(got_l) != np.isfinite(exact_l)
        if step > _MIN_STEP and failed.sum() > _REFINE_FRACTION * max(finite.sum(), 1):
            self.stats.refinements += 1
            finer = max(step // 2, _MIN_STEP)
            self.stats.min_step = min(self.stats.min_step, finer)
            return self._block(r0, r1, c0, c1, finer)
        self.stats.cells_checked += int(finite.sum())
        if finite.any():
            self.stats.max_check_error_px = max(
                self.stats.max_check_error_px, float(error[finite].max())
            )
            self.stats.sum_sq_check_error += float(np.sum(error[finite] ** 2))
        bad = failed | disagree | missing_node
        if bad.any():
            rows_bad, cols_bad = np.nonzero(bad[ir][:, ic])
            l_exact, s_exact = self.exact(rows_bad + r0, cols_bad + c0)
            line[rows_bad, cols_bad] = l_exact
            sample[rows_bad, cols_bad] = s_exact
            self.stats.cells_exact += int(bad.sum())
            self.stats.pixels_exact += int(rows_bad.size)
        return line, sample


def ortho_mapping(
    sensor: Sensor,
    grid: OrthoGrid,
    dem: DEM,
    *,
    coarse_step: int = 16,
    tol_px: float = 0.01,
) -> tuple[FloatArray, FloatArray]:
    """Image coordinates ``(line_map, sample_map)`` of every pixel centre of ``grid``.

    Exact on coarse nodes every ``coarse_step`` pixels, interpolated in between with each
    pixel's own DEM height, checked at every coarse cell centre against ``tol_px`` (see the
    module docstring and :class:`OrthoMapper`). Arrays of ``grid.shape``, float64, in the
    project's image convention (first pixel centre at 0.5, 0.5); NaN where the ground point
    has no DEM height or falls outside the image.

    Raises:
        InputError: bad sensor, grid or DEM (e.g. not ellipsoidal), ``coarse_step < 1``.
    """
    return OrthoMapper(sensor, grid, dem, coarse_step=coarse_step, tol_px=tol_px).map()


# ----------------------------------------------------------------------------- resampling
def _interpolation_flag(resampling: str) -> int:
    import cv2

    flags = {
        "nearest": cv2.INTER_NEAREST,
        "linear": cv2.INTER_LINEAR,
        "cubic": cv2.INTER_CUBIC,
        "lanczos": cv2.INTER_LANCZOS4,
    }
    if resampling not in flags:
        raise InputError(f"resampling {resampling!r} is not one of {', '.join(RESAMPLING_METHODS)}")
    return flags[resampling]


def _resample(
    raw: NDArray, line: FloatArray, sample: FloatArray, resampling: str, nodata: float
) -> NDArray[np.float32]:
    """``raw`` at the image coordinates (0.5-centred) with cv2.remap, from the window of
    ``raw`` the coordinates fall in (plus the kernel's margin); ``nodata`` where NaN."""
    import cv2

    out = np.full(line.shape, nodata, np.float32)
    valid = np.isfinite(line) & np.isfinite(sample)
    if not valid.any():
        return out
    n_lines, n_samples = raw.shape
    margin = _KERNEL_MARGIN_PX[resampling]
    lines, samples = line[valid], sample[valid]
    l0 = max(math.floor(float(lines.min()) - 0.5) - margin, 0)
    l1 = min(math.ceil(float(lines.max()) - 0.5) + margin + 1, n_lines)
    s0 = max(math.floor(float(samples.min()) - 0.5) - margin, 0)
    s1 = min(math.ceil(float(samples.max()) - 0.5) + margin + 1, n_samples)
    if max(l1 - l0, s1 - s0) >= _CV_MAX_SIDE and line.size > 1:  # split the tile
        if line.shape[0] >= line.shape[1]:
            h = line.shape[0] // 2
            out[:h] = _resample(raw, line[:h], sample[:h], resampling, nodata)
            out[h:] = _resample(raw, line[h:], sample[h:], resampling, nodata)
        else:
            w = line.shape[1] // 2
            out[:, :w] = _resample(raw, line[:, :w], sample[:, :w], resampling, nodata)
            out[:, w:] = _resample(raw, line[:, w:], sample[:, w:], resampling, nodata)
        return out
    src = np.ascontiguousarray(raw[l0:l1, s0:s1], dtype=np.float32)
    # 0.5-centred image coordinates -> 0-based indices in the window
    map_y = np.where(valid, line - 0.5 - l0, -1.0).astype(np.float32)
    map_x = np.where(valid, sample - 0.5 - s0, -1.0).astype(np.float32)
    values = cv2.remap(
        src, map_x, map_y, _interpolation_flag(resampling), borderMode=cv2.BORDER_REPLICATE
    )
    out[valid] = values[valid]
    return out


def orthorectify(
    raw: ArrayLike,
    sensor: Sensor,
    grid: OrthoGrid,
    dem: DEM,
    *,
    resampling: str = "cubic",
    nodata: float = np.nan,
    tile_size: int = 1024,
    coarse_step: int = 16,
    tol_px: float = 0.01,
) -> NDArray[np.float32]:
    """The raw image of ``sensor`` resampled on ``grid`` over ``dem``: float32 ``grid.shape``.

    The grid is processed in tiles of ``tile_size`` pixels (rounded up to a multiple of
    ``coarse_step``): each tile's mapping (:class:`OrthoMapper`), then ``cv2.remap`` of the
    window of ``raw`` the tile maps into, widened by the kernel's reach (so neighbouring
    windows overlap by a few pixels and tiles join seamlessly). Memory beyond the input and the
    output is a few dozen bytes per tile pixel, whatever the image size; ``raw`` may be a
    ``numpy.memmap``.

    Args:
        raw: the raw image, 2-D ``sensor.image_shape``, any numeric dtype (NaN = no data:
            output pixels whose kernel touches it are NaN); or an
            :class:`~carto.framework.raster.image_source.ImageSource`, of which only the
            windows the grid maps into are read.
        sensor: its geometric model.
        grid: the output grid.
        dem: DEM with ellipsoidal heights.
        resampling: ``"nearest"``, ``"linear"``, ``"cubic"`` (default) or ``"lanczos"``.
        nodata: value of the pixels outside the image or the DEM.
        tile_size: output tile side, pixels.
        coarse_step, tol_px: see :func:`ortho_mapping`.

    Raises:
        InputError: ``raw`` is not 2-D or not of the sensor's shape, unknown resampling, bad
            tile size, or a bad sensor, grid or DEM.
    """
    from carto.framework.raster.image_source import ImageSource

    image = raw if isinstance(raw, np.ndarray | ImageSource) else np.asarray(raw)
    if image.ndim != 2:
        raise InputError(f"orthorectify: raw image must be 2-D, got shape {image.shape}")
    if tuple(image.shape) != tuple(sensor.image_shape):
        raise InputError(
            f"orthorectify: raw image shape {image.shape} differs from the sensor's "
            f"{tuple(sensor.image_shape)}"
        )
    if not np.issubdtype(image.dtype, np.number) or np.issubdtype(image.dtype, np.complexfloating):
        raise InputError(f"orthorectify: raw image dtype {image.dtype} is not real numeric")
    _interpolation_flag(resampling)
    if isinstance(tile_size, bool) or not isinstance(tile_size, (int, np.integer)):
        raise InputError(f"tile_size must be an integer >= 16, got {tile_size!r}")
    if not 16 <= tile_size <= 16384:
        raise InputError(f"tile_size must be within 16..16384, got {tile_size}")
    mapper = OrthoMapper(sensor, grid, dem, coarse_step=coarse_step, tol_px=tol_px)
    step = mapper.coarse_step
    tile = -(-int(tile_size) // step) * step
    mapper.block = tile
    rows, cols = grid.shape
    out = np.empty((rows, cols), np.float32)
    for r0 in range(0, rows, tile):
        r1 = min(r0 + tile, rows)
        for c0 in range(0, cols, tile):
            c1 = min(c0 + tile, cols)
            line, sample = mapper.map(r0, c0, r1 - r0, c1 - c0)
            out[r0:r1, c0:c1] = _resample(image, line, sample, resampling, float(nodata))
    return out


# ----------------------------------------------------------------------------- output
_WRITE_ROWS = 1024  # rows written at once (a multiple of the 256-row GeoTIFF tiles)


def _bands(data: Any) -> list[Any]:
    """The bands of ``data``: a 2-D array or tiled layer, a 3-D array, or a sequence of
    2-D arrays and tiled layers."""
    from carto.framework.raster.tiled_layer import TiledLayer

    if isinstance(data, TiledLayer):
        return [data]
    if isinstance(data, list | tuple) and any(isinstance(b, TiledLayer) for b in data):
        bands = list(data)
    else:
        array = np.asarray(data)
        if array.ndim == 2:
            array = array[None]
        if array.ndim != 3:
            raise InputError(f"write_ortho: data must be 2-D or 3-D, got shape {array.shape}")
        bands = list(array)
    for band in bands:
        if np.ndim(band) != 2:
            raise InputError(f"write_ortho: every band must be 2-D, got {np.shape(band)}")
    return bands


def _converter(target: np.dtype, nodata: float | None) -> Any:
    """A block of float data in ``target``: integers rounded and clipped to the dtype's
    range, NaN as ``nodata``, a valid value equal to ``nodata`` moved to the next one."""

    def convert(block: Any) -> NDArray:
        values = np.asarray(block, np.float64)
        if not np.issubdtype(target, np.integer):
            return values.astype(target)
        info = np.iinfo(target)
        finite = np.isfinite(values)
        out = np.clip(np.rint(np.where(finite, values, 0.0)), info.min, info.max)
        if nodata is not None:
            fill = int(nodata)
            bump = fill + 1 if fill < info.max else fill - 1
            out = np.where(finite & (out == fill), bump, out)
            out = np.where(finite, out, fill)
        return out.astype(target)

    return convert


def write_ortho(
    path: str | os.PathLike[str],
    data: ArrayLike,
    grid: OrthoGrid,
    *,
    vertical: str | None = None,
    tags: Mapping[str, Any] | None = None,
    nodata: float | None = None,
    band_descriptions: Sequence[str] | None = None,
    overview_resampling: str = "average",
    out_dtype: Any = None,
    band_units: Sequence[str | None] | None = None,
) -> Path:
    """Write an ortho-image (or any raster on ``grid``) as a cloud-optimised GeoTIFF,
    atomically (:func:`carto.framework.raster.cog.cog_writer`: 256 x 256 tiles, DEFLATE,
    overviews), with the grid's CRS and transform and ``AREA_OR_POINT=Area``. Float data get
    NaN as nodata unless ``nodata`` says otherwise.

    Args:
        path: the output file.
        data: ``(rows, cols)`` or ``(bands, rows, cols)`` of ``grid.shape``, or bands held as
            tiles in files (:class:`~carto.framework.raster.tiled_layer.TiledLayer`, alone or
            in a list of bands), written window by window.
        grid: the grid the data are on.
        vertical: when the raster holds heights, their vertical reference (``"ellipsoid"``,
            ``"geoid:EGM96"``...): the CRS is then compound with its vertical CRS
            (:mod:`carto.framework.raster.vertical_reference`), the ``VERTICAL_REFERENCE``
            tag names it too and the band unit is metres.
        tags: more metadata tags (values written as strings).
        nodata: nodata value (default NaN for float data, none for integers).
        band_descriptions: one GDAL band description per band (what QGIS and ``gdalinfo``
            show as the band's name).
        band_units: one unit per band (GDAL's ``units``, e.g. ``"metre"``; None: none).
        overview_resampling: how the overviews are made: ``"average"`` (images, heights)
            or ``"nearest"`` (flags, counts).
        out_dtype: write float data in this dtype (the input images' radiometry, e.g.
            ``uint16``): an integer dtype rounds, clips to its range and writes NaN as
            ``nodata`` (default 0 for an integer dtype; a valid value equal to it becomes
            the next one, so no pixel with data reads as nodata).

    Returns:
        ``path``.

    Raises:
        InputError: data of the wrong shape or dtype, bad vertical reference, unwritable path.
    """
    from carto.framework.raster.cog import cog_writer

    if not isinstance(grid, OrthoGrid):
        raise InputError(f"write_ortho: grid must be an OrthoGrid, got {type(grid).__name__}")
    bands = _bands(data)
    if any(tuple(np.shape(b)) != tuple(grid.shape) for b in bands):
        raise InputError(
            f"write_ortho: data shape {[np.shape(b) for b in bands]} does not match the grid "
            f"{grid.shape}"
        )
    dtype = np.result_type(*[b.dtype for b in bands])
    convert = None
    if out_dtype is not None and np.dtype(out_dtype) != dtype:
        dtype, convert, nodata = _conversion(np.dtype(out_dtype), nodata)
    if band_descriptions is not None and len(band_descriptions) != len(bands):
        raise InputError(
            f"write_ortho: {len(band_descriptions)} band descriptions for {len(bands)} bands"
        )
    dtype, nodata = _written_dtype(dtype, nodata)
    all_tags = {"AREA_OR_POINT": "Area", **{str(k): str(v) for k, v in (tags or {}).items()}}
    profile = _profile(grid, len(bands), dtype, nodata)
    path = Path(path)
    with cog_writer(
        path, profile, overview_resampling=overview_resampling, what="ortho", vertical=vertical
    ) as dst:
        _write_rows(dst, bands, grid.shape, dtype, convert)
        dst.update_tags(**all_tags)
        _describe_bands(dst, band_descriptions, band_units)
    return path


def _conversion(target: np.dtype, nodata: float | None) -> tuple[np.dtype, Any, float | None]:
    """``(dtype, converter, nodata)`` of data written in ``out_dtype`` ``target``
    (:func:`_converter`; an integer dtype's nodata defaults to 0), refused unless numeric."""
    if not np.issubdtype(target, np.integer) and not np.issubdtype(target, np.floating):
        raise InputError(f"write_ortho: out_dtype {target} cannot be written")
    if np.issubdtype(target, np.integer) and nodata is None:
        nodata = 0
    return target, _converter(target, nodata), nodata


def _written_dtype(dtype: np.dtype, nodata: float | None) -> tuple[np.dtype, float | None]:
    """The dtype the GeoTIFF holds (float16 as float32; refused unless integer or float) and
    its nodata (NaN for float data unless given)."""
    if dtype == np.float16:
        dtype = np.dtype(np.float32)
    if not (np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)):
        raise InputError(f"write_ortho: dtype {dtype} cannot be written")
    if nodata is None and np.issubdtype(dtype, np.floating):
        nodata = float("nan")
    return dtype, nodata


def _profile(grid: OrthoGrid, count: int, dtype: np.dtype, nodata: float | None) -> dict[str, Any]:
    """The rasterio profile of ``count`` bands of ``dtype`` on ``grid`` (nodata when given)."""
    from rasterio.crs import CRS as RioCRS

    rows, cols = grid.shape
    profile: dict[str, Any] = {
        "height": rows,
        "width": cols,
        "count": count,
        "dtype": dtype,
        "crs": RioCRS.from_wkt(grid.crs.to_wkt()),
        "transform": grid.transform,
    }
    if nodata is not None:
        profile["nodata"] = nodata
    return profile


def _write_rows(
    dst: Any, bands: list[Any], shape: tuple[int, int], dtype: np.dtype, convert: Any
) -> None:
    """The bands of ``shape`` written by blocks of :data:`_WRITE_ROWS` rows, as ``dtype`` or
    by ``convert`` (:func:`_converter`) when given."""
    from rasterio.windows import Window

    from carto.framework.raster.tiled_layer import layer_window

    rows, cols = shape
    # by blocks of rows: tiled layers are read window by window, never whole
    for r0 in range(0, rows, _WRITE_ROWS):
        window = Window(0, r0, cols, min(_WRITE_ROWS, rows - r0))
        for k, band in enumerate(bands, 1):
            block = layer_window(band, slice(r0, r0 + window.height), slice(0, cols))
            block = convert(block) if convert is not None else np.asarray(block, dtype)
            dst.write(block, k, window=window)


def _describe_bands(
    dst: Any, descriptions: Sequence[str] | None, units: Sequence[str | None] | None
) -> None:
    """Each band's GDAL description and unit (none where not given)."""
    for k, description in enumerate(descriptions or (), 1):
        dst.set_band_description(k, str(description))
    for k, unit in enumerate(units or (), 1):
        if unit:
            dst.set_band_unit(k, str(unit))
