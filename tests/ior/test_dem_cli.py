"""``carto dem`` end to end on a small simulated scene, and its one-line errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio

from carto.framework.evaluation.dem_accuracy import dem_accuracy
from carto.framework.raster.dem import DEM
from tests.scenes import simulate


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return simulate(
        "cartosat1-pair",
        tmp_path_factory.mktemp("demcli") / "scene",
        seed=4,
        size=(300, 400),
        n_checkpoints=5,
        terrain="hilly",
    )


def test_dem_from_a_scene_writes_every_product(run_carto, scene, tmp_path):
    out = tmp_path / "dem"
    truth = scene / "truth"
    proc = run_carto(
        [
            "dem",
            str(scene),
            "--models",
            str(truth),
            "--posting",
            "10",
            "--out",
            str(out),
            "--reference",
            str(truth / "dem.tif"),
        ]
    )
    assert proc.returncode == 0, proc.stderr
    assert "iteration 1:" in proc.stderr  # progress per iteration
    # no spurious warning on a normal run (it printed rasterio's "Dataset has no geotransform"
    # for the raw images, issue 34); the test plugins' broken ones are reported, as they must
    warnings = [
        line
        for line in proc.stderr.splitlines()
        if "warning" in line and "plugin skipped" not in line
    ]
    assert warnings == []
    assert "against the reference" in proc.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["iterations"]
    assert report["iterations"][0]["iteration"] == 1
    # the record of the run (issue 34 item 1): versions, command line, times, inputs' hashes
    import hashlib

    from carto.framework import __version__

    # what GDAL users read (issue 34 item 3): the DEM band's name and unit, the quality
    # layers' units
    with rasterio.open(out / "dem.tif") as ds:
        assert ds.descriptions == ("height",)
        assert ds.units == ("metre",)
    with rasterio.open(out / "quality.tif") as ds:
        units = dict(zip(ds.descriptions, ds.units, strict=True))
    assert units["sigma_m"] == units["spread_m"] == "metre"
    assert not units["confidence"]
    assert (report["format"], report["version"]) == ("carto-dem-report", 1)  # docs/formats.md
    assert list(report)[:2] == ["format", "version"]
    run = report["run"]
    assert run["carto_version"] == __version__
    assert run["plugins"]["carto-ior"]
    assert run["command_line"].startswith("carto dem ")
    assert run["started_utc"] <= run["ended_utc"]
    inputs = {Path(i["path"]).name: i for i in run["inputs"]}
    fore = scene / "fore.tif"
    assert inputs["fore.tif"]["sha256"] == hashlib.sha256(fore.read_bytes()).hexdigest()
    assert inputs["fore.tif"]["size_bytes"] == fore.stat().st_size
    for key in ("median_abs_mismatch_px", "matched_percent", "median_abs_dem_change_m"):
        assert key in report["iterations"][0]
    assert report["settings"]["posting_m"] == 10.0
    # the relative orientation ran before the DEM; with the true models it finds no parallax
    # across the base and, along it, well under a metre to correct
    rel = report["relative_orientation"]
    assert rel["applied"]
    assert rel["correction"] == "line"
    assert rel["datum"] == "dem"
    assert abs(rel["after"]["median_across_base_px"]) < 0.05
    assert rel["after"]["rms_across_base_px"] <= rel["before"]["rms_across_base_px"]
    assert -1.0 < rel["correction_height_m"]["min"] <= rel["correction_height_m"]["max"] < 1.0
    with rasterio.open(out / "dem.tif") as ds:
        assert ds.dtypes[0] == "float32"
        assert ds.crs.is_projected  # UTM chosen automatically
        assert ds.res == pytest.approx((10.0, 10.0))
        assert "ellipsoid" in ds.tags()["VERTICAL_REFERENCE"].lower()
        assert np.isnan(ds.nodata)
    # per DEM node; counts and flags in files of their own types (issue 34: every band
    # float32 made matching.tif 14 MB beside a 0.6 MB DEM)
    with rasterio.open(out / "quality.tif") as ds:
        assert ds.descriptions == ("confidence", "spread_m", "sigma_m")  # GDAL's
        assert ds.dtypes == ("float32",) * 3
        assert ds.res == pytest.approx((10.0, 10.0))
        confidence, spread, sigma = ds.read()
    with rasterio.open(out / "quality_counts.tif") as ds:
        assert ds.descriptions == ("points",)
        assert ds.dtypes == ("uint16",)
        assert ds.nodata == 65535
        points = ds.read(1)
    with rasterio.open(out / "quality_flags.tif") as ds:
        assert ds.descriptions == ("filled",)
        assert ds.dtypes == ("uint8",)
        assert ds.nodata == 255
        filled = ds.read(1)
    heights = DEM.open(out / "dem.tif").heights
    has = np.isfinite(heights)
    measured = has & (filled == 0)
    assert measured.mean() > 0.5
    assert (points[has & (filled == 1)] == 0).all()  # filled: no point of its own
    assert (points[measured] >= 1).all()
    assert np.isfinite(spread[measured & (points >= 3)]).all()
    assert (confidence[measured] > 0).all()
    assert report["quality_bands"] == ["confidence", "points", "spread_m", "sigma_m", "filled"]
    assert np.isfinite(sigma[measured]).mean() > 0.9
    assert (sigma[measured & np.isfinite(sigma)] > 0).all()
    assert not np.isfinite(sigma[~measured]).any()  # no prediction without a measurement
    counts = report["completeness"]  # measured nodes only; the filled ones apart
    assert counts["measured_nodes"] == int(measured.sum())
    assert counts["filled_nodes"] == int((has & (filled == 1)).sum())
    assert counts["measured_fraction"] == pytest.approx(report["matched_fraction"], abs=1e-6)
    with rasterio.open(out / "matching.tif") as ds:  # per ortho pixel
        assert ds.descriptions == ("score",)
        assert ds.dtypes == ("float32",)
    with rasterio.open(out / "matching_flags.tif") as ds:
        assert ds.descriptions == ("valid",)
        assert ds.dtypes == ("uint8",)
        valid = ds.read(1)
    assert set(np.unique(valid).tolist()) <= {0, 1, 255}
    assert (valid == 1).any()
    assert report["matching_bands"] == ["score", "valid"]
    assert report["quality_layers"]["points"] == {
        "file": "quality_counts.tif",
        "kind": "count",
        "description": "matched ortho pixels whose rays gave the node's height",
    }
    assert report["quality_layers"]["valid"]["file"] == "matching_flags.tif"
    for name in ("ortho_left.tif", "ortho_right.tif"):  # in the images' radiometry
        with rasterio.open(out / name) as ds, rasterio.open(scene / "fore.tif") as raw:
            assert ds.dtypes == raw.dtypes == ("uint16",)
            assert ds.nodata == 0
    for name in ("ortho_left.tif", "ortho_right.tif", "dem_hillshade.png", "dem_difference.png"):
        assert (out / name).is_file(), name
    # with the true models, better than the starting DEM (truth from the simulator)
    ours = dem_accuracy(DEM.open(out / "dem.tif"), DEM.open(truth / "dem.tif"))
    start = dem_accuracy(DEM.open(scene / "init_dem.tif"), DEM.open(truth / "dem.tif"))
    assert ours["rmse_m"] < start["rmse_m"]
    assert report["accuracy"]["nmad_m"] == pytest.approx(ours["nmad_m"], rel=0.05)
    # the predicted sigma has the size of the error against the truth (within 2x here; the
    # benchmark dem_simulated.py measures the ratio)
    ratio = ours["nmad_m"] / float(np.nanmedian(sigma[measured]))
    assert 0.5 < ratio < 2.0, ratio


@pytest.mark.parametrize(
    ("args", "message", "code"),
    [
        ([], "give a scene folder, or both --left and --right", 1),
        (["--left", "nope.tif", "--right", "nope2.tif"], "no such image", 1),
        # a carto adjust configuration given as the scene (an outside probe: "field 'format'
        # is None"): a usage error
        (["{tmp}/pair.json"], "pair.json: not a scene folder; carto dem takes a scene", 2),
    ],
)
def test_dem_errors_are_one_line(run_carto, tmp_path, args, message, code):
    (tmp_path / "pair.json").write_text('{"images": {}}')
    args = [a.format(tmp=tmp_path) for a in args]
    proc = run_carto(["dem", *args, "--out", str(tmp_path / "x")], with_test_plugins=False)
    assert proc.returncode == code
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_dem_needs_a_starting_dem_for_loose_images(run_carto, scene, tmp_path):
    proc = run_carto(
        [
            "dem",
            "--left",
            str(scene / "aft.tif"),
            "--right",
            str(scene / "fore.tif"),
            "--left-model",
            str(scene / "truth" / "aft.model.json"),
            "--right-model",
            str(scene / "truth" / "fore.model.json"),
            "--out",
            str(tmp_path / "x"),
        ]
    )
    assert proc.returncode == 1
    assert "initial DEM" in proc.stderr


def test_dem_coregistered_to_a_reference(run_carto, scene, tmp_path):
    """A reference displaced by a known 3-D shift (the truth moved 8 m east, 5 m south and
    3 m up): the DEM of the true models is moved onto it by that shift."""
    from affine import Affine

    truth = DEM.open(scene / "truth" / "dem.tif")
    shifted = tmp_path / "shifted.tif"
    assert truth.crs.is_geographic
    lat = np.radians(truth.transform.f)
    east_deg, north_deg = 8.0 / (111_320.0 * np.cos(lat)), 5.0 / 110_950.0
    moved_transform = Affine.translation(east_deg, -north_deg) @ truth.transform
    DEM.from_array(truth.heights + 3.0, moved_transform, truth.crs).write(shifted)
    base = ["dem", str(scene), "--models", str(scene / "truth"), "--posting", "10"]
    args = ["--coregister", str(shifted), "--coregister-accuracy", "15"]
    proc = run_carto([*base, "--out", str(tmp_path / "co"), *args])
    assert proc.returncode == 0, proc.stderr
    assert "co-registered to" in proc.stderr
    c = json.loads((tmp_path / "co" / "report.json").read_text())["coregistration"]
    assert c["applied"]
    assert not c["flagged"]
    assert (c["dx_m"], c["dy_m"]) == pytest.approx((-8.0, 5.0), abs=1.5)
    assert c["dz_m"] == pytest.approx(-3.0, abs=0.5)
    after = dem_accuracy(DEM.open(tmp_path / "co" / "dem.tif"), DEM.open(shifted))
    assert abs(after["median_m"]) < 0.2
    assert after["nmad_m"] < 1.0
    # an adjustment without GCPs co-registers to the starting DEM by default; this scene's
    # 90 m start is too coarse over 750 m: the DEM is left as it is, and the report says why
    adjusted = tmp_path / "adj0"
    shutil.copytree(scene / "truth", adjusted)
    (adjusted / ".carto-output.json").write_text(json.dumps({"command": "adjust"}))
    auto = run_carto(
        [*base[:2], "--models", str(adjusted), "--posting", "10", "--out", str(tmp_path / "auto")]
    )
    assert auto.returncode == 0, auto.stderr
    c = json.loads((tmp_path / "auto" / "report.json").read_text())["coregistration"]
    assert not c["applied"]
    assert "span only" in c["reason"]


def test_dem_coregister_errors(run_carto, scene, tmp_path):
    proc = run_carto(["dem", str(scene), "--out", str(tmp_path / "x"), "--coregister", "nope"])
    assert proc.returncode == 2
    assert "--coregister must be auto, none or a reference DEM file" in proc.stderr
    far = tmp_path / "far.tif"
    d = DEM.open(scene / "truth" / "dem.tif")
    DEM.from_array(d.heights, d.transform @ d.transform.translation(5000, 0), d.crs).write(far)
    proc = run_carto(
        [
            "dem",
            str(scene),
            "--models",
            str(scene / "truth"),
            "--out",
            str(tmp_path / "y"),
            "--posting",
            "10",
            "--coregister",
            str(far),
        ]
    )
    assert proc.returncode == 1
    assert "does not cover" in proc.stderr or "do not overlap" in proc.stderr
    assert len(proc.stderr.strip().splitlines()[-1:]) == 1
    assert not (tmp_path / "y").exists()


def test_a_scene_with_loose_images_is_a_usage_error(run_carto, scene, tmp_path):
    """``--left``/``--right`` beside a scene folder were silently ignored (issue 31): refused,
    as is ``--pair`` without a scene; nothing is created."""
    left = scene / "fore.tif"
    for args, words in (
        ([str(scene), "--left", str(left), "--right", str(left)], "--left, --right exclude"),
        (["--left", str(left), "--right", str(left), "--pair", "a", "b"], "--pair chooses"),
    ):
        proc = run_carto(["dem", *args, "--out", str(tmp_path / "x")])
        assert proc.returncode == 2, proc.stderr
        assert words in proc.stderr
        assert "Traceback" not in proc.stderr
        assert not (tmp_path / "x").exists()


def test_bad_input_found_after_the_work_began_leaves_no_work_to_resume(run_carto, scene, tmp_path):
    """An initial DEM covering a fraction of the images is found bad once the images are prepared:
    no hidden work folder stays behind and no '--resume' is advised (it would refuse other
    inputs), only the cause (issue 31, family 5)."""
    init = DEM.open(scene / "init_dem.tif")
    heights = np.array(init.heights, dtype=np.float64)
    heights[:, heights.shape[1] // 4 :] = np.nan  # a quarter left
    half = tmp_path / "half.tif"
    DEM.from_array(heights, init.transform, init.crs).write(half)
    proc = run_carto(["dem", str(scene), "--init-dem", str(half), "--out", str(tmp_path / "x")])
    assert proc.returncode == 1, proc.stderr
    assert "% of the images' footprint" in proc.stderr
    assert "--resume" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half.tif"]


def test_images_of_two_places_do_not_give_a_dem(run_carto, scene, tmp_path):
    """Two images of different terrains given as a pair matched at 31-45 % of the nodes and
    gave a DEM of NMAD 74 m with exit 0 (issue 31): their coarse ortho-images do not
    correlate, which stops the run before matching; with --allow-poor it matches, and the
    DEM against its starting DEM tells too (NMAD 59 m here, against 3-4 m for a real pair):
    it is written with both warnings."""
    other = simulate(
        "cartosat1-pair", tmp_path / "other", seed=5, size=(300, 400), n_checkpoints=1,
        terrain="mountains",
    )  # fmt: skip
    mixed = tmp_path / "mixed"
    shutil.copytree(scene, mixed)
    shutil.copy(other / "fore.tif", mixed / "fore.tif")
    proc = run_carto(["dem", str(mixed), "--out", str(tmp_path / "d")])
    assert proc.returncode == 1, proc.stderr
    assert "the two images do not correlate" in proc.stderr
    assert "--allow-poor" in proc.stderr
    assert not (tmp_path / "d").exists()
    proc = run_carto(["dem", str(mixed), "--allow-poor", "--out", str(tmp_path / "d")])
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert report["pair_check"]["agreement"] < 0.5
    assert any("do not correlate" in w for w in report["warnings"])
    assert any("departs from its starting DEM" in w for w in report["warnings"])


def test_a_starting_dem_that_does_not_say_its_vertical_reference_is_warned_of(
    run_carto, scene, tmp_path
):
    """An outside probe saved SRTM's geoid heights as a plain EPSG:4326 GeoTIFF: read as
    ellipsoidal (the convention), the DEM came out 31 m low with no word. The scene's own
    starting DEM, tagged, gives no such warning (the test above)."""
    plain = tmp_path / "plain.tif"
    with rasterio.open(scene / "init_dem.tif") as src:
        profile, heights = src.profile, src.read(1)
    profile["crs"] = "EPSG:4326"  # the same heights, without a vertical CRS or tag
    with rasterio.open(plain, "w", **profile) as dst:
        dst.write(heights, 1)
    out = tmp_path / "dem"
    proc = run_carto(
        [
            *("dem", str(scene), "--models", str(scene / "truth"), "--init-dem", str(plain)),
            *("--posting", "20", "--max-iterations", "2", "--quiet", "--out", str(out)),
        ]
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "report.json").read_text())
    assert any("does not say what its heights are above" in w for w in report["warnings"])
    # a warning reaches stderr under --quiet too (an outside probe found it in the report only)
    assert "does not say what its heights are above" in proc.stderr


def test_a_generator_option_it_refuses_is_a_usage_error_before_any_work(run_carto, scene, tmp_path):
    """A CRS the generator refuses was refused by ior after the images had been prepared
    (issue 34, item 6): the generator's settings are now checked before, with exit 2 and no
    work left (a projected CRS in US survey feet)."""
    out = tmp_path / "x"
    proc = run_carto(["dem", str(scene), "--crs", "EPSG:2263", "--out", str(out)])
    assert proc.returncode == 2, proc.stderr
    assert "ior: option crs (--crs): 'EPSG:2263'" in proc.stderr
    assert "merge staggered" not in proc.stderr  # no image was prepared
    assert "--resume" not in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_te_sets_the_extent_on_the_grid_every_run_shares(run_carto, scene, tmp_path):
    """--te as gdalwarp's -te (issue 34 item 4): the DEM covers the extent asked for, snapped
    outwards to multiples of the posting (target-aligned pixels): two runs share one grid."""
    common = ["--models", str(scene / "truth"), "--posting", "20", "--max-iterations", "1"]
    full = tmp_path / "full"
    proc = run_carto(["dem", str(scene), *common, "--quiet", "--out", str(full)])
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(full / "dem.tif") as ds:
        left, bottom, right, top = ds.bounds
        whole = ds.read(1)
        whole_transform = ds.transform
    te = [left + 111.0, bottom + 95.0, right - 130.0, top - 77.0]  # not on the grid
    part = tmp_path / "part"
    proc = run_carto(
        ["dem", str(scene), *common, "--te", *map(str, te), "--quiet", "--out", str(part)]
    )
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(part / "dem.tif") as ds:
        b = ds.bounds
        assert (b.left, b.bottom) == (left + 100.0, bottom + 80.0)  # snapped outwards
        assert (b.right, b.top) == (right - 120.0, top - 60.0)
        # the same nodes as the full run's grid
        col, row = ~whole_transform * (b.left, b.top)
        assert (col, row) == (round(col), round(row))
        inner = whole[int(row) : int(row) + ds.height, int(col) : int(col) + ds.width]
        assert inner.shape == (ds.height, ds.width)
    far = run_carto(
        ["dem", str(scene), *common, "--te", "0", "0", "10", "10", "--out", str(tmp_path / "f")]
    )
    assert far.returncode == 1
    assert "(--te) 0 0 10 10 does not overlap the images' common footprint" in far.stderr
    flipped = run_carto(
        ["dem", str(scene), *common, "--te", "10", "0", "0", "10", "--out", str(tmp_path / "g")]
    )
    assert flipped.returncode == 2
    assert "XMIN < XMAX" in flipped.stderr
    assert not (tmp_path / "g").exists()


def test_a_geographic_dem_as_gdalwarp_users_ask_for_it(run_carto, scene, tmp_path):
    """--t_srs EPSG:4326 --tr DEG (issue 34 item 4): the DEM on a longitude/latitude grid
    snapped to multiples of the resolution, heights in EPSG:4979 (3-D, in the GeoTIFF keys),
    as accurate against the simulator's truth as the projected run."""
    common = ["--models", str(scene / "truth"), "--max-iterations", "2", "--quiet"]
    geo = tmp_path / "geo"
    proc = run_carto(
        ["dem", str(scene), *common, "--t_srs", "EPSG:4326", "--tr", "0.0002", "--out", str(geo)]
    )
    assert proc.returncode == 0, proc.stderr
    assert not (geo / "dem.tif.aux.xml").exists()  # the keys hold EPSG:4979
    with rasterio.open(geo / "dem.tif") as ds:
        crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        assert crs.to_epsg() == 4979
        assert ds.res == pytest.approx((0.0002, 0.0002))
        for edge in (ds.bounds.left, ds.bounds.top):
            assert edge / 0.0002 == pytest.approx(round(edge / 0.0002), abs=1e-6)
    with rasterio.open(geo / "quality_flags.tif") as ds:
        assert ds.dtypes == ("uint8",)
        assert pyproj.CRS.from_wkt(ds.crs.to_wkt()).to_epsg() == 4326
    with rasterio.open(geo / "ortho_left.tif") as ds:  # finer than the DEM, on its grid
        assert ds.res[0] < 0.0002
    report = json.loads((geo / "report.json").read_text())
    assert report["dem_grid"]["crs"] == "EPSG:4326"
    assert report["dem_grid"]["computed_on"]["crs"].startswith("EPSG:326")
    projected = tmp_path / "utm"
    proc = run_carto(["dem", str(scene), *common, "--posting", "22", "--out", str(projected)])
    assert proc.returncode == 0, proc.stderr
    truth = DEM.open(scene / "truth" / "dem.tif")
    geo_acc = dem_accuracy(DEM.open(geo / "dem.tif"), truth)
    utm_acc = dem_accuracy(DEM.open(projected / "dem.tif"), truth)
    assert geo_acc["nmad_m"] < 1.5 * utm_acc["nmad_m"] + 0.05
    assert abs(geo_acc["median_m"] - utm_acc["median_m"]) < 0.3
    other = run_carto(
        ["dem", str(scene), *common, "--t_srs", "EPSG:4258", "--out", str(tmp_path / "x")]
    )
    assert other.returncode == 2
    assert "EPSG:4326" in other.stderr
