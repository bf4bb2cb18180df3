"""Ground texture for the scene simulator, with known truth.

* :func:`make_texture`: a :class:`Texture`, the ground reflectance in [0, 1] on a grid finer
  than the DEM's: agricultural parcels, field boundaries, roads, natural cover, multi-scale
  fine texture, Lambertian terrain shading, and nearly uniform water or sand where the DEM is
  exactly flat.
* :func:`add_point_targets` adds bright Gaussian blobs centred on given ground points.

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

Memory and speed (2 cores): :func:`make_texture` on 10000 x 10000 pixels (12 km at 1.2 m) takes
about 6-7 s and, besides its result (float32 reflectance and boolean mask, 500 MB), 200-300 MB:
the full-resolution stage runs in strips of 256 rows and every intermediate is float32.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.raster.dem import DEM, bilinear_sample, to_affine
from carto.framework.simulation.fields import (
    NoisePyramid,
    linear_matrix,
    resample,
    spectral_field,
)
from carto.framework.simulation.terrain import (
    Bounds,
    check_posting,
    check_seed,
    geographic_grid,
    grid_centres,
    is_north_up_lonlat,
    radii_m,
    uniform_mask_from_dem,
)

if TYPE_CHECKING:
    import pyproj
    from affine import Affine

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
BoolArray = NDArray[np.bool_]

_STRIP_ROWS = 256  # rows of the full-resolution texture computed at a time
_COARSE = 4  # texture pixels per node of the coarse texture grid (shading, land use)
_AMBIENT = 0.2  # sky-light share of the illumination of flat ground


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
    heights = resample(
        dem.heights,
        linear_matrix(rows_f, dem.shape[0], extrapolate=True),
        linear_matrix(cols_f, dem.shape[1], extrapolate=True),
    )
    rows_m, cols_m = linear_matrix(rows_f, dem.shape[0]), linear_matrix(cols_f, dem.shape[1])
    # gradient in metres: east and north
    dlon = abs(float(lon_c[1] - lon_c[0])) if lon_c.size > 1 else 1.0
    dlat = abs(float(lat_c[1] - lat_c[0])) if lat_c.size > 1 else 1.0
    radii = np.array([radii_m(v) for v in lat_c])
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
    land_use = spectral_field(rng, slope_deg.shape, posting_c_m, [(3.6, 600.0, 1.0)])
    field_w = _smoothstep(12.0, 4.0, slope_deg) * _smoothstep(-1.2, -0.6, land_use)
    del land_use
    # natural cover: dark vegetation / brighter soil patches, bare rock on steep slopes
    patches = spectral_field(rng, slope_deg.shape, posting_c_m, [(3.0, 150.0, 1.0)])
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
        uniform_w = resample(blurred, rows_m, cols_m).astype(np.float32)
        premult = resample(level[labels] * blurred, rows_m, cols_m).astype(np.float32)
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
        dem: a north-up EPSG:4326 DEM without nodata
            (:func:`~carto.framework.simulation.terrain.make_terrain`,
            :func:`~carto.framework.simulation.terrain.terrain_from_dem`).
        posting_m: texture ground spacing at the centre latitude, metres (e.g. half the ground
            sample distance of the images to render).
        seed: random seed (integer >= 0); same seed and arguments give identical textures.
        sun_elevation_deg: sun elevation above the horizon for the shading, degrees (0-90].
        sun_azimuth_deg: sun azimuth clockwise from north, degrees.
        uniform_mask: bool array of the DEM's shape, True on uniform ground (water, sand);
            default :func:`~carto.framework.simulation.terrain.uniform_mask_from_dem` (exactly
            flat areas).

    Returns:
        A :class:`Texture` whose pixel centres start at the DEM's first pixel centre and cover
        the DEM's pixel centres (overhanging by less than one texture pixel).

    Raises:
        InputError: not a north-up EPSG:4326 DEM, nodata in the DEM, a bad posting, seed, sun
            angle or mask shape, or a texture larger than
            :data:`~carto.framework.simulation.terrain.MAX_GRID_PX`.
    """
    import cv2

    dem = _check_lonlat_dem(dem, "make_texture")
    posting = check_posting(posting_m)
    rng = np.random.default_rng(check_seed(seed))
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
    lon_t, lat_t = grid_centres(transform, shape)
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
    noise = NoisePyramid(rng, shape)

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
            m_m, n_m = radii_m(float(lat[i]))
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
    "Texture",
    "add_point_targets",
    "make_texture",
]
