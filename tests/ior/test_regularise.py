"""The regularised DEM update by bands of rows, its hole-filling filters on tiles, equals the
update computed on the whole grid at once (written here plainly: scipy filters over the whole
arrays), whatever the band and tile sizes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from carto.framework.raster.focal import focal_nanmedian
from carto.ior.regularise import regularise
from carto.ior.settings import IORSettings


def _whole_grid(heights, new, settings):
    dh = new - heights
    resid = (dh - focal_nanmedian(dh, 2)).astype(np.float32)
    r = resid[np.isfinite(resid)].astype(np.float64)
    nmad = 1.4826 * np.median(np.abs(r - np.median(r)))
    with np.errstate(invalid="ignore"):
        inlier = np.abs(resid) <= max(settings.outlier_m, 4.0 * nmad)
    sigma = settings.smoothing_nodes
    num = ndimage.gaussian_filter(np.where(inlier, dh, 0.0), sigma, mode="nearest")
    den = ndimage.gaussian_filter(inlier.astype(float), sigma, mode="nearest")
    for wide in (3 * sigma, 9 * sigma):
        missing = den < 0.05
        num = np.where(missing, ndimage.gaussian_filter(num, wide, mode="nearest"), num)
        den = np.where(missing, ndimage.gaussian_filter(den, wide, mode="nearest"), den)
    with np.errstate(invalid="ignore", divide="ignore"):
        return heights + np.where(den > 1e-3, num / den, 0.0), inlier


@pytest.fixture(scope="module")
def grids():
    rng = np.random.default_rng(5)
    rows, cols = 300, 170
    heights = 500.0 + 30.0 * np.sin(np.arange(cols) / 17.0)[None, :] + np.zeros((rows, 1))
    new = heights + 1.5 + rng.normal(0.0, 0.3, heights.shape)
    new[rng.random(heights.shape) < 0.02] += 40.0  # wild matches
    new[40:120, 30:90] = np.nan  # a hole wider than every Gaussian
    new[200:204, :] = np.nan  # a gap across the grid
    new[250:, 150:] = np.nan  # an unmatched corner
    return heights, new


@pytest.mark.parametrize(
    ("band_rows", "fill_tile"),
    [(1, 512), (7, 512), (64, 512), (10_000, 512), (64, 16), (10_000, 9)],
)
def test_bands_and_fill_tiles_give_the_whole_grid_update(grids, band_rows, fill_tile):
    heights, new = grids
    settings = IORSettings(smoothing_nodes=1.5)
    expected, expected_inlier = _whole_grid(heights, new, settings)
    out, inlier = regularise(heights, new, settings, band_rows=band_rows, fill_tile=fill_tile)
    np.testing.assert_array_equal(inlier, expected_inlier)
    # the wide fills run in float32: some micrometres where they filled
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-5)
    assert (~inlier & np.isfinite(new)).sum() > 100  # the wild matches were found
    assert np.abs(out[60:100, 50:70] - heights[60:100, 50:70] - 1.5).max() < 0.2  # hole filled


def test_default_smoothing_follows_the_matching_window_in_ortho_pixels():
    """A third of the window (9 px), in nodes of k ortho pixels, never under one node; a
    given value is kept whatever k."""
    assert IORSettings().smoothing_for(1) == pytest.approx(9 / 3)
    assert IORSettings().smoothing_for(2) == pytest.approx(9 / 6)
    assert IORSettings().smoothing_for(4) == 1.0
    assert IORSettings(window=21).smoothing_for(4) == pytest.approx(21 / 12)
    assert IORSettings(smoothing_nodes=1.5).smoothing_for(1) == 1.5


@pytest.mark.parametrize("tile", [16, 37, 64])
def test_fill_filters_on_tiles_equal_the_whole_grid_filter(tile):
    """The wide Gaussians that fill holes run only on the tiles holding a hole, with their
    reach around: the same values at the holes as scipy's filter of the whole grid."""
    from carto.framework.raster.focal import gaussian_nearest_at
    from carto.framework.raster.grid_window import GridWindow

    rng = np.random.default_rng(2)
    values = rng.normal(0.0, 1.0, (400, 300)).cumsum(axis=1)
    missing = np.zeros(values.shape, bool)
    missing[10:40, 250:295] = True  # near the grid's edges
    missing[200:230, 100:120] = True
    sigma = 4.0
    expected = np.where(missing, ndimage.gaussian_filter(values, sigma, mode="nearest"), values)
    got = gaussian_nearest_at(values, missing, sigma, tile)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    tiles = GridWindow(0, 0, *values.shape).tiles(tile)
    reach = int(4 * sigma + 0.5)
    grown = [t.grown(reach, *values.shape) for t in tiles if missing[t.slices].any()]
    cut_out = sum(g.n_rows * g.n_cols for g in grown)
    assert cut_out < values.size  # the tiles ran, not the whole grid
