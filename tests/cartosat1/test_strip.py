"""The ``cartosat1-strip`` preset: consecutive Fore/Aft pairs of one pass over one truth DEM,
made into one DEM by ``carto dem`` (each scene's pair, and the pairs across the scenes'
overlaps), without steps where the scenes meet (true models: the DEM's error is the
matching's)."""

from __future__ import annotations

import json

import numpy as np
import pyproj
import pytest
import rasterio

from carto.cartosat1.presets import STRIP_OVERLAP
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from tests.scenes import on_grid, simulate, true_model_dem


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    return simulate("cartosat1-strip", tmp_path_factory.mktemp("strip"), seed=4, size=(400, 500))


def test_scenes_follow_each_other_along_the_pass(strip):
    scene = Scene.open(strip)
    assert scene.image_names == ["fore1", "aft1", "fore2", "aft2", "fore3", "aft3"]
    truth = scene.truth_sensors()
    # the middle of scene 1's last lines is seen again in scene 2's first lines
    lines = truth["fore1"].image_shape[0]
    lon, lat = truth["fore1"].image_to_ground(lines * (1 - STRIP_OVERLAP / 2), 200.0, 500.0)
    line, _ = truth["fore2"].ground_to_image(lon, lat, 500.0)
    assert 0 < float(line) < lines * STRIP_OVERLAP


def test_a_strip_makes_one_dem_without_steps_between_scenes(strip, tmp_path, run_carto):
    out = tmp_path / "dem"
    done = run_carto(true_model_dem(strip, out, "--posting", "10"))
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "report.json").read_text())
    done_pairs = {frozenset((p["left"], p["right"])) for p in report["pairs"]}
    for k in (1, 2, 3):
        assert frozenset((f"fore{k}", f"aft{k}")) in done_pairs
    own = {f"aft{k}/fore{k}" for k in (1, 2, 3)} | {f"fore{k}/aft{k}" for k in (1, 2, 3)}
    seams = [s for s in report["seams"] if {s["first"], s["second"]} <= own]
    assert len(seams) >= 2
    assert all(abs(s["median_step_m"]) <= 0.3 for s in seams)
    error = on_grid(out / "dem.tif", out / "dem.tif") - on_grid(
        out / "dem.tif", strip / "truth" / "dem.tif", "bilinear"
    )
    has = np.isfinite(error)
    assert 1.4826 * np.median(np.abs(error[has] - np.median(error[has]))) < 0.5
    _orthos_cover_their_own_scene(strip, out)


def _orthos_cover_their_own_scene(strip, out):
    """Each image's ortho-image on the fused DEM is on the fused grid's lattice and covers that
    image's footprint (its corners located on the truth DEM, taken to the map by pyproj) as
    far as the fused DEM goes, not the strip: over half of it is image (a rotated footprint
    in its box), and it is under 0.6 of the strip's length."""
    truth_dem = DEM.open(strip / "truth" / "dem.tif")
    with rasterio.open(out / "dem.tif") as ds:
        lattice, crs, dem_bounds = ds.transform, ds.crs, ds.bounds
    to_map = pyproj.Transformer.from_crs("EPSG:4326", crs.to_wkt(), always_xy=True)
    for name, sensor in Scene.open(strip).truth_sensors().items():
        n_l, n_s = sensor.image_shape
        lon, lat, _ = sensor.locate_on_dem(
            np.array([0.0, 0.0, n_l, n_l]), np.array([0.0, n_s, 0.0, n_s]), truth_dem
        )
        x, y = to_map.transform(lon, lat)
        # as far as the fused DEM goes (the union of the pairs' DEMs, narrower than an image)
        x = np.clip(x, dem_bounds.left, dem_bounds.right)
        y = np.clip(y, dem_bounds.bottom, dem_bounds.top)
        with rasterio.open(out / f"ortho_{name}.tif") as ds:
            t, b, image = ds.transform, ds.bounds, ds.read(1, masked=True)
        offset = ((t.c - lattice.c) / t.a, (t.f - lattice.f) / t.e)
        assert np.allclose(offset, np.round(offset), atol=1e-6), name
        assert b.left <= x.min(), name
        assert x.max() <= b.right, name
        assert b.bottom <= y.min(), name
        assert y.max() <= b.top, name
        assert b.top - b.bottom < 0.6 * (dem_bounds.top - dem_bounds.bottom), name
        assert image.count() > 0.5 * image.size, name  # the whole strip: under 0.2


def test_a_strip_adjusts_as_one_block(strip, tmp_path, run_carto):
    """``carto adjust`` on the strip: one block of the six images, tied across the scenes'
    overlaps, judged at the checkpoints against the truth. A checkpoint in an overlap seen
    only in one camera's two scenes (parallel rays) has no intersection and is left out of
    the figures, not an internal error (it was, on a 1000 x 500 px strip)."""
    out = tmp_path / "adjusted"
    done = run_carto(["adjust", str(strip), "--gcps", "1", "--out", str(out), "-q"])
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["adjuster"] == "cartosat1-combined"
    # tied across the scenes: tie points between images of consecutive scenes
    with open(out / "tie_points.csv") as f:
        pairs = {line.split(":")[0] for line in f.read().splitlines()[1:]}
    scenes = {tuple(sorted(name[-1] for name in pair.split("-"))) for pair in pairs}
    assert {("1", "2"), ("2", "3")} <= scenes
    check = report["checkpoints"]
    assert check["count"] > 10
    # one GCP for three scenes: metres, not the hundreds of the system-level models
    assert check["rmse_planimetric_m"] < 5.0
    assert np.isfinite(check["predicted_sigma_planimetric_m"])
    assert report["checkpoints_before"]["rmse_planimetric_m"] > 10 * check["rmse_planimetric_m"]
    # the outer scenes' tie points are held to the starting DEM with one common offset that
    # the GCP sets (its errors are correlated: as independent heights they set the level of
    # the block, at a predicted sigma of centimetres on a whole strip, session 54)
    assert report["dem_height_constraints"] > 0
    offset = report["adjustment"]["parameters"]["height_constraints.offset_m"]
    assert offset["prior_sigma"] == 10.0
    assert check["rmse_height_m"] < 2.0 * check["predicted_sigma_height_m"]
    held = tmp_path / "held"
    done = run_carto(
        ["adjust", str(strip), "--gcps", "1", "--dem-offset-sigma", "0", "--out", str(held), "-q"]
    )
    assert done.returncode == 0, done.stderr
    without = json.loads((held / "report.json").read_text())["checkpoints"]
    assert check["rmse_height_m"] < 0.5 * without["rmse_height_m"]  # 0.16 against 0.69 m
