"""Image point -> ground point on a DEM surface, through any sensor.

:func:`dem_surface_locate` is the generic ray/DEM intersection behind
:meth:`carto.framework.geometry.sensor.Sensor.locate_on_dem`: it marches down each line of
sight and refines the first crossing of the terrain (see its docstring).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.raster.dem import DEM
from carto.framework.raster.grid_sampling import bilinear_sample

if TYPE_CHECKING:  # any sensor: used through its methods only
    from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]


def dem_surface_locate(
    sensor: Sensor,
    line: ArrayLike,
    sample: ArrayLike,
    dem: DEM,
    *,
    tol_m: float = 1e-3,
    max_iter: int = 30,
    step_px: float = 1.0,
    max_steps: int = 4096,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Locate image points on the DEM surface: ``(line, sample) -> (lon, lat, h)``.

    Works for any :class:`~carto.framework.geometry.sensor.Sensor` through its ``image_to_ground``;
    all points at once (the loops run over march steps and iterations, never over points).

    Method: along each line of sight, ``f(h) = DEM(image_to_ground(line, sample, h)) - h`` is
    negative above the terrain and positive below it.

    1. The line of sight is located at the DEM's lowest and highest heights (minus/plus 1 m);
       between them it is approximated by a straight segment in the DEM's pixel space, and
       marched from the top down in steps of at most ``step_px`` DEM pixels. The first sign
       change of ``f`` brackets the first (visible) intersection of the ray with the terrain.
    2. The bracket is refined by the Illinois variant of regula falsi using the sensor's own
       ``image_to_ground`` (so curved lines of sight are followed exactly) until
       ``|f| <= tol_m`` or the bracket is narrower than ``tol_m``.

    Unlike fixed-point iteration ``h <- DEM(lon(h), lat(h))``, this converges on any slope
    (the bracket always holds a root of the continuous bilinear surface). Features thinner
    than ``step_px`` along the ray may be stepped over.

    Args:
        sensor: the image's sensor model.
        line, sample: image coordinates (pixels), arrays that broadcast together.
        dem: a DEM with ellipsoidal heights (see :meth:`DEM.to_ellipsoid`).
        tol_m: height tolerance, metres.
        max_iter: maximum number of refinement iterations.
        step_px: march step along the ray, DEM pixels.
        max_steps: maximum number of march steps.

    Returns:
        ``(lon_deg, lat_deg, h_m)`` of the broadcast shape, with
        ``sensor.image_to_ground(line, sample, h) == (lon, lat)``; NaN where the line of sight
        leaves the DEM (or meets nodata) before it meets the terrain, or does not converge.

    Raises:
        InputError: the DEM heights are not ellipsoidal, or the DEM holds no valid height.
    """
    dem.check_ellipsoidal("locating image points")
    line_a, sample_a = as_float_arrays(line, sample)
    shape = line_a.shape
    lines, samples = line_a.ravel(), sample_a.ravel()
    n = lines.size
    lon_out = np.full(n, np.nan)
    lat_out = np.full(n, np.nan)
    h_out = np.full(n, np.nan)
    if n == 0:
        return lon_out.reshape(shape), lat_out.reshape(shape), h_out.reshape(shape)
    dem_min, dem_max = dem.height_range
    heights = (dem_min - 1.0 - tol_m, dem_max + 1.0 + tol_m)
    brackets = _march(sensor, lines, samples, dem, heights, step_px, max_steps)
    _regula_falsi(sensor, lines, samples, dem, brackets, tol_m, max_iter, (lon_out, lat_out, h_out))
    return lon_out.reshape(shape), lat_out.reshape(shape), h_out.reshape(shape)


