"""Rendering raw pushbroom images through a rigorous model over a DEM and a ground texture.

For every image pixel (and ``supersample x supersample`` sub-pixel positions in it, which
integrate the detector footprint and the motion during the line time) the line of sight of the
detector is intersected with the terrain and the ground texture is sampled there. Rays are
intersected with the DEM by *safe stepping*: at a height ``dh`` above the terrain a ray that
descends ``c`` metres per metre and moves ``s`` metres horizontally cannot meet terrain of
slope at most ``S`` before it has travelled ``dh / (c + s S)``; stepping by that much never
jumps over a ridge. In the DEM cell under the ray the crossing with the bilinear surface is
solved exactly (a quadratic), else the steps stop within ``1e-4`` m of the terrain height.
The steps follow each ray's geodetic coordinates as quadratics in the distance along it,
interpolated across the line between the exact models of every 32nd detector: the point
found lies within a millimetre of the exact ray's
(:func:`~carto.framework.geometry.linescan.terrain_intersection.trace_model`; measured under
0.2 mm), a thousandth of the texture's finest detail.

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

import math
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.linescan.raycast import (
    HEIGHT_TOLERANCE_M,
    MAX_STEPS,
    QUADRATIC_STEP,
    RAY_SIZE,
    STATE_SIZE,
    CameraStates,
    DemGrid,
    GeoGrid,
    camera_states,
    dem_grid,
    geo_grid,
    grid_bilinear,
    interp_time,
    line_state,
    quadratic_table,
    state_ray,
)
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.terrain_intersection import (
    interpolated_quadratic,
    ray_quadratic,
    trace_model,
    trace_quadratic,
)
from carto.framework.geometry.linescan.terrain_tops import BLOCK_CELLS, block_maxima, segment_tops

FloatArray = NDArray[np.float64]

__all__ = ["HEIGHT_TOLERANCE_M", "MAX_STEPS", "render_band", "render_reflectance"]


class _RenderWindow(NamedTuple):
    """The pixels one kernel call renders: image lines ``line0 ... line0 + n_lines - 1`` and
    ``n_cols`` detectors from ``first_sample`` (0-based detector index), each integrated over
    ``supersample x supersample`` sub-pixel rays; detectors with odd index look along track by
    the extra tangent ``stagger_tan``."""

    line0: int
    n_lines: int
    n_cols: int
    first_sample: int
    stagger_tan: float
    supersample: int


class _SublineScratch(NamedTuple):
    """Per-row scratch space of :func:`_render_kernel`: the camera state of the sub-line
    (:data:`STATE_SIZE`), one ray (:data:`RAY_SIZE`), the quadratic models of the node rays
    of the even and the odd detectors (:func:`quadratic_table`) and the highest terrain
    under the rays between consecutive nodes (:func:`segment_tops`), the sums and counts
    of texture values per window column, and the rays to trace exactly (detector sample,
    window column; :func:`_add_exact_rays`)."""

    state: NDArray
    ray: NDArray
    even: NDArray
    odd: NDArray
    top_even: NDArray
    top_odd: NDArray
    acc: NDArray
    count: NDArray
    exact_s: NDArray
    exact_j: NDArray


# Not inlined, and called after the sub-line's loop: the rare rays next to a node ray that
# misses. Any call inside the loop, even one never taken, made the loop a fifth slower.
@numba.njit(cache=True, nogil=True)
def _add_exact_rays(
    window: _RenderWindow,
    cam: CameraStates,
    dem: DemGrid,
    tex: GeoGrid,
    w: _SublineScratch,
    n_exact: int,
) -> None:  # pragma: no cover - compiled
    """Add the texture values of the sub-line's rays listed in ``w.exact_s`` /
    ``w.exact_j`` (detector sample, window column), each traced on its exact ray
    (:func:`trace_quadratic` on its own quadratic model), to ``w.acc`` and ``w.count``."""
    for p in range(n_exact):
        s, j = w.exact_s[p], w.exact_j[p]
        odd = ((window.first_sample + j) % 2) == 1
        state_ray(s, window.stagger_tan if odd else 0.0, cam, w.state, w.ray)
        ray = (w.ray[0], w.ray[1], w.ray[2], w.ray[3], w.ray[4], w.ray[5])
        q = ray_quadratic(ray, cam.omega_c, dem.h_top_m, dem.h_bottom_m)
        lon, lat, _h = trace_quadratic(ray, cam.omega_c, q, dem)
        if np.isfinite(lon):
            v = grid_bilinear(tex.values, tex.x0_deg, tex.dx_deg, tex.y0_deg, tex.dy_deg, lon, lat)
            if np.isfinite(v):
                w.acc[j] += v
                w.count[j] += 1


# Not inlined: numba 0.68's parallel loop then loses the writes to arrays passed in a tuple.
# Divisions by the grids' steps become products (arcp) and multiply-adds fuse (contract).
@numba.njit(cache=True, nogil=True, fastmath={"arcp", "contract"})
def _render_subline(
    window: _RenderWindow,
    cam: CameraStates,
    dem: DemGrid,
    tex: GeoGrid,
    blocks: NDArray,
    w: _SublineScratch,
) -> None:  # pragma: no cover - compiled
    """Add the texture values of one sub-line's rays (camera state ``w.state``,
    :func:`line_state`) to ``w.acc`` and their number to ``w.count``, per window column:
    ``supersample`` rays per pixel across, each where its quadratic model, interpolated
    from the sub-line's exact node models, meets the DEM (:func:`trace_model`, from just
    above the highest terrain under its segment); next to a node ray that misses, where the
    exact ray meets it (:func:`_add_exact_rays`). Rays that miss the DEM or the texture add
    nothing. ``blocks``: the DEM's :func:`block_maxima`."""
    supersample = window.supersample
    inv = 1.0 / supersample
    first = window.first_sample + 0.5 * inv
    n_nodes = w.even.shape[0]
    quadratic_table(first, n_nodes, 0.0, cam, dem, w.state, w.ray, w.even)
    quadratic_table(first, n_nodes, window.stagger_tan, cam, dem, w.state, w.ray, w.odd)
    segment_tops(w.even, n_nodes, dem, blocks, BLOCK_CELLS, w.top_even)
    segment_tops(w.odd, n_nodes, dem, blocks, BLOCK_CELLS, w.top_odd)
    n_exact = 0
    for j in range(window.n_cols):
        k = window.first_sample + j
        table, tops = (w.odd, w.top_odd) if (k % 2) == 1 else (w.even, w.top_even)
        for b in range(supersample):
            s = k + (b + 0.5) * inv
            q = interpolated_quadratic(table, n_nodes, first, s)
            if np.isnan(q.d0_m + q.span_m + q.lon2 + q.lat2 + q.h2):
                w.exact_s[n_exact] = s
                w.exact_j[n_exact] = j
                n_exact += 1
                continue
            segment = min(max(math.floor((s - first) / QUADRATIC_STEP), 0), n_nodes - 2)
            lon, lat, _h = trace_model(q, dem, tops[segment])
            if not np.isfinite(lon):
                continue
            v = grid_bilinear(tex.values, tex.x0_deg, tex.dx_deg, tex.y0_deg, tex.dy_deg, lon, lat)
            if np.isfinite(v):
                w.acc[j] += v
                w.count[j] += 1
    if n_exact:
        _add_exact_rays(window, cam, dem, tex, w, n_exact)


