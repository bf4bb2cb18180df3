"""Feathered mosaics of DEM tiles cut from one analytic surface (the truth), with steps,
holes, other postings, geoid heights and tiles smaller than the strip."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.crs import CRS

from carto.framework.errors import InputError
from carto.framework.merging.grid import union_grid
from carto.framework.merging.mosaic import (
    MosaicSettings,
    seam_steps,
    step_offsets,
    write_mosaic,
)
from carto.framework.merging.sources import check_together, open_sources

from .tiles import UTM, X0, Y0, truth_on, write_tile


def test_three_tiles_of_a_strip_join_into_the_truth(tmp_path):
    paths = [write_tile(tmp_path / f"t{k}.tif", 0, 150 * k, 120, 200) for k in range(3)]
    sources = open_sources(paths)
    check_together(sources)
    grid = union_grid(sources)
    assert (grid.width, grid.height) == (120, 500)
    out = tmp_path / "m.tif"
    write_mosaic(
        sources,
        grid,
        out,
        MosaicSettings(feather_px=16, tile_px=64),
        vertical="ellipsoid",
        counts_path=tmp_path / "n.tif",
    )
    got, truth = truth_on(out)
    np.testing.assert_allclose(got, truth, atol=2e-4)
    with rasterio.open(tmp_path / "n.tif") as ds:
        counts = ds.read(1)
    assert counts[100, 5] == 1
    assert counts[170, 5] == 2


def test_a_constant_step_is_measured_corrected_and_otherwise_feathered(tmp_path):
    a = write_tile(tmp_path / "a.tif", 0, 0, 100, 160)
    b = write_tile(tmp_path / "b.tif", 0, 100, 100, 160, offset=2.0)
    sources = open_sources([a, b])
    grid = union_grid(sources)
    settings = MosaicSettings(feather_px=20, tile_px=64)
    (step,) = seam_steps(sources, grid, settings)
    assert (step.first, step.second) == (0, 1)
    assert step.median_m == pytest.approx(2.0, abs=0.01)
    assert step.nmad_m < 0.01
    assert step.pixels == 60 * 100
    offsets = step_offsets([step], 2)
    np.testing.assert_allclose(offsets, [0.0, -2.0], atol=0.01)
    write_mosaic(sources, grid, tmp_path / "fixed.tif", settings, offsets_m=offsets)
    got, truth = truth_on(tmp_path / "fixed.tif")
    np.testing.assert_allclose(got, truth, atol=0.01)
    write_mosaic(sources, grid, tmp_path / "raw.tif", settings)
    got, truth = truth_on(tmp_path / "raw.tif")
    jump = np.abs(np.diff(got - truth, axis=0)).max()
    assert jump <= 2.0 / 20 + 1e-3  # the step spread over the feather, not a seam
    assert (got - truth)[:100].max() < 0.2
    assert (got - truth)[160:].min() > 1.8


def test_a_hole_in_one_tile_is_filled_from_the_other(tmp_path):
    holes = np.zeros((160, 100), bool)
    holes[110:130, 40:60] = True
    a = write_tile(tmp_path / "a.tif", 0, 0, 100, 160, holes=holes)
    b = write_tile(tmp_path / "b.tif", 0, 100, 100, 160)
    sources = open_sources([a, b])
    grid = union_grid(sources)
    write_mosaic(sources, grid, tmp_path / "m.tif", MosaicSettings(feather_px=8, tile_px=64))
    got, truth = truth_on(tmp_path / "m.tif")
    np.testing.assert_allclose(got, truth, atol=2e-4)


def test_a_coarser_unaligned_source_is_warped_onto_the_grid(tmp_path):
    a = write_tile(tmp_path / "a.tif", 0, 0, 100, 100)
    b = write_tile(tmp_path / "b.tif", 3, 83, 40, 40, step=25.0)  # 25 m posting, shifted
    sources = open_sources([a, b])
    grid = union_grid(sources)
    assert grid.transform.a == 10.0
    write_mosaic(sources, grid, tmp_path / "m.tif", MosaicSettings(feather_px=5))
    got, truth = truth_on(tmp_path / "m.tif")
    assert np.isfinite(got).sum() > 100 * 100
    np.testing.assert_allclose(got[:83, :100], truth[:83, :100], atol=2e-4)  # a alone
    # half a 25 m post from b's edges GDAL's warper holds the edge post's value; inside,
    # bilinear interpolation of the 25 m posts, blended with a where both are
    inside_b = np.s_[86:180, 6:100]
    assert np.abs(got[inside_b] - truth[inside_b]).max() < 0.1


def test_geoid_heights_are_brought_to_the_ellipsoid(tmp_path):
    from carto.framework.raster.dem import Geoid

    a = write_tile(tmp_path / "a.tif", 0, 0, 80, 80)
    b = write_tile(tmp_path / "b.tif", 0, 60, 80, 80, offset=-30.0, vertical="geoid:EGM96")
    sources = open_sources([a, b])
    with pytest.raises(InputError, match="--geoid"):
        check_together(sources)
    geoid = Geoid(np.full((181, 361), 30.0), Affine(1, 0, -180.5, 0, -1, 90.5))
    check_together(sources, geoid=geoid)
    grid = union_grid(sources)
    write_mosaic(sources, grid, tmp_path / "m.tif", MosaicSettings(feather_px=8), geoid=geoid)
    got, truth = truth_on(tmp_path / "m.tif")
    np.testing.assert_allclose(got, truth, atol=1e-3)


def test_sources_in_other_crss_are_refused_without_a_target(tmp_path):
    a = write_tile(tmp_path / "a.tif", 0, 0, 50, 50)
    b = write_tile(tmp_path / "b.tif", 0, 0, 50, 50, crs=CRS.from_epsg(32644))
    with pytest.raises(InputError, match=r"different CRSs.*--t_srs"):
        check_together(open_sources([a, b]))


def test_heights_and_images_are_not_joined(tmp_path):
    a = write_tile(tmp_path / "a.tif", 0, 0, 50, 50)
    img = tmp_path / "img.tif"
    with rasterio.open(
        img,
        "w",
        driver="GTiff",
        width=50,
        height=50,
        count=1,
        dtype="uint8",
        crs=UTM,
        transform=Affine(10, 0, X0, 0, -10, Y0),
    ) as ds:
        ds.write(np.zeros((50, 50), np.uint8), 1)
    with pytest.raises(InputError, match="heights, the other an image"):
        check_together(open_sources([a, img]))
    with pytest.raises(InputError, match="no such file"):
        open_sources([tmp_path / "missing.tif"])


def test_step_offsets_hold_the_source_asked_for():
    from carto.framework.merging.mosaic import SeamStep

    steps = [SeamStep(0, 1, 1.5, 0.1, 1000), SeamStep(1, 2, -2.0, 0.1, 1000)]
    np.testing.assert_allclose(step_offsets(steps, 3), [0.0, -1.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(step_offsets(steps, 3, held=2), [-0.5, -2.0, 0.0], atol=1e-6)
    # a source joined to none keeps its height
    np.testing.assert_allclose(step_offsets(steps[:1], 3, held=1), [1.5, 0.0, 0.0], atol=1e-6)
