"""Synthetic terrain for the scene simulator, with known truth.

The simulator renders satellite images of a ground whose heights and reflectance are known
exactly. This module makes the heights and the grids; :mod:`carto.framework.simulation.texture`
makes the reflectance on them:

* :func:`make_terrain`: a :class:`~carto.framework.raster.dem.DEM` of one of the :data:`TERRAINS`
  presets, modelled on the test sites of Radhadevi et al. (2010, Cartosat-1 large-scale
  mapping): flat coastal land with large water bodies, plains, mixed terrain, hills and high
  mountains. :func:`terrain_from_dem` puts any DEM (a user's GeoTIFF) on the same kind of grid.
* :func:`~carto.framework.simulation.texture.make_texture`: a
  :class:`~carto.framework.simulation.texture.Texture`, the ground reflectance in [0, 1] on a
  finer grid (see :mod:`carto.framework.simulation.texture`).

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
    component: white noise from the seeded generator filtered by ``sqrt(S(k)) / spacing`` in the
    Fourier domain (:class:`carto.framework.simulation.fields.LatticeField`). ``S`` is
    normalised in continuous wavenumber, so the statistics are the same whatever the posting and
    the size of the area. The field is synthesised once on a lattice that covers the grid padded
    by twice the correlation length on every side, so its opposite edges are unrelated (no
    wrap-around): the grid itself when that is small, else a coarse lattice of at most ~1024
    nodes a side (the former low band; wavelengths shorter than a few coarse nodes, a few per
    cent of the slope variance, are missing), and any window of the grid is its Keys cubic
    interpolation (:class:`ProceduralTerrain`: a scene's DEM never exists whole, and a node has
    the same height whatever the window). Hills and mountains mix in ridged multifractal noise
    (four octaves of crests ``exp(-|g|)`` along the zero lines of smooth fields, each octave
    weighted by the one before): a network of sharp ridges with spurs. ``z`` is mapped to
    heights by a fixed (not per-area) law: ``[-s, s]`` standard deviations (``s =
    spread_sigma``, 3) map linearly onto ``[h_min_m, h_max_m]`` with a smooth tanh saturation of
    the outer quarter at both ends, so heights never leave the preset's range. Presets with a
    ``uniform_fraction`` clamp ``z`` from below at that quantile of the unit normal: those areas
    (water, sand) are exactly flat at ``h_min_m``, and the clamped range ``[q, s]`` maps onto
    the height range.

    Statistics on 12 km x 12 km at 5 m posting, seed 1 (slopes by central differences over
    the ground distances; over 10 seeds of 20 km x 20 km at 50 m the heights span 0.75-0.96
    of each preset's range and the flat fraction of flat-coastal is 0.26-0.43, mean 0.34)::

        preset        heights (m)     slope p50 / p95 / p99 / max (deg)   flat fraction
        flat-coastal     0.0 ..   40   0.9 /  2.4 /  3.1 /  4.9           0.27
        plains         200.0 ..  279   1.0 /  2.2 /  2.6 /  3.7           0.04
        mixed          500.0 ..  677   3.5 /  7.4 /  9.1 / 14.3           0.02
        hilly          200.0 ..  752  10.2 / 22.4 / 27.8 / 42.6           0.02
        mountains     4198   .. 5828  21.3 / 41.7 / 49.1 / 63.3           0

    ``urban`` is the plains' relief (200-240 m) with flat-roofed buildings 6-60 m tall on
    80 m blocks (:mod:`carto.framework.simulation.buildings`): vertical breaks, where a
    correlation window straddles two surfaces and a wall hides the ground behind it in one
    view.

    A 2 km x 2 km area only holds part of the relief (wavelengths reach 5-10 km): over 10
    seeds it spans 0.35-0.57 of the height range on average, and its slope percentiles vary
    with the seed (at 5 m, p95 29-47 deg for mountains, 1.3-2.7 deg for plains). Slopes grow
    slowly with finer postings (mountains p95 37 deg at 50 m, 42 deg at 5 m).

The table was measured with the former whole-grid synthesis (the same large-scale relief for a
seed; the tests bound the same statistics). Memory: the lattices of a terrain take at most
~5 x 4 MB (mountains), whatever the area; a window costs about 100 bytes per node while it
is computed.
"""

