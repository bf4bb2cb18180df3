"""``carto mosaic`` as a user runs it: files, CRS, report, seams, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pyproj
import rasterio
from rasterio.crs import CRS

from ..merging.tiles import truth_on, write_tile


def test_a_strip_of_three_dems_with_steps(tmp_path, run_carto):
    tiles = [
        write_tile(tmp_path / f"s{k}.tif", 0, 150 * k, 120, 200, offset=step)
        for k, step in enumerate((0.0, 1.5, -0.5))
    ]
    out = tmp_path / "strip"
    done = run_carto(
        ["mosaic", *map(str, tiles), "--align", "--tile-size", "64", "--out", str(out)]
    )
    assert done.returncode == 0, done.stderr
    assert "median step +1.50" in done.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["format"] == "carto-mosaic-report"
    assert report["kind"] == "dem"
    steps = [s["median_step_m"] for s in report["seams"]]
    np.testing.assert_allclose(steps, [1.5, -2.0], atol=0.01)
    assert max(abs(s["median_step_after_m"]) for s in report["seams"]) < 0.01
    got, truth = truth_on(out / "dem.tif")
    np.testing.assert_allclose(got, truth, atol=0.01)
    with rasterio.open(out / "dem.tif") as ds:
        assert ds.tags()["VERTICAL_REFERENCE"].startswith("ellipsoid")
        assert ds.overviews(1) or max(ds.shape) < 512
        crs = pyproj.CRS.from_user_input(ds.crs)
    assert len(crs.axis_info) == 3  # heights' reference in the CRS GDAL reads
    with rasterio.open(out / "mosaic_counts.tif") as ds:
        assert ds.dtypes[0] == "uint16"
        assert ds.read(1).max() == 2
    assert (out / "dem_hillshade.png").stat().st_size > 0


def test_bad_input_is_one_line_and_keeps_the_earlier_output(tmp_path, run_carto):
    a = write_tile(tmp_path / "a.tif", 0, 0, 50, 50)
    b = write_tile(tmp_path / "b.tif", 0, 40, 50, 50, crs=CRS.from_epsg(32644))
    out = tmp_path / "m"
    assert (
        run_carto(["mosaic", str(a), str(tmp_path / "a2.tif"), "--out", str(out)]).returncode == 1
    )
    done = run_carto(["mosaic", str(a), str(b), "--out", str(out)])
    assert done.returncode == 1
    assert "different CRSs" in done.stderr
    assert "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not out.exists()
    done = run_carto(["mosaic", str(a), "--out", str(out)])
    assert done.returncode == 1
    assert "give two or more" in done.stderr
    c = write_tile(tmp_path / "c.tif", 0, 40, 50, 50)
    assert run_carto(["mosaic", str(a), str(c), "--out", str(out)]).returncode == 0
    before = (out / "dem.tif").read_bytes()
    assert run_carto(["mosaic", str(a), str(b), "--out", str(out)]).returncode == 1
    assert (out / "dem.tif").read_bytes() == before
