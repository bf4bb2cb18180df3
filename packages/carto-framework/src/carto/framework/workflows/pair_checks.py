"""The checks a stereo pair passes before it is matched (:func:`check_pair`): the two images
overlap on the ground, and their coarse ortho-images correlate. ``carto dem`` fails on a pair
that does not (``--allow-poor`` goes on, with the reasons in ``report.json`` ``warnings``): two
images of different places, a right image rotated or mirrored, a model that is not its
image's, all of which otherwise give a DEM that looks plausible and is not (issue 31).

How: both images are reduced by block means (GDAL's average overview of a raster, else
:class:`~carto.framework.raster.image_source.DecimatedImage`) to about the pixel of a grid
of :data:`CHECK_SIDE_PX` pixels over both footprints, and orthorectified on it over the
starting DEM with their own (reduced) models. The overlap is the share of the smaller
footprint that the other image covers. Then blocks of :data:`BLOCK_PX` pixels of the left
ortho-image are searched for in the right one (high-passed, correlation coefficient) within
:data:`SEARCH_M` of where the models put them, and again around the images' whole shift
(:func:`~carto.framework.matching.shifts.coarse_shift`: system-level pointing can move a
small footprint by more than its size). The blocks of a true pair agree on their shift, up
to the parallax of the starting DEM's errors and the drift of the pointing; those of
unrelated images land anywhere: the check is the share of blocks that agree
(:data:`MIN_AGREEMENT`). A block-wise search, so that relief the starting DEM does not have
does not decorrelate the whole image. The cost is one reading of each image.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.raster.dem import DEM

CHECK_SIDE_PX = 768
"""Pixels of the check's ortho grid along the longer side of both footprints."""
BLOCK_PX = 48
"""Side of the blocks correlated one by one (a block needs :data:`BLOCK_VALID` of its
pixels in both ortho-images)."""
BLOCK_VALID = 0.9
SEARCH_M = 1500.0
"""How far a block is searched for, metres: the system-level pointing error of the
products (60-900 m in the simulated presets, ``control_checks.GROSS_LIMIT_M``) and the
parallax of a starting DEM's error."""
SEARCH_SHARE = 5
"""... and at most this fraction of the grid's shorter side (small images, precise models:
a 1024-pixel Pleiades crop is 500 m wide)."""
AGREEMENT_M = 300.0
"""A block agrees with the pair when its shift is within this of the blocks' median shift
(or within :data:`AGREEMENT_PX`): what varies over a scene is the parallax of the starting
DEM's errors and the drift of the pointing (up to 300 m on the simulated scenes with
``--errors full``)."""
AGREEMENT_PX = 3.0
AGREEMENT_SHARE = 0.2
"""... but at most this share of the search radius (else unrelated blocks agree by chance)."""
HIGH_PASS_PX = 3.0
"""Sigma of the Gaussian whose blur is subtracted before correlating (ortho pixels): the
images' brightness and its slow variations differ between views and dates."""

MIN_OVERLAP = 0.1
"""A pair whose images cover less than this share of the smaller footprint fails: there is
next to nothing to make a DEM of (images of two places, or the wrong models); unless its
blocks agree on a shift (:data:`MIN_AGREEMENT`): then the models are off, not the images (a
simulated Cartosat-2 view placed 580 m off by its system-level model overlapped its pair on
5 % by the models, and its blocks agreed at 87 %)."""
MIN_AGREEMENT = 0.5
"""A pair whose blocks agree on their shift less often than this fails. Measured
(``benchmarks/results/pair_checks.json``): true pairs agree at 65-100 % (simulated Cartosat-1,
Cartosat-2 and generic pairs with ``--errors full``, the real Reunion and Ventoux Pleiades
pairs; the simulated pairs are our own simulator, a best case); a right image rotated by
180 deg, mirrored or of another scene at 0-20 % (the best shift of a block of unrelated
images is anywhere in the search area: a few fall near the median by chance). All 12 true
and 33 false pairs of the benchmark are judged right."""
MIN_BASE_TO_HEIGHT = 0.05
"""A pair whose base-to-height ratio at the centre of the left image is below this is
refused: its parallax is too small to give heights (the same image twice, identical
models). Stereo pairs have 0.2-0.8 (the Reunion Pleiades pair 0.26, a simulated Cartosat-1
pair 0.64)."""
MIN_BLOCKS = 4
"""Fewer blocks than this (a small overlap, little texture) is too little to judge by: the
check then only reports."""