from __future__ import annotations

import functools
import math
import numbers
import types
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.frames import WGS84_A_M, WGS84_E2
from carto.framework.raster.dem import DEM, ELLIPSOID
from carto.framework.simulation.fields import LatticeField, linear_matrix, resample
from carto.framework.simulation.grid_windows import bilinear_heights, centre_bounds

if TYPE_CHECKING:
    from affine import Affine

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
BoolArray = NDArray[np.bool_]
Bounds = tuple[float, float, float, float]

MAX_GRID_SIDE_PX = 30000
"""Largest number of rows or columns of a grid (OpenCV's warps take at most 32767)."""
MAX_GRID_PX = 400_000_000
"""Largest number of pixels of a grid held whole in memory (a float32 texture of this size is
1.6 GB): :func:`make_terrain`, :func:`terrain_from_dem`, ``make_texture``."""
MAX_TILED_GRID_SIDE_PX = 400_000
MAX_TILED_GRID_PX = 20_000_000_000
"""Limits of a grid evaluated window by window (:class:`ProceduralTerrain` and the simulator's
texture): 20e9 pixels (about 30 full Cartosat-1 scenes' textures); only absurd areas reach
them."""


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
        building_fraction: expected share of the ground under flat-roofed buildings (0: none;
            the ``urban`` preset): blocks on a lattice of ``block_m`` cells, each cell a
            building or not, its footprint and height drawn per cell; walls are vertical
            between two nodes. The relief below them takes the range up to ``h_max_m`` less
            the tallest building.
        building_heights_m: the range of building heights, metres.
        block_m: side of a city block (a lattice cell), metres.
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
    building_fraction: float = attrs.field(default=0.0, converter=float, validator=_unit_interval)
    building_heights_m: tuple[float, float] = attrs.field(
        default=(6.0, 60.0), converter=lambda v: (float(v[0]), float(v[1]))
    )
    block_m: float = attrs.field(default=80.0, converter=float, validator=_positive)

    @property
    def relief_max_m(self) -> float:
        """The top of the relief below the buildings."""
        if self.building_fraction > 0.0:
            return self.h_max_m - self.building_heights_m[1]
        return self.h_max_m

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
        low, high = self.building_heights_m
        if self.building_fraction > 0.0 and not (
            0.0 < low <= high and self.h_min_m < self.relief_max_m
        ):
            raise InputError(
                f"terrain preset {self.name!r}: building heights must be 0 < low <= high with "
                f"room below h_max_m, got {self.building_heights_m}"
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
                "urban",
                "a city on plains: flat-roofed blocks 6-60 m tall, vertical walls, streets",
                200.0,
                300.0,
                correlation_length_m=8000.0,
                spectral_exponent=5.0,
                building_fraction=0.35,
                building_heights_m=(6.0, 60.0),
                block_m=80.0,
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
def radii_m(lat_deg: float) -> tuple[float, float]:
    """Meridional and prime-vertical radii of curvature of WGS84 at ``lat_deg``, metres."""
    s = math.sin(math.radians(lat_deg))
    w2 = 1.0 - WGS84_E2 * s * s
    return WGS84_A_M * (1.0 - WGS84_E2) / w2**1.5, WGS84_A_M / math.sqrt(w2)


def grid_spacing_deg(posting_m: float, lat_deg: float) -> tuple[float, float]:
    """``(dlon_deg, dlat_deg)`` whose ground lengths on the WGS84 ellipsoid at ``lat_deg``
    are both ``posting_m`` metres (``M dlat = N cos(lat) dlon = posting``)."""
    m_m, n_m = radii_m(lat_deg)
    dlat = math.degrees(posting_m / m_m)
    dlon = math.degrees(posting_m / (n_m * math.cos(math.radians(lat_deg))))
    return dlon, dlat


def check_posting(posting_m: Any, what: str = "posting_m") -> float:
    try:
        value = float(posting_m)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number of metres, got {posting_m!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise InputError(f"{what} must be a finite number of metres > 0, got {posting_m!r}")
    return value


def check_bounds(bounds_lonlat: Any) -> Bounds:
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


def check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def geographic_grid(
    bounds_lonlat: Bounds,
    posting_m: float,
    *,
    max_side: int = MAX_GRID_SIDE_PX,
    max_px: int = MAX_GRID_PX,
) -> tuple[Affine, tuple[int, int]]:
    """The EPSG:4326 grid of :func:`make_terrain`: ``(transform, (rows, cols))``.

    The spacing is :func:`grid_spacing_deg` at the centre latitude of the bounds; the first
    pixel centre is ``(west, north)`` and the last one is at or just beyond ``(east, south)``
    (less than one spacing beyond). Pixel-is-area: the transform maps pixel corners.

    Raises:
        InputError: bounds not ``(west, south, east, north)`` within -85..85 degrees of latitude
            and 10 degrees in extent, posting not > 0, or a grid larger than ``max_side`` /
            ``max_px`` (default :data:`MAX_GRID_SIDE_PX` / :data:`MAX_GRID_PX`).
    """
    from rasterio.transform import Affine

    west, south, east, north = check_bounds(bounds_lonlat)
    posting = check_posting(posting_m)
    dlon, dlat = grid_spacing_deg(posting, 0.5 * (south + north))
    n_cols = math.ceil((east - west) / dlon - 1e-9) + 1
    n_rows = math.ceil((north - south) / dlat - 1e-9) + 1
    if max(n_rows, n_cols) > max_side or n_rows * n_cols > max_px:
        raise InputError(
            f"posting_m {posting:g} over bounds {(west, south, east, north)} makes a grid of "
            f"{n_rows} x {n_cols} pixels, more than {max_side} per side or "
            f"{max_px:.3g} in all; use a coarser posting or a smaller area"
        )
    transform = Affine(dlon, 0.0, west - 0.5 * dlon, 0.0, -dlat, north + 0.5 * dlat)
    return transform, (n_rows, n_cols)


def grid_centres(transform: Affine, shape: tuple[int, int]) -> tuple[FloatArray, FloatArray]:
    """Longitudes of the column centres and latitudes of the row centres of a north-up grid."""
    n_rows, n_cols = shape
    lon = transform.c + transform.a * (np.arange(n_cols) + 0.5)
    lat = transform.f + transform.e * (np.arange(n_rows) + 0.5)
    return lon, lat


def is_north_up_lonlat(dem: DEM) -> bool:
    t = dem.transform
    geographic = dem.crs.is_geographic and dem.crs.equals("EPSG:4326", ignore_axis_order=True)
    return bool(geographic and t.b == 0.0 and t.d == 0.0 and t.a > 0.0 and t.e < 0.0)


# ----------------------------------------------------------------------------- heights
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


def _ridged_multifractal(fields: list[FloatArray]) -> FloatArray:
    """Ridged multifractal noise (Musgrave) from the smooth unit fields ``g_k`` of its
    octaves, standardised to zero mean and unit variance.

    Octave ``k`` (outer scale ``wavelength_m / 2^k``, spectral exponent 6) contributes
    ``0.5^k`` times the crest signal ``exp(-|g_k|)``, weighted by twice the previous octave's
    signal (clipped to 1): small crests branch off the large ones, giving a network of sharp
    ridges with spurs between broader valleys.
    """
    total = np.zeros(fields[0].shape)
    signal: FloatArray | None = None
    for k, g in enumerate(fields):
        current = _ridge_signal(g)
        if signal is not None:
            current *= np.clip(signal * _RIDGE_GAIN, 0.0, 1.0)
        total += 0.5**k * current
        signal = current
    mean, std = _ridged_moments()
    return (total - mean) / std


def _heights_from_field(preset: TerrainPreset, z: FloatArray) -> FloatArray:
    """The fixed law from the unit field ``z`` to heights (metres) of ``preset``."""
    from scipy.special import ndtri

    s = preset.spread_sigma
    if preset.uniform_fraction > 0.0:
        q = float(ndtri(preset.uniform_fraction))
        frac = _softclip((np.maximum(z, q) - q) / (s - q), lower=False)
        frac[z <= q] = 0.0  # exactly flat
    else:
        frac = _softclip(0.5 + 0.5 * z / s)
    return preset.h_min_m + (preset.relief_max_m - preset.h_min_m) * frac


class ProceduralTerrain:
    """A synthetic terrain of a preset, evaluated window by window on its grid.

    The grid is :func:`geographic_grid` of the bounds (up to :data:`MAX_TILED_GRID_PX`
    nodes); its heights never exist whole in memory: :meth:`window` computes any window from
    a few bounded lattices (:class:`~carto.framework.simulation.fields.LatticeField`), with the
    same value at a node whatever the window.

    Attributes:
        preset: the terrain preset.
        transform, shape: the grid (EPSG:4326, pixel-is-area).
        source: ``"terrain 'hilly' seed 3"``.
    """

    crs = "EPSG:4326"

    def __init__(
        self, name: str | TerrainPreset, bounds_lonlat: Bounds, posting_m: float, seed: int
    ) -> None:
        self.preset = preset = _preset(name)
        self.transform, self.shape = geographic_grid(
            bounds_lonlat, posting_m, max_side=MAX_TILED_GRID_SIDE_PX, max_px=MAX_TILED_GRID_PX
        )
        rng = np.random.default_rng(check_seed(seed))
        posting = float(posting_m)
        beta = preset.spectral_exponent
        components = [(beta, preset.correlation_length_m, 1.0)]
        if preset.detail_weight > 0.0:
            components.append((beta, preset.detail_length_m, preset.detail_weight))
        self._main = LatticeField(rng, self.shape, posting, components)
        self._ridges = [
            LatticeField(rng, self.shape, posting, [(6.0, preset.ridge_wavelength_m / 2**k, 1.0)])
            for k in range(_RIDGE_OCTAVES if preset.ridge_weight > 0.0 else 0)
        ]
        self.source = f"terrain {preset.name!r} seed {int(seed)}"
        self._seed, self._posting = int(seed), posting

    @property
    def height_range(self) -> tuple[float, float]:
        """Bounds of the heights (the preset's range), metres."""
        return self.preset.h_min_m, self.preset.h_max_m

    @property
    def bounds_lonlat(self) -> Bounds:
        """``(west, south, east, north)`` of the span of the node centres."""
        return centre_bounds(self.transform, self.shape)

    def window(self, r0: int, r1: int, c0: int, c1: int) -> FloatArray:
        """Heights (float64, metres) at rows ``[r0, r1)`` and columns ``[c0, c1)``."""
        z = self._main.window(r0, r1, c0, c1)
        if self._ridges:
            w = self.preset.ridge_weight
            norm = math.hypot(w, 1.0 - w)
            ridged = _ridged_multifractal([f.window(r0, r1, c0, c1) for f in self._ridges])
            z = z * ((1.0 - w) / norm) + ridged * (w / norm)
        heights = _heights_from_field(self.preset, z)
        if self.preset.building_fraction > 0.0:
            from carto.framework.simulation.buildings import building_heights

            heights = heights + building_heights(
                self.preset, self._seed, (r0, r1, c0, c1), self._posting
            )
        return heights

    def height(self, lon_deg: Any, lat_deg: Any) -> FloatArray:
        """Bilinear height at WGS84 lon/lat (NaN outside the node centres), as
        :meth:`DEM.height` of the whole grid."""
        return bilinear_heights(self, lon_deg, lat_deg)

    def to_dem(self) -> DEM:
        """The whole grid as a :class:`DEM` (small areas only)."""
        n_rows, n_cols = self.shape
        if n_rows * n_cols > MAX_GRID_PX:
            raise InputError(
                f"terrain grid of {n_rows} x {n_cols} nodes is too large to hold whole "
                f"(more than {MAX_GRID_PX}); evaluate it by windows"
            )
        heights = self.window(0, n_rows, 0, n_cols)
        return DEM(heights, self.transform, "EPSG:4326", vertical=ELLIPSOID, source=self.source)


class GridTerrain:
    """A terrain held whole in memory (a DEM on the simulator's grid), with the interface of
    :class:`ProceduralTerrain` (user DEMs, tests)."""

    crs = "EPSG:4326"

    def __init__(self, dem: DEM) -> None:
        self.dem = dem
        self.transform, self.shape, self.source = dem.transform, dem.shape, dem.source
        lo, hi = np.nanmin(dem.heights), np.nanmax(dem.heights)
        self.height_range = (float(lo), float(hi))

    @property
    def bounds_lonlat(self) -> Bounds:
        return centre_bounds(self.transform, self.shape)

    def window(self, r0: int, r1: int, c0: int, c1: int) -> FloatArray:
        return np.array(self.dem.heights[r0:r1, c0:c1], dtype=np.float64)

    def height(self, lon_deg: Any, lat_deg: Any) -> FloatArray:
        return bilinear_heights(self, lon_deg, lat_deg)


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
            ``"hilly"``, ``"urban"``, ``"mountains"``) or a :class:`TerrainPreset`.
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
    geographic_grid(bounds_lonlat, posting_m)  # the limits of a grid held whole
    return ProceduralTerrain(name, bounds_lonlat, posting_m, seed).to_dem()


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
    dem.check_ellipsoidal("the simulator's terrain")
    transform, shape = geographic_grid(bounds_lonlat, posting_m)
    _, south, east, _ = check_bounds(bounds_lonlat)
    lon, lat = grid_centres(transform, shape)
    lon = np.minimum(lon, east)
    lat = np.maximum(lat, south)
    # the grid's outline first: the DEM's own message names what it covers
    outline_lon = np.concatenate([lon, lon, np.full(lat.size, lon[0]), np.full(lat.size, lon[-1])])
    outline_lat = np.concatenate([np.full(lon.size, lat[0]), np.full(lon.size, lat[-1]), lat, lat])
    dem.height(outline_lon, outline_lat, strict=True)
    if is_north_up_lonlat(dem):  # separable: exact bilinear by two sparse products
        rows = dem.lonlat_to_pixel(np.full(lat.size, lon[0]), lat)[0]
        cols = dem.lonlat_to_pixel(lon, np.full(lon.size, lat[0]))[1]
        r0, c0 = max(math.floor(rows.min()), 0), max(math.floor(cols.min()), 0)
        r1 = min(math.ceil(rows.max()) + 1, dem.shape[0])
        c1 = min(math.ceil(cols.max()) + 1, dem.shape[1])
        window = dem.heights[r0:r1, c0:c1]
        heights = resample(
            window, linear_matrix(rows - r0, r1 - r0), linear_matrix(cols - c0, c1 - c0)
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
            f"of {heights.size} nodes inside bounds {check_bounds(bounds_lonlat)}"
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


__all__ = [
    "MAX_GRID_PX",
    "MAX_GRID_SIDE_PX",
    "MAX_TILED_GRID_PX",
    "TERRAINS",
    "GridTerrain",
    "ProceduralTerrain",
    "TerrainPreset",
    "geographic_grid",
    "grid_spacing_deg",
    "make_terrain",
    "terrain_from_dem",
    "uniform_mask_from_dem",
]
