"""Area-based matching against independent truth: the ortho-images of a simulated Cartosat-1
pair whose true geometry gives the expected shift."""

from __future__ import annotations

import warnings
from pathlib import Path

import attrs
import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning

from carto.framework import get_registry
from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.matching.ncc_matcher import NCCMatcher
from carto.framework.matching.shifts import global_shift
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.simulation.simulate import simulate_scene


# ----------------------------------------------------------------------------- real images
@pytest.fixture(scope="module")
def plains_pair(tmp_path_factory) -> Scene:
    """A single-array (unstaggered) Cartosat-1 pair over plains, realistic product errors."""
    out: Path = tmp_path_factory.mktemp("match_plains")
    opts = SimulationOptions(seed=7, size=(400, 400), terrain="plains", n_gcps=0, n_checkpoints=0)
    plan = get_registry().get("scene-preset", "cartosat1-pair").plan(opts)
    segment = plan.segments[0]
    views = tuple(
        attrs.evolve(v, camera=attrs.evolve(v.camera, stagger_m=0.0)) for v in segment.views
    )
    plan = attrs.evolve(plan, segments=(attrs.evolve(segment, views=views),))
    simulate_scene(plan, out, opts, quiet=True)
    return Scene.open(out)


def test_system_level_orthos_of_a_cartosat1_pair_match_with_the_expected_shift(plains_pair):
    """Orthos of Fore and Aft made with the product models (realistic errors) on the initial
    DEM are shifted against each other by tens of pixels; for each matched Fore ortho pixel,
    the true models and the true DEM say where its ground point is in the Aft ortho."""
    scene = plains_pair
    product, true = scene.sensors(), scene.truth_sensors()
    init = DEM.open(scene.path("init_dem.tif"))
    truth_dem = DEM.open(scene.path("truth/dem.tif"))
    grid = OrthoGrid.covering(list(product.values()), init, 2.5)
    orthos = {}
    for name in ("fore", "aft"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)  # raw images have no CRS
            with rasterio.open(scene.raster(name)) as ds:
                raw = ds.read(1)
        orthos[name] = orthorectify(raw, product[name], grid, init)
    m = NCCMatcher(spacing=16).match(orthos["fore"], orthos["aft"])
    assert len(m) > 200
    # expected position: Fore ortho pixel -> Fore raw (product, init DEM) -> true ground (true
    # model, true DEM) -> Aft raw (true model) -> Aft ortho (product, init DEM)
    to_ll = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True)
    to_map = pyproj.Transformer.from_crs("EPSG:4326", grid.crs, always_xy=True)
    lon, lat = to_ll.transform(*grid.xy(m.left_line - 0.5, m.left_sample - 0.5))
    line, sample = product["fore"].ground_to_image(lon, lat, init.height(lon, lat))
    g_lon, g_lat, g_h = true["fore"].locate_on_dem(line, sample, truth_dem)
    line, sample = true["aft"].ground_to_image(g_lon, g_lat, g_h)
    a_lon, a_lat, _ = product["aft"].locate_on_dem(line, sample, init)
    x, y = to_map.transform(a_lon, a_lat)
    inv = ~grid.transform
    expected = np.stack([inv.e * y + inv.f, inv.a * x + inv.c], axis=1)
    shift = np.nanmedian(expected - np.stack([m.left_line, m.left_sample], axis=1), axis=0)
    assert np.hypot(*shift) > 20  # the system-level orthos are far apart
    err = np.hypot(*(np.stack([m.right_line, m.right_sample], axis=1) - expected).T)
    err = err[np.isfinite(err)]
    assert err.size > 0.9 * len(m)
    assert np.median(err) < 0.12  # measured 0.08 px
    assert np.percentile(err, 90) < 0.4  # measured 0.29 px
    d_line, d_sample, _ = global_shift(orthos["fore"], orthos["aft"])
    assert np.hypot(d_line - shift[0], d_sample - shift[1]) < 0.5
