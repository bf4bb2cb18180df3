"""Windows assembled from cached tiles equal the grid computed directly over the window,
and with a spill file every tile is computed once, however often the windows come back."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.simulation.tile_cache import TileCache, TileSpill

_SHAPE = (300, 410)


class _Grid:
    """A grid computed window by window (a value per node and a mask), counting the nodes it
    computed."""

    def __init__(self) -> None:
        rng = np.random.default_rng(0)
        self.values = rng.normal(size=_SHAPE).astype(np.float32)
        self.nodes = 0

    def __call__(self, r0: int, r1: int, c0: int, c1: int) -> tuple[np.ndarray, np.ndarray]:
        self.nodes += (r1 - r0) * (c1 - c0)
        v = self.values[r0:r1, c0:c1].copy()
        return v, v > 0.5


def _windows(seed: int, n: int) -> list[tuple[int, int, int, int]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        r0, c0 = rng.integers(0, _SHAPE[0] - 1), rng.integers(0, _SHAPE[1] - 1)
        out.append(
            (r0, rng.integers(r0 + 1, _SHAPE[0] + 1), c0, rng.integers(c0 + 1, _SHAPE[1] + 1))
        )
    return out


@pytest.mark.parametrize("spill", [False, True])
def test_windows_equal_the_grid_computed_over_them(tmp_path, spill):
    grid = _Grid()
    cache = TileCache(_SHAPE, tile=32, max_tiles=40)
    if spill:
        cache.spill = TileSpill(tmp_path / "tiles.bin")
    for r0, r1, c0, c1 in _windows(1, 60):
        values, mask = cache.window(grid, r0, r1, c0, c1)
        np.testing.assert_array_equal(values, grid.values[r0:r1, c0:c1])
        np.testing.assert_array_equal(mask, grid.values[r0:r1, c0:c1] > 0.5)
        values[:] = np.nan  # fresh arrays: the cache's tiles are not touched
    if spill:
        cache.spill.close()


def test_with_a_spill_each_tile_is_computed_once(tmp_path):
    grid = _Grid()
    cache = TileCache(_SHAPE, tile=32, max_tiles=6)  # far fewer tiles than the windows need
    cache.spill = TileSpill(tmp_path / "tiles.bin")
    bands = [
        (r0, min(r0 + 40, _SHAPE[0]), c0, min(c0 + 70, _SHAPE[1]))
        for r0 in range(0, _SHAPE[0], 40)
        for c0 in range(0, _SHAPE[1], 70)
    ]
    for _ in range(3):  # three images of the same ground, one after the other
        for r0, r1, c0, c1 in bands:
            values, _ = cache.window(grid, r0, r1, c0, c1)
            np.testing.assert_array_equal(values, grid.values[r0:r1, c0:c1])
            assert len(cache) <= 6  # tiles read back from the spill are evicted too
    assert grid.nodes == _SHAPE[0] * _SHAPE[1]
    # without the spill the evicted tiles are computed again
    again = _Grid()
    plain = TileCache(_SHAPE, tile=32, max_tiles=6)
    for _ in range(3):
        for r0, r1, c0, c1 in bands:
            plain.window(again, r0, r1, c0, c1)
    assert again.nodes > 2 * _SHAPE[0] * _SHAPE[1]
    cache.spill.close()


def test_the_spill_gives_back_what_it_stored(tmp_path):
    spill = TileSpill(tmp_path / "tiles.bin")
    rng = np.random.default_rng(2)
    stored = {}
    for key in [(0, 0), (0, 1), (3, 2)]:
        shape = tuple(rng.integers(1, 40, 2))  # edge tiles are smaller
        arrays = (
            rng.normal(size=shape),
            rng.random(shape) > 0.5,
            rng.integers(0, 9, shape).astype(np.uint16),
        )
        spill.store(key, arrays)
        stored[key] = arrays
    spill.store((0, 1), (np.zeros(3),))  # a key already stored keeps its first tiles
    assert (1, 1) not in spill
    for key, arrays in stored.items():
        got = spill.load(key)
        assert [g.dtype for g in got] == [a.dtype for a in arrays]
        for g, a in zip(got, arrays, strict=True):
            np.testing.assert_array_equal(g, a)
        got[0][...] = 0  # writable, and the file keeps the stored values
        np.testing.assert_array_equal(spill.load(key)[0], arrays[0])
    spill.close()
