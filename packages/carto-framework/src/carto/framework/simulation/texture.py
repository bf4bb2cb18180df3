"""Ground texture for the scene simulator, with known truth.

* :func:`make_texture`: a :class:`Texture`, the ground reflectance in [0, 1] on a grid finer
  than the DEM's: agricultural parcels, field boundaries, roads, natural cover, multi-scale
  fine texture, Lambertian terrain shading, and nearly uniform water or sand where the DEM is
  exactly flat.
* :func:`add_point_targets` adds bright Gaussian blobs centred on given ground points.
* :class:`GroundTexture`: the same reflectance computed window by window over a windowed
  terrain, with the same value at a pixel whatever the window (the simulator's texture of a
  whole scene never exists at once); it paints point targets and blurs per window too.

The grids, their conventions (geographic WGS84, north-up, pixel-is-area, seeded) and the DEMs
(:func:`~carto.framework.simulation.terrain.make_terrain`,
:func:`~carto.framework.simulation.terrain.terrain_from_dem`) are those of
:mod:`carto.framework.simulation.terrain`.

Texture synthesis (:func:`make_texture`)
    Reflectance ``R = clip(shade * land, 0, 1)``, replaced by a nearly constant value where the
    ground is uniform. ``land`` mixes *fields* (seeded Voronoi parcels of irregular brick
    lattices whose orientation and size, 60-140 m x 30-70 m, change every ~2.5 km; per-parcel
    brightness 0.12-0.40 for crops, soil, fallow; 1-1.5 m darker boundaries; 10 % multi-scale
    texture) and *natural cover* (patches of darker vegetation and brighter soil 20-200 m
    across, 0.14-0.24, bare rock 0.28 on slopes steeper than 20-32 deg; 20 % multi-scale
    texture), weighted by a land-use field: fields on slopes below 4 deg, none above 12 deg,
    with irregular gaps. Roads (5-10 m, dark asphalt or bright concrete) and tracks (2.5-4 m,
    bright) run as gently curving lines about every 1.5 km. ``shade`` is Lambertian with 20 %
    sky light, ``0.2 + 0.8 max(cos i, 0) / sin(sun elevation)`` (1 on flat ground; cast
    shadows are not modelled), computed on a grid of 4 texture pixels from the DEM's bilinear
    surface. The multi-scale texture is a Laplacian-pyramid sum of white noise from 1 to 64
    texture pixels, each level hashed white noise (:func:`~carto.framework.simulation.fields.
    pyramid_noise`). Parcels are the nearest lattice point of the zones around a pixel
    (:mod:`carto.framework.simulation.cover`); the land-use, natural-cover, water and tone
    fields are :class:`~carto.framework.simulation.fields.LatticeField` windows. Uniform ground
    (exactly flat DEM areas by default) is water (0.05-0.09) or, where a smooth field is high
    (about a quarter of it), sand (0.30-0.40) with wide gradual transitions, plus noise of
    standard deviation 0.003, with a shoreline about 2 texture pixels wide.

    Statistics on 2 km x 2 km at 1 m (DEM and texture seed 1; ``std 9x9``: median local
    standard deviation in 9 x 9 pixel windows, 10th percentile in brackets; ``blocks 33 / 129``:
    standard deviation of the means of 33 x 33 and 129 x 129 pixel blocks, i.e. contrast at the
    scales of parcels and of land use; all over land unless marked uniform)::

        preset        mean   std    std 9x9          std 9x9 uniform   blocks 33 / 129
        flat-coastal  0.22   0.076  0.019 (0.009)    0.0017            0.057 / 0.029
        plains        0.22   0.074  0.018 (0.010)    0.0017            0.056 / 0.030
        mixed         0.22   0.075  0.019 (0.010)    0.0017            0.057 / 0.033
        hilly         0.19   0.066  0.023 (0.014)    -                 0.051 / 0.033
        mountains     0.17   0.053  0.022 (0.014)    -                 0.039 / 0.027

    Uniform ground has 1/10 of the local contrast of the least textured land.

The table was measured with the former whole-grid synthesis; the tests bound the same
statistics. Memory and speed (2 cores): about 0.01 microseconds per texture pixel (compiled
kernels); a window is computed in strips of 2e6 pixels (about 30 MB of intermediates) besides
its result, from tiles of 256 x 256 pixels of which the last 320 used are kept (about 100 MB,
:class:`~carto.framework.simulation.tile_cache.TileCache`: overlapping windows, such as
successive bands of an image, compute their common pixels once). A texture with targets or
blur keeps as many tiles of its own values, so it paints and blurs them once too. While a
scene is simulated every tile is also written to a scratch file and read back rather than
computed again, since every image and the true ortho see the same ground
(:meth:`GroundTexture.spill_tiles`). The fields' lattices take at most ~2 x 16 MB + 2 x 4 MB
whatever the area.
"""