@attrs.frozen
class PairCheck:
    """What :func:`check_pair` measured.

    Attributes:
        overlap: share of the smaller footprint (on the starting DEM) the other image covers.
        blocks: the number of blocks correlated (at the models' place of the right image or
            at the images' whole shift, whichever gives more).
        agreement: the share of them whose best shift agrees with the median shift of the
            blocks around the models' place or around the whole shift, whichever agrees
            more (NaN: no block).
        correlation: the median of their best correlation coefficients (NaN: no block).
        shift_m: the blocks' median shift, ``(east, north)`` metres (right minus left).
        resolution_m: the check's ortho pixel.
    """

    overlap: float
    blocks: int
    agreement: float
    correlation: float
    shift_m: tuple[float, float]
    resolution_m: float

    def warnings(self) -> list[str]:
        """Why the pair should not be matched (empty when it may). The overlap is the
        models'; blocks that agree on a shift show the images do overlap there (system-level
        pointing can put a small view hundreds of metres off), and outweigh it."""
        judged = self.blocks >= MIN_BLOCKS
        if self.overlap < MIN_OVERLAP and not (judged and self.agreement >= MIN_AGREEMENT):
            return [
                f"the two images overlap on {100 * self.overlap:.1f} % of the smaller "
                f"footprint (< {100 * MIN_OVERLAP:g} %): images of two places, a starting "
                "height far off the terrain (--init-height, --init-dem) or the wrong models?"
            ]
        if judged and self.agreement < MIN_AGREEMENT:
            return [
                f"the two images do not correlate: {100 * self.agreement:.0f} % of "
                f"{self.blocks} blocks of {BLOCK_PX * self.resolution_m:.0f} m of their "
                f"coarse ortho-images agree on a shift (< {100 * MIN_AGREEMENT:g} %; median "
                f"correlation {self.correlation:.2f}): images of two places or dates, a "
                "rotated or mirrored image, a starting height far off the terrain "
                "(--init-height, --init-dem), or a model that is not its image's?"
            ]
        return []

    def as_dict(self) -> dict[str, Any]:
        def rounded(value: float, digits: int) -> float | None:
            return None if math.isnan(value) else round(value, digits)

        return {
            "overlap": round(self.overlap, 4),
            "blocks": self.blocks,
            "agreement": rounded(self.agreement, 3),
            "correlation": rounded(self.correlation, 3),
            "shift_m": [rounded(v, 1) for v in self.shift_m],
            "resolution_m": rounded(self.resolution_m, 2),
        }