@numba.njit(parallel=True, cache=True, nogil=True)
def _render_kernel(
    window: _RenderWindow, cam: CameraStates, dem: DemGrid, tex: GeoGrid, blocks: NDArray
) -> NDArray:  # pragma: no cover - compiled
    """Mean texture value of the ``supersample x supersample`` sub-pixel rays of every window
    pixel; NaN unless every ray meets the DEM and the texture. The camera state is
    interpolated once per sub-line, shared by the line's detectors, and so are the exact
    quadratic models of every :data:`QUADRATIC_STEP`-th ray."""
    image = np.full((window.n_lines, window.n_cols), np.nan, dtype=np.float32)
    supersample = window.supersample
    inv = 1.0 / supersample
    n_nodes = math.ceil((window.n_cols - inv) / QUADRATIC_STEP) + 2
    for i in numba.prange(window.n_lines):
        state = np.empty(STATE_SIZE)
        ray = np.empty(RAY_SIZE)
        even = np.empty((n_nodes, 11))
        odd = np.empty((n_nodes, 11))
        top_even = np.empty(n_nodes)
        top_odd = np.empty(n_nodes)
        acc = np.zeros(window.n_cols)
        count = np.zeros(window.n_cols, np.int64)
        exact_s = np.empty(window.n_cols * supersample)
        exact_j = np.empty(window.n_cols * supersample, np.int64)
        for a in range(supersample):
            line = window.line0 + i + (a + 0.5) * inv
            t = interp_time(line, cam.line_nodes, cam.t_nodes)
            if line_state(t, cam, state):
                scratch = _SublineScratch(
                    state, ray, even, odd, top_even, top_odd, acc, count, exact_s, exact_j
                )
                _render_subline(window, cam, dem, tex, blocks, scratch)
        for j in range(window.n_cols):
            if count[j] == supersample * supersample:
                image[i, j] = acc[j] / count[j]
    return image


