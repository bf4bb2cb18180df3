"""Accuracy against independent checkpoints: the figures the paper and users report.

:func:`checkpoint_accuracy` intersects the checkpoints' image coordinates in all images with
the sensors being evaluated (least squares,
:func:`carto.framework.geometry.intersection.intersect_sensors`) and compares the ground points
with the checkpoints' true coordinates: RMSE along track, across track, planimetric and in height,
in metres. Along track is the ground direction in which the first image's lines advance at each
point; across track is perpendicular to it in the local horizontal plane.

:func:`dem_accuracy` compares a DEM with a reference DEM (LiDAR, a survey, the simulator's
truth): the DEM is resampled bilinearly onto the reference grid and the height differences
``DEM - reference`` are summarised by the usual robust figures (bias, RMSE, NMAD, LE90),
completeness, and the same figures by class of terrain slope. :func:`dem_difference` gives the
difference grid itself (for maps, see :mod:`carto.framework.raster.quicklook`).
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.evaluation.difference_histogram import NMAD_FACTOR, DifferenceHistogram
from carto.framework.raster.dem import DEM, ELLIPSOID, Geoid
from carto.framework.raster.dem_measures import slope_deg

FloatArray = NDArray[np.float64]


# ----------------------------------------------------------------------------- DEM accuracy

DEFAULT_SLOPE_CLASSES_DEG = (0.0, 10.0, 20.0, 30.0, 90.0)
"""Edges of the default slope classes, degrees: ``[0, 10), [10, 20), [20, 30), [30, 90]``."""

DEMSource = DEM | str | os.PathLike[str]


def _as_dem(value: DEMSource) -> DEM:
    return value if isinstance(value, DEM) else DEM.open(value)


def _rio_crs(dem: DEM) -> Any:
    from rasterio.crs import CRS as RioCRS

    return RioCRS.from_wkt(dem.crs.to_wkt())


def _same_grid(dem: DEM, reference: DEM) -> bool:
    if dem.shape != reference.shape or not dem.crs.equals(reference.crs):
        return False
    t = reference.transform
    tol = 1e-6 * min(math.hypot(t.a, t.d), math.hypot(t.b, t.e))
    return bool(dem.transform.almost_equals(t, precision=tol))


def warp_heights(source: FloatArray, dem: DEM, reference: DEM, resampling: str) -> FloatArray:
    """``source`` (on the grid of ``dem``) resampled onto the grid of ``reference``; NaN
    where it has no value."""
    from rasterio.errors import RasterioError
    from rasterio.warp import Resampling, reproject

    out = np.full(reference.shape, np.nan, dtype=np.float64)
    try:
        reproject(
            source=np.array(source, dtype=np.float64),
            destination=out,
            src_transform=dem.transform,
            src_crs=_rio_crs(dem),
            src_nodata=np.nan,
            dst_transform=reference.transform,
            dst_crs=_rio_crs(reference),
            dst_nodata=np.nan,
            resampling=Resampling[resampling],
            # the exact transformation (not GDAL's approximation along lines) and plain
            # bilinear interpolation whatever the pixel sizes (GDAL widens the kernel by a
            # scale it estimates per chunk of work: figures would depend on the chunks)
            tolerance=0.0,
            XSCALE=1,
            YSCALE=1,
        )
    except (RasterioError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(
            f"cannot resample DEM {dem.name} onto the grid of reference {reference.name}: {first}"
        ) from exc
    return out


def reconcile_vertical(dem: DEM, reference: DEM, geoid: Geoid | None) -> tuple[DEM, DEM]:
    """Both DEMs in one vertical reference, converting a geoid one to ellipsoidal heights
    with ``geoid`` when the other is ellipsoidal; InputError otherwise."""
    if dem.vertical == reference.vertical:
        return dem, reference
    mixed = ELLIPSOID in (dem.vertical, reference.vertical)
    if mixed and geoid is not None:
        return dem.to_ellipsoid(geoid), reference.to_ellipsoid(geoid)
    hint = (
        "give a geoid grid (--geoid / geoid=, e.g. egm96_15.gtx) to convert the geoid heights "
        "to ellipsoidal heights"
        if mixed
        else "convert one of them first; one geoid cannot relate two geoid models"
    )
    raise InputError(
        f"DEM {dem.name} heights are {dem.vertical} but reference {reference.name} heights are "
        f"{reference.vertical}; {hint}"
    )


def dem_difference(
    dem: DEMSource,
    reference: DEMSource,
    *,
    geoid: Geoid | str | os.PathLike[str] | None = None,
) -> tuple[FloatArray, FloatArray, DEM]:
    """Height differences ``dem - reference`` on the grid of the reference DEM.

    The evaluated DEM is resampled onto the reference grid with
    :func:`rasterio.warp.reproject` (bilinear, NaN nodata), unless both share the same grid
    (CRS, transform and shape), in which case its heights are used as they are.

    Args:
        dem: the DEM to evaluate: a :class:`~carto.framework.raster.dem.DEM` or a file path.
        reference: the reference DEM (DEM or path); its grid is the evaluation grid.
        geoid: a :class:`~carto.framework.raster.dem.Geoid` or the path of a geoid grid. Needed only
            when one DEM holds ellipsoidal heights and the other geoid heights: the latter is
            converted with :meth:`DEM.to_ellipsoid`.

    Returns:
        ``(difference_m, slope_deg, reference)``: the float64 difference in metres on the
        reference grid (NaN where either DEM has no height), the terrain slope of the reference
        in degrees (:func:`slope_deg`), and the reference DEM as compared (converted to
        ellipsoidal heights when ``geoid`` was used). The resampled DEM is
        ``reference.heights + difference_m``.

    Raises:
        InputError: unreadable file, no valid reference height, different vertical references
            that ``geoid`` cannot reconcile, or grids that do not overlap at all.
    """
    dem, reference = _as_dem(dem), _as_dem(reference)
    if geoid is not None and not isinstance(geoid, Geoid):
        geoid = Geoid.open(geoid)
    if not np.isfinite(reference.heights).any():
        raise InputError(f"reference DEM {reference.name}: no valid height (all nodata)")
    dem, reference = reconcile_vertical(dem, reference, geoid)
    if _same_grid(dem, reference):
        resampled = np.array(dem.heights, dtype=np.float64)
    else:
        resampled = warp_heights(dem.heights, dem, reference, "bilinear")
        if not np.isfinite(resampled).any():
            footprint = warp_heights(np.ones(dem.shape), dem, reference, "nearest")
            if not np.isfinite(footprint).any():
                raise InputError(
                    f"DEM {dem.name} and reference {reference.name} do not overlap: "
                    f"the DEM covers {_fmt_lonlat(dem)}, the reference {_fmt_lonlat(reference)}"
                )
    difference = resampled - reference.heights  # NaN where either is NaN
    return difference, slope_deg(reference), reference


def _fmt_lonlat(dem: DEM) -> str:
    w, s, e, n = dem.bounds_lonlat
    return f"lon {w:.4f}..{e:.4f}, lat {s:.4f}..{n:.4f}"


_STATS_KEYS = ("bias_m", "median_m", "std_m", "rmse_m", "nmad_m", "le90_m", "max_abs_m")


def difference_statistics(d: ArrayLike) -> dict[str, Any]:
    """Accuracy figures of height differences ``d`` (metres; NaN ignored).

    Returns:
        ``{count, bias_m, median_m, std_m, rmse_m, nmad_m, le90_m, max_abs_m}``, metres:
        bias = mean, std = sample standard deviation (``n - 1``; None for one value),
        rmse = ``sqrt(mean(d**2))``, nmad = ``1.4826 * median(|d - median(d)|)``, le90 = 90th
        percentile of ``|d|`` (linear interpolation), max_abs = ``max |d|``. With no value,
        count is 0 and every figure None.
    """
    d = np.asarray(d, dtype=np.float64).ravel()
    d = d[np.isfinite(d)]
    n = int(d.size)
    if n == 0:
        return {"count": 0, **dict.fromkeys(_STATS_KEYS)}
    median = float(np.median(d))
    abs_d = np.abs(d)
    return {
        "count": n,
        "bias_m": float(np.mean(d)),
        "median_m": median,
        "std_m": float(np.std(d, ddof=1)) if n > 1 else None,
        "rmse_m": float(np.sqrt(np.mean(d * d))),
        "nmad_m": float(NMAD_FACTOR * np.median(np.abs(d - median))),
        "le90_m": float(np.percentile(abs_d, 90.0)),
        "max_abs_m": float(abs_d.max()),
    }


def _slope_edges(slope_classes_deg: Sequence[float]) -> list[float]:
    try:
        edges = [float(v) for v in slope_classes_deg]
    except (TypeError, ValueError):
        edges = []
    ok = len(edges) >= 2 and all(map(math.isfinite, edges))
    if not ok or any(b <= a for a, b in itertools.pairwise(edges)):
        raise InputError(
            f"slope classes {tuple(slope_classes_deg)!r} must be >= 2 increasing finite edges "
            "in degrees, e.g. (0, 10, 20, 30, 90)"
        )
    return edges


def difference_accuracy(
    difference_m: ArrayLike,
    slope_deg: ArrayLike,
    reference_valid: ArrayLike,
    *,
    slope_classes_deg: Sequence[float] = DEFAULT_SLOPE_CLASSES_DEG,
    mask: ArrayLike | None = None,
) -> dict[str, Any]:
    """Accuracy figures of a difference grid (as from :func:`dem_difference`).

    Args:
        difference_m: ``dem - reference`` in metres; NaN where either has no height.
        slope_deg: terrain slope of the reference in degrees, same shape.
        reference_valid: True where the reference has a height, same shape.
        slope_classes_deg: increasing class edges in degrees; class ``i`` holds slopes in
            ``[edge_i, edge_i+1)``, the last one includes its upper edge.
        mask: optional boolean grid of the same shape; only pixels where it is True count.

    Returns:
        the figures of :func:`difference_statistics` over all pixels where both DEMs are
        valid, plus ``completeness`` (the fraction, in ``[0, 1]``, of the reference's valid
        pixels where the DEM is valid too; None when there is no valid reference pixel),
        ``reference_count`` (those reference pixels) and ``by_slope``: a list of
        ``{slope_deg: [lo, hi], count, bias_m, rmse_m, nmad_m, le90_m}`` (pixels whose slope
        is NaN, next to reference nodata, are in no class).
    """
    diff = np.asarray(difference_m, dtype=np.float64)
    slope = np.asarray(slope_deg, dtype=np.float64)
    ref_valid = np.asarray(reference_valid, dtype=bool)
    if slope.shape != diff.shape or ref_valid.shape != diff.shape:
        raise InputError(
            f"difference {diff.shape}, slope {slope.shape} and reference validity "
            f"{ref_valid.shape} grids must have the same shape"
        )
    selected = np.ones(diff.shape, dtype=bool)
    if mask is not None:
        selected = np.asarray(mask, dtype=bool)
        if selected.shape != diff.shape:
            raise InputError(
                f"mask shape {selected.shape} differs from the reference grid {diff.shape}"
            )
    edges = _slope_edges(slope_classes_deg)
    valid = np.isfinite(diff) & selected
    values = diff[valid]
    report = difference_statistics(values)
    reference_count = int(np.count_nonzero(ref_valid & selected))
    report["completeness"] = (
        int(np.count_nonzero(valid & ref_valid)) / reference_count if reference_count else None
    )
    report["reference_count"] = reference_count
    report["by_slope"] = _by_slope(values, _slope_class(slope[valid], edges), edges)
    return report


def _slope_class(slopes: FloatArray, edges: list[float]) -> NDArray[np.int8]:
    """The class index of each slope (``[edge_i, edge_i+1)``, the last class closed; -1 for
    NaN or outside every class)."""
    index = np.full(slopes.shape, -1, np.int8)
    for i, (lo, hi) in enumerate(itertools.pairwise(edges)):
        last = i == len(edges) - 2
        index[(slopes >= lo) & ((slopes <= hi) if last else (slopes < hi))] = i
    return index


def _class_figures(lo: float, hi: float, stats: dict[str, Any]) -> dict[str, Any]:
    """One slope class's entry of ``by_slope``."""
    keys = ("count", "bias_m", "rmse_m", "nmad_m", "le90_m")
    return {"slope_deg": [lo, hi], **{k: stats[k] for k in keys}}


