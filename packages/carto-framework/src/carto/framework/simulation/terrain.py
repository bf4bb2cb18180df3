"""Synthetic terrain and ground texture for the scene simulator, with known truth.

The simulator renders satellite images of a ground whose heights and reflectance are known
exactly. This module makes both:

* :func:`make_terrain`: a :class:`~carto.framework.raster.dem.DEM` of one of the :data:`TERRAINS`
  presets, modelled on the test sites of Radhadevi et al. (2010, Cartosat-1 large-scale
  mapping): flat coastal land with large water bodies, plains, mixed terrain, hills and high
  mountains. :func:`terrain_from_dem` puts any DEM (a user's GeoTIFF) on the same kind of grid.
* :func:`make_texture`: a :class:`Texture`, the ground reflectance in [0, 1] on a finer grid:
  agricultural parcels, field boundaries, roads, natural cover, multi-scale fine texture,
  Lambertian terrain shading, and nearly uniform water or sand where the DEM is exactly flat.
  :func:`add_point_targets` adds bright Gaussian blobs centred on given ground points.

Conventions
    * Grids are geographic WGS84 (``EPSG:4326``), north-up, pixel-is-area (the transform maps
      pixel corners; the value of pixel ``(row, col)`` stands at its centre), like
      :class:`~carto.framework.raster.dem.DEM`. The degree spacing in longitude and latitude is
      chosen so that the ground spacing *on the ellipsoid* at the centre latitude is ``posting_m``
      in both directions (:func:`grid_spacing_deg`; away from the centre latitude the east-west
      spacing scales with ``cos(lat)``). The first pixel centre is the north-west corner of the
      requested bounds; the grid extends east and south until its pixel centres cover the bounds,
      so it may overhang them by less than one posting (:func:`geographic_grid`).
    * Heights are metres above the WGS84 ellipsoid.
    * Everything is seeded: the same seed and arguments give bit-identical arrays. The only
      random source is ``numpy.random.default_rng(seed)``, drawn in a fixed order.
    * Bounds are ``(west, south, east, north)`` in degrees.

Terrain synthesis (:func:`make_terrain`)
    A stationary Gaussian random field ``z`` of unit variance with the power spectral density
    ``S(k) ~ (k^2 + k0^2)^(-beta/2)`` (``k`` in cycles per metre, ``k0 = 1 /
    correlation_length_m``, ``beta = spectral_exponent``), optionally plus a smaller-scale
    component: white noise from the seeded generator filtered by ``sqrt(S(k)) / posting`` in
    the Fourier domain. ``S`` is normalised in continuous wavenumber, so the statistics are the
    same whatever the posting and the size of the area. The field is synthesised on a grid
    padded by twice the correlation length on every side and cropped, so its opposite edges
    are unrelated (no wrap-around); when that grid would be large, wavelengths longer than
    ~6 coarse nodes are synthesised on a coarse grid (<= ~1024 nodes a side) and interpolated
    by Keys cubic convolution, the rest on the fine grid (the two spectral bands are
    complementary). Hills and mountains mix in ridged multifractal noise (four octaves of
    crests ``exp(-|g|)`` along the zero lines of smooth fields, each octave weighted by the one
    before): a network of sharp ridges with spurs. ``z`` is mapped to heights by a fixed
    (not per-area) law: ``[-s, s]`` standard deviations (``s = spread_sigma``, 3) map
    linearly onto ``[h_min_m, h_max_m]`` with a smooth tanh saturation of the outer quarter at
    both ends, so heights never leave the preset's range. Presets with a ``uniform_fraction``
    clamp ``z`` from below at that quantile of the unit normal: those areas (water, sand) are
    exactly flat at ``h_min_m``, and the clamped range ``[q, s]`` maps onto the height range.

    Statistics on 12 km x 12 km at 5 m posting, seed 1 (slopes by central differences over
    the ground distances; over 10 seeds of 20 km x 20 km at 50 m the heights span 0.75-0.96
    of each preset's range and the flat fraction of flat-coastal is 0.26-0.43, mean 0.34)::

        preset        heights (m)     slope p50 / p95 / p99 / max (deg)   flat fraction
        flat-coastal     0.0 ..   40   0.9 /  2.4 /  3.1 /  4.9           0.27
        plains         200.0 ..  279   1.0 /  2.2 /  2.6 /  3.7           0.04
        mixed          500.0 ..  677   3.5 /  7.4 /  9.1 / 14.3           0.02
        hilly          200.0 ..  752  10.2 / 22.4 / 27.8 / 42.6           0.02
        mountains     4198   .. 5828  21.3 / 41.7 / 49.1 / 63.3           0

    A 2 km x 2 km area only holds part of the relief (wavelengths reach 5-10 km): over 10
    seeds it spans 0.35-0.57 of the height range on average, and its slope percentiles vary
    with the seed (at 5 m, p95 29-47 deg for mountains, 1.3-2.7 deg for plains). Slopes grow
    slowly with finer postings (mountains p95 37 deg at 50 m, 42 deg at 5 m).

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
    texture pixels. Uniform ground (exactly flat DEM areas by default: water or sand, chosen per
    connected area, 3 in 4 water) is a constant reflectance (water 0.05-0.09, sand 0.30-0.40)
    plus noise of standard deviation 0.003, with a shoreline about 2 texture pixels wide.

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

Memory and speed (2 cores): :func:`make_terrain` on 2400 x 2400 pixels (12 km at 5 m) takes
0.3-1.7 s (mountains, with five fields, the slowest) and about 170 MB besides the DEM;
:func:`make_texture` on 10000 x 10000 pixels (12 km at 1.2 m) about 6-7 s and, besides its
result (float32 reflectance and boolean mask, 500 MB), 200-300 MB: the full-resolution stage
runs in strips of 256 rows and every intermediate is float32.
"""

from __future__ import annotations

import functools
import math
import numbers
import types
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry.frames import WGS84_A_M, WGS84_E2
from carto.framework.raster.dem import DEM, ELLIPSOID, bilinear_sample, to_affine

if TYPE_CHECKING:
    import pyproj
    from affine import Affine

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
BoolArray = NDArray[np.bool_]
Bounds = tuple[float, float, float, float]

MAX_GRID_SIDE_PX = 30000
"""Largest number of rows or columns of a grid (OpenCV's warps take at most 32767)."""
MAX_GRID_PX = 400_000_000
"""Largest number of pixels of a grid (a float32 texture of this size is 1.6 GB)."""

_STRIP_ROWS = 256  # rows of the full-resolution texture computed at a time
_COARSE = 4  # texture pixels per node of the coarse texture grid (shading, land use)
_AMBIENT = 0.2  # sky-light share of the illumination of flat ground