from __future__ import annotations

import copy
import math
from typing import TYPE_CHECKING, Any, TypedDict, Unpack

import attrs
import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import FloatArray, as_float_arrays
from carto.framework.errors import InputError
from carto.framework.raster.dem import DEM, to_affine
from carto.framework.raster.grid_sampling import bilinear_sample
from carto.framework.simulation.cover import Parcels, make_roads, paint_roads
from carto.framework.simulation.fields import LatticeField, gaussian_blur, pyramid_noise
from carto.framework.simulation.point_targets import paint_targets
from carto.framework.simulation.terrain import (
    MAX_GRID_PX,
    MAX_TILED_GRID_PX,
    MAX_TILED_GRID_SIDE_PX,
    Bounds,
    GridTerrain,
    check_posting,
    check_seed,
    geographic_grid,
    is_north_up_lonlat,
    radii_m,
)
from carto.framework.simulation.tile_cache import TileCache, TileSpill

if TYPE_CHECKING:
    import pyproj
    from affine import Affine

Float32Array = NDArray[np.float32]
BoolArray = NDArray[np.bool_]

_STRIP_PX = 2_000_000  # texture pixels computed at a time
_TILE = 256  # texture pixels a side of the cached tiles
_CACHED_TILES = 320  # tiles kept (about 100 MB) for the overlaps of successive windows
_COARSE = 4  # texture pixels per node of the coarse texture grid (shading, land use)
_AMBIENT = 0.2  # sky-light share of the illumination of flat ground
_SERIAL_PX = 65_536  # strips smaller than this are computed on one thread


def _check_lonlat_dem(dem: Any, what: str) -> DEM:
    if not isinstance(dem, DEM):
        raise InputError(f"{what}: expected a DEM, got {type(dem).__name__}")
    if not is_north_up_lonlat(dem):
        raise InputError(
            f"{what}: DEM {dem.name} must be on a north-up EPSG:4326 grid "
            f"(crs {dem.crs.name}); resample it with terrain_from_dem first"
        )
    if not np.isfinite(dem.heights).all():
        raise InputError(f"{what}: DEM {dem.name} has nodata (NaN) heights; fill them first")
    return dem


# ----------------------------------------------------------------------------- texture
def _readonly_f32(value: ArrayLike) -> Float32Array:
    array = np.asarray(value, dtype=np.float32)
    if array.flags.writeable or not array.flags.c_contiguous:
        array = np.array(array, dtype=np.float32, order="C")
        array.flags.writeable = False
    return array


def _readonly_bool(value: ArrayLike) -> BoolArray:
    array = np.asarray(value, dtype=np.bool_)
    if array.flags.writeable:
        array = array.copy()
        array.flags.writeable = False
    return array


