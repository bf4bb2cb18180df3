"""The per-node search bound an update leaves, and the bound at work in a run."""

from __future__ import annotations

import numpy as np

from carto.ior.iteration import SEARCH_MARGIN_PX, next_search_px
from carto.ior.refine import IORSettings, refine_dem


def test_the_bound_is_twice_the_change_in_pixels_where_matched():
    change = np.array([[1.0, -2.0], [0.5, 3.0]])
    matched = np.array([[True, True], [False, True]])
    first = next_search_px(None, change, matched, px_per_m=0.25)
    np.testing.assert_allclose(
        first[matched], 2 * np.abs(change[matched]) * 0.25 + SEARCH_MARGIN_PX
    )
    assert np.isnan(first[1, 0])  # never matched: no bound
    second = next_search_px(first, np.zeros_like(change), ~matched, px_per_m=0.25)
    assert second[1, 0] == SEARCH_MARGIN_PX  # matched now, and nothing moved
    np.testing.assert_array_equal(second[matched], first[matched])  # kept where unmatched


def test_a_run_searches_within_its_bounds_after_the_first_update(hilly):
    """From the SRTM-like start at one resolution: the first iteration searches the pyramid's
    whole reach, the later ones within a few pixels of each node, and they match as much."""
    from carto.framework.raster.dem import DEM
    from carto.framework.raster.images import read_raster

    truth = hilly.truth_sensors()
    init = DEM.open(hilly.path("init_dem.tif"))
    images = [truth[n].prepare_raw(read_raster(hilly.raster(n)), init) for n in ("aft", "fore")]
    result = refine_dem(
        *images, truth["aft"], truth["fore"], init,
        IORSettings(posting_m=10.0, max_iterations=3, coarse_stages=0, threshold_px=1e-3),
    )  # fmt: skip
    reports = result.iterations
    assert np.isnan(reports[0].median_search_px)
    assert len(reports) >= 3
    for r in reports[1:]:
        assert SEARCH_MARGIN_PX <= r.median_search_px < 6.0
        assert r.matched_percent > 0.9 * reports[0].matched_percent


def test_the_final_resolution_updates_at_least_once_after_a_coarse_stage(hilly):
    """Even when the first mismatch at the final resolution is under the threshold (here a
    threshold no mismatch misses), the final grid gets one update of its own: a DEM left at
    the coarse stage's surface would lack the fine relief (and have no predicted sigma)."""
    from carto.framework.raster.dem import DEM
    from carto.framework.raster.images import read_raster

    truth = hilly.truth_sensors()
    init = DEM.open(hilly.path("init_dem.tif"))
    images = [truth[n].prepare_raw(read_raster(hilly.raster(n)), init) for n in ("aft", "fore")]
    result = refine_dem(
        *images, truth["aft"], truth["fore"], init,
        IORSettings(posting_m=10.0, coarse_stages=1, threshold_px=10.0),
    )  # fmt: skip
    final = [r for r in result.iterations if r.factor == 1]
    assert len(final) == 2
    assert final[0].median_abs_dem_change_m > 0.0
    assert result.converged
    sigma = np.asarray(result.node_quality["sigma_m"])
    assert np.nanmedian(sigma) > 0.0


def test_only_iterations_that_may_end_the_run_predict_the_precision(hilly, monkeypatch):
    """After a coarse stage the final grid's first iteration cannot be its last: it skips the
    predicted precision, as the coarse stage does, and the DEM and its sigma are those of a
    run that computes it in every iteration."""
    from carto.framework.raster.dem import DEM
    from carto.framework.raster.images import read_raster
    from carto.ior import iteration

    truth = hilly.truth_sensors()
    init = DEM.open(hilly.path("init_dem.tif"))
    images = [truth[n].prepare_raw(read_raster(hilly.raster(n)), init) for n in ("aft", "fore")]
    settings = IORSettings(posting_m=10.0, coarse_stages=1, max_iterations=2)
    args = (*images, truth["aft"], truth["fore"], init, settings)
    run_iteration = iteration._run_iteration
    calls = []

    def recorded(stage, *rest):
        calls.append((stage.factor, rest[-1]))
        return run_iteration(stage, *rest)

    monkeypatch.setattr(iteration, "_run_iteration", recorded)
    lean = refine_dem(*args)
    final = [p for f, p in calls if f == 1]
    assert all(not p for f, p in calls if f > 1)
    assert len(final) >= 2
    assert not final[0]
    assert all(final[1:])

    def always(stage, *rest):
        return run_iteration(stage, *rest[:-1], True)

    monkeypatch.setattr(iteration, "_run_iteration", always)
    full = refine_dem(*args)
    np.testing.assert_array_equal(lean.dem.heights, full.dem.heights)
    sigma = np.asarray(lean.node_quality["sigma_m"])
    assert np.isfinite(sigma).any()
    np.testing.assert_array_equal(sigma, np.asarray(full.node_quality["sigma_m"]))
