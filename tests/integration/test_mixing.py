"""Mixing plugins end to end: a third party's matcher and trajectory model used by the
framework's workflows (the test plugin in ``tests/plugins/carto-example-plugin``).

``example-biased`` is the ``ncc`` matcher with every match moved by ``BIAS_PX`` along lines.
If ``carto adjust --matcher`` and ``carto dem --matcher`` really use it, the tie points in the
second image move by that much, and the DEM by the height that parallax means
(``BIAS_PX * ortho pixel / (B/H)``); a workflow that ignored the option would change nothing.
``example-spline`` is a cubic-spline trajectory model: ``carto adjust --trajectory`` fits the
scene with it, the adjusted model files name it, ``carto dem --models`` reads them back
through the plugin, and an ancillary file that names it is opened with it.
``example-start`` is a DEM generator that delivers the starting DEM on the grid asked for:
``carto dem --generator`` writes it, and its heights are the scene's ``init_dem.tif``
interpolated bilinearly at the nodes (rasterio, pyproj and SciPy here).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import rasterio

from tests.scenes import simulate

BIAS_PX = 0.75  # carto_example_plugin.BIAS_PX (the plugin is installed for the tests only)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return simulate(
        "cartosat1-pair",
        tmp_path_factory.mktemp("mixing") / "scene",
        seed=4,
        size=(300, 400),
        n_checkpoints=5,
        terrain="hilly",
    )


def _tie_points(path: Path) -> dict[tuple[str, str], np.ndarray]:
    with path.open() as fh:
        return {
            (r["id"], r["image"]): np.array([float(r["line"]), float(r["sample"])])
            for r in csv.DictReader(fh)
        }


def test_adjust_uses_the_matcher_it_is_given(run_carto, scene, tmp_path):
    runs = {}
    for matcher in ("ncc", "example-biased"):
        out = tmp_path / matcher
        proc = run_carto(
            ["adjust", str(scene), "--gcps", "1", "--matcher", matcher, "--out", str(out)]
        )
        assert proc.returncode == 0, proc.stderr
        report = json.loads((out / "report.json").read_text())
        assert report["matcher"] == matcher
        assert report["adjuster"] == "cartosat1-combined"  # the sensor type's default
        runs[matcher] = _tie_points(out / "tie_points.csv")
    plain, biased = runs["ncc"], runs["example-biased"]
    for image, expected in (("fore", 0.0), ("aft", BIAS_PX)):  # fore is the reference
        common = [k for k in plain if k in biased and k[1] == image]
        assert len(common) > 100
        moved = np.array([biased[k] - plain[k] for k in common])
        # ortho pixels are about raw pixels here (2.5 m): the bias comes back along lines
        assert np.median(moved[:, 0]) == pytest.approx(expected, abs=0.1 * BIAS_PX)
        assert np.median(np.abs(moved[:, 1])) < 0.25 * BIAS_PX


def test_dem_uses_the_matcher_it_is_given(run_carto, scene, tmp_path):
    """With the matcher's own sub-pixel offsets (``--subpixel-steps 0``) its bias goes into
    the DEM; IOR's least-squares steps (the default) measure the images again and take most
    of it out."""
    dems, reports = {}, {}
    runs = [(m, s) for m in ("ncc", "example-biased") for s in ("0", "2")]
    for matcher, steps in runs:
        out = tmp_path / f"{matcher}-{steps}"
        proc = run_carto(
            [
                "dem",
                str(scene),
                "--models",
                str(scene / "truth"),
                "--posting",
                "10",
                "--matcher",
                matcher,
                "--subpixel-steps",
                steps,
                "--out",
                str(out),
            ]
        )
        assert proc.returncode == 0, proc.stderr
        key = f"{matcher}-{steps}"
        reports[key] = json.loads((out / "report.json").read_text())
        assert reports[key]["matcher"] == matcher
        assert reports[key]["generator"] == "ior"  # the sensor type's default
        assert reports[key]["settings"]["subpixel_steps"] == int(steps)
        with rasterio.open(out / "dem.tif") as ds:
            dems[key] = ds.read(1)
    report = reports["example-biased-0"]
    # the parallax BIAS_PX ortho pixels along the (north-south) base means this height
    expected_m = BIAS_PX * report["ortho_resolution_m"] / report["b_over_h"]
    shift = dems["example-biased-0"] - dems["ncc-0"]
    assert np.isfinite(shift).mean() > 0.5
    assert abs(np.nanmedian(shift)) == pytest.approx(expected_m, rel=0.25)
    assert np.nanstd(shift) < 0.25 * expected_m  # a shift of the whole DEM, not noise
    corrected = dems["example-biased-2"] - dems["ncc-2"]
    assert abs(np.nanmedian(corrected)) < 0.2 * expected_m  # two steps from 0.75 px


def test_a_sparse_only_matcher_is_refused_by_the_dense_generator(run_carto, scene, tmp_path):
    proc = run_carto(
        [
            "dem",
            str(scene),
            "--models",
            str(scene / "truth"),
            "--matcher",
            "example-shift",
            "--out",
            str(tmp_path / "d"),
        ]
    )
    assert proc.returncode == 1
    assert "does not match densely" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_plugin_trajectory_model_is_used_end_to_end(run_carto, scene, tmp_path):
    adjusted = tmp_path / "adjusted"
    proc = run_carto(
        [
            "adjust",
            str(scene),
            "--gcps",
            "1",
            "--trajectory",
            "example-spline",
            "--out",
            str(adjusted),
        ]
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads((adjusted / "report.json").read_text())
    assert report["trajectory_model"] == "example-spline"
    # the spline interpolates the samples as well as the polynomial fits them: the
    # adjustment reaches the same accuracy class (simulator scene, errors in the model's form)
    assert report["checkpoints"]["rmse_planimetric_m"] < 3.0
    for image in ("fore", "aft"):
        model = json.loads((adjusted / f"{image}.model.json").read_text())
        assert model["trajectory"]["orbit"]["kind"] == "example-spline"
        assert model["trajectory"]["angles"]["kind"] == "example-spline"
    # the model files are read back through the plugin ...
    dem = tmp_path / "dem"
    proc = run_carto(
        ["dem", str(scene), "--models", str(adjusted), "--posting", "10", "--out", str(dem)]
    )
    assert proc.returncode == 0, proc.stderr
    # ... and without it they are refused with the model's name, not misread
    proc = run_carto(
        ["dem", str(scene), "--models", str(adjusted), "--out", str(tmp_path / "d2")],
        with_test_plugins=False,
    )
    assert proc.returncode == 1
    assert "example-spline" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_an_ancillary_file_that_names_a_trajectory_model_is_opened_with_it(scene, tmp_path):
    import shutil

    from carto.framework.workflows.opening import open_sensors

    copy = tmp_path / "scene"
    shutil.copytree(scene, copy)
    path = copy / "body.ancillary.json"
    doc = json.loads(path.read_text())
    assert doc.get("trajectory_model", "polynomial") == "polynomial"
    plain = open_sensors(copy)
    doc["trajectory_model"] = "example-spline"
    path.write_text(json.dumps(doc))
    spline = open_sensors(copy)
    for name in ("fore", "aft"):
        assert plain[name].trajectory.model == "polynomial"
        assert spline[name].trajectory.model == "example-spline"
        # the same samples: both models put the image centre at the same place (to the
        # polynomial's fit residual), but not identically (a different model is used)
        n_l, n_s = spline[name].image_shape
        a = np.array(plain[name].image_to_ground(n_l / 2, n_s / 2, 500.0))
        b = np.array(spline[name].image_to_ground(n_l / 2, n_s / 2, 500.0))
        assert 0.0 < np.max(np.abs(a - b)) < 1e-4  # degrees: < 10 m


def test_a_plugin_dem_generator_is_used_end_to_end(run_carto, scene, tmp_path):
    import pyproj
    from scipy.ndimage import map_coordinates

    out = tmp_path / "dem"
    proc = run_carto(
        [
            "dem", str(scene), "--generator", "example-start", "--matcher", "ncc",
            "--posting", "20", "--workers", "1", "--quiet", "--out", str(out),
        ]
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["generator"] == "example-start"
    assert report["iterations"][0]["matched_percent"] > 20
    with rasterio.open(out / "quality_flags.tif") as ds:
        assert ds.descriptions == ("start",)
        assert ds.dtypes == ("uint8",)
    with rasterio.open(out / "dem.tif") as ds:
        dem, crs, transform = ds.read(1, masked=True).filled(np.nan), ds.crs, ds.transform
    with rasterio.open(scene / "init_dem.tif") as ds:
        start, start_crs, inverse = ds.read(1).astype(float), ds.crs, ~ds.transform
    rows, cols = np.indices(dem.shape)
    x, y = transform @ (cols + 0.5, rows + 0.5)
    x, y = pyproj.Transformer.from_crs(crs, start_crs, always_xy=True).transform(x, y)
    col, row = inverse @ (x, y)
    expected = map_coordinates(start, [row - 0.5, col - 0.5], order=1, cval=np.nan)
    inside = np.isfinite(expected) & np.isfinite(dem)
    assert inside.mean() > 0.9
    np.testing.assert_allclose(dem[inside], expected[inside], atol=1e-3)
