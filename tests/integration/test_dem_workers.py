"""``carto dem`` uses every core by default (tile tasks on threads): the same DEM as one
worker, byte for byte."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import rasterio


def test_the_default_workers_give_the_dem_of_one_worker(
    run_carto, tmp_path: Path, cartosat1_scene: Path, cartosat1_adjusted: Path
) -> None:
    dems = {}
    for label, extra in (("default", []), ("one", ["--workers", "1"])):
        out = tmp_path / label
        res = run_carto(
            [
                "dem",
                str(cartosat1_scene),
                "--models",
                str(cartosat1_adjusted),
                "--posting",
                "20",
                "--max-iterations",
                "2",
                "--out",
                str(out),
                "--quiet",
                *extra,
            ],
            with_test_plugins=False,
        )
        assert res.returncode == 0, res.stderr
        report = json.loads((out / "report.json").read_text())
        assert report["workers"] == (1 if extra else (os.cpu_count() or 1))
        with rasterio.open(out / "dem.tif") as ds:
            dems[label] = ds.read(1)
    assert np.isfinite(dems["one"]).mean() > 0.5
    np.testing.assert_array_equal(dems["default"], dems["one"])