def _march(
    sensor: Any,
    lines: FloatArray,
    samples: FloatArray,
    dem: Any,
    heights: tuple[float, float],
    step_px: float,
    max_steps: int,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Step 1 of :func:`dem_surface_locate`: march down each (straightened) line of sight
    from ``heights[1]`` to ``heights[0]`` in DEM pixel space; the heights below and above the
    terrain that bracket its first crossing and the height differences there (NaN: no
    bracket)."""
    h_low, h_high = heights
    n = lines.size
    lon_lo, lat_lo = sensor.image_to_ground(lines, samples, np.full(n, h_low))
    lon_hi, lat_hi = sensor.image_to_ground(lines, samples, np.full(n, h_high))
    r_lo, c_lo = dem.lonlat_to_pixel(np.asarray(lon_lo, float), np.asarray(lat_lo, float))
    r_hi, c_hi = dem.lonlat_to_pixel(np.asarray(lon_hi, float), np.asarray(lat_hi, float))
    ok = np.isfinite(r_lo) & np.isfinite(c_lo) & np.isfinite(r_hi) & np.isfinite(c_hi)
    span_px = np.hypot(r_lo - r_hi, c_lo - c_hi)
    longest = float(np.max(span_px[ok])) if ok.any() else 0.0
    n_steps = int(min(max(math.ceil(longest / step_px), 1), max_steps))
    active = np.flatnonzero(ok)
    f_prev = np.full(active.size, np.nan)
    bracket_lo = np.full(n, np.nan)  # height below the terrain (f >= 0)
    bracket_hi = np.full(n, np.nan)  # height above the terrain (f < 0)
    f_lo = np.full(n, np.nan)
    f_hi = np.full(n, np.nan)
    for k in range(n_steps + 1):
        if active.size == 0:
            break
        frac = k / n_steps
        h = h_high + frac * (h_low - h_high)
        row = r_hi[active] + frac * (r_lo[active] - r_hi[active])
        col = c_hi[active] + frac * (c_lo[active] - c_hi[active])
        f = bilinear_sample(dem.heights, row, col) - h
        found = (f_prev < 0.0) & (f >= 0.0)
        if found.any():
            idx = active[found]
            bracket_lo[idx] = h
            bracket_hi[idx] = h - (h_low - h_high) / n_steps
            f_lo[idx] = f[found]
            f_hi[idx] = f_prev[found]
        # a NaN breaks the bracket; a step under the terrain without a bracket is not visible
        keep = ~found & ~(np.isfinite(f) & (f >= 0.0))
        active = active[keep]
        f_prev = f[keep]
    return bracket_lo, bracket_hi, f_lo, f_hi


def _regula_falsi(
    sensor: Any,
    lines: FloatArray,
    samples: FloatArray,
    dem: Any,
    brackets: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    tol_m: float,
    max_iter: int,
    out: tuple[FloatArray, FloatArray, FloatArray],
) -> None:
    """Step 2 of :func:`dem_surface_locate`: Illinois regula falsi on each bracket with the
    sensor's own line of sight; the points found are written into ``out`` (lon, lat, h)."""
    lon_out, lat_out, h_out = out
    bracket_lo, bracket_hi, f_lo, f_hi = brackets
    active = np.flatnonzero(np.isfinite(bracket_lo))
    a, b = bracket_lo[active], bracket_hi[active]
    fa, fb = f_lo[active], f_hi[active]
    side = np.zeros(active.size, dtype=np.int8)  # which end moved last: +1 a, -1 b
    for _ in range(max_iter):
        if active.size == 0:
            break
        h = np.where(fa - fb > 0.0, a - fa * (b - a) / (fb - fa), 0.5 * (a + b))
        h = np.clip(h, a, b)
        lon, lat = sensor.image_to_ground(lines[active], samples[active], h)
        lon, lat = np.asarray(lon, float), np.asarray(lat, float)
        f = dem.height(lon, lat) - h
        bad = ~np.isfinite(f)
        done = ~bad & ((np.abs(f) <= tol_m) | (b - a <= tol_m))
        idx = active[done]
        lon_out[idx], lat_out[idx], h_out[idx] = lon[done], lat[done], h[done]
        below = f >= 0.0
        move_a = below & ~bad
        move_b = ~below & ~bad
        fb = np.where(move_a & (side == 1), 0.5 * fb, fb)
        fa = np.where(move_b & (side == -1), 0.5 * fa, fa)
        a, fa = np.where(move_a, h, a), np.where(move_a, f, fa)
        b, fb = np.where(move_b, h, b), np.where(move_b, f, fb)
        side = np.where(move_a, 1, np.where(move_b, -1, side)).astype(np.int8)
        keep = ~done & ~bad
        active, a, b, fa, fb, side = (v[keep] for v in (active, a, b, fa, fb, side))