# ----------------------------------------------------------------------------- presets
def _positive(_inst: Any, attribute: attrs.Attribute, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise InputError(f"terrain preset: {attribute.name} must be > 0, got {value!r}")


def _unit_interval(_inst: Any, attribute: attrs.Attribute, value: float) -> None:
    if not (0.0 <= value <= 1.0):
        raise InputError(f"terrain preset: {attribute.name} must be in [0, 1], got {value!r}")


@attrs.frozen
class TerrainPreset:
    """The recipe of a synthetic terrain (see the module docstring for the synthesis).

    Attributes:
        name: the key in :data:`TERRAINS`.
        description: one line on what the terrain stands for.
        h_min_m, h_max_m: the height range, metres above the WGS84 ellipsoid; generated
            heights stay inside it.
        correlation_length_m: outer scale of the relief, metres: wavelengths longer than about
            this are damped (the size of the largest hills and basins).
        spectral_exponent: ``beta``, the power spectral density falls as ``k^-beta`` at
            wavenumbers above the outer scale (3-5: larger is smoother at small scales; 4 puts
            the same slope variance in every octave).
        detail_weight: standard deviation of a second, smaller-scale component of the relief
            relative to the main one (0 for none).
        detail_length_m: outer scale of that component, metres.
        ridge_weight: share (0-1) of ridged noise (sharp crests, mountains).
        ridge_wavelength_m: outer scale of the ridged noise, metres (crests are about half of
            it apart).
        uniform_fraction: expected fraction of flat uniform ground (water, sand) at
            ``h_min_m``; realised fractions vary with the area and seed.
        spread_sigma: standard deviations of the field mapped onto the half range.
    """

    name: str
    description: str
    h_min_m: float = attrs.field(converter=float)
    h_max_m: float = attrs.field(converter=float)
    correlation_length_m: float = attrs.field(converter=float, validator=_positive)
    spectral_exponent: float = attrs.field(converter=float)
    detail_weight: float = attrs.field(default=0.0, converter=float)
    detail_length_m: float = attrs.field(default=500.0, converter=float, validator=_positive)
    ridge_weight: float = attrs.field(default=0.0, converter=float, validator=_unit_interval)
    ridge_wavelength_m: float = attrs.field(default=2000.0, converter=float, validator=_positive)
    uniform_fraction: float = attrs.field(default=0.0, converter=float, validator=_unit_interval)
    spread_sigma: float = attrs.field(default=3.0, converter=float, validator=_positive)

    def __attrs_post_init__(self) -> None:
        if not (math.isfinite(self.h_min_m) and self.h_min_m < self.h_max_m < math.inf):
            raise InputError(
                f"terrain preset {self.name!r}: needs h_min_m < h_max_m, "
                f"got {self.h_min_m} and {self.h_max_m}"
            )
        if not (2.5 <= self.spectral_exponent <= 6.0):
            raise InputError(
                f"terrain preset {self.name!r}: spectral_exponent must be in [2.5, 6], "
                f"got {self.spectral_exponent}"
            )
        if not (0.0 <= self.detail_weight <= 10.0):
            raise InputError(
                f"terrain preset {self.name!r}: detail_weight must be in [0, 10], "
                f"got {self.detail_weight}"
            )
        if self.uniform_fraction >= 0.9:
            raise InputError(
                f"terrain preset {self.name!r}: uniform_fraction must be < 0.9, "
                f"got {self.uniform_fraction}"
            )


TERRAINS: Mapping[str, TerrainPreset] = types.MappingProxyType(
    {
        p.name: p
        for p in (
            TerrainPreset(
                "flat-coastal",
                "low coastal land, 0-50 m, with large flat water bodies and sand flats",
                0.0,
                50.0,
                correlation_length_m=7000.0,
                spectral_exponent=5.0,
                detail_weight=0.15,
                detail_length_m=1000.0,
                uniform_fraction=0.35,
            ),
            TerrainPreset(
                "plains",
                "gently undulating agricultural plains, 200-300 m, a few ponds",
                200.0,
                300.0,
                correlation_length_m=8000.0,
                spectral_exponent=5.0,
                uniform_fraction=0.03,
            ),
            TerrainPreset(
                "mixed",
                "plains and low rolling hills, 500-700 m",
                500.0,
                700.0,
                correlation_length_m=5000.0,
                spectral_exponent=4.8,
                uniform_fraction=0.02,
            ),
            TerrainPreset(
                "hilly",
                "hills with valleys and reservoirs, 200-800 m, slopes mostly below 20 deg",
                200.0,
                800.0,
                correlation_length_m=6000.0,
                spectral_exponent=5.0,
                ridge_weight=0.35,
                ridge_wavelength_m=6000.0,
                uniform_fraction=0.02,
            ),
            TerrainPreset(
                "mountains",
                "high mountains, 4000-6000 m, ridges and valleys, slopes up to 35-45 deg",
                4000.0,
                6000.0,
                correlation_length_m=10000.0,
                spectral_exponent=5.0,
                ridge_weight=0.45,
                ridge_wavelength_m=10000.0,
            ),
        )
    }
)
"""The terrain presets by name (read-only)."""


# ----------------------------------------------------------------------------- grids
def _radii_m(lat_deg: float) -> tuple[float, float]:
    """Meridional and prime-vertical radii of curvature of WGS84 at ``lat_deg``, metres."""
    s = math.sin(math.radians(lat_deg))
    w2 = 1.0 - WGS84_E2 * s * s
    return WGS84_A_M * (1.0 - WGS84_E2) / w2**1.5, WGS84_A_M / math.sqrt(w2)


def grid_spacing_deg(posting_m: float, lat_deg: float) -> tuple[float, float]:
    """``(dlon_deg, dlat_deg)`` whose ground lengths on the WGS84 ellipsoid at ``lat_deg``
    are both ``posting_m`` metres (``M dlat = N cos(lat) dlon = posting``)."""
    m_m, n_m = _radii_m(lat_deg)
    dlat = math.degrees(posting_m / m_m)
    dlon = math.degrees(posting_m / (n_m * math.cos(math.radians(lat_deg))))
    return dlon, dlat


def _check_posting(posting_m: Any, what: str = "posting_m") -> float:
    try:
        value = float(posting_m)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number of metres, got {posting_m!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise InputError(f"{what} must be a finite number of metres > 0, got {posting_m!r}")
    return value


def _check_bounds(bounds_lonlat: Any) -> Bounds:
    try:
        west, south, east, north = (float(v) for v in bounds_lonlat)
    except (TypeError, ValueError):
        raise InputError(
            f"bounds_lonlat must be 4 numbers (west, south, east, north), got {bounds_lonlat!r}"
        ) from None
    values = (west, south, east, north)
    if not all(map(math.isfinite, values)) or not (west < east and south < north):
        raise InputError(
            f"bounds_lonlat {values} must be finite (west, south, east, north) degrees "
            "with west < east and south < north"
        )
    if not (south >= -85.0 and north <= 85.0):
        raise InputError(f"bounds_lonlat {values}: latitudes must be within -85..85 degrees")
    if east - west > 10.0 or north - south > 10.0:
        raise InputError(f"bounds_lonlat {values} spans more than 10 degrees")
    return values


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def geographic_grid(bounds_lonlat: Bounds, posting_m: float) -> tuple[Affine, tuple[int, int]]:
    """The EPSG:4326 grid of :func:`make_terrain`: ``(transform, (rows, cols))``.

    The spacing is :func:`grid_spacing_deg` at the centre latitude of the bounds; the first
    pixel centre is ``(west, north)`` and the last one is at or just beyond ``(east, south)``
    (less than one spacing beyond). Pixel-is-area: the transform maps pixel corners.

    Raises:
        InputError: bounds not ``(west, south, east, north)`` within -85..85 degrees of latitude
            and 10 degrees in extent, posting not > 0, or a grid larger than
            :data:`MAX_GRID_SIDE_PX` / :data:`MAX_GRID_PX`.
    """
    from rasterio.transform import Affine

    west, south, east, north = _check_bounds(bounds_lonlat)
    posting = _check_posting(posting_m)
    dlon, dlat = grid_spacing_deg(posting, 0.5 * (south + north))
    n_cols = math.ceil((east - west) / dlon - 1e-9) + 1
    n_rows = math.ceil((north - south) / dlat - 1e-9) + 1
    if max(n_rows, n_cols) > MAX_GRID_SIDE_PX or n_rows * n_cols > MAX_GRID_PX:
        raise InputError(
            f"posting_m {posting:g} over bounds {(west, south, east, north)} makes a grid of "
            f"{n_rows} x {n_cols} pixels, more than {MAX_GRID_SIDE_PX} per side or "
            f"{MAX_GRID_PX} in all; use a coarser posting or a smaller area"
        )
    transform = Affine(dlon, 0.0, west - 0.5 * dlon, 0.0, -dlat, north + 0.5 * dlat)
    return transform, (n_rows, n_cols)


def _grid_centres(transform: Affine, shape: tuple[int, int]) -> tuple[FloatArray, FloatArray]:
    """Longitudes of the column centres and latitudes of the row centres of a north-up grid."""
    n_rows, n_cols = shape
    lon = transform.c + transform.a * (np.arange(n_cols) + 0.5)
    lat = transform.f + transform.e * (np.arange(n_rows) + 0.5)
    return lon, lat


def _is_north_up_lonlat(dem: DEM) -> bool:
    t = dem.transform
    geographic = dem.crs.is_geographic and dem.crs.equals("EPSG:4326", ignore_axis_order=True)
    return bool(geographic and t.b == 0.0 and t.d == 0.0 and t.a > 0.0 and t.e < 0.0)


def _check_lonlat_dem(dem: Any, what: str) -> DEM:
    if not isinstance(dem, DEM):
        raise InputError(f"{what}: expected a DEM, got {type(dem).__name__}")
    if not _is_north_up_lonlat(dem):
        raise InputError(
            f"{what}: DEM {dem.name} must be on a north-up EPSG:4326 grid "
            f"(crs {dem.crs.name}); resample it with terrain_from_dem first"
        )
    if not np.isfinite(dem.heights).all():
        raise InputError(f"{what}: DEM {dem.name} has nodata (NaN) heights; fill them first")
    return dem


# ----------------------------------------------------------------------------- fields
def _spectrum(components: Sequence[tuple[float, float, float]], k2: Float32Array) -> Float32Array:
    """Power spectral density ``S(k)`` (float32, per cycle^2/m^2) of unit total variance:
    ``sum_i w_i^2 S_i(k) / sum_i w_i^2`` with ``S_i = C_i (k^2 + k0_i^2)^(-beta_i/2)``,
    ``k0_i = 1/outer_i`` and ``C_i = (beta_i - 2) k0_i^(beta_i - 2) / (2 pi)`` (unit integral).
    """
    total = np.zeros(k2.shape, np.float32)
    w_sum = sum(w * w for _, _, w in components)
    for beta, outer_m, w in components:
        k0 = 1.0 / outer_m
        c = (beta - 2.0) * k0 ** (beta - 2.0) / (2.0 * math.pi) * w * w / w_sum
        total += np.float32(c) * (k2 + np.float32(k0 * k0)) ** np.float32(-beta / 2.0)
    return total


def _filtered_noise(
    rng: np.random.Generator,
    shape: tuple[int, int],
    posting_m: float,
    amplitude: Any,
) -> Float32Array:
    """White noise of ``shape`` filtered by ``amplitude(k2)`` (``k2``: squared wavenumber in
    cycles^2/m^2 on the rfft half-plane), float32. The DC term is removed."""
    import scipy.fft

    noise = rng.standard_normal(shape, dtype=np.float32)
    spectrum = scipy.fft.rfft2(noise, workers=-1)
    del noise
    ky = scipy.fft.fftfreq(shape[0], d=posting_m).astype(np.float32)[:, None]
    kx = scipy.fft.rfftfreq(shape[1], d=posting_m).astype(np.float32)[None, :]
    gain = amplitude(ky * ky + kx * kx)
    gain[0, 0] = 0.0
    spectrum *= gain
    del gain
    return scipy.fft.irfft2(spectrum, s=shape, workers=-1).astype(np.float32, copy=False)


def _keys_matrix(positions: FloatArray, n_nodes: int) -> Any:
    """Sparse ``(len(positions), n_nodes)`` matrix of Keys cubic interpolation (a = -0.5) at
    fractional node ``positions`` (all within ``[1, n_nodes - 3]``)."""
    from scipy import sparse

    base = np.floor(positions).astype(np.intp)
    t = positions - base
    weights = np.stack(
        [
            ((-0.5 * t + 1.0) * t - 0.5) * t,
            (1.5 * t - 2.5) * t * t + 1.0,
            ((-1.5 * t + 2.0) * t + 0.5) * t,
            (0.5 * t - 0.5) * t * t,
        ],
        axis=1,
    )
    cols = base[:, None] + np.arange(-1, 3)[None, :]
    rows = np.repeat(np.arange(positions.size), 4)
    return sparse.csr_matrix(
        (weights.ravel(), (rows, cols.ravel())), shape=(positions.size, n_nodes)
    )


def _spectral_field(
    rng: np.random.Generator,
    shape: tuple[int, int],
    posting_m: float,
    components: Sequence[tuple[float, float, float]],
) -> Float32Array:
    """A stationary Gaussian random field of unit variance (float32, ``shape``, ``posting_m``)
    with the power spectrum of :func:`_spectrum` (``components = [(beta, outer_m, w)...]``).

    White noise of unit variance per pixel filtered in the Fourier domain by
    ``sqrt(S(k)) / posting`` has the variance ``integral S d2k = 1`` whatever the grid, so the
    statistics do not depend on the size of the area. The grid is padded by twice the largest
    outer scale on every side, then cropped. When that padded grid would be large, the field
    is split into a low band ``S exp(-(k/ks)^2)`` synthesised on a coarse grid (at most about
    1024 nodes a side, ``ks`` a sixth of its node frequency) and interpolated by Keys cubic
    convolution, plus the complementary high band on the fine grid with a small padding.
    """
    import scipy.fft

    n_rows, n_cols = shape
    outer = max(c[1] for c in components)
    extent_m = max(n_rows, n_cols) * posting_m + 4.0 * outer
    coarse_m = extent_m / 1024.0
    if coarse_m <= 2.0 * posting_m:  # one grid
        pad = math.ceil(2.0 * outer / posting_m)
        p_shape = (
            scipy.fft.next_fast_len(n_rows + 2 * pad, real=True),
            scipy.fft.next_fast_len(n_cols + 2 * pad, real=True),
        )
        field = _filtered_noise(
            rng, p_shape, posting_m, lambda k2: np.sqrt(_spectrum(components, k2)) / posting_m
        )
        r0, c0 = (p_shape[0] - n_rows) // 2, (p_shape[1] - n_cols) // 2
        return np.ascontiguousarray(field[r0 : r0 + n_rows, c0 : c0 + n_cols])

    ks2 = np.float32((1.0 / (6.0 * coarse_m)) ** 2)
    # low band on the coarse grid, its centre on the centre of the fine grid
    n_coarse = [
        scipy.fft.next_fast_len(math.ceil((n * posting_m + 4.0 * outer) / coarse_m) + 8)
        for n in shape
    ]
    low = _filtered_noise(
        rng,
        (n_coarse[0], n_coarse[1]),
        coarse_m,
        lambda k2: np.sqrt(_spectrum(components, k2) * np.exp(-k2 / ks2)) / np.float32(coarse_m),
    )
    interp = [
        _keys_matrix((np.arange(n) + 0.5 - 0.5 * n) * (posting_m / coarse_m) + 0.5 * nc, nc)
        for n, nc in zip(shape, n_coarse, strict=True)
    ]
    field = np.asarray(interp[0] @ (interp[1] @ low.T).T, dtype=np.float32)
    # high band on the fine grid
    pad = math.ceil(3.0 / (math.sqrt(float(ks2)) * posting_m))
    p_shape = (
        scipy.fft.next_fast_len(n_rows + 2 * pad, real=True),
        scipy.fft.next_fast_len(n_cols + 2 * pad, real=True),
    )
    high = _filtered_noise(
        rng,
        p_shape,
        posting_m,
        lambda k2: (
            np.sqrt(_spectrum(components, k2) * -np.expm1(-k2 / ks2)) / np.float32(posting_m)
        ),
    )
    r0, c0 = (p_shape[0] - n_rows) // 2, (p_shape[1] - n_cols) // 2
    field += high[r0 : r0 + n_rows, c0 : c0 + n_cols]
    return field


def _softclip(frac: FloatArray, knee: float = 0.25, lower: bool = True) -> FloatArray:
    """Map ``frac`` into (0, 1): identity on ``[knee, 1 - knee]`` (``[0, 1 - knee]`` without
    ``lower``), tanh saturation beyond, continuous with its first derivative."""
    out = frac.copy()
    hi = frac > 1.0 - knee
    out[hi] = 1.0 - knee + knee * np.tanh((frac[hi] - (1.0 - knee)) / knee)
    if lower:
        lo = frac < knee
        out[lo] = knee - knee * np.tanh((knee - frac[lo]) / knee)
    return out


_RIDGE_OCTAVES = 4
_RIDGE_GAIN = 2.0


def _ridge_signal(g: Any) -> Any:
    """A sharp crest (a cusp) along the zero lines of ``g``, decaying to 0 away from them."""
    return np.exp(-np.abs(g))


@functools.cache
def _ridged_moments() -> tuple[float, float]:
    """Mean and standard deviation of :func:`_ridged_multifractal` before standardisation.

    It is a pointwise function of ``|g_k|``, independent half-normal variables: integrated by
    40-node Gauss-Legendre quadrature over ``[0, 7]`` in each of the octaves (agrees with a
    Monte Carlo estimate on 2e7 samples to 3e-4).
    """
    x, w = np.polynomial.legendre.leggauss(40)
    nodes = 3.5 * (x + 1.0)
    weights = w * np.exp(-0.5 * nodes * nodes)
    weights /= weights.sum()
    dims = _RIDGE_OCTAVES
    grids = np.meshgrid(*([nodes] * dims), indexing="ij", sparse=True)
    prob = np.ones([nodes.size] * dims)
    for k in range(dims):
        prob = prob * weights.reshape([-1 if i == k else 1 for i in range(dims)])
    total = np.zeros(prob.shape)
    signal = np.ones(prob.shape)
    for k, g in enumerate(grids):
        weight = np.clip(signal * _RIDGE_GAIN, 0.0, 1.0) if k else 1.0
        signal = _ridge_signal(g) * weight
        total = total + signal * 0.5**k
    mean = float((prob * total).sum())
    return mean, math.sqrt(float((prob * (total - mean) ** 2).sum()))


def _ridged_multifractal(
    rng: np.random.Generator, shape: tuple[int, int], posting_m: float, wavelength_m: float
) -> Float32Array:
    """Ridged multifractal noise (Musgrave), standardised to zero mean and unit variance.

    Octave ``k`` (outer scale ``wavelength_m / 2^k``) contributes ``0.5^k`` times the crest
    signal ``exp(-|g_k|)`` of a smooth unit Gaussian field ``g_k`` (spectral exponent 6),
    weighted by twice the previous octave's signal (clipped to 1): small crests branch off
    the large ones, giving a network of sharp ridges with spurs between broader valleys.
    """
    total = np.zeros(shape, np.float32)
    signal: Float32Array | None = None
    for k in range(_RIDGE_OCTAVES):
        g = _spectral_field(rng, shape, posting_m, [(6.0, wavelength_m / 2**k, 1.0)])
        current = _ridge_signal(g)
        del g
        if signal is not None:
            current *= np.clip(signal * np.float32(_RIDGE_GAIN), 0.0, 1.0)
        total += np.float32(0.5**k) * current
        signal = current
    mean, std = _ridged_moments()
    total -= np.float32(mean)
    total *= np.float32(1.0 / std)
    return total


def _terrain_heights(
    preset: TerrainPreset, rng: np.random.Generator, shape: tuple[int, int], posting_m: float
) -> FloatArray:
    """Heights (float64, metres) of ``preset`` on a grid of ``shape`` at ``posting_m``."""
    from scipy.special import ndtri

    beta = preset.spectral_exponent
    components = [(beta, preset.correlation_length_m, 1.0)]
    if preset.detail_weight > 0.0:
        components.append((beta, preset.detail_length_m, preset.detail_weight))
    z = _spectral_field(rng, shape, posting_m, components)
    if preset.ridge_weight > 0.0:
        ridged = _ridged_multifractal(rng, shape, posting_m, preset.ridge_wavelength_m)
        w = preset.ridge_weight
        z *= np.float32((1.0 - w) / math.hypot(w, 1.0 - w))
        z += np.float32(w / math.hypot(w, 1.0 - w)) * ridged
        del ridged
    z64 = z.astype(np.float64)
    s = preset.spread_sigma
    if preset.uniform_fraction > 0.0:
        q = float(ndtri(preset.uniform_fraction))
        frac = _softclip((np.maximum(z64, q) - q) / (s - q), lower=False)
        frac[z64 <= q] = 0.0  # exactly flat
    else:
        frac = _softclip(0.5 + 0.5 * z64 / s)
    return preset.h_min_m + (preset.h_max_m - preset.h_min_m) * frac


def _preset(name: str | TerrainPreset) -> TerrainPreset:
    if isinstance(name, TerrainPreset):
        return name
    if not isinstance(name, str) or name not in TERRAINS:
        raise InputError(f"unknown terrain {name!r}; known terrains: {', '.join(TERRAINS)}")
    return TERRAINS[name]


# ----------------------------------------------------------------------------- terrain
def make_terrain(
    name: str | TerrainPreset, bounds_lonlat: Bounds, posting_m: float, seed: int
) -> DEM:
    """A synthetic DEM of terrain preset ``name`` over ``bounds_lonlat``.

    Args:
        name: a key of :data:`TERRAINS` (``"flat-coastal"``, ``"plains"``, ``"mixed"``,
            ``"hilly"``, ``"mountains"``) or a :class:`TerrainPreset`.
        bounds_lonlat: ``(west, south, east, north)`` WGS84 degrees.
        posting_m: ground spacing of the grid at the centre latitude, metres.
        seed: random seed (integer >= 0); same seed and arguments give identical heights.

    Returns:
        An EPSG:4326 DEM on :func:`geographic_grid` with ellipsoidal heights (metres) inside
        ``[h_min_m, h_max_m]`` of the preset; flat uniform areas are exactly ``h_min_m``.

    Raises:
        InputError: unknown terrain name (the message lists the known ones), invalid bounds,
            posting or seed.
    """
    preset = _preset(name)
    transform, shape = geographic_grid(bounds_lonlat, posting_m)
    rng = np.random.default_rng(_check_seed(seed))
    heights = _terrain_heights(preset, rng, shape, float(posting_m))
    return DEM(
        heights,
        transform,
        "EPSG:4326",
        vertical=ELLIPSOID,
        source=f"terrain {preset.name!r} seed {int(seed)}",
    )


def terrain_from_dem(dem: DEM, bounds_lonlat: Bounds, posting_m: float) -> DEM:
    """``dem`` resampled bilinearly onto the grid :func:`make_terrain` would use.

    Nodes of the last row or column that overhang the bounds (by less than one posting) are
    sampled at the bound itself, so a DEM that covers exactly ``bounds_lonlat`` is enough.

    Args:
        dem: any DEM with ellipsoidal heights (any CRS, e.g. a GeoTIFF read by
            :meth:`DEM.open`; convert geoid heights with :meth:`DEM.to_ellipsoid` first).
        bounds_lonlat: ``(west, south, east, north)`` WGS84 degrees.
        posting_m: ground spacing at the centre latitude, metres.

    Raises:
        InputError: geoid heights, invalid bounds or posting, or ``dem`` does not cover the
            bounds (or has nodata inside them); the message names the DEM and what it covers.
    """
    if not isinstance(dem, DEM):
        raise InputError(f"terrain_from_dem: expected a DEM, got {type(dem).__name__}")
    if not dem.is_ellipsoidal:
        raise InputError(
            f"DEM {dem.name}: heights are {dem.vertical}; terrain needs ellipsoidal heights, "
            "convert with DEM.to_ellipsoid(geoid)"
        )
    transform, shape = geographic_grid(bounds_lonlat, posting_m)
    _, south, east, _ = _check_bounds(bounds_lonlat)
    lon, lat = _grid_centres(transform, shape)
    lon = np.minimum(lon, east)
    lat = np.maximum(lat, south)
    # the grid's outline first: the DEM's own message names what it covers
    outline_lon = np.concatenate([lon, lon, np.full(lat.size, lon[0]), np.full(lat.size, lon[-1])])
    outline_lat = np.concatenate([np.full(lon.size, lat[0]), np.full(lon.size, lat[-1]), lat, lat])
    dem.height(outline_lon, outline_lat, strict=True)
    if _is_north_up_lonlat(dem):  # separable: exact bilinear by two sparse products
        rows = dem.lonlat_to_pixel(np.full(lat.size, lon[0]), lat)[0]
        cols = dem.lonlat_to_pixel(lon, np.full(lon.size, lat[0]))[1]
        r0, c0 = max(math.floor(rows.min()), 0), max(math.floor(cols.min()), 0)
        r1 = min(math.ceil(rows.max()) + 1, dem.shape[0])
        c1 = min(math.ceil(cols.max()) + 1, dem.shape[1])
        window = dem.heights[r0:r1, c0:c1]
        heights = _resample(
            window, _linear_matrix(rows - r0, r1 - r0), _linear_matrix(cols - c0, c1 - c0)
        )
    else:
        heights = np.empty(shape, dtype=np.float64)
        step = max(1, 2_000_000 // shape[1])  # rows at a time: bounded temporaries
        for r0 in range(0, shape[0], step):
            lon2, lat2 = np.meshgrid(lon, lat[r0 : r0 + step])
            heights[r0 : r0 + step] = dem.height(lon2, lat2)
    if not np.isfinite(heights).all():
        raise InputError(
            f"DEM {dem.name} has nodata at {int(np.count_nonzero(~np.isfinite(heights)))} "
            f"of {heights.size} nodes inside bounds {_check_bounds(bounds_lonlat)}"
        )
    return DEM(heights, transform, "EPSG:4326", vertical=ELLIPSOID, source=dem.source)


def uniform_mask_from_dem(dem: DEM) -> BoolArray:
    """Pixels of ``dem`` in exactly flat areas: True where the pixel belongs to a 3 x 3 window
    of identical heights (water bodies and flattened areas, as in SRTM or :func:`make_terrain`).
    """
    from scipy import ndimage

    h = dem.heights
    flat = ndimage.maximum_filter(h, size=3, mode="nearest") == ndimage.minimum_filter(
        h, size=3, mode="nearest"
    )
    return ndimage.binary_dilation(flat, structure=np.ones((3, 3), bool)) & np.isfinite(h)


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


def _white_u8(rng: np.random.Generator, shape: tuple[int, int]) -> Float32Array:
    """Uniform white noise of unit variance, float32, from random bytes (fast)."""
    out = rng.integers(0, 256, size=shape, dtype=np.uint8).astype(np.float32)
    out -= np.float32(127.5)
    out *= np.float32(1.0 / 73.9)  # std of the uniform integers 0..255
    return out


class _Pyramid:
    """Multi-scale noise: a Laplacian-pyramid sum of white noise at 1, 2, 4 ... 64 pixels.

    Levels 1..6 are summed at half resolution up front; each strip of the full-resolution field
    is the 2x Gaussian upsampling (``cv2.pyrUp``) of the half-resolution rows it needs plus
    per-pixel white noise drawn strip by strip. The result has about unit variance.
    """

    _AMPS = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.0)  # level 0 (1 px) ... level 6 (64 px)

    def __init__(self, rng: np.random.Generator, shape: tuple[int, int]) -> None:
        import cv2

        n_rows, n_cols = shape
        levels = len(self._AMPS) - 1
        sizes = [(-(-n_rows // 2**k), -(-n_cols // 2**k)) for k in range(levels + 1)]
        field = np.float32(self._AMPS[levels]) * _white_u8(rng, sizes[levels])
        for k in range(levels - 1, 0, -1):
            h, w = sizes[k]
            up = cv2.pyrUp(field, dstsize=(2 * field.shape[1], 2 * field.shape[0]))
            field = up[:h, :w] + np.float32(self._AMPS[k]) * _white_u8(rng, (h, w))
        self._half = np.ascontiguousarray(field)
        self._rng = rng
        self._cols = n_cols
        # variance after upsampling, estimated on a sample: the scale to unit variance
        sample = self._upsampled(0, min(n_rows, 512))
        var = float(np.var(sample, dtype=np.float64)) + self._AMPS[0] ** 2
        self._scale = np.float32(1.0 / math.sqrt(var))

    def _upsampled(self, r0: int, r1: int) -> Float32Array:
        import cv2

        h1 = self._half.shape[0]
        c0, c1 = max(r0 // 2 - 2, 0), min((r1 + 1) // 2 + 2, h1)
        sub = self._half[c0:c1]
        up = cv2.pyrUp(sub, dstsize=(2 * sub.shape[1], 2 * sub.shape[0]))
        return up[r0 - 2 * c0 : r1 - 2 * c0, : self._cols]

    def strip(self, r0: int, r1: int) -> Float32Array:
        """Rows ``[r0, r1)`` of the field; call for consecutive strips in order."""
        out = self._upsampled(r0, r1) + np.float32(self._AMPS[0]) * _white_u8(
            self._rng, (r1 - r0, self._cols)
        )
        out *= self._scale
        return out


def _parcels(
    rng: np.random.Generator, shape: tuple[int, int], posting_m: float
) -> tuple[list[NDArray[np.int32]], FloatArray]:
    """Field parcels: Voronoi cells of irregular brick lattices, one lattice per ~2.5 km zone
    (random orientation, parcel sizes 60-140 m x 30-70 m). Returns the polygons in texture
    pixel coordinates as fixed-point (4 fractional bits) int32 ``(n, 2)`` arrays (x = col,
    y = row) and their brightness."""
    from scipy.spatial import Voronoi, cKDTree

    n_rows, n_cols = shape
    width_m, height_m = n_cols * posting_m, n_rows * posting_m
    zone_m = 2500.0
    margin_m = 400.0
    gx = np.arange(-zone_m, width_m + 2 * zone_m, zone_m)
    gy = np.arange(-zone_m, height_m + 2 * zone_m, zone_m)
    zx, zy = np.meshgrid(gx, gy)
    zones = np.column_stack([zx.ravel(), zy.ravel()])
    zones += rng.uniform(-0.35, 0.35, zones.shape) * zone_m
    candidates = []
    owner = []
    radius = 1.6 * zone_m
    for index, (cx, cy) in enumerate(zones):
        theta = rng.uniform(0.0, math.pi)
        a_m, b_m = rng.uniform(60.0, 140.0), rng.uniform(30.0, 70.0)
        n_u, n_v = math.ceil(2 * radius / (0.6 * a_m)) + 1, math.ceil(2 * radius / (0.6 * b_m)) + 1
        u = np.cumsum(a_m * rng.uniform(0.6, 1.4, n_u)) - radius
        v = np.cumsum(b_m * rng.uniform(0.6, 1.4, (n_u, n_v)), axis=1) - radius
        v -= rng.uniform(0.0, b_m, (n_u, 1))
        uu = np.broadcast_to(u[:, None], v.shape) + rng.normal(0.0, 0.08 * a_m, v.shape)
        vv = v + rng.normal(0.0, 0.08 * b_m, v.shape)
        keep = (np.abs(uu) <= radius) & (np.abs(vv) <= radius)
        uu, vv = uu[keep], vv[keep]
        c, s = math.cos(theta), math.sin(theta)
        candidates.append(np.column_stack([cx + c * uu - s * vv, cy + s * uu + c * vv]))
        owner.append(np.full(uu.size, index))
    points = np.concatenate(candidates)
    owners = np.concatenate(owner)
    nearest = cKDTree(zones).query(points)[1]
    points = points[nearest == owners]
    inside = (
        (points[:, 0] > -margin_m)
        & (points[:, 0] < width_m + margin_m)
        & (points[:, 1] > -margin_m)
        & (points[:, 1] < height_m + margin_m)
    )
    points = points[inside]
    vor = Voronoi(points)
    vertices_px = vor.vertices / posting_m - 0.5  # metres from the grid corner -> centre index
    fixed = np.round(vertices_px * 16.0)
    polygons: list[NDArray[np.int32]] = []
    for region_index in vor.point_region:
        region = vor.regions[region_index]
        if not region or -1 in region:
            continue
        poly = fixed[region]
        if (
            poly[:, 0].max() < -32
            or poly[:, 1].max() < -32
            or poly[:, 0].min() > 16 * (n_cols + 2)
            or poly[:, 1].min() > 16 * (n_rows + 2)
        ):
            continue
        polygons.append(poly.astype(np.int32))
    # brightness: crops (dark), bare soil (bright), fallow / grass (between)
    kind = rng.choice(3, size=len(polygons), p=[0.45, 0.35, 0.20])
    low = np.array([0.12, 0.24, 0.18])[kind]
    high = np.array([0.22, 0.40, 0.30])[kind]
    brightness = rng.uniform(low, high)
    return polygons, brightness


def _roads(
    rng: np.random.Generator, shape: tuple[int, int], posting_m: float
) -> list[tuple[NDArray[np.int32], int, float]]:
    """Roads and tracks as gently curving polylines: ``(points, thickness_px, reflectance)``;
    points fixed-point (4 fractional bits) texture pixel coordinates, x = col, y = row."""
    n_rows, n_cols = shape
    width_m, height_m = n_cols * posting_m, n_rows * posting_m
    n_roads = max(2, round((width_m + height_m) / 1500.0))
    step_m = 20.0
    n_steps = math.ceil(math.hypot(width_m, height_m) / step_m) + 2
    roads = []
    for _ in range(n_roads):
        # a smooth random walk of 2 n_steps steps whose middle is near a random point
        x0, y0 = rng.uniform(0.0, width_m), rng.uniform(0.0, height_m)
        heading = rng.uniform(0.0, 2.0 * math.pi)
        # heading changes: white noise smoothed over 10 steps (200 m), a few degrees per km
        curvature = np.convolve(
            rng.normal(0.0, math.radians(0.6), 2 * n_steps + 9), np.full(10, 0.1), "valid"
        )
        angle = heading + np.cumsum(curvature)
        angle -= angle[n_steps] - heading
        x = np.cumsum(step_m * np.cos(angle))
        y = np.cumsum(step_m * np.sin(angle))
        x += x0 - x[n_steps]
        y += y0 - y[n_steps]
        pts = np.column_stack([x / posting_m - 0.5, y / posting_m - 0.5])
        kind = rng.choice(3, p=[0.3, 0.2, 0.5])  # asphalt, concrete, track
        width = rng.uniform(*((5.0, 10.0), (5.0, 8.0), (2.5, 4.0))[kind])
        albedo = rng.uniform(*((0.08, 0.13), (0.38, 0.48), (0.32, 0.42))[kind])
        thickness = max(1, round(width / posting_m))
        roads.append((np.round(pts * 16.0).astype(np.int32), thickness, float(albedo)))
    return roads


def _linear_matrix(positions: FloatArray, n_nodes: int, *, extrapolate: bool = False) -> Any:
    """Sparse ``(len(positions), n_nodes)`` matrix of linear interpolation at fractional node
    indices ``positions``; outside ``[0, n_nodes - 1]`` they are clamped, or with
    ``extrapolate`` the end intervals are extended linearly."""
    from scipy import sparse

    pos = positions if extrapolate else np.clip(positions, 0.0, n_nodes - 1.0)
    base = np.clip(np.floor(pos).astype(np.intp), 0, max(n_nodes - 2, 0))
    frac = pos - base
    rows = np.repeat(np.arange(pos.size), 2)
    cols = np.column_stack([base, np.minimum(base + 1, n_nodes - 1)]).ravel()
    weights = np.column_stack([1.0 - frac, frac]).ravel()
    return sparse.csr_matrix((weights, (rows, cols)), shape=(pos.size, n_nodes))


def _resample(grid: ArrayLike, row_matrix: Any, col_matrix: Any) -> FloatArray:
    """Separable bilinear resampling ``R grid C^T`` of a 2-D grid (exactly the bilinear
    interpolation of :class:`DEM` at the nodes of a north-up grid, edges clamped)."""
    return np.asarray(row_matrix @ (col_matrix @ np.asarray(grid, np.float64).T).T)


def _coarse_fields(
    dem: DEM,
    rng: np.random.Generator,
    lon_c: FloatArray,
    lat_c: FloatArray,
    posting_c_m: float,
    sun_elevation_deg: float,
    sun_azimuth_deg: float,
    uniform: BoolArray,
) -> tuple[Float32Array, Float32Array | None]:
    """Shading, field weight, natural-cover albedo, uniform weight (4 channels, float32) and
    the uniform reflectance pre-multiplied by the uniform weight (or None) on the coarse grid
    ``lat_c x lon_c``."""
    import cv2
    from scipy import ndimage

    # the DEM's bilinear surface at the coarse nodes, extended linearly over the margin
    t = dem.transform
    rows_f, cols_f = (lat_c - t.f) / t.e - 0.5, (lon_c - t.c) / t.a - 0.5
    heights = _resample(
        dem.heights,
        _linear_matrix(rows_f, dem.shape[0], extrapolate=True),
        _linear_matrix(cols_f, dem.shape[1], extrapolate=True),
    )
    rows_m, cols_m = _linear_matrix(rows_f, dem.shape[0]), _linear_matrix(cols_f, dem.shape[1])
    # gradient in metres: east and north
    dlon = abs(float(lon_c[1] - lon_c[0])) if lon_c.size > 1 else 1.0
    dlat = abs(float(lat_c[1] - lat_c[0])) if lat_c.size > 1 else 1.0
    radii = np.array([_radii_m(v) for v in lat_c])
    dx_m = np.radians(dlon) * radii[:, 1] * np.cos(np.radians(lat_c))
    dy_m = np.radians(dlat) * radii[:, 0]
    d_row, d_col = np.gradient(heights)
    hx = (d_col / dx_m[:, None]).astype(np.float32)
    hy = (-d_row / dy_m[:, None]).astype(np.float32)
    del d_row, d_col, heights
    el, az = math.radians(sun_elevation_deg), math.radians(sun_azimuth_deg)
    se, sn, su = math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)
    norm = np.sqrt(np.float32(1.0) + hx * hx + hy * hy)
    cos_i = (np.float32(su) - np.float32(se) * hx - np.float32(sn) * hy) / norm
    shade = np.float32(_AMBIENT) + np.float32((1.0 - _AMBIENT) / su) * np.maximum(cos_i, 0.0)
    slope_deg = np.degrees(np.arctan(np.sqrt(hx * hx + hy * hy)))
    del hx, hy, norm, cos_i
    # land use: fields on gentle slopes, with irregular gaps (villages, groves, scrub)
    land_use = _spectral_field(rng, slope_deg.shape, posting_c_m, [(3.6, 600.0, 1.0)])
    field_w = _smoothstep(12.0, 4.0, slope_deg) * _smoothstep(-1.2, -0.6, land_use)
    del land_use
    # natural cover: dark vegetation / brighter soil patches, bare rock on steep slopes
    patches = _spectral_field(rng, slope_deg.shape, posting_c_m, [(3.0, 150.0, 1.0)])
    natural = np.float32(0.14) + np.float32(0.10) * _smoothstep(-0.5, 0.5, patches)
    del patches
    rock = _smoothstep(20.0, 32.0, slope_deg)
    natural += rock * (np.float32(0.28) - natural)
    del rock, slope_deg
    # uniform ground: water or sand per connected area
    premult = None
    uniform_w = np.zeros(field_w.shape, np.float32)
    if uniform.any():
        labels, n_labels = ndimage.label(uniform, structure=np.ones((3, 3), bool))
        is_water = rng.random(n_labels + 1) < 0.75
        level = np.where(is_water, rng.uniform(0.05, 0.09, n_labels + 1), 0.0)
        level = np.where(is_water, level, rng.uniform(0.30, 0.40, n_labels + 1))
        level[0] = 0.0
        # a slightly blurred mask: smooth shorelines instead of the DEM's pixel staircase
        blurred = cv2.GaussianBlur(uniform.astype(np.float32), (0, 0), 1.0)
        uniform_w = _resample(blurred, rows_m, cols_m).astype(np.float32)
        premult = _resample(level[labels] * blurred, rows_m, cols_m).astype(np.float32)
    channels = np.ascontiguousarray(np.stack([shade, field_w, natural, uniform_w], axis=-1))
    return channels, premult


def make_texture(
    dem: DEM,
    posting_m: float,
    seed: int,
    *,
    sun_elevation_deg: float = 55.0,
    sun_azimuth_deg: float = 135.0,
    uniform_mask: ArrayLike | None = None,
) -> Texture:
    """Ground reflectance for ``dem`` on a finer geographic grid (see the module docstring).

    Args:
        dem: a north-up EPSG:4326 DEM without nodata (:func:`make_terrain`,
            :func:`terrain_from_dem`).
        posting_m: texture ground spacing at the centre latitude, metres (e.g. half the ground
            sample distance of the images to render).
        seed: random seed (integer >= 0); same seed and arguments give identical textures.
        sun_elevation_deg: sun elevation above the horizon for the shading, degrees (0-90].
        sun_azimuth_deg: sun azimuth clockwise from north, degrees.
        uniform_mask: bool array of the DEM's shape, True on uniform ground (water, sand);
            default :func:`uniform_mask_from_dem` (exactly flat areas).

    Returns:
        A :class:`Texture` whose pixel centres start at the DEM's first pixel centre and cover
        the DEM's pixel centres (overhanging by less than one texture pixel).

    Raises:
        InputError: not a north-up EPSG:4326 DEM, nodata in the DEM, a bad posting, seed, sun
            angle or mask shape, or a texture larger than :data:`MAX_GRID_PX`.
    """
    import cv2

    dem = _check_lonlat_dem(dem, "make_texture")
    posting = _check_posting(posting_m)
    rng = np.random.default_rng(_check_seed(seed))
    if not (0.0 < float(sun_elevation_deg) <= 90.0):
        raise InputError(f"sun_elevation_deg must be in (0, 90], got {sun_elevation_deg!r}")
    if not math.isfinite(float(sun_azimuth_deg)):
        raise InputError(f"sun_azimuth_deg must be finite, got {sun_azimuth_deg!r}")
    if uniform_mask is None:
        uniform = uniform_mask_from_dem(dem)
    else:
        uniform = np.asarray(uniform_mask)
        if uniform.shape != dem.shape or uniform.dtype != np.bool_:
            raise InputError(
                f"uniform_mask must be a bool array of the DEM's shape {dem.shape}, "
                f"got {uniform.dtype} {uniform.shape}"
            )
    west, south, east, north = dem.bounds_lonlat
    if west == east or south == north:
        raise InputError(f"make_texture: DEM {dem.name} must have at least 2 x 2 pixels")
    transform, shape = geographic_grid((west, south, east, north), posting)
    n_rows, n_cols = shape

    # coarse grid: node i <-> texture centre index _COARSE * (i - 1), one node of margin
    lon_t, lat_t = _grid_centres(transform, shape)
    rows_c = -(-(n_rows - 1) // _COARSE) + 3
    cols_c = -(-(n_cols - 1) // _COARSE) + 3
    lon_c = lon_t[0] + transform.a * _COARSE * (np.arange(cols_c) - 1.0)
    lat_c = lat_t[0] + transform.e * _COARSE * (np.arange(rows_c) - 1.0)
    del lon_t, lat_t
    channels, premult = _coarse_fields(
        dem,
        rng,
        lon_c,
        lat_c,
        _COARSE * posting,
        float(sun_elevation_deg),
        float(sun_azimuth_deg),
        uniform,
    )
    polygons, brightness = _parcels(rng, shape, posting)
    roads = _roads(rng, shape, posting)
    noise = _Pyramid(rng, shape)

    # parcels by strip, grouped by quantised brightness (one fillPoly call per level)
    n_strips = -(-n_rows // _STRIP_ROWS)
    levels = np.linspace(0.12, 0.40, 29)
    level_of = np.clip(np.round((brightness - 0.12) / 0.01).astype(int), 0, levels.size - 1)
    by_strip: list[dict[int, list[NDArray[np.int32]]]] = [{} for _ in range(n_strips)]
    for poly, lev in zip(polygons, level_of, strict=True):
        first = max(int(poly[:, 1].min()) // 16 - 2, 0) // _STRIP_ROWS
        last = min(int(poly[:, 1].max()) // 16 + 2, n_rows - 1) // _STRIP_ROWS
        for k in range(max(first, 0), min(last, n_strips - 1) + 1):
            by_strip[k].setdefault(int(lev), []).append(poly)
    boundary_weight = np.float32(0.3 * min(1.0, 1.5 / posting) / 255.0)

    # roads cut in pieces of 16 segments, bucketed by strip like the parcels
    road_pieces: list[list[tuple[NDArray[np.int32], int, float]]] = [[] for _ in range(n_strips)]
    for pts, thickness, albedo in roads:
        for i in range(0, len(pts) - 1, 16):
            piece = pts[i : i + 17]
            y_lo = int(piece[:, 1].min()) // 16 - thickness - 2
            y_hi = int(piece[:, 1].max()) // 16 + thickness + 2
            if y_hi < 0 or y_lo >= n_rows:
                continue
            for k in range(max(y_lo, 0) // _STRIP_ROWS, min(y_hi, n_rows - 1) // _STRIP_ROWS + 1):
                road_pieces[k].append((piece, thickness, albedo))

    reflectance = np.empty(shape, dtype=np.float32)
    mask = np.zeros(shape, dtype=np.bool_)
    one = np.float32(1.0)
    for k in range(n_strips):
        r0, r1 = k * _STRIP_ROWS, min((k + 1) * _STRIP_ROWS, n_rows)
        rows = r1 - r0
        warp = np.array(
            [[1.0 / _COARSE, 0.0, 1.0], [0.0, 1.0 / _COARSE, r0 / _COARSE + 1.0]], np.float64
        )
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        fields = cv2.warpAffine(
            channels, warp, (n_cols, rows), flags=flags, borderMode=cv2.BORDER_REPLICATE
        )
        shade, field_w, natural, uniform_w = cv2.split(fields)
        del fields
        n = noise.strip(r0, r1)
        # fields: parcels with boundaries and fine texture
        land = np.full((rows, n_cols), np.float32(0.26))
        outline = np.zeros((rows, n_cols), np.uint8)
        shift = np.array([0, 16 * r0], np.int32)
        for lev, polys in by_strip[k].items():
            cv2.fillPoly(land, polys, float(levels[lev]), cv2.LINE_8, 4, (0, -16 * r0))
        shifted = [p - shift for ps in by_strip[k].values() for p in ps]
        if shifted:
            cv2.polylines(outline, shifted, True, 255, 1, cv2.LINE_AA, 4)
        land *= one + np.float32(0.10) * n
        land *= one - boundary_weight * outline.astype(np.float32)
        del outline
        # natural cover, blended by the field weight
        natural *= one + np.float32(0.20) * n
        land -= natural
        land *= field_w
        land += natural
        del natural, field_w
        # roads
        cover = np.zeros((rows, n_cols), np.uint8)
        for piece, thickness, albedo in road_pieces[k]:
            local = piece - shift
            cv2.polylines(cover, [local], False, 255, thickness, cv2.LINE_AA, 4)
            y_lo = max(int(local[:, 1].min()) // 16 - thickness - 2, 0)
            y_hi = min(int(local[:, 1].max()) // 16 + thickness + 3, rows)
            x_lo = max(int(local[:, 0].min()) // 16 - thickness - 2, 0)
            x_hi = min(int(local[:, 0].max()) // 16 + thickness + 3, n_cols)
            if y_lo >= y_hi or x_lo >= x_hi:
                continue
            c = cover[y_lo:y_hi, x_lo:x_hi].astype(np.float32) * np.float32(1.0 / 255.0)
            window = land[y_lo:y_hi, x_lo:x_hi]
            window += c * (np.float32(albedo) - window)
            cover[y_lo:y_hi, x_lo:x_hi] = 0
        del cover
        land *= shade
        del shade
        # uniform ground
        if premult is not None:
            level = cv2.warpAffine(
                premult, warp, (n_cols, rows), flags=flags, borderMode=cv2.BORDER_REPLICATE
            )
            level /= np.maximum(uniform_w, np.float32(1e-6))
            level += np.float32(0.003) * n
            u = uniform_w
            u -= np.float32(0.5)
            u *= np.float32(4.0)
            u += np.float32(0.5)
            np.clip(u, 0.0, 1.0, out=u)
            level -= land
            level *= u
            land += level
            mask[r0:r1] = u >= 0.5
            del level, u
        np.clip(land, 0.0, 1.0, out=land)
        reflectance[r0:r1] = land
    reflectance.flags.writeable = False
    mask.flags.writeable = False
    return Texture(reflectance, transform, mask, posting)


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
    rows, cols = texture.lonlat_to_pixel(lon, lat)
    t = texture.transform
    n_rows, n_cols = texture.shape
    out = np.array(texture.reflectance)
    for i in range(lon.size):
        inside = False
        if np.isfinite(rows[i]) and np.isfinite(cols[i]) and abs(lat[i]) < 90.0:
            m_m, n_m = _radii_m(float(lat[i]))
            sx = radius[i] / (math.radians(t.a) * n_m * math.cos(math.radians(lat[i])))
            sy = radius[i] / (math.radians(-t.e) * m_m)
            half_r, half_c = math.ceil(5.0 * sy) + 1, math.ceil(5.0 * sx) + 1
            r_lo, r_hi = math.floor(rows[i]) - half_r, math.ceil(rows[i]) + half_r + 1
            c_lo, c_hi = math.floor(cols[i]) - half_c, math.ceil(cols[i]) + half_c + 1
            inside = r_lo >= 0 and c_lo >= 0 and r_hi <= n_rows and c_hi <= n_cols
        if not inside:
            raise InputError(
                f"point target {i} at lon {lon[i]:.7f}, lat {lat[i]:.7f} with radius_m "
                f"{radius[i]:g} is not inside texture bounds {texture.bounds_lonlat} "
                "(with a pad of 5 radii)"
            )
        rr = (np.arange(r_lo, r_hi) - rows[i])[:, None] / sy
        cc = (np.arange(c_lo, c_hi) - cols[i])[None, :] / sx
        rho = np.sqrt(rr * rr + cc * cc)
        window = out[r_lo:r_hi, c_lo:c_hi]
        inner = rho <= 4.0
        pad = min(float(window[inner].mean()), 1.0 - peak[i])
        weight = np.where(rho <= 4.0, 1.0, np.cos(0.5 * np.pi * np.clip(rho - 4.0, 0.0, 1.0)) ** 2)
        blob = pad + peak[i] * np.exp(-0.5 * rho * rho)
        out[r_lo:r_hi, c_lo:c_hi] = (window + weight * (blob - window)).astype(np.float32)
    np.clip(out, 0.0, 1.0, out=out)
    out.flags.writeable = False
    return Texture(out, texture.transform, texture.uniform_mask, texture.posting_m)


__all__ = [
    "MAX_GRID_PX",
    "MAX_GRID_SIDE_PX",
    "TERRAINS",
    "TerrainPreset",
    "Texture",
    "add_point_targets",
    "geographic_grid",
    "grid_spacing_deg",
    "make_terrain",
    "make_texture",
    "terrain_from_dem",
    "uniform_mask_from_dem",
]
