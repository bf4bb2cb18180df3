"""IOR tiles as tasks over files: an interrupted run continues from its finished tiles to the
DEM of an uninterrupted run; a failed tile stops the run with its cause, or (kept) leaves its
nodes without heights; tiles beyond the common footprint get no task."""

from __future__ import annotations

import itertools

import attrs
import numpy as np
import pytest

from carto.framework.parallel.engine import TaskFailure, TileEngine
from carto.framework.raster.dem import DEM
from carto.framework.raster.image_source import ArrayImage
from carto.framework.raster.images import read_raster
from carto.ior.iteration import tile_edges
from carto.ior.refine import IORSettings, TileFailure, refine_dem

SETTINGS = IORSettings(
    posting_m=10.0, max_iterations=2, tile_px=256, overlap_px=96, coarse_stages=0
)  # every iteration at one resolution: the tiles of each are known


@pytest.fixture(scope="module")
def pair(hilly):
    truth = hilly.truth_sensors()
    init = DEM.open(hilly.path("init_dem.tif"))
    images = [truth[n].prepare_raw(read_raster(hilly.raster(n)), init) for n in ("aft", "fore")]
    return (ArrayImage(images[0]), ArrayImage(images[1]), truth["aft"], truth["fore"], init)


@pytest.fixture(scope="module")
def uninterrupted(pair, tmp_path_factory):
    return refine_dem(*pair, SETTINGS, work_dir=tmp_path_factory.mktemp("work-ref"))