def _stagger_tan(sensor: LineScanner, stagger: bool) -> float:
    """The extra along-track tangent of the odd-indexed detectors: those of the even array
    when ``stagger`` (the camera describes the odd array, or the even one: then the others
    look back by as much), else 0."""
    if not stagger:
        return 0.0
    tan = float(sensor.camera.stagger_tan)
    return -tan if sensor.camera.array == "even" else tan


def _texture_values(values: NDArray) -> NDArray[np.float32]:
    """A texture's values as the kernel reads them: C-contiguous float32 flagged read-only,
    a view of the simulator's float32 texture (copied only to convert; the kernel reads
    them in float64)."""
    view = np.ascontiguousarray(values, dtype=np.float32).view()
    view.flags.writeable = False
    return view


def _check_supersample(supersample: int) -> None:
    """InputError unless at least one sub-pixel ray per pixel side."""
    if supersample < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")


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
            ``transform``, ``crs``), read as float32.
        supersample: sub-pixel rays per pixel side (the detector footprint and the motion
            during the line time are integrated as a box).
        stagger: render odd-indexed detectors from the even array (raw Cartosat data).

    Pixels whose rays leave the DEM or the texture are NaN.
    """
    _check_supersample(supersample)
    dem_search = dem_grid(dem)
    tex_values = getattr(texture, "reflectance", None)
    if tex_values is None:
        tex_values = texture.values
    grid = geo_grid(tex_values, texture.transform, getattr(texture, "crs", "EPSG:4326"), "texture")
    tex = grid._replace(values=_texture_values(grid.values))
    cam = camera_states(sensor)
    n_lines, n_cols = sensor.image_shape
    window = _RenderWindow(
        0, n_lines, n_cols, sensor.first_sample, _stagger_tan(sensor, stagger), supersample
    )
    return _render_kernel(window, cam, dem_search, tex, block_maxima(dem_search.heights))


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
    _check_supersample(supersample)
    dem_search = dem_grid(dem, h_range, max_slope)
    t = texture.transform
    tex = GeoGrid(
        _texture_values(texture.reflectance), float(t.c), float(t.a), float(t.f), float(t.e)
    )
    cam = camera_states(sensor)
    first, last = lines
    s0, s1 = samples or (0, sensor.image_shape[1])
    window = _RenderWindow(
        int(first),
        int(last - first),
        int(s1 - s0),
        sensor.first_sample + int(s0),
        _stagger_tan(sensor, stagger),
        supersample,
    )
    return _render_kernel(window, cam, dem_search, tex, block_maxima(dem_search.heights))
