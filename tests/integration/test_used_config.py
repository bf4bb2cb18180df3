"""Every output of ``carto simulate``, ``adjust`` and ``dem`` records the settings it used
(``used_config.json``, issue 34 item 1), and a run from that file gives the same rasters."""

from __future__ import annotations

import json

import numpy as np
import rasterio


def test_a_dem_from_its_used_config_is_the_same_dem(run_carto, tmp_path, cartosat1_scene):
    first = tmp_path / "first"
    proc = run_carto(
        [
            "dem", str(cartosat1_scene), "--models", str(cartosat1_scene / "truth"),
            "--posting", "30", "--max-iterations", "2", "--workers", "1", "--quiet",
            "--out", str(first),
        ]
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    document = json.loads((first / "used_config.json").read_text())
    assert document["format"] == "carto-used-config"
    assert document["command"] == "dem"
    settings = document["settings"]
    assert settings["scene"] == str(cartosat1_scene.resolve())
    assert settings["posting"] == 30.0
    assert settings["matcher"] == "sgm"  # defaults included
    assert "out" not in settings
    assert "workers" not in settings
    again = tmp_path / "again"
    proc = run_carto(["dem", "--config", str(first / "used_config.json"), "--out", str(again)])
    assert proc.returncode == 0, proc.stderr
    for name in ("dem.tif", "quality.tif", "quality_flags.tif", "ortho_left.tif"):
        with rasterio.open(first / name) as a, rasterio.open(again / name) as b:
            assert np.array_equal(a.read(), b.read(), equal_nan=True), name
    report = json.loads((again / "report.json").read_text())
    assert report["settings"]["generator"]["max_iterations"] == 2
    assert report["settings"]["generator"]["window"] == 9  # the default, resolved


def test_simulate_and_adjust_record_their_settings(run_carto, tmp_path):
    config = tmp_path / "scene.yaml"
    config.write_text("preset: cartosat1-pair\nsize: [200, 200]\nterrain: plains\nseed: 3\n")
    scene = tmp_path / "scene"
    proc = run_carto(["simulate", "--config", str(config), "--out", str(scene), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    used = json.loads((scene / "used_config.json").read_text())["settings"]
    assert used["preset"] == "cartosat1-pair"
    assert used["size"] == [200, 200]
    assert used["errors"] == "realistic"
    adjusted = tmp_path / "adj"
    proc = run_carto(["adjust", str(scene), "--gcps", "1", "--out", str(adjusted), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    used = json.loads((adjusted / "used_config.json").read_text())["settings"]
    assert used["source"] == str(scene.resolve())
    assert used["gcps"] == 1
    report = json.loads((adjusted / "report.json").read_text())
    assert report["settings"]["adjuster"]["mode"] == "combined"  # resolved default
    assert report["settings"]["height_sigma_m"] == 30.0