def _by_slope(
    values: FloatArray, classes: NDArray[np.int8], edges: list[float]
) -> list[dict[str, Any]]:
    """The figures of each slope class (``by_slope`` of :func:`difference_accuracy`)."""
    return [
        _class_figures(lo, hi, difference_statistics(values[classes == i]))
        for i, (lo, hi) in enumerate(itertools.pairwise(edges))
    ]


def dem_accuracy(
    dem: DEMSource,
    reference: DEMSource,
    *,
    slope_classes_deg: Sequence[float] = DEFAULT_SLOPE_CLASSES_DEG,
    mask: ArrayLike | None = None,
    geoid: Geoid | str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Vertical accuracy of ``dem`` against a ``reference`` DEM, in metres.

    The DEM is resampled onto the reference grid (:func:`dem_difference`) and the differences
    ``d = dem - reference`` over the pixels where both are valid are summarised.

    Args:
        dem: the DEM to evaluate (:class:`~carto.framework.raster.dem.DEM` or path).
        reference: the reference DEM (DEM or path); its grid is the evaluation grid.
        slope_classes_deg: increasing slope class edges in degrees (slope of the reference).
        mask: optional boolean grid of the reference's shape: only pixels where it is True
            are evaluated (e.g. to leave out water or forest).
        geoid: geoid grid (Geoid or path) to relate ellipsoidal and geoid heights.

    Returns:
        a JSON-ready dict: ``dem``, ``reference`` (names), ``vertical`` (the vertical
        reference compared), ``count``, ``bias_m`` (mean of ``d``), ``median_m``, ``std_m``,
        ``rmse_m``, ``nmad_m`` (``1.4826 * median(|d - median(d)|)``), ``le90_m`` (90th
        percentile of ``|d|``), ``max_abs_m``, ``completeness`` (fraction in ``[0, 1]`` of the
        reference's valid pixels where the DEM is valid), ``reference_count`` and ``by_slope``
        (see :func:`difference_accuracy`). Figures are None where no pixel is compared.

    Raises:
        InputError: see :func:`dem_difference`; also a bad ``mask`` or ``slope_classes_deg``.
    """
    dem = _as_dem(dem)
    _slope_edges(slope_classes_deg)  # fail before the resampling
    difference, slope, ref = dem_difference(dem, reference, geoid=geoid)
    stats = difference_accuracy(
        difference,
        slope,
        np.isfinite(ref.heights),
        slope_classes_deg=slope_classes_deg,
        mask=mask,
    )
    return {"dem": dem.name, "reference": ref.name, "vertical": ref.vertical, **stats}


@attrs.frozen(eq=False)
class BlockComparison:
    """What :func:`dem_accuracy_by_blocks` returns: the report of :func:`dem_accuracy` and a
    decimated difference grid for maps (every ``step``-th row and column of the reference
    grid)."""

    report: dict[str, Any]
    preview: FloatArray
    step: int


PREVIEW_PX = 2000
"""Longest side of the decimated difference grid kept for maps, pixels."""

BLOCK_PX = 2_000_000
"""Reference pixels per band of :func:`dem_accuracy_by_blocks` (about 100 MB of work)."""


def _covering(dem: DEM, part: DEM) -> DEM:
    """The window of ``dem`` that covers the reference band ``part`` (two pixels more on each
    side for the bilinear kernel), or ``dem`` when the band's bounds cannot be located in
    its CRS."""
    from rasterio.warp import transform_bounds

    t = part.transform
    rows, cols = part.shape
    xs = [t.c, t.c + t.a * cols + t.b * rows, t.c + t.b * rows, t.c + t.a * cols]
    ys = [t.f, t.f + t.d * cols + t.e * rows, t.f + t.e * rows, t.f + t.d * cols]
    try:
        left, bottom, right, top = transform_bounds(
            _rio_crs(part), _rio_crs(dem), min(xs), min(ys), max(xs), max(ys), densify_pts=21
        )
    except Exception:  # noqa: BLE001 (a CRS pair PROJ cannot relate: compare with all)
        return dem
    inverse = ~dem.transform
    corners = [inverse @ (x, y) for x in (left, right) for y in (bottom, top)]
    c = [p[0] for p in corners]
    r = [p[1] for p in corners]
    if not all(map(math.isfinite, c + r)):
        return dem
    n_rows, n_cols = dem.shape
    r0 = max(0, math.floor(min(r)) - 2)
    r1 = min(n_rows, math.ceil(max(r)) + 2)
    c0 = max(0, math.floor(min(c)) - 2)
    c1 = min(n_cols, math.ceil(max(c)) + 2)
    if r0 >= r1 or c0 >= c1:  # no overlap: a 1 x 1 window far from the band says so
        r0, r1, c0, c1 = 0, 1, 0, 1
    from affine import Affine

    return attrs.evolve(
        dem,
        heights=dem.heights[r0:r1, c0:c1],
        transform=dem.transform @ Affine.translation(c0, r0),
    )


def dem_accuracy_by_blocks(
    dem: DEMSource,
    reference: str | os.PathLike[str],
    *,
    geoid: Geoid | str | os.PathLike[str] | None = None,
    slope_classes_deg: Sequence[float] = DEFAULT_SLOPE_CLASSES_DEG,
    block_rows: int | None = None,
    preview_px: int = PREVIEW_PX,
) -> BlockComparison:
    """:func:`dem_accuracy` of ``dem`` against the reference DEM file, read by bands of
    ``block_rows`` rows (default: about :data:`BLOCK_PX` pixels a band; one row more on each
    side for the slope), each compared with the part of ``dem`` that covers it: the memory
    holds one band of the reference grid, the compared differences (float32) and a decimated
    difference grid, not the reference grid several times over (a LiDAR reference of a whole
    scene has hundreds of millions of pixels).

    The differences are summarised band by band (:class:`~carto.framework.evaluation.
    difference_histogram.DifferenceHistogram`, 8 MB per slope class): the count, bias,
    standard deviation, RMSE and largest difference equal :func:`dem_accuracy`'s, the median,
    NMAD and LE90 are within about a millimetre of them.

    Raises:
        InputError: an unreadable reference, no valid reference height, vertical references
            that ``geoid`` cannot reconcile, grids that do not overlap.
    """
    import rasterio
    import rasterio.warp
    from rasterio.errors import RasterioError

    dem = _as_dem(dem)
    if geoid is not None and not isinstance(geoid, Geoid):
        geoid = Geoid.open(geoid)
    edges = _slope_edges(slope_classes_deg)
    path = os.fspath(reference)
    DEM.open(path, rows=(0, 2))  # the file's checks (CRS, size, readable) before the work
    try:
        with rasterio.open(path) as ds:
            n_rows, n_cols = ds.height, ds.width
    except RasterioError as exc:  # pragma: no cover (DEM.open read it just before)
        raise InputError(f"DEM {path}: not a readable raster ({exc})") from exc
    step = max(1, math.ceil(max(n_rows, n_cols) / max(int(preview_px), 1)))
    block = max(int(block_rows), 1) if block_rows is not None else max(16, BLOCK_PX // n_cols)
    block += (-block) % step  # bands hold whole preview rows
    every = DifferenceHistogram()
    by_class = [DifferenceHistogram() for _ in edges[1:]]
    preview: list[FloatArray] = []
    reference_count = 0
    name = vertical = None
    overlap = False
    for r0 in range(0, n_rows, block):
        r1 = min(n_rows, r0 + block)
        band = _band(dem, path, (r0, r1), n_rows, n_cols, geoid)
        diff, slope, ref_valid = band.diff, band.slope, band.ref_valid
        if band.name is not None:
            name, vertical = band.name, band.vertical
        overlap = overlap or band.overlap
        reference_count += int(np.count_nonzero(ref_valid))
        valid = np.isfinite(diff)
        values = diff[valid]
        every.add(values)
        classes = _slope_class(slope[valid], edges)
        for i, histogram in enumerate(by_class):
            histogram.add(values[classes == i])
        preview.append(diff[(-r0) % step :: step, ::step])
    if name is None:
        raise InputError(f"reference DEM {path}: no valid height (all nodata)")
    if not overlap:
        raise _no_overlap(dem, path)
    report = every.statistics()
    report["completeness"] = report["count"] / reference_count if reference_count else None
    report["reference_count"] = reference_count
    report["by_slope"] = [
        _class_figures(lo, hi, histogram.statistics())
        for (lo, hi), histogram in zip(itertools.pairwise(edges), by_class, strict=True)
    ]
    report = {"dem": dem.name, "reference": name, "vertical": vertical, **report}
    return BlockComparison(report, np.concatenate(preview, axis=0), step)


@attrs.frozen(eq=False)
class _Band:
    """One band of a comparison by blocks: the differences DEM - reference, the reference's
    slope and valid pixels over the band's rows; the reference's name and vertical reference
    (None for a band without valid height) and whether the DEM covers any of it."""

    diff: FloatArray
    slope: FloatArray
    ref_valid: NDArray[np.bool_]
    name: str | None = None
    vertical: str | None = None
    overlap: bool = False


def _band(
    dem: DEM,
    path: str,
    rows: tuple[int, int],
    n_rows: int,
    n_cols: int,
    geoid: Geoid | None,
) -> _Band:
    """The reference's rows ``r0..r1`` (read with one row more on each side, for the slope)
    compared with the part of ``dem`` that covers them."""
    r0, r1 = rows
    a, b = max(0, r0 - 1), min(n_rows, r1 + 1)
    part = DEM.open(path, rows=(a, b))
    inner = slice(r0 - a, r0 - a + (r1 - r0))
    if not np.isfinite(part.heights).any():
        empty = np.full((r1 - r0, n_cols), np.nan)
        return _Band(empty, empty, np.zeros(empty.shape, bool))
    evaluated, part = reconcile_vertical(_covering(dem, part), part, geoid)
    if _same_grid(evaluated, part):
        resampled = np.array(evaluated.heights, np.float64)
    else:
        resampled = warp_heights(evaluated.heights, evaluated, part, "bilinear")
    overlap = bool(np.isfinite(resampled).any())
    if not overlap:
        footprint = warp_heights(np.ones(evaluated.shape), evaluated, part, "nearest")
        overlap = bool(np.isfinite(footprint).any())
    return _Band(
        (resampled - part.heights)[inner],
        slope_deg(part)[inner],
        np.isfinite(part.heights[inner]),
        part.name,
        part.vertical,
        overlap,
    )


def _no_overlap(dem: DEM, path: str) -> InputError:
    """The error of a DEM and a reference that do not overlap, with both footprints."""
    import rasterio
    import rasterio.warp

    with rasterio.open(path) as ds:
        west, south, east, north = rasterio.warp.transform_bounds(ds.crs, "EPSG:4326", *ds.bounds)
    return InputError(
        f"DEM {dem.name} and reference {path} do not overlap: the DEM covers "
        f"{_fmt_lonlat(dem)}, the reference lon {west:.4f}..{east:.4f}, "
        f"lat {south:.4f}..{north:.4f}"
    )
