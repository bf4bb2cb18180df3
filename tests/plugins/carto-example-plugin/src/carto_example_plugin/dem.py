"""DEM generator ``example-start``: the starting DEM on a grid of the posting asked for, the
ortho-images on it and one dense match of them, whose offsets say how far the starting DEM
is from the terrain the images see (it measures no height). The plugin guide's section 13
shows it whole: the options every generator gets, refusing the others, the product."""

from __future__ import annotations

import time

import numpy as np

from carto.framework import InputError, hookimpl
from carto.framework.sdk.dem import (
    DEM,
    DEMGenerator,
    DEMProduct,
    IterationRecord,
    OrthoGrid,
    QualityLayer,
    orthorectify,
)
from carto.framework.sdk.matchers import Matcher

OWN_OPTIONS = {"posting_m", "ortho_res_m"}  # from carto dem --posting, --ortho-res


class StartDEMGenerator(DEMGenerator):
    name = "example-start"
    description = "the starting DEM, its ortho-images and how well they match (tests)"

    def generate(self, images, sensors, **options) -> DEMProduct:
        began = time.perf_counter()
        init_dem = options.pop("init_dem", None)
        if not isinstance(init_dem, DEM):
            raise InputError("example-start: option init_dem (a DEM) is required")
        matcher = options.pop("matcher", None)
        if matcher is not None and not isinstance(matcher, Matcher):
            raise InputError(f"example-start: option matcher must be a matcher, got {matcher!r}")
        if matcher is not None and not matcher.dense:
            raise InputError(f"example-start: matcher {matcher.name!r} does not match densely")
        progress = options.pop("progress", None)  # None or a callable taking one line
        options.pop("scheduler", None)  # None or runs argument-less tasks (one task here)
        options.pop("work_dir", None)  # a folder for intermediate files (none here)
        options.pop("keep_failed_tiles", None)  # carto dem --allow-poor (no tiles here)
        unknown = sorted(set(options) - OWN_OPTIONS)
        if unknown:
            raise InputError(f"example-start: unknown option(s) {', '.join(unknown)}")
        if len(images) != 2 or len(sensors) != 2:
            raise InputError(f"example-start: needs two images, got {len(images)}")
        posting_m = float(options.get("posting_m", 10.0))
        dem_grid = OrthoGrid.covering(list(sensors), init_dem, posting_m)
        rows, cols = np.indices(dem_grid.shape)
        heights = init_dem.height(*dem_grid.lonlat(rows, cols))  # NaN outside the start
        dem = DEM.from_array(heights, dem_grid.transform, dem_grid.crs)
        res_m = float(options.get("ortho_res_m", posting_m / 2))
        ortho_grid = OrthoGrid.covering(list(sensors), init_dem, res_m, crs=dem_grid.crs)
        orthos = tuple(
            orthorectify(image, sensor, ortho_grid, init_dem)
            for image, sensor in zip(images, sensors, strict=True)
        )
        if progress is not None:
            progress("example-start: one dense match of the ortho-images")
        field = matcher.match_dense(*orthos) if matcher is not None else None
        known = np.isfinite(heights)
        quality = [QualityLayer("start", "1: height from the starting DEM", known, "dem", "flag")]
        measures = {}
        if field is not None:
            quality += [
                QualityLayer("d_row", "right - left along ortho rows, px", field.d_row),
                QualityLayer("valid", "valid match (1) or not (0)", field.valid, kind="flag"),
            ]
            measures["matched_percent"] = round(100.0 * float(np.mean(field.valid)), 1)
            measures["median_abs_d_row_px"] = round(float(np.nanmedian(np.abs(field.d_row))), 3)
        return DEMProduct(
            dem=dem,  # ellipsoidal heights on dem_grid, NaN = none
            dem_grid=dem_grid,
            orthos=orthos,  # float32, one per image, on ortho_grid
            ortho_grid=ortho_grid,
            quality=quality,  # grid "dem": quality.tif; "ortho" (default): matching.tif
            iterations=[IterationRecord(1, time.perf_counter() - began, measures)],
            converged=None,  # no stopping test of its own
            extras={"posting_m": posting_m},  # JSON-able, for report.json
        )


@hookimpl
def carto_dem_generators():
    return [StartDEMGenerator()]
