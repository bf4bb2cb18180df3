"""Iterative ortho-image refinement (IOR): a DEM and ortho-images from a stereo pair with known
orientation (Radhadevi et al. 2010; design brief section 2).

With exact orientation, the ortho-images of the left and right image made on the true DEM are
identical; where the DEM height is wrong by ``e`` they are shifted against each other along
the stereo base. The loop:

1. orthorectify both images on the current DEM (:func:`carto.framework.imaging.ortho.orthorectify`);
2. match the two ortho-images densely with the chosen matcher's ``match_dense`` (the
   matcher extension point, ``carto dem --matcher``; the default ``"ncc"`` is
   :func:`carto.framework.matching.disparity.dense_offsets`: pyramid, left-right check,
   sub-pixel, score and validity);
3. turn each mismatch into a height by intersecting the two image rays at the matched points
   (:func:`carto.framework.geometry.intersection.intersect_sensors`), carried back to the DEM node;
4. update the DEM with regularisation: outliers against the local median removed, holes and
   noise handled by a normalised Gaussian convolution of the height changes;
5. repeat until the median mismatch is below a threshold or a number of iterations is reached.

**Height from mismatch, to first order.** The left ortho pixel at ``(x, y)`` shows the terrain
where the left line of sight through ``(x, y, h_dem)`` meets it: for a height error ``e =
h_dem - h_true`` a ground detail appears ``e t_L`` away from its true place (``t``: the
horizontal displacement of a line of sight per metre of height, of length ``tan(theta)``,
``theta`` the off-nadir angle), and ``e t_R`` away in the right ortho. The two ortho-images
are therefore shifted against each other by ``dr = e |t_R - t_L| = e B/H`` along the base
(the direction of ``t_R - t_L``), so

    ``dh = -e = -dr / (B/H)``  (:func:`first_order_height_change`).

The paper prints ``dh = dr * (B/H)`` (its eq. 7): dimensionally the inverse (for Cartosat-1,
B/H = 0.62, a 1 m mismatch is a 1.6 m height error, not 0.62 m). The intersection used in step
3 needs no such approximation; the test suite checks that both agree for small mismatches.

The work of an iteration is split into tiles of DEM nodes (with overlap), each orthorectified,
matched and intersected on its own (:func:`refine_tile`), so a scheduler can distribute them;
the regularisation then runs on the assembled DEM grid.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from collections.abc import Callable
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.ortho_grid import OrthoGrid, check_grid_size, footprint_box
from carto.framework.matching.base import DenseSettings, Matcher
from carto.framework.raster.dem import DEM, ELLIPSOID
from carto.framework.raster.dem_measures import fill_voids
from carto.ior.settings import IORSettings, option_label

__all__ = [
    "IORResult",
    "IORSettings",
    "IterationReport",
    "b_over_h",
    "base_direction",
    "first_order_height_change",
    "refine_dem",
    "refine_tile",
    "regularise",
    "starting_surface",
]

FloatArray = NDArray[np.float64]


def first_order_height_change(mismatch_m: Any, b_over_h: float) -> FloatArray:
    """Height change, metres, that cancels an ortho-image mismatch, to first order:
    ``dh = -dr / (B/H)``.

    ``mismatch_m`` (``dr``): position of a detail in the right ortho-image minus its position
    in the left one, metres, along the base: the unit vector of ``t_R - t_L``, where ``t`` is
    the horizontal displacement per metre of height of a line of sight (a DEM too high by
    ``e`` puts the detail ``e t`` away from its true place in each ortho-image, so ``dr = e
    B/H``). ``b_over_h`` is ``|t_R - t_L|`` (:func:`b_over_h`)."""
    if not b_over_h > 0:
        raise InputError(f"b_over_h must be > 0, got {b_over_h}")
    return -np.asarray(mismatch_m, np.float64) / float(b_over_h)


@attrs.frozen
class IterationReport:
    """One iteration: the mismatch of the ortho-images on the DEM it started from, and the
    update. ``median_abs_mismatch_px``: median |offset along the base| of the valid matches
    (what a height change removes), ortho pixels; ``matched_percent``: nodes with a valid
    match among the nodes both images cover; ``median_abs_dem_change_m``: median |height
    change| applied (0 when converged); ``median_across_base_px``: median offset across the
    base (a relative orientation error: no height change removes it)."""

    iteration: int
    median_abs_mismatch_px: float
    matched_percent: float
    median_abs_dem_change_m: float
    median_across_base_px: float
    seconds: float


@attrs.frozen(eq=False)
class IORResult:
    """The outcome of :func:`refine_dem`.

    Attributes:
        dem: the refined DEM (ellipsoidal heights, NaN outside the common area).
        dem_grid, ortho_grid: the grids of the DEM and of the ortho-images.
        ortho_left, ortho_right: float32 ortho-images on the final DEM (NaN = no data).
        score, valid: the last matching's correlation score and validity, per ortho pixel.
        iterations: one report per iteration.
        converged: the mismatch fell below the threshold.
        b_over_h: base-to-height ratio at the scene centre.
        init_coverage: share of the images' common footprint where the initial DEM had a
            height.
        init_filled: share of that footprint whose starting height was filled (voids of
            the initial DEM, :func:`starting_surface`).
    """

    dem: DEM
    dem_grid: OrthoGrid
    ortho_grid: OrthoGrid
    ortho_left: NDArray[np.float32]
    ortho_right: NDArray[np.float32]
    score: NDArray[np.float32]
    valid: NDArray[np.bool_]
    iterations: tuple[IterationReport, ...]
    converged: bool
    b_over_h: float
    init_coverage: float = 1.0
    init_filled: float = 0.0


def _grids(
    left: Sensor, right: Sensor, init_dem: DEM, settings: IORSettings
) -> tuple[OrthoGrid, OrthoGrid, int]:
    """DEM grid (posting) and ortho grid (``k`` ortho pixels per node), aligned, covering the
    area both images see. Refuses (before allocating anything) grids too large or too small
    for the common footprint."""
    from affine import Affine

    from carto.framework.imaging.preparation import ground_sampling_m
    from carto.framework.raster.images import MIN_IMAGE_PX

    h_mid = float(np.nanmedian(init_dem.heights))
    posting = float(settings.posting_m)
    res = settings.ortho_res_m
    if res is None:
        sampling = {
            side: ground_sampling_m(s, h_mid) for side, s in (("left", left), ("right", right))
        }
        for side, value in sampling.items():
            if not (np.isfinite(value) and value > 0.0):
                raise InputError(
                    f"dem: the centre of the {side} image does not locate on the ground at "
                    f"{h_mid:.0f} m (its model gives no ground sampling there: a model outside "
                    "its validity domain, or not this image's?)"
                )
        res = max(sampling.values())
    k = max(1, round(posting / res))
    crs = settings.crs
    if crs is None:  # the UTM zone of the two footprints' centre
        crs = footprint_box([left, right], init_dem)[0]
    _, (la, ba, ra, ta) = footprint_box([left], init_dem, crs)
    _, (lb, bb, rb, tb) = footprint_box([right], init_dem, crs)
    box = (max(la, lb), max(ba, bb), min(ra, rb), min(ta, tb))
    if not (box[0] < box[2] and box[1] < box[3]):
        raise InputError("dem: the two images do not overlap on the ground")
    width, height = box[2] - box[0], box[3] - box[1]
    size = f"{width:.0f} x {height:.0f} m"
    if 2.0 * posting > min(width, height):
        raise InputError(
            f"{option_label('posting_m')} {posting:g} m is larger than the images' common "
            f"footprint ({size}) allows: a DEM needs at least 2 x 2 nodes"
        )
    check_grid_size(
        width,
        height,
        posting,
        what="ior",
        option="posting_m (--posting)",
        max_cells=settings.max_cells,
    )
    o_rows, o_cols = check_grid_size(
        width,
        height,
        posting / k,
        what="ior",
        option="ortho_res_m (--ortho-res)",
        max_cells=settings.max_cells,
    )
    if min(o_rows, o_cols) < MIN_IMAGE_PX:
        raise InputError(
            f"{option_label('ortho_res_m')} {posting / k:g} m gives {o_cols} x {o_rows} "
            f"ortho pixels "
            f"over the images' common footprint ({size}); matching needs at least "
            f"{MIN_IMAGE_PX} x {MIN_IMAGE_PX}"
        )
    dem_grid = OrthoGrid.covering(
        [], init_dem, posting, crs=crs, bounds=box, max_cells=settings.max_cells
    )
    t = dem_grid.transform
    ortho_grid = OrthoGrid(
        dem_grid.crs,
        Affine(t.a / k, 0.0, t.c, 0.0, t.e / k, t.f),
        (dem_grid.shape[0] * k, dem_grid.shape[1] * k),
    )
    return dem_grid, ortho_grid, k


@attrs.frozen
class StartingSurface:
    """The starting heights on the DEM grid and what the initial DEM gave.

    Attributes:
        heights: heights of every DEM node (no NaN): the initial DEM's, its voids filled.
        coverage: share of the images' common footprint where the initial DEM has a height.
        filled: share of the footprint whose starting height was filled (interpolated).
        footprint: share of the DEM grid's nodes that both images see.
    """

    heights: FloatArray = attrs.field(eq=False)
    coverage: float
    filled: float
    footprint: float


def _seen_by_both(
    sensors: tuple[Sensor, Sensor], lon: FloatArray, lat: FloatArray, h: FloatArray
) -> NDArray[np.bool_]:
    """Whether both images see the ground points (inside both images' extents)."""
    inside = np.ones(lon.shape, bool)
    for sensor in sensors:
        n_l, n_s = sensor.image_shape
        with warnings.catch_warnings(), np.errstate(invalid="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            line, sample = sensor.ground_to_image(lon, lat, h)
            line, sample = np.asarray(line), np.asarray(sample)
            inside &= (line >= 0) & (line <= n_l) & (sample >= 0) & (sample <= n_s)
    return inside


def _nearest_post_valid(dem: DEM, lon: FloatArray, lat: FloatArray) -> NDArray[np.bool_]:
    """Whether the post of ``dem`` nearest to each point exists and holds a height."""
    row, col = dem.lonlat_to_pixel(lon, lat)
    n_rows, n_cols = dem.shape
    with np.errstate(invalid="ignore"):
        inside = (row > -0.5) & (row < n_rows - 0.5) & (col > -0.5) & (col < n_cols - 0.5)
    r = np.clip(np.rint(np.where(inside, row, 0)), 0, n_rows - 1).astype(np.intp)
    c = np.clip(np.rint(np.where(inside, col, 0)), 0, n_cols - 1).astype(np.intp)
    return inside & np.isfinite(dem.heights[r, c])


_FOOTPRINT_SAMPLES = 250_000  # nodes at most on which the footprint and coverage are measured


def starting_surface(
    init_dem: DEM,
    grid: OrthoGrid,
    sensors: tuple[Sensor, Sensor],
    min_coverage: float = 0.75,
) -> StartingSurface:
    """The starting heights of IOR on ``grid``: the initial DEM, its voids (and the nodes just
    outside it) filled by GDAL's inverse-distance interpolation
    (:func:`~carto.framework.raster.dem_measures.fill_voids`), so the
    first ortho-images have no holes and the first heights no jumps.

    Raises:
        InputError: the initial DEM gives a height at less than ``min_coverage`` of the
            images' common footprint (mostly void, or a tile of another place).
    """
    rows, cols = np.mgrid[0 : grid.shape[0], 0 : grid.shape[1]]
    lon, lat = grid.lonlat(rows, cols)
    raw = init_dem.height(lon, lat)
    covered = np.isfinite(raw)
    step = max(1, math.ceil(math.sqrt(raw.size / _FOOTPRINT_SAMPLES)))
    pick = (slice(None, None, step), slice(None, None, step))
    h_mid = float(np.nanmedian(raw)) if covered.any() else float(np.nanmedian(init_dem.heights))
    h_fp = np.where(covered[pick], raw[pick], h_mid)
    seen = _seen_by_both(sensors, lon[pick], lat[pick], h_fp)
    if not seen.any():  # a sliver: measure over the whole grid
        seen = np.ones_like(seen)
    # coverage: the nearest post has a height (bilinear sampling would also lose the ring of
    # cells around each void, which overstates a void of a coarse DEM)
    post = _nearest_post_valid(init_dem, lon[pick], lat[pick])
    coverage = float(post[seen].mean())
    if coverage < min_coverage:
        raise InputError(
            f"dem: initial DEM {init_dem.name} covers {100.0 * coverage:.0f} % of the images' "
            f"footprint (at least {100.0 * min_coverage:.0f} % needed: a DEM mostly void, or "
            "a tile of another place; check the file, or start from --init-height M)"
        )
    heights = raw
    if not covered.all():
        bounds = (float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max()))
        filled_dem, _ = fill_voids(init_dem, bounds)
        heights = np.where(covered, raw, filled_dem.height(lon, lat))
        still = ~np.isfinite(heights)
        if still.any():  # beyond the initial DEM: fill on the grid itself
            from rasterio.fill import fillnodata

            heights = fillnodata(
                np.where(still, 0.0, heights),
                mask=(~still).astype(np.uint8),
                max_search_distance=float(math.hypot(*heights.shape)) + 1.0,
                smoothing_iterations=0,
            )
        heights = np.where(np.isfinite(heights), heights, h_mid)
    filled = float((~post & seen).sum()) / max(int(seen.sum()), 1)
    return StartingSurface(np.asarray(heights, np.float64), coverage, filled, float(seen.mean()))


def _dem_on(grid: OrthoGrid, heights: FloatArray) -> DEM:
    return DEM.from_array(
        np.where(np.isfinite(heights), heights, np.nanmedian(heights)),
        grid.transform,
        grid.crs.to_wkt(),
        vertical=ELLIPSOID,
    )


def base_direction(
    left: Sensor, right: Sensor, lon: float, lat: float, h: float
) -> tuple[float, FloatArray]:
    """``(B/H, unit (east, north))`` at a ground point: ``t_R - t_L``, the horizontal
    displacement between the two lines of sight per metre of height (``t``: of length
    ``tan theta``), its length and direction. A DEM too high shifts a detail in the right
    ortho-image against the left one along this direction."""
    from carto.framework.geometry import frames

    e_n_u = frames.enu_basis(lon, lat)
    t = []
    for s in (left, right):
        line, sample = s.ground_to_image(lon, lat, h)
        lo, la = s.image_to_ground(line, sample, h + 100.0)
        d = frames.geodetic_to_ecef(lo, la, h + 100.0) - frames.geodetic_to_ecef(lon, lat, h)
        t.append((e_n_u @ np.ravel(d))[:2] / 100.0)
    base = t[1] - t[0]
    length = float(np.linalg.norm(base))
    return length, base / length


def b_over_h(left: Sensor, right: Sensor, lon: float, lat: float, h: float) -> float:
    """Base-to-height ratio at a ground point (:func:`base_direction`)."""
    return base_direction(left, right, lon, lat, h)[0]


def _block_mean(values: NDArray, k: int, shape: tuple[int, int]) -> FloatArray:
    """Mean of the finite values of each ``k x k`` block (NaN for an empty block)."""
    v = np.asarray(values, np.float64)[: shape[0] * k, : shape[1] * k]
    blocks = v.reshape(shape[0], k, shape[1], k)
    finite = np.isfinite(blocks)
    count = finite.sum(axis=(1, 3))
    total = np.where(finite, blocks, 0.0).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


@attrs.frozen(eq=False)
class TileResult:
    """What :func:`refine_tile` returns for its interior nodes: the height each matched node
    should have (NaN: no valid match), the node offsets right minus left (ortho pixels, rows
    and columns), whether both images cover the node, and the ortho-images and matching
    layers of the tile interior."""

    rows: slice
    cols: slice
    new_height: FloatArray
    d_row_px: FloatArray
    d_col_px: FloatArray
    covered: NDArray[np.bool_]
    ortho_left: NDArray[np.float32]
    ortho_right: NDArray[np.float32]
    score: NDArray[np.float32]
    valid: NDArray[np.bool_]


def _default_matcher() -> Matcher:
    from carto.framework.matching.ncc_matcher import NCCMatcher

    return NCCMatcher()


def refine_tile(
    images: tuple[NDArray, NDArray],
    sensors: tuple[Sensor, Sensor],
    heights: FloatArray,
    dem_grid: OrthoGrid,
    k: int,
    rows: slice,
    cols: slice,
    overlap: int,
    settings: IORSettings,
    levels: int | None = None,
    guess: tuple[float, float] = (0.0, 0.0),
    matcher: Matcher | None = None,
) -> TileResult:
    """One tile of one iteration: orthos on the current DEM, dense matching, intersection.

    ``heights`` is the whole current DEM grid (the tile reads its window plus ``overlap``
    nodes around it); the result covers ``rows, cols`` (DEM node slices) only.
    """
    from carto.framework.geometry.intersection import intersect_sensors

    n_r, n_c = dem_grid.shape
    r0, r1 = max(0, rows.start - overlap), min(n_r, rows.stop + overlap)
    c0, c1 = max(0, cols.start - overlap), min(n_c, cols.stop + overlap)
    sub = dem_grid.window(r0, c0, r1 - r0, c1 - c0)
    dem = _dem_on(sub, heights[r0:r1, c0:c1])
    t = sub.transform
    from affine import Affine

    ogrid = OrthoGrid(
        sub.crs, Affine(t.a / k, 0.0, t.c, 0.0, t.e / k, t.f), ((r1 - r0) * k, (c1 - c0) * k)
    )
    left, right = sensors
    ortho = [orthorectify(img, s, ogrid, dem) for img, s in zip(images, sensors, strict=True)]
    field = (matcher or _default_matcher()).match_dense(
        ortho[0],
        ortho[1],
        settings=DenseSettings(
            levels=settings.levels if levels is None else levels,
            guess=guess,
            window=settings.window,
            min_score=settings.min_score,
        ),
    )
    # node offsets: the mean of the valid offsets of the node's k x k ortho pixels
    shape = (r1 - r0, c1 - c0)
    d_row = _block_mean(field.d_row, k, shape)
    d_col = _block_mean(field.d_col, k, shape)
    covered = np.isfinite(_block_mean(ortho[0], k, shape)) & np.isfinite(
        _block_mean(ortho[1], k, shape)
    )
    ok = np.isfinite(d_row) & np.isfinite(d_col) & covered
    nr, nc = np.nonzero(ok)
    # left ray: the node's ground point on the current DEM; right ray: the matched position
    h_node = heights[r0:r1, c0:c1][nr, nc]
    lon_l, lat_l = sub.lonlat(nr, nc)
    line_l, sample_l = left.ground_to_image(lon_l, lat_l, h_node)
    rr = (nr + 0.5) * k - 0.5 + d_row[nr, nc]  # ortho pixel index of the match
    cc = (nc + 0.5) * k - 0.5 + d_col[nr, nc]
    lon_r, lat_r = ogrid.lonlat(rr, cc)
    h_r = dem.height(lon_r, lat_r)
    line_r, sample_r = right.ground_to_image(lon_r, lat_r, h_r)
    h_lo = float(np.nanmin(heights)) - 500.0
    h_hi = float(np.nanmax(heights)) + 500.0
    inter = intersect_sensors(
        [left, right],
        np.stack([line_l, line_r]),
        np.stack([sample_l, sample_r]),
        h_range_m=(h_lo, h_hi),
    )
    lon_p, lat_p, h_p = inter.lon_deg, inter.lat_deg, inter.h_m
    # back to the node: the intersection lies on the left ray, a little off the node
    # (horizontally); remove the height change of that offset along the current surface
    x_p, y_p = sub.map_xy(lon_p, lat_p)
    x_n, y_n = sub.xy(nr, nc)
    g_row, g_col = np.gradient(heights[r0:r1, c0:c1])
    px, py = sub.resolution
    slope_x = g_col[nr, nc] / px
    slope_y = -g_row[nr, nc] / py
    new = np.full(shape, np.nan)
    new[nr, nc] = h_p - slope_x * (x_p - x_n) - slope_y * (y_p - y_n)
    ir = slice(rows.start - r0, rows.stop - r0)
    ic = slice(cols.start - c0, cols.stop - c0)
    orr = slice(ir.start * k, ir.stop * k)
    occ = slice(ic.start * k, ic.stop * k)
    return TileResult(
        rows,
        cols,
        new[ir, ic],
        d_row[ir, ic],
        d_col[ir, ic],
        covered[ir, ic],
        ortho[0][orr, occ],
        ortho[1][orr, occ],
        field.score[orr, occ],
        field.valid[orr, occ],
    )


def regularise(
    heights: FloatArray, new_height: FloatArray, settings: IORSettings
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The DEM update: height changes ``new - heights`` at matched nodes, outliers against
    the 5 x 5 local median removed, then a normalised Gaussian convolution (sigma
    ``smoothing_nodes``) that smooths the noise and fills the holes from their neighbours
    (nodes far from any match keep their height). Returns the new heights and the inliers."""
    from numpy.lib.stride_tricks import sliding_window_view
    from scipy import ndimage

    dh = new_height - heights
    valid = np.isfinite(dh)
    if not valid.any():
        return heights.copy(), valid
    padded = np.pad(np.where(valid, dh, np.nan), 2, mode="edge")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        local = np.nanmedian(sliding_window_view(padded, (5, 5)).reshape(*dh.shape, 25), axis=-1)
    resid = dh - local
    r = resid[np.isfinite(resid)]
    nmad = 1.4826 * float(np.median(np.abs(r - np.median(r)))) if r.size else 0.0
    inlier = valid & np.isfinite(local) & (np.abs(resid) <= max(settings.outlier_m, 4.0 * nmad))
    w = inlier.astype(np.float64)
    sigma = float(settings.smoothing_nodes)
    num = ndimage.gaussian_filter(np.where(inlier, dh, 0.0), sigma, mode="nearest")
    den = ndimage.gaussian_filter(w, sigma, mode="nearest")
    # holes: grow the fill with wider Gaussians where the narrow one has no support
    for wide in (3 * sigma, 9 * sigma):
        missing = den < 0.05
        if not missing.any():
            break
        num = np.where(missing, ndimage.gaussian_filter(num, wide, mode="nearest"), num)
        den = np.where(missing, ndimage.gaussian_filter(den, wide, mode="nearest"), den)
    with np.errstate(invalid="ignore", divide="ignore"):
        update = np.where(den > 1e-3, num / den, 0.0)
    return heights + update, inlier


def refine_dem(
    left_image: NDArray,
    right_image: NDArray,
    left: Sensor,
    right: Sensor,
    init_dem: DEM,
    settings: IORSettings | None = None,
    progress: Callable[[str], None] | None = None,
    scheduler: Callable[[list[Callable[[], TileResult]]], list[TileResult]] | None = None,
    matcher: Matcher | None = None,
) -> IORResult:
    """The IOR loop (see the module docstring).

    Args:
        left_image, right_image: raw images (2-D, the sensors' shapes; staggered arrays
            already merged).
        left, right: their models (adjusted, for a DEM of the adjusted accuracy).
        init_dem: the starting DEM (ellipsoidal heights; SRTM with a geoid, or
            :meth:`DEM.constant`).
        settings: :class:`IORSettings`.
        progress: called with one line per iteration.
        scheduler: runs a list of tile tasks and returns their results (default: in turn;
            e.g. ``lambda tasks: dask.compute(*map(dask.delayed, tasks))``).
        matcher: the dense matcher of the ortho-images (default: the framework's ``"ncc"``,
            hierarchical NCC with a left-right check); any matcher with ``match_dense``.

    Raises:
        InputError: images that do not overlap, an initial DEM that covers too little of
            them (:func:`starting_surface`), a posting or ortho resolution that makes a grid
            too large or too small for the footprint, bad settings.
    """
    s = settings or IORSettings()
    dem_grid, ortho_grid, k = _grids(left, right, init_dem, s)
    start = starting_surface(init_dem, dem_grid, (left, right), s.min_init_coverage)
    heights = start.heights
    if progress and start.filled > 0.0:
        progress(
            f"initial DEM {init_dem.name}: {100.0 * start.filled:.1f} % of the footprint "
            "filled (voids)"
        )
    n_r, n_c = dem_grid.shape
    c_lon, c_lat = dem_grid.lonlat(n_r / 2, n_c / 2)
    bh, base_en = base_direction(
        left, right, float(c_lon), float(c_lat), float(np.nanmedian(heights))
    )
    base_rc = np.array([-base_en[1], base_en[0]])  # (row, col) of the north-up grid
    run = scheduler or (lambda tasks: [task() for task in tasks])
    tile_n = max(16, s.tile_px // k)
    overlap_n = max(2, -(-s.overlap_px // k))
    reports: list[IterationReport] = []
    converged = False
    tiles: list[TileResult] = []
    guess = (0.0, 0.0)
    ever_matched = np.zeros(dem_grid.shape, bool)
    for iteration in range(1, s.max_iterations + 2):
        t0 = time.perf_counter()
        current = heights.copy()
        tasks = [
            functools.partial(
                refine_tile,
                (left_image, right_image),
                (left, right),
                current,
                dem_grid,
                k,
                slice(r, min(n_r, r + tile_n)),
                slice(c, min(n_c, c + tile_n)),
                overlap_n,
                s,
                s.refine_levels
                if reports and reports[-1].median_abs_mismatch_px < 2.0
                else s.levels,
                guess,
                matcher,
            )
            for r in range(0, n_r, tile_n)
            for c in range(0, n_c, tile_n)
        ]
        tiles = run(tasks)
        new = np.full(dem_grid.shape, np.nan)
        d_row = np.full(dem_grid.shape, np.nan)
        d_col = np.full(dem_grid.shape, np.nan)
        covered = np.zeros(dem_grid.shape, bool)
        for tile in tiles:
            new[tile.rows, tile.cols] = tile.new_height
            d_row[tile.rows, tile.cols] = tile.d_row_px
            d_col[tile.rows, tile.cols] = tile.d_col_px
            covered[tile.rows, tile.cols] = tile.covered
        matched = np.isfinite(d_row) & covered
        ever_matched |= matched
        # the mismatch a height change removes: along the base; across it, what the
        # relative orientation leaves (reported, and the next search starts from it)
        along = d_row * base_rc[0] + d_col * base_rc[1]
        across = -d_row * base_rc[1] + d_col * base_rc[0]
        med = float(np.median(np.abs(along[matched]))) if matched.any() else float("nan")
        across_px = float(np.median(across[matched])) if matched.any() else float("nan")
        if matched.any():  # the across-base offset stays; the along-base one the DEM removes
            guess = (-across_px * float(base_rc[1]), across_px * float(base_rc[0]))
        pct = 100.0 * float(matched.sum()) / max(int(covered.sum()), 1)
        # converged: the mismatch is below the threshold, or it no longer improves (what
        # is left is the matching noise, which no height change removes)
        stalled = (
            bool(reports) and med > (1.0 - s.min_improvement) * reports[-1].median_abs_mismatch_px
        )
        done = bool(matched.any() and (med < s.threshold_px or stalled))
        if done or iteration > s.max_iterations:
            converged = done
            reports.append(
                IterationReport(iteration, med, pct, 0.0, across_px, time.perf_counter() - t0)
            )
            if progress:
                progress(
                    f"iteration {iteration}: median mismatch {med:.3f} px along the base, "
                    f"{pct:.1f} % matched" + (" (converged)" if done else " (last)")
                )
            break
        heights, _ = regularise(current, new, s)
        change = np.abs(heights - current)[covered]
        med_change = float(np.median(change)) if change.size else 0.0
        reports.append(
            IterationReport(iteration, med, pct, med_change, across_px, time.perf_counter() - t0)
        )
        if progress:
            progress(
                f"iteration {iteration}: median mismatch {med:.3f} px along the base, "
                f"{pct:.1f} % matched, median DEM change {med_change:.2f} m"
            )
    # assemble the last orthos (made on the final DEM) and quality layers
    shape = ortho_grid.shape
    out_l = np.full(shape, np.nan, np.float32)
    out_r = np.full(shape, np.nan, np.float32)
    score = np.full(shape, np.nan, np.float32)
    valid = np.zeros(shape, bool)
    for tile in tiles:
        rs = slice(tile.rows.start * k, tile.rows.stop * k)
        cs = slice(tile.cols.start * k, tile.cols.stop * k)
        out_l[rs, cs], out_r[rs, cs] = tile.ortho_left, tile.ortho_right
        score[rs, cs], valid[rs, cs] = tile.score, tile.valid
    final = np.where(covered & _support(ever_matched, s), heights, np.nan)
    dem = DEM.from_array(final, dem_grid.transform, dem_grid.crs.to_wkt(), vertical=ELLIPSOID)
    return IORResult(
        dem,
        dem_grid,
        ortho_grid,
        out_l,
        out_r,
        score,
        valid,
        tuple(reports),
        converged,
        bh,
        init_coverage=start.coverage,
        init_filled=start.filled,
    )


def _support(matched: NDArray[np.bool_], settings: IORSettings) -> NDArray[np.bool_]:
    """The nodes :func:`regularise` reaches from matched nodes (its widest Gaussian, 9 sigma):
    the others were never measured and keep the starting height, so the DEM has no value
    there."""
    from scipy import ndimage

    if not matched.any():
        return matched.copy()
    wide = 9.0 * float(settings.smoothing_nodes)
    reach = ndimage.gaussian_filter(matched.astype(np.float64), wide, mode="constant")
    return (reach > 1e-3) | matched
