"""Rendering raw pushbroom images through a rigorous model over a DEM and a ground texture.

For every image pixel (and ``supersample x supersample`` sub-pixel positions in it, which
integrate the detector footprint and the motion during the line time) the line of sight of the
detector is intersected with the terrain and the ground texture is sampled there. Rays are
intersected with the DEM by *safe stepping*: at a height ``dh`` above the terrain a ray that
descends ``c`` metres per metre and moves ``s`` metres horizontally cannot meet terrain of
slope at most ``S`` before it has travelled ``dh / (c + s S)``; stepping by that much never
jumps over a ridge, and it converges like Newton's method on gentle terrain. Iterations stop
when the ray is within ``1e-4`` m of the terrain height.

The camera state comes from the sensor's exact interpolation table (see
:mod:`carto.framework.geometry.linescan.scanner`); with ``stagger=True`` detectors with odd
0-based index
(the even array) look along track by the camera's ``stagger_tan`` more than the others, as the raw
Cartosat images are recorded.

DEMs and textures are regular geographic grids (EPSG:4326, north up, pixel-is-area): the
simulator generates them so; :func:`locate_pixels` and :func:`render_reflectance` raise
:class:`InputError` for anything else.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.linescan.raycast import (
    camera_ray,
    geographic_grid,
    grid_bilinear,
    interp_time,
    max_terrain_slope,
    ray_dem,
    sensor_arrays,
)
from carto.framework.geometry.linescan.scanner import LineScanner

FloatArray = NDArray[np.float64]

_A = frames.WGS84_A_M
_B = frames.WGS84_B_M
_E2 = frames.WGS84_E2
_EP2 = (_A * _A - _B * _B) / (_B * _B)
HEIGHT_TOLERANCE_M = 1e-4
MAX_STEPS = 4000


@numba.njit(parallel=True, cache=True, nogil=True)
def _render_kernel(
    line0: int,
    n_lines: int,
    n_cols: int,
    first_sample: int,
    stagger_tan: float,
    supersample: int,
    line_nodes: NDArray,
    t_nodes: NDArray,
    node0: float,
    spacing: float,
    pos: NDArray,
    rot: NDArray,
    beta: NDArray,
    omega_c: NDArray,
    tan_x: NDArray,
    tan_y: NDArray,
    half: float,
    dem: NDArray,
    x0: float,
    dx: float,
    y0: float,
    dy: float,
    h_top: float,
    h_bottom: float,
    max_slope: float,
    tex: NDArray,
    tx0: float,
    tdx: float,
    ty0: float,
    tdy: float,
) -> NDArray:  # pragma: no cover - compiled
    image = np.full((n_lines, n_cols), np.nan, dtype=np.float32)
    inv = 1.0 / supersample
    for i in numba.prange(n_lines):
        ray = np.empty(6)
        for j in range(n_cols):
            k = first_sample + j
            stagger = stagger_tan if (k % 2) == 1 else 0.0
            acc = 0.0
            count = 0
            for a in range(supersample):
                line = line0 + i + (a + 0.5) * inv
                t = interp_time(line, line_nodes, t_nodes)
                for b in range(supersample):
                    s = k + (b + 0.5) * inv
                    if not camera_ray(
                        t, s, stagger, node0, spacing, pos, rot, beta, tan_x, tan_y, half, ray
                    ):
                        continue
                    lon, lat, _h = ray_dem(
                        ray[0],
                        ray[1],
                        ray[2],
                        ray[3],
                        ray[4],
                        ray[5],
                        dem,
                        x0,
                        dx,
                        y0,
                        dy,
                        h_top,
                        h_bottom,
                        max_slope,
                        omega_c,
                    )
                    if not np.isfinite(lon):
                        continue
                    v = grid_bilinear(tex, tx0, tdx, ty0, tdy, lon, lat)
                    if np.isfinite(v):
                        acc += v
                        count += 1
            if count == supersample * supersample:
                image[i, j] = acc / count
    return image


def render_reflectance(
    sensor: LineScanner,
    dem: object,
    texture: object,
    *,
    supersample: int = 2,
    stagger: bool = True,
) -> NDArray[np.float32]:
    """Render the sensor's image (its window) as ground reflectance, float32 ``(lines, cols)``.

    Args:
        sensor: the **true** model of the image (its camera describes the odd array).
        dem: terrain with ellipsoidal heights on a geographic grid (``heights``,
            ``transform``, ``crs``).
        texture: reflectance on a geographic grid (attributes ``reflectance`` or ``values``,
            ``transform``, ``crs``).
        supersample: sub-pixel rays per pixel side (the detector footprint and the motion
            during the line time are integrated as a box).
        stagger: render odd-indexed detectors from the even array (raw Cartosat data).

    Pixels whose rays leave the DEM or the texture are NaN.
    """
    if supersample < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")
    grid, x0, dx, y0, dy = geographic_grid(dem.heights, dem.transform, dem.crs, "DEM")
    tex_values = getattr(texture, "reflectance", None)
    if tex_values is None:
        tex_values = texture.values
    tex, tx0, tdx, ty0, tdy = geographic_grid(
        tex_values, texture.transform, getattr(texture, "crs", "EPSG:4326"), "texture"
    )
    arr = sensor_arrays(sensor)
    n_lines, n_cols = sensor.image_shape
    lat_c = y0 + dy * grid.shape[0] / 2
    stagger_tan = sensor.camera.stagger_tan if stagger else 0.0
    if sensor.camera.array == "even":
        stagger_tan = -stagger_tan if stagger else 0.0
    return _render_kernel(
        0,
        n_lines,
        n_cols,
        sensor.first_sample,
        stagger_tan,
        supersample,
        arr["line_nodes"],
        arr["t_nodes"],
        arr["node0"],
        arr["spacing"],
        arr["pos"],
        arr["rot"],
        arr["beta"],
        arr["omega_c"],
        arr["tan_x"],
        arr["tan_y"],
        arr["half"],
        grid,
        x0,
        dx,
        y0,
        dy,
        float(np.nanmax(grid)) + 1.0,
        float(np.nanmin(grid)) - 1.0,
        max_terrain_slope(grid, dx, dy, lat_c),
        tex,
        tx0,
        tdx,
        ty0,
        tdy,
    )


def render_band(
    sensor: LineScanner,
    lines: tuple[int, int],
    dem: object,
    texture: object,
    *,
    samples: tuple[int, int] | None = None,
    h_range: tuple[float, float],
    max_slope: float,
    supersample: int = 2,
    stagger: bool = True,
) -> NDArray[np.float32]:
    """Lines ``[first, last)`` (and image columns ``samples``, default all) of
    :func:`render_reflectance`, from windows of the DEM and the texture that hold every ray
    of those pixels, float32 ``(last - first, cols)``.

    The ray search starts and ends at the heights ``h_range`` (widened by 1 m) and steps
    safely for slopes up to ``max_slope`` (rise/run) whatever the windows, so a band gives
    the pixels of the whole image rendered at once.
    """
    if supersample < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")
    grid, x0, dx, y0, dy = geographic_grid(dem.heights, dem.transform, dem.crs, "DEM")
    t = texture.transform
    tex, tx0, tdx, ty0, tdy = np.ascontiguousarray(texture.reflectance), t.c, t.a, t.f, t.e
    arr = sensor_arrays(sensor)
    stagger_tan = sensor.camera.stagger_tan if stagger else 0.0
    if sensor.camera.array == "even":
        stagger_tan = -stagger_tan if stagger else 0.0
    first, last = lines
    s0, s1 = samples or (0, sensor.image_shape[1])
    return _render_kernel(
        int(first),
        int(last - first),
        int(s1 - s0),
        sensor.first_sample + int(s0),
        stagger_tan,
        supersample,
        arr["line_nodes"],
        arr["t_nodes"],
        arr["node0"],
        arr["spacing"],
        arr["pos"],
        arr["rot"],
        arr["beta"],
        arr["omega_c"],
        arr["tan_x"],
        arr["tan_y"],
        arr["half"],
        grid,
        x0,
        dx,
        y0,
        dy,
        float(h_range[1]) + 1.0,
        float(h_range[0]) - 1.0,
        float(max_slope),
        tex,
        tx0,
        tdx,
        ty0,
        tdy,
    )
