"""Tiling independence of the simulator's terrain and texture (scene scale, #16).

The terrain and texture of a whole scene never exist in memory: they are evaluated window by
window. These tests check that a window computed in tiles equals the same window computed in
one piece, bit for bit, and check the lattice interpolation against an independent per-node
evaluation (Keys cubic convolution written out here from its definition).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.simulation.cover import Parcels
from carto.framework.simulation.fields import LatticeField, hashed_noise, pyramid_noise
from carto.framework.simulation.terrain import ProceduralTerrain, make_terrain
from carto.framework.simulation.texture import GroundTexture, make_texture

BOUNDS = (78.0, 20.0, 78.02, 20.018)


def _tiled(func, r0: int, r1: int, c0: int, c1: int, tile: tuple[int, int]) -> np.ndarray:
    """``func`` over ``[r0, r1) x [c0, c1)`` assembled from tiles of ``tile`` (uneven)."""
    rows = []
    for a in range(r0, r1, tile[0]):
        b = min(a + tile[0], r1)
        rows.append(
            np.concatenate(
                [func(a, b, c, min(c + tile[1], c1)) for c in range(c0, c1, tile[1])], axis=1
            )
        )
    return np.concatenate(rows, axis=0)


def _keys(t: float) -> np.ndarray:
    """Keys (a = -0.5) cubic convolution weights of the nodes -1, 0, 1, 2 at offset t."""

    def kernel(x: float) -> float:
        x = abs(x)
        if x <= 1.0:
            return 1.5 * x**3 - 2.5 * x**2 + 1.0
        if x < 2.0:
            return -0.5 * x**3 + 2.5 * x**2 - 4.0 * x + 2.0
        return 0.0

    return np.array([kernel(t + 1.0), kernel(t), kernel(t - 1.0), kernel(t - 2.0)])


@pytest.mark.parametrize("shape", [(300, 260), (9000, 8000)])
def test_lattice_field_windows_equal_an_independent_interpolation(shape):
    rng = np.random.default_rng(4)
    field = LatticeField(rng, shape, 5.0, [(5.0, 6000.0, 1.0)])
    lattice = field.values.astype(np.float64)
    n_lat = lattice.shape
    window = field.window(101, 131, 57, 80)
    # independent: the lattice position of grid node i, then 4 x 4 Keys weights per node
    ratio = field.ratio
    for i in range(101, 131, 7):
        for j in range(57, 80, 5):
            if ratio == 1.0:
                pr, pc = i + (n_lat[0] - shape[0]) // 2, j + (n_lat[1] - shape[1]) // 2
            else:
                pr = (i + 0.5 - 0.5 * shape[0]) * ratio + 0.5 * n_lat[0]
                pc = (j + 0.5 - 0.5 * shape[1]) * ratio + 0.5 * n_lat[1]
            br, bc = math.floor(pr), math.floor(pc)
            wr, wc = _keys(pr - br), _keys(pc - bc)
            block = lattice[br - 1 : br + 3, bc - 1 : bc + 3]
            expected = float(wr @ block @ wc)
            assert window[i - 101, j - 57] == pytest.approx(expected, abs=1e-12)
    assert np.array_equal(
        _tiled(field.window, 90, 170, 40, 133, (17, 29)), field.window(90, 170, 40, 133)
    )


def test_terrain_tiles_equal_one_piece_and_the_whole_dem():
    for name in ("hilly", "flat-coastal", "mountains", "urban"):
        terrain = ProceduralTerrain(name, BOUNDS, 5.0, seed=7)
        n_rows, n_cols = terrain.shape
        whole = terrain.window(0, n_rows, 0, n_cols)
        tiled = _tiled(terrain.window, 0, n_rows, 0, n_cols, (37, 101))
        assert np.array_equal(tiled, whole), name
        dem = make_terrain(name, BOUNDS, 5.0, seed=7)
        assert np.array_equal(dem.heights, whole)
        lo, hi = terrain.height_range
        assert lo <= whole.min()
        assert whole.max() <= hi
        # bilinear heights from windows = the DEM's own bilinear interpolation
        rng = np.random.default_rng(1)
        west, south, east, north = dem.bounds_lonlat
        lon = rng.uniform(west - 0.001, east + 0.001, 500)
        lat = rng.uniform(south - 0.001, north + 0.001, 500)
        np.testing.assert_allclose(terrain.height(lon, lat), dem.height(lon, lat), atol=1e-9)
        assert np.array_equal(np.isnan(terrain.height(lon, lat)), np.isnan(dem.height(lon, lat)))


def test_noise_windows_are_the_same_at_every_node():
    whole = hashed_noise(11, -40, 60, 1000, 1100)
    assert np.array_equal(whole[30:50, 10:90], hashed_noise(11, -10, 10, 1010, 1090))
    assert abs(float(whole.mean())) < 0.05
    assert abs(float(whole.std()) - 1.0) < 0.05
    assert not np.array_equal(whole, hashed_noise(12, -40, 60, 1000, 1100))
    pyr = pyramid_noise(5, 0, 400, 0, 500)
    assert np.array_equal(_tiled(lambda *w: pyramid_noise(5, *w), 0, 400, 0, 500, (63, 77)), pyr)
    assert 0.8 < float(pyr.std()) < 1.2


def test_parcels_are_the_same_whatever_the_window():
    parcels = Parcels(3, 1.0)
    land, outline = parcels.window(0, 600, 0, 700)
    again = Parcels(3, 1.0)  # fresh caches, other window order
    tiles = _tiled(lambda *w: again.window(*w)[0], 0, 600, 0, 700, (130, 170))
    assert np.array_equal(tiles, land)
    assert np.array_equal(again.window(200, 260, 300, 380)[1], outline[200:260, 300:380])
    assert land.min() >= 0.12
    assert land.max() <= 0.40
    assert 0.01 < float((outline > 0.5).mean()) < 0.1  # about one-pixel boundaries


def test_texture_tiles_with_targets_and_blur_equal_one_piece():
    terrain = ProceduralTerrain("flat-coastal", BOUNDS, 5.0, seed=5)
    ground = GroundTexture(terrain, 1.25, seed=9)
    n_rows, n_cols = ground.shape
    t = ground.transform
    rows, cols = np.array([300.4, 900.7, 1400.1]), np.array([420.2, 1300.9, 700.5])
    lon, lat = t.c + t.a * (cols + 0.5), t.f + t.e * (rows + 0.5)
    painted = ground.with_targets(lon, lat, 6.0, 0.8).blurred(0.8)
    # in one piece, outside the texture's cache of tiles (which windows are assembled from)
    whole, mask = painted._marked(0, n_rows, 0, n_cols)
    tiled = _tiled(lambda *w: painted.window(*w)[0], 0, n_rows, 0, n_cols, (211, 389))
    assert np.array_equal(tiled, whole)
    again = ground.with_targets(lon, lat, 6.0, 0.8).blurred(0.8)  # another order of windows
    assert np.array_equal(
        _tiled(lambda *w: again.window(*w)[0], 0, n_rows, 0, n_cols, (97, 530)), whole
    )
    assert np.array_equal(
        _tiled(lambda *w: painted.window(*w)[1], 0, n_rows, 0, n_cols, (500, 700)), mask
    )
    assert mask.any()
    assert not mask.all()
    # the targets are there, and the plain texture is make_texture's
    for r, c in zip(rows, cols, strict=True):
        assert whole[round(r), round(c)] > 0.6
    plain, _ = ground.window(0, n_rows, 0, n_cols)
    tex = make_texture(terrain.to_dem(), 1.25, seed=9)
    assert np.array_equal(tex.reflectance, plain)


def test_absurd_areas_are_refused_with_the_posting_named():
    with pytest.raises(InputError, match=r"posting_m 0.01 .* more than"):
        ProceduralTerrain("hilly", (70.0, 20.0, 79.0, 29.0), 0.01, seed=0)


def test_a_full_scene_grid_is_accepted_and_its_lattices_are_bounded():
    """A full Cartosat-1 scene (~31 km a side: a 7000 x 7000 DEM at 5 m, a 27000 x 27000
    texture at 1.25 m) is beyond what a whole grid may hold, but not beyond windows."""
    south, west = 30.15, 77.8
    bounds = (west, south, west + 31_000 / (111_320 * math.cos(math.radians(30.3))), 30.43)
    with pytest.raises(InputError, match="grid of"):
        make_terrain("hilly", bounds, 1.25, seed=1)  # a whole grid of 7e8 nodes: refused
    terrain = ProceduralTerrain("hilly", bounds, 5.0, seed=1)
    ground = GroundTexture(terrain, 1.25, seed=1)
    assert ground.shape[0] * ground.shape[1] > 4e8
    lattices = [terrain._main, *terrain._ridges, ground._land_use, ground._patches]
    assert max(max(f.values.shape) for f in lattices) <= 4200
    values, _ = ground.window(10_000, 10_100, 20_000, 20_300)
    assert values.shape == (100, 300)
    assert np.isfinite(values).all()


def test_true_ortho_blocks_are_those_an_outline_reaches():
    """The true ortho-image's blocks kept for a thin, tilted strip: every block a point of
    the strip (inside or on its edge, sampled densely) falls in is kept, plus the margin;
    blocks far from it are not."""
    import pyproj

    from carto.framework.simulation import scene_tiles as st

    crs = "EPSG:32643"
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    to_lonlat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    # a 30 km x 200 m strip, tilted 8 degrees, in a grid of 2.5 m pixels
    u, v = np.meshgrid(np.linspace(0, 30_000, 3001), np.linspace(0, 200, 21))
    tilt = math.radians(8.0)
    x = 500_000 + u * math.cos(tilt) - v * math.sin(tilt)
    y = 3_000_000 - u * math.sin(tilt) - v * math.cos(tilt)
    ring_u = np.r_[np.linspace(0, 30_000, 50), np.full(5, 30_000), np.linspace(30_000, 0, 50)]
    ring_v = np.r_[np.zeros(50), np.linspace(0, 200, 5), np.full(50, 200)]
    rx = 500_000 + ring_u * math.cos(tilt) - ring_v * math.sin(tilt)
    ry = 3_000_000 - ring_u * math.sin(tilt) - ring_v * math.cos(tilt)
    outline = to_lonlat.transform(rx, ry)
    grid = (499_000.0, 3_001_000.0, 2.5)
    shape = (3000, 14000)
    kept = st._covered_blocks(to_utm, grid, shape, [tuple(map(np.asarray, outline))], 0)
    rows = ((grid[1] - y) / grid[2]).astype(int) // st.ORTHO_STRIP_ROWS
    cols = ((x - grid[0]) / grid[2]).astype(int) // st.ORTHO_BLOCK_COLS
    reached = np.zeros_like(kept)
    reached[rows.ravel(), cols.ravel()] = True
    assert kept[reached].all()
    assert kept.sum() <= reached.sum() + 2 * kept.shape[1]  # the cell grid adds little
    assert kept.sum() < 0.5 * kept.size
    # a margin of one block keeps the neighbours too
    grown = st._covered_blocks(to_utm, grid, shape, [tuple(map(np.asarray, outline))], 256)
    assert grown[np.roll(reached, 1, axis=0)].all()
