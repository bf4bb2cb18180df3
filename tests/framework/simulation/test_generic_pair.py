"""The framework on its own: the built-in ``linescan-pair`` preset simulated, opened by the
built-in ``carto-scene`` sensor type and matched, with no platform plugin involved.

Truth is the simulator's (the true models and terrain of the scene): a best case for the
matching, since the scene is rendered through the same line-scanner model family.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from carto.framework.matching.tiepoints import automatic_tie_points, tie_point_errors
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.workflows.opening import open_product
from tests.scenes import simulate


@pytest.fixture(scope="module")
def generic_scene(tmp_path_factory):
    return simulate(
        "linescan-pair", tmp_path_factory.mktemp("generic") / "scene", seed=2, size=(500, 600)
    )


def test_the_generic_pair_is_opened_by_the_framework_scene_type(generic_scene):
    manifest = json.loads((generic_scene / "scene.json").read_text())
    assert manifest["platform"] == "Generic line scanner"
    opened = open_product(generic_scene)
    assert set(opened.sensors) == {"forward", "backward"}
    assert {t.name for t in opened.types.values()} == {"carto-scene"}
    assert all(t.default_adjuster is None for t in opened.types.values())
    # the delivered models are the truth plus the realistic ancillary errors: off by tens
    # to hundreds of metres, not kilometres
    truth = Scene.open(generic_scene).truth_sensors()
    for name, sensor in opened.sensors.items():
        n_l, n_s = sensor.image_shape
        a = np.array(sensor.image_to_ground(n_l / 2, n_s / 2, 500.0))
        b = np.array(truth[name].image_to_ground(n_l / 2, n_s / 2, 500.0))
        assert 1e-6 < np.max(np.abs(a - b)) < 0.02  # degrees


def test_tie_points_on_the_generic_pair_meet_the_truth(generic_scene):
    scene = Scene.open(generic_scene)
    opened = open_product(generic_scene)
    dem = DEM.open(scene.path(scene.manifest["init_dem"]))
    rasters = {n: scene.raster(n) for n in scene.image_names}
    table = automatic_tie_points(rasters, opened.sensors, dem)
    assert len(set(table["id"].tolist())) >= 150
    errors = tie_point_errors(table, scene.truth_sensors(), DEM.open(scene.path("truth/dem.tif")))
    errors = errors[np.isfinite(errors) & (errors > 0)]  # the reference rows are exact
    assert np.median(errors) < 0.15
    assert np.percentile(errors, 95) < 0.5


def test_adjusting_without_a_platform_adjuster_asks_for_one(run_carto, generic_scene, tmp_path):
    proc = run_carto(["adjust", str(generic_scene), "--out", str(tmp_path / "a")])
    assert proc.returncode == 1
    assert "no default adjuster" in proc.stderr
    assert "--adjuster" in proc.stderr
