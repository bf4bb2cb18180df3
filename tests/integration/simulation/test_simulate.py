"""The simulator engine: truth bookkeeping, rendering fidelity, determinism, CLI errors."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio

from carto.framework.errors import InputError
from carto.framework.files.point_table import read_point_table
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.products.ancillary import read_ancillary
from carto.framework.raster.dem import DEM

from ...scenes import simulate


def _read(path: Path) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path) as ds:
            return ds.read(1)


def _checkpoints(scene: Path) -> dict:
    return read_point_table(
        scene / "checkpoints.csv", numeric=("lon_deg", "lat_deg", "h_m", "line", "sample")
    )


def test_scene_folder_has_every_product(cartosat1_scene):
    scene = json.loads((cartosat1_scene / "scene.json").read_text())
    assert scene["format"] == "carto-scene"
    for image in scene["images"].values():
        raw = _read(cartosat1_scene / image["raster"])
        assert raw.dtype == np.uint16
        assert raw.shape == (400, 400)
        assert raw.max() <= 1023  # 10 bit (uint16 is never negative)
        assert (cartosat1_scene / image["ancillary"]).is_file()
        assert (cartosat1_scene / image["truth_model"]).is_file()
    for name in (
        "gcps.csv",
        "checkpoints.csv",
        "init_dem.tif",
        "truth/dem.tif",
        "truth/ortho.tif",
        "truth/errors.json",
    ):
        assert (cartosat1_scene / name).is_file(), name
    cp = _checkpoints(cartosat1_scene)
    assert set(cp["image"]) == {"fore", "aft"}
    assert len(set(cp["id"])) == 20
    gcps = read_point_table(cartosat1_scene / "gcps.csv", numeric=("sigma_px",))
    assert len(set(gcps["id"])) == 1
    assert np.all(gcps["sigma_px"] == 0.3)
    with rasterio.open(cartosat1_scene / "truth/dem.tif") as ds:
        assert ds.crs.to_epsg() == 4326
        assert "ellipsoid" in ds.tags()["VERTICAL_REFERENCE"]


def test_checkpoints_lie_on_the_true_dem_and_project_with_the_true_models(cartosat1_scene):
    """Checkpoint image coordinates come from the reference geometry; the true models (what
    the images are rendered through, another implementation) must agree to 0.01 px."""
    cp = _checkpoints(cartosat1_scene)
    dem = DEM.open(cartosat1_scene / "truth/dem.tif")
    np.testing.assert_allclose(dem.height(cp["lon_deg"], cp["lat_deg"]), cp["h_m"], atol=0.01)
    for name in ("fore", "aft"):
        truth = LineScanner.load(cartosat1_scene / f"truth/{name}.model.json")
        m = cp["image"] == name
        line, sample = truth.ground_to_image(cp["lon_deg"][m], cp["lat_deg"][m], cp["h_m"][m])
        np.testing.assert_allclose(line, cp["line"][m], atol=0.01)
        np.testing.assert_allclose(sample, cp["sample"][m], atol=0.01)
        assert np.abs(line - cp["line"][m]).max() > 0.0  # two implementations, not one call


def _target_centroids(
    raw: np.ndarray, first_sample: int, parity: int, line: float, sample: float, half: int = 7
) -> tuple[float, float]:
    """Centre of a point target in the columns of one array: least-squares fit of a 2-D
    Gaussian on a planar background (unbiased however coarsely the blob is sampled)."""
    from scipy.optimize import least_squares

    i0, j0 = round(float(line)), round(float(sample))
    rows = np.arange(i0 - half, i0 + half + 1)
    cols = np.arange(j0 - half, j0 + half + 1)
    cols = cols[(first_sample + cols) % 2 == parity]
    win = raw[np.ix_(rows, cols)].astype(float)
    r, c = np.meshgrid(rows + 0.5, cols + 0.5, indexing="ij")

    def model(p: np.ndarray) -> np.ndarray:
        b0, br, bc, amp, r0, c0, sr, sc = p
        g = np.exp(-0.5 * (((r - r0) / sr) ** 2 + ((c - c0) / sc) ** 2))
        return b0 + br * (r - line) + bc * (c - sample) + amp * g

    start = np.array([np.median(win), 0.0, 0.0, win.max() - np.median(win), line, sample, 2.0, 2.0])
    fit = least_squares(lambda p: (model(p) - win).ravel(), start)
    return float(fit.x[4]), float(fit.x[5])


@pytest.mark.parametrize("which", ["cartosat1", "cartosat2"])
def test_rendering_puts_targets_where_the_true_geometry_says(
    which, cartosat1_scene, cartosat2_triplet_scene
):
    scene = cartosat1_scene if which == "cartosat1" else cartosat2_triplet_scene
    manifest = json.loads((scene / "scene.json").read_text())
    cp = _checkpoints(scene)
    errors = []
    for name in manifest["images"]:
        raw = _read(scene / f"{name}.tif")
        truth = LineScanner.load(scene / f"truth/{name}.model.json")
        even = truth.with_camera(truth.camera.with_array("even"))
        m = (
            (cp["image"] == name)
            & (cp["line"] > 10)
            & (cp["line"] < 390)
            & (cp["sample"] > 10)
            & (cp["sample"] < 390)
        )
        for lon, lat, h, line, sample in zip(
            cp["lon_deg"][m],
            cp["lat_deg"][m],
            cp["h_m"][m],
            cp["line"][m],
            cp["sample"][m],
            strict=True,
        ):
            # odd array (0-based even detectors): the image model itself
            c_line, c_sample = _target_centroids(raw, truth.first_sample, 0, line, sample)
            errors.append((c_line - line, c_sample - sample))
            # even array: 5 lines later, seen by the even-array model
            e_line, e_sample = (float(v) for v in even.ground_to_image(lon, lat, h))
            c_line, c_sample = _target_centroids(raw, truth.first_sample, 1, e_line, e_sample)
            errors.append((c_line - e_line, c_sample - e_sample))
    errors = np.abs(np.array(errors))
    assert len(errors) >= 40
    assert np.median(errors) < 0.05
    assert errors.max() <= 0.1, errors.max()


def test_drawn_errors_explain_the_product_exactly(cartosat1_scene):
    """Applying the drawn errors as corrections to the product model gives back the truth."""
    drawn = json.loads((cartosat1_scene / "truth/errors.json").read_text())["drawn"]
    seg = drawn["segments"][0]
    anc = read_ancillary(cartosat1_scene / "body.ancillary.json")
    sensors = anc.sensors()
    traj = next(iter(sensors.values())).trajectory
    values = {}
    for k, axis in enumerate(("roll", "pitch", "yaw")):
        bias, drift = seg["attitude_bias_rad"][k], seg["attitude_drift_rad_s"][k]
        values[f"trajectory.attitude.{axis}.c0"] = bias + drift * traj.t_mid_s
        values[f"trajectory.attitude.{axis}.c1"] = drift * traj.t_half_s
    for k, axis in enumerate(("along", "across", "radial")):
        values[f"trajectory.position.{axis}.c0"] = seg["ephemeris_bias_m"][k]
    cp = _checkpoints(cartosat1_scene)
    for name, sensor in sensors.items():
        mis = drawn["camera_misalignment_rad"][name]
        cam = {f"camera.{name}.align.{a}": mis[i] for i, a in enumerate(("roll", "pitch", "yaw"))}
        corrected = sensor.with_parameters({**values, **cam})
        m = cp["image"] == name
        raw_l, raw_s = sensor.ground_to_image(cp["lon_deg"][m], cp["lat_deg"][m], cp["h_m"][m])
        line, sample = corrected.ground_to_image(cp["lon_deg"][m], cp["lat_deg"][m], cp["h_m"][m])
        before = np.nanmax(np.hypot(raw_l - cp["line"][m], raw_s - cp["sample"][m]))
        after = np.max(np.hypot(line - cp["line"][m], sample - cp["sample"][m]))
        assert after < 0.15, (name, after)  # the cubic orbit fit of the product remains
        assert np.isnan(before) or before > 20.0  # realistic errors are large


def test_same_seed_same_bytes_and_another_seed_differs(tmp_path):
    a = simulate("cartosat1-pair", tmp_path / "a", seed=3, size=(120, 100), n_checkpoints=5)
    b = simulate("cartosat1-pair", tmp_path / "b", seed=3, size=(120, 100), n_checkpoints=5)
    c = simulate("cartosat1-pair", tmp_path / "c", seed=4, size=(120, 100), n_checkpoints=5)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in files:
        if f.name == ".carto-output.json":  # the completion marker holds the time
            continue
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert _read(a / "fore.tif").shape == (100, 120)
    assert not np.array_equal(_read(a / "fore.tif"), _read(c / "fore.tif"))


def test_errors_none_product_matches_truth(tmp_path):
    scene = simulate(
        "cartosat1-pair", tmp_path / "s", seed=2, size=(200, 200), errors="none", n_checkpoints=10
    )
    sensors = read_ancillary(scene / "body.ancillary.json").sensors()
    cp = _checkpoints(scene)
    for name, sensor in sensors.items():
        m = cp["image"] == name
        line, sample = sensor.ground_to_image(cp["lon_deg"][m], cp["lat_deg"][m], cp["h_m"][m])
        assert np.max(np.hypot(line - cp["line"][m], sample - cp["sample"][m])) < 0.15
    gcps = read_point_table(scene / "gcps.csv", numeric=("lon_deg", "line", "sigma_px"))
    assert np.all(gcps["sigma_px"] == 0)


def test_init_dem_is_coarse_biased_and_covers_the_scene(cartosat1_scene):
    init = DEM.open(cartosat1_scene / "init_dem.tif")
    truth = DEM.open(cartosat1_scene / "truth/dem.tif")
    assert abs(init.transform.a * 3600 - 3.0) < 1e-9  # 3 arc-seconds, like SRTM
    assert init.covers(*_corners(truth)).all()
    west, south, east, north = truth.bounds_lonlat
    lon, lat = np.meshgrid(np.linspace(west, east, 50)[1:-1], np.linspace(south, north, 50)[1:-1])
    diff = init.height(lon.ravel(), lat.ravel()) - truth.height(lon.ravel(), lat.ravel())
    assert 1.0 < np.sqrt(np.nanmean(diff**2)) < 40.0
    assert not np.isnan(init.heights).any()


def _corners(dem: DEM):
    west, south, east, north = dem.bounds_lonlat
    eps = 1e-6
    return (
        np.array([west + eps, east - eps, west + eps, east - eps]),
        np.array([south + eps, south + eps, north - eps, north - eps]),
    )


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [  # a name or option that is wrong is a usage error (2), a file or a size bad data (1)
        (
            ["simulate", "no-such-preset", "--out", "X"],
            2,
            "unknown scene preset 'no-such-preset'",
        ),
        (
            ["simulate", "cartosat1-pair", "--out", "X", "--terrain", "moon"],
            2,
            "--terrain 'moon': known terrains: flat-coastal",
        ),
        (
            ["simulate", "cartosat1-pair", "--out", "X", "--size", "20000", "100"],
            1,
            "must be within the full image",
        ),
        (["simulate", "cartosat1-pair", "--out", "X", "--dem", "missing.tif"], 1, "no such file"),
    ],
)
def test_bad_simulate_arguments_are_one_line_errors(run_carto, tmp_path, args, code, message):
    args = [a if a != "X" else str(tmp_path / "out") for a in args]
    res = run_carto(args, with_test_plugins=False)
    assert res.returncode == code
    assert res.stderr.strip().count("\n") == 0, res.stderr
    assert message in res.stderr
    assert "Traceback" not in res.stderr


def test_simulate_cli_writes_a_scene(run_carto, tmp_path):
    res = run_carto(
        [
            "simulate",
            "cartosat1-pair",
            "--out",
            str(tmp_path / "s"),
            "--size",
            "64",
            "64",
            "--seed",
            "1",
            "--checkpoints",
            "4",
            "--terrain",
            "plains",
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    scene = json.loads((tmp_path / "s" / "scene.json").read_text())
    assert scene["terrain"] == "plains"
    assert "rendered fore" in res.stderr  # progress
    assert math.isfinite(scene["epoch_j2000_s"])


def test_error_sizes_switch_single_sources(tmp_path):
    scene = simulate(
        "cartosat1-pair",
        tmp_path / "e",
        seed=1,
        size=(80, 80),
        n_checkpoints=3,
        errors="none",
        error_sizes=(("attitude_bias_deg", 0.05),),
    )
    drawn = json.loads((scene / "truth/errors.json").read_text())
    seg = drawn["drawn"]["segments"][0]
    assert any(v != 0 for v in seg["attitude_bias_rad"])
    assert seg["ephemeris_bias_m"] == [0.0, 0.0, 0.0]
    assert drawn["error_model"]["attitude_bias_deg"] == 0.05
    with pytest.raises(InputError, match="unknown error source 'sun'"):
        simulate("cartosat1-pair", tmp_path / "f", size=(80, 80), error_sizes=(("sun", 1.0),))
    # a slip of the finger (1e308 deg) is no product: refused, nothing simulated
    with pytest.raises(InputError, match=r"attitude_bias_deg=1e\+308: beyond 2"):
        simulate(
            "cartosat1-pair",
            tmp_path / "g",
            size=(80, 80),
            error_sizes=(("attitude_bias_deg", 1e308),),
        )
    with pytest.raises(InputError, match="--seed must be an integer >= 0, got -1"):
        simulate("cartosat1-pair", tmp_path / "h", size=(80, 80), seed=-1)
    assert not (tmp_path / "g").exists()
    assert not (tmp_path / "h").exists()


def test_a_user_dem_becomes_the_terrain(tmp_path, cartosat1_scene):
    user_dem = cartosat1_scene / "truth/dem.tif"  # any ellipsoidal DEM covering the area
    scene = simulate(
        "cartosat1-pair",
        tmp_path / "u",
        seed=1,
        size=(100, 100),
        n_checkpoints=4,
        dem_path=user_dem,
    )
    manifest = json.loads((scene / "scene.json").read_text())
    assert manifest["terrain"] == "file:dem.tif"
    a, b = DEM.open(user_dem), DEM.open(scene / "truth/dem.tif")
    west, south, east, north = b.bounds_lonlat
    lon = np.linspace(west, east, 9)[1:-1]
    lat = np.linspace(south, north, 9)[1:-1]
    np.testing.assert_allclose(b.height(lon, lat), a.height(lon, lat), atol=0.5)


def test_cli_error_size_and_platform_seed(run_carto, tmp_path):
    """``--error-size`` switches single sources; ``--platform-seed`` gives two scenes of one
    satellite the same camera misalignment while their other errors differ."""
    drawn = {}
    for seed in (3, 4):
        out = tmp_path / f"s{seed}"
        result = run_carto(
            [
                "simulate",
                "cartosat1-pair",
                "--out",
                str(out),
                "--seed",
                str(seed),
                "--size",
                "60",
                "60",
                "--checkpoints",
                "2",
                "--platform-seed",
                "11",
                "--error-size",
                "ephemeris_bias_m=0",
                "--quiet",
            ]
        )
        assert result.returncode == 0, result.stderr
        drawn[seed] = json.loads((out / "truth/errors.json").read_text())
        assert json.loads((out / "scene.json").read_text())["platform_seed"] == 11
    mis = [d["drawn"]["camera_misalignment_rad"] for d in drawn.values()]
    assert mis[0] == mis[1]
    assert all(v != 0 for v in mis[0]["aft"])
    segs = [d["drawn"]["segments"][0] for d in drawn.values()]
    assert segs[0]["attitude_bias_rad"] != segs[1]["attitude_bias_rad"]
    assert segs[0]["ephemeris_bias_m"] == [0.0, 0.0, 0.0]
    assert drawn[3]["error_model"]["ephemeris_bias_m"] == 0.0
    bad = run_carto(
        ["simulate", "cartosat1-pair", "--out", str(tmp_path / "x"), "--error-size", "sun"]
    )
    assert bad.returncode != 0
    assert "expected NAME=VALUE" in bad.stderr
    assert "Traceback" not in bad.stderr
    # usage errors (exit 2, one line): a value out of range, an unknown source, a seed < 0
    for args, words in (
        (["--error-size", "attitude_bias_deg=1e308"], "must be between 0 and 2"),
        (["--error-size", "gcp_heigth_m=1"], "unknown error source 'gcp_heigth_m'"),
        (["--seed", "-1"], "--seed: must be >= 0, got -1"),
        (["--size", "0", "80"], "--size: must be >= 1, got 0"),
    ):
        bad = run_carto(["simulate", "cartosat1-pair", "--out", str(tmp_path / "x"), *args])
        assert bad.returncode == 2, bad.stderr
        assert words in bad.stderr
        assert "Traceback" not in bad.stderr
        assert not (tmp_path / "x").exists()


def test_the_true_ortho_covers_every_pixel_the_images_see(cartosat1_scene):
    """The true ortho-image is resampled only where the images see the ground (plus a
    margin): every pixel of either image, located on the true DEM with its true model (and
    pyproj into the ortho's grid), falls on a value."""
    ortho_ds = rasterio.open(cartosat1_scene / "truth/ortho.tif")
    ortho = ortho_ds.read(1)
    dem = DEM.open(cartosat1_scene / "truth/dem.tif")
    import pyproj

    to_grid = pyproj.Transformer.from_crs("EPSG:4326", ortho_ds.crs, always_xy=True)
    rng = np.random.default_rng(0)
    for name in ("fore", "aft"):
        truth = LineScanner.load(cartosat1_scene / f"truth/{name}.model.json")
        lines, samples = truth.image_shape
        edge = np.r_[0.0, lines].repeat(500)
        line = np.r_[rng.uniform(0, lines, 4000), edge]
        sample = np.r_[rng.uniform(0, samples, 4000), rng.uniform(0, samples, edge.size)]
        lon, lat, _ = truth.locate_on_dem(line, sample, dem)
        x, y = to_grid.transform(lon, lat)
        rows, cols = rasterio.transform.rowcol(ortho_ds.transform, x, y)
        assert np.isfinite(ortho[np.asarray(rows), np.asarray(cols)]).all(), name