@attrs.frozen(eq=False)
class Texture:
    """Ground reflectance on a north-up EPSG:4326 grid (pixel-is-area, like :class:`DEM`).

    Attributes:
        reflectance: ``(rows, cols)`` float32 reflectance in [0, 1], read-only.
        transform: affine transform of pixel corners to lon/lat degrees.
        uniform_mask: ``(rows, cols)`` bool, True on nearly uniform ground (water, sand),
            read-only.
        posting_m: ground spacing at the centre latitude, metres.
    """

    reflectance: Float32Array = attrs.field(converter=_readonly_f32)
    transform: Affine = attrs.field(converter=to_affine)
    uniform_mask: BoolArray = attrs.field(converter=_readonly_bool)
    posting_m: float = attrs.field(converter=float)

    def __attrs_post_init__(self) -> None:
        if self.reflectance.ndim != 2 or min(self.reflectance.shape) < 2:
            raise InputError(
                f"texture: reflectance must be a 2-D grid of at least 2 x 2, "
                f"got shape {self.reflectance.shape}"
            )
        if self.uniform_mask.shape != self.reflectance.shape:
            raise InputError(
                f"texture: uniform_mask shape {self.uniform_mask.shape} differs from "
                f"reflectance shape {self.reflectance.shape}"
            )
        t = self.transform
        if t.b != 0.0 or t.d != 0.0 or t.a <= 0.0 or t.e >= 0.0:
            raise InputError(f"texture: transform {tuple(t)[:6]} is not north-up lon/lat")

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the grid."""
        return self.reflectance.shape  # type: ignore[return-value]

    @property
    def crs(self) -> pyproj.CRS:
        """The grid's CRS: always WGS84 geographic ``EPSG:4326`` (like :attr:`DEM.crs`)."""
        import pyproj

        return pyproj.CRS.from_epsg(4326)

    @property
    def bounds_lonlat(self) -> Bounds:
        """``(west, south, east, north)`` degrees of the span of the pixel centres."""
        n_rows, n_cols = self.shape
        t = self.transform
        west, north = t.c + 0.5 * t.a, t.f + 0.5 * t.e
        return (west, north + (n_rows - 1) * t.e, west + (n_cols - 1) * t.a, north)

    @property
    def uniform_fraction(self) -> float:
        """Fraction of the pixels on uniform ground (water, sand)."""
        return float(np.count_nonzero(self.uniform_mask)) / self.uniform_mask.size

    def lonlat_to_pixel(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Fractional centre indices ``(row, col)`` (0 = centre of the first pixel)."""
        lon, lat = as_float_arrays(lon_deg, lat_deg)
        t = self.transform
        return (lat - t.f) / t.e - 0.5, (lon - t.c) / t.a - 0.5

    def value(self, lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
        """Bilinear reflectance at WGS84 lon/lat (arrays broadcast), float64; NaN outside the
        span of the pixel centres."""
        row, col = self.lonlat_to_pixel(lon_deg, lat_deg)
        return bilinear_sample(self.reflectance, row, col)


def _smoothstep(edge0: float, edge1: float, x: Float32Array) -> Float32Array:
    t = np.clip((x - np.float32(edge0)) * np.float32(1.0 / (edge1 - edge0)), 0.0, 1.0)
    return t * t * (np.float32(3.0) - np.float32(2.0) * t)


def _linear_window(
    grid: FloatArray,
    first: tuple[int, int],
    pos_r: FloatArray,
    pos_c: FloatArray,
    n_nodes: tuple[int, int],
    extrapolate: bool,
) -> FloatArray:
    """Bilinear values of a grid (given by its window ``grid`` starting at node ``first``) at
    fractional node positions ``pos_r x pos_c`` of the whole grid of ``n_nodes``: clamped
    (or extended linearly) at the whole grid's edges, columns first, in a fixed order."""
    out = []
    for pos, n in zip((pos_r, pos_c), n_nodes, strict=True):
        p = pos if extrapolate else np.clip(pos, 0.0, n - 1.0)
        base = np.clip(np.floor(p).astype(np.intp), 0, max(n - 2, 0))
        out.append((base, p - base, np.minimum(base + 1, n - 1)))
    (br, fr, br1), (bc, fc, bc1) = out
    cols, cols1 = bc - first[1], bc1 - first[1]
    along = (1.0 - fc) * grid[:, cols] + fc * grid[:, cols1]
    rows, rows1 = br - first[0], br1 - first[0]
    return (1.0 - fr)[:, None] * along[rows] + fr[:, None] * along[rows1]


@numba.njit(cache=True, nogil=True)
def _clip01(v: np.float32) -> np.float32:  # pragma: no cover - compiled
    """``v`` clipped to [0, 1] as ``np.clip`` does (NaN kept)."""
    return np.float32(0.0) if v < 0.0 else (np.float32(1.0) if v > 1.0 else v)


_MixJob = tuple[
    tuple[int, int, int, int],
    NDArray,
    NDArray,
    NDArray,
    tuple[NDArray, NDArray, np.float32, bool],
]
"""A strip's mixing: ``(first, coarse, noise, land, extra)`` (see :func:`_mix_rows`)."""


@numba.njit(cache=True, nogil=True)
def _mix_rows(stage: int, job: _MixJob, rows: tuple[int, int]) -> None:  # pragma: no cover
    """Rows ``rows`` of a strip (``job = (first, coarse, noise, land, extra)``) from
    ``first = (r0, c0, a0, b0)`` (its first pixel and coarse node), in place in ``land``:
    stage 0 textures and blends the parcels (``land``, ``extra = (outline, mask,
    outline_darkening, has_uniform)``) with natural cover; stage 1 (after the roads) shades,
    blends uniform ground, clips and sets the mask. The coarse channels are linear between
    the nodes (pixel ``r`` at node ``r / 4 + 1``, columns first, rounded to float32); float32
    arithmetic in the order of the former whole-array steps."""
    first, coarse, noise, land, extra = job
    r0, c0, a0, b0 = first
    outline, mask, darken, has_uniform = extra
    channels = np.array([1, 2]) if stage == 0 else np.array([0, 3, 4] if has_uniform else [0])
    n_cols = land.shape[1]
    cols, fc = np.empty(n_cols, np.int64), np.empty(n_cols)
    for j in range(n_cols):
        cols[j], fc[j] = (c0 + j) // 4 + 1 - b0, ((c0 + j) % 4) * 0.25
    along = np.empty((2, channels.size, n_cols))  # coarse rows m, m + 1 along the columns
    ch = np.empty((channels.size, n_cols), np.float32)
    one, done = np.float32(1.0), -1
    for i in range(rows[0], rows[1]):
        m, fr = (r0 + i) // 4 + 1 - a0, ((r0 + i) % 4) * 0.25
        for k in range(channels.size if m != done else 0):
            for d in range(2):
                node = coarse[channels[k], m + d]
                for j in range(n_cols):
                    along[d, k, j] = (1.0 - fc[j]) * node[cols[j]] + fc[j] * node[cols[j] + 1]
        done = m
        for k in range(channels.size):
            for j in range(n_cols):
                ch[k, j] = np.float32((1.0 - fr) * along[0, k, j] + fr * along[1, k, j])
        z, v = noise[i], land[i]
        if stage == 0:  # ch: field weight, natural cover
            for j in range(n_cols):
                natural = ch[1, j] * (one + np.float32(0.20) * z[j])
                w = v[j] * (one + np.float32(0.10) * z[j]) * (one - darken * outline[i, j])
                v[j] = (w - natural) * ch[0, j] + natural
            continue
        for j in range(n_cols):  # ch: shade, uniform weight, pre-multiplied uniform level
            v[j] *= ch[0, j]
        for j in range(n_cols if has_uniform else 0):
            floor = np.float32(1e-6)
            weight = ch[1, j] if (ch[1, j] > floor or ch[1, j] != ch[1, j]) else floor
            level = ch[2, j] / weight + np.float32(0.003) * z[j]
            u = _clip01((ch[1, j] - np.float32(0.5)) * np.float32(4.0) + np.float32(0.5))
            v[j] += (level - v[j]) * u
            mask[i, j] = u >= 0.5
        for j in range(n_cols):
            v[j] = _clip01(v[j])


@numba.njit(parallel=True, cache=True, nogil=True)
def _mix_chunks(
    stage: int,
    first: tuple[int, int, int, int],
    coarse: NDArray,
    noise: NDArray,
    land: NDArray,
    extra: tuple[NDArray, NDArray, np.float32, bool],
) -> None:  # pragma: no cover - compiled
    """:func:`_mix_rows` by chunks of 64 rows, one thread each (the job's parts as
    arguments: numba's parallel loop takes no tuple nested in a tuple)."""
    n_rows = land.shape[0]
    for k in numba.prange(-(-n_rows // 64)):
        job = (first, coarse, noise, land, extra)
        _mix_rows(stage, job, (64 * k, min(64 * k + 64, n_rows)))


def _mix(stage: int, job: _MixJob) -> None:
    """:func:`_mix_rows` over the whole strip (on one thread when it is small)."""
    land = job[3]
    if land.size >= _SERIAL_PX:
        _mix_chunks(stage, *job)
    else:
        _mix_rows(stage, job, (0, land.shape[0]))


class GroundTexture:
    """The procedural ground reflectance of a terrain, computed window by window on its grid
    (see the module docstring): the same value at a pixel whatever the window, so a scene's
    texture never needs to exist whole.

    Args:
        terrain: a windowed terrain (:class:`~carto.framework.simulation.terrain.ProceduralTerrain`
            or :class:`~carto.framework.simulation.terrain.GridTerrain`) on a north-up
            EPSG:4326 grid.
        posting_m, seed, sun_elevation_deg, sun_azimuth_deg, uniform_mask: as
            :func:`make_texture`.
        targets: point targets ``(lon_deg, lat_deg)`` painted as :func:`add_point_targets`
            does, with ``target_radius_m`` and ``target_contrast``.
        blur_sigma_px: Gaussian blur (texture pixels) applied last (0: none).
    """

    def __init__(
        self,
        terrain: Any,
        posting_m: float,
        seed: int,
        *,
        sun_elevation_deg: float = 55.0,
        sun_azimuth_deg: float = 135.0,
        uniform_mask: ArrayLike | None = None,
        max_px: int = MAX_TILED_GRID_PX,
    ) -> None:
        posting = check_posting(posting_m)
        rng = np.random.default_rng(check_seed(seed))
        if not (0.0 < float(sun_elevation_deg) <= 90.0):
            raise InputError(f"sun_elevation_deg must be in (0, 90], got {sun_elevation_deg!r}")
        if not math.isfinite(float(sun_azimuth_deg)):
            raise InputError(f"sun_azimuth_deg must be finite, got {sun_azimuth_deg!r}")
        if uniform_mask is not None:
            uniform_mask = np.asarray(uniform_mask)
            if uniform_mask.shape != terrain.shape or uniform_mask.dtype != np.bool_:
                raise InputError(
                    f"uniform_mask must be a bool array of the DEM's shape {terrain.shape}, "
                    f"got {uniform_mask.dtype} {uniform_mask.shape}"
                )
        west, south, east, north = terrain.bounds_lonlat
        if west == east or south == north:
            raise InputError("make_texture: the DEM must have at least 2 x 2 pixels")
        self.terrain = terrain
        self.posting_m = posting
        self.transform, self.shape = geographic_grid(
            (west, south, east, north), posting, max_side=MAX_TILED_GRID_SIDE_PX, max_px=max_px
        )
        n_rows, n_cols = self.shape
        self._coarse_shape = (-(-(n_rows - 1) // _COARSE) + 3, -(-(n_cols - 1) // _COARSE) + 3)
        self._sun = (float(sun_elevation_deg), float(sun_azimuth_deg))
        self._mask = uniform_mask
        t = terrain.transform
        dem_posting = math.radians(-t.e) * radii_m(0.5 * (south + north))[0]
        c_post = _COARSE * posting
        fine = {"max_nodes": 2048}
        self._land_use = LatticeField(rng, self._coarse_shape, c_post, [(3.6, 600.0, 1.0)], **fine)
        self._patches = LatticeField(rng, self._coarse_shape, c_post, [(3.0, 150.0, 1.0)], **fine)
        self._water = LatticeField(rng, terrain.shape, dem_posting, [(6.0, 4000.0, 1.0)])
        self._level = LatticeField(rng, terrain.shape, dem_posting, [(6.0, 2000.0, 1.0)])
        self._parcels = Parcels(int(rng.integers(2**31)), posting)
        self._roads = make_roads(np.random.default_rng([int(seed), 7]), self.shape, posting)
        self._noise_key = int(rng.integers(2**62))
        self._tiles = TileCache(self.shape, tile=_TILE, max_tiles=_CACHED_TILES)
        self._finals: TileCache | None = None  # with targets or blur: their tiles
        self.targets: tuple[FloatArray, FloatArray] | None = None
        self.target_radius_m = 0.0
        self.target_contrast = 0.0
        self.blur_sigma_px = 0.0

    def with_targets(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, radius_m: float, contrast: float
    ) -> GroundTexture:
        """This texture with point targets (a shallow copy sharing the caches)."""
        other = copy.copy(self)
        lon, lat = as_float_arrays(lon_deg, lat_deg)
        other.targets = (lon.ravel(), lat.ravel())
        other.target_radius_m, other.target_contrast = float(radius_m), float(contrast)
        other._finals = TileCache(self.shape, tile=_TILE, max_tiles=_CACHED_TILES)
        return other

    def blurred(self, sigma_px: float) -> GroundTexture:
        """This texture convolved with a Gaussian of ``sigma_px`` texture pixels."""
        other = copy.copy(self)
        other.blur_sigma_px = float(sigma_px)
        other._finals = TileCache(self.shape, tile=_TILE, max_tiles=_CACHED_TILES)
        return other

    def spill_tiles(self, spill: TileSpill | None) -> None:
        """From now on write the tiles computed to ``spill`` and read evicted ones back from
        it, rather than computing them again (None: stop): the tiles of this texture's
        values (with its targets and blur), or of the texture shared with its copies when it
        has neither."""
        (self._tiles if self._finals is None else self._finals).spill = spill

    # ------------------------------------------------------------------ windows
    def window(self, r0: int, r1: int, c0: int, c1: int) -> tuple[Float32Array, BoolArray]:
        """Reflectance (float32) and uniform-ground mask at pixels ``[r0, r1) x [c0, c1)``
        (clipped to the grid)."""
        n_rows, n_cols = self.shape
        r0, r1, c0, c1 = max(r0, 0), min(r1, n_rows), max(c0, 0), min(c1, n_cols)
        if self._finals is None:
            return self._base(r0, r1, c0, c1)
        values, mask = self._finals.window(self._marked, r0, r1, c0, c1)
        return values, mask

    def _marked(self, r0: int, r1: int, c0: int, c1: int) -> tuple[Float32Array, BoolArray]:
        """:meth:`window` computed: the texture around the window, its targets painted and
        the blur applied there (the same values whatever the window)."""
        n_rows, n_cols = self.shape
        blur_r = math.ceil(4.0 * self.blur_sigma_px) + 1 if self.blur_sigma_px > 0 else 0
        halo, chosen = blur_r, None
        if self.targets is not None and self.targets[0].size:
            chosen, reach = self._targets_near(r0, r1, c0, c1, blur_r)
            if chosen.size:
                halo = 2 * reach
        if halo == 0:
            return self._base(r0, r1, c0, c1)
        e0, e1 = max(r0 - halo, 0), min(r1 + halo, n_rows)
        f0, f1 = max(c0 - halo, 0), min(c1 + halo, n_cols)
        values, mask = self._base(e0, e1, f0, f1)
        if chosen is not None and chosen.size:
            paint_targets(
                values,
                (e0, f0),
                self.transform,
                self.targets[0][chosen],
                self.targets[1][chosen],
                np.full(chosen.size, self.target_radius_m),
                np.full(chosen.size, self.target_contrast),
            )
        if blur_r:
            values = gaussian_blur(values, self.blur_sigma_px)
        s = np.s_[r0 - e0 : r1 - e0, c0 - f0 : c1 - f0]
        return np.ascontiguousarray(values[s]), np.ascontiguousarray(mask[s])

    def _targets_near(
        self, r0: int, r1: int, c0: int, c1: int, blur_r: int
    ) -> tuple[NDArray[np.intp], int]:
        lon, lat = self.targets  # type: ignore[misc]
        t = self.transform
        rows = (lat - t.f) / t.e - 0.5
        cols = (lon - t.c) / t.a - 0.5
        m_m = radii_m(float(np.mean(lat)))[0]
        half = math.ceil(5.5 * self.target_radius_m / (math.radians(-t.e) * m_m)) + 2
        reach = 2 * half + blur_r + 2
        near = (rows > r0 - reach) & (rows < r1 + reach) & (cols > c0 - reach) & (cols < c1 + reach)
        return np.flatnonzero(near), reach

    def _base(self, r0: int, r1: int, c0: int, c1: int) -> tuple[Float32Array, BoolArray]:
        """The texture before targets and blur, through the cache of tiles."""
        values, mask = self._tiles.window(self._strips, r0, r1, c0, c1)
        return values, mask

    def _strips(self, r0: int, r1: int, c0: int, c1: int) -> tuple[Float32Array, BoolArray]:
        step = max(16, _STRIP_PX // max(c1 - c0, 1))
        if 0 < r1 - r0 <= step:  # one strip
            return self._strip(r0, r1, c0, c1)
        values = np.empty((r1 - r0, c1 - c0), np.float32)
        mask = np.empty((r1 - r0, c1 - c0), np.bool_)
        for a in range(r0, r1, step):
            b = min(a + step, r1)
            values[a - r0 : b - r0], mask[a - r0 : b - r0] = self._strip(a, b, c0, c1)
        return values, mask

    def _coarse(self, a0: int, a1: int, b0: int, b1: int) -> tuple[list[Float32Array], bool]:
        """Shading, field weight, natural cover, uniform weight and the pre-multiplied uniform
        reflectance at coarse nodes ``[a0, a1) x [b0, b1)``; False when no uniform ground."""
        import cv2
        from scipy import ndimage

        t = self.transform
        lon0, lat0 = t.c + 0.5 * t.a, t.f + 0.5 * t.e
        # one node of halo for the gradient
        lon_c = lon0 + t.a * _COARSE * (np.arange(b0 - 1, b1 + 1) - 1.0)
        lat_c = lat0 + t.e * _COARSE * (np.arange(a0 - 1, a1 + 1) - 1.0)
        d = self.terrain.transform
        n_dem = self.terrain.shape
        rows_f, cols_f = (lat_c - d.f) / d.e - 0.5, (lon_c - d.c) / d.a - 0.5
        pad = 7  # nodes: bilinear (1), the uniform mask (2) and its blur (4)
        w0 = max(int(np.floor(rows_f.min())) - pad, 0)
        w1 = min(int(np.ceil(rows_f.max())) + pad + 2, n_dem[0])
        v0 = max(int(np.floor(cols_f.min())) - pad, 0)
        v1 = min(int(np.ceil(cols_f.max())) + pad + 2, n_dem[1])
        dem = self.terrain.window(w0, w1, v0, v1)
        heights = _linear_window(dem, (w0, v0), rows_f, cols_f, n_dem, True)
        dlon, dlat = abs(t.a) * _COARSE, abs(t.e) * _COARSE
        radii = np.array([radii_m(v) for v in lat_c])
        dx_m = np.radians(dlon) * radii[:, 1] * np.cos(np.radians(lat_c))
        dy_m = np.radians(dlat) * radii[:, 0]
        d_row, d_col = np.gradient(heights)
        hx = (d_col / dx_m[:, None]).astype(np.float32)[1:-1, 1:-1]
        hy = (-d_row / dy_m[:, None]).astype(np.float32)[1:-1, 1:-1]
        el, az = (math.radians(v) for v in self._sun)
        se, sn, su = math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)
        norm = np.sqrt(np.float32(1.0) + hx * hx + hy * hy)
        cos_i = (np.float32(su) - np.float32(se) * hx - np.float32(sn) * hy) / norm
        shade = np.float32(_AMBIENT) + np.float32((1.0 - _AMBIENT) / su) * np.maximum(cos_i, 0.0)
        slope_deg = np.degrees(np.arctan(np.sqrt(hx * hx + hy * hy)))
        # land use: fields on gentle slopes, with irregular gaps (villages, groves, scrub)
        land_use = self._land_use.window(a0, a1, b0, b1).astype(np.float32)
        field_w = _smoothstep(12.0, 4.0, slope_deg) * _smoothstep(-1.2, -0.6, land_use)
        # natural cover: dark vegetation / brighter soil patches, bare rock on steep slopes
        patches = self._patches.window(a0, a1, b0, b1).astype(np.float32)
        natural = np.float32(0.14) + np.float32(0.10) * _smoothstep(-0.5, 0.5, patches)
        rock = _smoothstep(20.0, 32.0, slope_deg)
        natural += rock * (np.float32(0.28) - natural)
        # uniform ground (water or sand): exactly flat DEM areas, smooth shorelines
        if self._mask is None:  # as uniform_mask_from_dem (3 x 3 max = min, dilated 3 x 3)
            square = np.ones((3, 3), np.uint8)
            flat = cv2.dilate(dem, square, borderType=cv2.BORDER_REPLICATE) == cv2.erode(
                dem, square, borderType=cv2.BORDER_REPLICATE
            )
            uniform = cv2.dilate(flat.view(np.uint8), square, borderType=cv2.BORDER_CONSTANT)
            uniform = uniform.view(np.bool_)
        else:
            uniform = self._mask[w0:w1, v0:v1]
        zeros = np.zeros(shade.shape, np.float32)
        if not uniform.any():
            return [shade, field_w, natural, zeros, zeros], False
        blurred = ndimage.gaussian_filter(
            uniform.astype(np.float64), 1.0, mode="mirror", truncate=4.0
        )
        # water, or sand where a smooth field is high (about a quarter), with wide gradual
        # transitions (shallows, wet sand) so that uniform ground stays nearly uniform
        sand = np.clip((self._water.window(w0, w1, v0, v1) - 0.2) / 1.2, 0.0, 1.0)
        sand = sand * sand * (3.0 - 2.0 * sand)
        tone = np.tanh(self._level.window(w0, w1, v0, v1))
        level = (0.07 + 0.02 * tone) * (1.0 - sand) + (0.35 + 0.05 * tone) * sand
        inner_r, inner_c = rows_f[1:-1], cols_f[1:-1]
        uniform_w = _linear_window(blurred, (w0, v0), inner_r, inner_c, n_dem, False)
        premult = _linear_window(level * blurred, (w0, v0), inner_r, inner_c, n_dem, False)
        channels = [shade, field_w, natural, uniform_w.astype(np.float32)]
        return [*channels, premult.astype(np.float32)], True

    def _strip(self, r0: int, r1: int, c0: int, c1: int) -> tuple[Float32Array, BoolArray]:
        a0, a1 = r0 // _COARSE + 1, (r1 - 1) // _COARSE + 3
        b0, b1 = c0 // _COARSE + 1, (c1 - 1) // _COARSE + 3
        channels, has_uniform = self._coarse(a0, a1, b0, b1)
        # shade, field weight, natural cover, uniform weight, pre-multiplied uniform level
        coarse = np.ascontiguousarray(np.stack(channels), np.float32)
        noise = pyramid_noise(self._noise_key, r0, r1, c0, c1)
        # fields (parcels with boundaries) and natural cover, textured, blended by the field
        # weight; then the roads; then shading and uniform ground
        land, outline = self._parcels.window(r0, r1, c0, c1)
        mask = np.zeros(land.shape, np.bool_)
        darken = np.float32(0.3 * min(1.0, 1.5 / self.posting_m))
        job = ((r0, c0, a0, b0), coarse, noise, land, (outline, mask, darken, has_uniform))
        _mix(0, job)
        paint_roads(land, r0, c0, self._roads)
        _mix(1, job)
        return land, mask


class TextureLook(TypedDict, total=False):
    """The keyword options of :func:`make_texture`, passed on to :class:`GroundTexture`."""

    sun_elevation_deg: float
    sun_azimuth_deg: float
    uniform_mask: ArrayLike | None


def make_texture(dem: DEM, posting_m: float, seed: int, **look: Unpack[TextureLook]) -> Texture:
    """Ground reflectance for ``dem`` on a finer geographic grid (see the module docstring).

    Args:
        dem: a north-up EPSG:4326 DEM without nodata
            (:func:`~carto.framework.simulation.terrain.make_terrain`,
            :func:`~carto.framework.simulation.terrain.terrain_from_dem`).
        posting_m: texture ground spacing at the centre latitude, metres (e.g. half the ground
            sample distance of the images to render).
        seed: random seed (integer >= 0); same seed and arguments give identical textures.
        look: keyword options (:class:`TextureLook`): ``sun_elevation_deg``, the sun's
            elevation above the horizon for the shading, degrees (0-90], default 55;
            ``sun_azimuth_deg``, its azimuth clockwise from north, degrees, default 135;
            ``uniform_mask``, a bool array of the DEM's shape, True on uniform ground (water,
            sand), default :func:`~carto.framework.simulation.terrain.uniform_mask_from_dem`
            (exactly flat areas).

    Returns:
        A :class:`Texture` whose pixel centres start at the DEM's first pixel centre and cover
        the DEM's pixel centres (overhanging by less than one texture pixel); the same values
        as :class:`GroundTexture` windows.

    Raises:
        InputError: not a north-up EPSG:4326 DEM, nodata in the DEM, a bad posting, seed, sun
            angle or mask shape, or a texture larger than
            :data:`~carto.framework.simulation.terrain.MAX_GRID_PX`.
    """
    dem = _check_lonlat_dem(dem, "make_texture")
    ground = GroundTexture(GridTerrain(dem), posting_m, seed, max_px=MAX_GRID_PX, **look)
    n_rows, n_cols = ground.shape
    values, mask = ground.window(0, n_rows, 0, n_cols)
    values.flags.writeable = False
    mask.flags.writeable = False
    return Texture(values, ground.transform, mask, ground.posting_m)


# ----------------------------------------------------------------------------- targets
def add_point_targets(
    texture: Texture,
    lon_deg: ArrayLike,
    lat_deg: ArrayLike,
    radius_m: ArrayLike,
    contrast: ArrayLike,
) -> Texture:
    """A copy of ``texture`` with bright Gaussian blobs centred exactly on ground points.

    Each target is ``m + contrast * exp(-r^2 / (2 radius_m^2))`` on a flat pad of the local
    mean reflectance ``m`` (lowered to ``1 - contrast`` if needed, so nothing clips): the pad
    replaces the texture out to 4 radii and blends back into it by 5 radii, so the blob's
    centroid is exactly the target whatever the texture underneath. ``r`` is the ground
    distance, metres (the pixel sizes in metres are taken at the target's latitude). Targets
    should be at least 10 radii apart (a later one flattens an earlier one).

    Args:
        texture: the texture to copy.
        lon_deg, lat_deg: target positions, WGS84 degrees (arrays broadcast with the rest).
        radius_m: Gaussian standard deviation of each blob, metres (> 0).
        contrast: peak reflectance above the pad, in (0, 1].

    Raises:
        InputError: a target outside the texture (with its pad), a radius <= 0, or a contrast
            outside (0, 1].
    """
    lon, lat, radius, peak = (
        v.ravel() for v in as_float_arrays(lon_deg, lat_deg, radius_m, contrast)
    )
    if not np.all(np.isfinite(radius) & (radius > 0.0)):
        raise InputError(f"radius_m must be > 0 metres, got {np.asarray(radius_m)!r}")
    if not np.all((peak > 0.0) & (peak <= 1.0)):
        raise InputError(f"contrast must be in (0, 1], got {np.asarray(contrast)!r}")
    out = np.array(texture.reflectance)
    paint_targets(out, (0, 0), texture.transform, lon, lat, radius, peak, strict=True)
    np.clip(out, 0.0, 1.0, out=out)
    out.flags.writeable = False
    return Texture(out, texture.transform, texture.uniform_mask, texture.posting_m)


__all__ = [
    "GroundTexture",
    "Texture",
    "add_point_targets",
    "make_texture",
]