def check_pair(images: Sequence[Any], sensors: Sequence[Sensor], dem: DEM) -> PairCheck:
    """Overlap and coarse correlation of a pair (see the module docstring): ``images`` are
    the prepared raw images (:class:`~carto.framework.raster.image_source.ImageSource`) of
    ``sensors``, ``dem`` the starting DEM (ellipsoidal heights)."""
    from carto.framework.imaging.ortho_grid import OrthoGrid, footprint_box
    from carto.framework.imaging.preparation import ground_sampling_m
    from carto.framework.matching.shifts import coarse_shift

    nothing = (math.nan, math.nan)
    boxes = [footprint_box(s, dem, "EPSG:4326")[1] for s in sensors]
    if not _boxes_meet(*boxes):  # two places: no grid over both
        return PairCheck(0.0, 0, math.nan, math.nan, nothing, math.nan)
    h_mid = float(np.nanmedian(dem.heights)) if np.isfinite(dem.heights).any() else 0.0
    gsd = [ground_sampling_m(s, h_mid) for s in sensors]
    crs, (left, bottom, right, top) = footprint_box(list(sensors), dem)
    res = max(max(right - left, top - bottom) / CHECK_SIDE_PX, 2.0 * max(gsd))
    grid = OrthoGrid.covering([], dem, res, crs=crs, bounds=(left, bottom, right, top))
    dem = _surface(dem, grid)
    orthos = []
    for image, sensor, g in zip(images, sensors, gsd, strict=True):
        factor = max(1, int(res / g))
        orthos.append(_coarse_ortho(image, sensor, factor, grid, dem))
    valid = [np.isfinite(o) for o in orthos]
    smaller = min(int(v.sum()) for v in valid)
    overlap = float((valid[0] & valid[1]).sum() / smaller) if smaller else 0.0
    # where the models put the right image, and the images' whole shift (system-level
    # pointing can move a small footprint by more than its size): the better of the two
    d_row, d_col, _score = coarse_shift(orthos[0], orthos[1])
    search_px = max(2, min(round(SEARCH_M / res), min(grid.shape) // SEARCH_SHARE))
    tolerance = max(AGREEMENT_PX, min(AGREEMENT_M / res, AGREEMENT_SHARE * search_px))
    tried = [_blocks_at(orthos, shift, search_px, tolerance) for shift in ((0, 0), (d_row, d_col))]
    population = max(len(found) for found, _agree, _median in tried)
    if not population:
        return PairCheck(overlap, 0, math.nan, math.nan, nothing, float(res))
    found, agree, median = max(tried, key=lambda t: int(t[1].sum()))
    return PairCheck(
        overlap,
        population,
        float(agree.sum() / population),
        float(np.median(found[:, 0])),
        (float(median[1] * res), float(-median[0] * res)),
        float(res),
    )


def _blocks_at(
    orthos: Sequence[NDArray[np.float32]],
    shift: tuple[float, float],
    search_px: int,
    tolerance: float,
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
    """The blocks found around ``shift`` (:func:`_block_shifts`), which of them agree with
    their median shift within ``tolerance`` pixels, and that median ``(d_row, d_col)``."""
    found = _block_shifts(orthos[0], orthos[1], (round(shift[0]), round(shift[1])), search_px)
    if not len(found):
        return found, np.zeros(0, bool), np.full(2, np.nan)
    median = np.median(found[:, 1:], axis=0)
    return found, np.all(np.abs(found[:, 1:] - median) <= tolerance, axis=1), median


def _surface(dem: DEM, grid: Any) -> DEM:
    """``dem``, or a constant height (its median) when it covers less than half of ``grid``:
    a starting DEM of another place or mostly void is the DEM generator's to refuse, with
    its own message; the pair can still be judged on a flat surface."""
    rows, cols = (np.linspace(0, n - 1, 33) for n in grid.shape)
    lon, lat = grid.lonlat(*np.meshgrid(rows, cols, indexing="ij"))
    if np.isfinite(dem.height(lon, lat)).mean() >= 0.5:
        return dem
    valid = np.isfinite(dem.heights)
    return DEM.constant(float(np.median(dem.heights[valid])) if valid.any() else 0.0)


def _boxes_meet(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """Whether two ``(left, bottom, right, top)`` boxes intersect."""
    return max(a[0], b[0]) < min(a[2], b[2]) and max(a[1], b[1]) < min(a[3], b[3])


def _coarse_ortho(
    image: Any, sensor: Sensor, factor: int, grid: Any, dem: DEM
) -> NDArray[np.float32]:
    """``image`` reduced ``factor`` times and orthorectified on ``grid``."""
    from carto.framework.geometry.decimated import DecimatedSensor
    from carto.framework.imaging.ortho import orthorectify
    from carto.framework.raster.image_source import DecimatedImage, RasterImage

    if factor == 1:
        reduced = image
    elif isinstance(image, RasterImage):
        reduced = image.averaged(factor)
    else:
        reduced = DecimatedImage(image, factor)[:, :]
    return orthorectify(reduced, DecimatedSensor(sensor, factor), grid, dem, resampling="linear")


def _high_pass(ortho: NDArray[np.float32]) -> NDArray[np.float32]:
    """``ortho`` minus its Gaussian blur (NaN-aware: normalised convolution), NaN kept."""
    import cv2

    ok = np.isfinite(ortho)
    filled = np.where(ok, ortho, 0.0).astype(np.float32)
    weight = cv2.GaussianBlur(ok.astype(np.float32), (0, 0), HIGH_PASS_PX)
    blur = cv2.GaussianBlur(filled, (0, 0), HIGH_PASS_PX) / np.maximum(weight, 1e-6)
    return np.where(ok, filled - blur, np.nan).astype(np.float32)


def _block_shifts(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    global_shift: tuple[int, int],
    search_px: int,
) -> NDArray[np.float64]:
    """Per block of ``left`` whose place in ``right`` (moved by ``global_shift``, pixels)
    is valid in both: the best correlation coefficient within ``search_px`` of that place,
    and its shift ``(d_row, d_col)``, pixels: an ``(n, 3)`` array."""
    import cv2

    a, b = _high_pass(left), _high_pass(right)
    pad = search_px + max(abs(global_shift[0]), abs(global_shift[1]))
    b = np.pad(b, pad, constant_values=np.nan)
    ok_a, ok_b = np.isfinite(a), np.isfinite(b)
    a0, b0 = np.nan_to_num(a), np.nan_to_num(b)
    rows, cols = a.shape
    found = []
    for r0 in range(0, rows - BLOCK_PX + 1, BLOCK_PX):
        for c0 in range(0, cols - BLOCK_PX + 1, BLOCK_PX):
            block = np.s_[r0 : r0 + BLOCK_PX, c0 : c0 + BLOCK_PX]
            rb, cb = r0 + pad + global_shift[0], c0 + pad + global_shift[1]
            there = np.s_[rb : rb + BLOCK_PX, cb : cb + BLOCK_PX]
            if min(ok_a[block].mean(), ok_b[there].mean()) < BLOCK_VALID:
                continue
            template = a0[block]
            if not template.std() > 1e-6 * (np.abs(template).max() + 1e-30):
                continue  # no texture: nothing to judge by
            window = b0[
                rb - search_px : rb + BLOCK_PX + search_px,
                cb - search_px : cb + BLOCK_PX + search_px,
            ]
            ncc = np.nan_to_num(cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED))
            k_r, k_c = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
            found.append(
                (
                    float(ncc[k_r, k_c]),
                    k_r - search_px + global_shift[0],
                    k_c - search_px + global_shift[1],
                )
            )
    return np.array(found, np.float64).reshape(-1, 3)


def checked_pair(
    images: Sequence[Any], sensors: Sequence[Sensor], dem: DEM, *, allow_poor: bool
) -> tuple[PairCheck, list[str]]:
    """:func:`check_pair` and its warnings, for a DEM run: images that do not overlap at
    all fail; a pair that fails a check fails unless ``allow_poor``.

    Raises:
        InputError: no overlap, or a failed check without ``allow_poor``."""
    ratio = base_to_height(sensors, dem)
    if ratio < MIN_BASE_TO_HEIGHT:  # NaN (the right image does not see there): not judged
        raise InputError(
            f"dem: the two images have a base-to-height ratio of {ratio:.3f} (< "
            f"{MIN_BASE_TO_HEIGHT:g}): no stereo parallax to make heights of (the same image "
            "twice, or the same model for both?)"
        )
    check = check_pair(images, sensors, dem)
    if check.overlap == 0.0:
        raise InputError(
            "dem: the two images do not overlap on the ground (with their models, on the "
            "starting DEM): images of two places, a starting height far off the terrain "
            "(--init-height, --init-dem) or the wrong models?"
        )
    warnings = check.warnings()
    if warnings and not allow_poor:
        raise InputError(f"dem: {'; '.join(warnings)} (--allow-poor matches them anyway)")
    return check, warnings


def base_to_height(sensors: Sequence[Sensor], dem: DEM) -> float:
    """The base-to-height ratio of a pair where the left image's centre meets the ground
    (:func:`~carto.framework.geometry.intersection.base_direction`; NaN when the right image
    does not see that point)."""
    from carto.framework.geometry.intersection import base_direction

    left, right = sensors
    n_l, n_s = left.image_shape
    lon, lat, h = left.locate_on_dem(np.array([n_l / 2]), np.array([n_s / 2]), dem)
    if not np.isfinite(h).all():
        h = np.array([float(np.nanmedian(dem.heights))])
        lon, lat = left.image_to_ground(np.array([n_l / 2]), np.array([n_s / 2]), h)
    return base_direction(left, right, float(lon[0]), float(lat[0]), float(h[0]))[0]