class StopAfter(TileEngine):
    """An engine interrupted (Ctrl-C) after ``n`` tasks of the run."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.left = n

    def run(self, tasks, **kwargs):
        out = []
        for task in tasks:
            if self.left == 0:
                raise KeyboardInterrupt
            self.left -= 1
            out.append(task())
        return out


def test_resume_from_finished_tiles_gives_the_same_dem(pair, uninterrupted, tmp_path):
    work = tmp_path / "work"
    # interrupted in the middle of the second iteration
    first = refine_dem(*pair, SETTINGS, work_dir=tmp_path / "count")
    per_iteration = len(list((tmp_path / "count").glob("iteration_*/tile_*.npz")))
    assert per_iteration >= 4  # several tiles, so the test means something
    with pytest.raises(KeyboardInterrupt):
        refine_dem(*pair, SETTINGS, scheduler=StopAfter(per_iteration + 2), work_dir=work)
    done = sorted(p.name for p in work.glob("iteration_02/tile_*.npz"))
    assert len(done) == 2  # the state: iteration 2 with two finished tiles
    resumed = refine_dem(*pair, SETTINGS, work_dir=work)
    np.testing.assert_array_equal(resumed.dem.heights, uninterrupted.dem.heights)
    np.testing.assert_array_equal(resumed.dem.heights, first.dem.heights)
    np.testing.assert_array_equal(
        np.asarray(resumed.ortho_left), np.asarray(uninterrupted.ortho_left)
    )
    assert [r.iteration for r in resumed.iterations] == [
        r.iteration for r in uninterrupted.iterations
    ]


def test_a_finished_tile_of_another_extent_is_computed_again(pair, uninterrupted, tmp_path):
    """A work folder whose tile file starts where a tile of this plan starts but holds
    another extent (a version that cut the grid otherwise) is not taken for that tile."""
    work = tmp_path / "work"
    first = refine_dem(*pair, SETTINGS, work_dir=tmp_path / "count")
    per_iteration = len(list((tmp_path / "count").glob("iteration_*/tile_*.npz")))
    del first
    with pytest.raises(KeyboardInterrupt):
        refine_dem(*pair, SETTINGS, scheduler=StopAfter(per_iteration + 2), work_dir=work)
    path = sorted(work.glob("iteration_02/tile_*.npz"))[0]
    with np.load(path) as data:
        cropped = {name: data[name][:-1] for name in data.files}  # one row short
    with open(path, "wb") as stream:
        np.savez(stream, **cropped)
    resumed = refine_dem(*pair, SETTINGS, work_dir=work)
    np.testing.assert_array_equal(resumed.dem.heights, uninterrupted.dem.heights)


def test_resume_inside_a_coarse_stage_gives_the_same_dem(pair, tmp_path):
    """Interrupted in the coarse stage (half resolution), resumed: the same DEM and the same
    iterations as a run never interrupted."""
    settings = attrs.evolve(SETTINGS, coarse_stages=1, coarse_iterations=2)
    reference = refine_dem(*pair, settings, work_dir=tmp_path / "reference")
    factors = [r.factor for r in reference.iterations]
    assert factors[0] == 2
    assert factors[-1] == 1
    assert (tmp_path / "reference" / "stage_1_2" / "state.json").is_file()
    work = tmp_path / "work"
    with pytest.raises(KeyboardInterrupt):
        refine_dem(*pair, settings, scheduler=StopAfter(1), work_dir=work)
    assert not (work / "state.json").exists()  # stopped inside the stage
    resumed = refine_dem(*pair, settings, work_dir=work)
    np.testing.assert_array_equal(resumed.dem.heights, reference.dem.heights)
    assert [(r.iteration, r.factor) for r in resumed.iterations] == [
        (r.iteration, r.factor) for r in reference.iterations
    ]


class FailOne(TileEngine):
    """Runs every task but reports the second as failed."""

    def run(self, tasks, *, keys=None, **kwargs):
        out = [task() for task in tasks]
        out[1] = TaskFailure(keys[1], "OSError: disk gone")
        return out


def test_a_failed_tile_stops_the_run_with_its_cause(pair, tmp_path):
    pattern = r"1 of \d+ tiles failed in iteration 1 \(tile \d+,\d+: OSError: disk gone\)"
    with pytest.raises(TileFailure, match=pattern):
        refine_dem(*pair, SETTINGS, scheduler=FailOne(), work_dir=tmp_path)
    assert (tmp_path / "state.json").is_file()  # the finished tiles stay for a resume


def test_a_kept_failed_tile_has_no_heights(pair, uninterrupted, tmp_path):
    result = refine_dem(
        *pair, SETTINGS, scheduler=FailOne(), work_dir=tmp_path, keep_failed_tiles=True
    )
    assert len(result.failed_tiles) == 1
    key, cause = result.failed_tiles[0].split(": ", 1)
    assert cause == "OSError: disk gone"
    r, c = (int(v) for v in key.removeprefix("tile ").split(","))
    k = round(SETTINGS.posting_m / result.ortho_grid.resolution[0])
    n = max(16, SETTINGS.tile_px // k)
    heights = result.dem.heights
    (r0, r1), (c0, c1) = tile_edges(heights.shape[0], n)[r], tile_edges(heights.shape[1], n)[c]
    assert np.isnan(heights[r0:r1, c0:c1]).all()
    assert np.isnan(np.asarray(result.ortho_left)[r0 * k : r1 * k, c0 * k : c1 * k]).all()
    elsewhere = np.isfinite(heights) & np.isfinite(uninterrupted.dem.heights)
    assert elsewhere.mean() > 0.3


def test_tiles_beyond_the_footprint_get_no_task(pair):
    from carto.ior.iteration import _tile_plan
    from carto.ior.refine import _grids

    left, right, init = pair[2], pair[3], pair[4]
    grid, _, _ = _grids(left, right, init, SETTINGS)
    heights = np.full(grid.shape, float(np.nanmedian(init.heights)))
    plan = _tile_plan((left, right), grid, heights, 16)
    n_r, n_c = grid.shape
    total = -(-n_r // 16) * -(-n_c // 16)
    assert 0 < len(plan) <= total


@pytest.mark.parametrize(("n", "tile_n"), [(531, 512), (512, 512), (1, 16), (3200, 457), (100, 16)])
def test_tiles_split_an_axis_evenly_within_the_tile_size(n, tile_n):
    edges = tile_edges(n, tile_n)
    sizes = [b - a for a, b in edges]
    assert edges[0][0] == 0
    assert edges[-1][1] == n
    assert all(a == b for (_, a), (b, _) in itertools.pairwise(edges))
    assert max(sizes) <= tile_n
    assert max(sizes) - min(sizes) <= 1
    assert len(edges) == -(-n // tile_n)  # no more tiles than the size needs
