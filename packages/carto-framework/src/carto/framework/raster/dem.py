"""Digital elevation models: reading, bilinear sampling, geoid conversion, location on a DEM.

Besides the :class:`DEMGenerator` component contract that plugins use to add DEM generators,
this module holds the DEM that every other part of Carto samples:

* :class:`DEM`: an immutable height grid with its affine transform and CRS (any CRS pyproj
  knows; geographic WGS84 ``EPSG:4326`` is the common case, UTM the other one), read from a
  GeoTIFF or an SRTM ``.hgt`` tile, sampled bilinearly at WGS84 longitudes and latitudes.
* :class:`Geoid`: a geoid undulation grid (a GDAL ``.gtx`` file such as EGM96 15').
* :func:`dem_surface_locate`: image point -> ground point on the DEM through any sensor.

Conventions
    * Longitudes and latitudes are WGS84 geodetic degrees; a DEM in another CRS is sampled by
      converting them to its CRS with pyproj (``always_xy``: x = easting or longitude).
    * Heights are metres. :attr:`DEM.vertical` says what they are above: ``"ellipsoid"`` (the
      WGS84 ellipsoid, the Carto convention, what sensors take) or ``"geoid:<NAME>"`` (e.g.
      ``"geoid:EGM96"`` for SRTM tiles: orthometric heights ``H``). The ellipsoidal height is
      ``h = H + N`` with ``N`` the geoid undulation (:meth:`DEM.to_ellipsoid`).
    * Pixel-is-area: the transform maps pixel *corners*; the value of pixel ``(row, col)``
      stands at its centre ``(col + 0.5, row + 0.5)``. GDAL already shifts the transform of
      pixel-is-point rasters (SRTM) by half a pixel, so their nodes land on pixel centres.
    * Bilinear interpolation between the four surrounding pixel centres. Heights are defined on
      the span of the pixel centres only (no extrapolation over the outer half pixel); outside
      it, or where any of the four neighbours is nodata, the height is NaN.
    * Nodata is NaN in memory; files are written as float32 GeoTIFF with NaN nodata and the
      vertical reference in the tag ``VERTICAL_REFERENCE`` (``"ellipsoid WGS84"`` or
      ``"geoid EGM96"``...).
    * Heights outside ``MIN_HEIGHT_M..MAX_HEIGHT_M`` (-1000..10000 m) and non-finite heights
      are nodata (undeclared voids: -9999, -32768; fill values: 1e30).
    * Bounds are ``(west, south, east, north)``.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.files.paths import existing_file
from carto.framework.raster.dem_file import MIN_DEM_POSTS as MIN_DEM_POSTS
from carto.framework.raster.dem_file import check_dem_file, vertical_of
from carto.framework.raster.gdal_errors import gdal_cause
from carto.framework.raster.grid_sampling import (
    EDGE_TOL_PX,
    bilinear_sample,
    bilinear_sample_grid,
)
from carto.framework.raster.vertical_reference import (
    EGM96 as EGM96,
)
from carto.framework.raster.vertical_reference import (
    ELLIPSOID,
    normalise_vertical,
    split_vertical,
)
from carto.framework.raster.vertical_reference import (
    VERTICAL_TAG as VERTICAL_TAG,
)

if TYPE_CHECKING:  # rasterio and pyproj are imported when a DEM is used, not at plugin discovery
    import pyproj
    from affine import Affine

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Bounds = tuple[float, float, float, float]


MIN_HEIGHT_M = -1000.0
MAX_HEIGHT_M = 10000.0
"""Plausible heights on Earth, metres (above the ellipsoid or the geoid): the Dead Sea shore
is at -430 m, Everest at 8849 m and geoid undulations stay within -107..+86 m. Anything
outside is nodata: undeclared voids (-9999, -32768), fill values (1e30), overflowed sums."""
MAX_UNDULATION_M = 150.0
"""Largest plausible |geoid undulation|, metres (EGM96 and EGM2008 stay within -107..+86 m)."""
# what to do about geoid heights (SRTM .hgt) where ellipsoidal heights are needed
GEOID_ADVICE = 'give the geoid grid with --geoid GTX (configuration key "geoid"), e.g. egm96_15.gtx'


# ----------------------------------------------------------------------------- helpers
def to_affine(value: Any) -> Affine:
    from rasterio.transform import Affine

    if isinstance(value, Affine):
        return value
    coefficients = tuple(float(v) for v in value)
    if len(coefficients) == 9:
        coefficients = coefficients[:6]
    if len(coefficients) != 6:
        raise InputError(
            f"DEM transform must be an Affine or its 6 coefficients (a, b, c, d, e, f), "
            f"got {value!r}"
        )
    return Affine(*coefficients)


def _to_crs(value: Any) -> pyproj.CRS:
    import pyproj

    try:
        return pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError as exc:
        raise InputError(f"crs {value!r} is not a CRS pyproj knows ({_first_line(exc)})") from exc


def _to_horizontal_crs(value: Any) -> pyproj.CRS:
    return split_vertical(_to_crs(value))[0]


def _readonly(array: ArrayLike) -> FloatArray:
    out = np.array(array, dtype=np.float64)  # always a copy
    out.flags.writeable = False
    return out


def _plausible_heights(array: ArrayLike) -> FloatArray:
    """A read-only float64 copy with non-finite heights and heights outside
    ``MIN_HEIGHT_M..MAX_HEIGHT_M`` set to NaN (nodata)."""
    out = np.array(array, dtype=np.float64)  # always a copy
    with np.errstate(invalid="ignore"):
        out[~((out >= MIN_HEIGHT_M) & (out <= MAX_HEIGHT_M))] = np.nan
    out.flags.writeable = False
    return out


_HEIGHT_RANGE = f"{MIN_HEIGHT_M:g}..{MAX_HEIGHT_M:g} m"


def _is_wgs84_lonlat(crs: pyproj.CRS) -> bool:
    return bool(crs.is_geographic and crs.equals("EPSG:4326", ignore_axis_order=True))


@functools.lru_cache(maxsize=32)
def _transformer(crs_wkt: str, forward: bool) -> Any:
    """``EPSG:4326 -> crs`` (forward) or back, lon/lat order, cached per CRS."""
    import pyproj

    lonlat = pyproj.CRS.from_epsg(4326)
    crs = pyproj.CRS.from_wkt(crs_wkt)
    if forward:
        return pyproj.Transformer.from_crs(lonlat, crs, always_xy=True)
    return pyproj.Transformer.from_crs(crs, lonlat, always_xy=True)


def _wrap_lon(lon: FloatArray, start: float) -> FloatArray:
    """Longitudes shifted by multiples of 360 into ``[start, start + 360)`` (start - 1e-12)."""
    start = start - 1e-12
    return start + np.mod(lon - start, 360.0)


def _fmt_bounds(bounds: Sequence[float]) -> str:
    w, s, e, n = bounds
    return f"lon {w:.6f}..{e:.6f}, lat {s:.6f}..{n:.6f}"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# ----------------------------------------------------------------------------- geoid
@attrs.frozen(eq=False)
class Geoid:
    """A geoid undulation grid ``N(lon, lat)`` in metres (``h_ellipsoid = H + N``).

    Attributes:
        undulations: ``(rows, cols)`` float64 grid, read-only; NaN = nodata.
        transform: affine transform (pixel corners, pixel-is-area) in lon/lat degrees.
        source: the file it was read from (for messages), or None.
    """

    undulations: FloatArray = attrs.field(converter=_readonly)
    transform: Affine = attrs.field(converter=to_affine)
    source: str | None = None
    _global: bool = attrs.field(init=False, repr=False)
    _padded: FloatArray = attrs.field(init=False, repr=False)

    def __attrs_post_init__(self) -> None:
        if self.undulations.ndim != 2 or min(self.undulations.shape) < 1:
            raise InputError(f"geoid {self.source}: undulations must be a 2-D grid")
        t = self.transform
        if t.b != 0.0 or t.d != 0.0:
            raise InputError(f"geoid {self.source}: rotated grids are not supported")
        if not (math.isfinite(t.a) and math.isfinite(t.e) and t.a > 0.0 and t.e < 0.0):
            raise InputError(
                f"geoid {self.source}: grid spacing (field transform) {t.a:g} degrees of "
                f"longitude by {-t.e:g} of latitude; both must be finite and > 0"
            )
        if not (math.isfinite(t.c) and math.isfinite(t.f)):
            raise InputError(f"geoid {self.source}: grid origin {t.c}, {t.f} is not finite")
        with np.errstate(invalid="ignore"):
            wild = ~np.isnan(self.undulations) & ~(np.abs(self.undulations) <= MAX_UNDULATION_M)
        if wild.any():
            row, col = (int(v[0]) for v in np.nonzero(wild))
            lon, lat = t.c + t.a * (col + 0.5), t.f + t.e * (row + 0.5)
            raise InputError(
                f"geoid {self.source}: undulation {self.undulations[row, col]:g} m at lon "
                f"{lon:.4f}, lat {lat:.4f} ({int(wild.sum())} nodes) is implausible "
                f"(|N| <= {MAX_UNDULATION_M:g} m on Earth; an undeclared nodata value?)"
            )
        n_cols = self.undulations.shape[1]
        is_global = math.isclose(abs(t.a) * n_cols, 360.0, rel_tol=1e-9)
        padded = self.undulations
        if is_global:  # repeat the first column after the last one: wrap-around interpolation
            padded = np.concatenate([padded, padded[:, :1]], axis=1)
            padded.flags.writeable = False
        object.__setattr__(self, "_global", is_global)
        object.__setattr__(self, "_padded", padded)

    @property
    def model(self) -> str:
        """The geoid model, from the grid's file name (``egm96_15.gtx``: ``"EGM96"``;
        ``egm08_25.gtx`` or ``us_nga_egm2008_1.tif``: ``"EGM2008"``); otherwise the file's
        stem in capitals (``"GEOID"`` without a file)."""
        stem = Path(self.source).stem.upper() if self.source else "GEOID"
        compact = stem.replace("_", "").replace("-", "")
        if "EGM2008" in compact or "EGM08" in compact:
            return "EGM2008"
        for model in ("EGM96", "EGM84"):
            if model in compact:
                return model
        return "".join(c for c in stem if c.isalnum()) or "GEOID"

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> Geoid:
        """Read a geoid grid (``.gtx`` or any geographic single-band raster GDAL reads).

        Raises:
            InputError: the file is missing, unreadable, or not a geographic grid.
        """
        import rasterio
        from rasterio.errors import RasterioError

        path = existing_file(path, "geoid")
        try:
            with rasterio.open(path) as ds:
                if ds.crs is None or not ds.crs.is_geographic:
                    raise InputError(f"geoid {path}: crs {ds.crs} is not geographic lon/lat")
                if ds.transform.is_identity:
                    raise InputError(f"geoid {path}: no georeferencing (field transform)")
                grid = ds.read(1, masked=True).astype(np.float64).filled(np.nan)
                transform = ds.transform
        except RasterioError as exc:
            raise InputError(f"geoid {path}: not a readable grid ({gdal_cause(exc)})") from exc
        if not np.isfinite(grid).any():
            raise InputError(f"geoid {path}: the grid holds no valid undulation")
        return cls(grid, transform, source=str(path))

    def undulation(self, lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
        """Geoid undulation ``N`` in metres, bilinear; longitudes wrap around the globe.

        NaN outside a regional grid and where a neighbouring node is nodata.
        """
        lon, lat = as_float_arrays(lon_deg, lat_deg)
        inv = ~self.transform
        if self._global:
            lon = _wrap_lon(lon, self.transform.c + 0.5 * self.transform.a)
        col = inv.a * lon + inv.b * lat + inv.c - 0.5
        row = inv.d * lon + inv.e * lat + inv.f - 0.5
        return bilinear_sample(self._padded, row, col)

    def undulation_grid(self, lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
        """:meth:`undulation` at every pair of ``lat_deg`` (1-D, rows) and ``lon_deg`` (1-D,
        columns) of a lon/lat grid: ``(len(lat_deg), len(lon_deg))``, computed separably."""
        lon, lat = (np.asarray(v, np.float64).ravel() for v in (lon_deg, lat_deg))
        inv = ~self.transform
        if inv.b or inv.d:  # a rotated geoid grid: point by point
            return self.undulation(*np.meshgrid(lon, lat))
        if self._global:
            lon = _wrap_lon(lon, self.transform.c + 0.5 * self.transform.a)
        col = inv.a * lon + inv.c - 0.5
        row = inv.e * lat + inv.f - 0.5
        return bilinear_sample_grid(self._padded, row, col)


# ----------------------------------------------------------------------------- DEM
@attrs.frozen(eq=False)
class _FileGrid:
    """Heights as a DEM file holds them (scale and offset applied, NaN = nodata), the
    transform of their first post, the horizontal CRS and the vertical reference."""

    heights: FloatArray
    transform: Affine
    crs: pyproj.CRS
    vertical: str


@attrs.frozen(eq=False)
class DEM:
    """An immutable digital elevation model: heights on a regular grid, sampled bilinearly.

    Build one with :meth:`open`, :meth:`constant` or :meth:`from_array`.

    Attributes:
        heights: ``(rows, cols)`` float64 heights in metres, read-only; NaN = nodata (also
            where the given heights were not finite or outside ``MIN_HEIGHT_M..MAX_HEIGHT_M``).
        transform: affine transform of pixel corners into ``crs`` coordinates.
        crs: the horizontal CRS (:class:`pyproj.CRS`).
        vertical: ``"ellipsoid"`` or ``"geoid:<NAME>"`` (see module docstring).
        source: the file it was read from (named in error messages), or None.
    """

    heights: FloatArray = attrs.field(converter=_plausible_heights)
    transform: Affine = attrs.field(converter=to_affine)
    crs: pyproj.CRS = attrs.field(converter=_to_horizontal_crs)
    vertical: str = attrs.field(default=ELLIPSOID, converter=normalise_vertical)
    source: str | None = None
    _crs_wkt: str = attrs.field(init=False, repr=False)
    _native_lonlat: bool = attrs.field(init=False, repr=False)

    def __attrs_post_init__(self) -> None:
        if self.heights.ndim != 2 or min(self.heights.shape) < 1:
            raise InputError(
                f"DEM {self.name}: heights must be a non-empty 2-D grid, "
                f"got shape {self.heights.shape}"
            )
        if not (self.crs.is_geographic or self.crs.is_projected):
            raise InputError(f"DEM {self.name}: crs {self.crs.name} has no horizontal part")
        if abs(self.transform.determinant) == 0.0:
            raise InputError(f"DEM {self.name}: transform {tuple(self.transform)[:6]} is singular")
        object.__setattr__(self, "_crs_wkt", self.crs.to_wkt())
        object.__setattr__(self, "_native_lonlat", _is_wgs84_lonlat(self.crs))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_array(
        cls,
        heights: ArrayLike,
        transform: Affine | Sequence[float],
        crs: Any,
        *,
        vertical: str = ELLIPSOID,
        nodata: float | None = None,
        source: str | None = None,
    ) -> DEM:
        """A DEM from a height grid (copied), its transform and CRS.

        Args:
            heights: ``(rows, cols)`` heights in metres.
            transform: :class:`affine.Affine` of pixel corners, or its 6 coefficients.
            crs: anything :meth:`pyproj.CRS.from_user_input` takes (``"EPSG:32631"``...).
            vertical: vertical reference of the heights.
            nodata: a value of ``heights`` that means "no data" (NaN always does).
        """
        grid = np.array(heights, dtype=np.float64)
        if nodata is not None and not math.isnan(nodata):
            grid[grid == nodata] = np.nan
        return cls(grid, transform, crs, vertical=vertical, source=source)

    @classmethod
    def constant(
        cls,
        h_m: float,
        *,
        bounds: Bounds = (-180.0, -90.0, 180.0, 90.0),
        vertical: str = ELLIPSOID,
    ) -> DEM:
        """A flat DEM of height ``h_m`` over lon/lat ``bounds`` (the whole Earth by default).

        It is a 2x2 grid in EPSG:4326 whose pixel centres are the corners of ``bounds``.
        """
        from rasterio.transform import Affine

        west, south, east, north = (float(v) for v in bounds)
        if not (west < east and south < north):
            raise InputError(f"DEM.constant: bounds {bounds} must be (west, south, east, north)")
        if not MIN_HEIGHT_M <= float(h_m) <= MAX_HEIGHT_M:
            raise InputError(
                f"DEM.constant: height {h_m} m is outside the plausible range {_HEIGHT_RANGE}"
            )
        dx, dy = east - west, north - south
        transform = Affine(dx, 0.0, west - dx / 2, 0.0, -dy, north + dy / 2)
        return cls(np.full((2, 2), float(h_m)), transform, "EPSG:4326", vertical=vertical)

    @classmethod
    def open(
        cls,
        path: str | os.PathLike[str],
        *,
        geoid: Geoid | str | os.PathLike[str] | None = None,
        bounds: Bounds | None = None,
        vertical: str | None = None,
        band: int | None = None,
        require_ellipsoidal: bool = False,
        rows: tuple[int, int] | None = None,
    ) -> DEM:
        """Read a DEM from a GeoTIFF, an SRTM ``.hgt`` tile or any raster GDAL reads.

        Args:
            path: the file.
            geoid: a :class:`Geoid` or the path of a geoid grid (``egm96_15.gtx``). When given
                and the DEM heights are geoid heights, they are converted to ellipsoidal
                heights (``h = H + N``, ``N`` bilinear at every DEM node). Ellipsoidal DEMs are
                returned unchanged.
            bounds: ``(west, south, east, north)`` in WGS84 degrees: read only the window that
                covers them (plus the pixels needed for bilinear sampling at their edges).
            vertical: override the vertical reference of the file. Otherwise it is the
                ``VERTICAL_REFERENCE`` tag, ``"geoid:EGM96"`` for SRTM ``.hgt`` tiles, the
                vertical part of a compound CRS, else ``"ellipsoid"`` (the Carto convention).
            band: the band holding the heights (default: the only band; a raster of several
                bands is refused unless one is named).
            require_ellipsoidal: refuse geoid heights that no ``geoid`` converts, with the
                advice to give ``--geoid GTX`` (:meth:`check_ellipsoidal`).
            rows: read only the rows ``start..stop`` (clipped to the file): a band of a
                large DEM read piece by piece. Such a band may hold no valid height.

        Heights outside ``MIN_HEIGHT_M..MAX_HEIGHT_M`` are nodata (undeclared voids such as
        -9999 or -32768, fill values such as 1e30), as is the file's declared nodata.

        Raises:
            InputError: missing or unreadable file, no CRS, smaller than 2 x 2 posts, no
                valid height (all nodata or implausible), ``bounds`` not covered, geoid
                heights with ``require_ellipsoidal`` and no geoid.
        """
        path = existing_file(path, "DEM")
        raw = cls._read_file(path, band=band, vertical=vertical, bounds=bounds, rows=rows)
        dem = cls(raw.heights, raw.transform, raw.crs, vertical=raw.vertical, source=str(path))
        # a window read (``rows``, or the one covering ``bounds``) may hold no valid height
        if rows is None and bounds is None and not np.isfinite(dem.heights).any():
            grid = raw.heights
            raise InputError(
                f"DEM {path}: no valid height (all {grid.shape[1]} x {grid.shape[0]} "
                f"posts are nodata or outside {_HEIGHT_RANGE})"
            )
        if geoid is not None:
            dem = dem.to_ellipsoid(geoid)
        if require_ellipsoidal:
            dem.check_ellipsoidal()
        return dem

    @classmethod
    def _read_file(
        cls,
        path: Path,
        *,
        band: int | None,
        vertical: str | None,
        bounds: Bounds | None,
        rows: tuple[int, int] | None,
    ) -> _FileGrid:
        """The heights of :meth:`open` as the file holds them (its band checked, the window
        of ``rows`` or ``bounds`` only, scale and offset applied), placed and referenced."""
        import rasterio
        from rasterio.errors import RasterioError

        try:
            with rasterio.open(path) as ds:
                band = check_dem_file(ds, band, path)
                crs, file_vertical = split_vertical(_to_crs(ds.crs))
                vref = vertical_of(ds, vertical, file_vertical, path)
                window, transform = cls._file_window(ds, path, crs, bounds, rows)
                grid = ds.read(band, window=window, masked=True)
                grid = grid.astype(np.float64).filled(np.nan)
                scale, offset = ds.scales[band - 1], ds.offsets[band - 1]
        except RasterioError as exc:
            raise InputError(f"DEM {path}: not a readable raster ({gdal_cause(exc)})") from exc
        if scale not in (None, 1.0) or offset not in (None, 0.0):
            grid = grid * (1.0 if scale is None else scale) + (offset or 0.0)
        return _FileGrid(grid, transform, crs, vref)

    @classmethod
    def _file_window(
        cls,
        ds: Any,
        path: Path,
        crs: pyproj.CRS,
        bounds: Bounds | None,
        rows: tuple[int, int] | None,
    ) -> tuple[Any, Affine]:
        """The window of the open raster ``ds`` to read (``rows`` if given, else the one
        covering ``bounds``, else None: all) and the transform of its first pixel."""
        from rasterio.transform import Affine
        from rasterio.windows import Window

        window = None
        transform = ds.transform
        if rows is not None:
            r0, r1 = max(0, int(rows[0])), min(ds.height, int(rows[1]))
            if r0 >= r1:
                raise InputError(
                    f"DEM {path}: rows {rows[0]}..{rows[1]} are outside its {ds.height} rows"
                )
            window = Window(0, r0, ds.width, r1 - r0)
            transform = transform @ Affine.translation(0, r0)
        elif bounds is not None:
            full = cls(np.zeros((1, 1)), transform, crs, source=str(path))
            rows, cols = full._window_for(bounds, ds.height, ds.width)
            window = Window(cols[0], rows[0], cols[1] - cols[0], rows[1] - rows[0])
            transform = transform @ Affine.translation(cols[0], rows[0])
        return window, transform

    # ------------------------------------------------------------------ properties
    @property
    def name(self) -> str:
        """The source file, or ``"(in memory)"``: how error messages name this DEM."""
        return self.source or "(in memory)"

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the grid."""
        return self.heights.shape  # type: ignore[return-value]

    @property
    def is_ellipsoidal(self) -> bool:
        """True when the heights are above the WGS84 ellipsoid (what sensors take)."""
        return self.vertical == ELLIPSOID

    def check_ellipsoidal(self, purpose: str = "Carto") -> DEM:
        """``self`` if its heights are ellipsoidal; else InputError (one line) naming the file
        and its vertical reference, with the advice to give the geoid grid (``--geoid GTX``,
        configuration key ``"geoid"``). ``purpose`` names what needs ellipsoidal heights."""
        if not self.is_ellipsoidal:
            raise InputError(
                f"DEM {self.name}: heights are above the geoid ({self.vertical}), {purpose} "
                f"needs ellipsoidal heights; {GEOID_ADVICE}"
            )
        return self

    @functools.cached_property
    def height_range(self) -> tuple[float, float]:
        """``(min, max)`` of the valid heights (once: they are read-only); InputError when none."""
        valid = self.heights[np.isfinite(self.heights)]
        if valid.size == 0:
            raise InputError(f"DEM {self.name}: no valid height (all nodata)")
        return float(valid.min()), float(valid.max())

    @property
    def bounds_lonlat(self) -> Bounds:
        """``(west, south, east, north)`` WGS84 degrees of the area where heights are defined.

        That is the span of the pixel centres; for a projected DEM, the lon/lat box that
        encloses it (found along its densified edges).
        """
        n_rows, n_cols = self.shape
        t = np.linspace(0.0, 1.0, 33)
        one = np.ones_like(t)
        rows = np.concatenate([t * (n_rows - 1), one * (n_rows - 1), t * (n_rows - 1), 0 * t])
        cols = np.concatenate([0 * t, t * (n_cols - 1), one * (n_cols - 1), t * (n_cols - 1)])
        lon, lat = self._pixel_to_lonlat(rows, cols)
        return (float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max()))

    # ------------------------------------------------------------------ sampling
    def height(self, lon_deg: ArrayLike, lat_deg: ArrayLike, *, strict: bool = False) -> FloatArray:
        """Bilinear height in metres (in :attr:`vertical`) at WGS84 lon/lat (arrays broadcast).

        NaN outside the span of the pixel centres and where one of the four neighbours is
        nodata; with ``strict=True`` such points (with finite lon/lat) raise InputError
        naming the DEM file and their lon/lat bounding box.
        """
        lon, lat = as_float_arrays(lon_deg, lat_deg)
        row, col = self.lonlat_to_pixel(lon, lat)
        out = bilinear_sample(self.heights, row, col)
        if strict:
            missing = np.isnan(out) & np.isfinite(lon) & np.isfinite(lat)
            if missing.any():
                box = (lon[missing].min(), lat[missing].min(), lon[missing].max())
                box = (*box, lat[missing].max())
                raise InputError(
                    f"DEM {self.name} has no height for {int(missing.sum())} of {out.size} "
                    f"points in {_fmt_bounds(box)} (outside or nodata); "
                    f"it covers {_fmt_bounds(self.bounds_lonlat)}"
                )
        return out

    def covers(self, lon_deg: ArrayLike, lat_deg: ArrayLike) -> BoolArray:
        """True where :meth:`height` gives a height (inside the grid, neighbours not nodata)."""
        return np.isfinite(self.height(lon_deg, lat_deg))

    # ------------------------------------------------------------------ conversions
    def to_ellipsoid(self, geoid: Geoid | str | os.PathLike[str]) -> DEM:
        """This DEM with ellipsoidal heights ``h = H + N`` (``N`` bilinear at each node).

        Returns ``self`` when the heights are already ellipsoidal. Raises InputError when the
        geoid grid does not cover a valid node.
        """
        if self.is_ellipsoidal:
            return self
        undulation = self._undulation(geoid)
        return attrs.evolve(self, heights=self.heights + undulation, vertical=ELLIPSOID)

    def to_geoid(self, geoid: Geoid | str | os.PathLike[str]) -> DEM:
        """This DEM of ellipsoidal heights as orthometric heights ``H = h - N`` above the
        geoid of the grid (vertical reference ``"geoid:<model>"``, :attr:`Geoid.model`).

        Raises InputError for heights that are not ellipsoidal, or a geoid grid that does
        not cover a valid node."""
        if not self.is_ellipsoidal:
            raise InputError(
                f"DEM {self.name}: heights are above {self.vertical}, not the ellipsoid"
            )
        if not isinstance(geoid, Geoid):
            geoid = Geoid.open(geoid)
        undulation = self._undulation(geoid)
        return attrs.evolve(
            self, heights=self.heights - undulation, vertical=f"geoid:{geoid.model}"
        )

    def node_lonlat(self, rows: slice = slice(None)) -> tuple[FloatArray, FloatArray]:
        """WGS84 lon/lat of every node's centre (of the band of ``rows``), two grids."""
        n_rows, n_cols = self.shape
        r = np.arange(n_rows, dtype=np.float64)[rows]
        return self._pixel_to_lonlat(r[:, None], np.arange(n_cols, dtype=np.float64)[None, :])

    def _undulation(self, geoid: Geoid | str | os.PathLike[str]) -> FloatArray:
        """The geoid undulation at every node; InputError where it misses a valid node."""
        if not isinstance(geoid, Geoid):
            geoid = Geoid.open(geoid)
        t = self.transform
        if self._native_lonlat and not (t.b or t.d):  # lon by column, lat by row
            lon_1d = t.a * (np.arange(self.shape[1]) + 0.5) + t.c
            lat_1d = t.e * (np.arange(self.shape[0]) + 0.5) + t.f
            undulation = geoid.undulation_grid(lon_1d, lat_1d)
        else:
            undulation = geoid.undulation(*self.node_lonlat())
        uncovered = np.isfinite(self.heights) & ~np.isfinite(undulation)
        if uncovered.any():
            lon, lat = (v[uncovered][0] for v in self.node_lonlat())
            raise InputError(
                f"geoid {geoid.source} does not cover DEM {self.name} at "
                f"{int(uncovered.sum())} nodes (e.g. lon {lon:.6f}, lat {lat:.6f})"
            )
        return undulation

    def write(self, path: str | os.PathLike[str]) -> Path:
        """Write a float32 cloud-optimised GeoTIFF (NaN nodata, the CRS compound with the
        vertical reference's CRS, which the ``VERTICAL_REFERENCE`` tag names too); return
        the path. A reader never sees a partial file
        (:func:`carto.framework.raster.cog.cog_writer`).
        """
        from rasterio.crs import CRS as RioCRS

        from carto.framework.raster.cog import cog_writer

        path = Path(path)
        n_rows, n_cols = self.shape
        profile: dict[str, Any] = {
            "height": n_rows,
            "width": n_cols,
            "count": 1,
            "dtype": "float32",
            "crs": RioCRS.from_wkt(self.crs.to_wkt()),
            "transform": self.transform,
            "nodata": np.nan,
        }
        with cog_writer(path, profile, what="DEM to", vertical=self.vertical) as dst:
            dst.write(self.heights.astype(np.float32), 1)
            dst.update_tags(AREA_OR_POINT="Area")
        return path

    # ------------------------------------------------------------------ internals
    def lonlat_to_pixel(self, lon: FloatArray, lat: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Fractional centre indices ``(row, col)`` (0 = first centre) of WGS84 lon/lat."""
        if self._native_lonlat:
            x, y = lon, lat
        else:
            x, y = _transformer(self._crs_wkt, True).transform(lon, lat)
            x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        if self.crs.is_geographic:  # into the 360 degrees centred on the grid
            t = self.transform
            n_rows, n_cols = self.shape
            x_mid = t.c + 0.5 * (t.a * n_cols + t.b * n_rows)
            x = _wrap_lon(x, x_mid - 180.0)
        inv = ~self.transform
        col = inv.a * x + inv.b * y + inv.c - 0.5
        row = inv.d * x + inv.e * y + inv.f - 0.5
        return row, col

    def _pixel_to_lonlat(self, row: FloatArray, col: FloatArray) -> tuple[FloatArray, FloatArray]:
        """WGS84 lon/lat of fractional centre indices."""
        t = self.transform
        x = t.a * (col + 0.5) + t.b * (row + 0.5) + t.c
        y = t.d * (col + 0.5) + t.e * (row + 0.5) + t.f
        if self._native_lonlat:
            return x, y
        lon, lat = _transformer(self._crs_wkt, False).transform(x, y)
        return np.asarray(lon, np.float64), np.asarray(lat, np.float64)

    def _window_for(
        self, bounds: Bounds, n_rows: int, n_cols: int
    ) -> tuple[tuple[int, int], tuple[int, int]]:
        """Row and column ranges ``[start, stop)`` of a grid of ``n_rows x n_cols`` (with this
        DEM's transform and CRS) that hold the lon/lat ``bounds``, or InputError."""
        west, south, east, north = (float(v) for v in bounds)
        if not (west <= east and south <= north) or not all(map(math.isfinite, bounds)):
            raise InputError(
                f"DEM {self.name}: bounds {tuple(bounds)} must be finite "
                "(west, south, east, north) with west <= east, south <= north"
            )
        t = np.linspace(0.0, 1.0, 33)
        lon = np.concatenate([west + t * (east - west), np.full_like(t, east)])
        lon = np.concatenate([lon, west + t * (east - west), np.full_like(t, west)])
        lat = np.concatenate([np.full_like(t, south), south + t * (north - south)])
        lat = np.concatenate([lat, np.full_like(t, north), south + t * (north - south)])
        row, col = self.lonlat_to_pixel(lon, lat)
        r_min, r_max, c_min, c_max = row.min(), row.max(), col.min(), col.max()
        tol = EDGE_TOL_PX
        if not (r_min >= -tol and c_min >= -tol and r_max <= n_rows - 1 + tol) or not (
            c_max <= n_cols - 1 + tol
        ):
            grid = attrs.evolve(self, heights=np.zeros((n_rows, n_cols)))
            raise InputError(
                f"DEM {self.name} does not cover the requested bounds {_fmt_bounds(bounds)}; "
                f"it covers {_fmt_bounds(grid.bounds_lonlat)}"
            )
        r0 = max(math.floor(r_min + tol), 0)
        c0 = max(math.floor(c_min + tol), 0)
        r1 = min(math.ceil(r_max - tol) + 1, n_rows)
        c1 = min(math.ceil(c_max - tol) + 1, n_cols)
        return (r0, max(r1, r0 + 1)), (c0, max(c1, c0 + 1))
