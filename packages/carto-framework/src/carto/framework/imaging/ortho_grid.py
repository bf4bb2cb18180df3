"""The output grid of orthorectification: a north-up map grid over one or several images.

:class:`OrthoGrid` is a CRS, a north-up affine transform of pixel corners and a shape;
:meth:`OrthoGrid.covering` builds the grid that covers one or several images (their borders
located on the DEM) or given bounds, snapped to the resolution. The mapping onto a grid and
the resampling are in :mod:`carto.framework.imaging.ortho`.

Conventions
    * Ortho pixels are areas: the transform maps pixel corners; pixel ``(row, col)`` stands at
      its centre ``(col + 0.5, row + 0.5)``. Grids are north-up (no rotation).
    * The DEM holds ellipsoidal heights (:class:`carto.framework.raster.dem.DEM`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.raster.dem import DEM

if TYPE_CHECKING:  # pyproj and affine are imported when used
    import pyproj
    from affine import Affine

FloatArray = NDArray[np.float64]
Bounds = tuple[float, float, float, float]

MAX_GRID_CELLS = 400_000_000
"""Most cells of a grid built by :meth:`OrthoGrid.covering` (and of the grids of a DEM
generator): 4e8 cells are 1.6 GB per float32 layer, and orthorectification or a DEM
generator holds several layers of the grid's size (the ortho-images, the mapping, the score);
a full 12000 x 12000 px scene at its own resolution is 1.44e8 cells. Larger grids are refused
before anything is allocated."""


# ----------------------------------------------------------------------------- helpers
def _to_crs(value: Any) -> pyproj.CRS:
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"ortho grid: crs {value!r} is not a CRS pyproj knows") from exc
    if not (crs.is_projected or crs.is_geographic):
        raise InputError(f"ortho grid: crs {crs.name} is neither projected nor geographic")
    return crs


def _to_affine(value: Any) -> Affine:
    from affine import Affine

    if isinstance(value, Affine):
        return value
    try:
        coefficients = tuple(float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"ortho grid: transform {value!r} is not an affine transform") from exc
    if len(coefficients) == 9:
        coefficients = coefficients[:6]
    if len(coefficients) != 6:
        raise InputError(f"ortho grid: transform needs 6 coefficients, got {len(coefficients)}")
    return Affine(*coefficients)


def _to_shape(value: Any) -> tuple[int, int]:
    try:
        rows, cols = (int(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"ortho grid: shape {value!r} is not (rows, cols)") from exc
    return rows, cols


@functools.lru_cache(maxsize=16)
def lonlat_transformer(crs_wkt: str) -> Any:
    """``crs -> EPSG:4326`` in lon/lat order, cached per CRS."""
    import pyproj

    return pyproj.Transformer.from_crs(
        pyproj.CRS.from_wkt(crs_wkt), pyproj.CRS.from_epsg(4326), always_xy=True
    )


@functools.lru_cache(maxsize=16)
def dem_transformer(crs_wkt: str) -> Any:
    """``EPSG:4326 -> crs`` in lon/lat order (a DEM's CRS), cached per CRS."""
    import pyproj

    return pyproj.Transformer.from_crs(
        pyproj.CRS.from_epsg(4326), pyproj.CRS.from_wkt(crs_wkt), always_xy=True
    )


def check_dem(dem: Any) -> DEM:
    """``dem`` if it is a :class:`DEM` with ellipsoidal heights; InputError otherwise."""
    if not isinstance(dem, DEM):
        raise InputError(f"dem must be a carto.framework.raster.dem.DEM, got {type(dem).__name__}")
    return dem.check_ellipsoidal("orthorectification")


def check_grid_size(
    width: float,
    height: float,
    resolution: float,
    *,
    what: str = "ortho grid",
    option: str = "resolution",
    unit: str = "m",
    max_cells: float = MAX_GRID_CELLS,
) -> tuple[int, int]:
    """``(rows, cols)`` of a grid of ``resolution`` over ``width x height`` (CRS units), or
    InputError (one line) naming ``option``, its value, the area and the grid size when the
    grid would hold more than ``max_cells`` cells. Nothing is allocated."""
    res = float(resolution)
    if not (math.isfinite(res) and res > 0.0):
        raise InputError(f"{what}: {option} {resolution!r} must be a finite number > 0")
    cols = max(math.ceil(float(width) / res - 1e-9), 1)
    rows = max(math.ceil(float(height) / res - 1e-9), 1)
    if float(rows) * float(cols) > max_cells:
        coarsest = res * math.sqrt(float(rows) * float(cols) / max_cells)
        raise InputError(
            f"{what}: {option} {res:g} {unit} over a footprint of {width:.6g} x {height:.6g} "
            f"{unit} gives {cols} x {rows} = {float(rows) * float(cols):.3g} cells, more than "
            f"{max_cells:.3g}; use a {option} of at least {coarsest:.3g} {unit}"
        )
    return rows, cols


def check_sensor(sensor: Any) -> Sensor:
    """``sensor`` if it is a :class:`Sensor`; InputError otherwise."""
    if not isinstance(sensor, Sensor):
        raise InputError(f"sensor must be a carto Sensor, got {type(sensor).__name__}")
    return sensor


# ----------------------------------------------------------------------------- grid
@attrs.frozen
class OrthoGrid:
    """A north-up map grid: CRS, affine transform of pixel corners, ``(rows, cols)``.

    Attributes:
        crs: the map CRS (:class:`pyproj.CRS`; anything ``CRS.from_user_input`` takes).
        transform: :class:`affine.Affine` ``(res_x, 0, left, 0, -res_y, top)`` of pixel corners.
        shape: ``(rows, cols)``.
    """

    crs: pyproj.CRS = attrs.field(converter=_to_crs)
    transform: Affine = attrs.field(converter=_to_affine)
    shape: tuple[int, int] = attrs.field(converter=_to_shape)

    def __attrs_post_init__(self) -> None:
        t = self.transform
        if t.b != 0.0 or t.d != 0.0 or not (t.a > 0.0 and t.e < 0.0):
            raise InputError(
                f"ortho grid: transform {tuple(t)[:6]} is not north-up "
                "(need a > 0, e < 0, no rotation)"
            )
        if not all(math.isfinite(v) for v in tuple(t)[:6]):
            raise InputError(f"ortho grid: transform {tuple(t)[:6]} is not finite")
        if min(self.shape) < 1:
            raise InputError(f"ortho grid: shape {self.shape} must be at least 1 x 1")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def covering(
        cls,
        sensors: Sensor | Sequence[Sensor],
        dem: DEM,
        resolution_m: float,
        crs: Any = None,
        bounds: Bounds | None = None,
        max_cells: float = MAX_GRID_CELLS,
    ) -> OrthoGrid:
        """The grid at ``resolution_m`` that covers the images' footprints (or ``bounds``).

        The footprint of each image is its border (every edge sampled at 33 points) located on
        the DEM (:meth:`Sensor.locate_on_dem`; where the line of sight misses the DEM, at the
        DEM's middle height). The grid edges are snapped outwards to multiples of the
        resolution, so grids of the same resolution and CRS are aligned.

        Args:
            sensors: one sensor or several.
            dem: DEM with ellipsoidal heights.
            resolution_m: pixel size in CRS units (metres for projected CRSs).
            crs: the map CRS; default the WGS84 UTM zone of the footprint's centre.
            bounds: ``(left, bottom, right, top)`` in ``crs`` (or in the default UTM CRS) to
                cover instead of the footprint.
            max_cells: refuse a grid of more cells (:func:`check_grid_size`).

        Raises:
            InputError: no sensor, bad resolution or bounds, a footprint entirely off the DEM,
                a grid of more than ``max_cells`` cells.
        """
        sensor_list = [sensors] if isinstance(sensors, Sensor) else list(sensors)
        for s in sensor_list:
            check_sensor(s)
        check_dem(dem)
        res = float(resolution_m)
        if not (math.isfinite(res) and res > 0.0):
            raise InputError(f"ortho grid: resolution {resolution_m!r} must be > 0")
        if not sensor_list and (crs is None or bounds is None):
            raise InputError("ortho grid: give at least one sensor, or both crs and bounds")
        if bounds is None:
            crs_obj, box = footprint_box(sensor_list, dem, crs)
        else:
            crs_obj = _to_crs(crs) if crs is not None else footprint_box(sensor_list, dem)[0]
            box = tuple(float(v) for v in bounds)  # type: ignore[assignment]
            if len(box) != 4 or not all(map(math.isfinite, box)):
                raise InputError(f"ortho grid: bounds {bounds!r} must be 4 finite numbers")
        left, bottom, right, top = box
        if not (left < right and bottom < top):
            raise InputError(
                f"ortho grid: bounds {box} must be (left, bottom, right, top) with "
                "left < right and bottom < top"
            )
        eps = 1e-9
        unit = "m" if crs_obj.is_projected else "degrees"
        check_grid_size(right - left, top - bottom, res, unit=unit, max_cells=max_cells)
        x0 = math.floor(left / res + eps) * res
        x1 = math.ceil(right / res - eps) * res
        y0 = math.floor(bottom / res + eps) * res
        y1 = math.ceil(top / res - eps) * res
        cols = max(round((x1 - x0) / res), 1)
        rows = max(round((y1 - y0) / res), 1)
        from affine import Affine

        return cls(crs_obj, Affine(res, 0.0, x0, 0.0, -res, y1), (rows, cols))

    # ------------------------------------------------------------------ properties
    @property
    def resolution(self) -> tuple[float, float]:
        """``(res_x, res_y)``, positive, in CRS units."""
        return float(self.transform.a), float(-self.transform.e)

    @property
    def bounds(self) -> Bounds:
        """``(left, bottom, right, top)`` of the outer pixel edges, in CRS units."""
        t = self.transform
        rows, cols = self.shape
        return (t.c, t.f + t.e * rows, t.c + t.a * cols, t.f)

    def xy(self, row: ArrayLike, col: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Map coordinates of pixel centres: 0-based ``(row, col)`` indices (fractional ok)."""
        t = self.transform
        r, c = np.broadcast_arrays(np.asarray(row, np.float64), np.asarray(col, np.float64))
        return t.c + t.a * (c + 0.5), t.f + t.e * (r + 0.5)

    def lonlat(self, row: ArrayLike, col: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """WGS84 ``(lon_deg, lat_deg)`` of pixel centres."""
        x, y = self.xy(row, col)
        lon, lat = lonlat_transformer(self.crs.to_wkt()).transform(x, y)
        return np.asarray(lon, np.float64), np.asarray(lat, np.float64)

    def map_xy(self, lon: ArrayLike, lat: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Map coordinates (CRS units) of WGS84 ``(lon_deg, lat_deg)`` points."""
        x, y = dem_transformer(self.crs.to_wkt()).transform(
            np.asarray(lon, np.float64), np.asarray(lat, np.float64)
        )
        return np.asarray(x, np.float64), np.asarray(y, np.float64)

    def rowcol(self, lon: ArrayLike, lat: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Fractional 0-based ``(row, col)`` of WGS84 points (pixel centres at whole numbers:
        the inverse of :meth:`lonlat`)."""
        x, y = self.map_xy(lon, lat)
        t = self.transform
        return (y - t.f) / t.e - 0.5, (x - t.c) / t.a - 0.5

    def window(self, row0: int, col0: int, n_rows: int, n_cols: int) -> OrthoGrid:
        """The sub-grid of ``n_rows x n_cols`` pixels starting at pixel ``(row0, col0)``."""
        from affine import Affine

        return OrthoGrid(
            self.crs, self.transform @ Affine.translation(col0, row0), (n_rows, n_cols)
        )


def footprint_box(
    sensors: Sensor | Sequence[Sensor], dem: DEM, crs: Any = None
) -> tuple[pyproj.CRS, Bounds]:
    """The map CRS (``crs``, default the WGS84 UTM zone of the footprint's centre) and the
    ``(left, bottom, right, top)`` box, in it, of the images' borders located on ``dem`` (not
    snapped to any resolution)."""
    import pyproj

    from carto.framework.raster.crs import utm_crs

    sensor_list = [sensors] if isinstance(sensors, Sensor) else list(sensors)
    if not sensor_list:
        raise InputError("ortho grid: give at least one sensor")
    lon, lat = _footprint(sensor_list, check_dem(dem))
    if crs is None:
        lon_c = 0.5 * (lon.min() + lon.max())
        lat_c = 0.5 * (lat.min() + lat.max())
        crs_obj = utm_crs(float(lon_c), float(lat_c))
    else:
        crs_obj = _to_crs(crs)
    to_map = pyproj.Transformer.from_crs(pyproj.CRS.from_epsg(4326), crs_obj, always_xy=True)
    x, y = (np.asarray(v, np.float64) for v in to_map.transform(lon, lat))
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        raise InputError(f"ortho grid: the images' footprint has no coordinates in {crs_obj.name}")
    x, y = x[ok], y[ok]
    return crs_obj, (float(x.min()), float(y.min()), float(x.max()), float(y.max()))


def _footprint(sensors: Sequence[Sensor], dem: DEM) -> tuple[FloatArray, FloatArray]:
    """lon/lat of the images' borders on the DEM (NaN-free), concatenated."""
    lo, hi = dem.height_range
    h_mid = 0.5 * (lo + hi)
    lons, lats = [], []
    t = np.linspace(0.0, 1.0, 33)
    for sensor in sensors:
        n_l, n_s = sensor.image_shape
        line = np.concatenate([0 * t, t * n_l, 0 * t + n_l, t * n_l])
        sample = np.concatenate([t * n_s, 0 * t, t * n_s, 0 * t + n_s])
        lon, lat, _h = sensor.locate_on_dem(line, sample, dem)
        miss = ~(np.isfinite(lon) & np.isfinite(lat))
        if miss.any():
            lon_m, lat_m = sensor.image_to_ground(
                line[miss], sample[miss], np.full(miss.sum(), h_mid)
            )
            lon, lat = lon.copy(), lat.copy()
            lon[miss], lat[miss] = lon_m, lat_m
        ok = np.isfinite(lon) & np.isfinite(lat)
        if not ok.any():
            raise InputError(
                f"ortho grid: the footprint of image {getattr(sensor, 'name', '?')} cannot be "
                f"located (on DEM {dem.name})"
            )
        lons.append(lon[ok])
        lats.append(lat[ok])
    lon = np.concatenate(lons)
    lat = np.concatenate(lats)
    lon = lon[0] + (np.mod(lon - lon[0] + 180.0, 360.0) - 180.0)  # no jump at the antimeridian
    return lon, lat
