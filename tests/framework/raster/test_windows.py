"""Images read by windows (:mod:`carto.framework.raster.image_source`) and layers held as
tiles (:mod:`carto.framework.raster.tiled_layer`), against whole reads with rasterio and
numpy slicing; a GeoTIFF written window by window from tiles equals the one written whole."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from carto.framework.errors import InputError
from carto.framework.imaging.ortho import write_ortho
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.raster.image_source import (
    ArrayImage,
    BandedImage,
    RasterImage,
    as_image_source,
    check_image_source,
)
from carto.framework.raster.tiled_layer import TiledLayer, TilePiece, piece_path


@pytest.fixture
def raster(tmp_path: Path) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(1)
    data = rng.integers(1, 4000, (300, 517)).astype(np.uint16)
    data[10:20, 30:40] = 0  # nodata
    path = tmp_path / "img.tif"
    profile = dict(driver="GTiff", height=300, width=517, count=1, dtype="uint16", nodata=0)
    profile.update(tiled=True, blockxsize=128, blockysize=128, compress="deflate")
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(data, 1)
    return path, data


def test_raster_windows_equal_a_whole_read(raster):
    path, data = raster
    expected = np.where(data == 0, np.nan, data.astype(np.float32))
    source = as_image_source(path)
    assert isinstance(source, RasterImage)
    assert source.shape == (300, 517)
    for rows, cols in [
        (slice(0, 300), slice(0, 517)),
        (slice(5, 25), slice(25, 45)),
        (slice(250, 400), slice(-20, None)),  # clipped at the ends
        (slice(7, 7), slice(0, 5)),
    ]:
        got = source[rows, cols]
        want = expected[rows, cols]
        assert got.dtype == np.float32
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.asarray(source), expected)
    check_image_source(source, "img")
    with pytest.raises(TypeError):
        source[::2, :]


def test_raster_errors(tmp_path, raster):
    path, _ = raster
    with pytest.raises(InputError, match="no band 2"):
        RasterImage.open(path, band=2)
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"not a tiff")
    with pytest.raises(InputError, match="cannot read raster"):
        RasterImage.open(bad)
    constant = ArrayImage(np.full((40, 40), 5.0))
    with pytest.raises(InputError, match="no texture"):
        check_image_source(constant, "flat")
    with pytest.raises(InputError, match="needs at least"):
        check_image_source(ArrayImage(np.ones((8, 40))), "thin")


def test_a_truncated_tiff_names_the_file_and_gdals_cause(tmp_path, raster):
    """A TIFF cut in half opens (its header is whole) but its tiles fail: rasterio said only
    "Read failed. See previous exception for details." (issue 31); the file and GDAL's own
    cause now."""
    path, _ = raster
    cut = tmp_path / "cut.tif"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    source = RasterImage.open(cut)
    for read in (lambda: source.overview(64), lambda: source[0:300, 0:517]):
        with pytest.raises(InputError) as err:
            read()
        text = str(err.value)
        assert str(cut) in text
        assert "truncated or damaged" in text
        assert "See previous exception" not in text


def test_banded_image(tmp_path):
    data = np.arange(103 * 37, dtype=np.float32).reshape(103, 37)
    image = BandedImage(tmp_path, data.shape, 25)
    for r0 in range(0, 103, 25):
        np.save(image.band_path(r0), data[r0 : r0 + 25])
    for rows in (slice(0, 103), slice(20, 30), slice(49, 51), slice(100, 200)):
        np.testing.assert_array_equal(image[rows, 3:30], data[rows, 3:30])
    (tmp_path / "band_000050.npy").unlink()
    with pytest.raises(InputError, match="band_000050"):
        image[40:60, 0:5]


def _tiles(tmp_path: Path, data: np.ndarray, tile: int) -> TiledLayer:
    pieces = []
    for r in range(0, data.shape[0], tile):
        for c in range(0, data.shape[1], tile):
            block = data[r : r + tile, c : c + tile]
            path = piece_path(tmp_path, r, c)
            if (r, c) != (0, tile):  # one tile missing: fill value
                np.savez(path, values=block)
                pieces.append(TilePiece(path, "values", r, c, block.shape))
    return TiledLayer.of(data.shape, pieces)


def test_tiled_layer_reads_and_writes_like_the_array(tmp_path):
    rng = np.random.default_rng(2)
    data = rng.normal(size=(700, 530)).astype(np.float32)
    layer = _tiles(tmp_path, data, 256)
    expected = data.copy()
    expected[0:256, 256:512] = np.nan
    np.testing.assert_array_equal(np.asarray(layer), expected)
    np.testing.assert_array_equal(layer[300:650, 100:400], expected[300:650, 100:400])
    grid = OrthoGrid("EPSG:32643", Affine(2.0, 0, 500000.0, 0, -2.0, 2000000.0), data.shape)
    a = write_ortho(tmp_path / "a.tif", expected, grid)
    b = write_ortho(tmp_path / "b.tif", [layer, layer], grid, band_descriptions=["x", "y"])
    with rasterio.open(a) as da, rasterio.open(b) as db:
        assert db.count == 2
        assert db.descriptions == ("x", "y")
        np.testing.assert_array_equal(da.read(1), db.read(1))
        np.testing.assert_array_equal(da.read(1), db.read(2))
    with pytest.raises(InputError, match="outside"):
        TiledLayer.of((100, 100), [TilePiece(tmp_path / "x.npz", "v", 90, 0, (20, 10))])


def test_a_raster_averaged_by_gdal_equals_block_means(raster):
    """``RasterImage.averaged`` (GDAL's average resampling) gives the block means numpy
    gives over the valid pixels of whole blocks (the partial ones at the edges dropped;
    rounded, as GDAL averages in the file's integer type), NaN where a block is all
    nodata."""
    path, data = raster
    f = 4
    got = RasterImage.open(path).averaged(f)
    assert got.shape == (300 // f, 517 // f)
    blocks = data[: 75 * f, : 129 * f].astype(np.float64).reshape(75, f, 129, f)
    valid = blocks != 0
    with np.errstate(invalid="ignore"):
        want = np.where(blocks != 0, blocks, 0).sum(axis=(1, 3)) / valid.sum(axis=(1, 3))
    np.testing.assert_allclose(got, want, atol=0.5)
    assert np.isnan(got[3:5, 8:10]).all()  # rows 12-19, cols 32-39: all nodata
    assert np.isfinite(got).sum() == got.size - 4
    with pytest.raises(InputError, match="smaller than"):
        RasterImage.open(path).averaged(400)
